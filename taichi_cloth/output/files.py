"""Writing outputs whole or not at all: every file goes to a temporary name beside its target
and is renamed into place (``os.replace`` is atomic on one file system), so an interrupted run
leaves only whole files. JSON documents, PNG frames, copies; videos (``output.video``) and meshes
(``output.meshes``) write through ``atomic_path`` too."""

import csv
import errno
import io
import json
import os
import shutil
import tempfile
from contextlib import contextmanager
from pathlib import Path

import imageio.v3 as iio
import numpy as np


@contextmanager
def atomic_path(target: Path, suffix: str = ""):
    """Yield a temporary path in ``target``'s folder; rename it to ``target`` on success,
    delete it on failure. ``suffix`` keeps the extension that writers infer formats from."""
    target = Path(target)
    target.parent.mkdir(parents=True, exist_ok=True)
    handle, temporary = tempfile.mkstemp(prefix=f".{target.name}.", suffix=suffix or target.suffix,
                                         dir=target.parent)
    os.close(handle)
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(temporary, 0o666 & ~umask)  # mkstemp's 0600 → what open() would have made
    try:
        yield Path(temporary)
        os.replace(temporary, target)
    except BaseException:
        Path(temporary).unlink(missing_ok=True)
        raise


def write_json(target: Path, document: dict) -> None:
    """``document`` as indented JSON, atomically. Non-finite numbers are refused, so no NaN is
    ever written."""
    text = json.dumps(document, indent=1, allow_nan=False)
    with atomic_path(target) as temporary:
        temporary.write_text(text + "\n", encoding="utf-8")


def read_png(path: Path) -> np.ndarray:
    """An (H, W, 3) uint8 frame written by ``write_png``."""
    return iio.imread(path)[..., :3]


def write_png(target: Path, image: np.ndarray) -> None:
    """An (H, W, 3) uint8 image as a PNG, atomically."""
    with atomic_path(target, ".png") as temporary:
        iio.imwrite(temporary, image)


def write_csv(target: Path, rows: list[dict], columns) -> None:
    """``rows`` under ``columns`` as CSV, blanks for missing or None values, atomically."""
    text = io.StringIO()
    writer = csv.DictWriter(text, columns, restval="", lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow({key: ("" if value is None else value) for key, value in row.items()})
    with atomic_path(target) as temporary:
        temporary.write_text(text.getvalue(), encoding="utf-8")


def copy_file(source: Path, target: Path) -> None:
    """A byte-for-byte copy of ``source``, atomically."""
    with atomic_path(target) as temporary:
        shutil.copyfile(source, temporary)


# errno values that mean the path given is wrong (exit 2); others (a full disk, I/O) exit 1
PATH_ERRORS = {errno.ENOENT, errno.ENOTDIR, errno.EISDIR, errno.ENAMETOOLONG, errno.ELOOP,
               errno.EACCES, errno.EPERM, errno.EEXIST, errno.EROFS}


def file_system_message(error: OSError) -> str:
    """``path: reason`` of a file-system error, on one line."""
    where = error.filename if error.filename is not None else ""
    reason = error.strerror or str(error)
    text = f"{where}: {reason}" if where else reason
    if error.errno == errno.ENOSPC:
        text += " (the disk is full: the frames written so far are whole)"
    return " ".join(text.split())

