"""Model kinds: what a spec describes decides how its table is read, fitted, loaded and reported.

``calibration`` is the camera's measurement equation (this package's model, the default);
``film`` is the density calibration of seed 003's film camera (:mod:`bayescal.film`).  A spec's
TOML names its kind (``kind = "film"``); :func:`bayescal.load_spec`, :func:`bayescal.fit`,
:meth:`bayescal.Calibration.load`, :func:`bayescal.invert` and the report dispatch on it, so the
command line has no branch per kind.  Each kind other than the camera's is a module with
``spec_from_dict``, ``load_table``, ``fit``, ``load_posterior`` and ``write_report``, registered by
its own package through the package metadata (:mod:`bayescal.model.plugins`; the kinds sit above the
model in the layers, so the model names none of them).
"""

from __future__ import annotations

from types import ModuleType
from typing import Any

from bayescal.io.summary import CALIBRATION  # the camera model's kind (this package), a summary's default
from bayescal.model import plugins

__all__ = ["CALIBRATION", "kind_of", "get", "names"]


def names() -> tuple[str, ...]:
    """Every model kind: the camera's, then the registered ones."""
    return (CALIBRATION, *plugins.names(plugins.KIND_GROUP))


def kind_of(obj: Any) -> str:
    """The kind of a spec, a fit or a calibration (``calibration`` unless it says otherwise)."""
    return getattr(obj, "kind", CALIBRATION)


def get(kind: str) -> ModuleType:
    """The entry points of a kind other than ``calibration`` (the module its package registered)."""
    return plugins.load(plugins.KIND_GROUP, kind, "model kind")


def load_table(spec: Any, path):
    """The measurement table ``spec``'s kind reads from ``path`` (a camera's: :func:`bayescal.load_table`)."""
    if kind_of(spec) == CALIBRATION:
        from bayescal.io.table import load_table as load

        return load(path)
    return get(kind_of(spec)).load_table(path)
