#!/usr/bin/env bash
# The --arch cuda figures of docs/performance.md, on a machine with an NVIDIA GPU: the CPU/CUDA
# agreement tests, then each real scene with every integrator on CUDA, one process per scene
# under its own time limit, the rows printed as JSON lines as they are measured, so that a slow
# compile or a failing part keeps what came before. (A run defers SIGTERM to the end of its
# launch and a compile is not interrupted: the limit kills 10 s after it.)
# Usage: scripts/cuda-figures.sh OUT_DIR [SCENE:SECONDS ...]
#   (default parts: hula-paper:80 flag:80 drape:80 hula:150; each part's log lands in OUT_DIR)
set -uo pipefail
out="${1:?usage: scripts/cuda-figures.sh OUT_DIR [SCENE:SECONDS ...]}"
shift
mkdir -p "$out"
python="${PYTHON:-python3}"
export PYTHONUNBUFFERED=1
nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader || true

part() {  # part NAME SECONDS COMMAND...: run a command under a limit, its output to NAME.log
    local name="$1" limit="$2"; shift 2
    local started=$SECONDS
    timeout -k 10 "$limit" "$@" >"$out/$name.log" 2>&1
    echo "== $name: exit $? after $((SECONDS - started)) s"
    grep -v -e Warning -e '^ *"""' -e '^  *Save a field' "$out/$name.log" | tail -n 25
}

scene_rows='
import json, sys
import taichi as ti
from taichi_cloth.runtime import start_taichi
from taichi_cloth.studies.bench_scene import bench_scene_integrators
start_taichi("cuda")
assert ti.lang.impl.current_cfg().arch == ti.cuda, "no CUDA device: Taichi fell back"
for row in bench_scene_integrators(sys.argv[1], 0.3, 2):
    print(json.dumps(row), flush=True)
'

part agree 150 "$python" -m pytest -q -p no:cacheprovider --basetemp=/tmp/agree \
    tests/test_backends.py -k cuda -rs
for spec in "${@:-hula-paper:80 flag:80 drape:80 hula:150}"; do
    for item in $spec; do
        part "${item%%:*}" "${item##*:}" "$python" -c "$scene_rows" "${item%%:*}"
    done
done
