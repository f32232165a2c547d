"""taichi_cloth: a Taichi mass-spring cloth simulator for garments on moving bodies."""

import os

# Taichi prints a banner on import; our commands print their own summary instead.
os.environ.setdefault("ENABLE_TAICHI_HEADER_PRINT", "false")
os.environ.setdefault("TI_LOG_LEVEL", "warn")
