"""The simulation proper: the constant model and its states (``model.py``), the prescribed motion
(``control.py``, written by the body ``rig.py``), the one force evaluation (``forces.py``, with the
SIMD layout of grid cloth in ``packed_grid.py``), the integrators, the time step (``timestep.py``),
the per-frame metrics (``metrics.py``), and ``simulation.py``, which builds and runs them."""
