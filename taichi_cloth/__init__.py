"""taichi_cloth: a Taichi mass-spring cloth simulator for garments on moving bodies.

Layers, each importing only from those before it (docs/architecture.md): ``errors``;
``settings``, ``runtime``, ``flags``, ``gather``; ``effects`` (one file per effect); ``config``
(scene file → Scene); ``cloth`` (garment) and ``body`` (dancer); ``physics`` (model, control,
forces, integrators, simulation); ``render``; ``output`` (frames, meshes, video, stats);
``studies`` (compare, bench, the textile lab); ``cli``."""

import os

__version__ = "0.4.0"  # pyproject.toml reads it (setuptools dynamic version)

# Taichi prints a banner on import; our commands print their own summary instead.
os.environ.setdefault("ENABLE_TAICHI_HEADER_PRINT", "false")
# Errors only: a missing backend's warnings (no libcuda, falling back) would add lines to our
# one-line error messages. TI_LOG_LEVEL set by the user wins.
os.environ.setdefault("TI_LOG_LEVEL", "error")
