"""MAP with optimistix and a Gaussian at the mode (the ``laplace`` backend).

The mode is found by BFGS in the unconstrained space; the Gaussian's
precision is the exact Hessian of the negative log posterior there (jax).
For a linear-Gaussian model (linear response, known noise, normal priors)
this *is* the posterior (DESIGN.md section 4).
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from ..data import ModelData
from .program import Program

__all__ = ["LaplaceResult", "find_map", "laplace"]


@dataclass(frozen=True)
class LaplaceResult:
    """Mode and covariance in the flat unconstrained space."""

    mode: np.ndarray
    cov: np.ndarray
    potential: float
    converged: bool
    steps: int
    positive_definite: bool


def find_map(program: Program, data: ModelData, z0: jax.Array | None = None, rounds: int = 4):
    """Minimise the potential with optimistix BFGS in Hessian-whitened coordinates.

    Calibration likelihoods are stiff (row precisions ~1e7 in scaled units
    against O(1) prior scales), which stalls plain BFGS.  Each round
    whitens with the Hessian at the current point, ``z = z_c + P w`` with
    ``P = V |Lambda|^(-1/2)`` (absolute eigenvalues, floored), and runs BFGS
    in ``w``; it stops when the Newton decrement is negligible.

    Returns ``(z_map, converged, steps)``.
    """
    z = program.z0 if z0 is None else jnp.asarray(z0)
    steps, converged = 0, False
    for _ in range(rounds):
        precond = _preconditioner(np.asarray(program.hessian(z, data)))
        sol = _WHITENED_BFGS(program.potential, z, jnp.asarray(precond), data)
        steps += int(sol.stats["num_steps"])
        z = z + jnp.asarray(precond) @ sol.value
        grad = np.asarray(program.value_and_grad(z, data)[1])
        step = precond.T @ grad  # gradient in whitened coordinates = Newton step length
        if float(step @ step) < 1e-8:
            converged = True
            break
    return z, converged, steps


def _preconditioner(hess: np.ndarray) -> np.ndarray:
    hess = 0.5 * (hess + hess.T)
    if not np.all(np.isfinite(hess)):
        return np.eye(hess.shape[0])
    w, v = np.linalg.eigh(hess)
    w = np.maximum(np.abs(w), 1e-10 * max(np.abs(w).max(), 1.0))
    return v / np.sqrt(w)


def _make_whitened_bfgs():
    solver = optx.BFGS(rtol=1e-12, atol=1e-12)

    def run(potential, z_c, precond, data):
        fn = lambda w, args: potential(args[0] + args[1] @ w, args[2])
        w0 = jnp.zeros_like(z_c)
        return optx.minimise(fn, solver, w0, args=(z_c, precond, data), max_steps=500, throw=False)

    return jax.jit(run, static_argnums=0)


_WHITENED_BFGS = _make_whitened_bfgs()


def laplace(program: Program, data: ModelData, z0: jax.Array | None = None) -> LaplaceResult:
    """Mode and Gaussian covariance (inverse Hessian) of the posterior, searched from ``z0``."""
    z_map, converged, steps = find_map(program, data, z0)
    hess = np.asarray(program.hessian(z_map, data))
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
        potential=float(program.potential(z_map, data)),
        converged=converged,
        steps=steps,
        positive_definite=pd,
    )


def laplace_draws(result: LaplaceResult, n: int, seed: int) -> np.ndarray:
    """``n`` draws of the flat unconstrained vector from the Gaussian."""
    rng = np.random.default_rng(seed)
    chol = np.linalg.cholesky(result.cov + 1e-300 * np.eye(result.cov.shape[0]))
    return result.mode + rng.standard_normal((n, result.mode.size)) @ chol.T
