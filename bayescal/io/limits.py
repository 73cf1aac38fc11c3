"""The physical limits of every number bayescal reads: one table, checked at the boundary.

A temperature below absolute zero, an exposure of 1e308 s or a negative radiance is never a
measurement; taken as one, it is fitted without a word or breaks the numerics far from where it
came in (an SVD that does not converge).  Every table column, spec key and command-line option
that holds a physical quantity is checked against its row of :data:`LIMITS`, and the message
names where the value came from, the value and the limit.

The limits are generous on purpose: they refuse what no sensor measures, not what is unusual
(a cooled CCD at -120 degC, an exposure of an hour, a gain of 1000 are all accepted).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["Limit", "LIMITS", "limit", "check_value"]


@dataclass(frozen=True)
class Limit:
    """The range of one physical quantity: ``low < x`` (or ``<=``), ``x <= high`` (or ``<``)."""

    quantity: str
    unit: str
    low: float
    high: float
    low_open: bool = False
    high_open: bool = False
    why: str = ""

    def holds(self, x: float) -> bool:
        """``x`` is finite and within the range."""
        if not math.isfinite(x):
            return False
        above = x > self.low if self.low_open else x >= self.low
        below = x < self.high if self.high_open else x <= self.high
        return above and below

    def fault(self, x: float) -> str:
        """What is wrong with ``x`` in words (``"is negative"``, ``"is not positive"``, ``"is out of range"``)."""
        if math.isfinite(x) and self.low == 0 and self.low_open and x <= 0:
            return "is not positive"
        if math.isfinite(x) and self.low == 0 and x < 0:
            return "is negative"
        return "is out of range"

    def describe(self) -> str:
        """The range in words: ``-273.15 < temperature <= 200 degC``."""
        lo = "<" if self.low_open else "<="
        hi = "<" if self.high_open else "<="
        unit = f" {self.unit}" if self.unit else ""
        text = f"{self.low:g} {lo} {self.quantity} {hi} {self.high:g}{unit}"
        return f"{text} ({self.why})" if self.why else text


#: the limits by name; a table column, spec key or option is checked against the row its quantity names
LIMITS: dict[str, Limit] = {
    "temperature_c": Limit(
        "temperature", "degC", -273.15, 200.0, low_open=True, why="above absolute zero, within a sensor's range"
    ),
    "temperature_span_c": Limit("a temperature coefficient's scale", "degC", 0.0, 200.0, low_open=True),
    "exposure_s": Limit("exposure", "s", 0.0, 86_400.0, low_open=True, why="positive, at most a day"),
    "gain": Limit("gain", "", 0.0, 1e6, low_open=True, why="a positive factor"),
    "tdi_stages": Limit("TDI stages", "", 1.0, 1e5, why="a whole number of stages, 1 without TDI"),
    "stimulus": Limit("stimulus", "", 0.0, 1e12, why="radiance or irradiance >= 0; dark rows have 0"),
    "time_s": Limit("time", "s", 0.0, 1e10, why="seconds since the session began, >= 0"),
    "count": Limit("count", "", 1.0, 1e15, why="frames or pixels averaged, at least 1"),
    "dn": Limit("DN", "DN", 0.0, 2.0**32, why="a raw reading, not dark-subtracted"),
    "dn_var": Limit("temporal variance", "DN^2", 0.0, 2.0**64, why="0 only where a region is clipped"),
    "relative": Limit("relative uncertainty", "", 0.0, 1.0, high_open=True, why="a fraction, below 1"),
    "relative_sd": Limit("relative standard deviation", "", 0.0, 0.5, high_open=True),
    "doubling_c": Limit("doubling temperature", "degC", 0.0, 100.0, low_open=True),
    "positive": Limit("value", "", 0.0, 1e300, low_open=True, why="a finite number above 0"),
    "noise_dn": Limit("noise", "DN", 0.0, 2.0**32, why="a standard deviation, >= 0"),
    "signal_dn": Limit("signal", "DN", -(2.0**32), 2.0**32, why="a finite level in DN"),
    "finite": Limit("value", "", -1e300, 1e300, why="a finite number"),
}


def limit(name: str) -> Limit:
    """The row ``name`` of :data:`LIMITS`."""
    return LIMITS[name]


def check_value(value: float, name: str, where: str) -> float:
    """``value`` as a float when it lies within the limit ``name``; else
    :class:`~bayescal.errors.SpecError` naming ``where`` (``"offset_temperature.reference_c"``,
    ``"--temperature-c"``), the value and the range."""
    from bayescal.errors import SpecError

    try:
        x = float(value)
    except (TypeError, ValueError):
        raise SpecError(f"{where} = {value!r}; expected a number") from None
    lim = LIMITS[name]
    if not lim.holds(x):
        raise SpecError(f"{where} = {value!r}; expected {lim.describe()}")
    return x
