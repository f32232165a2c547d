"""The garment in NumPy, before any Taichi field: shapes, UVs, triangles, spring families,
masses and pins (``garment.py``), and their connectivity and gather lists (``topology.py``)."""
