"""Physical quantities from scaled posterior draws.

Each component reports its own quantities (``Component.physical``); this module adds the
papers' table ``DN = A0 + A1 L + ...`` at the reference setting, which the components make
together: the response's monomials, the equation's offset terms at the reference setting
(``A0``: the dark level and the offset effects, evaluated as predictions evaluate them) and the
sphere's common scale folded into the coefficients (docs/architecture.md,
section 4), both relative to the sphere (comparable with least squares on the same sphere
readings) and absolute.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from bayescal.model.assemble import CalibrationModel
from bayescal.model.basis import response_monomials
from bayescal.model.components import Context, offset_terms, reported_dims, site_dims
from bayescal.model.components.sphere import fold_common_scale
from bayescal.model.setting import Setting

__all__ = ["physical_draws", "dims", "POOLED", "pooled_quantities", "reported_from_pooled"]

#: a camera's quantities that a fleet pools, per channel, before its nonlinearity coefficients (``eta1``, ...):
#: the log gain against the sphere's reading (``log A1``) and the offset at the reference setting (``A0``, DN)
POOLED = ("log_gain", "offset")


def dims() -> dict[str, list[str]]:
    """Dimension names of every sampled site and reported quantity (beyond chain, draw)."""
    return {k: list(v) for k, v in {**site_dims(), **reported_dims()}.items()}


def physical_draws(model: CalibrationModel, draws: dict[str, np.ndarray], seed: int) -> dict[str, np.ndarray]:
    """Reported quantities, each with leading ``(chain, draw)`` dims.

    ``seed`` drives the draws of the sphere's common scale and of the settings' spreads.
    """
    spec, layout, parts = model.spec, model.layout, model.parts
    ctx = Context(layout, np.asarray(model.data.level_sigma), seed)
    out: dict[str, np.ndarray] = {}
    for component in parts.components:
        out.update(component.physical(draws, ctx))
    coef_rel = out["A_rel"].copy()
    coef_rel[..., 0] = _offsets_at_reference(model, out)
    coef_abs, scale = fold_common_scale(
        coef_rel, spec.sphere.common_rel, ctx.rng(0x5CA1E), spec.sphere.channel_scale_rel
    )
    out.update(gain=coef_abs[..., 1], gain_rel=coef_rel[..., 1], A_abs=coef_abs, A_rel=coef_rel, sphere_scale=scale)
    return {name: out[name] for name in reported_dims() if name in out}


def pooled_quantities(reported: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
    """A camera's quantities that a fleet pools (:data:`POOLED`, then ``eta1``, ...) from its reported
    draws: each ``(chain, draw, C)`` (docs/architecture.md, section 8).  A non-positive gain gives a
    non-finite log gain."""
    with np.errstate(divide="ignore", invalid="ignore"):
        out = {"log_gain": np.log(np.asarray(reported["gain_rel"], dtype=float))}
    out["offset"] = np.asarray(reported["A_rel"], dtype=float)[..., 0]
    eta = reported.get("nonlinearity")
    if eta is not None:
        out |= {f"eta{k + 1}": np.asarray(eta, dtype=float)[..., k] for k in range(np.shape(eta)[-1])}
    return out


def reported_from_pooled(values: Mapping[str, np.ndarray], spec: Any) -> dict[str, np.ndarray]:
    """The reported response quantities of pooled values (the inverse of :func:`pooled_quantities`):
    ``A_rel`` ``(..., C, order + 1)`` with ``A0`` the offset, ``gain_rel`` and, for a nonlinear
    response, ``nonlinearity`` ``(..., C, order - 1)``."""
    gain = np.exp(values["log_gain"])
    etas = sorted((k for k in values if k.startswith("eta")), key=lambda k: int(k[3:]))
    eta = np.stack([values[k] for k in etas], axis=-1) if etas else None
    full = spec.full_scale
    coef = response_monomials(gain / full, eta, spec.response.order) * full  # DN per stimulus^k, S(L) = f(gain L / FS)
    coef[..., 0] = values["offset"]
    out = {"A_rel": coef, "gain_rel": gain}
    if eta is not None:
        out["nonlinearity"] = eta
    return out


def _offsets_at_reference(model: CalibrationModel, out: dict[str, np.ndarray]) -> np.ndarray:
    """The offset terms' sum at the reference setting (reference temperature, start of the run) per
    channel, ``(chain, draw, C)``: the papers' ``A0`` (NaN where the reference gain has no dark rows)."""
    spec, layout = model.spec, model.layout
    lead = out["A_rel"].shape[:2]
    if not (model.parts.dark.proportional or spec.reference.gain in layout.gain_values):
        return np.full(lead + (len(layout.channels),), np.nan)
    dark, effects = offset_terms(spec, out, layout.channels, layout.gain_values, model.table.frame)
    terms = (dark, *effects)
    ref, n = Setting.at_reference(spec.reference), int(np.prod(lead))
    return np.stack(
        [sum((t.offset(c, ref, n) for t in terms), np.zeros(n)).reshape(lead) for c in layout.channels], axis=-1
    )
