"""What a run will cost, estimated before the work: memory before anything is allocated, and
time once the step is chosen (before the first substep). A run past the machine's memory or past
a time bound stops with exit code 2, the estimate, and the flag that allows it.

Memory: a measured base (the Python process, Taichi, the runtime: about 170 MB) plus a measured
cost per particle (about 4 kB in float32 on the implicit integrator with its solver fields,
``docs/performance.md``), both with 50 % headroom, doubled per particle in float64. Time: the
particle-substeps of the run (settling included) at ``FASTEST_RATE``, ten times what the real
scenes reach on the CPU (≤ 5e6 particle-substeps/s measured; only the gravity-only reference
sheet runs faster), so the estimate is a lower bound: a run refused would take at least that
long.
"""

import math
import os
from dataclasses import dataclass

from taichi_cloth.cloth.mesh_garment import mesh_path
from taichi_cloth.cloth.obj_mesh import count_vertices
from taichi_cloth.errors import InputError

BASE_BYTES = 2.5e8  # B
PARTICLE_BYTES = {"f32": 6e3, "f64": 12e3}  # B per particle
FASTEST_RATE = 5e7  # particle-substeps per second: 10× the real scenes' best (docs/performance.md)
MEMORY_SHARE = 0.8  # of the memory available when the run starts


@dataclass(frozen=True)
class RunLimits:
    """max_hours: the longest estimated run that starts without asking [h]; max_memory_gb: the
    most memory a run may need [GB] (None: ``MEMORY_SHARE`` of what is available)."""

    max_hours: float = 2.0
    max_memory_gb: float | None = None


def available_memory() -> float:
    """Bytes of memory available now (MemAvailable, else all physical memory)."""
    try:
        with open("/proc/meminfo") as meminfo:
            for line in meminfo:
                if line.startswith("MemAvailable:"):
                    return float(line.split()[1]) * 1024
    except OSError:
        pass
    return float(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))


def check_memory(scene, limits: RunLimits) -> None:
    """Before allocation: InputError when the cloth needs more memory than allowed."""
    if scene.cloth.shape == "mesh":
        particles = count_vertices(mesh_path(scene.cloth, scene.path))
        what_cloth = f"cloth.mesh {scene.cloth.mesh}"
    else:
        columns, rows = scene.cloth.resolution
        particles = columns * rows
        what_cloth = f"cloth.resolution [{columns}, {rows}]"
    need = BASE_BYTES + particles * PARTICLE_BYTES[scene.simulation.precision]
    if limits.max_memory_gb is not None:
        allowed, what = limits.max_memory_gb * 1e9, f"--max-memory {limits.max_memory_gb:g} GB"
    else:
        allowed = MEMORY_SHARE * available_memory()
        what = f"{MEMORY_SHARE:.0%} of this machine's available memory"
    if need > allowed:
        raise InputError(f"{what_cloth}: {particles:,} particles need "
                         f"about {need / 1e9:.1f} GB, more than {allowed / 1e9:.1f} GB ({what}); "
                         f"lower it, or pass --max-memory {math.ceil(need / 1e9)} to run it")


def check_time(simulation, frame_count: int, limits: RunLimits) -> None:
    """With the step chosen: InputError when the run would take longer than allowed."""
    step = simulation.time_step
    settle = simulation.scene.simulation.settle
    substeps = frame_count * step.substeps_per_frame + math.ceil(settle / step.dt)
    seconds = substeps * simulation.model.particle_count / FASTEST_RATE
    if seconds > limits.max_hours * 3600:
        longer = "raise simulation.dt or set it to \"auto\""
        if step.requested == "auto" and simulation.scene.simulation.integrator == "implicit":
            longer = "give simulation.dt a longer step"
        elif step.requested == "auto":  # an explicit integrator's: the longest stable step
            longer = "use integrator = \"implicit\" (\"auto\" took the longest stable step)"
        raise InputError(f"simulation.dt: {substeps:,} substeps of {step.dt:.3g} s × "
                         f"{simulation.model.particle_count:,} particles would take at least "
                         f"{seconds / 3600:.1f} h (--max-hours {limits.max_hours:g}); {longer}, "
                         f"ask for fewer --frames, or pass --max-hours "
                         f"{math.ceil(seconds / 3600)} to run it")
