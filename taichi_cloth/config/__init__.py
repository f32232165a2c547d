"""What a run is asked to do: the scene file's sections and their checks (``scene.py``, built on
``settings.py``) and the fabric presets (``materials.py``)."""
