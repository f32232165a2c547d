"""One Taichi runtime for the whole test session (compiling kernels is the slow part), on the CPU
unless --arch says otherwise; GPU-only tests skip cleanly (cf. Genesis tests/conftest.py)."""

import pytest

from taichi_cloth.runtime import start_taichi


def pytest_addoption(parser):
    parser.addoption("--arch", default="cpu", choices=("cpu", "cuda", "vulkan", "gpu"),
                     help="Taichi backend for the test session")


@pytest.fixture(scope="session", autouse=True)
def taichi_runtime(request):
    start_taichi(request.config.getoption("--arch"))
