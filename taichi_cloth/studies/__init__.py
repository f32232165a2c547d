"""Measurements across many runs: the integrator comparison (``compare*.py``) and the throughput
benchmark (``bench*.py``, ``numpy_cloth.py``, ``timing.py``)."""
