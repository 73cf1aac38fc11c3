"""What the effects with a temperature coefficient per channel share: the table column they read, the
simulator's truth of a coefficient per channel, and the coefficients' posterior at a camera setting.

The responsivity's coefficient (:mod:`.responsivity`, a factor on the effective stimulus) and the
readout offset's (:mod:`.offset_temperature`, DN added to the reading) are both ``c_ch (T - T_ref)``
inside their own forward functions; this module holds the bookkeeping around that product, once.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Self

import numpy as np

from bayescal.errors import SpecError

__all__ = ["COLUMN", "ChannelCoefficients", "true_coefficients"]

#: the table column the temperature effects read: the sensor temperature of a row (degC)
COLUMN = "temperature_c"


def true_coefficients(params: Mapping[str, Any], rows, section: str, key: str) -> tuple[np.ndarray, np.ndarray]:
    """The simulator's coefficient and ``T - T_ref`` for every row, from ``[truth.effects.<section>]``:
    ``key`` (one value, or a table channel -> value) and ``reference_c`` (default 20); rows without a
    temperature are at the reference."""
    known = {key, "reference_c"}
    if set(params) - known:
        raise SpecError(f"[truth.effects.{section}] keys {sorted(set(params) - known)}; expected {sorted(known)}")
    coefficient = params.get(key, 0.0)
    if isinstance(coefficient, dict):
        coefficient = rows["channel"].map(lambda c: float(coefficient.get(c, 0.0))).to_numpy()
    temperature = rows[COLUMN].to_numpy(dtype=float) if COLUMN in rows else np.full(len(rows), np.nan)
    delta = np.where(np.isfinite(temperature), temperature - float(params.get("reference_c", 20.0)), 0.0)
    return np.asarray(coefficient, dtype=float), delta


@dataclass(frozen=True)
class ChannelCoefficients:
    """A coefficient per channel, its posterior draws ``(S, C)``, and the temperature it refers to."""

    coefficient: np.ndarray
    channels: tuple[str, ...]
    reference_c: float

    @classmethod
    def from_draws(cls, draws: np.ndarray, frame, reference_c: float) -> Self:
        """From reported draws ``(chain, draw, C)`` and the table the channels come from."""
        coef = np.asarray(draws, dtype=float)
        channels = tuple(dict.fromkeys(str(c) for c in frame["channel"]))
        return cls(coef.reshape((-1,) + coef.shape[2:]), channels, reference_c)

    def at(self, channel, setting, what: str) -> tuple[np.ndarray, float] | None:
        """The channel's draws and ``T - T_ref`` at the setting's temperature (None when it is not
        given: the reference); ``what`` names the effect in the error of a prediction without a channel."""
        if setting.temperature_c is None:
            return None
        if channel is None:
            raise SpecError(f"a temperature-dependent {what} needs the channel of the prediction")
        return self.coefficient[:, self.channels.index(str(channel))], setting.temperature_c - self.reference_c

    def flags(self, setting) -> list[str]:
        return []  # the calibrated range flags temperatures outside the measured ones
