"""Output folders a user can trust with a campaign's only copy of its results.

Every folder bayescal writes holds a marker file, :data:`MARKER`, that names the run that
wrote it (a run id, the kind of output, the bayescal version, the format) and lists every
file of the run with its size and, for files up to :data:`HASHED_BYTES`, its SHA-256, each
entry sealed (:mod:`.seal`).  The files the run wrote are the folder's *members*; a file added
later (a report, a prediction table, an inversion's tables) is listed as an *addition*, with the
product that added it.

Writing.  A run stages its files in a hidden folder beside the output and puts it in place
in one rename (:func:`staged_directory`).  A folder is replaced only when its marker says
bayescal wrote it, of the same kind, every entry carries this account's seal, every file in it
is listed and unchanged, and it holds none of the command's inputs; any other non-empty folder
is refused before any work (:func:`check_output_dir`), so bayescal never deletes a file it did
not write.  A file added to a finished output is written atomically and entered in the list in
the same step (:func:`record_file`); it never replaces a member (:func:`member_refusal`).

Interrupts.  The swap of the old folder for the new one, and each addition to the list, run
with Ctrl-C held back (:func:`~.interrupts.interrupts_held`).

Reading.  :func:`verify_output` checks a folder before a reader uses it: the marker, the
format, the kind, and that each listed file is the one the run wrote.  Reading needs no seal.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import tempfile
import uuid
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

from bayescal.io.outputs import claims, interrupts
from bayescal.io.outputs.disk import as_given, public, sha256, write_errors
from bayescal.io.outputs.seal import seal, sealed

__all__ = [
    "MARKER",
    "FORMAT",
    "HASHED_BYTES",
    "RunInfo",
    "Stage",
    "check_output_dir",
    "staged_directory",
    "scratch_directory",
    "record_file",
    "member_refusal",
    "verify_output",
    "read_marker",
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
    "survey": "a survey's inverted frames (`bayescal invert` of several images)",
    "characterization": "an EMVA 1288 characterisation (`bayescal characterize`)",
    "design": "a campaign design (`bayescal design`)",
    "output": "a bayescal output",
}


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

    def members(self) -> list[str]:
        """The files the run itself wrote (not those added to its folder later)."""
        return [name for name, entry in self.files.items() if "added" not in entry]


# ----------------------------------------------------------------------------- the marker
def _entry(path: Path, run_id: str, rel: str, added: str | None = None) -> dict:
    size = path.stat().st_size
    entry: dict = {"size": size}
    if "/" not in rel and size <= HASHED_BYTES:
        entry["sha256"] = sha256(path)
    if added is not None:
        entry["added"] = added
    return seal(run_id, rel, entry)


def _listing(root: Path, run_id: str) -> dict[str, dict]:
    """Every file under ``root`` but the marker, by its POSIX path relative to ``root``, sealed."""
    files = {}
    for path in sorted(root.rglob("*")):
        if path.is_file() and path.name != MARKER:
            rel = path.relative_to(root).as_posix()
            files[rel] = _entry(path, run_id, rel)
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
    public(tmp)
    os.replace(tmp, directory / MARKER)


def _info(directory: Path, marker: dict) -> RunInfo:
    files = marker.get("files", {})
    return RunInfo(
        directory,
        str(marker.get("kind", "output")),
        str(marker.get("run_id", "")),
        str(marker.get("bayescal_version", "?")),
        {str(k): v for k, v in files.items() if isinstance(v, dict)} if isinstance(files, dict) else {},
    )


def _current(marker: dict | None) -> bool:
    return bool(marker) and marker.get("format") == FORMAT  # type: ignore[union-attr]


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
    try:
        with interrupts.staging(scratch):
            yield scratch
    finally:
        shutil.rmtree(scratch, ignore_errors=True)


_NOT_SEALED = (
    "its record carries no seal of this account's (written by hand, by another account or machine, or by an "
    "earlier bayescal), so bayescal cannot tell that it wrote these files; move or delete the folder yourself, "
    "or give another --out"
)


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
    if not _current(marker):
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
    if not all(sealed(info.run_id, rel, entry) for rel, entry in listed.items()):
        return _NOT_SEALED
    changed = [rel for rel, p in present.items() if _differs(p, listed[rel])]
    if changed:
        return f"files of run {info.run_id[:8]} were changed after it wrote them ({_few(changed)}); move them first"
    return None


def _differs(path: Path, entry: dict) -> bool:
    if path.stat().st_size != entry.get("size"):
        return True
    return "sha256" in entry and sha256(path) != entry["sha256"]


def _few(names: list[str]) -> str:
    return ", ".join(names[:5]) + (f" and {len(names) - 5} more" if len(names) > 5 else "")


def check_output_dir(out_dir: str | os.PathLike, kind: str) -> Path:
    """Refuse an output folder before any work is done, unless bayescal may replace it.

    ``out_dir`` may be missing, an empty folder, or a folder that an earlier run of
    the same ``kind`` wrote and nobody changed since (see the module docstring); it may
    not be, or hold, an input of the command (:func:`~.claims.reading`).  Anything else
    raises :class:`~bayescal.errors.OutputError`, which names what stands in the way.
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
    given = claims.input_inside(out_dir)
    if given is not None:
        raise OutputError(
            f"refusing to replace {out_dir}: it holds {given}, an input of this command; give another --out"
        )
    if out_dir.is_dir():
        why = _foreign(out_dir, read_marker(out_dir), kind)
        if why is not None:
            raise OutputError(f"refusing to replace {out_dir}: {why}")
    parent = out_dir.absolute().parent
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir() or not os.access(parent, os.W_OK):
        raise OutputError(f"cannot create {out_dir}: {as_given(parent, out_dir)} is not a writable folder")
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
    from bayescal._version import __version__, commit

    out_dir = check_output_dir(out_dir, kind)
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    staged = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.staging.", dir=out_dir.parent))
    run_id = uuid.uuid4().hex
    old = None
    try:
        with interrupts.staging(staged):
            with write_errors(out_dir):
                yield Stage(staged, run_id)
            interrupts.checkpoint("staged")
            marker = {
                "format": FORMAT,
                "kind": kind,
                "run_id": run_id,
                "bayescal_version": __version__,
                "bayescal_commit": commit(),  # the checkout's commit; None from a wheel
                "files": _listing(staged, run_id),
            }
            with write_errors(out_dir):
                _write_marker(staged, marker)
            public(staged, folder=True)
            with interrupts.interrupts_held():
                check_output_dir(out_dir, kind)  # nothing of the user's arrived while the run worked
                if out_dir.exists():
                    old = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.old.", dir=out_dir.parent))
                    interrupts._STAGING.add(old)
                    os.replace(out_dir, old / "d")
                interrupts.checkpoint("swap")
                os.replace(staged, out_dir)
                interrupts.commit(out_dir)
            interrupts.checkpoint("committed")
    finally:
        if staged.exists():
            shutil.rmtree(staged, ignore_errors=True)
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
            interrupts._STAGING.discard(old)
    interrupts.checkpoint("cleaned")


