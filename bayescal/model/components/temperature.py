"""What the effects with a temperature coefficient per channel share: the table column they read, the
simulator's truth of ``c_ch`` and ``T - T_ref``, and the coefficients' posterior at a camera setting.

The responsivity's coefficient (:mod:`.responsivity`, a factor on the effective stimulus) and the
readout offset's (:mod:`.offset_temperature`, DN added to the reading) are both ``c_ch (T - T_ref)``
inside their own forward functions; this module holds the bookkeeping around that product, once.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from bayescal.errors import SpecError
from bayescal.model.components.channels import ChannelDraws, per_row

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
    temperature = rows[COLUMN].to_numpy(dtype=float) if COLUMN in rows else np.full(len(rows), np.nan)
    delta = np.where(np.isfinite(temperature), temperature - float(params.get("reference_c", 20.0)), 0.0)
    return per_row(params.get(key, 0.0), rows), delta


@dataclass(frozen=True)
class ChannelCoefficients(ChannelDraws):
    """A temperature coefficient per channel, its posterior draws ``(S, C)``, and the temperature it
    refers to."""

    reference_c: float

    def at(self, channel, setting, what: str) -> tuple[np.ndarray, float] | None:
        """The channel's draws and ``T - T_ref`` at the setting's temperature (None when it is not
        given: the reference); ``what`` names the effect in the error of a prediction without a channel."""
        if setting.temperature_c is None:
            return None
        return self.of(channel, f"a temperature-dependent {what}"), setting.temperature_c - self.reference_c
