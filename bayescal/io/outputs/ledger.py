"""Single output files a user can trust: bayescal never replaces a file it did not write.

A file-valued output (``predict --out table.csv``, a report beside a fit, a simulated table)
lands in a folder of the user's, beside the user's own files.  Each folder where bayescal
writes such files holds a small record, :data:`LEDGER`, listing every file bayescal put there
with its size and SHA-256, each entry sealed (:mod:`.seal`).  A target may be replaced only when
that record lists it with this account's seal and its content is still what bayescal wrote;
anything else (a file of the user's, one bayescal wrote that was edited since, an entry written
by hand, a symbolic link) is refused before any work, naming the file, unless the caller allows
it explicitly (:func:`~.claims.overwrite_allowed`, the command line's ``--force``).  In a bayescal
output folder the folder's own record decides (:func:`~.folders.member_refusal`), and no command
writes over one of its inputs (:func:`~.claims.reading`), with ``--force`` or without.

The record is updated in the same step as the file is put in place, under a lock on the folder,
so two runs writing into one folder keep both their entries.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import tempfile
from collections.abc import Iterable, Iterator
from pathlib import Path

from bayescal.io.outputs import claims, interrupts
from bayescal.io.outputs.disk import as_given, public, sha256
from bayescal.io.outputs.folders import FORMAT, member_refusal, read_marker
from bayescal.io.outputs.seal import seal, sealed

__all__ = ["LEDGER", "check_output_file", "commit_file", "refusal"]

#: the record of the single files bayescal wrote into a folder (one per folder, hidden)
LEDGER = ".bayescal-files"
_FORMAT = 1
#: what every entry of a ledger is sealed for (the entries of an output folder are sealed for its run)
_CONTEXT = "files"


def _entry(path: Path, name: str) -> dict:
    return seal(_CONTEXT, name, {"size": path.stat().st_size, "sha256": sha256(path)})


def _read(directory: Path) -> dict[str, dict]:
    """The folder's record: file name -> entry (empty without one, or when it cannot be read)."""
    try:
        data = json.loads((directory / LEDGER).read_text())
    except (OSError, UnicodeError, ValueError):
        return {}
    files = data.get("files") if isinstance(data, dict) and data.get("format") == _FORMAT else None
    return {str(k): v for k, v in files.items() if isinstance(v, dict)} if isinstance(files, dict) else {}


def _ours(path: Path, entry: dict | None) -> str | None:
    """Why the ledger's ``entry`` does not make ``path`` bayescal's own (``None``: it does)."""
    if entry is None:
        return "bayescal did not write it"
    if "sha256" not in entry or not sealed(_CONTEXT, path.name, entry):
        return f"its entry in {path.parent / LEDGER} was not written by bayescal under this account"
    if path.stat().st_size != entry.get("size") or sha256(path) != entry["sha256"]:
        return "it was changed after bayescal wrote it"
    return None


def refusal(target: str | os.PathLike) -> str | None:
    """Why ``target`` may not be written (``None``: it may)."""
    target = Path(target)
    if target.is_symlink():
        link = os.readlink(target)
        return (
            f"{target} is a symbolic link (to {link}); bayescal does not write through links, which could "
            "replace a file elsewhere: give the real path"
        )
    given = claims.input_at(target)
    if given is not None:
        what = "an input" if given == str(target) else f"{given}, an input"
        return f"refusing to write {target}: it is {what} of this command (--force does not apply)"
    if not target.exists():
        parent = target.absolute().parent
        while not parent.exists():
            parent = parent.parent
        if not parent.is_dir() or not os.access(parent, os.W_OK):
            return f"cannot create {target}: {as_given(parent, target)} is not a writable folder"
        return None
    if target.is_dir():
        return f"{target} is a folder; expected a file name for this output"
    if not target.is_file():
        return f"{target} is not a regular file (a device, a pipe or a socket); give a file name"
    marker = read_marker(target.parent)
    if marker and marker.get("format") == FORMAT:  # a file of an output folder: its run's list decides
        return member_refusal(target, marker)
    if claims.forced():
        return None
    why = _ours(target, _read(target.parent).get(target.name))
    if why is not None:
        return f"refusing to overwrite {target}: {why} (move it, give another name, or --force)"
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
    the target is checked again first (a file of the user's may have arrived while the run worked).

    A record that is not a file (a folder, a link) is refused before the file is put in place.
    """
    from bayescal.errors import OutputError

    directory = target.parent
    record_path = directory / LEDGER
    if os.path.lexists(record_path) and (record_path.is_symlink() or not record_path.is_file()):
        raise OutputError(
            f"cannot write {target}: {target.with_name(LEDGER)}, where bayescal records the files it writes "
            "into this folder, is not a file; remove it, or write elsewhere"
        )
    entry = _entry(tmp, target.name)
    public(tmp)
    with _locked(directory), interrupts.interrupts_held():
        why = refusal(target)
        if why is not None:
            raise OutputError(why)
        files = _read(directory)
        files[target.name] = entry
        fd, record = tempfile.mkstemp(prefix=f"{LEDGER}.", suffix=".tmp", dir=directory)
        try:
            with os.fdopen(fd, "w") as f:
                f.write(json.dumps({"format": _FORMAT, "files": files}, indent=1, sort_keys=True) + "\n")
            public(record)
            os.replace(tmp, target)
            os.replace(record, record_path)
        finally:
            if os.path.exists(record):
                os.unlink(record)
