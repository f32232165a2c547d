"""What a run leaves on disk, always whole: files (``files.py``), meshes (``meshes.py``), videos
(``video.py``), checkpoints (``checkpoint.py``), progress on the console (``progress.py``), and
the run of a scene with all of them (``run.py``)."""
