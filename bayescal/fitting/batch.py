"""Fit many datasets of one model structure together: replications, sensors, SBC; one dataset is a fit.

:func:`fit_many` shares one compilation across datasets of one shape (docs/architecture.md,
section 4): the MAP searches run one after another or as one ``jax.vmap``-ed program, and the
backend samples every dataset through its ``sample_many`` (NUTS queues every (dataset, chain)
pair on one thread pool; the other backends run the datasets in turn).  Dataset ``i`` gets
exactly the draws ``fit(tables[i], spec, backend, seed=seeds[i])`` gives: :func:`~bayescal.fit`
*is* this function on one table.  :meth:`FitBatch.fit` turns one dataset into a full
:class:`~bayescal.fitting.result.Fit` (physical quantities, checks, report, files) on demand; the
batch's own per-dataset verdict (:attr:`FitBatch.diagnostics`) is computed only when asked for.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from functools import cached_property

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd

from bayescal._config import computes
from bayescal.errors import SpecError
from bayescal.fitting.result import OUTLIER_Z, SAMPLED, Fit, finish, misfit_of, row_summaries
from bayescal.inference import registry as backends
from bayescal.inference.guide import guide_pooled, pools
from bayescal.inference.laplace import LaplaceResult, laplace, laplace_many
from bayescal.inference.lsq import lsq_baseline
from bayescal.inference.program import LOGLIK, Program, program_for
from bayescal.inference.registry import Draws
from bayescal.inference.samplers import refuse_pooled
from bayescal.inference.start import initial_point
from bayescal.io.table import MeasurementTable
from bayescal.model.assemble import CalibrationModel, build_model
from bayescal.model.physical import physical_draws
from bayescal.model.spec import ModelSpec

__all__ = ["FitBatch", "fit_many", "fit_models", "with_data"]


@dataclass(frozen=True, eq=False)
class FitBatch:
    """Posterior draws of many datasets fitted with one model structure.

    Attributes
    ----------
    models : tuple of CalibrationModel
        One per dataset, in input order.
    backend : str
        The backend's name (:mod:`bayescal.inference.registry`).
    seeds : tuple of int
        Seed of each dataset's fit.
    samples : tuple of Draws
        Each dataset's unconstrained draws and its sampler's numbers.
    modes : tuple of LaplaceResult
        Each dataset's posterior mode and Laplace covariance.
    timings : dict
        Wall seconds of the stages, for the whole batch.
    """

    models: tuple[CalibrationModel, ...]
    backend: str
    seeds: tuple[int, ...]
    samples: tuple[Draws, ...]
    modes: tuple[LaplaceResult, ...]
    timings: dict
    program: Program = field(repr=False)

    def __len__(self) -> int:
        return len(self.models)

    # ------------------------------------------------------------------ one dataset
    def _sites(self, i: int, loglik: bool = False) -> dict[str, np.ndarray]:
        """Dataset ``i``'s constrained sites (sampled and deterministic), ``(chain, draw, ...)``; with ``loglik``,
        each draw's pointwise log-likelihood too (under :data:`~bayescal.inference.program.LOGLIK`)."""
        chains, draws, dim = self.samples[i].z.shape
        with_data = self.program.constrain(self.samples[i].z.reshape(-1, dim), self.models[i].data, loglik=loglik)
        return {k: np.asarray(v).reshape((chains, draws) + np.shape(v)[1:]) for k, v in with_data.items()}

    @computes
    def physical(self, i: int) -> dict[str, np.ndarray]:
        """Dataset ``i``'s reported quantities (``gain``, ``A_abs``, ...), ``(chain, draw, ...)``,
        without building a full :class:`~bayescal.fitting.result.Fit` (the same draws ``fit(i)`` reports)."""
        return physical_draws(self.models[i], self._sites(i), self.seeds[i])

    @computes
    def fit(self, i: int, strict: bool = False) -> Fit:
        """Dataset ``i`` as a full :class:`~bayescal.fitting.result.Fit` (same draws; physical quantities,
        outlier, misfit and leave-one-setting-out checks, least-squares baseline, ``save`` and reports)."""
        model = self.models[i]
        spec = model.spec
        t = time.perf_counter()
        lsq = lsq_baseline(model.table, orders=range(1, spec.response.order + 1), full_scale=spec.full_scale)
        timings = dict(self.timings) if len(self) == 1 else {"batch_" + k: v for k, v in self.timings.items()}
        timings["lsq"] = time.perf_counter() - t
        return finish(
            model, self.program, self.samples[i], self.backend, self.seeds[i], self.modes[i], lsq, timings, strict
        )

    # ------------------------------------------------------------- the batch's verdict
    @cached_property
    def _checked(self) -> tuple[dict[str, np.ndarray], np.ndarray, list[list[str]], list]:
        """Sampled sites per dataset ``(dataset, chain, draw, ...)``, each dataset's largest posterior
        predictive |z| over its rows, its misfit problems and its backend's verdict on its draws."""
        backend = backends.get(self.backend)
        stacked: dict[str, list] = {}
        worst, misfits, verdicts = np.empty(len(self)), [], []
        for i, m in enumerate(self.models):
            sites = self._sites(i, loglik=backends.reads_loglik(backend))  # the verdict's, in the same pass
            flat = {k: v.reshape((-1,) + v.shape[2:]) for k, v in sites.items()}
            rows = row_summaries(flat)
            resid = (np.asarray(m.data.y) - rows["mean"]) / np.sqrt(rows["var"])
            worst[i] = float(np.max(np.abs(np.where(np.asarray(m.data.censored), 0.0, resid))))
            excess = flat["excess"] * m.layout.dn_scale if "excess" in flat else None
            misfits.append(misfit_of(m, rows, excess)[0])
            sampled = {k: v for k, v in sites.items() if k in SAMPLED}
            draws = backends.judged(backend, self.samples[i], self.program, m.data, sites.get(LOGLIK))
            verdicts.append(backend.verdict(draws, sampled, m.spec, self.modes[i]))
            for k, v in sampled.items():
                stacked.setdefault(k, []).append(v)
        return {k: np.stack(v) for k, v in stacked.items()}, worst, misfits, verdicts

    @property
    def draws(self) -> dict[str, np.ndarray]:
        """Constrained sampled parameters, shape ``(dataset, chain, draw, ...)`` in the model's scaled
        units (as in ``posterior.nc``)."""
        return self._checked[0]

    @cached_property
    def diagnostics(self) -> pd.DataFrame:
        """Per dataset: ``map_ok``, ``max_abs_residual_z``, ``misfit`` (the misfit problems, empty when
        none), the sampler's ``divergences``, ``retried`` (NUTS chains rerun with smaller steps after
        divergences), ``max_rhat``, ``min_ess_bulk``, ``min_ess_tail``, ``sampled`` (the backend's
        verdict on its draws), ``converged`` (and no outlying row) and ``ok`` (and no misfit)."""
        _, worst, misfits, verdicts = self._checked
        frame = pd.DataFrame(
            {
                "map_ok": [r.converged and r.positive_definite for r in self.modes],
                "max_abs_residual_z": worst,
                "misfit": ["; ".join(p) for p in misfits],
                "divergences": [d.divergences for d in self.samples],
                "retried": ["retried" in d.extra for d in self.samples],
                "max_rhat": [v.max_rhat for v in verdicts],
                "min_ess_bulk": [v.min_ess_bulk for v in verdicts],
                "min_ess_tail": [v.min_ess_tail for v in verdicts],
            }
        )
        sampled = frame["map_ok"].to_numpy() & np.array([v.ok for v in verdicts])
        frame["sampled"] = sampled  # the posterior was computed correctly, whatever the rows say
        frame["converged"] = sampled & (worst <= OUTLIER_Z)  # the inference is trustworthy (what SBC asks)
        frame["ok"] = frame["converged"] & np.array([not p for p in misfits])  # ... and the model fits (fit() asks)
        return frame

    @property
    def ok(self) -> np.ndarray:
        """Whether each dataset's fit passed its diagnostics."""
        return self.diagnostics["ok"].to_numpy()

    @property
    def converged(self) -> np.ndarray:
        """Per dataset: the inference passed its checks (MAP, the backend's verdict, outliers),
        whatever the misfit checks say.  Datasets drawn from the model's own prior (SBC) may carry
        an excess scatter far above the noise floor, which ``ok`` reports as misfit."""
        return self.diagnostics["converged"].to_numpy()


