"""One compiled program per model structure (docs/architecture.md, section 4).

A :class:`Program` holds the model's log density in the *flat unconstrained*
space as jitted functions of ``(z, data)``: data are arguments, never
closed over, so every dataset of one shape reuses one compilation.  Programs
are cached by structure (components and array shapes); JAX's persistent
cache (``bayescal._config``) keeps the compilations across processes.

Nothing here runs numpyro eagerly: the parameter layout comes from
``jax.eval_shape`` of one model trace, so building a program costs a trace,
not hundreds of small op-by-op compilations.
"""

from __future__ import annotations

import functools
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, NamedTuple, Protocol

import jax
import jax.numpy as jnp
import numpy as np
from jax.flatten_util import ravel_pytree
from numpyro import handlers
from numpyro.distributions.transforms import biject_to
from numpyro.infer.util import potential_energy, unconstrain_fn

from bayescal._config import computes
from bayescal._parallel import parallel_map
from bayescal.inference.persist import TRACING, dtype_of, load_json, persisted, save_json, structure_key
from bayescal.model.assemble import CalibrationModel

__all__ = [
    "LOGLIK",
    "Objective",
    "Program",
    "Smooth",
    "derivatives_of",
    "program_for",
    "program_of",
    "clear_program_cache",
]

#: the key of each row's log-likelihood among the constrained sites (no numpyro site has this name)
LOGLIK = "__loglik__"

#: programs kept in memory, the most recently used: a diagnosis tries ~16 structures once each, and
#: keeping them all held 1.8 GB where 8 hold 1.4 GB at the same speed (a structure evicted and fitted
#: again is traced again; its compilation comes from the persistent cache)
_MAX_PROGRAMS = 8


class _Programs(OrderedDict):
    """The cached programs, most recently used last; ``cache_clear`` as an ``lru_cache`` has, so
    :func:`bayescal._caches.clear_caches` forgets them with every other cache of the package."""

    def cache_clear(self) -> None:
        self.clear()


_CACHE: _Programs = _Programs()


def clear_program_cache() -> None:
    """Forget the cached programs (see :func:`bayescal._caches.clear_caches`)."""
    _CACHE.cache_clear()


#: a program's data: any pytree of arrays (a calibration's ``ModelData``, a film's or a regression's tuple)
ProgramData = Any


class Smooth(Protocol):
    """What a mode search needs of a potential (:func:`bayescal.inference.laplace.find_map`): a
    :class:`Program` is one, and so is an :class:`Objective` built from any potential (the fleet's)."""

    @property
    def potential(self) -> Callable:
        """``potential(z, data)``: minus the log density; the same object for one structure."""
        ...

    @property
    def derivatives(self) -> Callable:
        """``derivatives(z, data)``: its value, gradient and Hessian in ``z``, from one run."""
        ...


class Objective(NamedTuple):
    """A potential ``potential(z, data)`` with its value-and-gradient, Hessian, and all three at once,
    jitted (:class:`Smooth`; each compiled on its first call only)."""

    potential: Callable
    value_and_grad: Callable
    hessian: Callable
    derivatives: Callable

    @classmethod
    def of(cls, potential: Callable) -> Objective:
        """The objective of ``potential`` (compile once per structure: cache the result per potential).
        Its value and gradient alone are the program the Hessian differentiates."""
        value_and_grad = jax.jit(jax.value_and_grad(potential))
        derivatives = jax.jit(derivatives_of(potential, value_and_grad))
        hessian = lambda z, data: derivatives(z, data)[2]  # noqa: E731
        return cls(potential, value_and_grad, hessian, derivatives)


def derivatives_of(potential: Callable, value_and_grad: Callable | None = None) -> Callable:
    """``(z, data) -> (value, gradient, Hessian)`` of ``potential(z, data)``, to be jitted.

    The Hessian is the forward-mode Jacobian of the jitted gradient's program (its jaxpr traced once,
    not the potential's Python again: a quarter of the tracing and two thirds of the compilation of
    ``jax.hessian(potential)`` on a camera's model), and the value and gradient come from the same
    run.  One program where a value-and-gradient program beside a Hessian program cost a camera's
    model 2.0 s more to compile and 0.16-0.24 s more to load in a new process; the numbers agree with
    the two programs' to rounding (a seed-000 Laplace fit's draws within 1e-11); on that model a call
    costs about 1.0 ms against 0.15-0.2 ms for the value and gradient alone, and a Newton step, which
    needs all three, makes one call instead of two.  ``value_and_grad``: the jitted value and gradient
    of ``potential`` to differentiate, where the caller has one.
    """
    if value_and_grad is None:
        value_and_grad = jax.jit(jax.value_and_grad(potential))

    def derivatives(z, data):
        def gradient(z):
            value, grad = value_and_grad(z, data)
            return grad, (value, grad)

        hess, (value, grad) = jax.jacfwd(gradient, has_aux=True)(z)
        return value, grad, hess

    return derivatives


