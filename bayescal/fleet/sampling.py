"""Sampling the fleet hierarchy: NUTS on the scales, exact Gaussian draws of the rest.

NUTS samples only the hierarchy's scales on their marginal likelihood
(:func:`.marginal.log_marginal`); each draw of the scales is then completed by one
draw of every other quantity from its Gaussian conditional.  The programs are
compiled once per model structure (:class:`.plan.Plan` and array shapes) with the
data as arguments, and chains run vectorised.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import lru_cache
from typing import Any

import numpy as np

from bayescal._config import computes
from bayescal.fleet.conditional import conditional_draws, draw_scales, latent_draws, standard_normals
from bayescal.fleet.excess import excess_of, log_det_t, scale_directions
from bayescal.fleet.marginal import log_marginal
from bayescal.fleet.plan import FleetData, Plan
from bayescal.fleet.spec import FleetSpec
from bayescal.inference.chains import attempt_seed, map_chains, with_retries
from bayescal.inference.laplace import find_map
from bayescal.inference.phases import Phased, run_phases
from bayescal.inference.program import Objective
from bayescal.model.spec import InferenceSpec

__all__ = ["sample_fleet", "FleetDraws", "laplace_start", "loo_of", "unit_log_likelihood"]


@dataclass(frozen=True, eq=False)
class FleetDraws:
    """Posterior draws of the hierarchy (standardised units), ``(chain, draw, ...)``.

    ``diagnostics``: ``divergences``, ``gradients`` (evaluations of the potential's gradient,
    warmup and every run included), ``max_rhat``, ``min_ess_bulk``, ``min_ess_tail``
    (over the sampled scales and every unit's quantities).
    """

    draws: dict[str, np.ndarray]
    log_likelihood: np.ndarray  # (chain, draw, unit), given each draw's latents (loo_of integrates them out)
    diagnostics: dict


def scale_priors(plan: Plan) -> dict[str, float | np.ndarray]:
    """The half-normal prior scale of every sampled scale of stage two (of ``kappa - 1`` for the
    excess: one per kind and direction, :meth:`~.plan.Plan.excess_priors`)."""
    return {
        "sigma_camera": plan.spread_prior,
        "sigma_channel": plan.spread_prior,
        "rate_sd": plan.rate_prior,
        "walk_sd": plan.walk_prior,
        "jitter_sd": plan.jitter_prior,
        "excess": plan.excess_priors(),
    }


def _log_scales(plan: Plan, u, interval, xp=np) -> dict:
    """Unconstrained ``u`` to the log of each scale (of ``kappa - 1`` for the excess).

    Where a kind has both a random walk and a campaign jitter, ``u`` holds, per kind, the log of
    their total sd ``s`` over the units' mean campaign interval ``d`` (``interval``, years,
    ``FleetData.walk_interval``: traced, so fleets of one structure share the compiled programs)
    and their log ratio ``q``::

        s = 1/2 log(walk^2 d + jitter^2),   q = log(walk sqrt(d) / jitter)

    The campaigns measure the total well and the split poorly: in the scales' own logs this is
    a curved ridge (``walk^2 d + jitter^2`` about constant), in ``(s, q)`` a straight one.  The map
    from ``(s, q)`` to the two logs has Jacobian determinant -1, so the density is unchanged.
    """
    out, i = {}, 0
    for name, size in plan.sampled().items():
        out[name] = u[..., i : i + size]
        i += size
    if plan.walk and plan.jitter:
        s, q = out["walk_sd"], out["jitter_sd"]
        out["walk_sd"] = s + 0.5 * _log_sigmoid(2.0 * q, xp) - 0.5 * xp.log(interval)
        out["jitter_sd"] = s + 0.5 * _log_sigmoid(-2.0 * q, xp)
    return out


def _log_sigmoid(x, xp):
    return -xp.logaddexp(0.0, -x)


def _unpack(plan: Plan, u, interval, xp=np) -> dict:
    """Unconstrained ``u`` (:func:`_log_scales`) to the scales."""
    return _exp(_log_scales(plan, u, interval, xp), xp)


def _exp(logs: dict, xp) -> dict:
    """The scales of their logs (``kappa = 1 + exp`` for the excess)."""
    return {name: 1.0 + xp.exp(v) if name == "excess" else xp.exp(v) for name, v in logs.items()}


@lru_cache(maxsize=16)
def _potential(plan: Plan):
    """The potential of stage two: minus the log posterior density of the unconstrained scales
    ``u`` (HalfNormal priors, with the log Jacobian), ``potential(u, arrays)``."""
    import jax.numpy as jnp
    from jax.scipy.stats import norm

    priors = scale_priors(plan)

    def potential(u, arrays):
        logs = _log_scales(plan, u, arrays["walk_interval"], jnp)
        lp: Any = 0.0
        for name, v in logs.items():  # HalfNormal(prior) on each scale (on kappa - 1), with the log Jacobian
            lp = lp + jnp.sum(norm.logpdf(jnp.exp(v), 0.0, priors[name]) + v)
        return -(lp + log_marginal(plan, _exp(logs, jnp), arrays))

    return potential


@lru_cache(maxsize=16)
def _objective(plan: Plan) -> Objective:
    """The potential with its gradient and Hessian, compiled once per structure."""
    return Objective.of(_potential(plan))


def laplace_start(plan: Plan, arrays: dict) -> tuple[np.ndarray, np.ndarray] | None:
    """The mode of the scales' posterior (the camera's mode search,
    :func:`bayescal.inference.laplace.find_map`, on the unconstrained scales) and the inverse of the
    potential's Hessian there; ``None`` when the search fails or the Hessian is not positive definite
    (the sampler then starts as it would without it).

    NUTS starts from draws of this normal, with its variances as the first diagonal mass
    matrix: with the latents integrated out the scales' posterior is close to it in the bulk,
    and warmup then spends its iterations on the step size, not on finding the posterior.
    """
    objective = _objective(plan)
    dim = sum(plan.sampled().values())
    mode, converged, _ = find_map(objective, arrays, np.full(dim, np.log(0.5)))
    mode = np.asarray(mode)
    h = np.asarray(objective.hessian(mode, arrays))
    if not (converged and np.all(np.isfinite(mode)) and np.all(np.isfinite(h))):
        return None
    w, v = np.linalg.eigh(0.5 * (h + h.T))
    if w.min() <= 0.0:
        return None
    return mode, (v / w) @ v.T


#: conditional draws per call of the compiled program (its memory: ~80 kB per draw and camera)
DRAW_CHUNK = 256


@lru_cache(maxsize=16)
def _latent_program(plan: Plan):
    """``latent_draws`` compiled once per structure, for a chunk of :data:`DRAW_CHUNK` draws."""
    import jax
    import jax.numpy as jnp

    return jax.jit(lambda sc, kappa, arrays, z_g, z_m: latent_draws(plan, sc, kappa, arrays, z_g, z_m, jnp))


def _latents(plan: Plan, hyper: dict, args: dict, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """:func:`.conditional.conditional_draws` (the same normal variates, so the same draws) by the compiled
    program, in chunks of :data:`DRAW_CHUNK` draws (the last one padded), one chunk per core at a time."""
    import jax

    sc, kappa = draw_scales(plan, hyper, args)
    z_g, z_m = standard_normals(plan, sc.shape[0], rng)
    program = _latent_program(plan)
    arrays = jax.device_put(args)
    s = sc.shape[0]

    def chunk(i: int) -> list[np.ndarray]:
        idx = np.minimum(np.arange(i, i + DRAW_CHUNK), s - 1)  # pad with the last draw
        out = jax.block_until_ready(program(sc[idx], kappa[idx], arrays, z_g[idx], z_m[idx]))
        return [np.asarray(o)[: min(DRAW_CHUNK, s - i)] for o in out]

    parts = map_chains(lambda k: chunk(k * DRAW_CHUNK), -(-s // DRAW_CHUNK))
    return np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts])


def _run_chains(plan: Plan, spec: FleetSpec, args: dict, seed: int, inference: InferenceSpec | None = None) -> Phased:
    """Every chain by the inference layer's phased NUTS (:func:`bayescal.inference.phases.run_phases`):
    unconstrained draws ``(chain, draw, dim)``, their divergent transitions and the gradient
    evaluations of warmup and draws.

    The chains start from draws of the Laplace approximation at the mode (:func:`laplace_start`),
    whose variances are the diagonal mass matrix throughout; warmup adapts the step size toward
    ``spec.target_accept``.  With ``inference``, while the sampled scales' bulk or tail ESS (of the
    scales, as the verdict judges them, not their logs) is below its ``min_ess`` or their R-hat above
    its ``max_rhat``, every chain continues for another ``spec.draws`` draws, ``spec.extend`` times at
    most: a posterior ridge (a drift that is either trend or walk) mixes slowly on some seeds, and
    more draws, not a failed fit, are the remedy.  What was measured against other warmups, dense
    masses and other coordinates is in ``benchmarks/results/fleet_speed.md``.
    """
    import jax

    dim = sum(plan.sampled().values())
    arrays = {k: jax.numpy.asarray(v) for k, v in args.items()}
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0x57A27]))
    start = laplace_start(plan, arrays)
    if start is None:  # no usable mode: dispersed starts about scales of 0.5 and a unit mass matrix
        u0, imm = np.log(0.5) + rng.uniform(-0.5, 0.5, (spec.chains, dim)), np.ones(dim)
    else:
        u0, imm = rng.multivariate_normal(start[0], start[1], size=spec.chains), np.diag(start[1])

    def mixed(z: np.ndarray) -> bool:  # the scales as the verdict judges them
        assert inference is not None
        return _mixed(_convergence(_unpack(plan, z, args["walk_interval"])), inference)

    return run_phases(
        _potential(plan),
        arrays,
        u0,
        imm,
        warmup=spec.warmup,
        draws=spec.draws,
        target_accept=spec.target_accept,
        seed=seed,
        extend=spec.extend if inference is not None else 0,
        mixed=mixed if inference is not None else None,
    )


@computes
def sample_fleet(
    data: FleetData, plan: Plan, spec: FleetSpec, seed: int = 0, inference: InferenceSpec | None = None
) -> FleetDraws:
    """Run NUTS on the scales, complete every draw, and judge the chains (R-hat, ESS, divergences).

    With ``inference`` the chains continue (``spec.extend`` times at most) while the scales miss
    its ``min_ess`` or ``max_rhat``, and chains with a divergent transition are run again (new
    chains) by the retry policy a unit's own NUTS fit follows
    (:func:`bayescal.inference.chains.with_retries`); the diagnostics then say
    ``first_divergences`` and ``retried_at``.
    """

    args = data.arrays()
    chains, n = spec.chains, spec.draws
    sampled = plan.sampled()
    first, retried_at = None, 0.0
    if sampled:
        runs: list[Phased] = []

        def attempt(_items, target: float, k: int) -> list[Phased]:  # new chains, smaller steps on a rerun
            runs.append(_run_chains(plan, replace(spec, target_accept=target), args, attempt_seed(seed, k), inference))
            return runs[-1:]

        retry = inference.retry_target_accept if inference is not None else 0.0
        (done,) = with_retries(attempt, 1, spec.target_accept, retry, lambda r: (r.divergences, r.z[..., 0].size))
        z, divergences = done.out.z, done.out.divergences
        gradients = sum(r.gradients for r in runs)
        first, retried_at = (done.first_divergences, done.rerun_at) if done.rerun_at else (None, 0.0)
        n = z.shape[1]
        hyper = _unpack(plan, z.reshape(chains * n, -1), args["walk_interval"])
    else:  # nothing to sample: the conditional draws are the posterior
        hyper = {}
        divergences = gradients = 0
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0xF1EE7]))
    if not hyper:
        parts = [conditional_draws(plan, {}, args, rng) for _ in range(chains * n)]
        g, cam = np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts])
    else:
        g, cam = _latents(plan, hyper, args, rng)
    draws = {k: v.reshape(chains, n, -1) for k, v in hyper.items()}
    kappa = excess_of(plan, hyper, draws=chains * n)
    named = _named(plan, data, np.asarray(g), np.asarray(cam), kappa)
    draws |= {k: v.reshape((chains, n) + v.shape[1:]) for k, v in named.items()}
    ll = unit_log_likelihood(
        plan,
        data,
        draws["unit_reported" if plan.shared else "theta_observed"].reshape(
            (chains * n,) + draws["theta_observed"].shape[2:]
        ),
        kappa,
    )
    judged = _convergence({k: draws[k] for k in [*sampled, "theta"]})
    diagnostics = {"divergences": divergences, "gradients": gradients} | judged
    if first is not None:  # the retry's diagnostics decide the verdict; the first run's count is kept
        diagnostics["first_divergences"] = first
        diagnostics["retried_at"] = retried_at
    return FleetDraws(draws, ll.reshape(chains, n, -1), diagnostics)


def _named(plan: Plan, data: FleetData, g: np.ndarray, cam: np.ndarray, kappa: np.ndarray) -> dict[str, np.ndarray]:
    """The latents by name: ``mu (S, K, C)``, ``camera_level (S, K, M, C)``, ``rate_mean (S, 2)``,
    ``rate (S, 2, M)``, ``walk (S, 2, U)``, ``sphere_log_scale (S, J)``, ``theta`` and
    ``theta_observed (S, K, U, C)`` (the sphere's factor added to the log gain); ``kappa``
    ``(S, K, D)`` scales the camera's shared error (``T L e``)."""
    gs, ms = plan.g, plan.m
    mu = g[:, :, gs.mu]
    level = mu[:, :, None, :] + cam[:, :, :, ms.a, None] + cam[:, :, :, ms.b]  # (S, K, M, C)
    out = {"mu": mu, "camera_level": level}
    theta = level[:, :, data.camera, :].copy()  # (S, K, U, C)
    if plan.drift:
        rate = g[:, :2, gs.rho, None] + cam[:, :2, :, ms.r]  # (S, 2, M)
        out["rate_mean"] = g[:, :2, gs.rho]
        out["rate"] = rate
        drift = rate[:, :, data.camera] * data.t[None, None, :]
        if plan.walk:
            walk = np.zeros((g.shape[0], 2, plan.n_units))
            for j, v in enumerate(data.walk_units):
                m = data.camera[v]
                step = cam[:, :2, m, ms.walk.start + data.walk_slot[j]] * np.sqrt(data.walk_dt[j])
                later = np.flatnonzero((data.camera == m) & (data.years >= data.years[v]))
                walk[:, :, later] += step[:, :, None]
            out["walk"] = walk
            drift = drift + walk
        if plan.jitter:
            jitter = np.stack(
                [cam[:, :2, data.camera[u], ms.jitter.start + data.unit_slot[u]] for u in range(plan.n_units)], axis=-1
            )
            out["jitter"] = jitter  # (S, 2, U)
            drift = drift + jitter
        theta[:, :2] += drift[..., None]
    sphere = g[:, 0, gs.sphere]
    out["sphere_log_scale"] = sphere
    state = None
    if plan.n_campaigns:  # a common effect on every gain measured in a campaign, not extrapolated
        state = g[:, 0, gs.campaign]
        out["campaign_state"] = state
    if plan.shared:  # the camera's repeating error: not the camera, but in what its units report
        unscaled = np.einsum("kmcd,skmd->smkc", data.shared_chol, cam[:, :, :, ms.shared])
        out["shared_error"] = np.swapaxes(scale_directions(plan, unscaled, kappa[:, None]), 1, 2)  # (S, K, M, C)
    out["theta"] = theta
    observed = theta.copy()
    observed[:, 0] += sphere[:, data.sphere][..., None]
    if state is not None:
        observed[:, 0] += state[:, data.campaign][..., None]
    out["theta_observed"] = observed
    if plan.shared:
        out["unit_reported"] = observed + out["shared_error"][:, :, data.camera, :]
    return out


def unit_log_likelihood(plan: Plan, data: FleetData, theta_observed: np.ndarray, kappa: np.ndarray) -> np.ndarray:
    """``log N(y_u | theta_u, T Sigma_u T)`` per draw and unit, ``(S, U)`` (``kappa`` ``(S, K, D)``)."""
    s, k, u, c = theta_observed.shape
    resid = data.y.reshape(1, u, k, c) - np.transpose(theta_observed, (0, 2, 1, 3))
    white = scale_directions(plan, resid, kappa[:, None], inverse=True).reshape(s, u, k * c)  # T^-1 r
    inv_l = np.linalg.inv(data.chol)  # (U, KC, KC)
    z = np.einsum("uqr,sur->suq", inv_l, white)
    logdet = (
        np.sum(np.log(np.diagonal(data.chol, axis1=1, axis2=2)), axis=1)[None]
        + np.sum(log_det_t(plan, kappa), axis=1)[:, None]
    )
    return -0.5 * np.sum(z**2, axis=2) - logdet - 0.5 * k * c * np.log(2 * np.pi)


def _convergence(values: dict[str, np.ndarray]) -> dict:
    """Largest R-hat and smallest bulk and tail ESS over ``(chain, draw, ...)`` arrays (the numbers
    of :func:`bayescal.inference.diagnostics.convergence`; R-hat is NaN for one chain)."""
    from bayescal.inference.diagnostics import convergence

    rhat, bulk, tail = convergence(values)
    return {"max_rhat": rhat, "min_ess_bulk": bulk, "min_ess_tail": tail}


def _mixed(d: dict, inference: InferenceSpec) -> bool:
    """The chains' ESS and R-hat pass the verdict's bounds (R-hat unjudged for one chain, as in the fleet's verdict)."""
    rhat_ok = not (np.isfinite(d["max_rhat"]) and d["max_rhat"] > inference.max_rhat)
    return rhat_ok and min(d["min_ess_bulk"], d["min_ess_tail"]) >= inference.min_ess


def loo_of(plan: Plan, data: FleetData, draws: FleetDraws) -> dict:
    """PSIS leave-one-unit-out: ``elpd_loo``, its ``se``, ``p_loo``, units with Pareto k > 0.7 and
    arviz's ``ELPDData`` (``"elpd_data"``, what :func:`arviz_stats.compare` ranks).

    Each draw of the scales contributes ``log p(y_u | y_-u, h)`` with every latent integrated
    out (:mod:`.loo`), so the importance weights only move the scales; ``p_loo`` is the
    log pointwise predictive density of the draws' conditional likelihood minus ``elpd_loo``.
    """
    import arviz_base
    import arviz_stats

    from bayescal.fleet.loo import loo_predictive

    ll = draws.log_likelihood
    chains, n = ll.shape[:2]
    hyper = {k: draws.draws[k].reshape(chains * n, -1) for k in plan.sampled()}
    sc, kappa = draw_scales(plan, hyper, data.arrays())
    if not hyper:  # nothing sampled: one set of scales for every draw
        sc, kappa = np.repeat(sc, chains * n, axis=0), np.repeat(kappa, chains * n, axis=0)
    pred = loo_predictive(plan, data, sc, kappa).reshape(chains, n, -1)
    tree = arviz_base.from_dict({"posterior": {"dummy": np.zeros((chains, n))}, "log_likelihood": {"y": pred}})
    loo = arviz_stats.loo(tree, pointwise=True)
    flat = ll.reshape(chains * n, -1)
    lppd = float(np.sum(np.logaddexp.reduce(flat, axis=0) - np.log(flat.shape[0])))
    return {
        "elpd_loo": float(loo.elpd),
        "se": float(loo.se),
        "p_loo": lppd - float(loo.elpd),
        "n_high_k": int(np.sum(np.asarray(loo.pareto_k) > 0.7)),
        "pointwise": np.asarray(loo.elpd_i),
        "elpd_data": loo,
    }
