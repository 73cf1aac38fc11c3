"""Guides for pooled channels: what each channel's data alone say of a pooled value.

A pooled value ``theta_c ~ Normal(mu, tau)`` is drawn in coordinates whitened by its
conditional posterior (:func:`bayescal.model.components.priors.pooled_normal`), which needs a
Gaussian view of the channel's data: a centre and a spread per value.  Both come from the
Laplace fit of the *unpooled* twin of the model (every channel with its own wide prior), whose
mode is well defined, unlike the pooled model's joint mode at small ``tau``.  The guide only
shapes the coordinates NUTS moves in; the posterior is the pooled model's whatever it says.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from bayescal.inference.laplace import laplace
from bayescal.inference.program import program_for
from bayescal.inference.start import initial_point
from bayescal.model.assemble import CalibrationModel, build_model

__all__ = ["guide_pooled", "pools"]

#: the pooled site's latent in the unpooled twin, and how the guide reads it (unconstrained values)
_TWIN_SITE = {"logG": "G", "eta": "eta", "b0": "b0"}


def pools(model: CalibrationModel) -> bool:
    """The model draws a pooled value (it has a guide to set)."""
    return any(k.startswith("guide_") for k in model.data.extra)


def _unpooled(spec):
    gain_prior = "lognormal" if spec.response.gain_prior == "pooled" else spec.response.gain_prior
    return spec.replace(response={"pooled": False, "gain_prior": gain_prior}, dark={"pooled": False})


def guide_pooled(models: Sequence[CalibrationModel]) -> list[CalibrationModel]:
    """``models`` with the guides of their pooled values set from their unpooled twins' Laplace
    fits, in the unconstrained space (log gain, nonlinearity, offset): the mode, the conditional
    sd given every other latent (``1 / sqrt`` of the precision's diagonal; the values' view) and
    the marginal sd (the population mean's view, every channel's other latents free).

    Models without pooled values, and models without a table to refit (datasets built
    from arrays), are returned unchanged (their guide stays neutral: the non-centred form).
    """
    out = []
    for model in models:
        if not pools(model) or model.table is None:
            out.append(model)
            continue
        twin = build_model(model.table, _unpooled(model.spec))
        program = program_for(twin)
        fit = laplace(program, twin.data, initial_point(twin, program))
        if not (fit.converged and fit.positive_definite):
            out.append(model)  # no honest data view: keep the neutral guide
            continue
        center = program.unravel(np.asarray(fit.mode))
        cov = np.asarray(fit.cov)
        spread = program.unravel(1.0 / np.sqrt(np.clip(np.diag(np.linalg.inv(cov)), 1e-300, None)))
        marginal = program.unravel(np.sqrt(np.clip(np.diag(cov), 0.0, None)))
        extra = dict(model.data.extra)
        for site, latent in _TWIN_SITE.items():
            if f"guide_{site}_center" in extra:
                shape = extra[f"guide_{site}_center"].shape
                extra[f"guide_{site}_center"] = np.asarray(center[latent], dtype=float).reshape(shape)
                extra[f"guide_{site}_spread"] = np.asarray(spread[latent], dtype=float).reshape(shape)
                extra[f"guide_{site}_marginal"] = np.asarray(marginal[latent], dtype=float).reshape(shape)
        out.append(replace(model, data=model.data._replace(extra=extra)))
    return out
