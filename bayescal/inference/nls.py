"""Nonlinear least squares (optimistix Levenberg-Marquardt) with the Gaussian at the optimum.

For saturating or otherwise nonlinear sensor responses fitted the classical
way (docs/architecture.md, section 4, NIST StRD nonlinear problems).  Parameters are
rescaled by their starting values so the solver sees O(1) unknowns; the
residual function is jitted once per model function.  The covariance is
``s^2 (J^T J)^-1`` with ``s^2 = SSE / (n - p)`` -- the Laplace approximation
of the flat-prior posterior with the noise scale profiled, which is also the
classical asymptotic covariance.

Convergence is certified, not taken from the solver's word: the answer must
be a stationary point by the Bates-Watts relative offset (the residual's
component in the Jacobian's column space against the rest, below
``1e-3``; the gradient itself for a zero-residual fit), with a
full-rank Jacobian (positive curvature of the sum of squares).  A solve that
search also runs from ``|start|``, ``10 start`` and ``start / 10`` (a
stationary point far from the optimum is a local minimum the certificate
cannot see: on NIST Misra1b from -100 x the start, LM certifiably stops at
4e5 x the certified sum of squares); the lowest certified minimum is kept
and the others are noted, and a fit none of whose starts certifies is
reported ``converged = False`` with the reason.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from bayescal._config import computes

__all__ = ["NonlinearFit", "nonlinear_lsq"]


@dataclass(frozen=True)
class NonlinearFit:
    """Optimum, its standard errors, residual statistics and convergence."""

    coef: np.ndarray
    se: np.ndarray
    cov: np.ndarray
    sse: float
    rmse: float
    converged: bool
    steps: int
    why: str = ""
    rel_offset: float = float("nan")
    restarts: int = 0


@lru_cache(maxsize=64)
def _solver(model: Callable) -> tuple[Callable, Callable]:
    def residual(u, args):
        scale, x, y = args
        return model(u * scale, x) - y

    import optimistix as optx  # on first use: a fit that needs no nonlinear least squares never imports it

    solver: Any = optx.LevenbergMarquardt(rtol=1e-14, atol=1e-14)

    def run(u0, scale, x, y):
        sol: Any = optx.least_squares(residual, solver, u0, args=(scale, x, y), max_steps=5000, throw=False)
        return sol.value, sol.result == optx.RESULTS.successful, sol.stats["num_steps"]

    jac = jax.jacfwd(lambda b, x: model(b, x))
    return jax.jit(run), jax.jit(jac)


#: Bates-Watts relative offset below which a point is accepted as the least-squares optimum
REL_OFFSET_TOL = 1e-3


@computes
def nonlinear_lsq(model: Callable, x: np.ndarray, y: np.ndarray, start: np.ndarray, polish: int = 3) -> NonlinearFit:
    """Fit ``y = model(beta, x) + e`` by least squares from ``start``.

    ``model(beta, x)`` must be a JAX-traceable function (pass the same
    function object to reuse the compilation).  Levenberg-Marquardt runs in
    parameters scaled by ``|start|``, restarted from its own answer
    ``polish`` times (each restart rescales); the result is certified (see the
    module docstring) and, failing that, the search restarts from ``|start|``,
    ``10 start`` and ``start / 10``.  The covariance is formed from the
    Jacobian at the optimum by a QR decomposition.
    """
    run, jac = _solver(model)
    xj, yj = jnp.asarray(x, dtype=float), jnp.asarray(y, dtype=float)
    start = np.asarray(start, dtype=float)
    fits = [_solve(model, run, jac, xj, yj, c, polish) for c in (start, np.abs(start), 10.0 * start, start / 10.0)]
    best = max(fits, key=lambda f: (f.converged, -f.sse if np.isfinite(f.sse) else -np.inf))
    minima = sorted({round(f.sse / max(best.sse, np.finfo(float).tiny), 6) for f in fits if f.converged})
    note = best.why
    if len(minima) > 1:
        note = f"{len(minima)} distinct stationary points from the 4 starts; kept the lowest sum of squares"
    return NonlinearFit(**{**best.__dict__, "restarts": len(fits) - 1, "why": note})


def _solve(model, run, jac, x, y, beta: np.ndarray, polish: int) -> NonlinearFit:
    steps, solver_ok = 0, False
    for _ in range(1 + polish):
        scale = np.where(beta != 0, np.abs(beta), 1.0)
        u0 = jnp.asarray(np.where(beta < 0, -1.0, 1.0))
        value, success, n_steps = run(u0, jnp.asarray(scale), x, y)
        steps += int(n_steps)
        solver_ok = bool(success)
        new = np.asarray(value) * scale
        if np.allclose(new, beta, rtol=1e-15, atol=0):
            beta = new
            break
        beta = new
    resid = np.asarray(model(jnp.asarray(beta), x) - y)
    sse = float(resid @ resid)
    n, p = resid.size, beta.size
    j = np.asarray(jac(jnp.asarray(beta), x))
    nan = np.full((p, p), np.nan)
    if not (np.all(np.isfinite(beta)) and np.all(np.isfinite(j)) and np.isfinite(sse)):
        return NonlinearFit(beta, np.full(p, np.nan), nan, sse, float("nan"), False, steps, "non-finite parameters")
    q, r = np.linalg.qr(j)
    diag = np.abs(np.diag(r))
    if diag.min() <= np.finfo(float).eps * max(diag.max(), np.finfo(float).tiny) * max(n, p):
        return NonlinearFit(
            beta, np.full(p, np.nan), nan, sse, float("nan"), False, steps, "the Jacobian is rank-deficient here"
        )
    along = q.T @ resid
    rest = max(sse - float(along @ along), 0.0)
    if rest > 0 and n > p:
        rel_offset = float(np.sqrt(float(along @ along) / p) / np.sqrt(rest / (n - p)))
    else:  # a zero-residual fit: the gradient relative to the data's scale
        rel_offset = float(np.linalg.norm(along) / max(np.linalg.norm(np.asarray(y)), np.finfo(float).tiny))
    rinv = np.linalg.solve(r, np.eye(p))
    s2 = sse / (n - p) if n > p else np.nan
    cov = s2 * rinv @ rinv.T
    why = ""
    if rel_offset > REL_OFFSET_TOL:
        why = f"not a stationary point (relative offset {rel_offset:.2g} > {REL_OFFSET_TOL:g})"
    elif not solver_ok:
        why = "the solver stopped before its tolerance"
    ok = not why or (why.startswith("the solver") and rel_offset < REL_OFFSET_TOL * 1e-3)
    return NonlinearFit(
        beta, np.sqrt(np.diag(cov)), cov, sse, float(np.sqrt(s2)), ok, steps, "" if ok else why, rel_offset
    )
