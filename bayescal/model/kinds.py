"""Model kinds: what a spec describes decides how its table is read, fitted, loaded and reported.

``calibration`` is the camera's measurement equation (this package's model, the default);
``film`` is the density calibration of seed 003's film camera (:mod:`bayescal.film`).  A spec's
TOML names its kind (``kind = "film"``); :func:`bayescal.load_spec`, :func:`bayescal.fit`,
:meth:`bayescal.Calibration.load`, :func:`bayescal.invert` and the report dispatch on it, so the
command line has no branch per kind.  Each kind other than the camera's is a module with
``spec_from_dict``, ``load_table``, ``fit``, ``load_posterior`` and ``write_report``, found by
name here (imported on first use: the kinds sit above the model in the layers).
"""

from __future__ import annotations

import importlib
from types import ModuleType
from typing import Any

from bayescal.errors import SpecError

__all__ = ["CALIBRATION", "KINDS", "kind_of", "get"]

#: the camera model's kind (this package), the default
CALIBRATION = "calibration"
#: the other kinds: name -> the module with their entry points
KINDS: dict[str, str] = {"film": "bayescal.film.kind"}


def kind_of(obj: Any) -> str:
    """The kind of a spec, a fit or a calibration (``calibration`` unless it says otherwise)."""
    return getattr(obj, "kind", CALIBRATION)


def get(kind: str) -> ModuleType:
    """The entry points of a kind other than ``calibration``."""
    if kind not in KINDS:
        raise SpecError(f"unknown model kind '{kind}'; expected one of {[CALIBRATION, *KINDS]}")
    return importlib.import_module(KINDS[kind])


def load_table(spec: Any, path):
    """The measurement table ``spec``'s kind reads from ``path`` (a camera's: :func:`bayescal.load_table`)."""
    if kind_of(spec) == CALIBRATION:
        from bayescal.io.table import load_table as load

        return load(path)
    return get(kind_of(spec)).load_table(path)
