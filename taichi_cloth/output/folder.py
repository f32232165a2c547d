"""An output folder a run owns, never shares: a lock file while the run writes, and a manifest
of the files it wrote, so that a later run removes only files of an earlier run's manifest that
it does not write again, and never anything else a user keeps in the folder.

What a run wrote is what changed under it: every output is written to a temporary name and
renamed into place (``files.atomic_path``), which gives the target a new inode. The folder's
files are listed (path → inode, size, modification time) when the run starts; at its end every
file that is new or changed is the run's. The lock is created with O_EXCL and holds the owner's
PID: a second run into a locked folder stops with exit code 2, and a lock whose PID is no longer
running (a killed run) is taken over.
"""

import json
import os
from pathlib import Path

from taichi_cloth.errors import InputError
from taichi_cloth.output.files import write_json

LOCK_NAME = ".taichi_cloth.lock"
MANIFEST_NAME = "manifest.json"


def file_states(directory: Path) -> dict:
    """Relative path → (inode, size, mtime [ns]) of every file under ``directory``."""
    states = {}
    if not directory.is_dir():
        return states
    for root, _, names in os.walk(directory):
        for name in names:
            path = Path(root) / name
            try:
                info = path.stat(follow_symlinks=False)
            except OSError:
                continue
            states[path.relative_to(directory).as_posix()] = (info.st_ino, info.st_size,
                                                              info.st_mtime_ns)
    return states


def process_running(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


class OwnedFolder:
    """``with OwnedFolder(directory, flag) as folder:`` locks ``directory`` for the run;
    ``folder.finish()`` (at the end, or after a stop) removes what an earlier run wrote and this
    one did not write again, and writes the manifest of this run's files."""

    def __init__(self, directory: Path, flag: str = "--out"):
        self.directory = Path(directory)
        self.flag = flag
        self.lock = self.directory / LOCK_NAME
        self.before = {}
        self.created = []  # folders this run made, innermost first

    def __enter__(self) -> "OwnedFolder":
        missing = self.directory
        while not missing.exists():
            self.created.append(missing)
            missing = missing.parent
        self.directory.mkdir(parents=True, exist_ok=True)
        while True:
            try:
                handle = os.open(self.lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
            except FileExistsError:
                owner = self._lock_owner()
                if owner is not None and owner != os.getpid() and process_running(owner):
                    raise InputError(f"{self.flag} {self.directory}: another run (pid {owner}) "
                                     f"is writing into this folder; wait for it or choose "
                                     f"another --out") from None
                self.lock.unlink(missing_ok=True)  # stale: its run was killed
                continue
            with os.fdopen(handle, "w") as lock:
                lock.write(f"{os.getpid()}\n")
            break
        self.before = file_states(self.directory)
        return self

    def _lock_owner(self) -> int | None:
        try:
            return int(self.lock.read_text().strip())
        except (OSError, ValueError):
            return None

    def __exit__(self, *exc) -> None:
        """Unlock; a folder this run made and left empty (it stopped before writing) goes."""
        self.lock.unlink(missing_ok=True)
        for folder in self.created:
            try:
                folder.rmdir()
            except OSError:  # not empty: the run wrote there
                break

    def previous_manifest(self) -> set:
        """The files an earlier run listed as its own (none when there is no readable
        manifest: then nothing is removed)."""
        try:
            document = json.loads((self.directory / MANIFEST_NAME).read_text())
            return {str(name) for name in document.get("files", [])}
        except (OSError, ValueError, AttributeError):
            return set()

    def written(self) -> set:
        """The files this run wrote: new or changed since it started (the lock aside)."""
        after = file_states(self.directory)
        return {name for name, state in after.items()
                if name not in (LOCK_NAME, MANIFEST_NAME) and self.before.get(name) != state}

    def finish(self, resumed: bool = False) -> None:
        """Remove the files of the earlier manifest that this run did not write (none when the
        run resumed that one: it continues them), then write the manifest of the files this run
        owns: those it wrote, and a resumed run's earlier ones that still exist."""
        written = self.written()
        earlier = self.previous_manifest()
        if not resumed:
            for name in sorted(earlier - written):
                path = self.directory / name
                if path.is_file() and not path.is_symlink():
                    path.unlink(missing_ok=True)
            earlier = set()
        owned = written | {name for name in earlier if (self.directory / name).is_file()}
        write_json(self.directory / MANIFEST_NAME, {"files": sorted(owned)})
