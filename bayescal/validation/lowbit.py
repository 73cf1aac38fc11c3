"""A low-bit area sensor measured as EMVA 1288 prescribes, simulated pixel by pixel.

Written from the standard's sensor model (EMVA 1288 release 4.0, section 2), apart from
bayescal's characterisation: it imports nothing from it and reduces its own image pairs.
Each pixel ``i`` collects ``Poisson(eta mu_p (1 + prnu_i))`` photo-electrons (plus dark
electrons ``I t``), adds a Gaussian read noise of ``sigma_d`` electrons, is converted with
the system gain ``K`` (DN/e-), shifted by its own offset ``o + dsnu_i`` (DN), rounded to the
nearest code and clipped to ``0 .. 2^bits - 1``.  A sense node whose capacitance grows with its
charge (a V/Q nonlinearity, seed 004) converts ``Q`` electrons as ``Q / (1 + Q / Q_knee)`` before
the gain: the conversion gain falls with the signal and the photon transfer curve is concave.
Where the dark noise is a fraction of a DN (0.2-1 DN on 8- and 10-bit sensors), the rounding
dominates the dark frames: exactly the regime in which photon-transfer estimates go wrong.

:func:`simulate_lowbit` returns the per-step pair statistics (mean and temporal variance,
EMVA 1288 eq. 9-10) of an exposure sweep or an illumination sweep, with the sensor's truth.
:func:`random_lowbit` draws a sensor's parameters from ranges of real 8- and 10-bit CMOS
sensors.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
import pandas as pd

__all__ = ["LowBitSensor", "simulate_lowbit", "random_lowbit", "real_8bit"]


@dataclass(frozen=True)
class LowBitSensor:
    """A sensor in datasheet terms (defaults: an 8-bit CMOS sensor with 0.33 DN dark noise)."""

    bits: int = 8
    k: float = 0.0206  # system gain K, DN per electron
    qe: float = 0.55  # quantum efficiency at the source's wavelength
    sigma_d_e: float = 16.0  # read (dark) noise, electrons
    dark_current_e_s: float = 20.0  # electrons per second
    offset_dn: float = 4.5  # mean dark level, DN (its fraction decides how the rounding hits)
    dsnu_dn: float = 0.05  # spread of the pixels' offsets, DN
    prnu: float = 0.008  # spread of the pixels' gains, relative
    height: int = 96
    width: int = 96
    knee_e: float = float("inf")  # V/Q nonlinearity: Q electrons read as Q / (1 + Q / knee_e)

    @property
    def full_scale(self) -> int:
        return 2**self.bits - 1

    @property
    def sigma_y_dark(self) -> float:
        """Dark temporal noise before the rounding, DN (the standard's ``sigma_y.dark`` less quantisation)."""
        return self.k * self.sigma_d_e


def simulate_lowbit(
    sensor: LowBitSensor,
    *,
    n_steps: int = 50,
    layout: str = "exposure",
    t_max_s: float = 0.02,
    saturate: float = 1.15,
    source_jitter: float = 0.002,
    first: float = 1e-4,
    seed: int = 0,
) -> tuple[pd.DataFrame, dict]:
    """Pair statistics of an EMVA 1288 sweep of ``sensor`` and its truth.

    ``layout="exposure"``: the exposure runs up to ``t_max_s`` at one irradiance, a dark pair
    at every exposure; ``"illumination"``: the photon count is varied at ``t_max_s``, one dark
    pair for every bright pair.  The steps are evenly spaced from ``first`` of the brightest
    (as real sweeps start near zero: the darkest bright step reads a small fraction of a DN)
    to the brightest, which collects ``saturate`` times the electrons that fill the ADC's range.
    Returns a table in the reduced steps layout (``kind, texp_ns, photons_per_pixel, n_images,
    mean_DN, var_temporal_DN2, bits, n_pixels``) and the truth (``K``, ``QE`` in %, the sensor's
    parameters).
    """
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0x10B17]))
    s = sensor
    shape = (s.height, s.width)
    offsets = s.offset_dn + s.dsnu_dn * rng.standard_normal(shape)
    gains = 1.0 + s.prnu * rng.standard_normal(shape)
    full_dn = (s.full_scale - s.offset_dn) / s.k  # the compressed charge that fills the range above the offset
    full_e = full_dn / (1.0 - full_dn / s.knee_e) if np.isfinite(s.knee_e) else full_dn  # electrons giving it
    top_photons = saturate * full_e / s.qe
    fraction = np.linspace(first, 1.0, n_steps)
    if layout == "exposure":
        texp = t_max_s * fraction
        photons = top_photons * fraction
        dark_texp = texp
    elif layout == "illumination":
        texp = np.full(n_steps, t_max_s)
        photons = top_photons * fraction
        dark_texp = texp[:1]
    else:
        raise ValueError(f"layout '{layout}': expected 'exposure' or 'illumination'")

    def pair(mu_p: float, t: float) -> tuple[float, float]:
        images = []
        for _ in range(2):
            level = mu_p * (1.0 + source_jitter * rng.standard_normal())
            electrons = rng.poisson(s.qe * level * gains + s.dark_current_e_s * t)
            charge = electrons / (1.0 + electrons / s.knee_e)  # the sense node's V/Q (none: knee_e = inf)
            signal = offsets + s.k * (charge + s.sigma_d_e * rng.standard_normal(shape))
            images.append(np.clip(np.floor(signal + 0.5), 0, s.full_scale))
        a, b = images
        mean_a, mean_b = a.mean(), b.mean()
        return 0.5 * (mean_a + mean_b), float(np.mean((a - b) ** 2) / 2 - (mean_a - mean_b) ** 2 / 2)

    rows = []
    for t, mu_p in zip(texp, photons, strict=True):
        m, v = pair(mu_p, t)
        rows.append(("bright", t * 1e9, mu_p, 2, m, v))
    for t in dark_texp:
        m, v = pair(0.0, t)
        rows.append(("dark", t * 1e9, 0.0, 2, m, v))
    table = pd.DataFrame(
        rows, columns=["kind", "texp_ns", "photons_per_pixel", "n_images", "mean_DN", "var_temporal_DN2"]
    ).assign(bits=s.bits, n_pixels=s.height * s.width)
    truth = {"K": s.k, "QE": 100.0 * s.qe, **{f"sensor_{k}": v for k, v in asdict(s).items()}}
    return table, truth


