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

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, NamedTuple, Protocol

import numpy as np

if TYPE_CHECKING:
    from bayescal.inference.diagnostics import Diagnostics
    from bayescal.inference.laplace import LaplaceResult
    from bayescal.inference.program import Program, ProgramData
    from bayescal.model.spec import InferenceSpec

__all__ = [
    "Draws",
    "Backend",
    "Sampled",
    "Tuned",
    "OneByOne",
    "Shipped",
    "SHIPPED",
    "REGISTRY",
    "BASELINE",
    "register",
    "names",
    "get",
    "chained",
    "reports",
]

#: the classical fit, accepted by ``fit`` beside the posterior backends
BASELINE = "lsq"


@dataclass
class Draws:
    """What a backend returns: unconstrained draws and the numbers its verdict needs."""

    z: np.ndarray  # (chain, draw, dim)
    divergences: int = 0
    stats: dict = field(default_factory=dict)  # per-draw sampler statistics (arviz sample_stats)
    extra: dict = field(default_factory=dict)  # diagnostics entries
    #: pointwise log-likelihood ``(chain, draw, row)``, computed once when the fit is finished (the
    #: verdict and the DataTree's ``log_likelihood`` group both read it)
    loglik: np.ndarray | None = None


def with_loglik(draws: Draws, program: Program, data, known: np.ndarray | None = None) -> Draws:
    """``draws`` with their pointwise log-likelihood ``(chain, draw, row)``: ``known`` when the caller has it
    already (``program.constrain(..., loglik=True)`` gives it with the sites, in the same pass), computed
    when neither it nor the draws have it."""
    if draws.loglik is not None:
        return draws
    chains, n, dim = np.shape(draws.z)
    if known is None:
        known = program.loglik(np.asarray(draws.z).reshape(-1, dim), data)
    return replace(draws, loglik=np.asarray(known).reshape(chains, n, -1))


def reads_loglik(backend: Backend) -> bool:
    """Whether ``backend.verdict`` reads the draws' pointwise log-likelihood."""
    return bool(getattr(backend, "reads_loglik", False))


def judged(backend: Backend, draws: Draws, program: Program, data, known: np.ndarray | None = None) -> Draws:
    """``draws`` as ``backend.verdict`` reads them: with their log-likelihood when its verdict reads it
    (:func:`reads_loglik`; a batch keeps none, so this one is dropped after the verdict); ``known``: see
    :func:`with_loglik`."""
    return with_loglik(draws, program, data, known) if reads_loglik(backend) else draws


class Tuned(Protocol):
    """A spec with sampler settings: a camera's :class:`~bayescal.model.spec.ModelSpec` or a film's."""

    @property
    def inference(self) -> InferenceSpec: ...


class Sampled(Protocol):
    """What a backend samples: one dataset of a model (a camera's
    :class:`~bayescal.model.assemble.CalibrationModel`, a film band's model), its data the program's
    argument and its spec's ``[inference]`` the sampler's settings."""

    @property
    def data(self) -> ProgramData: ...

    @property
    def spec(self) -> Tuned: ...


#: ``progress(datasets_done)`` or ``iterations(iterations_done)``
Progress = Callable[[int], None]
#: ``stage(message)``: what the run is doing now, in words
Stage = Callable[[str], None]


class Backend(Protocol):
    """A posterior sampler.

    ``sample_many`` returns one :class:`Draws` per dataset (``progress(datasets_done)``;
    ``iterations(done)`` reports a single dataset's sampler iterations); ``verdict`` judges one
    dataset's draws (``posterior``: its constrained sites ``(chain, draw, ...)``).  A backend whose
    verdict reads the draws' pointwise log-likelihood sets ``reads_loglik = True``; callers pass the
    draws through :func:`judged`.
    """

    @property
    def name(self) -> str: ...

    @property
    def batched(self) -> bool:
        """Runs many datasets together (vectorised, or on one thread pool) rather than in turn."""
        ...

    def sample_many(
        self,
        models: Sequence[Sampled],
        program: Program,
        modes: Sequence[LaplaceResult],
        seeds: Sequence[int],
        *,
        progress: Progress | None = None,
        iterations: Progress | None = None,
        stage: Stage | None = None,
    ) -> list[Draws]: ...

    def verdict(
        self, draws: Draws, posterior: Mapping[str, np.ndarray], spec: Tuned, mode: LaplaceResult
    ) -> Diagnostics: ...


