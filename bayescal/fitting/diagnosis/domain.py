"""Where the nonlinearity arises (in the charge, before the gain, or in the output, after it), decided by the
data whenever gains are swept."""

from __future__ import annotations

from typing import Any

import numpy as np

from bayescal.fitting.diagnosis.candidates import other_domain
from bayescal.fitting.diagnosis.trials import EVIDENCE_SE, difference, laplace_proxy, psis_loo, quiet_fit
from bayescal.fitting.modegain import mode_fits, screen
from bayescal.fitting.result import Fit
from bayescal.io.table import MeasurementTable
from bayescal.model.spec import ModelSpec


def decide_domain(table: MeasurementTable, spec: ModelSpec, seed: int = 0) -> tuple[ModelSpec, dict | None, Fit | None]:
    """Where the nonlinearity arises, decided by the data whenever gains are swept: Laplace fits with it in
    the charge (before the gain) and in the output (after it), compared by PSIS-LOO; the other domain is
    taken when it gains more than :data:`EVIDENCE_SE` standard errors.  A charge-domain model fitted to a
    camera whose nonlinearity is the output's passes every check yet its offsets and gains cover the
    truth 0.37 of the time on the independent bench (benchmarks/results/misspecification.md).

    The other domain is screened by its mode first (:func:`~bayescal.fitting.modegain.screen`): when its
    in-sample gain is at most :data:`~bayescal.fitting.modegain.SCREEN_SE` standard errors it cannot be
    taken, and it is not fitted further (``elpd_diff_other`` is then None and ``mode_gain`` says why).

    Returns the chosen spec, the comparison (None when the table cannot tell), and the chosen
    spec's Laplace fit."""
    change = other_domain(spec, table)
    if change is None:
        return spec, None, None
    other = spec.replace(**change)
    info: dict[str, Any] = {"spec": spec.response.nonlinearity_domain, "other": other.response.nonlinearity_domain}
    modes = mode_fits(table, {"spec": laplace_proxy(spec), "other": laplace_proxy(other)})
    kept_out = screen(modes["spec"], modes["other"])
    info |= {"mode_gain": kept_out.gain, "mode_dse": kept_out.se}
    own = quiet_fit(table, laplace_proxy(spec), "laplace", seed)
    if kept_out.out:
        info |= {"elpd_diff_other": np.nan, "dse": np.nan, "chosen": info["spec"], "screened": True}
        return spec, info, own if laplace_proxy(spec) is spec else None
    fits = [own, quiet_fit(table, laplace_proxy(other), "laplace", seed)]
    diff, se = difference(*(psis_loo(f) for f in fits))
    take = diff > EVIDENCE_SE * se
    chosen = other if take else spec
    info |= {"elpd_diff_other": diff, "dse": se, "chosen": chosen.response.nonlinearity_domain, "screened": False}
    return chosen, info, fits[1 if take else 0] if laplace_proxy(spec) is spec else None
