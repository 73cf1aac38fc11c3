"""Derived settings: what the camera will read at a setting, with credible and predictive intervals.

Seed 000 section 5.3 (Table 2) derives the response at 1/100 s from the
1/250 s fit by scaling the slope with the exposure ratio and keeping the dark
offset; seed 002 eq. 11-12 does the same over TDI stages, integration time
and gain.  Here the same measurement equation runs per posterior draw
(:class:`~bayescal.posterior.calibration.Calibration`): the credible interval is that
of the expected DN, the predictive interval adds the noise of one reading
and clipping at full scale.  Settings outside the calibrated range are
flagged, never silently extrapolated.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from bayescal.model.setting import Setting
from bayescal.posterior.calibration import Calibration

__all__ = ["predict"]


def predict(
    cal: Calibration,
    stimulus,
    setting: Setting,
    channels: list[str] | None = None,
    *,
    n_avg: float = 1.0,
    prnu: float = 0.0,
    relative: bool = False,
    level: float = 0.95,
    seed: int = 0,
) -> pd.DataFrame:
    """Posterior predictive DN at ``setting`` for each stimulus value and channel.

    Parameters
    ----------
    stimulus : float or array
        Radiance (or irradiance) values, in the calibration's unit.
    setting : Setting
        Exposure, gain and TDI stages, measured or not.
    channels : list of str, optional
        Default: every calibrated channel.
    n_avg : float
        Pixels x frames averaged per reading (1: a single pixel).
    relative : bool
        Stimulus as read by the calibration's own sphere (coefficients
        relative to its scale) instead of absolute.
    seed : int
        Seed of the predictive noise draws.

    Returns
    -------
    pandas.DataFrame
        channel, stimulus, exposure_s, gain, tdi_stages, dn_mean, dn_median,
        ci_lo/ci_hi (credible interval of the expected DN), pi_lo/pi_hi
        (predictive interval of one reading), p_saturated, extrapolated and
        the reason.

    Examples
    --------
    >>> import bayescal as bc
    >>> cal = bc.Calibration.from_coefficients({"G": [45.0, 30.0]}, reference=bc.Reference(0.004), bits=12)
    >>> table = bc.predict(cal, [10.0], bc.Setting(0.008), "G")  # twice the reference exposure
    >>> float(table["dn_median"].iloc[0])
    645.0
    """
    stim = np.atleast_1d(np.asarray(stimulus, dtype=float))
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0xD1CE]))
    tail = (1 - level) / 2
    rows = []
    for ch in channels or list(cal.channels):
        mean = cal.clipped_dn(ch, stim, setting, relative)
        reading = cal.sample_dn(ch, stim, setting, rng, n_avg=n_avg, prnu=prnu, relative=relative)
        ci = np.quantile(mean, [tail, 0.5, 1 - tail], axis=0)
        pi = np.quantile(reading, [tail, 1 - tail], axis=0)
        p_sat = np.mean(reading >= cal.saturation_dn, axis=0)
        for i, value in enumerate(stim):
            why = cal.flags(setting, value)
            rows.append(
                {
                    "channel": ch,
                    "stimulus": value,
                    "exposure_s": setting.exposure_s,
                    "gain": setting.gain,
                    "tdi_stages": setting.tdi_stages,
                    "dn_mean": float(mean[:, i].mean()),
                    "dn_median": float(ci[1, i]),
                    "ci_lo": float(ci[0, i]),
                    "ci_hi": float(ci[2, i]),
                    "pi_lo": float(pi[0, i]),
                    "pi_hi": float(pi[1, i]),
                    "p_saturated": float(p_sat[i]),
                    "extrapolated": bool(why),
                    "why": "; ".join(why),
                }
            )
    return pd.DataFrame(rows)
