"""One Taichi runtime for the whole test session (compiling kernels is the slow part), on the CPU
unless --arch says otherwise; GPU-only tests skip cleanly (cf. Genesis tests/conftest.py).

``make test`` runs the suite on two pytest-xdist workers, one runtime each; each worker keeps
its own Taichi offline cache, so the two never wait on one cache's lock."""

import os
from pathlib import Path

import pytest

from taichi_cloth.runtime import start_taichi


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