def member_refusal(target: Path, marker: dict) -> str | None:
    """Why a single file may not be written at ``target`` in the output folder whose ``marker`` is given
    (``None``: it may).

    - a member of the run (``posterior.nc``, ``summary.json``, ...): never, ``--force`` or not, since
      readers check the folder whole and a replaced member makes it unreadable;
    - a file the run's list does not hold: when it exists, it is the user's;
    - an addition (a report, a table): only by the same product, with its seal, unchanged since
      (``--force``: changed or unsealed too).
    """
    info = _info(target.parent, marker)
    entry = info.files.get(target.name)
    where = f"{target.parent} ({info.describe()})"
    if entry is None:
        if os.path.lexists(target):
            return f"refusing to overwrite {target}: the run that wrote {where} did not write it (move it first)"
        return None
    added = entry.get("added")
    if added is None:
        return (
            f"refusing to overwrite {target}: it is part of {where}, which readers check whole; give a path "
            "outside that folder (--force does not apply: replacing it would break the output)"
        )
    now = claims.product()
    if added != now:
        return (
            f"refusing to overwrite {target}: it is the {added} output added to {where}, and this command writes "
            f"a {now} output; give another name"
        )
    if claims.forced():
        return None
    if not sealed(info.run_id, target.name, entry):
        return f"refusing to overwrite {target}: its entry in {where}'s record carries no seal of this account's " + (
            "(move it, give another name, or --force)"
        )
    if target.is_file() and _differs(target, entry):
        return (
            f"refusing to overwrite {target}: it was changed after bayescal wrote it (move it, give another name, "
            "or --force)"
        )
    return None


def record_file(tmp: Path, target: Path) -> bool:
    """Move the finished file ``tmp`` onto ``target``, entering it in the run's list as an addition of the
    current product (:func:`~.claims.writing_as`) when ``target`` lies in a bayescal output folder;
    returns whether it did.

    A ``target`` that :func:`member_refusal` refuses is refused (:class:`~bayescal.errors.OutputError`): the
    file there stays.  The move and the new list are made with interrupts held back, so the folder is
    never left half-listed.
    """
    from bayescal.errors import OutputError

    directory = target.parent
    marker = read_marker(directory)
    if not _current(marker):
        return False
    assert marker is not None
    why = member_refusal(target, marker)
    if why is not None:
        raise OutputError(why)
    info = _info(directory, marker)
    files = dict(info.files)
    files[target.name] = _entry(tmp, info.run_id, target.name, added=claims.product())
    public(tmp)
    with interrupts.interrupts_held():
        os.replace(tmp, target)
        _write_marker(directory, {**marker, "files": files})
        interrupts.commit(directory)
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
    write, or a member (or a needed addition) missing, truncated or replaced since the run.
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
    if not _current(marker):
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
    checked = set(info.members()) | set(needs)  # an addition edited later (a report) leaves the run whole
    for rel, entry in info.files.items():
        if rel not in checked:
            continue
        file = directory / rel
        if not file.is_file():
            raise PosteriorError(f"{file} is missing from {directory} ({info.describe()}): re-run")
        size = file.stat().st_size
        if size != entry.get("size"):
            raise PosteriorError(
                f"{file} is {size} bytes where {info.describe()} wrote {entry.get('size')}: it was truncated or "
                "replaced after the run, so the folder mixes runs; re-run"
            )
        if "sha256" in entry and sha256(file) != entry["sha256"]:
            raise PosteriorError(
                f"{file} differs from what {info.describe()} wrote: it was replaced or edited after the run, "
                "so the folder mixes runs; re-run"
            )
    return info
