"""Output folders a user can trust with a campaign's only copy of its results.

Every folder bayescal writes holds a marker file, :data:`MARKER`, that names the run that
wrote it (a run id, the kind of output, the bayescal version, the format) and lists every
file of the run with its size and, for files up to :data:`HASHED_BYTES`, its SHA-256.  The
marker is what ties each file to its run: a file the run did not write, or one whose content
changed since, is found by comparing the folder with the list.

Writing.  A run stages its files in a hidden folder beside the output and puts it in place
in one rename (:func:`staged_directory`).  A folder is replaced only when its marker says
bayescal wrote it, of the same kind, and every file in it is the run's own, unchanged; any
other non-empty folder is refused before any work (:func:`check_output_dir`), so bayescal
never deletes a file it did not write.  A file added to a finished output later (a report)
is written atomically and entered in the list in the same step (:func:`record_file`).

Interrupts.  The swap of the old folder for the new one, and each addition to the list, run
with Ctrl-C held back (:func:`interrupts_held`): the signal is acted on as soon as the step
is over, so an interrupt at any moment leaves the old output or the new one whole, and
:func:`committed` tells the interrupt handler truthfully which.

Reading.  :func:`verify_output` checks a folder before a reader uses it: the marker, the
format, the kind, and that each listed file is the one the run wrote.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import shutil
import signal
import tempfile
import threading
import uuid
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

from bayescal.io.files import write_errors

__all__ = [
    "MARKER",
    "FORMAT",
    "RunInfo",
    "check_output_dir",
    "staged_directory",
    "scratch_directory",
    "record_file",
    "verify_output",
    "read_marker",
    "interrupts_held",
    "committed",
    "discard_staging",
]

#: written into every output folder bayescal makes: the run's id and the list of its files
MARKER = ".bayescal-output"
#: the marker's format; folders of an older format are neither replaced nor read
FORMAT = 2
#: files up to this size are listed with their SHA-256 (larger ones, and files in sub-folders,
#: with their size): hashing a multi-gigabyte store on every read would cost more than it tells
HASHED_BYTES = 64 * 2**20
#: files that identify a folder written by a bayescal version that wrote no marker
_OLD_FILES = ("summary.json", "characterization.json", "radiance.nc", "film_summary.json", "fleet.nc")
#: what each kind of output is called in messages, and the verb that writes it
KIND_NAMES = {
    "fit": "a calibration fit (`bayescal fit`)",
    "fleet": "a fleet fit (`bayescal fleet`)",
    "maps": "per-pixel maps (`bayescal maps`)",
    "radiance": "inverted radiance images (`bayescal invert`)",
    "characterization": "an EMVA 1288 characterisation (`bayescal characterize`)",
    "output": "a bayescal output",
}

#: staging folders of outputs being written in this process (removed on an interrupt)
_STAGING: set[Path] = set()
#: output folders put in place (or added to) by this process, in order
_COMMITTED: list[Path] = []


def _checkpoint(name: str) -> None:
    """A named point in writing an output (tests interrupt the process here)."""


@dataclass(frozen=True)
class RunInfo:
    """What an output folder's marker says about the run that wrote it."""

    path: Path
    kind: str
    run_id: str
    version: str
    files: dict[str, dict]

    def describe(self) -> str:
        """The run in words, for messages."""
        return f"{KIND_NAMES.get(self.kind, self.kind)}, run {self.run_id[:8]}"


