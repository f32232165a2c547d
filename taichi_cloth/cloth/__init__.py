"""The garment in NumPy, before any Taichi field: shapes, UVs, triangles, spring families,
masses, pins and warp directions (``garment.py``), and its connectivity: spring pairs,
triangles, lumped masses, bending stencils (``topology.py``)."""
