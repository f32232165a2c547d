"""Headless GGUI frames: the cloth, body and ground surfaces (``surfaces.py``), the print on the
cloth (``texture.py``) and the renderer (``renderer.py``)."""
