"""Data-driven starting point for MAP and NUTS.

Starting at prior medians lands optimisers on saturation plateaus (a huge
gain clips every point and the gradient vanishes).  A cheap moment estimate
puts them in the right basin: offsets from dark rows, gains from least
squares on unsaturated rows through those offsets, the excess scatter from
the residuals.
"""

from __future__ import annotations

from typing import Any

import jax.numpy as jnp
import numpy as np

from bayescal.inference.program import Program
from bayescal.model.assemble import CalibrationModel

__all__ = ["initial_point"]

#: the roll-off's knee (fraction of full scale) and sharpness ``p - 1`` at the start
ROLLOFF_START = (3.0, 3.0)


def initial_point(model: CalibrationModel, program: Program) -> jnp.ndarray:
    """Flat unconstrained starting vector for ``model``."""
    d = {k: np.asarray(v) for k, v in model.data._asdict().items()}
    parts = model.parts
    c, g = len(model.layout.channels), len(model.layout.gain_values)
    dark = d["u"] == 0
    ok = ~d["censored"] & ~dark
    prop = parts.dark.proportional
    b0 = _dark_offsets(d, dark, c, g, prop)
    offset = b0[d["channel"], 0] * d["g_rel"] if prop else b0[d["channel"], d["gset"]]
    gains = np.empty(c)
    resid = []
    for ch in range(c):
        m = ok & (d["channel"] == ch)
        x, y = d["u"][m], d["y"][m] - offset[m]
        gains[ch] = max(float(x @ y / (x @ x)), 1e-6)
        resid.append(y - gains[ch] * x)
    rms = float(np.sqrt(np.mean(np.concatenate(resid) ** 2)))
    init = {k: np.asarray(v) for k, v in program.unravel(program.z0).items()}
    values = _constrained_defaults(program, model)
    values.update({"b0": b0 if not prop else b0[:, :1], "G": gains})
    # pooled values (deterministic here, left out below) start at their guided conditional means: w = 0
    if "excess" in values:
        values["excess"] = max(rms, 1e-6)
    if "rolloff_knee" in values:  # a roll-off far above the data: the linear fit's basin, compressed gently
        values["rolloff_knee"], values["rolloff_sharpness"] = ROLLOFF_START
    values = {k: v for k, v in values.items() if k in init}
    return program.unconstrain({k: np.asarray(v, dtype=float) for k, v in values.items()}, model.data)


def _dark_offsets(d: dict, dark: np.ndarray, c: int, g: int, prop: bool) -> np.ndarray:
    cols = 1 if prop else g
    b0 = np.full((c, cols), np.nan)
    y = d["y"] / d["g_rel"] if prop else d["y"]
    for ch in range(c):
        for gi in range(cols):
            m = dark & (d["channel"] == ch) & ((d["gset"] == gi) | prop)
            if m.any():
                b0[ch, gi] = y[m].mean()
    fallback = np.nanmean(b0) if np.isfinite(b0).any() else 0.01
    return np.where(np.isfinite(b0), b0, fallback)


def _constrained_defaults(program: Program, model: CalibrationModel) -> dict[str, Any]:
    z0 = program.constrain(program.z0[None], model.data)
    return {k: np.asarray(v)[0] for k, v in z0.items()}
