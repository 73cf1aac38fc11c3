"""Leave one unit out, with every linear latent integrated out exactly.

Given the scales ``h``, stage two is linear and Gaussian (:mod:`.model`), so a unit's
predictive density given every other unit, ``p(y_u | y_-u, h)``, is a closed form:
with ``X_u`` the unit's rows of the (whitened, ``T^-1``) design, ``mu`` and ``V`` the
latents' posterior mean and covariance given all units, ``Q = X_u V X_u'`` and the
residual ``r = T^-1 y_u - X_u mu``::

    y_u | y_-u, h ~ Normal(H_u mu_-u, T (Sigma_u + X_u V_-u X_u') T),
    log p = -1/2 r' A^-1 r + 1/2 log|A| - log|Sigma_u| - C/2 log(2 pi) - log|T|,   A = Sigma_u - Q

(removing one unit's rows from a Gaussian linear model, per kind: the predictive
covariance is ``Sigma A^-1 Sigma`` and the residual ``Sigma A^-1 r``).  PSIS then
reweights only the draws of the few scales, not a unit's own jitter, walk step and
camera level, which is what made the Pareto k of the conditional log-likelihood high
for most units (Vehtari, Mononen, Tolvanen, Sivula & Winther 2016, "Bayesian leave-one-out
cross-validation approximations for Gaussian latent variable models", JMLR 17).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from bayescal.fleet.data import design_of, pieces
from bayescal.fleet.excess import factors, kind_blocks, log_det_t, weighted
from bayescal.fleet.marginal import factorise, solve_chol, solve_lower
from bayescal.fleet.plan import FleetData, Plan

__all__ = ["loo_pieces", "loo_log_predictive", "loo_predictive"]

#: draws per call of the compiled program (its memory: ~0.5 MB per draw and unit)
LOO_CHUNK = 64


def loo_pieces(plan: Plan, data: FleetData) -> dict[str, np.ndarray]:
    """The units' design and values split by direction (:func:`.model.pieces`), their
    covariances ``sigma (K, U, C, C)`` and ``log|Sigma_u|`` per kind ``(K, U)``."""
    h_g, h_m, _ = design_of(plan, data)
    x_g, x_m, v = pieces(plan, h_g, h_m, data.y.reshape(plan.n_units, plan.n_kinds, plan.n_channels))
    sigma = kind_blocks(plan, data.chol @ np.swapaxes(data.chol, -1, -2))
    return {"x_g": x_g, "x_m": x_m, "v": v, "sigma": sigma, "logdet": np.linalg.slogdet(sigma)[1]}


def loo_log_predictive(plan: Plan, camera, sc, kappa, arrays: dict, parts: dict, xp=np):
    """``log p(y_u | y_-u, h)`` per draw and unit ``(S, U)`` (module docstring), in the array module ``xp``.

    ``sc`` ``(S, K, M, B)`` and ``kappa`` ``(S, K, D)``: each draw's slot scales and excess
    (:func:`.model.draw_scales`); ``parts``: :func:`loo_pieces`; ``camera``: each unit's camera.
    """
    a = weighted(plan, arrays, kappa, xp)
    bm_s, l_m, l_s, b_g2, p_gm, x_mg = factorise(plan, sc, a, xp)  # P_gm, P_mm^-1 P_mg
    mu_g = solve_chol(l_s, b_g2, xp)
    mu_m = solve_chol(l_m, bm_s - xp.einsum("skmgb,skg->skmb", p_gm, mu_g), xp)  # standardised slots
    f = factors(kappa, xp)  # (S, K, F)
    x_g = xp.einsum("skf,fkucg->skucg", f, parts["x_g"])
    x_m = xp.einsum("skf,fkucb->skucb", f, parts["x_m"]) * sc[:, :, camera, None, :]
    resid = (
        xp.einsum("skf,fkuc->skuc", f, parts["v"])
        - xp.einsum("skucg,skg->skuc", x_g, mu_g)
        - xp.einsum("skucb,skub->skuc", x_m, mu_m[:, :, camera])
    )
    # Q = Z V_gg Z' + X_m P_mm^-1 X_m' with Z = X_g - X_m P_mm^-1 P_mg
    z = x_g - xp.einsum("skucb,skubg->skucg", x_m, x_mg[:, :, camera])
    l_s_u = xp.broadcast_to(l_s[:, :, None], z.shape[:3] + l_s.shape[-2:])
    w = solve_lower(l_s_u, xp.swapaxes(z, -1, -2), xp)  # (S, K, U, G, C)
    y = solve_lower(l_m[:, :, camera], xp.swapaxes(x_m, -1, -2), xp)  # (S, K, U, B, C)
    q = xp.swapaxes(w, -1, -2) @ w + xp.swapaxes(y, -1, -2) @ y
    l_a = xp.linalg.cholesky(parts["sigma"] - q)
    white = solve_lower(l_a, resid[..., None], xp)[..., 0]
    c_n = plan.n_channels
    log_t = log_det_t(plan, kappa, xp)  # (S, K)
    per_kind = (
        -0.5 * xp.sum(white**2, axis=-1)
        + xp.sum(xp.log(xp.diagonal(l_a, axis1=-2, axis2=-1)), axis=-1)
        - parts["logdet"]
        - 0.5 * c_n * np.log(2.0 * np.pi)
        - log_t[..., None]
    )
    return xp.sum(per_kind, axis=1)


@lru_cache(maxsize=16)
def _program(plan: Plan):
    """:func:`loo_log_predictive` compiled once per structure, for a chunk of :data:`LOO_CHUNK` draws."""
    import jax
    import jax.numpy as jnp

    return jax.jit(
        lambda camera, sc, kappa, arrays, parts: loo_log_predictive(plan, camera, sc, kappa, arrays, parts, jnp)
    )


def loo_predictive(plan: Plan, data: FleetData, sc: np.ndarray, kappa: np.ndarray) -> np.ndarray:
    """:func:`loo_log_predictive` of every draw by the compiled program, in chunks (the last one padded)."""
    import jax

    program = _program(plan)
    arrays = jax.device_put(data.arrays())
    parts = jax.device_put(loo_pieces(plan, data))
    camera = jax.device_put(np.asarray(data.camera))
    s = sc.shape[0]
    out = []
    for i in range(0, s, LOO_CHUNK):
        idx = np.minimum(np.arange(i, i + LOO_CHUNK), s - 1)
        out.append(np.asarray(program(camera, sc[idx], kappa[idx], arrays, parts))[: min(LOO_CHUNK, s - i)])
    return np.concatenate(out)
