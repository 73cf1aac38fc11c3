"""A fit that diagnoses itself: when its checks fail, the search (or one flexible model) finds what the
library has that describes the data; a fit that passes is screened with what the table records."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from bayescal.fitting.diagnosis.candidates import other_domain, screen_candidates
from bayescal.fitting.diagnosis.domain import decide_domain
from bayescal.fitting.diagnosis.doubts import range_check, rival_doubt, structure_doubt
from bayescal.fitting.diagnosis.found import Diagnosis
from bayescal.fitting.diagnosis.search import diagnose
from bayescal.fitting.fit import fit
from bayescal.fitting.result import Fit
from bayescal.io.table import MeasurementTable
from bayescal.model.spec import ModelSpec


def kinds_calibration(spec: ModelSpec) -> bool:
    """A camera calibration (not another model kind, such as a film's)."""
    from bayescal.model import kinds

    return kinds.kind_of(spec) == kinds.CALIBRATION


#: per-channel lamp level errors whose posterior means rank-correlate this strongly with the level's stimulus
#: in some channel are a response shape (a roll-off) absorbed level by level, not a lamp's scatter: with 12


def misfit_only(result: Fit) -> bool:
    """The fit failed its checks of the data (misfit, held-out settings, outlying rows), not its sampler."""
    d = result.diagnostics
    sampler = d.divergences > 0 or (np.isfinite(d.max_rhat) and d.max_rhat > 1.01)
    return not d.ok and not sampler and result.posterior is not None


def fit_diagnosed(
    table: MeasurementTable,
    spec: ModelSpec,
    backend: str = "nuts",
    *,
    seed: int = 0,
    stage=None,
    screen: bool = True,
    strategy: str = "search",
    **kw,
) -> tuple[Fit, Diagnosis | None]:
    """:func:`~bayescal.fitting.fit.fit`, and when the fit does not describe its data, :func:`diagnose`
    (``strategy="search"``) or one flexible model (``"flexible"``, :mod:`bayescal.fitting.flexible`): the
    backend then fits the spec found.  A fit that passes is screened with the candidates over what the table
    records (``screen``; :func:`screen_candidates`).  Returns the final fit (its diagnostics carry the
    diagnosis) and the diagnosis (None when nothing was adopted, or the first fit failed in its sampler)."""
    if backend == "lsq" or not kinds_calibration(spec):  # nothing to diagnose: the baseline, another kind
        return fit(table, spec, backend, seed=seed, stage=stage, **kw), None
    if stage is not None and other_domain(spec, table) is not None:
        stage("where the nonlinearity arises: charge or output, by PSIS-LOO (Laplace)")
    spec, domain, laplace = decide_domain(table, spec, seed)
    if laplace is None and backend == "laplace":
        laplace = fit(table, spec, backend, seed=seed, stage=stage, **kw)
    first = (
        laplace
        if backend == "laplace" and laplace is not None
        else fit(table, spec, backend, seed=seed, stage=stage, **kw)
    )
    if domain is not None:
        first = replace(first, diagnostics=first.diagnostics.with_check("domain", [], domain))
    if first.ok and screen:
        return _screened(table, spec, backend, first, laplace, seed, stage, kw)
    if first.ok or not misfit_only(first):
        return first, None
    if strategy == "flexible":
        return _flexible(table, spec, backend, first, seed, stage, kw)
    if stage is not None:
        stage("the fit does not describe its data: trying what the library has (Laplace, PSIS-LOO)")
    found = diagnose(table, spec, seed, base=laplace)  # the Laplace fit of this spec, when one was made
    final = first
    if found.adopted:
        if stage is not None:
            stage(f"refitting with {' and '.join(found.adopted)}")
        reused = found.fit if backend == "laplace" and not kw else None  # the diagnosis's own fit of that spec
        final = reused if reused is not None else fit(table, found.spec, backend, seed=seed, **kw)
    diag = final.diagnostics.with_check("diagnosis", [], found.to_dict())
    if found.adopted and final.ok and "order" in found.changes().get("response", {}):
        diag = diag.with_check("range", *range_check(table, found.spec, final, seed))
    doubt = rival_doubt(final, found) if found.adopted and final.ok else None
    if doubt is not None:
        diag = diag.with_check("structure", [], doubt)
    if not found.adopted or not final.ok:
        problem = (
            "nothing in the library explains the data (see diagnosis)"
            if not found.adopted
            else f"with {' and '.join(found.adopted)} the fit still fails (see diagnosis)"
        )
        diag = replace(diag, ok=False, problems=tuple(dict.fromkeys(diag.problems + (problem,))))
    return replace(final, diagnostics=diag), found


def _flexible(table, spec, backend, first: Fit, seed: int, stage, kw) -> tuple[Fit, Diagnosis | None]:
    """The spec with every term the table can inform on (:func:`~bayescal.fitting.flexible.flexible_changes`),
    fitted once by the user's backend; it fails (exit 3) when even that does not describe the data."""
    from bayescal.fitting.flexible import flexible_changes

    changes = flexible_changes(spec, table)
    if not changes:
        return first, None
    if stage is not None:
        stage("the fit does not describe its data: one model with every term the table can inform")
    trial = spec.replace(**changes)
    final = fit(table, trial, backend, seed=seed, **kw)
    terms = tuple(
        f"[{section}] " + ", ".join(f"{k} = {v!r}" for k, v in keys.items()) for section, keys in changes.items()
    )
    found = Diagnosis(terms, trial, bool(final.ok), [], final, merged=changes)
    diag = final.diagnostics.with_check("diagnosis", [], found.to_dict() | {"strategy": "flexible"})
    if not final.ok:
        problem = "with every term the library has for this table on, the fit still fails (see diagnosis)"
        diag = replace(diag, ok=False, problems=tuple(dict.fromkeys(diag.problems + (problem,))))
    return replace(final, diagnostics=diag), found


def _screened(
    table, spec, backend, first: Fit, laplace: Fit | None, seed: int, stage, kw
) -> tuple[Fit, Diagnosis | None]:
    """A fit that passes its checks, screened with the candidates over what the table records
    (:func:`screen_candidates`): a departure that follows the time or the temperature, or a dark signal
    that grows faster than the exposure, can pass every check of the residuals while its offsets are off.
    A candidate adopted by PSIS-LOO replaces the fit only when its own fit passes too."""
    if not screen_candidates(spec, table):
        return first, None
    if stage is not None:
        stage("screening what the table records (time, temperature, dark exposures) by PSIS-LOO (Laplace)")
    found = diagnose(
        table, spec, seed, base=laplace if laplace is not None else None, offered=screen_candidates, by_mode=False
    )
    diag = first.diagnostics.with_check("screen", [], found.to_dict())
    if found.adopted and found.explained:
        reused = found.fit if backend == "laplace" and not kw else None
        final = reused if reused is not None else fit(table, found.spec, backend, seed=seed, **kw)
        if not final.ok:  # the adopted model fails where the spec's passed: keep the spec's
            return replace(first, diagnostics=diag), None
        return replace(final, diagnostics=final.diagnostics.with_check("diagnosis", [], found.to_dict())), found
    doubt = structure_doubt(first, found)
    if doubt is None:
        return replace(first, diagnostics=diag), None
    name, info = doubt
    trial_spec = found.trials[name][0]
    final = fit(table, trial_spec, backend, seed=seed, **kw)
    if not final.ok:
        return replace(first, diagnostics=diag.with_check("structure", [], info)), None
    return replace(
        final, diagnostics=final.diagnostics.with_check("screen", [], found.to_dict()).with_check("structure", [], info)
    ), None


#: a candidate the data cannot tell from the spec (elpd within this many se) that moves a reported coefficient