class OneByOne:
    """``sample_many`` for a backend that samples one dataset at a time with
    ``sample(model, program, mode, seed, iterations, stage)``."""

    def sample(
        self, model: Sampled, program: Program, mode: LaplaceResult, seed: int, progress: Progress | None, stage: Stage
    ) -> Draws:
        """One dataset's draws (``progress(iterations_done)`` or None; ``stage(message)``)."""
        raise NotImplementedError

    def sample_many(
        self,
        models: Sequence[Sampled],
        program: Program,
        modes: Sequence[LaplaceResult],
        seeds: Sequence[int],
        *,
        progress: Progress | None = None,
        iterations: Progress | None = None,
        stage: Stage | None = None,
    ) -> list[Draws]:
        say: Stage = stage or (lambda message: None)
        out = []
        for i, (model, mode, seed) in enumerate(zip(models, modes, seeds, strict=True)):
            out.append(self.sample(model, program, mode, seed, iterations if len(models) == 1 else None, say))
            if progress is not None:
                progress(i + 1)
        return out


class Shipped(NamedTuple):
    """What is known of a shipped backend without importing it (its module pulls in JAX)."""

    module: str  # the module that registers it
    batched: bool  # runs many datasets together
    chained: bool  # its draws come in chains (trace and rank plots, a progress bar of iterations)
    reports: tuple[str, ...]  # the diagnostics its verdict fills (what a report shows for it)
    description: str


_NUTS_REPORTS = ("divergences", "max_rhat", "min_ess_bulk", "min_ess_tail")

#: the shipped backends, read without importing their modules, so the command line's help stays instant;
#: the backend classes take their ``batched`` flag from here.
SHIPPED: dict[str, Shipped] = {
    "nuts": Shipped(
        "bayescal.inference.samplers", True, True, _NUTS_REPORTS, "numpyro NUTS in Laplace-whitened coordinates"
    ),
    "laplace": Shipped(
        "bayescal.inference.samplers",
        False,
        False,
        ("map_converged", "hessian_positive_definite"),
        "Gaussian at the posterior mode (fast)",
    ),
    "emcee": Shipped("bayescal.inference.samplers", False, True, ("min_ess_bulk",), "emcee's ensemble sampler"),
    "blackjax": Shipped(
        "bayescal.inference.blackjax_backend", False, True, _NUTS_REPORTS, "BlackJAX NUTS with window adaptation"
    ),
}

REGISTRY: dict[str, Backend] = {}


def register(backend: Backend) -> Backend:
    """Add a backend under its name (the name the CLI's ``--backend`` offers)."""
    REGISTRY[backend.name] = backend
    return backend


def names(*, baseline: bool = False, batched: bool = False) -> list[str]:
    """Backend names (``batched``: only those that run many datasets together), optionally with ``lsq``."""
    out = [n for n, info in SHIPPED.items() if info.batched or not batched]
    out += [n for n, b in REGISTRY.items() if n not in SHIPPED and (b.batched or not batched)]
    return out + [BASELINE] if baseline else out


def get(name: str) -> Backend:
    """The backend registered as ``name`` (importing the module of a shipped one)."""
    if name not in REGISTRY and name in SHIPPED:
        import importlib

        importlib.import_module(SHIPPED[name].module)
    return REGISTRY[name]


def chained(name: str) -> bool:
    """Whether backend ``name`` draws in chains (a registered backend says so by a ``chained`` attribute)."""
    if name in SHIPPED:
        return SHIPPED[name].chained
    backend = REGISTRY.get(name)  # None for the least-squares baseline
    return backend is not None and bool(getattr(backend, "chained", True))


def reports(name: str) -> tuple[str, ...]:
    """The diagnostics backend ``name``'s verdict fills (a registered backend lists them in ``reports``)."""
    return SHIPPED[name].reports if name in SHIPPED else tuple(getattr(REGISTRY.get(name), "reports", ()))
