"""Noise of a reading: read, shot, quantisation, averaging, excess scatter, PRNU.

Physics: seed 000 eq. 3 (N2 read and quantisation noise, N3 photon shot noise, zero-mean so
averaging 20 frames suppresses them), seed 002 section 2.3 (quantisation), EMVA 1288 photon
transfer ``var = K (mu - mu_dark) + sigma_d^2``.  The conversion gain and read noise scale with
the programmable gain factor.  Quantisation adds 1/12 DN^2 per pixel reading::

    pixel variance   = (r g_rel)^2 + 1/12 + K g_rel max(S, 0)
    reading variance = pixel variance / n_avg + excess^2 + (prnu S)^2

:meth:`Noise.temporal_variance`, :meth:`Noise.pixel_variance` and :meth:`Noise.reading_variance`
are these lines; the model, predictions, inversion, the per-pixel maps and the simulator call them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from bayescal.model.components.base import Component

__all__ = ["Noise", "NoiseSpec", "QUANTISATION_DN2"]

#: variance of rounding to integer DN (uniform over one code)
QUANTISATION_DN2 = 1.0 / 12.0


@dataclass(frozen=True)
class NoiseSpec:
    """Noise of a row's mean DN (seed 000 eq. 3: N2, N3; seed 002 section 2).

    ``kind = "physical"``: per-pixel variance ``(g r)^2 + K g S + 1/12`` (read
    noise ``r`` in DN at the reference gain, conversion gain ``K`` in DN/e- at
    the reference gain, quantisation), divided by ``n_frames * n_pixels``.
    ``r`` and ``K`` are fixed (from photon transfer): region means carry
    almost no information about them.  ``kind = "measured"``: the table's
    ``dn_var`` column is the per-pixel temporal variance.  ``excess_dn`` is the half-normal scale of an extra
    per-row scatter (lamp drift, model error); 0 turns it off.

    Attributes
    ----------
    read_noise_dn : float
        The read noise ``r`` (DN, at the reference gain), from photon transfer.
    conversion_gain : float
        The conversion gain ``K`` (DN per electron, at the reference gain), from photon transfer
        (``bayescal characterize`` measures it).
    """

    kind: Literal["physical", "measured"] = "physical"
    read_noise_dn: float = 2.0
    conversion_gain: float = 0.1
    excess_dn: float = 5.0


@dataclass(frozen=True)
class Noise(Component):
    """Per-pixel variance and variance of the row mean, in scaled units."""

    section = "noise"
    role = "noise"
    sites = {"excess": ()}
    reported = {"excess_dn": ()}

    spec: NoiseSpec
    dn_scale: float

    # ------------------------------------------------------------------ physics
    @staticmethod
    def temporal_variance(signal, floor, conversion, xp=np):
        """Per-pixel temporal variance: a ``floor`` (read noise and quantisation) plus shot noise
        ``conversion * max(signal, 0)``."""
        return floor + conversion * xp.maximum(signal, 0.0)

    @staticmethod
    def pixel_variance(read, conversion, g_rel, signal, xp=np, quantisation=QUANTISATION_DN2):
        """``(r g_rel)^2 + quantisation + K g_rel max(S, 0)``, read noise ``r`` and conversion gain ``K``
        at the reference gain (in scaled units pass ``r / fs``, ``K / fs`` and ``1 / (12 fs^2)``)."""
        return Noise.temporal_variance(signal, (read * g_rel) ** 2 + quantisation, conversion * g_rel, xp)

    @staticmethod
    def reading_variance(pixel_variance, n_avg=1.0, excess=0.0, prnu=0.0, signal=0.0):
        """Variance of a reading that averages ``n_avg`` pixels x frames: the temporal part shrinks,
        an excess scatter does not, and a single pixel adds its response non-uniformity ``prnu S``."""
        return pixel_variance / n_avg + excess**2 + (prnu * signal) ** 2

    # ----------------------------------------------------------------- sampling
    def scaled_pixel_variance(self, data, signal, read, conversion, xp):
        """:meth:`pixel_variance` of every row in the model's scaled units (DN / full scale)."""
        fs = self.dn_scale
        return self.pixel_variance(read / fs, conversion / fs, data.g_rel, signal, xp, QUANTISATION_DN2 / fs**2)

    def nominal_pixel_variance(self, data, signal, xp=np):
        """Per-pixel variance (scaled): measured ``dn_var``, or the spec's read noise and conversion gain."""
        if self.spec.kind == "measured":
            return data.var_meas
        return self.scaled_pixel_variance(data, signal, self.spec.read_noise_dn, self.spec.conversion_gain, xp)

    def sample(self, data, signal):
        """Variance of each row's mean (scaled units), sampling the excess scatter if enabled.

        Read noise and conversion gain are fixed at the spec's photon-transfer
        values: a region mean over many frames and pixels carries almost no
        information about them (its temporal noise is ~0.1 DN), and leaving
        them free lets shot noise absorb multiplicative scatter.
        """
        import jax.numpy as jnp
        import numpyro
        import numpyro.distributions as dist

        excess = 0.0
        if self.spec.excess_dn > 0:
            excess = numpyro.sample("excess", dist.HalfNormal(self.spec.excess_dn / self.dn_scale))
        return self.reading_variance(self.nominal_pixel_variance(data, signal, jnp), data.n_avg, excess)

    # ---------------------------------------------------------------- reporting
    def describe(self) -> str:
        excess = f", excess (scale {self.spec.excess_dn:g} DN)" if self.spec.excess_dn else ""
        return f"noise: {self.spec.kind}{excess}"

    def physical(self, draws, ctx) -> dict[str, np.ndarray]:
        """Excess scatter of a row mean (DN)."""
        return {"excess_dn": draws["excess"] * self.dn_scale} if "excess" in draws else {}
