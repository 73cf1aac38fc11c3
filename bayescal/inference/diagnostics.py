"""Convergence diagnostics with arviz; a failed fit is reported as failed.

Thresholds (docs/architecture.md, section 4, issue acceptance): no divergences, R-hat
<= 1.01, bulk and tail ESS >= ``min_ess`` for every sampled and reported
quantity.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace

import numpy as np

from bayescal.model.spec import InferenceSpec

__all__ = ["Diagnostics", "convergence", "mcmc_diagnostics"]


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


def mcmc_diagnostics(
    posterior: Mapping[str, np.ndarray], divergences: int, settings: InferenceSpec, extra=None
) -> Diagnostics:
    """R-hat and ESS of every variable of ``posterior`` (arrays ``(chain, draw, ...)``), judged against
    ``settings``."""
    rhat, bulk, tail = convergence(posterior)
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


def convergence(posterior: Mapping[str, np.ndarray]) -> tuple[float, float, float]:
    """The largest rank-normalised R-hat and the smallest bulk and tail ESS over every element of
    ``posterior``'s arrays ``(chain, draw, ...)`` that varies (arviz-stats; NaN when none does, and
    R-hat NaN for one chain).

    The elements are stacked into one ``(element, chain, draw)`` array, so arviz-stats runs once per
    statistic rather than once per variable and statistic.
    """
    from arviz_stats.base import array_stats
    from arviz_stats.validate import validate_ci_prob

    columns = [np.asarray(v) for v in posterior.values()]
    if not columns:
        return float("nan"), float("nan"), float("nan")
    chains, draws = columns[0].shape[:2]
    stacked = np.concatenate([c.reshape(chains, draws, -1) for c in columns], axis=2)
    stacked = np.moveaxis(stacked[:, :, stacked.std(axis=(0, 1)) > 0], 2, 0)
    if not stacked.size:
        return float("nan"), float("nan"), float("nan")
    rhat = array_stats.rhat(stacked, chain_axis=-2, draw_axis=-1)
    bulk = array_stats.ess(stacked, chain_axis=-2, draw_axis=-1, method="bulk")
    # the tail's quantiles as arviz-stats' own interface takes them (its ``stats.ci_prob``)
    tail = array_stats.ess(stacked, chain_axis=-2, draw_axis=-1, method="tail", prob=validate_ci_prob(None))
    return _nan_reduce(rhat, np.nanmax), _nan_reduce(bulk, np.nanmin), _nan_reduce(tail, np.nanmin)


def _nan_reduce(values: np.ndarray, reducer) -> float:
    """``reducer`` over the values that are not NaN (NaN when none is: R-hat of one chain)."""
    values = np.asarray(values).ravel()
    values = values[~np.isnan(values)]
    return float(reducer(values)) if values.size else float("nan")
