"""A fit folder's ``summary.json``: one typed schema that every writer and every reader shares.

Three writers make it (a camera's fit, a film's fit, a camera's calibration exported from a fleet)
and the readers (the report, the film report, ``design --after``) read it through
:attr:`bayescal.io.fit_folder.FitFolder.summary` (:meth:`FitSummary.from_json`), which names the file
and the key when one is missing or of the wrong kind, so a summary that one writer leaves short fails
where it is read, in words, not as a ``KeyError`` in a figure.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

from bayescal.errors import PosteriorError

__all__ = ["CALIBRATION", "FitSummary"]

#: the model kind of a camera's calibration (the default of a summary without one)
CALIBRATION = "calibration"


@dataclass(frozen=True)
class FitSummary:
    """The verdict, the diagnostics and the summaries of one fit.

    Attributes
    ----------
    model_kind : str
        ``"calibration"`` (a camera) or ``"film"``: which report reads the folder.
    status : str
        ``"ok"`` or ``"FAILED"``.
    backend : str
        The backend that drew the posterior (``"fleet"``: drawn from a fleet's hierarchy).
    seed : int
    model : dict
        ``name`` and the kind's own description of the model (components, reference setting, bands).
    diagnostics : dict
        ``verdict`` and ``problems`` at least, with the backend's own diagnostics.
    parameters : list of dict
        Per reported quantity: ``parameter``, mean, sd, quantiles, R-hat and ESS.
    bayescal_version : str
    timings_s : dict
        Seconds per stage of the fit.
    stimulus_unit : str or None
        The stimulus's unit (a camera's calibration).
    comparison_at_reference : list of dict
        The coefficients at the reference setting, least squares beside the posterior (a camera's).
    lsq : list of dict
        The least-squares baseline per setting and channel (a camera's).
    source : dict or None
        Where a posterior came from when not from a fit of its own data (a fleet's export: the fleet,
        the camera, the date, the template camera, a note).
    """

    model_kind: str
    status: str
    backend: str
    seed: int
    model: dict
    diagnostics: dict
    parameters: list
    bayescal_version: str = ""
    timings_s: dict = field(default_factory=dict)
    stimulus_unit: str | None = None
    comparison_at_reference: list = field(default_factory=list)
    lsq: list = field(default_factory=list)
    source: dict | None = None

    @property
    def ok(self) -> bool:
        """Whether the fit passed its checks."""
        return self.status == "ok"

    def to_json(self) -> dict[str, Any]:
        """The JSON document (``source`` only when there is one)."""
        out = asdict(self)
        if out["source"] is None:
            del out["source"]
        return out

    @classmethod
    def from_json(cls, data: Any, where: str | Path = "a fit's summary") -> FitSummary:
        """The summary of a parsed ``summary.json`` (read from ``where``), every key a reader relies on
        checked.

        Raises
        ------
        PosteriorError
            Naming the file and the key that is missing or not of the kind expected.
        """
        if not isinstance(data, dict):
            raise PosteriorError(
                f"{where} is not a bayescal summary: expected a JSON object, got {type(data).__name__}"
            )
        kind = data.get("model_kind", CALIBRATION)
        needed = {
            "status": str,
            "backend": str,
            "seed": int,
            "model": dict,
            "diagnostics": dict,
            "parameters": list,
        }
        if kind == CALIBRATION:
            needed |= {"stimulus_unit": str, "comparison_at_reference": list, "lsq": list}
        for key, kind_of in needed.items():
            if key not in data:
                raise PosteriorError(
                    f"{where} is not a bayescal summary: key '{key}' is missing; re-run `bayescal fit`"
                )
            if not isinstance(data[key], kind_of):
                raise PosteriorError(
                    f"{where}: key '{key}' should be a {kind_of.__name__}, got {type(data[key]).__name__}"
                )
        for key in ("verdict", "problems"):
            if key not in data["diagnostics"]:
                raise PosteriorError(f"{where} is not a bayescal summary: key 'diagnostics.{key}' is missing")
        if "name" not in data["model"]:
            raise PosteriorError(f"{where} is not a bayescal summary: key 'model.name' is missing")
        known = {f.name for f in fields(cls)}
        return cls(model_kind=kind, **{k: v for k, v in data.items() if k in known and k != "model_kind"})
