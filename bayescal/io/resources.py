"""The shipped model specs, example designs and data (the repository's ``models/``), by file or by name.

Every command that reads a spec or a design also takes a shipped example's name, from any
folder: ``--model seed000`` is ``models/seed000_bayer.toml``, ``--design seed000`` is
``models/seed000_design.toml`` (:func:`example_path`; ``bayescal examples`` lists them and
copies them out).
"""

from __future__ import annotations

import functools
import os
from dataclasses import dataclass
from importlib.resources import files
from pathlib import Path

__all__ = ["models_dir", "Example", "examples", "example_path", "did_you_mean"]


def models_dir() -> Path:
    """The shipped ``models/`` directory.

    In a source checkout or an editable install it is the repository's top-level
    ``models/``; a built wheel carries the same files as the ``bayescal.models``
    package (``pyproject.toml`` maps one onto the other).
    """
    source = Path(__file__).resolve().parents[2] / "models"  # bayescal/io/resources.py -> the repository root
    if (source / "seed000_design.toml").is_file():
        return source
    # ``bayescal.models`` has no ``__init__``: asked for directly, importlib gives a namespace path whose str is
    # not a file path; as a folder of the ``bayescal`` package it is a plain one
    return Path(str(files("bayescal") / "models"))


@dataclass(frozen=True)
class Example:
    """One shipped file: its name (the file's stem), what it is, what its first comment line says."""

    name: str
    kind: str  # "spec", "design", "fleet design", "data" or "image"
    path: Path
    about: str


#: the shipped raw frames' formats
IMAGES = (".tif", ".fits")
#: the descriptor of an EMVA 1288 image set shipped as a folder (its images beside it)
DESCRIPTOR = "EMVA1288_Data.txt"


def _kind(path: Path) -> str:
    if path.suffix in IMAGES:
        return "image"
    if path.suffix != ".toml":
        return "data"
    if path.stem.endswith("_design"):
        return "fleet design" if path.stem.startswith("fleet") else "design"
    return "spec"


def _about(path: Path) -> str:
    """What a shipped file is: its opening comment's first sentence (comment lines joined), or what its
    kind says."""
    if path.suffix in IMAGES:
        form = "FITS" if path.suffix == ".fits" else "TIFF"
        return f"a raw RGGB frame of the seed 000 camera at 1/250 s, gain 1 ({form}; models/make_frames.py)"
    if path.suffix not in (".toml", ".txt"):
        return "the shipped EMVA 1288 reference table" if path.name.startswith("emva") else "example measurements"
    comment: list[str] = []
    for line in path.read_text(encoding="utf-8").splitlines():
        if not line.startswith("#"):
            if comment:
                break
            continue
        comment.append(line.lstrip("# ").strip())
        if comment[-1].endswith((".", ":", ";", ")")):  # the first sentence ends with its line
            break
    return " ".join(comment).rstrip(".:;") or "an EMVA 1288 image set"


@functools.cache
def examples() -> tuple[Example, ...]:
    """Every shipped spec, design and data file, by name (read once per process); an EMVA 1288 image set
    shipped as a folder goes by the folder's name, its path the descriptor inside it."""
    files = sorted(models_dir().iterdir())
    shipped = (".toml", ".csv", *IMAGES)
    out = [Example(p.stem, _kind(p), p, _about(p)) for p in files if p.is_file() and p.suffix in shipped]
    out += [
        Example(d.name, "data", d / DESCRIPTOR, _about(d / DESCRIPTOR)) for d in files if (d / DESCRIPTOR).is_file()
    ]
    return tuple(sorted(out, key=lambda e: e.name))


def example_path(name: str | os.PathLike, kind: str) -> Path:
    """``name`` as a path when it is one; else the shipped example it names, for ``kind`` ``"spec"`` or
    ``"design"`` or ``"data"``: its file's stem (``seed000_bayer``) or the stem's first part (``seed000``,
    ``fleet``, ``8bit``, ``emva``).  A name that is neither stays as given (the reader then says no such file)."""
    path = Path(name)
    if path.exists() or path.suffix or len(path.parts) > 1:
        return path
    wanted = {"spec": ("spec",), "design": ("design", "fleet design"), "data": ("data",)}[kind]
    mine = [e for e in examples() if e.kind in wanted]
    for e in mine:
        if e.name == str(name):
            return e.path
    prefix = [e for e in mine if e.name.split("_")[0] == str(name)]
    return prefix[0].path if len(prefix) == 1 else path


def did_you_mean(path: str | os.PathLike) -> str:
    """For a path that does not exist: ``"; did you mean 'seed000'?"`` naming the closest shipped example (for a
    bare name) or the closest file beside it, or ``""`` when nothing is close (difflib's ratio 0.6 or more)."""
    import difflib

    path = Path(path)
    shipped: set[str] = set()
    if len(path.parts) == 1 and not path.suffix:
        names = [e.name for e in examples()]
        shipped = set(names) | {n.split("_")[0] for n in names}
    try:
        beside = [p.name for p in path.parent.iterdir()]
    except OSError:
        beside = []

    def rank(c: str) -> tuple:  # the closest; among equals, what the name begins, then the first by name
        return -difflib.SequenceMatcher(None, path.name, c).ratio(), not c.startswith(path.name), c

    found = difflib.get_close_matches(path.name, sorted(shipped) + beside, n=5, cutoff=0.6)
    close = sorted((c for c in found if c != path.name), key=rank)  # never the very name that was not found
    if not close:
        return ""
    where = " (a shipped example; `bayescal examples` lists them)" if close[0] in shipped else ""
    return f"; did you mean '{close[0]}'{where}?"
