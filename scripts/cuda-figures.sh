#!/usr/bin/env bash
# The --arch cuda figures of docs/performance.md, on a machine with an NVIDIA GPU: the CPU/CUDA
# agreement tests, the reference sheet, then each real scene with every integrator on CUDA, one
# process per part under its own time limit, the rows printed as JSON lines as they are measured,
# so that a slow compile or a failing part keeps what came before. (A run defers SIGTERM to the
# end of its launch and a compile is not interrupted: the limit kills 10 s after it.)
# Compiling for CUDA takes most of such a run (10-60 s a kernel set) and uses the host's CPU
# only, so it is done first for every part at once, in parallel, with one tiny timed repeat that
# fills Taichi's offline cache; the agreement tests run beside it. Then the parts are timed one
# after the other, from the cache, each alone on the GPU.
# Usage: scripts/cuda-figures.sh OUT_DIR [SCENE:SECONDS[:INTEGRATOR,...] ...]
#   (a part's integrators: all four unless named; default parts: the reference sheet at 64² and 256², hula-paper:80 flag:80 drape:80
#   hula:240; each part's log lands in OUT_DIR; the warm-up's logs as warm-NAME.log)
set -uo pipefail
out="${1:?usage: scripts/cuda-figures.sh OUT_DIR [SCENE:SECONDS[:INTEGRATOR,...] ...]}"
shift
mkdir -p "$out"
python="${PYTHON:-python3}"
export PYTHONUNBUFFERED=1
nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader || true
parts="${*:-hula-paper:80 flag:80 drape:80 hula:240}"

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
integrators = sys.argv[4].split(",") if sys.argv[4] else None
for row in bench_scene_integrators(sys.argv[1], float(sys.argv[2]), int(sys.argv[3]), integrators):
    print(json.dumps(row), flush=True)
'
sheet=("$python" -m taichi_cloth bench --arch cuda --sizes 64,256 --quiet)  # its table

echo "== warm-up: compiling every part at once, the agreement tests beside it"
started=$SECONDS
part agree 280 "$python" -m pytest -q -p no:cacheprovider --basetemp=/tmp/agree \
    tests/test_backends.py -k cuda -rs > "$out/agree.summary" &
part warm-sheet 280 "${sheet[@]}" --seconds 0.01 --repeats 1 > /dev/null &
for item in $parts; do
    IFS=: read -r scene limit integrators <<< "$item"
    part "warm-$scene" 280 "$python" -c "$scene_rows" "$scene" 0.01 1 "$integrators" > /dev/null &
done
wait
echo "== warm-up done after $((SECONDS - started)) s"
cat "$out/agree.summary"

part sheet 120 "${sheet[@]}" --seconds 0.5 --repeats 3
for item in $parts; do
    IFS=: read -r scene limit integrators <<< "$item"
    part "$scene" "$limit" "$python" -c "$scene_rows" "$scene" 0.3 2 "$integrators"
done
