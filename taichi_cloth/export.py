"""Writing outputs whole or not at all: every file goes to a temporary name beside its target
and is renamed into place (``os.replace`` is atomic on one file system)."""

import json
import os
import tempfile
from contextlib import contextmanager
from pathlib import Path


@contextmanager
def atomic_path(target: Path, suffix: str = ""):
    """Yield a temporary path in ``target``'s folder; rename it to ``target`` on success,
    delete it on failure. ``suffix`` keeps the extension that writers infer formats from."""
    target = Path(target)
    target.parent.mkdir(parents=True, exist_ok=True)
    handle, temporary = tempfile.mkstemp(prefix=f".{target.name}.", suffix=suffix or target.suffix,
                                         dir=target.parent)
    os.close(handle)
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
