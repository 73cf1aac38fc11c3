"""Choosing measurements greedily by what they add (docs/guides/design.md).

Each step measures the group (a setting at a level, or dark) whose information lowers the targets'
expected posterior variances most per unit of cost; the update of the covariance is a low-rank one
(:meth:`~bayescal.campaign.information.Linearisation.reductions`).  The criterion is target-weighted:
``sum_t max(v_t / g_t^2, 1)`` while some target is wider than its goal ``g_t`` (the cheapest design that
meets every goal), or ``sum_t v_t / g_t^2`` within a budget (the narrowest design of that cost), a
weighted A-criterion (Atkinson, Donev and Tobias 2007, Optimum Experimental Designs, chapter 10).
Greedy selection is within a constant factor of the best for such criteria and is what a lab can
follow block by block.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from bayescal.campaign.information import Linearisation

__all__ = ["Costs", "greedy"]


@dataclass(frozen=True)
class Costs:
    """What a measurement costs, in rows.

    Attributes
    ----------
    rows_per_group : int
        Rows one group adds (one per channel).
    setting_change : float
        The extra cost of a setting not yet in the design (time to change exposure, gain, stages or
        temperature at the sphere), in rows.
    """

    rows_per_group: int
    setting_change: float = 0.0

    def of(self, settings: list[tuple], chosen: set[tuple]) -> np.ndarray:
        """The cost of adding each group, given the settings already chosen."""
        change = np.array([0.0 if s in chosen else self.setting_change for s in settings])
        return self.rows_per_group + change


def _score(var: np.ndarray, goal_var: np.ndarray, meet: bool) -> np.ndarray:
    ratio = var / goal_var
    return np.maximum(ratio, 1.0).sum(axis=-1) if meet else ratio.sum(axis=-1)


def greedy(
    lin: Linearisation,
    counts: np.ndarray,
    goals: np.ndarray,
    costs: Costs,
    settings: list[tuple],
    *,
    eligible: np.ndarray,
    budget: float = np.inf,
    meet: bool = True,
    spent: float = 0.0,
    steps: int | None = None,
    progress: Callable[[int, float], None] | None = None,
) -> tuple[np.ndarray, float]:
    """Add groups to ``counts`` until every target meets its goal (``meet``) or the budget is spent.

    Parameters
    ----------
    lin : Linearisation
        The groups' information and the targets' gradients.
    counts : array (K,)
        Groups already in the design (measured or required); a copy is extended.
    goals : array (T,)
        The standard deviation wanted for each target.
    costs : Costs
        What each group costs.
    settings : list
        Each group's setting (:attr:`~bayescal.campaign.grid.Group.setting`).
    eligible : array (K,) of bool
        Groups that may be added (clipped ones are not).
    budget : float
        The most the design may cost, in rows (``spent`` included).
    meet : bool
        Stop once every goal is met; otherwise narrow the targets until the budget is spent.
    spent : float
        The cost of ``counts`` already.
    steps : int, optional
        Add at most this many groups, each the best eligible one even when it narrows nothing (a group
        the model's checks need).
    progress : callable, optional
        ``progress(groups_added, cost)`` after each step.

    Returns
    -------
    counts, cost
    """
    counts = np.array(counts, dtype=int)
    goal_var = np.asarray(goals, dtype=float) ** 2
    chosen = {settings[k] for k in np.flatnonzero(counts)}
    added = 0
    while steps is None or added < steps:
        cov = lin.covariance(counts)
        var = lin.variances(cov).mean(axis=0)
        if meet and np.all(var <= goal_var):
            break
        cost = costs.of(settings, chosen)
        ok = eligible & (spent + cost <= budget + 1e-9)
        if not ok.any():
            break
        after = var[None, :] - lin.reductions(cov).mean(axis=0)  # (K, T)
        gain = (_score(var, goal_var, meet) - _score(after, goal_var, meet)) / cost
        gain = np.where(ok, gain, -np.inf)
        best = int(np.argmax(gain))
        if steps is None and not gain[best] > 1e-12 * max(float(_score(var, goal_var, meet)), 1.0):
            break
        counts[best] += 1
        spent += float(cost[best])
        chosen.add(settings[best])
        added += 1
        if progress is not None:
            progress(added, spent)
    return counts, spent
