"""NUTS in phases on a potential whose scale is known in advance (the fleet's scales).

:func:`run_phases` runs the one NUTS program (:func:`bayescal.inference.transitions.chain_program`)
on ``potential(u, arrays)`` with a diagonal inverse mass matrix from a Laplace approximation, and
only the step size adapted, by dual averaging toward the target acceptance, in two halves of the
warmup: the second restarts from the first's average once the chains have left their starting
points, and the chains then share the geometric mean of their averaged steps.  The draws follow;
while they do not pass ``mixed`` the chains continue from their last state with the same step and
mass, ``extend`` times at most.  Each phase is the program compiled once per (potential, length,
adaptation), so every dataset of one structure shares it; chains run on threads
(:func:`bayescal.inference.chains.map_chains`).

A camera's fit adapts its mass matrix as well (numpyro's windowed adaptation, in coordinates whitened
by the Laplace covariance): its posterior's scales span orders of magnitude that a fixed diagonal
does not capture.  The fleet's scales are few and near-Gaussian after the latents are integrated
out, and step-only adaptation took 2.1x fewer gradient evaluations there
(``benchmarks/results/fleet_speed.md``).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import numpy as np

from bayescal.inference.chains import map_chains
from bayescal.inference.transitions import Chain, Transitions, chain_program

__all__ = ["Phased", "run_phases"]


class Phased(NamedTuple):
    """Draws of :func:`run_phases`: unconstrained ``z`` ``(chain, draw, dim)``, the divergent transitions
    among them, and the gradient evaluations of every phase (warmup included)."""

    z: np.ndarray
    divergences: int
    gradients: int


def run_phases(
    potential: Callable,
    arrays: Any,
    u0: np.ndarray,
    imm: np.ndarray,
    *,
    warmup: int,
    draws: int,
    target_accept: float,
    seed: int,
    extend: int = 0,
    mixed: Callable[[np.ndarray], bool] | None = None,
    threads: int | None = None,
) -> Phased:
    """NUTS in phases (the module's docstring) from the chains' starts ``u0`` ``(chain, dim)``.

    Parameters
    ----------
    potential : callable
        ``potential(u, arrays)``, minus the log density; the same object for one structure (it keys
        the compiled programs).
    arrays : pytree
        The data, an argument of the compiled programs.
    imm : array (dim,)
        Diagonal inverse mass matrix, kept throughout.
    mixed : callable, optional
        ``mixed(z)`` on the draws so far ``(chain, draw, dim)``: True when they are enough; until then
        every chain continues for another ``draws`` draws, ``extend`` times at most.
    """
    import jax

    chains, dim = int(u0.shape[0]), int(u0.shape[1])
    key = jax.random.PRNGKey(seed)
    center, eye = np.zeros(dim), np.eye(dim)  # no whitening: the mass matrix carries the scale
    target = np.float64(target_accept)

    def phase(n: int, adapt: bool, us, steps, tag: int) -> list[Transitions]:
        run = chain_program(potential, Chain(n, 0, "step") if adapt else Chain(0, n))
        keys = jax.random.split(jax.random.fold_in(key, tag), chains)

        def one(c: int) -> Transitions:
            return jax.device_get(run(0, c, keys[c], us[c], steps[c], imm, target, arrays, center, eye))

        return map_chains(one, chains, threads)

    def gradients(outs: list[Transitions]) -> int:
        return int(sum(int(o.warmup_gradients) + int(np.sum(o.num_steps)) for o in outs))

    half = warmup // 2
    # with the Laplace variances as the mass, the posterior is about unit scale: a first step of 0.5
    settle = phase(half, True, u0, np.full(chains, 0.5), 0)
    warm = phase(warmup - half, True, [o.w_last for o in settle], [o.step for o in settle], 1)
    steps = np.full(chains, np.exp(np.mean([np.log(o.step) for o in warm])))  # one for all: they share the mass
    outs = phase(draws, False, [o.w_last for o in warm], steps, 2)
    z = [[np.asarray(o.x)] for o in outs]
    divergences = int(sum(np.sum(o.diverging) for o in outs))
    used = gradients(settle) + gradients(warm) + gradients(outs)
    for i in range(extend if mixed is not None else 0):
        assert mixed is not None  # the loop runs only with it
        if mixed(np.stack([np.concatenate(c) for c in z])):
            break
        outs = phase(draws, False, [o.w_last for o in outs], steps, 3 + i)  # the chains go on
        for c, o in enumerate(outs):
            z[c].append(np.asarray(o.x))
        divergences += int(sum(np.sum(o.diverging) for o in outs))
        used += gradients(outs)
    return Phased(np.stack([np.concatenate(c) for c in z]), divergences, used)
