"""Starting the one Taichi runtime of a process."""

import contextlib
import functools
import io
import textwrap
import traceback
import types

import taichi as ti
from taichi.lang import _ndarray, impl, kernel_impl, matrix, snode
from taichi.lang.ast import ast_transformer_utils

from taichi_cloth.errors import InputError

ARCHES = {"cpu": ti.cpu, "cuda": ti.cuda, "vulkan": ti.vulkan, "gpu": ti.gpu}
ARCH_NAMES = tuple(ARCHES)  # --arch and simulation.arch
# Taichi's own optimisation of a kernel's stores and loads (``cfg_optimization``: store-to-load
# forwarding over reaching definitions, then dead stores) costs more than the rest of a compile
# and grows faster than the kernel (40 of the 47 s that `fold`'s frame kernel spent in Taichi's
# passes); LLVM, which optimises the code next, keeps local variables in registers itself.
# Off on the CPU: the kernels compile 2-3 times faster and step as fast, within the noise
# (docs/performance.md, "Where a compile's time goes"). On for the GPU archs, unmeasured there.
CFG_OPTIMIZATION_ON_CPU = False
# Taichi's other IR passes (``advanced_optimization``: common subexpressions over the whole
# kernel, loop-invariant motion, ...) stay as Taichi's default (on): `hula`'s steps are 10-20 %
# faster with them and its contact pass ~40 %. They take half of a compile, so the test session
# turns them off through ``TI_ADVANCED_OPTIMIZATION`` (tests/conftest.py; docs/performance.md).
# A launch whose whole substep runs in SIMD lanes without face effects or gathered effects
# (contact, wind) is compiled without them (``without_taichi_passes``): the gravity-only
# reference sheet steps 20-40 % faster so.

# Taichi's own optimisation level, set here so that ``TI_OPT_LEVEL`` in the environment (which
# ``ti.init`` reads) cannot change it: at 0 Taichi 1.7.4 compiles a serial loop that reads and
# writes a counter in a 0-d field as if the counter never changed (self-collision's candidate
# list kept 1 pair of 919; docs/performance.md), wrong results without an error.
OPT_LEVEL = 1


def taichi_started() -> bool:
    return ti.lang.impl.get_runtime().prog is not None


def start_taichi(arch: str = "cpu", kernel_profiler: bool = False,
                 threads: int | None = None) -> None:
    """``ti.init`` on ``arch`` unless this process already started Taichi (a test session
    shares one runtime; ``ti.init`` again would drop every field and compiled kernel).
    kernel_profiler: time every kernel (``ti.profiler``; it slows each launch); threads: the
    CPU backend's thread count (None: one per core; a sweep's worker takes one, so that runs
    side by side do not compete for cores and their timings stay comparable)."""
    if taichi_started():
        return
    ast_transformer_utils.ASTTransformerContext.get_pos_info = short_position_info
    remember_kernel_sources()
    for module in (impl, snode, matrix, _ndarray):
        module.get_traceback = innermost_traceback
    options = {"opt_level": OPT_LEVEL}
    if threads is not None:
        options["cpu_max_num_threads"] = threads
    if arch == "cpu":
        options["cfg_optimization"] = CFG_OPTIMIZATION_ON_CPU
    with contextlib.redirect_stdout(io.StringIO()):  # ti.init prints "Starting on arch=..."
        ti.init(arch=ARCHES[arch], random_seed=0, kernel_profiler=kernel_profiler, **options)
    if arch != "cpu" and ti.lang.impl.current_cfg().arch == ti.cpu:
        raise InputError(f"--arch {arch}: no {arch} device found (Taichi fell back to the CPU)")


@contextlib.contextmanager
def without_taichi_passes(wanted: bool = True):
    """Kernels first launched inside compile without Taichi's IR passes (``advanced_optimization``
    off; LLVM still optimises them), when ``wanted``. Taichi reads the program's configuration
    when it first compiles a kernel and keys the compiled kernel (and its offline cache entry) by
    it, so later launches outside run the same code. A ``ti.real_func`` is compiled once, by the
    first kernel that calls it, whatever the next one's configuration: a caller wraps only
    kernels whose real functions no other kernel calls. The gravity-only SIMD lanes (the
    reference sheet) step 20-40 % faster so at 64²-128² (docs/performance.md, "The lanes
    compiled without Taichi's IR passes"; why, was not traced)."""
    if not wanted:  # every other integrator's launch: nothing to read or set
        yield
        return
    config = ti.lang.impl.get_runtime().prog.config()
    before = config.advanced_optimization
    config.advanced_optimization = False
    try:
        yield
    finally:
        config.advanced_optimization = before


