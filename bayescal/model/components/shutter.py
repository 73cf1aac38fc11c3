"""Shutter offset: the sensor integrates a little longer (or shorter) than the exposure it is set to.

Physics: a mechanical shutter opens and closes over a finite time, an electronic shutter adds the
charge collected while the readout starts; either way the sensor integrates ``t + t0`` for a
set exposure ``t`` (seed 000 Table 2: at 1/100 s the measured slope was 5 % above the one
derived from 1/250 s).  Relative to the reference exposure, where the gains are stated, the
effective stimulus of a row scales by

    f(t) = (1 + t0 / t) / (1 + t0 / t_ref)

which is 1 at the reference, grows for short exposures when ``t0 > 0`` and is the same for every
channel and gain.  Unlike the exposure setting factors (one free factor per measured exposure,
:mod:`bayescal.model.components.settings`), it predicts an exposure never measured from one
physical number; use it with ``settings.exposure_tolerance = 0`` when the departure is a shutter.

Off by default (``[shutter] enabled = true`` or ``"auto"``: fitted when the illuminated rows span
two or more exposures).  Prior: ``t0 ~ Normal(0, offset_prior_s)``, 1 ms.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from bayescal.errors import SpecError
from bayescal.model.components.base import FactorEffect, Nuisance

__all__ = ["ShutterOffset", "ShutterSpec", "ShutterTerm"]

#: its per-row input in ``ModelData.extra``: the set exposure (s)
INPUT = "shutter.exposure_s"


@dataclass(frozen=True)
class ShutterSpec:
    """``[shutter]``: an offset of the integration time, common to every exposure.

    ``enabled``: ``false`` (default), ``true``, or ``"auto"`` (when the illuminated rows span two or
    more exposures); ``offset_prior_s``: prior sd of the offset, seconds.
    """

    enabled: Literal[True, False, "auto"] = False
    offset_prior_s: float = 1e-3

    def __post_init__(self) -> None:
        if not self.offset_prior_s > 0:
            raise SpecError("shutter.offset_prior_s must be > 0")


@dataclass(frozen=True)
class ShutterOffset(FactorEffect):
    """``(1 + t0 / t) / (1 + t0 / t_ref)`` on the effective stimulus of every illuminated row."""

    section = "shutter"
    spec_class = ShutterSpec
    sites = {"shutter_offset_ms": ()}
    reported = {"shutter_offset_s": ()}

    spec: ShutterSpec
    reference_s: float

    @staticmethod
    def forward(offset_s, exposure_s, reference_s, xp=np):
        """The factor ``(1 + t0 / t) / (1 + t0 / t_ref)`` on the effective stimulus."""
        return (1.0 + offset_s / exposure_s) / (1.0 + offset_s / reference_s)

    @classmethod
    def build(cls, section: ShutterSpec, spec, frame) -> ShutterOffset | None:
        lit = frame["stimulus"].to_numpy() > 0
        several = np.unique(frame.loc[lit, "exposure_s"]).size >= 2
        if section.enabled is True or (section.enabled == "auto" and several):
            return cls(section, float(spec.reference.exposure_s))
        return None

    def inputs(self, frame) -> dict[str, np.ndarray]:
        return {INPUT: frame["exposure_s"].to_numpy(dtype=float)}

    def sample(self, data):
        import jax.numpy as jnp
        import numpyro
        import numpyro.distributions as dist

        # sampled in milliseconds, so the site is O(1) beside the model's other scaled parameters
        offset_ms = numpyro.sample("shutter_offset_ms", dist.Normal(0.0, 1e3 * self.spec.offset_prior_s))
        return self.forward(1e-3 * offset_ms, data.extra[INPUT], self.reference_s, jnp)

    def nuisances(self, level_sigma) -> dict[str, Nuisance]:
        sd = 1e3 * self.spec.offset_prior_s
        return {"shutter_offset_ms": Nuisance(sd, "the shutter's integration-time offset{}", unit="ms")}

    def describe(self) -> str:
        return f"shutter: integration-time offset (prior sd {1e3 * self.spec.offset_prior_s:g} ms)"

    def physical(self, draws, ctx) -> dict[str, np.ndarray]:
        return {"shutter_offset_s": 1e-3 * draws["shutter_offset_ms"]}

    @classmethod
    def term(cls, section: ShutterSpec, spec, draws, frame) -> ShutterTerm | None:
        if "shutter_offset_s" not in draws:
            return None
        return ShutterTerm(np.asarray(draws["shutter_offset_s"], dtype=float).ravel(), float(spec.reference.exposure_s))

    @classmethod
    def truth(cls, params, rows, spec) -> np.ndarray:
        """``params``: ``offset_s`` (the true integration-time offset, seconds)."""
        if set(params) - {"offset_s"}:
            raise SpecError(f"[truth.effects.shutter] keys {sorted(params)}; expected ['offset_s']")
        exposure = rows["exposure_s"].to_numpy(dtype=float)
        return cls.forward(float(params.get("offset_s", 0.0)), exposure, float(spec.reference.exposure_s))


@dataclass(frozen=True)
class ShutterTerm:
    """The offset's posterior ``(S,)`` as predictions use it."""

    offset_s: np.ndarray
    reference_s: float

    def factor(self, channel, setting, n_draws: int) -> np.ndarray:
        """The factor at the setting's exposure, per draw."""
        return ShutterOffset.forward(self.offset_s, setting.exposure_s, self.reference_s)

    def flags(self, setting) -> list[str]:
        return []  # an exposure outside the calibrated ones is flagged by the calibrated range
