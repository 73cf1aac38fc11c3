"""The one NUTS program: a chain's warmup and draws on a potential, compiled once per structure.

Every NUTS run of the package (a camera's fit, :mod:`bayescal.inference.nuts`; the fleet's scales in
phases, :mod:`bayescal.inference.phases`) is this program.  It runs numpyro's NUTS kernel on
``w``, with the potential evaluated at ``x = center + chol @ w``: a camera whitens its posterior by
the Laplace covariance there (``chol`` its Cholesky factor), the fleet passes ``center = 0`` and
``chol = I`` (exact: a product with the identity and a sum with zero round nothing) and a diagonal
inverse mass matrix instead.

Warmup adapts in one of two ways (:class:`Chain`):

``"windowed"``
    numpyro's windowed adaptation of the step size and the mass matrix (diagonal or dense), from a
    first step ``step``: a camera's posterior has scales across orders of magnitude that a fixed
    diagonal does not capture.
``"step"``
    only the step size, by dual averaging toward ``target`` from ``10 * step``, the mass ``imm`` kept;
    the step returned is the dual average (the fleet's phases, whose scales are few and
    near-Gaussian once the latents are integrated out).

The draws follow at the step warmup ends with.  Each chain reports its iterations every
:data:`EVERY` to its run's progress channel (:func:`bayescal.inference.chains.report`) by a host
callback, so a progress bar costs no recompilation.  The target acceptance is an argument, so a
retry at a higher one reuses the program.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import lru_cache
from typing import Literal, NamedTuple

import jax
import jax.numpy as jnp
from numpyro.infer.hmc import hmc
from numpyro.infer.hmc_util import dual_averaging

from bayescal.inference.chains import report

__all__ = ["EVERY", "Chain", "Transitions", "chain_program"]

#: iterations between two progress reports of a chain
EVERY = 50


class Chain(NamedTuple):
    """What a chain program is compiled for (its lengths and adaptation; the data are arguments)."""

    warmup: int
    draws: int
    adapt: Literal["windowed", "step"] = "windowed"
    dense: bool = False
    depth: int = 10


class Transitions(NamedTuple):
    """One chain's result: its last state and step, the gradient evaluations and divergent transitions
    of its warmup, and per draw ``x`` (the potential's coordinates) with the sampler's statistics."""

    w_last: jax.Array
    step: jax.Array
    warmup_gradients: jax.Array
    warmup_divergences: jax.Array
    x: jax.Array
    diverging: jax.Array
    num_steps: jax.Array
    accept_prob: jax.Array
    energy: jax.Array
    step_size: jax.Array


@lru_cache(maxsize=64)
def chain_program(potential: Callable, chain: Chain) -> Callable[..., Transitions]:
    """``run(run, index, key, w0, step, imm, target, data, center, chol) -> Transitions``, jitted.

    Parameters
    ----------
    potential : callable
        ``potential(x, data)``, minus the log density; the same object for one structure (it keys the
        compiled programs with ``chain``).
    chain : Chain
        Warmup and draw lengths, the adaptation (the module's docstring), dense mass, tree depth.

    Notes
    -----
    ``imm`` (the inverse mass matrix) is used by ``"step"`` adaptation and by draws without warmup;
    ``"windowed"`` adaptation starts from the identity, as numpyro does.  ``run`` and ``index`` name
    the progress channel and the chain in it (a run nobody listens to is not heard).
    """
    warmup, draws, adapt, dense, depth = chain
    da_init, da_update = dual_averaging()

    def run(run_id, index, key, w0, step, imm, target, data, center, chol) -> Transitions:
        def at(w):
            return potential(center + chol @ w, data)

        init_kernel, sample_kernel = hmc(potential_fn=at, algo="NUTS")
        windowed = adapt == "windowed" and warmup > 0
        mass = {} if windowed else {"inverse_mass_matrix": imm}
        state = init_kernel(
            w0,
            num_warmup=warmup if windowed else 0,
            step_size=step,
            adapt_step_size=windowed,
            adapt_mass_matrix=windowed,
            dense_mass=dense,
            target_accept_prob=target,
            max_tree_depth=depth,
            rng_key=key,
            **mass,
        )

        def tick(i):
            jax.lax.cond(i % EVERY == EVERY - 1, lambda: jax.debug.callback(report, run_id, index, i), lambda: None)

        def warm(carry, i):
            s, da = carry
            tick(i)
            s = sample_kernel(s)
            if not windowed:  # dual averaging of the step alone, the mass kept
                da = da_update(target - s.accept_prob, da)
                s = s._replace(adapt_state=s.adapt_state._replace(step_size=jnp.exp(da[0])))
            return (s, da), (s.num_steps, s.diverging)

        def draw(s, i):
            tick(i + warmup)
            s = sample_kernel(s)
            return s, (center + chol @ s.z, s.diverging, s.num_steps, s.accept_prob, s.energy, s.adapt_state.step_size)

        (state, da), (steps, diverging) = jax.lax.scan(warm, (state, da_init(jnp.log(10.0 * step))), jnp.arange(warmup))
        if warmup > 0 and not windowed:  # the draws go on at the dual average
            state = state._replace(adapt_state=state.adapt_state._replace(step_size=jnp.exp(da[1])))
        last, out = jax.lax.scan(draw, state, jnp.arange(draws))
        return Transitions(last.z, last.adapt_state.step_size, jnp.sum(steps), jnp.sum(diverging), *out)

    return jax.jit(run)
