"""The runtime's configuration holds whatever the environment says: ``TI_OPT_LEVEL=0`` (which
``ti.init`` reads) made Taichi 1.7.4 compile a serial loop's read-modify-write of a 0-d field as
if the field never changed, so ``start_taichi`` sets the level itself (taichi_cloth/runtime.py)."""

import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent

# rows of 3 finds gathered into one list through a counter in a 0-d field, on one thread, as
# self-collision's candidate list is (effects/candidate_pairs.py, ``_gather_found``)
COUNTER_KERNEL = """
import taichi as ti
from taichi_cloth.runtime import start_taichi
start_taichi("cpu")
count = ti.field(ti.i32, ())
rows = ti.field(ti.i32, 10)
listed = ti.field(ti.i32, 100)

@ti.kernel
def gather():
    ti.loop_config(serialize=True)
    for _ in range(1):
        count[None] = 0
        for owner in range(10):
            for n in range(rows[owner]):
                k = count[None]
                listed[k] = owner
                count[None] = k + 1

rows.fill(3)
gather()
print(count[None], ti.lang.impl.current_cfg().opt_level)
"""


def test_a_counter_in_a_serial_loop_counts_whatever_ti_opt_level_says(tmp_path):
    script = tmp_path / "counter.py"  # a file: Taichi reads a kernel's source
    script.write_text(COUNTER_KERNEL)
    result = subprocess.run([sys.executable, str(script)], cwd=REPO,
                            capture_output=True, text=True, timeout=120,
                            env={**os.environ, "TI_OPT_LEVEL": "0", "PYTHONPATH": str(REPO)})
    assert result.returncode == 0, result.stderr
    assert result.stdout.split()[-2:] == ["30", "1"]
