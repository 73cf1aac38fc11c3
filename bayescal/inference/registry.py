"""The backend seam: every posterior sampler behind one protocol, chosen from one registry.

A backend receives a compiled program (:mod:`bayescal.inference.program`),
the data and the Laplace result at the posterior mode (every backend starts
from, or whitens with, it) and returns unconstrained draws ``(chain, draw,
dim)`` with its own numbers; it then judges its own draws (divergences and
R-hat for NUTS, the autocorrelation time for emcee, the mode's convergence
for Laplace).  ``fit``, ``fit_many`` and the command line know backends only through this
module: adding a sampler is one module that registers itself (``register``)
and, for a shipped one, its line in :data:`SHIPPED`.

The least-squares baseline (``lsq``) is not a posterior backend; ``fit``
accepts it by name beside these (:data:`BASELINE`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

__all__ = ["Draws", "Backend", "REGISTRY", "BASELINE", "register", "names", "get"]

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

    ``sample(model, program, mode, seed, progress, stage)`` returns :class:`Draws`;
    ``verdict(draws, posterior, spec, mode)`` judges them (a :class:`Diagnostics`).
    """

    name: str
    batched: bool  # has a vectorised path for many datasets of one structure (fit_many)

    def sample(self, model, program, mode, seed: int, progress: Callable | None, stage: Callable) -> Draws: ...

    def verdict(self, draws: Draws, posterior: dict, spec, mode): ...


#: the shipped backends: name -> (module that registers it, has a fit_many path, description).  Read
#: without importing the modules (they pull in JAX), so the command line's help stays instant; the
#: backend classes take their ``batched`` flag from here.
SHIPPED: dict[str, tuple[str, bool, str]] = {
    "nuts": ("bayescal.inference.samplers", True, "numpyro NUTS in Laplace-whitened coordinates"),
    "laplace": ("bayescal.inference.samplers", True, "Gaussian at the posterior mode (fast)"),
    "emcee": ("bayescal.inference.samplers", False, "emcee's ensemble sampler"),
    "blackjax": ("bayescal.inference.blackjax_backend", False, "BlackJAX NUTS with window adaptation"),
}

REGISTRY: dict[str, Backend] = {}


def register(backend: Backend) -> Backend:
    """Add a backend under its name (the name the CLI's ``--backend`` offers)."""
    REGISTRY[backend.name] = backend
    return backend


def names(*, baseline: bool = False, batched: bool = False) -> list[str]:
    """Backend names (``batched``: only those with a ``fit_many`` path), optionally with ``lsq``."""
    out = [n for n, (_, many, _) in SHIPPED.items() if many or not batched]
    out += [n for n, b in REGISTRY.items() if n not in SHIPPED and (b.batched or not batched)]
    return out + [BASELINE] if baseline else out


def get(name: str) -> Backend:
    """The backend registered as ``name`` (importing the module of a shipped one)."""
    if name not in REGISTRY and name in SHIPPED:
        import importlib

        importlib.import_module(SHIPPED[name][0])
    return REGISTRY[name]
