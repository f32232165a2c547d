"""taichi_cloth: a Taichi mass-spring cloth simulator for garments on moving bodies.

Pipeline (docs/architecture.md): ``config`` (scene file → Scene) → ``cloth`` (garment) and
``body`` (dancer) → ``effects`` and ``physics`` (model, control, forces, integrators, simulation)
→ ``render`` and ``output`` (frames, meshes, video, stats) ← ``studies`` (compare, bench) ←
``cli``."""

import os

# Taichi prints a banner on import; our commands print their own summary instead.
os.environ.setdefault("ENABLE_TAICHI_HEADER_PRINT", "false")
os.environ.setdefault("TI_LOG_LEVEL", "warn")
