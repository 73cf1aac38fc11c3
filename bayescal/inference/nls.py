"""Nonlinear least squares (optimistix Levenberg-Marquardt) with the Gaussian at the optimum.

For saturating or otherwise nonlinear sensor responses fitted the classical
way (DESIGN.md section 4, NIST StRD nonlinear problems).  Parameters are
rescaled by their starting values so the solver sees O(1) unknowns; the
residual function is jitted once per model function.  The covariance is
``s^2 (J^T J)^-1`` with ``s^2 = SSE / (n - p)`` -- the Laplace approximation
of the flat-prior posterior with the noise scale profiled, which is also the
classical asymptotic covariance.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import lru_cache

import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

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


@lru_cache(maxsize=64)
def _solver(model: Callable) -> Callable:
    def residual(u, args):
        scale, x, y = args
        return model(u * scale, x) - y

    solver = optx.LevenbergMarquardt(rtol=1e-14, atol=1e-14)

    def run(u0, scale, x, y):
        sol = optx.least_squares(residual, solver, u0, args=(scale, x, y), max_steps=5000, throw=False)
        return sol.value, sol.result == optx.RESULTS.successful, sol.stats["num_steps"]

    jac = jax.jacfwd(lambda b, x: model(b, x))
    return jax.jit(run), jax.jit(jac)


def nonlinear_lsq(model: Callable, x: np.ndarray, y: np.ndarray, start: np.ndarray, polish: int = 3) -> NonlinearFit:
    """Fit ``y = model(beta, x) + e`` by least squares from ``start``.

    ``model(beta, x)`` must be a JAX-traceable function (pass the same
    function object to reuse the compilation).  Levenberg-Marquardt runs in
    parameters scaled by ``|start|``, restarted from its own answer
    ``polish`` times (each restart rescales), then the covariance is formed
    from the Jacobian at the optimum by a QR decomposition.
    """
    run, jac = _solver(model)
    x, y = jnp.asarray(x, dtype=float), jnp.asarray(y, dtype=float)
    beta = np.asarray(start, dtype=float)
    steps, converged = 0, False
    for _ in range(1 + polish):
        scale = np.where(beta != 0, np.abs(beta), 1.0)
        u0 = jnp.asarray(np.where(beta < 0, -1.0, 1.0))
        value, success, n_steps = run(u0, jnp.asarray(scale), x, y)
        steps += int(n_steps)
        converged = bool(success)
        new = np.asarray(value) * scale
        if np.allclose(new, beta, rtol=1e-15, atol=0):
            beta = new
            break
        beta = new
    resid = np.asarray(model(jnp.asarray(beta), x) - y)
    sse = float(resid @ resid)
    n, p = resid.size, beta.size
    j = np.asarray(jac(jnp.asarray(beta), x))
    _, r = np.linalg.qr(j)
    rinv = np.linalg.solve(r, np.eye(p))
    s2 = sse / (n - p) if n > p else np.nan
    cov = s2 * rinv @ rinv.T
    ok = bool(converged) and bool(np.all(np.isfinite(beta)))
    return NonlinearFit(beta, np.sqrt(np.diag(cov)), cov, sse, float(np.sqrt(s2)), ok, steps)
