"""One Taichi runtime for the whole test session (compiling kernels is the slow part), on the CPU
unless --arch says otherwise; GPU-only tests skip cleanly (cf. Genesis tests/conftest.py).

``make test`` runs the suite on two pytest-xdist workers, one runtime each; each worker keeps
its own Taichi offline cache, so the two never wait on one cache's lock.

The session compiles without Taichi's own IR optimisation passes (``advanced_optimization``,
which ``ti.init`` reads from ``TI_ADVANCED_OPTIMIZATION``; set here for this process and the
command-line runs it starts, unless already set): the same kernels and model, LLVM
optimising them as always (the rounding differs, so a trajectory is not the product's bit for
bit), and about half the compile time that dominates the suite, while runs (``simulate``,
``bench``) keep the passes, with which the shipped scenes step 10-40 % faster
(docs/performance.md, "The test session compiles without Taichi's IR passes").
``tests/test_runtime.py`` runs the shipped ``hula`` with the passes on, as a user does.
``TI_ADVANCED_OPTIMIZATION=1 make test`` runs the whole suite with them."""

import os
from pathlib import Path

import pytest

from taichi_cloth.runtime import start_taichi

os.environ.setdefault("TI_ADVANCED_OPTIMIZATION", "0")


def pytest_addoption(parser):
    parser.addoption("--arch", default="cpu", choices=("cpu", "cuda", "vulkan", "gpu"),
                     help="Taichi backend for the test session")


@pytest.fixture(scope="session", autouse=True)
def taichi_runtime(request):
    worker = os.environ.get("PYTEST_XDIST_WORKER")
    if worker and "TI_OFFLINE_CACHE_FILE_PATH" not in os.environ:
        os.environ["TI_OFFLINE_CACHE_FILE_PATH"] = str(
            Path.home() / ".cache" / "taichi" / f"ticache-{worker}")
    start_taichi(request.config.getoption("--arch"))


@pytest.fixture(scope="session")
def blender_python() -> Path:
    """The Python of Blender's module venv (``make check-blender`` installs pip's bpy there,
    ~350 MB: not in CI); the test is skipped where it is absent."""
    python = Path(__file__).resolve().parents[1] / ".venv-blender" / "bin" / "python"
    if not python.exists():
        pytest.skip("Blender's Python module is not installed: `make check-blender` installs "
                    "it (pip's bpy, ~350 MB) and runs this check")
    return python
