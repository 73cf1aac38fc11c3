"""A simulated EMVA 1288 measurement: an exposure sweep of a sensor with known truth.

bayescal's own simulator of the standard's pair statistics (photon transfer with an optional
nonlinearity of the sense node or ADC); the tests of :mod:`bayescal.characterization.emva1288` run
it with known conversion gain, quantum efficiency and dark noise.
"""

from __future__ import annotations

import numpy as np

from bayescal.io.emva import Steps, steps_of
from bayescal.model.components.noise import QUANTISATION_DN2

__all__ = ["simulate_steps"]


def simulate_steps(
    *,
    k: float = 0.28,
    qe: float = 0.45,
    sigma_d_e: float = 11.0,
    dark_current_e: float = 30.0,
    offset_dn: float = 15.0,
    photons_per_s: float = 3e6,
    n_steps: int = 50,
    t_max_s: float = 0.011,
    n_pixels: int = 307200,
    bits: int = 12,
    nonlinearity: float = 0.0,
    nonlinearity_power: float = 2.0,
    seed: int = 0,
) -> Steps:
    """An EMVA 1288 exposure sweep of a sensor with known truth (pair statistics, photon transfer).

    Mean signal ``mu = offset + f(e)``, ``e = QE mu_p + I t`` electrons, with
    ``f(e) = K e (1 + a (e / e_fs)^p)``, ``p = nonlinearity_power``: linear for
    ``nonlinearity = a = 0``, a compression (``a < 0``) or expansion of relative
    size ``a`` at full scale ``e_fs`` otherwise (a sense node or ADC that is not
    linear; ``p = 2`` a cubic); ``K`` is the small-signal conversion gain
    ``f'(0)``.  Temporal variance
    ``f'(e)^2 (sigma_d^2 + e) + 1/12``, observed through the sampling
    distribution of a pair variance (``chi^2`` with ``N - 1`` degrees of
    freedom) and a small step-to-step source jitter.  Steps clip at full scale.
    """
    rng = np.random.default_rng(seed)
    fs = 2**bits - 1
    t = np.linspace(t_max_s / n_steps, t_max_s, n_steps)
    mu_p = photons_per_s * t * (1 + 0.001 * rng.standard_normal(n_steps))
    rows = []
    for kind in ("bright", "dark"):
        p = mu_p if kind == "bright" else np.zeros(n_steps)
        electrons = qe * p + dark_current_e * t
        u = electrons * k / (fs - offset_dn)  # fraction of the range above the offset
        p_nl = nonlinearity_power
        mean = offset_dn + k * electrons * (1.0 + nonlinearity * u**p_nl)
        slope = k * (1.0 + (p_nl + 1.0) * nonlinearity * u**p_nl)
        var = slope**2 * (sigma_d_e**2 + electrons) + QUANTISATION_DN2
        var_hat = var * rng.chisquare(n_pixels - 1, n_steps) / (n_pixels - 1)
        mean_hat = mean + np.sqrt(var / n_pixels) * rng.standard_normal(n_steps)
        sat = mean + 3 * np.sqrt(var) >= fs
        var_hat = np.where(sat, var_hat * np.clip((fs - mean) / (3 * np.sqrt(var)), 0.05, 1.0) ** 2, var_hat)
        mean_hat = np.minimum(mean_hat, fs)
        for i in range(n_steps):
            rows.append(
                {
                    "kind": kind,
                    "texp_s": t[i],
                    "photons": float(p[i]),
                    "mean_dn": mean_hat[i],
                    "var_dn2": var_hat[i],
                    "n_pixels": n_pixels,
                    "n_saturated": int(sat[i]) * n_pixels,
                }
            )
    return steps_of(rows, {}, bits, f"simulate_steps(seed={seed})")