@dataclass(frozen=True, eq=False)
class Program:
    """Jitted functions of one model structure.

    Attributes
    ----------
    z0 : numpy.ndarray
        Flat unconstrained origin (zeros): every latent at the centre of its
        unconstrained space (unit scales, zero non-centred offsets, linear
        response).  :func:`bayescal.inference.start.initial_point` replaces
        the data-dependent parts.
    unravel : callable
        Flat vector -> dict of unconstrained sites.
    potential : callable
        ``potential(z, data)``: negative log posterior density (with Jacobians).
    derivatives : callable
        ``derivatives(z, data)``: its value, gradient and Hessian in ``z``, one compiled program.
    value_and_grad, hessian : callable
        Its value and gradient, and its Hessian, from ``derivatives``.
    constrain : callable
        ``constrain(z_batch, data, loglik=False)``: dict of constrained sites
        (and deterministic sites) for a batch of flat vectors; with ``loglik``,
        each row's log-likelihood too, under :data:`LOGLIK` (one program, one
        run of the model: a fit's posterior gets both in one pass, and loads one
        program where it loaded two).
    unconstrain : callable
        ``unconstrain(values, data)``: flat unconstrained vector of a dict of
        constrained values (one per latent site).
    loglik : callable
        ``loglik(z_batch, data)``: pointwise log-likelihood of every row,
        ``(batch, n_rows)`` (for PSIS-LOO): ``constrain``'s :data:`LOGLIK`.
    """

    model: Callable
    z0: np.ndarray
    unravel: Callable
    potential: Callable
    derivatives: Callable
    constrain: Callable
    unconstrain: Callable
    loglik: Callable

    def value_and_grad(self, z, data) -> tuple:
        """The potential's value and gradient in ``z`` (:attr:`derivatives`: a separate program for them
        would cost a compilation and a load for ~1 ms saved per call)."""
        value, grad, _ = self.derivatives(z, data)
        return value, grad

    def hessian(self, z, data):
        """The potential's Hessian in ``z`` (:attr:`derivatives`)."""
        return self.derivatives(z, data)[2]

    @property
    def dim(self) -> int:
        """Number of unconstrained parameters."""
        return int(self.z0.size)

    def site_index(self, name: str) -> int | None:
        """Position of a scalar site in the flat vector (None if absent or not scalar)."""
        marked = np.zeros(self.dim)
        sites = self.unravel(marked)
        if name not in sites or np.size(sites[name]) != 1:
            return None
        sites[name][...] = 1.0  # a view of ``marked``
        return int(np.argmax(marked))


def program_for(model: CalibrationModel) -> Program:
    """The cached program of ``model``'s structure (built on first use; its traced functions kept on disk,
    :mod:`bayescal.inference.persist`)."""
    return program_of(model.model, model.data, structure=repr(model.parts))


@computes
def program_of(model: Callable, example, obs: str = "obs", structure: str | None = None) -> Program:
    """The cached program of any numpyro ``model(data)`` whose only argument is a data pytree.

    ``model`` must be the same object for every dataset of one structure (build
    it once, e.g. in an ``lru_cache``d factory): it is the cache key, together
    with the data's shapes.  ``obs`` names the observed site (pointwise
    log-likelihood).  ``structure``, a complete description of what ``model``
    computes, lets later processes load its traced functions from disk
    instead of tracing them again (:func:`~bayescal.inference.persist.persisted`).
    """
    key = (model, obs, _shape_key(example))
    program = _CACHE.get(key)
    if program is None:
        disk = None if structure is None else structure_key(structure, example, obs)
        program = _build(model, example, obs, disk)
        _CACHE[key] = program
        if len(_CACHE) > _MAX_PROGRAMS:
            _CACHE.popitem(last=False)
    else:
        _CACHE.move_to_end(key)
    return program


def _shape_key(data) -> tuple:
    return tuple((np.shape(x), str(dtype_of(x))) for x in jax.tree.leaves(data))


def _one_tracer[F: Callable](fn: F) -> F:
    """``fn``, which runs a numpyro model's Python, holding :data:`~bayescal.inference.persist.TRACING` while
    it runs (when a jit traces it; a compiled program runs without it): numpyro's effect handlers are one
    stack per process, so two threads may not trace models at once."""

    @functools.wraps(fn)
    def traced(*args):
        with TRACING:
            return fn(*args)

    return traced  # type: ignore[return-value]


