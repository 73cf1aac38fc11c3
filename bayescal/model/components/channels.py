"""What the effects with a coefficient per channel share: the simulator's truth of such a coefficient,
and its posterior draws looked up by channel name (the responsivity's and the readout offset's
temperature coefficients, :mod:`.temperature`; the amplifier glow, :mod:`.glow`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Self

import numpy as np

from bayescal.errors import SpecError

__all__ = ["ChannelDraws", "per_row"]


def per_row(value: Any, rows) -> np.ndarray:
    """A truth's coefficient at every row of a simulated table: one value for every channel, or a table
    channel -> value (channels it does not name: 0)."""
    if isinstance(value, dict):
        return rows["channel"].map(lambda c: float(value.get(c, 0.0))).to_numpy(dtype=float)
    return np.full(len(rows), float(value))


@dataclass(frozen=True)
class ChannelDraws:
    """A coefficient's posterior draws per channel, ``(S, C)``, and the channels' names."""

    coefficient: np.ndarray
    channels: tuple[str, ...]

    @classmethod
    def from_draws(cls, draws: np.ndarray, frame, *rest: Any) -> Self:
        """From reported draws ``(chain, draw, C)`` and the table the channels come from (``rest``: the
        subclass's further fields)."""
        coef = np.asarray(draws, dtype=float)
        channels = tuple(dict.fromkeys(str(c) for c in frame["channel"]))
        return cls(coef.reshape((-1,) + coef.shape[2:]), channels, *rest)

    def of(self, channel: str | None, what: str) -> np.ndarray:
        """The draws of ``channel``; ``what`` names the effect in the error of a prediction without one."""
        if channel is None:
            raise SpecError(f"{what} differs by channel: a prediction needs its channel")
        return self.coefficient[:, self.channels.index(str(channel))]

    def flags(self, setting: Any) -> list[str]:
        return []  # the calibrated range flags settings outside the measured ones
