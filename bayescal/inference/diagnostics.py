"""Convergence diagnostics with arviz; a failed fit is reported as failed.

Thresholds (docs/architecture.md, section 4, issue acceptance): no divergences, R-hat
<= 1.01, bulk and tail ESS >= ``min_ess`` for every sampled and reported
quantity.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
import xarray as xr

from bayescal.model.spec import InferenceSpec

__all__ = ["Diagnostics", "mcmc_diagnostics"]


@dataclass(frozen=True)
class Diagnostics:
    """Verdict and the numbers behind it."""

    ok: bool
    problems: tuple[str, ...]
    divergences: int = 0
    max_rhat: float = float("nan")
    min_ess_bulk: float = float("nan")
    min_ess_tail: float = float("nan")
    extra: dict = field(default_factory=dict)

    @property
    def verdict(self) -> str:
        """``"ok"`` or ``"FAILED: ..."``."""
        return "ok" if self.ok else "FAILED: " + "; ".join(self.problems)

    def with_check(self, name: str, problems: list[str], info: dict) -> Diagnostics:
        """This verdict after a check: its numbers kept under ``name``, its problems (if any) failing the fit."""
        extra = dict(self.extra, **{name: info})
        if not problems:
            return replace(self, extra=extra)
        return replace(self, ok=False, problems=self.problems + tuple(problems), extra=extra)

    def to_dict(self) -> dict:
        """JSON-ready form."""
        return {
            "ok": self.ok,
            "verdict": self.verdict,
            "problems": list(self.problems),
            "divergences": self.divergences,
            "max_rhat": self.max_rhat,
            "min_ess_bulk": self.min_ess_bulk,
            "min_ess_tail": self.min_ess_tail,
            **self.extra,
        }


def mcmc_diagnostics(posterior: xr.Dataset, divergences: int, settings: InferenceSpec, extra=None) -> Diagnostics:
    """R-hat and ESS of every variable of ``posterior`` (dims chain, draw, ...)."""
    import arviz_stats

    varying = [v for v in posterior.data_vars if float(posterior[v].std()) > 0]
    ds = posterior[varying]
    rhat = _min_max(arviz_stats.rhat(ds), np.nanmax)
    bulk = _min_max(arviz_stats.ess(ds, method="bulk"), np.nanmin)
    tail = _min_max(arviz_stats.ess(ds, method="tail"), np.nanmin)
    problems = []
    if divergences:
        problems.append(f"{divergences} divergent transitions")
    if not rhat <= settings.max_rhat:
        problems.append(f"max R-hat {rhat:.4f} > {settings.max_rhat}")
    if not bulk >= settings.min_ess:
        problems.append(f"min bulk ESS {bulk:.0f} < {settings.min_ess:.0f}")
    if not tail >= settings.min_ess:
        problems.append(f"min tail ESS {tail:.0f} < {settings.min_ess:.0f}")
    return Diagnostics(not problems, tuple(problems), divergences, rhat, bulk, tail, extra or {})


def _min_max(ds, reducer) -> float:
    """``reducer`` over every value of ``ds`` that is not NaN (NaN when none is: R-hat of one chain)."""
    values = np.concatenate([np.asarray(ds[v]).ravel() for v in ds.data_vars] or [np.array([np.nan])])
    values = values[~np.isnan(values)]
    return float(reducer(values)) if values.size else float("nan")