# ----------------------------------------------------------------------------- the marker
def _hash(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _entry(path: Path, top_level: bool) -> dict:
    size = path.stat().st_size
    entry: dict = {"size": size}
    if top_level and size <= HASHED_BYTES:
        entry["sha256"] = _hash(path)
    return entry


def _listing(root: Path) -> dict[str, dict]:
    """Every file under ``root`` but the marker, by its POSIX path relative to ``root``."""
    files = {}
    for path in sorted(root.rglob("*")):
        if path.is_file() and path.name != MARKER:
            rel = path.relative_to(root).as_posix()
            files[rel] = _entry(path, "/" not in rel)
    return files


def read_marker(directory: str | os.PathLike) -> dict | None:
    """The marker of ``directory`` as a dict (``None`` without one; ``{}`` if unreadable)."""
    path = Path(directory) / MARKER
    if not path.is_file():
        return None
    try:
        data = json.loads(path.read_text())
    except (OSError, UnicodeError, ValueError):
        return {}
    return data if isinstance(data, dict) else {}


def _write_marker(directory: Path, marker: dict) -> None:
    fd, tmp = tempfile.mkstemp(prefix=f"{MARKER}.", suffix=".tmp", dir=directory)
    with os.fdopen(fd, "w") as f:
        f.write(json.dumps(marker, indent=1, sort_keys=True) + "\n")
    os.chmod(tmp, 0o666 & ~_umask())
    os.replace(tmp, directory / MARKER)


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _info(directory: Path, marker: dict) -> RunInfo:
    return RunInfo(
        directory,
        str(marker.get("kind", "output")),
        str(marker.get("run_id", "")),
        str(marker.get("bayescal_version", "?")),
        dict(marker.get("files", {})),
    )


# ------------------------------------------------------------------------- interrupts
@contextlib.contextmanager
def interrupts_held() -> Iterator[None]:
    """Hold back SIGINT (Ctrl-C) for the block and act on it right after.

    In the main thread the current handler is swapped for one that only notes the
    signal; on leaving, the previous handler is put back and, if a signal came, called
    (or ``KeyboardInterrupt`` raised, for the default handler).  Elsewhere the block
    runs as it is (signals are only delivered to the main thread).
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught: list[int] = []
    previous = signal.signal(signal.SIGINT, lambda signum, frame: caught.append(signum))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
        if caught:
            if callable(previous):
                previous(signal.SIGINT, None)
            elif previous != signal.SIG_IGN:
                raise KeyboardInterrupt


def committed() -> list[Path]:
    """Output folders this process has put in place or added to, in order."""
    return list(_COMMITTED)


def discard_staging() -> None:
    """Remove the staging folders of outputs still being written (an interrupted run leaves none)."""
    for path in list(_STAGING):
        shutil.rmtree(path, ignore_errors=True)
        _STAGING.discard(path)


# --------------------------------------------------------------------------- writing
@contextlib.contextmanager
def scratch_directory(beside: str | os.PathLike, name: str) -> Iterator[Path]:
    """A hidden working folder beside ``beside``, removed afterwards, also when the run is interrupted.

    For intermediate files a run needs but does not keep (an image set rewritten as
    stacks); being beside the output, it is on the same disk, visible to a cluster's
    workers when that disk is shared.
    """
    beside = Path(beside).resolve()
    beside.parent.mkdir(parents=True, exist_ok=True)
    scratch = Path(tempfile.mkdtemp(prefix=f".{beside.name}.{name}-", dir=beside.parent))
    _STAGING.add(scratch)
    try:
        yield scratch
    finally:
        _STAGING.discard(scratch)
        shutil.rmtree(scratch, ignore_errors=True)


def _foreign(directory: Path, marker: dict | None, kind: str) -> str | None:
    """Why ``directory`` may not be replaced by an output of ``kind`` (``None``: it may)."""
    names = sorted(p.name for p in directory.iterdir())
    if not names:
        return None
    if marker is None:
        if set(names) & set(_OLD_FILES):
            return (
                "it looks like an output of an older bayescal, which wrote no record of its files, so bayescal "
                "cannot tell its files from yours; move or delete it yourself, or give another --out"
            )
        return f"it holds files bayescal did not write ({_few(names)}); give a new or empty --out folder"
    if marker.get("format") != FORMAT:
        return (
            f"it was written by bayescal {marker.get('bayescal_version', '?')} in an older output format "
            f"({marker.get('format', 1)}, current {FORMAT}); move or delete it yourself, or give another --out"
        )
    info = _info(directory, marker)
    if info.kind != kind:
        return (
            f"it holds {KIND_NAMES.get(info.kind, info.kind)}, and this run writes "
            f"{KIND_NAMES.get(kind, kind)}; give another --out, or delete the folder yourself"
        )
    listed = info.files
    present = {p.relative_to(directory).as_posix(): p for p in directory.rglob("*") if p.is_file() and p.name != MARKER}
    extra = sorted(set(present) - set(listed))
    if extra:
        return f"it holds files that run {info.run_id[:8]} did not write ({_few(extra)}); move them first"
    changed = [rel for rel, p in present.items() if _differs(p, listed[rel])]
    if changed:
        return f"files of run {info.run_id[:8]} were changed after it wrote them ({_few(changed)}); move them first"
    return None


def _differs(path: Path, entry: dict) -> bool:
    if path.stat().st_size != entry.get("size"):
        return True
    return "sha256" in entry and _hash(path) != entry["sha256"]


def _few(names: list[str]) -> str:
    return ", ".join(names[:5]) + (f" and {len(names) - 5} more" if len(names) > 5 else "")


def check_output_dir(out_dir: str | os.PathLike, kind: str) -> Path:
    """Refuse an output folder before any work is done, unless bayescal may replace it.

    ``out_dir`` may be missing, an empty folder, or a folder that an earlier run of
    the same ``kind`` wrote and nobody changed since (see the module docstring).
    Anything else raises :class:`~bayescal.errors.OutputError`, which names the files
    that stand in the way.
    """
    from bayescal.errors import OutputError

    out_dir = Path(out_dir)
    if out_dir.is_symlink():
        raise OutputError(
            f"{out_dir} is a symbolic link (to {os.readlink(out_dir)}); bayescal does not write outputs through "
            "links, which could replace a folder elsewhere: give the real path"
        )
    if out_dir.exists() and not out_dir.is_dir():
        raise OutputError(f"{out_dir} is a file; expected a folder for the outputs (give another --out)")
    if out_dir.is_dir():
        why = _foreign(out_dir, read_marker(out_dir), kind)
        if why is not None:
            raise OutputError(f"refusing to replace {out_dir}: {why}")
    parent = out_dir.absolute().parent
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir() or not os.access(parent, os.W_OK):
        raise OutputError(f"cannot create {out_dir}: {parent} is not a writable folder")
    return out_dir


@dataclass(frozen=True)
class Stage:
    """``stage(name) -> Path``: where a staged run writes ``name`` (its folders made); ``root`` is the
    staged folder itself (for stores such as zarr), ``run_id`` the run's id."""

    root: Path
    run_id: str

    def __call__(self, name: str) -> Path:
        path = self.root / name
        path.parent.mkdir(parents=True, exist_ok=True)
        return path


@contextlib.contextmanager
def staged_directory(out_dir: str | os.PathLike, kind: str) -> Iterator[Stage]:
    """Stage a folder of outputs, then put it in place of ``out_dir`` as a whole, only on success.

    Yields ``stage(name) -> Path``: a path to write ``name`` to (``stage.root`` is the
    staged folder itself, for stores such as zarr; ``stage.run_id`` the run's id).  If
    the block raises, ``out_dir`` is left exactly as it was.  On success the marker
    listing every staged file is written, and the folder replaces ``out_dir`` in one
    step with interrupts held back; an earlier output there goes as a whole (see
    :func:`check_output_dir`, which is checked again just before the swap).
    """
    from bayescal._version import __version__

    out_dir = check_output_dir(out_dir, kind)
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.staging.", dir=out_dir.parent))
    _STAGING.add(staging)
    run_id = uuid.uuid4().hex

    stage = Stage(staging, run_id)
    old = None
    try:
        with write_errors(out_dir):
            yield stage
        _checkpoint("staged")
        marker = {
            "format": FORMAT,
            "kind": kind,
            "run_id": run_id,
            "bayescal_version": __version__,
            "files": _listing(staging),
        }
        with write_errors(out_dir):
            _write_marker(staging, marker)
        os.chmod(staging, 0o777 & ~_umask())
        with interrupts_held():
            check_output_dir(out_dir, kind)  # nothing of the user's arrived while the run worked
            if out_dir.exists():
                old = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.old.", dir=out_dir.parent))
                _STAGING.add(old)
                os.replace(out_dir, old / "d")
            _checkpoint("swap")
            os.replace(staging, out_dir)
            if not any(_inside(out_dir, s) for s in _STAGING):  # a folder inside another run's staging is not yet out
                _COMMITTED.append(out_dir)
        _checkpoint("committed")
    finally:
        _STAGING.discard(staging)
        if staging.exists():
            shutil.rmtree(staging, ignore_errors=True)
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
            _STAGING.discard(old)
    _checkpoint("cleaned")


def _inside(path: Path, folder: Path) -> bool:
    return path.absolute().is_relative_to(folder.absolute())


def record_file(tmp: Path, target: Path) -> bool:
    """Move the finished file ``tmp`` onto ``target``, entering it in the run's list when
    ``target`` lies in a bayescal output folder; returns whether it did.

    A ``target`` that exists in such a folder but is not the run's own is refused
    (:class:`~bayescal.errors.OutputError`): the user's file stays.  The move and the new
    list are made with interrupts held back, so the folder is never left half-listed.
    """
    from bayescal.errors import OutputError

    directory = target.parent
    marker = read_marker(directory)
    if not marker or marker.get("format") != FORMAT:
        return False
    files = dict(marker.get("files", {}))
    if target.exists() and target.name not in files:
        raise OutputError(f"refusing to overwrite {target}: bayescal did not write it (move it first)")
    files[target.name] = _entry(tmp, True)
    os.chmod(tmp, 0o666 & ~_umask())  # a temporary file is private; the output gets the usual permissions
    with interrupts_held():
        os.replace(tmp, target)
        _write_marker(directory, {**marker, "files": files})
        if directory not in _COMMITTED and not any(_inside(directory, s) for s in _STAGING):
            _COMMITTED.append(directory)
    return True


# --------------------------------------------------------------------------- reading
def verify_output(
    path: str | os.PathLike, kinds: Iterable[str], needs: Iterable[str] = (), verb: str = "this command"
) -> RunInfo | None:
    """Check that ``path`` (an output folder, or a file in one) is one whole run of one of ``kinds``.

    Returns the run's :class:`RunInfo`, or ``None`` for a file that lies outside any
    output folder (a lone file cannot mix runs).  Raises
    :class:`~bayescal.errors.PosteriorError` naming the folder and what is wrong: no
    marker, an older format, another kind of output, a file in ``needs`` the run did not
    write, or a listed file missing, truncated or replaced since the run.
    """
    from bayescal.errors import PosteriorError

    path = Path(path)
    directory = path if path.is_dir() else path.parent
    marker = read_marker(directory)
    if marker is None:
        if not path.is_dir():
            return None
        present = sorted(p.name for p in directory.iterdir()) if directory.is_dir() else []
        if set(present) & set(_OLD_FILES):
            raise PosteriorError(
                f"{directory} was written by an older bayescal, which kept no record of which run wrote each "
                f"file; {verb} reads only folders of the current format: re-run the command that made it"
            )
        raise PosteriorError(f"{directory} is not a bayescal output folder (it has no {MARKER} record)")
    if marker.get("format") != FORMAT:
        raise PosteriorError(
            f"{directory} was written by bayescal {marker.get('bayescal_version', '?')} in an older output "
            f"format ({marker.get('format', 1)}, current {FORMAT}); re-run the command that made it"
        )
    info = _info(directory, marker)
    kinds = tuple(kinds)
    if info.kind not in kinds:
        wanted = " or ".join(KIND_NAMES.get(k, k) for k in kinds)
        raise PosteriorError(f"{directory} holds {KIND_NAMES.get(info.kind, info.kind)}; {verb} needs {wanted}")
    needs = list(needs) + ([path.name] if not path.is_dir() else [])
    for name in needs:
        if name not in info.files:
            there = "is there" if (directory / name).exists() else "is missing"
            raise PosteriorError(
                f"{directory / name} was not written by the run that wrote {directory} ({info.describe()}); "
                f"it {there}, so the folder is not one run's output: re-run, or give the folder of the run "
                f"that wrote it"
            )
    for rel, entry in info.files.items():
        file = directory / rel
        if not file.is_file():
            raise PosteriorError(f"{file} is missing from {directory} ({info.describe()}): re-run")
        size = file.stat().st_size
        if size != entry.get("size"):
            raise PosteriorError(
                f"{file} is {size} bytes where {info.describe()} wrote {entry.get('size')}: it was truncated or "
                "replaced after the run, so the folder mixes runs; re-run"
            )
        if "sha256" in entry and _hash(file) != entry["sha256"]:
            raise PosteriorError(
                f"{file} differs from what {info.describe()} wrote: it was replaced or edited after the run, "
                "so the folder mixes runs; re-run"
            )
    return info
