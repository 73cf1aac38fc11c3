"""Where the shipped model specs and example designs are (the repository's ``models/``)."""

from __future__ import annotations

from importlib.resources import files
from pathlib import Path

__all__ = ["models_dir"]


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
