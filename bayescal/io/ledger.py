"""Single output files a user can trust: bayescal never replaces a file it did not write.

A file-valued output (``predict --out table.csv``, a report beside a fit, a simulated table)
lands in a folder of the user's, beside the user's own files.  Each folder where bayescal
writes such files holds a small record, :data:`LEDGER`, listing every file bayescal put there
with its size and SHA-256 (the same record an output folder keeps of its files,
:mod:`bayescal.io.outputs`).  A target may be replaced only when that record lists it and its
content is still what bayescal wrote; anything else (a file of the user's, one bayescal wrote
that was edited since, a symbolic link) is refused before any work, naming the file, unless the
caller allows it explicitly (:func:`overwrite_allowed`, the command line's ``--force``).

The record is updated in the same step as the file is put in place, under a lock on the folder,
so two runs writing into one folder keep both their entries.  Writes are atomic: the file is
written beside the target and renamed onto it (:func:`bayescal.io.files.atomic_path`).
"""

from __future__ import annotations

import contextlib
import contextvars
import fcntl
import hashlib
import json
import os
import tempfile
from collections.abc import Iterable, Iterator
from pathlib import Path

__all__ = ["LEDGER", "check_output_file", "commit_file", "overwrite_allowed", "refusal"]

#: the record of the single files bayescal wrote into a folder (one per folder, hidden)
LEDGER = ".bayescal-files"
_FORMAT = 1
#: files up to this size are recorded with their SHA-256, larger ones with their size and modification time
_HASHED_BYTES = 64 * 2**20

_FORCE: contextvars.ContextVar[bool] = contextvars.ContextVar("bayescal_overwrite", default=False)


@contextlib.contextmanager
def overwrite_allowed(allowed: bool = True) -> Iterator[None]:
    """Within the block, single files may replace files bayescal did not write (``--force``).

    Output folders are not affected: a folder of the user's is never replaced
    (:func:`bayescal.io.outputs.check_output_dir`).
    """
    token = _FORCE.set(bool(allowed))
    try:
        yield
    finally:
        _FORCE.reset(token)


def _hash(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _entry(path: Path) -> dict:
    st = path.stat()
    if st.st_size <= _HASHED_BYTES:
        return {"size": st.st_size, "sha256": _hash(path)}
    return {"size": st.st_size, "mtime_ns": st.st_mtime_ns}


def _read(directory: Path) -> dict[str, dict]:
    """The folder's record: file name -> entry (empty without one, or when it cannot be read)."""
    try:
        data = json.loads((directory / LEDGER).read_text())
    except (OSError, UnicodeError, ValueError):
        return {}
    files = data.get("files") if isinstance(data, dict) and data.get("format") == _FORMAT else None
    return {str(k): v for k, v in files.items() if isinstance(v, dict)} if isinstance(files, dict) else {}


def _unchanged(path: Path, entry: dict) -> bool:
    st = path.stat()
    if st.st_size != entry.get("size"):
        return False
    if "sha256" in entry:
        return _hash(path) == entry["sha256"]
    return st.st_mtime_ns == entry.get("mtime_ns")


def refusal(target: str | os.PathLike) -> str | None:
    """Why ``target`` may not be written (``None``: it may), ignoring :func:`overwrite_allowed`
    for everything but a file of the user's."""
    target = Path(target)
    if target.is_symlink():
        link = os.readlink(target)
        return (
            f"{target} is a symbolic link (to {link}); bayescal does not write through links, which could "
            "replace a file elsewhere: give the real path"
        )
    if not target.exists():
        parent = target.absolute().parent
        while not parent.exists():
            parent = parent.parent
        if not parent.is_dir() or not os.access(parent, os.W_OK):
            return f"cannot create {target}: {parent} is not a writable folder"
        return None
    if target.is_dir():
        return f"{target} is a folder; expected a file name for this output"
    if not target.is_file():
        return f"{target} is not a regular file (a device, a pipe or a socket); give a file name"
    from bayescal.io.outputs import FORMAT, read_marker

    marker = read_marker(target.parent)
    if marker and marker.get("format") == FORMAT:  # a file of an output folder: its run's list decides
        if target.name in marker.get("files", {}):
            return None
        return f"refusing to overwrite {target}: the run that wrote {target.parent} did not write it (move it first)"
    if _FORCE.get():
        return None
    entry = _read(target.parent).get(target.name)
    if entry is None:
        return f"refusing to overwrite {target}: bayescal did not write it (move it, give another name, or --force)"
    if not _unchanged(target, entry):
        return (
            f"refusing to overwrite {target}: it was changed after bayescal wrote it (move it, give another "
            "name, or --force)"
        )
    return None


def check_output_file(*targets: str | os.PathLike | None, siblings: Iterable[str] = ()) -> None:
    """Refuse, before any work, output files that bayescal may not write (see :func:`refusal`).

    ``siblings``: suffixes of files written beside each target under the same stem (a report's
    ``.json`` and ``.md``), checked as well.  Raises :class:`~bayescal.errors.OutputError`.
    """
    from bayescal.errors import OutputError

    for target in targets:
        if target is None:
            continue
        target = Path(target)
        for path in (target, *(target.with_suffix(s) for s in siblings)):
            why = refusal(path)
            if why is not None:
                raise OutputError(why)


@contextlib.contextmanager
def _locked(directory: Path) -> Iterator[None]:
    """An exclusive lock on ``directory`` (held while its record is read, changed and written)."""
    fd = os.open(directory, os.O_RDONLY)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)  # closing releases the lock


def commit_file(tmp: Path, target: Path) -> None:
    """Rename the finished ``tmp`` onto ``target`` and enter it in the folder's record, in one locked step;
    the target is checked again first (a file of the user's may have arrived while the run worked)."""
    from bayescal.errors import OutputError
    from bayescal.io.outputs import interrupts_held

    directory = target.parent
    entry = _entry(tmp)
    with _locked(directory), interrupts_held():
        why = refusal(target)
        if why is not None:
            raise OutputError(why)
        files = _read(directory)
        files[target.name] = entry
        fd, record = tempfile.mkstemp(prefix=f"{LEDGER}.", suffix=".tmp", dir=directory)
        try:
            with os.fdopen(fd, "w") as f:
                f.write(json.dumps({"format": _FORMAT, "files": files}, indent=1, sort_keys=True) + "\n")
            os.replace(tmp, target)
            os.replace(record, directory / LEDGER)
        finally:
            if os.path.exists(record):
                os.unlink(record)
