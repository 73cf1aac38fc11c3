"""A camera setting: where the measurement equation is evaluated for a prediction."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bayescal.errors import SpecError
from bayescal.model.spec import Reference

__all__ = ["Setting"]


@dataclass(frozen=True)
class Setting:
    """Camera setting: exposure (s), programmable gain factor, TDI stages, sensor temperature (degC).

    ``temperature_c = None`` means the calibration's reference temperature
    (it matters only for a calibration with a temperature-dependent dark current).

    Examples
    --------
    >>> import bayescal as bc
    >>> bc.Setting(0.01, 2.0)  # 1/100 s at gain 2
    Setting(exposure_s=0.01, gain=2.0, tdi_stages=1.0, temperature_c=None)
    """

    exposure_s: float
    gain: float = 1.0
    tdi_stages: float = 1.0
    temperature_c: float | None = None

    def __post_init__(self):
        for name in ("exposure_s", "gain", "tdi_stages"):
            value = getattr(self, name)
            if not np.isfinite(value) or value <= 0:
                raise SpecError(f"setting {name} must be a positive number, got {value!r}")
        if self.temperature_c is not None and not np.isfinite(self.temperature_c):
            raise SpecError(f"setting temperature_c must be a number, got {self.temperature_c!r}")

    def ratio(self, ref: Reference) -> float:
        """Factor from stimulus to effective stimulus: ``t M g / (t_ref M_ref g_ref)``."""
        return (self.exposure_s * self.tdi_stages * self.gain) / (ref.exposure_s * ref.tdi_stages * ref.gain)

    @classmethod
    def at_reference(cls, ref: Reference) -> Setting:
        """The reference setting (exposure, gain, TDI stages; the reference temperature)."""
        return cls(ref.exposure_s, ref.gain, ref.tdi_stages)