@computes
def fit_many(
    tables: Sequence[MeasurementTable],
    spec: ModelSpec,
    backend: str = "nuts",
    *,
    seed: int = 0,
    seeds: Sequence[int] | None = None,
    progress: Callable[[int], None] | None = None,
    iterations: Callable[[int], None] | None = None,
    stage: Callable[[str], None] | None = None,
    vectorize: bool | None = None,
    starts: Sequence[np.ndarray | None] | None = None,
) -> FitBatch:
    """Fit ``spec`` to every table with one compiled program per stage.

    Parameters
    ----------
    tables : sequence of MeasurementTable
        Datasets of one structure: same rows per setting, channels, gain
        settings and levels (the values may differ).
    backend : str
        Any posterior backend (``nuts``, ``laplace``, ``emcee``, ``blackjax``).
    seed, seeds : int, sequence of int
        Dataset ``i`` is fitted with ``seeds[i]`` (default ``seed + i``):
        the same random numbers ``fit(tables[i], spec, backend, seed=seeds[i])`` uses.
    progress : callable, optional
        ``progress(datasets_done)``.
    iterations : callable, optional
        ``iterations(done)``: the sampler's iterations of a single dataset (a progress bar of one fit).
    stage : callable, optional
        ``stage(message)`` as each stage starts.
    vectorize : bool, optional
        Run the MAP searches as one vmapped program (see :func:`fit_models`).
    starts : sequence of arrays, optional
        Where each dataset's mode search starts (flat unconstrained vectors; None: the data-driven start,
        :func:`~bayescal.inference.start.initial_point`): a mode already found (the diagnosis's screen) is
        then only polished.

    Raises
    ------
    SpecError
        Unknown backend, or a table whose structure differs from the first's.
    """
    if backend not in backends.names():
        raise SpecError(f"unknown backend '{backend}'; expected one of {', '.join(backends.names())}")
    if not tables:
        raise SpecError("fit_many needs at least one table")
    if backend == "laplace":
        refuse_pooled(spec)
    t0 = time.perf_counter()
    if stage is not None:
        rows = f"{len(tables[0])} rows" + (f" x {len(tables)} tables" if len(tables) > 1 else "")
        stage(f"assembling the model ({rows})")
    models = [build_model(t, spec) for t in tables]
    first = models[0]
    for i, m in enumerate(models[1:], start=1):
        if m.structure_key != first.structure_key:
            raise SpecError(
                f"table {i} has structure {m.layout.shape_key} (rows, channels, gain settings, levels) but table 0 "
                f"has {first.layout.shape_key}; fit_many needs datasets of one structure: fit the others separately"
            )
    seeds = list(range(seed, seed + len(models))) if seeds is None else [int(s) for s in seeds]
    if len(seeds) != len(models):
        raise SpecError(f"{len(seeds)} seeds for {len(models)} tables")
    return fit_models(
        models,
        backend,
        seeds,
        progress,
        iterations=iterations,
        stage=stage,
        vectorize=vectorize,
        prepare_s=time.perf_counter() - t0,
        starts=starts,
    )


