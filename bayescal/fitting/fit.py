"""Fit a calibration model to one table with any backend.

``fit(table, spec, backend)`` is :func:`~bayescal.fitting.batch.fit_many` of one table: it
assembles the model, finds a data-driven start and the posterior mode, runs the backend
(``nuts`` by default, ``laplace``, ``emcee``, ``blackjax``; :mod:`bayescal.inference.registry`)
and diagnoses the draws (:mod:`bayescal.fitting.result`).  ``lsq`` is the papers' least-squares
baseline alone.  The Bayesian backends return draws of the same reported quantities, so their
speed and error can be compared (docs/architecture.md, section 4); the least-squares baseline is
always computed beside them.
"""

from __future__ import annotations

import time

import pandas as pd

from bayescal._config import computes
from bayescal.errors import SpecError
from bayescal.fitting.batch import fit_many
from bayescal.fitting.result import Fit
from bayescal.inference import registry as backends
from bayescal.inference.diagnostics import Diagnostics
from bayescal.inference.lsq import lsq_baseline
from bayescal.inference.registry import BASELINE
from bayescal.io.table import MeasurementTable
from bayescal.model import kinds
from bayescal.model.assemble import CalibrationModel, build_model
from bayescal.model.spec import ModelSpec

__all__ = ["fit", "BACKENDS"]

#: the posterior backends (:mod:`bayescal.inference.registry`) and the least-squares baseline
BACKENDS = tuple(backends.names(baseline=True))


@computes
def fit(
    table: MeasurementTable,
    spec: ModelSpec,
    backend: str = "nuts",
    *,
    seed: int = 0,
    progress=None,
    strict: bool = False,
    stage=None,
    start=None,
) -> Fit:
    """Fit ``spec`` to ``table``: the posterior of every calibration quantity, judged by its diagnostics,
    beside the least-squares baseline.

    Parameters
    ----------
    table : MeasurementTable
        The measurements (:func:`~bayescal.load_table`; a film's table for a film spec).
    spec : ModelSpec
        The model (:func:`~bayescal.load_spec`): the sensor's facts and the components to assemble.
    backend : {"nuts", "laplace", "emcee", "blackjax", "lsq"}
        Inference method (docs/architecture.md, section 4).
    seed : int
        Seed of every random number (chains, jitter, sphere-scale draws).
    progress : callable, optional
        ``progress(iterations_done)`` for the MCMC backends (per chain, warmup included;
        emcee: ensemble steps, burn-in included).
    strict : bool
        Raise :class:`~bayescal.errors.FitFailedError` instead of warning when diagnostics fail.
    stage : callable, optional
        ``stage(message)`` is called as each stage starts (model, mode, sampling, checks).
    start : array, optional
        Where the mode search starts (a flat unconstrained vector of this structure; default: the
        data-driven start).

    Returns
    -------
    Fit
        The draws, the summaries (``summary``, ``comparison``), the diagnostics and the baseline;
        ``save(dir)`` writes them, :meth:`~bayescal.Calibration.from_fit` turns them into predictions.

    Examples
    --------
    >>> import bayescal as bc
    >>> spec = bc.load_spec("seed000")
    >>> table = bc.simulate(spec, bc.load_design("seed000"), seed=1).table
    >>> result = bc.fit(table, spec, "laplace", seed=1)  # doctest: +SKIP
    >>> result.ok  # doctest: +SKIP
    True
    """
    if kinds.kind_of(spec) != kinds.CALIBRATION:  # another model kind fits itself (bayescal.model.kinds)
        return kinds.get(kinds.kind_of(spec)).fit(
            table, spec, backend, seed=seed, progress=progress, strict=strict, stage=stage
        )
    if backend not in BACKENDS:
        raise SpecError(f"unknown backend '{backend}'; expected one of {', '.join(BACKENDS)}")
    if backend != BASELINE:
        batch = fit_many([table], spec, backend, seeds=[seed], iterations=progress, stage=stage, starts=[start])
        return batch.fit(0, strict=strict)
    t0 = time.perf_counter()
    model = build_model(table, spec)
    lsq = lsq_baseline(table, orders=range(1, spec.response.order + 1), full_scale=spec.full_scale)
    return Fit(model, backend, seed, None, _lsq_diagnostics(model, lsq), lsq, {"prepare": time.perf_counter() - t0})


def _lsq_diagnostics(model: CalibrationModel, lsq: pd.DataFrame) -> Diagnostics:
    """The baseline's verdict: every channel got a least-squares fit at some setting."""
    fitted = set(lsq["channel"]) if len(lsq) else set()
    missing = [c for c in model.layout.channels if c not in fitted]
    problems = (
        (
            f"least squares fitted nothing for channel(s) {', '.join(missing)}: no exposure/gain/TDI setting "
            f"has {model.spec.response.order + 2} or more distinct unsaturated levels",
        )
        if missing
        else ()
    )
    return Diagnostics(not problems, problems, extra={"note": "least squares: no posterior"})
