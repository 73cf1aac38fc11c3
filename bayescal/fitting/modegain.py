"""What a candidate model gains in-sample at its posterior mode: the diagnosis's screen before a full fit.

A candidate of the diagnosis (:mod:`bayescal.fitting.diagnosis`) is judged by its gain in expected log
predictive density, PSIS-LOO over 4000 Laplace draws of a full fit.  Most candidates of a dataset the
library cannot explain gain nothing, and a full fit of each costs seconds (a monotone roll-off's, with a
quadrature in every evaluation, 7-9 s).  The gain of the log-likelihood at the candidate's mode over the
model's at its own, row by row, is as a rule larger than that gain: leaving a row out costs a model with
more parameters more than the model it nests (its effective number of parameters, ``p_loo``, is larger),
and a density at the mode rewards fitting the very rows it is judged on.  It is not a strict bound (the
posterior's average density can beat the density at the mode), so the screen keeps a margin: a candidate
whose in-sample gain stays at most :data:`SCREEN_SE` standard errors of its paired differences is taken
as unable to reach the two standard errors of elpd_loo that adoption needs, and only its mode is searched
(its value, gradient and Hessian programs, and the constrained sites' with the log-likelihood at the mode;
none of the draws, the checks or the PSIS smoothing of a full fit).  ``benchmarks/diagnosis_screen.py`` measures
the screen against PSIS-LOO on both independent simulators' departures: PSIS-LOO gained more than the
in-sample gain on 14 of 186 candidates, by at most 0.71 of the in-sample standard errors, and no
candidate screened out would have been adopted.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from typing import NamedTuple

import numpy as np

from bayescal._config import computes
from bayescal.inference.laplace import laplace
from bayescal.inference.program import program_for
from bayescal.inference.start import initial_point
from bayescal.io.table import MeasurementTable
from bayescal.model.assemble import build_model
from bayescal.model.spec import ModelSpec

__all__ = ["ModeFit", "Screen", "mode_fit", "mode_fits", "paired_gain", "screen", "SCREEN_SE"]

#: a candidate whose in-sample gain at its mode is at most this many standard errors of the paired
#: differences is screened out (adoption needs 2 of elpd_loo's; the in-sample gain, as a rule the larger,
#: fell short of elpd_loo's by at most 0.71 se on the independent simulators)
SCREEN_SE = 1.0


class ModeFit(NamedTuple):
    """The posterior mode of a model of a table (flat unconstrained: a full fit of the same structure starts
    its own search there) and each row's log-likelihood there."""

    loglik: np.ndarray
    converged: bool
    mode: np.ndarray | None = None


@computes
def mode_fit(table: MeasurementTable, spec: ModelSpec) -> ModeFit:
    """The mode of ``spec``'s posterior on ``table`` (the fit's own start and Newton search, stopped once
    converged) and the pointwise log-likelihood of every row there.  (Starting the search at the model so
    far's mode instead, the sites a candidate shares carried over, was measured slower: 20.5 s against 13 s
    for the 17 candidates of a stray-light dataset's first step.)"""
    model = build_model(table, spec)
    program = program_for(model)
    found = laplace(program, model.data, initial_point(model, program), polish=False)
    loglik = np.asarray(program.loglik(np.asarray(found.mode)[None], model.data))[0]
    ok = bool(found.converged and found.positive_definite and np.isfinite(loglik).all())
    return ModeFit(loglik, ok, np.asarray(found.mode) if ok else None)


@computes
def mode_fits(table: MeasurementTable, specs: dict[str, ModelSpec], workers: int | None = None) -> dict[str, ModeFit]:
    """:func:`mode_fit` of each spec, ``workers`` at a time in threads (default: one per core,
    :func:`bayescal._parallel.workers`): a new structure's programs are mostly loaded and run outside the
    interpreter, so two cores load two at once."""
    from bayescal._parallel import workers as threads

    workers = workers or threads(len(specs))
    if workers <= 1 or len(specs) <= 1:
        return {name: mode_fit(table, spec) for name, spec in specs.items()}
    with ThreadPoolExecutor(workers) as pool:
        done = {name: pool.submit(mode_fit, table, spec) for name, spec in specs.items()}
        return {name: future.result() for name, future in done.items()}


def paired_gain(current: np.ndarray, candidate: np.ndarray) -> tuple[float, float]:
    """Sum of ``candidate - current`` over rows, and its standard error (``sqrt(n) * sd`` of the paired
    differences, as for elpd_loo)."""
    d = np.asarray(candidate, dtype=float).ravel() - np.asarray(current, dtype=float).ravel()
    return float(d.sum()), float(np.sqrt(d.size * np.var(d)))


class Screen(NamedTuple):
    """A candidate's in-sample gain at its mode over the model so far's, its se, and whether it is screened
    out (both modes found and the gain at most :data:`SCREEN_SE` se)."""

    gain: float
    se: float
    out: bool


def screen(current: ModeFit, candidate: ModeFit) -> Screen:
    """The screen of ``candidate`` against ``current`` (see the module docstring)."""
    gain, se = paired_gain(current.loglik, candidate.loglik)
    return Screen(gain, se, bool(current.converged and candidate.converged and gain <= SCREEN_SE * se))
