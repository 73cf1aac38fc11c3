"""One compiled program per model structure (DESIGN.md section 4).

A :class:`Program` holds the model's log density in the *flat unconstrained*
space as jitted functions of ``(z, data)``: data are arguments, never
closed over, so every dataset of one shape reuses one compilation.  Programs
are cached by structure; JAX's persistent cache (``bayescal._config``) keeps
compilations across processes.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import lru_cache

import jax
import jax.numpy as jnp
import numpy as np
from jax.flatten_util import ravel_pytree
from numpyro.infer import init_to_median
from numpyro.infer.util import constrain_fn, initialize_model, potential_energy

from ..assemble import CalibrationModel, Parts, numpyro_model
from ..data import ModelData

__all__ = ["Program", "program_for"]


@dataclass(frozen=True, eq=False)
class Program:
    """Jitted functions of one model structure.

    Attributes
    ----------
    z0 : jax.Array
        Flat unconstrained starting point (prior medians).
    unravel : callable
        Flat vector -> dict of unconstrained sites.
    potential : callable
        ``potential(z, data)``: negative log posterior density (with Jacobians).
    value_and_grad, hessian : callable
        Its value and gradient, and Hessian, in ``z``.
    constrain : callable
        ``constrain(z_batch, data)``: dict of constrained sites (and
        deterministic sites) for a batch of flat vectors.
    """

    model: Callable
    z0: jax.Array
    unravel: Callable
    potential: Callable
    value_and_grad: Callable
    hessian: Callable
    constrain: Callable

    @property
    def dim(self) -> int:
        """Number of unconstrained parameters."""
        return int(self.z0.size)


def program_for(model: CalibrationModel) -> Program:
    """The cached program of ``model``'s structure."""
    register_example(model)
    return _program(model.parts, model.layout.shape_key, _example_key(model.data))


def _example_key(data: ModelData) -> tuple:
    return tuple((np.shape(x), str(jnp.asarray(x).dtype)) for x in data)


_EXAMPLES: dict[tuple, ModelData] = {}


@lru_cache(maxsize=32)
def _program(parts: Parts, shape_key: tuple, example_key: tuple) -> Program:
    model = numpyro_model(parts)
    example = _EXAMPLES[(parts, shape_key, example_key)]
    info = initialize_model(
        jax.random.PRNGKey(0), model, model_args=(example,), init_strategy=init_to_median(num_samples=31)
    )
    z0, unravel = ravel_pytree(info.param_info.z)

    def potential(z, data):
        return potential_energy(model, (data,), {}, unravel(z))

    def constrain_one(z, data):
        return constrain_fn(model, (data,), {}, unravel(z), return_deterministic=True)

    return Program(
        model=model,
        z0=z0,
        unravel=unravel,
        potential=jax.jit(potential),
        value_and_grad=jax.jit(jax.value_and_grad(potential)),
        hessian=jax.jit(jax.hessian(potential)),
        constrain=jax.jit(jax.vmap(constrain_one, in_axes=(0, None))),
    )


def register_example(model: CalibrationModel) -> None:
    """Remember an example dataset of this structure (needed to trace the model once)."""
    _EXAMPLES.setdefault((model.parts, model.layout.shape_key, _example_key(model.data)), model.data)
