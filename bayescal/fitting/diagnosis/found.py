"""What a search found: the switches adopted, each step's ranking, the rivals the data cannot tell apart."""

from __future__ import annotations

from dataclasses import dataclass, field

from bayescal.fitting.result import Fit
from bayescal.model.spec import ModelSpec


@dataclass(frozen=True)
class Diagnosis:
    """What the search found.

    Attributes
    ----------
    adopted : tuple of str
        The switches adopted, in order (empty: none explained more than the spec).
    spec : ModelSpec
        The spec with them switched on.
    explained : bool
        Whether a fit of ``spec`` passes every check.
    steps : list of pandas.DataFrame
        Per step, every candidate beside the model so far: elpd_diff against it (positive:
        better), its standard error, and whether its fit passed its checks (every check but the
        leave-one-setting-out refits, which only the adopted model's fit runs).
    fit : Fit or None
        The Laplace fit of ``spec`` with every check (None when nothing was adopted).
    trials : dict
        When nothing was adopted: the first step's candidates, name -> (spec, Laplace fit).
    rivals : dict
        The candidates of the step that adopted the last switch which pass their checks and predict the
        data about as well as it (elpd_loo within :data:`EVIDENCE_SE` standard errors of their paired
        difference): name -> (elpd difference, its se, Laplace fit).
    preferred : dict
        When a rival draws the adopted structure and more (:func:`_more_flexible`) it is adopted in its
        place: ``{"candidate": its name, "over": the switch it replaced, "elpd_diff", "dse"}``; the rigid
        one is then among the rivals.
    """

    adopted: tuple[str, ...]
    spec: ModelSpec
    explained: bool
    steps: list
    fit: Fit | None = field(default=None, repr=False, compare=False)
    trials: dict = field(default_factory=dict, repr=False, compare=False)
    rivals: dict = field(default_factory=dict, repr=False, compare=False)
    preferred: dict = field(default_factory=dict, repr=False, compare=False)
    #: the spec changes of a flexible model (:mod:`bayescal.fitting.flexible`), which has no search steps
    merged: dict = field(default_factory=dict, repr=False, compare=False)

    def describe(self) -> str:
        """The diagnosis in words, for the command line."""
        lines = []
        for i, step in enumerate(self.steps):
            lines.append(f"step {i + 1}: each candidate against the model so far (elpd_loo difference +- se):")
            for r in step.itertuples():
                if getattr(r, "screened", False):
                    lines.append(
                        f"  {'-':>9} {'':>9}  {r.candidate}  (screened out: at its mode it gains "
                        f"{r.mode_gain:+.1f} +- {r.mode_dse:.1f} in-sample)"
                    )
                    continue
                ok = "passes its checks" if r.fit_ok else "still fails"
                lines.append(f"  {r.elpd_diff:+9.1f} +- {r.dse:6.1f}  {r.candidate}  ({ok})")
        if self.adopted:
            what = " and ".join(self.adopted)
            verdict = "explains the data" if self.explained else "explains part of the data; the fit still fails"
            lines.append(f"adopted: {what}: {verdict}")
            lines.append("to fit it directly, change the spec: " + _changes_text(self.changes()))
        else:
            lines.append("nothing in the library explains the data better than the spec")
        return "\n".join(lines)

    def changes(self) -> dict:
        """The spec changes adopted, merged by section."""
        if self.merged:
            return self.merged
        merged: dict = {}
        for step in self.steps:
            for r in step.itertuples():
                if r.candidate in self.adopted:
                    for section, keys in r.changes.items():
                        merged.setdefault(section, {}).update(keys)
        return merged

    def to_dict(self) -> dict:
        """JSON-ready form (``summary.json``'s ``diagnostics.diagnosis``)."""
        return {
            "adopted": list(self.adopted),
            "explained": self.explained,
            "changes": self.changes(),
            "steps": [s.drop(columns="changes").to_dict("records") for s in self.steps],
        }


def _changes_text(changes: dict) -> str:
    return "; ".join(f"[{sec}] " + ", ".join(f"{k} = {v!r}" for k, v in keys.items()) for sec, keys in changes.items())
