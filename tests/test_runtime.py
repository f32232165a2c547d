"""The runtime's configuration holds whatever the environment says: ``TI_OPT_LEVEL=0`` (which
``ti.init`` reads) made Taichi 1.7.4 compile a serial loop's read-modify-write of a 0-d field as
if the field never changed, so ``start_taichi`` sets the level itself (taichi_cloth/runtime.py).
And the configuration a user runs, with Taichi's IR optimisation passes that the test session
turns off (conftest.py), runs the shipped ``hula`` within its bounds; a launch compiled without
those passes (``without_taichi_passes``: the reference sheet's SIMD lanes) is keyed by that
configuration, and the passes are back on after it."""

import json
import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent


def shipped_environment(**extra) -> dict:
    """The environment of a user's run: the test session's ``TI_ADVANCED_OPTIMIZATION`` left
    out, so Taichi's default (on) holds."""
    environment = {k: v for k, v in os.environ.items() if k != "TI_ADVANCED_OPTIMIZATION"}
    return {**environment, "PYTHONPATH": str(REPO), **extra}

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
                            env=shipped_environment(TI_OPT_LEVEL="0"))
    assert result.returncode == 0, result.stderr
    assert result.stdout.split()[-2:] == ["30", "1"]


# one kernel, launched inside ``without_taichi_passes(wanted)`` (argv[1]) or not at all (""),
# then the passes' state after it
PASSES_KERNEL = """
import sys
import taichi as ti
from taichi_cloth.runtime import start_taichi, without_taichi_passes
start_taichi("cpu")
total = ti.field(ti.f32, ())

@ti.kernel
def add(value: ti.f32):
    total[None] += value * value

config = ti.lang.impl.get_runtime().prog.config()
with without_taichi_passes(sys.argv[1] == "off"):
    before = config.advanced_optimization
    add(3.0)
try:
    with without_taichi_passes():
        raise RuntimeError
except RuntimeError:
    pass
print(before, config.advanced_optimization, total[None])
"""


def test_a_launch_without_taichi_passes_compiles_a_kernel_of_its_own_and_restores_them(tmp_path):
    """Each process compiles ``add`` into an empty offline cache shared by the three: with the
    passes off a kernel of its own (a second cache file beside the one compiled with them on),
    found again by the next process that turns them off (no third file); after the context, an
    exception in one included, the passes are on again."""
    script = tmp_path / "passes.py"
    script.write_text(PASSES_KERNEL)
    cache = tmp_path / "cache"
    files = []
    for passes, expected_during in (("on", "True"), ("off", "False"), ("off", "False")):
        result = subprocess.run([sys.executable, str(script), passes], cwd=REPO,
                                capture_output=True, text=True, timeout=120,
                                env=shipped_environment(TI_OFFLINE_CACHE_FILE_PATH=str(cache)))
        assert result.returncode == 0, result.stderr
        assert result.stdout.split()[-3:] == [expected_during, "True", "9.0"]
        files.append(len(list(cache.rglob("*.tic"))))
    assert files[0] >= 1
    assert files[1] == files[0] + 1 and files[2] == files[1]


def test_the_shipped_hula_runs_within_its_bounds_as_a_user_compiles_it(tmp_path):
    """`simulate hula` (64 × 28 measured cotton, backward Euler at 1/60 s, settled first) for
    its first 6 frames in the configuration a user runs: finite, strain under 3 %, the whole
    surface's penetration under the 4 mm contact margin, frame 0 hanging at rest (mean speed
    < 0.05 m/s)."""
    out = tmp_path / "hula"
    result = subprocess.run([sys.executable, "-m", "taichi_cloth", "simulate", "hula",
                             "--frames", "6", "--out", str(out), "--quiet"], cwd=REPO,
                            capture_output=True, text=True, timeout=300,
                            env=shipped_environment())
    assert result.returncode == 0, result.stderr
    stats = json.loads((out / "stats.json").read_text())
    assert stats["finite"] and stats["frames"] == 7 and stats["particles"] >= 64 * 28
    assert stats["max_strain"] < 0.03
    assert stats["max_penetration"] < 0.004
    assert stats["per_frame"][0]["mean_speed"] < 0.05


def test_remembered_sources_are_read_once_per_code_and_file_and_keep_no_function_alive(tmp_path):
    """``remembered_by_code``: two closures of one code share one read; the same code from
    another file is read again (code objects compare equal across files); a closure whose
    answer is kept is not kept alive by it."""
    import gc
    import weakref

    from taichi_cloth.runtime import remembered_by_code

    reads = []
    read = remembered_by_code(lambda func: reads.append(func.__code__.co_filename) or len(reads))

    def make(scale):
        def scaled(value):
            return scale * value
        return scaled

    first, second = make(2.0), make(3.0)
    assert read(first) == read(second) == 1 and len(reads) == 1
    twins = []
    for name in ("a.py", "b.py"):  # equal code objects, two files
        namespace = {}
        exec(compile("def twin(value):\n    return 2.0 * value\n", str(tmp_path / name), "exec"),
             namespace)
        twins.append(namespace["twin"])
    assert twins[0].__code__ == twins[1].__code__
    assert (read(twins[0]), read(twins[1]), read(twins[0])) == (2, 3, 2)
    alive = weakref.ref(second)
    del second
    gc.collect()
    assert alive() is None


def test_a_field_keeps_the_innermost_frames_of_where_it_was_declared():
    """``innermost_traceback``: what Taichi records where a field is declared is the end of the
    whole stack's traceback, ``TRACEBACK_FRAMES`` frames of it, this test's line among them."""
    import taichi as ti
    from taichi.lang.util import get_traceback

    from taichi_cloth.runtime import TRACEBACK_FRAMES, innermost_traceback

    whole, innermost = get_traceback(1), innermost_traceback(1)
    assert whole.endswith(innermost)
    assert innermost.count('  File "') == TRACEBACK_FRAMES < whole.count('  File "')
    declared = ti.field(ti.f32, 2)
    where = declared.vars[0].declaration_tb
    assert where.count('  File "') == TRACEBACK_FRAMES
    assert f'File "{__file__}"' in where and "declared = ti.field(ti.f32, 2)" in where
