"""Physical quantities from scaled posterior draws.

Each component reports its own quantities; this module adds the reference
offset ``A0`` and folds the sphere's common scale into the coefficients
(docs/architecture.md, section 4), giving the papers' table ``DN = A0 + A1 L + ...`` at
the reference setting both relative to the sphere (comparable with least
squares on the same sphere readings) and absolute.
"""

from __future__ import annotations

import numpy as np

from bayescal.model.assemble import CalibrationModel
from bayescal.model.components.sphere import fold_common_scale

__all__ = ["physical_draws", "DIMS"]

#: dimension names of each reported variable (beyond chain, draw)
DIMS: dict[str, list[str]] = {
    "G": ["channel"],
    "eta": ["channel", "nl_term"],
    "b0": ["channel", "gain_setting"],
    "b1": ["gain_setting"],
    "level_z": ["level"],
    "gain": ["channel"],
    "gain_rel": ["channel"],
    "A_rel": ["channel", "power"],
    "A_abs": ["channel", "power"],
    "nonlinearity": ["channel", "nl_term"],
    "dark_offset": ["channel", "gain_setting"],
    "dark_slope": ["gain_setting"],
    "dark_offset_ref": ["channel"],
    "level_error": ["level"],
    "gain_log": ["gain_free"],
    "exposure_log": ["exposure_free"],
    "tdi_log": ["tdi_free"],
    "setting_factor_gain": ["lit_gain_setting"],
    "setting_factor_exposure": ["exposure_setting"],
    "setting_factor_tdi": ["tdi_setting"],
}


def physical_draws(model: CalibrationModel, draws: dict[str, np.ndarray], seed: int) -> dict[str, np.ndarray]:
    """Reported quantities, each with leading ``(chain, draw)`` dims.

    ``seed`` drives the draws of the sphere's common scale.
    """
    spec, layout, parts = model.spec, model.layout, model.parts
    out: dict[str, np.ndarray] = {}
    resp = parts.response.physical(draws, layout.x_scale, layout.dn_scale)
    ref = spec.reference
    a0 = np.stack(
        [
            parts.dark.offset_dn(draws, c, ref.gain, ref.exposure_s, layout, ref.gain)
            if parts.dark.proportional or ref.gain in layout.gain_values
            else np.full(draws["G"].shape[:2], np.nan)
            for c in range(len(layout.channels))
        ],
        axis=-1,
    )
    coef_rel = resp["A_rel"].copy()
    coef_rel[..., 0] = a0
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0x5CA1E]))
    coef_abs, scale = fold_common_scale(coef_rel, spec.sphere.common_rel, rng)
    out["gain"] = coef_abs[..., 1]
    out["gain_rel"] = coef_rel[..., 1]
    out["A_abs"] = coef_abs
    out["A_rel"] = coef_rel
    if "nonlinearity" in resp:
        out["nonlinearity"] = resp["nonlinearity"]
    out.update(parts.dark.physical(draws, layout))
    out.update(parts.sphere.physical(draws, np.asarray(model.data.level_sigma)))
    out.update(parts.noise.physical(draws))
    out.update(parts.saturation.physical(draws))
    out.update(parts.settings.physical(draws, np.random.default_rng(np.random.SeedSequence([seed, 0x5E7]))))
    out["sphere_scale"] = scale
    return out
