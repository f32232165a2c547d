"""The machine a measurement ran on, recorded beside every timing (compare, sweep)."""

import os
import platform
import socket
from pathlib import Path

import taichi as ti


def machine_description() -> dict:
    """The CPU model (/proc/cpuinfo), logical cores, the Taichi backend and versions."""
    cpu = platform.processor() or "unknown"
    cpuinfo = Path("/proc/cpuinfo")
    if cpuinfo.exists():
        models = [line.split(":", 1)[1].strip() for line in cpuinfo.read_text().splitlines()
                  if line.startswith("model name")]
        cpu = models[0] if models else cpu
    return {"host": socket.gethostname(), "cpu": cpu, "cores": os.cpu_count(),
            "taichi_arch": ti.lang.impl.current_cfg().arch.name,
            "taichi": ".".join(map(str, ti.__version__)), "python": platform.python_version(),
            "system": platform.platform()}
