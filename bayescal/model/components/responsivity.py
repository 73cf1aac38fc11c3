"""Responsivity that changes with sensor temperature: a temperature coefficient of the gain.

Physics: a silicon sensor's quantum efficiency changes with temperature (the band gap narrows
as it warms, so red and near-infrared responsivity rises, by up to ~1 %/K beyond 900 nm), and
the sense node's conversion gain and the amplifier gain drift with it.  Over a calibration's
range of temperatures this is a factor on the linear signal,

    S(x exp(c_ch (T - T_ref)))

with one coefficient ``c_ch`` per channel (per degC; the bands differ).  The effect is fitted
when the table's illuminated rows were measured at two or more temperatures (a
``temperature_c`` column); a calibration at one temperature says nothing about ``c`` and leaves
the effect out.  Predictions at a temperature never measured carry the coefficient's posterior;
temperatures outside the calibrated range are flagged as extrapolations.

Prior: ``c_ch ~ Normal(0, coefficient_prior_sd)``, 1 %/K by default (wider than any silicon
sensor's visible-band coefficient, ~0.1-0.5 %/K).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from bayescal.errors import SpecError, TableError
from bayescal.io.checks import require_spread
from bayescal.io.limits import check_value
from bayescal.model.components.base import FactorEffect
from bayescal.model.components.temperature import COLUMN, ChannelCoefficients, true_coefficients

__all__ = ["ResponsivityTemperature", "ResponsivitySpec", "ResponsivityTerm"]

#: its per-row input in ``ModelData.extra``: T - T_ref (degC)
INPUT = "responsivity.delta_c"


@dataclass(frozen=True)
class ResponsivitySpec:
    """``[responsivity]``: a temperature coefficient of each channel's gain.

    ``temperature``: ``"auto"`` (default) fits it when the illuminated rows were measured at two or
    more temperatures (``temperature_c`` column), ``true`` always (the table must record the
    temperature), ``false`` never.  ``reference_c``: the temperature the gains refer to.
    ``coefficient_prior_sd``: prior sd of each channel's coefficient, per degC.
    """

    temperature: Literal[True, False, "auto"] = "auto"
    reference_c: float = 20.0
    coefficient_prior_sd: float = 0.01

    def __post_init__(self) -> None:
        check_value(self.reference_c, "temperature_c", "responsivity.reference_c")
        if not self.coefficient_prior_sd > 0:
            raise SpecError("responsivity.coefficient_prior_sd must be > 0")


@dataclass(frozen=True)
class ResponsivityTemperature(FactorEffect):
    """``exp(c_ch (T - T_ref))`` on the effective stimulus of every illuminated row."""

    section = "responsivity"
    spec_class = ResponsivitySpec
    sites = {"responsivity_tc": ("channel",)}
    reported = {"responsivity_tc": ("channel",)}

    spec: ResponsivitySpec
    n_channels: int

    @staticmethod
    def forward(coefficient, delta_c, xp=np):
        """The factor ``exp(c (T - T_ref))`` on the effective stimulus."""
        return xp.exp(coefficient * delta_c)

    @classmethod
    def build(cls, section: ResponsivitySpec, spec, frame) -> ResponsivityTemperature | None:
        if section.temperature is False:
            return None
        if COLUMN not in frame:
            if section.temperature is True:
                raise TableError(
                    f"responsivity.temperature = true needs a '{COLUMN}' column (sensor temperature, degC)",
                    column=COLUMN,
                )
            return None
        lit = frame["stimulus"].to_numpy() > 0
        if section.temperature == "auto" and np.unique(frame.loc[lit, COLUMN]).size < 2:
            return None
        require_spread(frame.loc[lit, COLUMN].to_numpy(dtype=float), "responsivity.temperature", COLUMN)
        return cls(section, frame["channel"].nunique())

    def inputs(self, frame) -> dict[str, np.ndarray]:
        return {INPUT: frame[COLUMN].to_numpy(dtype=float) - self.spec.reference_c}

    def sample(self, data):
        import numpyro
        import numpyro.distributions as dist

        prior = dist.Normal(0.0, self.spec.coefficient_prior_sd).expand([self.n_channels]).to_event(1)
        coefficient = numpyro.sample("responsivity_tc", prior)
        import jax.numpy as jnp

        return self.forward(coefficient[data.channel], data.extra[INPUT], jnp)

    def describe(self) -> str:
        return f"responsivity: temperature coefficient per channel (reference {self.spec.reference_c:g} degC)"

    def physical(self, draws, ctx) -> dict[str, np.ndarray]:
        return {"responsivity_tc": draws["responsivity_tc"]}

    @classmethod
    def term(cls, section: ResponsivitySpec, spec, draws, frame) -> ResponsivityTerm | None:
        if "responsivity_tc" not in draws:
            return None
        return ResponsivityTerm.from_draws(draws["responsivity_tc"], frame, section.reference_c)

    @classmethod
    def truth(cls, params, rows, spec) -> np.ndarray:
        """``params``: ``coefficient_per_c`` (one value, or a table channel -> value) and
        ``reference_c`` (default 20); rows without a temperature are at the reference."""
        return cls.forward(*true_coefficients(params, rows, "responsivity", "coefficient_per_c"))


@dataclass(frozen=True)
class ResponsivityTerm(ChannelCoefficients):
    """The coefficient's posterior ``(S, C)`` as predictions use it."""

    def factor(self, channel, setting, n_draws: int) -> np.ndarray:
        """``exp(c (T - T_ref))`` per draw at the setting's temperature (its reference when not given)."""
        here = self.at(channel, setting, "responsivity")
        return np.ones(n_draws) if here is None else ResponsivityTemperature.forward(*here)
