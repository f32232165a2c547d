"""Measurements across many runs: the integrator comparison (``compare*.py``), the throughput
benchmark (``bench*.py``, ``numpy_cloth.py``, ``timing.py``) and the virtual textile lab
(``fabric_lab.py``, ``cantilever.py``, ``drape.py``, ``fabric_plots.py``)."""
