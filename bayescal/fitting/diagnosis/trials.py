"""The fits a search compares: Laplace fits of the trial specs, two at a time, ranked by PSIS-LOO."""

from __future__ import annotations

import warnings
from concurrent.futures import ThreadPoolExecutor

from bayescal._parallel import workers
from bayescal.errors import FitFailedWarning
from bayescal.fitting.fit import fit
from bayescal.fitting.modegain import paired_gain
from bayescal.fitting.result import Fit
from bayescal.model.spec import ModelSpec

#: a switch is adopted when it raises elpd_loo by more than this many standard errors of the difference
EVIDENCE_SE = 2.0


def laplace_proxy(spec: ModelSpec) -> ModelSpec:
    """The spec whose Laplace fits stand for ``spec`` in the domain decision and the diagnosis: ``spec``
    itself, or with its channel pooling off where it pools (the Laplace backend cannot integrate the
    pooling scales; pooling changes the priors of the coefficients, not the equation the candidates
    differ in).  The user's backend then fits the pooled spec the search chose."""
    r, d = spec.response, spec.dark
    if not (r.pooled or d.pooled or r.gain_prior == "pooled"):
        return spec
    gain_prior = "lognormal" if r.gain_prior == "pooled" else r.gain_prior
    return spec.replace(response={"pooled": False, "gain_prior": gain_prior}, dark={"pooled": False})


def quiet_fit(table, spec, backend, seed, start=None) -> Fit:
    """A fit whose failures and warnings are the search's to judge, not the user's to read."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FitFailedWarning)
        warnings.simplefilter("ignore", UserWarning)
        return fit(table, spec, backend, seed=seed, start=start)


def fit_all(table, specs: list[ModelSpec], seed: int, starts: list | None = None) -> list[Fit]:
    """Laplace fits of ``specs``, one per core at a time in threads (each a compiled program that runs outside
    the interpreter's lock: on two cores the candidates of one step take about half the time), in order; a
    fit's own blocks then run one after the other (:func:`bayescal._parallel.parallel_map`).  ``starts``: where
    each mode search starts (a mode the screen found: then only polished)."""
    starts = list(starts) if starts is not None else [None] * len(specs)
    if workers(len(specs)) < 2:
        return [quiet_fit(table, spec, "laplace", seed, start) for spec, start in zip(specs, starts, strict=True)]
    with warnings.catch_warnings():  # here, once: the warning filters are the process's, not a thread's
        warnings.simplefilter("ignore", FitFailedWarning)
        warnings.simplefilter("ignore", UserWarning)
        with ThreadPoolExecutor(workers(len(specs))) as pool:
            pairs = list(zip(specs, starts, strict=True))
            return list(pool.map(lambda pair: fit(table, pair[0], "laplace", seed=seed, start=pair[1]), pairs))


def psis_loo(result: Fit):
    """PSIS-LOO of a fit, pointwise (its ``elpd_i`` pair candidates with the model so far)."""
    import arviz_stats

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        return arviz_stats.loo(result.posterior, pointwise=True)


def difference(current, candidate) -> tuple[float, float]:
    """elpd_loo of ``candidate`` minus that of ``current`` and the standard error of the difference."""
    return paired_gain(current.elpd_i, candidate.elpd_i)
