"""Physical quantities from scaled posterior draws.

Each component reports its own quantities (``Component.physical``); this module adds the
papers' table ``DN = A0 + A1 L + ...`` at the reference setting, which three components make
together: the response's monomials, the dark component's level at the reference setting
(``A0``) and the sphere's common scale folded into the coefficients (docs/architecture.md,
section 4), both relative to the sphere (comparable with least squares on the same sphere
readings) and absolute.
"""

from __future__ import annotations

import numpy as np

from bayescal.model.assemble import CalibrationModel
from bayescal.model.components import Context, reported_dims, site_dims
from bayescal.model.components.sphere import fold_common_scale

__all__ = ["physical_draws", "dims"]


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
    ref = spec.reference
    measured = parts.dark.proportional or ref.gain in layout.gain_values
    a0 = np.stack(
        [
            parts.dark.offset_at(draws, c, ref.gain, ref.exposure_s, layout, ref.gain)
            if measured
            else np.full(draws["G"].shape[:2], np.nan)
            for c in range(len(layout.channels))
        ],
        axis=-1,
    )
    coef_rel = out["A_rel"].copy()
    coef_rel[..., 0] = a0
    coef_abs, scale = fold_common_scale(
        coef_rel, spec.sphere.common_rel, ctx.rng(0x5CA1E), spec.sphere.channel_scale_rel
    )
    out.update(gain=coef_abs[..., 1], gain_rel=coef_rel[..., 1], A_abs=coef_abs, A_rel=coef_rel, sphere_scale=scale)
    return {name: out[name] for name in reported_dims() if name in out}
