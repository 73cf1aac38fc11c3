"""The backend seam: every posterior sampler behind one protocol, chosen from one registry.

A backend runs a compiled program (:mod:`bayescal.inference.program`) on one or many datasets of
one structure: it receives the assembled models, the program and the Laplace result at each
dataset's posterior mode (every backend starts from, or whitens with, it) and returns, per
dataset, unconstrained draws ``(chain, draw, dim)`` with its own numbers; it then judges its own
draws (divergences and R-hat for NUTS, the autocorrelation time for emcee, the mode's
convergence for Laplace).  ``fit`` is ``fit_many`` of one dataset, and both, like the command
line, know backends only through this module: adding a sampler is one module that registers
itself (``register``) and, for a shipped one, its line in :data:`SHIPPED`.  A backend without a
path of its own for many datasets takes :class:`OneByOne`'s, which runs them in turn.

The least-squares baseline (``lsq``) is not a posterior backend; ``fit``
accepts it by name beside these (:data:`BASELINE`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

__all__ = ["Draws", "Backend", "OneByOne", "REGISTRY", "BASELINE", "register", "names", "get"]

#: the classical fit, accepted by ``fit`` beside the posterior backends
BASELINE = "lsq"


@dataclass
class Draws:
    """What a backend returns: unconstrained draws and the numbers its verdict needs."""

    z: np.ndarray  # (chain, draw, dim)
    divergences: int = 0
    stats: dict = field(default_factory=dict)  # per-draw sampler statistics (arviz sample_stats)
    extra: dict = field(default_factory=dict)  # diagnostics entries


class Backend(Protocol):
    """A posterior sampler.

    ``sample_many(models, program, modes, seeds, progress=, iterations=, stage=)`` returns one
    :class:`Draws` per dataset (``progress(datasets_done)``; ``iterations(done)`` reports a single
    dataset's sampler iterations); ``verdict(draws, posterior, spec, mode)`` judges one dataset's
    draws (a :class:`~bayescal.inference.diagnostics.Diagnostics`).
    """

    name: str
    batched: bool  # runs many datasets together (vectorised, or on one thread pool) rather than in turn

    def sample_many(
        self, models, program, modes, seeds, *, progress=None, iterations=None, stage=None
    ) -> list[Draws]: ...

    def verdict(self, draws: Draws, posterior: dict, spec, mode): ...


class OneByOne:
    """``sample_many`` for a backend that samples one dataset at a time with
    ``sample(model, program, mode, seed, iterations, stage)``."""

    def sample_many(self, models, program, modes, seeds, *, progress=None, iterations=None, stage=None) -> list[Draws]:
        stage = stage or (lambda message: None)
        out = []
        for i, (model, mode, seed) in enumerate(zip(models, modes, seeds, strict=True)):
            out.append(self.sample(model, program, mode, seed, iterations if len(models) == 1 else None, stage))
            if progress is not None:
                progress(i + 1)
        return out


#: the shipped backends: name -> (module that registers it, runs many datasets together, description).  Read
#: without importing the modules (they pull in JAX), so the command line's help stays instant; the
#: backend classes take their ``batched`` flag from here.
SHIPPED: dict[str, tuple[str, bool, str]] = {
    "nuts": ("bayescal.inference.samplers", True, "numpyro NUTS in Laplace-whitened coordinates"),
    "laplace": ("bayescal.inference.samplers", False, "Gaussian at the posterior mode (fast)"),
    "emcee": ("bayescal.inference.samplers", False, "emcee's ensemble sampler"),
    "blackjax": ("bayescal.inference.blackjax_backend", False, "BlackJAX NUTS with window adaptation"),
}

REGISTRY: dict[str, Backend] = {}


def register(backend: Backend) -> Backend:
    """Add a backend under its name (the name the CLI's ``--backend`` offers)."""
    REGISTRY[backend.name] = backend
    return backend


def names(*, baseline: bool = False, batched: bool = False) -> list[str]:
    """Backend names (``batched``: only those that run many datasets together), optionally with ``lsq``."""
    out = [n for n, (_, many, _) in SHIPPED.items() if many or not batched]
    out += [n for n, b in REGISTRY.items() if n not in SHIPPED and (b.batched or not batched)]
    return out + [BASELINE] if baseline else out


def get(name: str) -> Backend:
    """The backend registered as ``name`` (importing the module of a shipped one)."""
    if name not in REGISTRY and name in SHIPPED:
        import importlib

        importlib.import_module(SHIPPED[name][0])
    return REGISTRY[name]
