"""MAP with optimistix and a Gaussian at the mode (the ``laplace`` backend).

The mode is found by BFGS in the unconstrained space; the Gaussian's
precision is the exact Hessian of the negative log posterior there (jax).
For a linear-Gaussian model (linear response, known noise, normal priors)
this *is* the posterior (docs/architecture.md, section 4).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from bayescal._config import computes
from bayescal.inference.program import Program, ProgramData, Smooth

__all__ = [
    "LaplaceResult",
    "find_map",
    "laplace",
    "laplace_many",
    "laplace_draws",
    "integrated_draws",
    "covariance_factor",
]


@dataclass(frozen=True)
class LaplaceResult:
    """Mode and covariance in the flat unconstrained space."""

    mode: np.ndarray
    cov: np.ndarray
    potential: float
    converged: bool
    steps: int
    positive_definite: bool


@computes
def find_map(
    program: Program | Smooth,
    data: ProgramData,
    z0: np.ndarray | jax.Array | None = None,
    rounds: int = 4,
    polish: bool = True,
):
    """Minimise the potential: damped Newton steps in Hessian-whitened coordinates, BFGS rounds if needed.

    The one mode search of a camera's fit and of the fleet's stage two: ``program`` is a model's
    :class:`~bayescal.inference.program.Program` or any :class:`~bayescal.inference.program.Smooth`
    potential (then ``z0`` is required).

    Calibration likelihoods are stiff (row precisions ~1e7 in scaled units against O(1) prior
    scales), which stalls plain gradient methods.  Each Newton step whitens with the exact
    Hessian at the current point, ``P = V |Lambda|^(-1/2)`` (absolute eigenvalues, floored:
    a saddle-free step that goes downhill where the potential is not convex), steps
    ``-P P' g`` with a backtracking line search, and stops when the Newton decrement
    ``|P' g|^2`` is negligible.  It uses only the program's value, gradient and Hessian, which
    every fit compiles anyway.  Should it not converge in :data:`NEWTON_STEPS` steps (a start on
    a plateau far from the mode), up to ``rounds`` rounds of BFGS in the whitened coordinates
    take over from where it stopped.  ``polish=False`` stops as soon as the mode counts as
    converged (squared decrement below :data:`CONVERGED_DECREMENT`: the potential within 5e-9 of its
    minimum, the mode within 1e-4 posterior sds), without the full steps that take it to rounding
    level: what a check that compares readings with several sds needs (the leave-one-setting-out
    refits of :mod:`bayescal.fitting.holdout`).

    Returns ``(z_map, converged, steps)``.
    """
    z, converged, steps, _ = _search(program, data, z0, rounds, polish)
    return z, converged, steps


def _search(program, data, z0, rounds: int, polish: bool):
    """:func:`find_map`, with the potential's value and Hessian at the mode: ``(z, converged, steps,
    (value, hess))``, the last None where the search stopped at a point it did not evaluate."""
    if z0 is None:
        if not isinstance(program, Program):
            raise TypeError("find_map needs a start z0 for a potential that is not a model's program")
        z0 = program.z0
    z = np.asarray(z0, dtype=float)
    z, converged, steps, at = _newton(program, data, z, POLISH_STEPS if polish else 0)
    if converged:
        return jnp.asarray(z), True, steps, at
    hess = _at(program, z, data)[2]
    zj = jnp.asarray(z)
    for _ in range(rounds):
        precond = _whitening(hess)
        sol = _whitened_bfgs()(program.potential, zj, jnp.asarray(precond), data)
        steps += int(sol.stats["num_steps"])
        zj = zj + jnp.asarray(precond) @ sol.value
        value, grad, hess = _at(program, np.asarray(zj), data)
        step = precond.T @ grad  # gradient in whitened coordinates = Newton step length
        if float(step @ step) < 1e-8:
            return zj, True, steps, (value, hess)
    return zj, converged, steps, None


#: Newton steps before the BFGS rounds take over
NEWTON_STEPS = 60
#: the longest Newton step, in local posterior standard deviations (whitened units)
MAX_STEP_SD = 10.0
#: Newton stops below this squared Newton decrement (half the potential still to gain): far below the
#: 1e-8 that counts as converged, since near the mode each step squares the error (one more step, ~1 ms)
NEWTON_DECREMENT = 1e-14
#: a mode is converged when its squared Newton decrement is below this
CONVERGED_DECREMENT = 1e-8
#: full Newton steps that polish a converged mode
POLISH_STEPS = 2
#: the whitening's eigenvalue floor, relative to the largest: a Hessian's eigenvalues are accurate to
#: ~1e-16 of the largest, and calibration Hessians span 12 decades (dark rows ~1e12 in scaled units
#: against an excess-scatter scale near 1), so a floor of 1e-10 there would take 87 for 2 and turn
#: Newton's quadratic convergence into ~2 % per step
EIGENVALUE_FLOOR = 1e-13


def _newton(
    program: Program | Smooth, data: ProgramData, z: np.ndarray, polish_steps: int = POLISH_STEPS
) -> tuple[np.ndarray, bool, int, tuple[float, np.ndarray] | None]:
    """Damped saddle-free Newton from ``z``: ``(z, converged, steps, (value, Hessian) at z or None)``.

    Once the squared Newton decrement is below :data:`CONVERGED_DECREMENT` the iterate is in the
    quadratic regime: up to ``polish_steps`` full steps then polish it (no line search, whose
    test would be decided by the rounding of the potential there) while they still shrink the
    decrement below :data:`NEWTON_DECREMENT`.
    """
    value, grad, hess = _at(program, z, data)
    polish = 0
    for step in range(NEWTON_STEPS):
        if not (np.isfinite(value) and np.all(np.isfinite(grad))):
            return z, False, step, None
        precond = _whitening(hess)
        g_w = precond.T @ grad  # the gradient in whitened coordinates
        decrement = float(g_w @ g_w)
        polished = polish == polish_steps if polish_steps else decrement < CONVERGED_DECREMENT
        if decrement < NEWTON_DECREMENT or polished:
            return z, decrement < CONVERGED_DECREMENT, step, (value, hess)
        direction = -(precond @ g_w)
        if decrement < CONVERGED_DECREMENT:  # quadratic regime: a full step
            trial = z + direction
            v, g, h = _at(program, trial, data)
            if not (np.isfinite(v) and np.all(np.isfinite(g))):
                return z, True, step, (value, hess)
            polish += 1
            z, value, grad, hess = trial, v, g, h
            continue
        t = min(1.0, MAX_STEP_SD / np.sqrt(decrement))
        while t > 1e-12:
            trial = z + t * direction
            v, g, h = _at(program, trial, data)
            if np.isfinite(v) and v <= value - 1e-4 * t * decrement:
                break
            t *= 0.5
        else:  # no step decreases the potential: leave it to BFGS
            return z, False, step, None
        z, value, grad, hess = trial, v, g, h
    return z, False, NEWTON_STEPS, None


def _at(program: Program | Smooth, z: np.ndarray, data: ProgramData) -> tuple[float, np.ndarray, np.ndarray]:
    """The potential's value, gradient and Hessian at ``z`` on the host (one program: the Hessian at a
    line search's trial point costs little more than its value and gradient, and an accepted trial,
    the usual case, needs it for the next step)."""
    value, grad, hess = program.derivatives(z, data)
    return float(value), np.asarray(grad), np.asarray(hess)


def _whitening(hess, xp=np):
    """``P`` with ``P' H P`` the identity for the symmetrised Hessian ``H``, from its eigenvalues'
    magnitudes floored at :data:`EIGENVALUE_FLOOR` of the largest; the identity where ``H`` is
    not finite.  Written once for numpy (one fit at a time) and ``jax.numpy`` (the vmapped search)."""
    hess = 0.5 * (hess + hess.T)
    finite = xp.all(xp.isfinite(hess))
    w, v = xp.linalg.eigh(xp.where(xp.isfinite(hess), hess, 0.0))
    w = xp.maximum(xp.abs(w), EIGENVALUE_FLOOR * xp.maximum(xp.abs(w).max(), 1.0))
    return xp.where(finite, v / xp.sqrt(w), xp.eye(hess.shape[0]))


@lru_cache(maxsize=1)
def _whitened_bfgs():
    """The jitted BFGS round in whitened coordinates (built on first use: optimistix is imported only
    by a fit whose Newton steps did not converge)."""
    import optimistix as optx

    solver: Any = optx.BFGS(rtol=1e-12, atol=1e-12)

    def run(potential, z_c, precond, data):
        fn = lambda w, args: potential(args[0] + args[1] @ w, args[2])
        w0 = jnp.zeros_like(z_c)
        return optx.minimise(fn, solver, w0, args=(z_c, precond, data), max_steps=500, throw=False)

    return jax.jit(run, static_argnums=0)


@lru_cache(maxsize=16)
def _batched_newton(program: Program):
    """Jitted, vmapped Newton search of :func:`find_map`: ``(z0 (B, d), data (B, ...)) -> (z, value, Hessian,
    squared Newton decrement, steps)``.

    The steps of :func:`_newton` (saddle-free, whitened by the Hessian, at most :data:`MAX_STEP_SD` long,
    backtracked on the potential's value alone, full steps once the decrement is below
    :data:`CONVERGED_DECREMENT`, :data:`POLISH_STEPS` of them), as one loop over the batch: a dataset that
    has stopped is held where it is while the others go on.  A search that stalls (no step lowers the
    potential) stops unconverged; :func:`laplace_many` searches it again one by one.
    """

    def whiten(hess, grad):
        precond = _whitening(hess, jnp)
        g_w = precond.T @ grad
        return precond, g_w @ g_w

    def one(z, data):
        value, grad, hess = program.derivatives(z, data)
        precond, decrement = whiten(hess, grad)

        def going(c):
            z, value, grad, hess, precond, decrement, steps, polish, stuck = c
            finite = jnp.isfinite(value) & jnp.all(jnp.isfinite(grad))
            return finite & ~stuck & (decrement >= NEWTON_DECREMENT) & (polish < POLISH_STEPS) & (steps < NEWTON_STEPS)

        def step(c):
            z, value, grad, hess, precond, decrement, steps, polish, _ = c
            direction = -(precond @ (precond.T @ grad))
            quadratic = decrement < CONVERGED_DECREMENT
            t0 = jnp.where(quadratic, 1.0, jnp.minimum(1.0, MAX_STEP_SD / jnp.sqrt(decrement)))

            def shorter(s):
                return ~s[1] & (s[0] > 1e-12)

            def halve(s):
                t = s[0]
                v = program.potential(z + t * direction, data)
                ok = jnp.isfinite(v) & (quadratic | (v <= value - 1e-4 * t * decrement))
                return jnp.where(ok, t, 0.5 * t), ok

            t, ok = jax.lax.while_loop(shorter, halve, (t0, jnp.asarray(False)))
            trial = z + t * direction
            v, g, h = program.derivatives(trial, data)
            moved = ok & jnp.isfinite(v) & jnp.all(jnp.isfinite(g))
            z, value = jnp.where(moved, trial, z), jnp.where(moved, v, value)
            grad, hess = jnp.where(moved, g, grad), jnp.where(moved, h, hess)
            precond, decrement = whiten(hess, grad)
            return z, value, grad, hess, precond, decrement, steps + 1, polish + quadratic, ~moved

        start = (z, value, grad, hess, precond, decrement, 0, 0, jnp.asarray(False))
        z, value, _, hess, _, decrement, steps, _, _ = jax.lax.while_loop(going, step, start)
        return z, value, hess, decrement, steps

    return jax.jit(jax.vmap(one))


@computes
def laplace(
    program: Program, data: ProgramData, z0: np.ndarray | jax.Array | None = None, polish: bool = True
) -> LaplaceResult:
    """Mode and Gaussian covariance (inverse Hessian) of the posterior, searched from ``z0``
    (``polish``: see :func:`find_map`)."""
    z_map, converged, steps, at = _search(program, data, program.z0 if z0 is None else z0, 4, polish)
    if at is None:
        value, _, hess = _at(program, np.asarray(z_map), data)
    else:
        value, hess = at
    return _gaussian_at(value, z_map, converged, steps, hess)


@computes
def laplace_many(
    program: Program, datas: list[ProgramData], starts: list[jax.Array], chunk: int = 16
) -> list[LaplaceResult]:
    """:func:`laplace` for many datasets of one structure, vectorised with ``jax.vmap``.

    The datasets are stacked along a leading axis and the Newton search of :func:`find_map` runs as
    one compiled program over batches of ``chunk`` datasets (the last one padded), compiled once per
    structure (:func:`_batched_newton`).  A dataset whose search stalls there is searched on by
    :func:`laplace` from the point it reached, where BFGS rounds take over from Newton.
    """
    run = _batched_newton(program)
    out: list[LaplaceResult] = []
    for first in range(0, len(datas), chunk):
        idx = list(range(first, min(first + chunk, len(datas))))
        padded = idx + [idx[-1]] * (chunk - len(idx))  # one batch size: one compilation
        stacked = jax.tree.map(lambda *xs: jnp.stack(xs), *(datas[i] for i in padded))
        z, value, hess, decrement, steps = (
            np.asarray(a) for a in run(jnp.stack([jnp.asarray(starts[i]) for i in padded]), stacked)
        )
        for k, i in enumerate(idx):
            if decrement[k] < CONVERGED_DECREMENT:
                out.append(_gaussian_at(float(value[k]), z[k], True, int(steps[k]), hess[k]))
            else:  # from where the batched Newton steps stalled, not their start again
                out.append(laplace(program, datas[i], z[k]))
    return out


def _gaussian_at(value: float, z_map, converged: bool, steps: int, hess: np.ndarray) -> LaplaceResult:
    """The Gaussian with precision ``hess`` at ``z_map``, where the potential is ``value``."""
    hess = 0.5 * (hess + hess.T)
    try:
        chol = np.linalg.cholesky(hess)
        inv_chol = np.linalg.solve(chol, np.eye(hess.shape[0]))
        cov = inv_chol.T @ inv_chol
        pd = True
    except np.linalg.LinAlgError:
        cov = np.linalg.pinv(hess)
        pd = False
    return LaplaceResult(
        mode=np.asarray(z_map),
        cov=cov,
        potential=float(value),
        converged=converged,
        steps=steps,
        positive_definite=pd,
    )


def laplace_draws(result: LaplaceResult, n: int, seed: int) -> np.ndarray:
    """``n`` draws of the flat unconstrained vector from the Gaussian."""
    rng = np.random.default_rng(seed)
    return result.mode + rng.standard_normal((n, result.mode.size)) @ covariance_factor(result.cov).T


def covariance_factor(cov: np.ndarray) -> np.ndarray:
    """``L`` with ``L L^T = cov``.  A singular, indefinite or non-finite ``cov`` (a failed mode,
    a hierarchical scale at its boundary) gets its eigenvalues' magnitudes floored at 1e-8 of
    the largest (non-finite entries zeroed) so that draws and whitening still run; the fit
    that produced it is reported as failed elsewhere."""
    try:
        return np.linalg.cholesky(cov)
    except np.linalg.LinAlgError:
        sym = np.nan_to_num(0.5 * (cov + cov.T), nan=0.0, posinf=0.0, neginf=0.0)
        w, v = np.linalg.eigh(sym)
        w = np.abs(w)
        w = np.maximum(w, 1e-8 * w.max()) if w.max() > 0 else np.full_like(w, 1e-12)
        return v * np.sqrt(w)


@computes
def integrated_draws(
    program: Program,
    data: ProgramData,
    result: LaplaceResult,
    index: int,
    n: int,
    seed: int,
    grid: int = 15,
    newton_steps: int = 6,
) -> tuple[np.ndarray, dict]:
    """Draws with one scale parameter integrated numerically, the rest Gaussian given it.

    The joint mode under-states a variance parameter (like maximum
    likelihood against REML: the other 30-odd coordinates are fitted at
    it), so a Gaussian at the joint mode is ~10 % too narrow for every
    coefficient whose noise that scale sets.  Here (an integrated nested
    Laplace approximation in one dimension) the scale's unconstrained
    coordinate ``theta = z[index]`` runs over a grid; at each point the
    rest is maximised by Newton steps and ``log p(theta | y) ~ -U(z*) -
    1/2 log det H_rest(z*)``; draws pick a grid cell by that weight, a
    ``theta`` uniformly inside it, and the rest from the conditional Gaussian.

    Returns ``(z_draws (n, dim), info)`` with the grid's weights.
    """
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0x1A91]))
    dim = result.mode.size
    rest = np.delete(np.arange(dim), index)
    sd = float(np.sqrt(result.cov[index, index]))
    step = 11.0 * sd / (grid - 1)
    found: dict[float, tuple] = {}

    # the rest's conditional mode moves with theta as the Gaussian's regression on it predicts: each grid
    # point starts from its nearest neighbour's mode moved along that slope (one Newton step fewer per point)
    slope = result.cov[:, index] / result.cov[index, index]

    def conditional(theta: float) -> None:
        nearest = min(found, key=lambda t: abs(t - theta), default=None)
        start = found[nearest][0] if nearest is not None else result.mode
        z = start + slope * (theta - start[index])
        z[index] = theta
        for step in range(newton_steps + 1):  # the value, gradient and Hessian at the point it stops at
            value, grad, hess = _at(program, z, data)
            hess_r = hess[np.ix_(rest, rest)]
            if step == newton_steps:
                break
            delta = np.linalg.solve(0.5 * (hess_r + hess_r.T), np.asarray(grad)[rest])
            if not float(delta @ hess_r @ delta) >= 1e-10:  # converged here (or not a number: judged below)
                break
            z[rest] -= delta
        try:
            chol_h = np.linalg.cholesky(0.5 * (hess_r + hess_r.T))
        except np.linalg.LinAlgError:
            found[theta] = (z, None, -np.inf)  # not a local maximum in the rest: no weight
            return
        u = float(value)
        if not (np.isfinite(u) and np.all(np.isfinite(z))):  # Newton left the density: no weight
            found[theta] = (z, None, -np.inf)
            return
        found[theta] = (z, chol_h, -u - np.sum(np.log(np.diag(chol_h))))

    if not (np.isfinite(sd) and sd > 0 and np.all(np.isfinite(result.mode))):
        return laplace_draws(result, n, seed), {"edge_weight": np.nan, "failed": "no finite mode or scale"}

    initial = result.mode[index] + step * (np.arange(grid) - 5.0 * (grid - 1) / 11.0)
    for theta in sorted(initial, key=lambda t: abs(t - result.mode[index])):  # outwards: warm starts
        conditional(float(theta))
    for _ in range(4):  # extend the grid while an edge still carries weight (a skewed scale posterior)
        items = sorted(found.items())
        thetas = np.array([t for t, _ in items])
        logp = np.array([v[2] for _, v in items])
        logp = np.where(np.isnan(logp), -np.inf, logp)  # a grid point whose density is not a number: no weight
        if not np.isfinite(logp.max()):
            break
        w = np.exp(logp - logp.max())
        w /= w.sum()
        grow = []
        if w[0] > 1e-3:
            grow += [thetas[0] - step * k for k in range(1, grid // 2 + 1)]
        if w[-1] > 1e-3:
            grow += [thetas[-1] + step * k for k in range(1, grid // 2 + 1)]
        if not grow:
            break
        for theta in grow:
            conditional(float(theta))
    keep = [t for t in sorted(found) if found[t][1] is not None and np.isfinite(found[t][2])]
    if not keep:  # no grid point is a proper conditional maximum: the Gaussian, flagged as failed
        return laplace_draws(result, n, seed), {"edge_weight": np.nan, "failed": "no grid point is a maximum"}
    thetas = np.array(keep)
    modes = np.array([found[t][0] for t in keep])
    chols = [found[t][1] for t in keep]
    logp = np.array([found[t][2] for t in keep])
    width = np.gradient(thetas) if thetas.size > 1 else np.full(1, sd)
    weights = np.exp(logp - logp.max()) * width
    weights /= weights.sum()
    cells = rng.choice(thetas.size, size=n, p=weights)
    theta = thetas[cells] + width[cells] * (rng.random(n) - 0.5)
    # conditional mode: linear between the grid's conditional modes
    k = np.clip(np.searchsorted(thetas, theta), 1, max(thetas.size - 1, 1))
    lo = np.maximum(k - 1, 0)
    frac = np.where(thetas[k] > thetas[lo], (theta - thetas[lo]) / np.maximum(thetas[k] - thetas[lo], 1e-300), 0.0)
    frac = np.clip(frac, 0.0, 1.0)[:, None]
    out = modes[lo] * (1 - frac) + modes[k] * frac
    out[:, index] = theta
    for c in np.unique(cells):
        pick = np.flatnonzero(cells == c)
        # conditional Gaussian N(mode, H_c^{-1}): z = mode + L^{-T} e with H = L L^T
        e = rng.standard_normal((pick.size, rest.size))
        out[np.ix_(pick, rest)] += np.linalg.solve(chols[c].T, e.T).T
    info = {
        "grid_theta": thetas.tolist(),
        "grid_weight": weights.tolist(),
        "edge_weight": float(weights[[0, -1]].max()),
    }
    return out, info
