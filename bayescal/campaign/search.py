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

__all__ = ["Costs", "greedy", "relaxed", "pruned", "trimmed", "cost_of"]


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
        if steps is None and not gain[best] * cost[best] > 1e-6 * float(_score(var, goal_var, meet)):
            break
        counts[best] += 1
        spent += float(cost[best])
        chosen.add(settings[best])
        added += 1
        if progress is not None:
            progress(added, spent)
    return counts, spent


def _group_terms(lin: Linearisation, counts: np.ndarray, eligible: np.ndarray):
    """The targets' variances ``(T,)`` under ``counts`` and their derivatives in each eligible group's
    count ``(K_eligible, T)``: ``d v_t / d n_k = -|U_k Sigma g_t|^2`` (averaged over the points)."""
    cov = lin.covariance(counts)
    var = lin.variances(cov).mean(axis=0)
    a = lin.factors[:, eligible] @ (cov @ np.swapaxes(lin.gradients, 1, 2))[:, None]  # (S, K, m, T)
    return var, -np.sum(a * a, axis=2).mean(axis=0)


def relaxed(
    lin: Linearisation,
    base: np.ndarray,
    goals: np.ndarray,
    costs: np.ndarray,
    eligible: np.ndarray,
    budget: float | None = None,
) -> np.ndarray:
    """The continuous design: non-negative counts ``w`` (added to ``base``) of least cost ``costs @ w`` whose
    targets' variances meet ``goals^2`` (or, with a ``budget``, of least ``sum_t v_t / g_t^2`` within it).

    Both problems are convex in ``w`` (a variance ``g' (H + sum_k w_k F_k)^-1 g`` is convex in ``w``;
    Boyd and Vandenberghe 2004, section 7.5) and are solved by SLSQP with exact gradients; the result is
    rounded by :func:`rounded`.
    """
    from scipy.optimize import minimize

    idx = np.flatnonzero(eligible)
    goal_var = np.asarray(goals, dtype=float) ** 2
    c = np.asarray(costs, dtype=float)[idx]
    base = np.asarray(base, dtype=float)

    def full(w):
        counts = base.copy()
        counts[idx] += w
        return counts

    cache: dict[bytes, tuple] = {}

    def terms(w):
        key = w.tobytes()
        if key not in cache:
            cache.clear()
            cache[key] = _group_terms(lin, full(w), eligible)
        return cache[key]

    w0 = np.full(idx.size, 1.0)
    bounds = [(0.0, None)] * idx.size
    if budget is None:
        cons = {
            "type": "ineq",
            "fun": lambda w: -np.log(terms(w)[0] / goal_var),
            "jac": lambda w: -(terms(w)[1] / terms(w)[0]).T,
        }
        res = minimize(
            lambda w: c @ w,
            w0,
            jac=lambda w: c,
            bounds=bounds,
            constraints=[cons],
            method="SLSQP",
            options={"maxiter": 300, "ftol": 1e-9},
        )
    else:
        w0 = w0 * max(budget, 0.0) / max(float(c @ w0), 1e-12)
        cons = {"type": "ineq", "fun": lambda w: budget - c @ w, "jac": lambda w: -c}
        res = minimize(
            lambda w: float(np.sum(terms(w)[0] / goal_var)),
            w0,
            jac=lambda w: terms(w)[1] @ (1.0 / goal_var),
            bounds=bounds,
            constraints=[cons],
            method="SLSQP",
            options={"maxiter": 300, "ftol": 1e-12},
        )
    w = np.zeros(len(base))
    w[idx] = np.maximum(res.x, 0.0)
    return w


def pruned(
    lin: Linearisation,
    counts: np.ndarray,
    goals: np.ndarray,
    costs: Costs,
    settings: list[tuple],
    keep: np.ndarray,
    allowed: Callable[[np.ndarray], bool] = lambda counts: True,
) -> np.ndarray:
    """Remove measurements one at a time, the costliest saving first among those whose removal keeps every
    target within its goal, until none can go (never below ``keep``; ``allowed(counts)`` vetoes a removal,
    e.g. one that gives up a model check)."""
    counts = np.array(counts, dtype=int)
    goal_var = np.asarray(goals, dtype=float) ** 2
    while True:
        best, best_key = -1, (0.0, -np.inf)
        for k in map(int, np.flatnonzero(counts > keep)):
            trial = counts.copy()
            trial[k] -= 1
            if not allowed(trial):
                continue
            saving = costs.rows_per_group + (costs.setting_change if _last_of_setting(trial, settings, k) else 0.0)
            var = lin.variances(lin.covariance(trial)).mean(axis=0)
            key = (saving, -float(np.sum(var / goal_var)))
            if np.all(var <= goal_var * (1 + 1e-9)) and key > best_key:
                best, best_key = k, key
        if best < 0:
            return counts
        counts[best] -= 1


def _last_of_setting(counts: np.ndarray, settings: list[tuple], k: int) -> bool:
    return not any(counts[j] > 0 for j in range(len(settings)) if settings[j] == settings[k])


def cost_of(counts: np.ndarray, costs: Costs, settings: list[tuple]) -> float:
    """What a design costs in rows: its groups' rows and one setting change per setting it uses."""
    counts = np.asarray(counts)
    used = {settings[k] for k in np.flatnonzero(counts)}
    return float(costs.rows_per_group * counts.sum() + costs.setting_change * len(used))


def trimmed(
    lin: Linearisation,
    counts: np.ndarray,
    goals: np.ndarray,
    costs: Costs,
    settings: list[tuple],
    budget: float,
    keep: np.ndarray,
    allowed: Callable[[np.ndarray], bool] = lambda counts: True,
) -> np.ndarray:
    """Remove measurements, the one whose loss widens the targets least (``sum_t v_t / g_t^2``) first,
    until the design costs no more than ``budget`` (never below ``keep``; ``allowed`` vetoes a removal)."""
    counts = np.array(counts, dtype=int)
    goal_var = np.asarray(goals, dtype=float) ** 2
    while cost_of(counts, costs, settings) > budget + 1e-9:
        best, best_score = -1, np.inf
        for k in map(int, np.flatnonzero(counts > keep)):
            trial = counts.copy()
            trial[k] -= 1
            if not allowed(trial):
                continue
            score = float(np.sum(lin.variances(lin.covariance(trial)).mean(axis=0) / goal_var))
            if score < best_score:
                best, best_score = k, score
        if best < 0:
            return counts
        counts[best] -= 1
    return counts