def _build(model: Callable, example, obs: str = "obs", disk: str | None = None) -> Program:

    @_one_tracer
    def latent_unconstrained(data):
        tr = handlers.trace(handlers.seed(model, 0)).get_trace(data)
        return {
            name: biject_to(site["fn"].support).inv(site["value"])
            for name, site in tr.items()
            if site["type"] == "sample" and not site["is_observed"]
        }

    shapes = _latent_shapes(latent_unconstrained, example, disk)
    z0, unravel = _flat_layout(shapes)

    @_one_tracer
    def potential(z, data):
        return potential_energy(model, (data,), {}, unravel(z))

    @_one_tracer
    def constrain_one(z, data, with_loglik):
        """One run of the model with each latent mapped to its support: the constrained and deterministic
        sites, and where ``with_loglik`` (a scalar flag, one for the whole batch: a branch taken, not both
        computed) the observed site's log-density row by row (its mask applied; zeros otherwise)."""
        params = unravel(z)

        def constrained(site):
            name = site["name"]
            return biject_to(site["fn"].support)(params[name]) if name in params else None

        tr = handlers.trace(handlers.substitute(handlers.seed(model, 0), substitute_fn=constrained)).get_trace(data)
        sites = {
            name: site["value"]
            for name, site in tr.items()
            if site["type"] == "deterministic" or (site["type"] == "sample" and not site["is_observed"])
        }
        site = tr[obs]
        loglik = jax.lax.cond(
            with_loglik,
            lambda: site["fn"].log_prob(site["value"]).astype(z.dtype),
            lambda: jnp.zeros(jnp.shape(site["value"]), z.dtype),
        )
        return sites | {LOGLIK: loglik}

    @_one_tracer
    def unconstrain(values, data):
        z = unconstrain_fn(model, (data,), {}, values)
        return ravel_pytree({k: z[k] for k in shapes})[0]

    derivatives = derivatives_of(potential)
    constrain = _constrain(persisted(jax.vmap(constrain_one, in_axes=(0, None, None)), disk, "constrain"))
    return Program(
        model=model,
        z0=z0,
        unravel=unravel,
        potential=computes(jax.jit(potential)),  # differentiated by the samplers: traced in each process
        derivatives=computes(persisted(derivatives, disk, "derivatives")),
        constrain=constrain,
        unconstrain=computes(persisted(unconstrain, disk, "unconstrain")),
        loglik=lambda z_batch, data: constrain(z_batch, data, loglik=True)[LOGLIK],
    )


def _flat_layout(shapes: dict) -> tuple[np.ndarray, Callable]:
    """The flat origin (zeros) and its ``unravel``: each site a slice of the flat vector, the sites in
    sorted order as :func:`jax.flatten_util.ravel_pytree` lays them out.  ``unravel`` slices and reshapes,
    so it runs as numpy on a numpy vector (building a program runs no JAX op eagerly: each would
    compile in every new process) and is traced on a JAX one."""
    names = sorted(shapes)
    sizes = [int(np.prod(shapes[k].shape)) for k in names]
    ends = np.cumsum(sizes, dtype=int)
    dtype = np.result_type(*(shapes[k].dtype for k in names)) if names else np.float64

    def unravel(z):
        return {k: z[e - n : e].reshape(shapes[k].shape) for k, n, e in zip(names, sizes, ends.tolist(), strict=True)}

    return np.zeros(int(sum(sizes)), dtype=dtype), unravel


def _latent_shapes(latent_unconstrained: Callable, example, disk: str | None) -> dict:
    """Each latent site's unconstrained shape and dtype: from one trace of the model, or kept on disk."""
    kept = load_json(disk, "latent")
    if kept is not None:
        return {k: jax.ShapeDtypeStruct(tuple(shape), np.dtype(dtype)) for k, (shape, dtype) in kept.items()}
    shapes = jax.eval_shape(latent_unconstrained, example)
    save_json(disk, "latent", {k: [list(s.shape), str(s.dtype)] for k, s in shapes.items()})
    return shapes


#: rows of a batch of draws evaluated per call: every batch size (one start, 200 refit draws, 4000
#: posterior draws) runs the one program compiled for this size
BLOCK = 500


def _constrain(batched: Callable) -> Callable:
    """``constrain(z_batch, data, loglik=False)`` from the vmapped ``batched(z_batch, data, with_loglik)``: the
    sites, with :data:`LOGLIK` only when asked."""
    blocks = _in_blocks(batched)

    @computes
    def constrain(z_batch, data, loglik: bool = False) -> dict:
        sites = blocks(z_batch, data, np.asarray(loglik))
        return sites if loglik else {k: v for k, v in sites.items() if k != LOGLIK}

    return constrain


def _in_blocks(batched: Callable) -> Callable:
    """``batched(z_batch, data, *rest)`` over blocks of :data:`BLOCK` rows (the last padded), the results joined.

    Two blocks run at once (:func:`~bayescal._parallel.parallel_map`): the 4000 draws of a seed-000
    fit's posterior with their log-likelihood took 0.10 s against 0.14 s one block after another on
    two cores, with the same numbers (each block is the same program on the same rows).
    """

    def one(z_batch, first, data, rest):
        block = z_batch[first : first + BLOCK]
        rows = block.shape[0]
        if rows < BLOCK:
            block = np.concatenate([block, np.repeat(block[-1:], BLOCK - rows, axis=0)])
        return jax.tree.map(lambda a: np.asarray(a)[:rows], batched(block, data, *rest))

    def run(z_batch, data, *rest):
        z_batch = np.asarray(z_batch)
        firsts = range(0, z_batch.shape[0], BLOCK)
        parts = parallel_map(lambda first: one(z_batch, first, data, rest), firsts)
        if len(parts) == 1:
            return parts[0]
        return jax.tree.map(lambda *a: np.concatenate(a), *parts)

    return run
