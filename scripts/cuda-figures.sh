#!/usr/bin/env bash
# The --arch cuda figures of docs/performance.md, on a machine with an NVIDIA GPU: the CPU/CUDA
# agreement tests, then `bench --arch cuda` on the reference sheet and on the real scenes, each
# part under its own time limit so that one slow or failing part cannot take the others with it.
# Usage: scripts/cuda-figures.sh OUT_DIR  (JSON rows and each part's log land in OUT_DIR)
set -uo pipefail
out="${1:?usage: scripts/cuda-figures.sh OUT_DIR}"
mkdir -p "$out"
python="${PYTHON:-python3}"
export PYTHONUNBUFFERED=1
nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader || true

part() {  # part NAME SECONDS COMMAND...: run a command under a limit, its output to NAME.log
    local name="$1" limit="$2"; shift 2
    local started=$SECONDS
    timeout "$limit" "$@" >"$out/$name.log" 2>&1
    echo "== $name: exit $? after $((SECONDS - started)) s"
    tail -n 40 "$out/$name.log"
}

part agree 90 "$python" -m pytest -q -p no:cacheprovider tests/test_backends.py -k cuda -rs
part reference 100 "$python" -m taichi_cloth bench --arch cuda --sizes 64,256,512 \
    --integrators symplectic,implicit --seconds 0.5 --repeats 2 --json "$out/reference.json"
part hula 190 "$python" -m taichi_cloth bench --arch cuda --scene hula --seconds 0.5 \
    --repeats 2 --json "$out/hula.json"
part scenes 160 "$python" -m taichi_cloth bench --arch cuda --scene hula-paper,flag,drape \
    --seconds 0.3 --repeats 2 --json "$out/scenes.json"
