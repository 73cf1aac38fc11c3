"""The units' excess dispersion per direction: where the channels move together, and apart.

A unit's stage-one covariance ``Sigma_u`` becomes ``T Sigma_u T`` in stage two, with
``T = sqrt(kappa_1) P_1 + sqrt(kappa_2) P_2`` per quantity kind (``P_1`` the channels'
mean, ``P_2 = I - P_1``): a unit's log gains are 0.93-0.97 correlated across channels,
and the channel model's misfit inflates the two directions by different amounts
(``benchmarks/fleet_excess_directions.py``).  Multiplying a unit's values by ``T^-1``
leaves ``Sigma_u`` unscaled, so the Gram arrays of :mod:`.model` are computed once per
weight product ``f_a f_b`` (``f = kappa^-1/2`` per direction, and 1 for the camera's
shared error) and combined here per evaluation.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from bayescal.fleet.plan import Plan

__all__ = [
    "channel_inflation",
    "direction_sizes",
    "excess_of",
    "log_det_t",
    "factors",
    "kind_blocks",
    "projections",
    "scale_directions",
    "weighted",
]


def kind_blocks(plan: Plan, cov: np.ndarray) -> np.ndarray:
    """The units' covariances ``(U, K*C, K*C)`` as their kinds' blocks ``(K, U, C, C)``."""
    c_n = plan.n_channels
    return np.stack([cov[:, k * c_n : (k + 1) * c_n, k * c_n : (k + 1) * c_n] for k in range(plan.n_kinds)])


def projections(n_channels: int) -> np.ndarray:
    """``(D, C, C)``: onto the channels' mean (all channels together) and, with two or more
    channels, onto its complement (the channels apart)."""
    together = np.full((n_channels, n_channels), 1.0 / n_channels)
    return np.stack([together, np.eye(n_channels) - together]) if n_channels > 1 else together[None]


def excess_of(plan: Plan, hyper: dict, xp=np, draws: int | None = None):
    """Each kind's excess dispersion per direction, ``(..., K, D)``; without an excess, ones
    (``(draws, K, D)`` when ``draws`` is given, else ``(K, D)``)."""
    if "excess" not in hyper:
        return xp.ones(((draws,) if draws is not None else ()) + (plan.n_kinds, plan.n_directions))
    kappa = hyper["excess"]
    return kappa.reshape(kappa.shape[:-1] + (plan.n_kinds, plan.n_directions))


def direction_sizes(plan: Plan) -> np.ndarray:
    """A unit's values in each direction of one kind, ``(D,)``: 1 together, ``C - 1`` apart."""
    return np.array([1.0, plan.n_channels - 1.0])[: plan.n_directions]


def log_det_t(plan: Plan, kappa, xp=np):
    """``log|T|`` per kind, ``(..., K)``: ``1/2 sum_a n_a log kappa_a`` (:func:`direction_sizes`)."""
    return 0.5 * xp.sum(direction_sizes(plan) * xp.log(kappa), axis=-1)


def factors(kappa, xp=np):
    """``(..., K, F)``: ``kappa_a^-1/2`` per direction and 1 (the camera's shared error, unscaled)."""
    return xp.concatenate([1.0 / xp.sqrt(kappa), xp.ones(kappa.shape[:-1] + (1,))], axis=-1)


def scale_directions(plan: Plan, v, kappa, xp=np, inverse: bool = False):
    """``T v`` (``T^-1 v`` with ``inverse``) for values ``v`` ``(..., K, C)`` and ``kappa`` ``(..., K, D)``:
    each direction's part of ``v`` times ``sqrt(kappa)`` of that direction."""
    proj = xp.asarray(projections(plan.n_channels))
    root = xp.sqrt(kappa)
    root = 1.0 / root if inverse else root
    return xp.einsum("...kd,dce,...ke->...kc", root, proj, v)


def channel_inflation(plan: Plan, unit_cov: np.ndarray, kappa: np.ndarray) -> np.ndarray:
    """Per kind, how much wider the excess makes a unit's own interval of one channel:
    ``sqrt(diag(T Sigma_u T) / diag(Sigma_u))``, the median over units and channels ``(K,)``.

    ``unit_cov``: the units' covariances ``(U, K*C, K*C)`` (any per-kind units); ``kappa``:
    ``(..., K, D)``, leading dimensions (draws) carried through to ``(..., K)``.
    """
    t = np.einsum("...kd,dce->...kce", np.sqrt(kappa), projections(plan.n_channels))  # T per kind
    sigma = kind_blocks(plan, unit_cov)  # (K, U, C, C)
    wide = np.einsum("...kce,kuef,...kcf->...kuc", t, sigma, t)
    own = np.diagonal(sigma, axis1=-2, axis2=-1)
    return np.median(np.sqrt(wide / own), axis=(-2, -1))


#: the arrays :func:`weighted` combines
_GRAM = ("g_gg", "g_gm", "g_mm", "b_g", "b_m", "yy")


def weighted(plan: Plan, arrays: dict, kappa, xp=np) -> dict:
    """The Gram arrays of given excess dispersions ``kappa`` ``(..., K, D)``: ``sum_p w_p G_p``
    (``model._blocks``), with the prior's variances; leading dimensions of ``kappa`` carry through."""
    f = factors(kappa, xp)
    w = xp.stack([f[..., a] * f[..., b] for a, b in plan.pairs], axis=-2)  # (..., P, K)
    out = {}
    for name in _GRAM:
        g = arrays[name]
        extra = g.ndim - 2
        # a broadcast product summed over P, not an einsum: XLA fuses it into one pass, where its
        # dot_general over these small axes took 0.5 ms of a 1.2 ms gradient
        out[name] = xp.sum(w.reshape(w.shape + (1,) * extra) * g, axis=-(extra + 2))
    out["prior_var_g"] = arrays["prior_var_g"]
    return out
