"""The fleet's marginal likelihood: every linear latent integrated out given the scales
(:mod:`.plan` says the model), its value and gradient from one factorisation per kind, and the
batched triangular solves the conditional draws (:mod:`.conditional`) and the leave-one-out
(:mod:`.loo`) share.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from bayescal.fleet.excess import excess_of, weighted
from bayescal.fleet.plan import UNPOOLED_SD, Plan

__all__ = ["block_scales", "factorise", "integrated_value", "log_marginal", "solve_chol", "solve_lower"]


def block_scales(plan: Plan, hyper: dict, xp=np):
    """The scale of each camera slot per kind, ``(K, B)``, from the scales' values (columns in the
    order of :class:`CameraSlots`: ``a``, ``b``, ``r``, ``walk``, ``jitter``, ``shared``)."""
    k_n, c_n = plan.n_kinds, plan.n_channels
    pad = xp.zeros(k_n - 2) if plan.drift else None
    if plan.pooling == "partial":
        s_cam, s_ch = hyper["sigma_camera"], hyper["sigma_channel"]
        tau = xp.concatenate([hyper["rate_sd"], pad]) if plan.drift else xp.zeros(k_n)
    elif plan.pooling == "none":
        s_cam, s_ch = xp.zeros(k_n), xp.full(k_n, UNPOOLED_SD)
        tau = xp.full(k_n, 4.0 * plan.rate_prior)
    else:
        s_cam = s_ch = tau = xp.zeros(k_n)
    walk = xp.concatenate([hyper["walk_sd"], pad]) if plan.walk else xp.zeros(k_n)
    cols = [s_cam[:, None], xp.repeat(s_ch[:, None], c_n, axis=1), tau[:, None]]
    cols.append(xp.repeat(walk[:, None], max(plan.max_walk, 0), axis=1))
    if plan.jitter:
        jitter = xp.concatenate([hyper["jitter_sd"], pad])
        cols.append(xp.repeat(jitter[:, None], plan.max_units, axis=1))
    if plan.shared:  # unit sd: the excess dispersion scales it with the units' own errors (``_blocks``)
        cols.append(xp.ones((k_n, c_n)))
    return xp.concatenate(cols, axis=1)


def log_marginal(plan: Plan, hyper: dict, arrays: dict):
    """log p(y | scales) up to a constant: every linear latent integrated out, summed over kinds.

    The value and its gradient come from one factorisation (:func:`_integrated`); JAX
    carries the gradient from the slots' scales and the weighted Gram arrays back to the
    sampled scales.  ``log |T Sigma T| = log |Sigma| + sum_a n_a log kappa_a`` per kind
    (``n_a``: the units' values in direction ``a``).
    """
    import jax.numpy as jnp

    kappa = excess_of(plan, hyper, jnp)
    sc = block_scales(plan, hyper, jnp)[:, None, :] * arrays["active"]  # (K, M, B)
    value = _integrated()(sc, weighted(plan, arrays, kappa, jnp))
    return value - 0.5 * jnp.sum(arrays["n_rows"] * jnp.log(kappa))


@lru_cache(maxsize=1)
def _integrated():
    """``F(sc, a) = 1/2 b' P^-1 b - 1/2 log|P| - 1/2 y' Sigma^-1 y`` per kind, summed, with its
    gradient in closed form (``a``: the Gram arrays as :func:`.excess.weighted` combines them).

    Latents in the camera blocks are standardised (``x_m = S_m z_m``, ``z_m ~ N(0, I)``), so
    the posterior precision and the data vector are, per kind::

        P_mm = I + S G_mm S,   P_mg = S G_mg,   P_gg = G_gg + D,
        b_m = S b_m,   b_g = b_g.

    With ``mu = P^-1 b`` and ``V = P^-1`` (the posterior mean and covariance),
    ``dF = db' mu - 1/2 mu' dP mu - 1/2 tr(V dP)``.  For one slot ``j`` of camera ``m`` that is
    ``mu_mj (b_mj - (G_mm S mu_m)_j - (G_mg mu_g)_j) - (G_mm S V_mm)_jj - (G_mg V_gm)_jj``; for
    the arrays (``x_m = S mu_m``)::

        dF/db_m = x_m,  dF/db_g = mu_g,  dF/dyy = -1/2,
        dF/dG_mm = -1/2 (x_m x_m' + S V_mm S),  dF/dG_gm = -(mu_g x_m' + V_gm S),
        dF/dG_gg = -1/2 (mu_g mu_g' + V_gg),  dF/dv_g = 1/2 (mu_g^2 + diag V_gg) / v_g^2

    (``v_g`` the global prior variances, ``D = diag(1 / v_g)``).  ``V``'s blocks come from the
    same Cholesky factors (``V_mg = -P_mm^-1 P_mg V_gg``, ``V_mm = P_mm^-1 + P_mm^-1 P_mg V_gg
    P_gm P_mm^-1``, ``V_gg`` the inverse Schur complement), so a gradient costs matrix products
    instead of reverse-mode passes through the factorisations: about half the time on the CPU.
    """
    import jax
    import jax.numpy as jnp

    @jax.custom_vjp
    def integrated(sc, a):
        return integrated_value(sc, a)[0]

    def forward(sc, a):
        value, res = integrated_value(sc, a)
        return value, (sc, a, res)

    def backward(saved, ct):
        sc, a, (inv_l, y_g, inv_s, mu_g, mu_m) = saved
        g_mm = a["g_mm"]
        g_mg = jnp.swapaxes(a["g_gm"], -1, -2)
        inv_lt = jnp.swapaxes(inv_l, -1, -2)
        v_gg = jnp.swapaxes(inv_s, -1, -2) @ inv_s
        x_mg = inv_lt @ y_g  # P_mm^-1 P_mg
        v_mg = -x_mg @ v_gg[:, None]
        v_mm = inv_lt @ inv_l - v_mg @ jnp.swapaxes(x_mg, -1, -2)
        x_m = sc * mu_m
        d_mm = jnp.einsum("kmij,kmj,kmji->kmi", g_mm, sc, v_mm)  # (G_mm S V_mm)_jj
        d_mg = jnp.einsum("kmjg,kmjg->kmj", g_mg, v_mg)  # (G_mg V_gm)_jj
        resid = a["b_m"] - jnp.einsum("kmij,kmj->kmi", g_mm, x_m) - jnp.einsum("kmbg,kg->kmb", g_mg, mu_g)
        grad_sc = mu_m * resid - d_mm - d_mg
        s_v_mg = sc[..., :, None] * v_mg  # S V_mg
        grads = {
            "b_m": x_m,
            "b_g": mu_g,
            "yy": jnp.full_like(a["yy"], -0.5),
            "g_mm": -0.5 * (x_m[..., :, None] * x_m[..., None, :] + sc[..., :, None] * v_mm * sc[..., None, :]),
            "g_gm": -(mu_g[:, None, :, None] * x_m[:, :, None, :] + jnp.swapaxes(s_v_mg, -1, -2)),
            "g_gg": -0.5 * (mu_g[:, :, None] * mu_g[:, None, :] + v_gg),
            "prior_var_g": 0.5 * (mu_g**2 + jnp.diagonal(v_gg, axis1=-2, axis2=-1)) / a["prior_var_g"] ** 2,
        }
        return ct * grad_sc, {k: ct * grads[k] for k in a}

    integrated.defvjp(forward, backward)
    return integrated


def factor_blocks(sc, a, xp):
    """The one factorisation of the posterior precision that every path shares (the marginal
    likelihood and its gradient, the conditional draws, the leave-one-out densities).

    ``sc``: slot scales ``(..., K, M, B)``; ``a``: the weighted Gram arrays (:func:`.excess.weighted`),
    leading dims broadcast (draws).  With ``P_mm = I + S G_mm S = L_m L_m'``, returns ``L_m``,
    ``L_m^-1``, ``Y_g = L_m^-1 S G_mg``, ``y_b = L_m^-1 S b_m`` and the factor ``L_s`` of the Schur
    complement ``G_gg + D - Y_g' Y_g`` (summed over cameras).
    """
    g_mg = xp.swapaxes(a["g_gm"], -1, -2)  # (..., K, M, B, G)
    p_mm = sc[..., :, None] * a["g_mm"] * sc[..., None, :] + xp.eye(sc.shape[-1])
    l_m = xp.linalg.cholesky(p_mm)
    inv_l = inverse_lower(l_m, xp)
    y_g = inv_l @ (sc[..., :, None] * g_mg)  # L_m^-1 P_mg
    y_b = xp.einsum("...ij,...j->...i", inv_l, sc * a["b_m"])
    schur = a["g_gg"] + _diag(1.0 / a["prior_var_g"], xp) - xp.einsum("...mbg,...mbh->...gh", y_g, y_g)
    return l_m, inv_l, y_g, y_b, xp.linalg.cholesky(schur)


def inverse_lower(low, xp):
    """``L^-1`` of batched lower-triangular factors."""
    return solve_lower(low, xp.broadcast_to(xp.eye(low.shape[-1]), low.shape), xp)


def integrated_value(sc, a):
    """The value of :func:`_integrated` and the pieces its gradient reuses (JAX; reverse-mode
    differentiable too, which is the slower path the closed form replaces)."""
    import jax.numpy as jnp

    l_m, inv_l, y_g, y_b, l_s = factor_blocks(sc, a, jnp)
    inv_s = inverse_lower(l_s, jnp)
    v = jnp.einsum("kgh,kh->kg", inv_s, a["b_g"] - jnp.einsum("kmbg,kmb->kg", y_g, y_b))
    mu_g = jnp.einsum("khg,kh->kg", inv_s, v)
    mu_m = jnp.einsum("kmji,kmj->kmi", inv_l, y_b - jnp.einsum("kmbg,kg->kmb", y_g, mu_g))
    logdet = 2.0 * jnp.sum(jnp.log(jnp.diagonal(l_m, axis1=-2, axis2=-1))) + 2.0 * jnp.sum(
        jnp.log(jnp.diagonal(l_s, axis1=-2, axis2=-1))
    )
    value = 0.5 * (jnp.sum(y_b * y_b) + jnp.sum(v * v)) - 0.5 * logdet - 0.5 * jnp.sum(a["yy"])
    return value, (inv_l, y_g, inv_s, mu_g, mu_m)


def factorise(plan, sc, a, xp):
    """What the conditional draws and the leave-one-out densities read, from :func:`factor_blocks`.

    ``sc``: ``(..., K, M, B)``; ``a``: the weighted Gram arrays (:func:`.excess.weighted`), leading
    dims broadcast (draws).  Returns ``S b_m``, the factors of ``P_mm`` and of the Schur
    complement, the reduced global vector, ``P_gm`` and ``P_mm^-1 P_mg``.
    """
    l_m, inv_l, y_g, y_b, l_s = factor_blocks(sc, a, xp)
    x_mg = xp.swapaxes(inv_l, -1, -2) @ y_g  # P_mm^-1 P_mg, (..., K, M, B, G)
    b_g2 = a["b_g"] - xp.einsum("...mbg,...mb->...g", y_g, y_b)  # b_g - P_gm P_mm^-1 S b_m
    return sc * a["b_m"], l_m, l_s, b_g2, a["g_gm"] * sc[..., None, :], x_mg


def _diag(v, xp):
    return v[..., :, None] * xp.eye(v.shape[-1])


def solve_lower(low, b, xp, transpose: bool = False):
    """``L^-1 b`` (``L'^-1 b`` with ``transpose``) for batched lower factors and matrix ``b``."""
    if xp is np:
        return np.linalg.solve(np.swapaxes(low, -1, -2) if transpose else low, b)
    import jax.scipy.linalg as jsl

    return jsl.solve_triangular(low, b, lower=True, trans=1 if transpose else 0)


def solve_chol(low, b, xp=np):
    """``(L L')^-1 b`` for batched lower factors; ``b`` a vector or a matrix per factor."""
    vector = b.ndim == low.ndim - 1
    rhs = b[..., None] if vector else b
    out = solve_lower(low, solve_lower(low, rhs, xp), xp, transpose=True)
    return out[..., 0] if vector else out
