"""Draws of the fleet's linear latents given draws of its scales: exact Gaussian conditionals
(:mod:`.marginal` factorises them), batched over draws, in numpy or compiled JAX.
"""

from __future__ import annotations

import numpy as np

from bayescal.fleet.excess import excess_of, weighted
from bayescal.fleet.marginal import block_scales, factorise, solve_chol, solve_lower
from bayescal.fleet.plan import Plan

__all__ = ["conditional_draws", "draw_scales", "latent_draws", "standard_normals"]


def conditional_draws(plan: Plan, hyper: dict, arrays: dict, rng: np.random.Generator):
    """Draws of the linear latents given each draw of the scales (NumPy, batched over draws).

    ``hyper``: scale name -> ``(S, size)``.  Returns the global coefficients ``(S, K, G)``
    and the per-camera ones ``(S, K, M, B)`` (already multiplied by their scales).
    """
    sc, kappa = draw_scales(plan, hyper, arrays)
    z_g, z_m = standard_normals(plan, sc.shape[0], rng)
    return latent_draws(plan, sc, kappa, arrays, z_g, z_m)


def draw_scales(plan: Plan, hyper: dict, arrays: dict) -> tuple[np.ndarray, np.ndarray]:
    """Each draw's slot scales ``(S, K, M, B)`` and excess dispersion ``(S, K, D)``."""
    s = next(iter(hyper.values())).shape[0] if hyper else 1
    sc = np.stack([block_scales(plan, {k: v[i] for k, v in hyper.items()}) for i in range(s)])  # (S, K, B)
    sc = sc[:, :, None, :] * arrays["active"][None]  # (S, K, M, B)
    kappa = excess_of(plan, hyper, draws=s)
    return sc, kappa


def standard_normals(plan: Plan, s: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """The standard normal variates of ``s`` conditional draws: global ``(S, K, G)``, per camera ``(S, K, M, B)``."""
    z_g = rng.standard_normal((s, plan.n_kinds, plan.n_global))
    z_m = rng.standard_normal((s, plan.n_kinds, plan.n_cameras, plan.block))
    return z_g, z_m


def latent_draws(plan: Plan, sc, kappa, arrays: dict, z_g, z_m, xp=np):
    """The conditional draws of :func:`conditional_draws` from given standard normals, in the array
    module ``xp`` (numpy, or ``jax.numpy`` compiled: :func:`bayescal.fleet.sampling.sample_fleet`)."""
    a = weighted(plan, arrays, kappa, xp)
    bm_s, l_m, l_s, b_g2, p_gm, _ = factorise(plan, sc, a, xp)
    g = solve_chol(l_s, b_g2, xp) + solve_lower(l_s, z_g[..., None], xp, transpose=True)[..., 0]
    rhs = bm_s - xp.einsum("skmgb,skg->skmb", p_gm, g)
    cam = solve_chol(l_m, rhs, xp) + solve_lower(l_m, z_m[..., None], xp, transpose=True)[..., 0]
    return g, sc * cam