def real_8bit() -> LowBitSensor:
    """An 8-bit CMOS sensor with the features a real one's EMVA 1288 measurement showed (K 0.0206 DN/e- and
    QE 55 % by the standard's straight lines): the dark level near 3 DN, so the darkest pixels' dark
    distribution is clipped at 0; a dark temporal variance of about 0.11 DN^2, near the quantisation floor
    (1/12); a concave photon transfer curve, var/mean about 0.024 at 20 DN, 0.021 at 100 DN and 0.019 at
    200 DN (a V/Q knee at 90,000 electrons), collapsing as pixels saturate near 250 DN."""
    return LowBitSensor(
        bits=8,
        k=0.0245,
        qe=0.55,
        sigma_d_e=7.5,  # 0.18 DN before the rounding
        dark_current_e_s=20.0,
        offset_dn=3.0,
        dsnu_dn=1.2,
        prnu=0.008,
        knee_e=90_000.0,
    )


def random_lowbit(rng: np.random.Generator, bits: int | None = None) -> LowBitSensor:
    """A sensor drawn from the ranges of real low-bit CMOS sensors: 8 or 10 bits, dark noise
    0.2-1 DN, a full well of 3,000-40,000 electrons, QE 30-80 %, offsets 2-12 DN with any
    fraction, DSNU 0.05-1.5 DN, PRNU 0.3-1.5 %."""
    bits = int(rng.choice([8, 10])) if bits is None else bits
    full_well = float(np.exp(rng.uniform(np.log(3000), np.log(40000))))
    k = (2**bits - 1) / full_well
    sigma_y_dark = rng.uniform(0.2, 1.0)
    return LowBitSensor(
        bits=bits,
        k=k,
        qe=rng.uniform(0.3, 0.8),
        sigma_d_e=sigma_y_dark / k,
        dark_current_e_s=rng.uniform(0.0, 200.0),
        offset_dn=rng.uniform(2.0, 12.0),
        dsnu_dn=float(np.exp(rng.uniform(np.log(0.05), np.log(1.5)))),
        prnu=rng.uniform(0.003, 0.015),
    )