@computes
def fit_models(
    models: Sequence[CalibrationModel],
    backend: str,
    seeds: Sequence[int],
    progress: Callable[[int], None] | None = None,
    *,
    iterations: Callable[[int], None] | None = None,
    stage: Callable[[str], None] | None = None,
    vectorize: bool | None = None,
    prepare_s: float = 0.0,
    starts: Sequence[np.ndarray | None] | None = None,
) -> FitBatch:
    """:func:`fit_many` on assembled models of one structure (datasets built without tables,
    e.g. simulated from the prior by :mod:`bayescal.validation.sbc`; their :meth:`FitBatch.fit` would
    report against the original table, so use ``draws`` and ``diagnostics``).

    ``vectorize`` runs the MAP searches as one vmapped program, the same Newton
    steps batched (default: on an accelerator only; on a 2-core CPU 32 seed-000
    datasets took 1.10 s vectorised against 1.08 s one by one, since each search
    is already a few milliseconds of small, latency-bound operations, and the
    batched program's first search, compiling it, 10.4 s;
    ``benchmarks/results/batched_map.md``).
    """
    if vectorize is None:
        vectorize = jax.default_backend() != "cpu"
    say = stage or (lambda message: None)
    if any(pools(m) for m in models):
        say("guiding the pooled channels: each channel's own Laplace fit (the unpooled model)")
        models = guide_pooled(models)
    say("finding the posterior mode (the first fit of a model structure compiles it; cached afterwards)")
    program = program_for(models[0])
    timings = {"prepare": prepare_s}
    t = time.perf_counter()
    given = list(starts) if starts is not None else [None] * len(models)
    begin = [initial_point(m, program) if s is None else jnp.asarray(s) for m, s in zip(models, given, strict=True)]
    if vectorize:
        modes = laplace_many(program, [m.data for m in models], begin)
    else:
        modes = [laplace(program, m.data, s) for m, s in zip(models, begin, strict=True)]
    timings["map"] = time.perf_counter() - t
    t = time.perf_counter()
    samples = backends.get(backend).sample_many(
        models, program, modes, list(seeds), progress=progress, iterations=iterations, stage=say
    )
    for draws, mode in zip(samples, modes, strict=True):
        draws.extra = {"map_converged": mode.converged, "hessian_positive_definite": mode.positive_definite} | (
            draws.extra
        )
    timings[backend] = time.perf_counter() - t
    say("diagnostics, misfit checks and the posterior in physical units")
    return FitBatch(
        models=tuple(models),
        backend=backend,
        seeds=tuple(seeds),
        samples=tuple(samples),
        modes=tuple(modes),
        timings=timings,
        program=program,
    )


def with_data(model: CalibrationModel, **arrays) -> CalibrationModel:
    """``model`` with some data arrays replaced (same shapes: same compiled program)."""
    return replace(model, data=model.data._replace(**arrays))