def remember_kernel_sources() -> None:
    """Taichi 1.7 reads a ``ti.func``'s source again every time a kernel inlines it
    (``inspect.getsourcelines``: the module found by scanning ``sys.modules``, the function's
    block tokenised; ``getsourcefile``), hundreds of times a scene (812 reads of 98 functions
    for 3 frames of ``hula``). Each answer is kept for the process, by the function's code
    object and its file (closures of one code share it; code put in place by a reload is new;
    nothing else of the function is kept alive): building ``hula``'s kernels took 1.2-1.4 s
    against 1.6-1.9 s, the whole 3-frame run 4.5-5.2 s against 5.0-6.0 s (in turns; with the
    offline cache warm). The tree is still parsed afresh each time (Taichi's transformer writes
    into it)."""
    for name in ("getsourcelines", "getsourcefile"):
        reader = getattr(kernel_impl, name)
        if not getattr(reader, "remembers", False):
            setattr(kernel_impl, name, remembered_by_code(reader))
    kernel_impl.textwrap = REMEMBERED_TEXTWRAP


# What Taichi 1.7 uses of ``textwrap`` when it parses a function (``fill`` on each source line,
# then ``dedent``): pure functions of their text, their answers kept for the process (the
# lines of every parse of every function of the 3 files of tests profiled: 117,000 ``fill``s,
# 5 of the 330 s under the profiler).
REMEMBERED_TEXTWRAP = types.SimpleNamespace(
    fill=functools.cache(textwrap.fill), dedent=functools.cache(textwrap.dedent))


def remembered_by_code(reader):
    """``reader(func)`` remembered per (file, first line, code object) of ``func``: code
    objects compare by value, not by file. Anything without ``__code__`` is read each time."""
    answers = {}

    def read(func):
        code = getattr(func, "__code__", None)
        if code is None:
            return reader(func)
        key = (code.co_filename, code.co_firstlineno, code)
        if key not in answers:
            answers[key] = reader(func)
        return answers[key]

    read.remembers = True
    return read


TRACEBACK_FRAMES = 4  # of the stack where a field is declared, kept for Taichi's messages


def innermost_traceback(stacklevel: int = 1) -> str:
    """Taichi 1.7's ``get_traceback`` for what it records where a field or SNode is declared
    (shown if a field is used unplaced), but of the ``TRACEBACK_FRAMES`` frames within: Taichi
    formats the whole stack, each line read from its file, at every field it creates (13 of
    the 330 s that 3 files of tests took under the profiler; deep under pytest)."""
    frames = traceback.extract_stack(limit=stacklevel + 1 + TRACEBACK_FRAMES)
    return "".join(traceback.format_list(frames[: -1 - stacklevel]))


def short_position_info(context, node) -> str:
    """Where an AST node of a kernel is: 'File "...", line N, in name:' and a newline.

    Taichi 1.7 builds this for every node of every kernel it parses, the line of source and a
    caret line under it wrapped by ``textwrap`` included, to be ready for an error message that
    almost never comes; on the ``hula`` that was 0.4 s of the 1.3 s its kernels took to build
    and load from the offline cache (docs/performance.md). Compile errors keep the file, line
    and function, without the excerpt."""
    return f'File "{context.file}", line {node.lineno + context.lineno_offset}, ' \
           f"in {context.func.func.__name__}:\n"


def field_trees() -> int:
    """How many field (SNode) trees the started runtime holds: every batch of fields allocated
    between two kernel launches is one, and none is freed until the runtime is reset."""
    return ti.lang.impl.get_runtime().prog.get_snode_tree_size()


def reset_taichi() -> None:
    """Stop the started runtime, dropping every field and compiled kernel (the next
    ``start_taichi`` starts a fresh one; kernels compile again, from the offline cache)."""
    ti.reset()


def taichi_threads() -> int:
    """The started runtime's CPU thread count."""
    return ti.lang.impl.current_cfg().cpu_max_num_threads


def runs_on_cpu() -> bool:
    """Whether the started runtime runs on the CPU. Only there does ``ti.loop_config(serialize=
    True)`` on a kernel's outer loop make its inner loops run one after another on one thread:
    the GPU backends (Vulkan, CUDA) run such an outer loop's iterations side by side, so a
    whole-frame launch would take one substep's worth of motion per frame."""
    return ti.lang.impl.current_cfg().arch in (ti.x64, ti.arm64)
