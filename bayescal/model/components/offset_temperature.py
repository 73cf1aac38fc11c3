"""Offset that changes with sensor temperature: the readout's black level drifts as the camera warms.

Physics: the ADC's bias and the output amplifier's offset voltage are set by analogue references
that drift with temperature, typically a fraction of a DN to a few DN per kelvin at the output, and
differently for each channel's readout path (EMVA 1288 4.0, section 8.1, asks for the dark signal
at several temperatures for this reason).  Unlike the dark current, which doubles every few degrees
but grows with the exposure (:mod:`bayescal.model.components.dark`), this level is there at zero
exposure and zero light::

    offset(T) = b0 + o_ch (T - T_ref)

one coefficient ``o_ch`` per channel (DN per degC), added to every reading, dark or lit.  Dark
frames at two or more temperatures (and at two or more exposures, so the dark current's own
temperature law is told apart from it) measure it; predictions at a temperature never measured
carry its posterior.

Off by default (``[offset_temperature] enabled = true``, or ``"auto"``: fitted when the dark
rows span two or more temperatures).  Prior: ``o_ch ~ Normal(0, prior_dn_per_c)``, 2 DN/degC.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from bayescal.errors import SpecError, TableError
from bayescal.io.checks import require_spread
from bayescal.io.limits import check_value
from bayescal.model.components.base import OffsetEffect
from bayescal.model.components.temperature import COLUMN, ChannelCoefficients, true_coefficients

__all__ = ["OffsetTemperature", "OffsetTemperatureSpec", "OffsetTemperatureTerm"]

#: its per-row input in ``ModelData.extra``: T - T_ref (degC; 0 where no temperature was recorded)
INPUT = "offset_temperature.delta_c"


@dataclass(frozen=True)
class OffsetTemperatureSpec:
    """``[offset_temperature]``: an offset per degC of each channel's readout.

    ``enabled``: ``false`` (default), ``true`` (the table must record ``temperature_c``), or
    ``"auto"`` (when the dark rows span two or more temperatures).  ``reference_c``: the
    temperature the offsets refer to.  ``prior_dn_per_c``: prior sd of each channel's coefficient.
    """

    enabled: Literal[True, False, "auto"] = False
    reference_c: float = 20.0
    prior_dn_per_c: float = 2.0

    def __post_init__(self) -> None:
        check_value(self.reference_c, "temperature_c", "offset_temperature.reference_c")
        if not self.prior_dn_per_c > 0:
            raise SpecError("offset_temperature.prior_dn_per_c must be > 0")


@dataclass(frozen=True)
class OffsetTemperature(OffsetEffect):
    """``o_ch (T - T_ref)`` DN added to every reading of channel ``ch``."""

    section = "offset_temperature"
    spec_class = OffsetTemperatureSpec
    sites = {"offset_tc": ("channel",)}
    reported = {"offset_tc_dn_per_c": ("channel",)}

    spec: OffsetTemperatureSpec
    n_channels: int

    @staticmethod
    def forward(coefficient, delta_c):
        """The DN ``o (T - T_ref)`` added to a reading."""
        return coefficient * delta_c

    @classmethod
    def build(cls, section: OffsetTemperatureSpec, spec, frame) -> OffsetTemperature | None:
        if section.enabled is False:
            return None
        if COLUMN not in frame:
            if section.enabled is True:
                raise TableError(
                    f"offset_temperature.enabled = true needs a '{COLUMN}' column (sensor temperature, degC)",
                    column=COLUMN,
                )
            return None
        dark = frame["stimulus"].to_numpy() == 0
        if section.enabled == "auto" and np.unique(frame.loc[dark, COLUMN].dropna()).size < 2:
            return None
        require_spread(frame[COLUMN].to_numpy(dtype=float), "offset_temperature.enabled", COLUMN)
        return cls(section, frame["channel"].nunique())

    @classmethod
    def candidates(cls, section: OffsetTemperatureSpec, spec, frame) -> dict[str, dict]:
        """Offered when the dark rows span two or more temperatures."""
        dark = frame["stimulus"].to_numpy() == 0
        if section.enabled is True or COLUMN not in frame or frame.loc[dark, COLUMN].nunique() < 2:
            return {}
        name = "an offset that drifts with the sensor temperature (per channel)"
        return {name: {"offset_temperature": {"enabled": True}}}

    def inputs(self, frame) -> dict[str, np.ndarray]:
        temperature = frame[COLUMN].to_numpy(dtype=float)
        return {INPUT: np.where(np.isfinite(temperature), temperature - self.spec.reference_c, 0.0)}

    def sample(self, data):
        import numpyro
        import numpyro.distributions as dist

        prior = dist.Normal(0.0, self.spec.prior_dn_per_c).expand([self.n_channels]).to_event(1)
        coefficient = numpyro.sample("offset_tc", prior)
        return self.forward(coefficient[data.channel], data.extra[INPUT])

    def describe(self) -> str:
        return f"offset: a temperature coefficient per channel (reference {self.spec.reference_c:g} degC)"

    def physical(self, draws, ctx) -> dict[str, np.ndarray]:
        return {"offset_tc_dn_per_c": draws["offset_tc"]}

    @classmethod
    def term(cls, section: OffsetTemperatureSpec, spec, draws, frame) -> OffsetTemperatureTerm | None:
        if "offset_tc_dn_per_c" not in draws:
            return None
        return OffsetTemperatureTerm.from_draws(draws["offset_tc_dn_per_c"], frame, section.reference_c)

    @classmethod
    def truth(cls, params, rows, spec) -> np.ndarray:
        """``params``: ``dn_per_c`` (one value, or a table channel -> value) and ``reference_c``
        (default 20); rows without a temperature are at the reference."""
        return cls.forward(*true_coefficients(params, rows, "offset_temperature", "dn_per_c"))


@dataclass(frozen=True)
class OffsetTemperatureTerm(ChannelCoefficients):
    """The coefficients' posterior ``(S, C)`` as predictions use them."""

    def offset(self, channel, setting, n_draws: int) -> np.ndarray:
        """``o (T - T_ref)`` DN per draw at the setting's temperature (none when it is not given)."""
        here = self.at(channel, setting, "offset")
        return np.zeros(n_draws) if here is None else OffsetTemperature.forward(*here)
