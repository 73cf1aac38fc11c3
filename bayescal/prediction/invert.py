"""Radiance inversion: DN -> stimulus posterior with credible intervals.

For each posterior draw ``s`` the response is inverted exactly,
``x_s = f_s^{-1}(DN - dark_s - e_s)`` with ``e_s ~ N(0, var_s)`` the
reading's noise (:class:`~bayescal.posterior.calibration.Calibration`; the inverse is the
response component's, :meth:`~bayescal.model.components.response.Response.inverse`), and
``L_s = x_s t_ref M_ref g_ref / (t M g)``.  The draws ``L_s`` are the
posterior of the stimulus under a flat prior on the reading's signal; they
carry the parameter uncertainty, the sphere's common systematic (folded into
the absolute coefficients) and the measurement noise (seed 000 section 6,
seed 002 eq. 10).  The noise draws ``e_s`` use the same standard normals for
every DN value (common random numbers), so quantiles are smooth and monotone
in DN.

Bounds
------
* A reading at or above ``full scale - margin`` is clipped: the stimulus is
  at least the value that reaches it, so only a one-sided 95 % **lower**
  bound is reported (``bound = "lower"``).
* A reading whose interval reaches zero stimulus (at or below the dark
  level) gives a one-sided 95 % **upper** bound only (``bound = "upper"``):
  the quantile of the posterior truncated to stimulus >= 0 (a normal with
  the draws' mean and sd, truncated at zero; near dark the posterior is
  noise-dominated and normal), so even a reading far below dark gets a
  small positive bound rather than zero.
* The median is reported only for two-sided results (NaN otherwise).

Images
------
The posterior is computed once per *distinct* reading (at most ``2**bits``
per channel for integers) and gathered, so the cost does not grow with the
number of readings; images keep their per-DN summaries on the calibration
(:mod:`bayescal.prediction.tables`), so a survey's later frames cost only
the gather.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
import pandas as pd

from bayescal._parallel import workers
from bayescal.errors import TableError
from bayescal.model import equation
from bayescal.model.components import Response
from bayescal.model.setting import Setting
from bayescal.posterior.calibration import Calibration

__all__ = ["Inversion", "invert", "radiance_draws", "BOUND_NAMES"]

#: meaning of the ``bound`` codes
BOUND_NAMES = {0: "two-sided", 1: "lower", 2: "upper"}
_CHUNK = 32  # DN values per block: block x draws doubles stay in cache (measured fastest)


@dataclass(frozen=True)
class Inversion:
    """Stimulus posterior summaries for an array of readings of one channel.

    Attributes
    ----------
    median, lower, upper : arrays
        Posterior median and the interval ends (two-sided: ``level``
        central interval; one-sided: a ``level`` bound, the other end 0 or
        inf).
    bound : array of int8
        0 two-sided, 1 lower bound only (clipped), 2 upper bound only (at or
        below dark); see :data:`BOUND_NAMES`.
    extrapolated : array of bool
        The median lies beyond the largest calibrated signal.

    Examples
    --------
    >>> import bayescal as bc
    >>> cal = bc.Calibration.from_coefficients({"G": [45.0, 30.0]}, reference=bc.Reference(0.004), bits=12)
    >>> inversion = bc.invert(cal, [645.0], "G", bc.Setting(0.008))
    >>> row = inversion.to_frame().iloc[0]
    >>> round(float(row["median"]), 3), row["bound"]
    (10.004, 'two-sided')
    """

    dn: np.ndarray
    median: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    bound: np.ndarray
    extrapolated: np.ndarray
    channel: str
    setting: Setting | None
    unit: str
    level: float

    def describe(self, stimulus: str = "stimulus") -> str:
        """What the table holds: the channel, the unit, the setting of the readings and the interval."""
        at = ""
        if self.setting is not None:
            s = self.setting
            at = f" at exposure {s.exposure_s:g} s, gain {s.gain:g}, TDI {s.tdi_stages:g}"
        return (
            f"{self.channel} {stimulus} ({self.unit}){at}; {self.level:.0%} intervals (one-sided where 'bound' says so)"
        )

    def to_frame(self) -> pd.DataFrame:
        """One row per reading: dn, median, lower, upper, bound (text), extrapolated."""
        return pd.DataFrame(
            {
                "channel": self.channel,
                "dn": np.ravel(self.dn),
                "median": np.ravel(self.median),
                "lower": np.ravel(self.lower),
                "upper": np.ravel(self.upper),
                "bound": [BOUND_NAMES[int(b)] for b in np.ravel(self.bound)],
                "extrapolated": np.ravel(self.extrapolated),
            }
        )


def reading_prnu(cal: Calibration, n_avg: float, prnu: float | None = None) -> float:
    """The pixel response non-uniformity in a reading's noise: ``prnu`` if given, else the calibration's
    for a single pixel (``n_avg == 1``) and 0 for a mean over pixels or frames (it averages away)."""
    if prnu is not None:
        return prnu
    return cal.prnu if n_avg == 1 else 0.0


def radiance_draws(
    cal: Calibration,
    channel: str,
    dn: np.ndarray,
    setting: Setting,
    *,
    n_avg: float = 1.0,
    prnu: float = 0.0,
    z: np.ndarray | None = None,
    relative: bool = False,
) -> np.ndarray:
    """Stimulus draws ``(len(dn), S)`` for readings ``dn`` (1-D), one per posterior draw.

    ``z`` are the standard normals of the noise (one per draw); None means
    no measurement noise (the expected DN is inverted).  ``relative`` uses
    the coefficients relative to the sphere's scale (no common-scale
    uncertainty).

    Examples
    --------
    >>> import numpy as np
    >>> import bayescal as bc
    >>> cal = bc.Calibration.from_coefficients({"G": [45.0, 30.0]}, reference=bc.Reference(0.004), bits=12)
    >>> draws = bc.radiance_draws(cal, "G", np.array([645.0]), bc.Setting(0.008))
    >>> draws.shape, round(float(np.median(draws)), 3)  # (draws, readings); one draw of published coefficients
    ((1, 1), 10.0)
    """
    dn = np.asarray(dn, dtype=float)[:, None]
    coef = cal.coefficients(channel, setting, relative)

    def inverse_response(signal: np.ndarray) -> np.ndarray:
        linear = cal.response_signal(signal)
        beyond = ~np.isfinite(linear)  # past a roll-off's knee: no stimulus reads that much
        x = Response.inverse(coef, np.where(beyond, 0.0, linear))
        x[beyond] = np.inf
        return x

    def noise(signal: np.ndarray) -> np.ndarray:  # the reading's own noise (its variance per draw, at its signal)
        assert z is not None
        return np.sqrt(cal.noise_var(signal.T, setting, n_avg, prnu, channel).T) * z[None, :]

    dark = cal.dark_dn(channel, setting)[None, :]
    ratio = cal.ratio(setting, channel)[None, :]
    return equation.stimulus(dn, (ratio,), inverse_response, (dark,), noise if z is not None else None)


def invert(
    cal: Calibration,
    dn,
    channel: str,
    setting: Setting | None = None,
    *,
    n_avg: float = 1.0,
    prnu: float | None = None,
    level: float = 0.95,
    noise: bool = True,
    seed: int = 0,
) -> Inversion:
    """Stimulus posterior (median and ``level`` interval) for readings ``dn`` of ``channel``.

    Parameters
    ----------
    cal : Calibration
        Posterior (or fixed published) calibration.
    dn : array_like
        Readings (any shape).  Integer arrays are inverted once per distinct
        value.
    setting : Setting, optional
        Exposure, gain, TDI stages of the readings; default the reference.
    n_avg : float
        Pixels x frames averaged in each reading (1: a single pixel).
    prnu : float, optional
        Pixel response non-uniformity added to a single pixel's noise;
        default the spec's value when ``n_avg == 1`` and 0 otherwise (region
        means average it away).
    noise : bool
        Include the reading's noise (default).  False inverts the expected
        DN (the papers' point inversion, seed 000 section 6).
    seed : int
        Seed of the noise draws.

    Examples
    --------
    >>> import numpy as np
    >>> import bayescal as bc
    >>> cal = bc.Calibration.from_coefficients({"G": [45.0, 30.0]}, reference=bc.Reference(0.004), bits=12)
    >>> inv = bc.invert(cal, np.array([645.0]), "G", bc.Setting(0.008))
    >>> inv.to_frame()[["dn", "bound"]].to_dict("records")
    [{'dn': 645.0, 'bound': 'two-sided'}]
    >>> bool(abs(inv.to_frame()["median"].iloc[0] - 10.0) < 0.05)  # the radiance that reads 645 DN
    True
    """
    if not isinstance(cal, Calibration):  # a posterior of another model kind inverts its own readings
        return cal.invert(dn, channel, setting, n_avg=n_avg, prnu=prnu, level=level, noise=noise, seed=seed)
    setting = setting or Setting(cal.reference.exposure_s, cal.reference.gain, cal.reference.tdi_stages)
    values = np.asarray(dn)
    if values.size and not np.all(np.isfinite(values)):
        bad = np.flatnonzero(~np.isfinite(values.ravel()))[0]
        raise TableError(f"DN value at index {bad} is not finite ({values.ravel()[bad]!r}); expected a number")
    if values.size and (values.min() < 0 or values.max() > cal.full_scale + 0.5):
        raise TableError(f"DN values must lie in 0..{cal.full_scale:g} for a {cal.bits}-bit camera")
    prnu = reading_prnu(cal, n_avg, prnu)
    if np.issubdtype(values.dtype, np.integer):  # distinct values by bincount (linear time), then one take each
        present = np.flatnonzero(np.bincount(values.ravel(), minlength=1))
        lut = np.full((5, int(present.max(initial=0)) + 1), np.nan)
        lut[:, present] = value_summaries(cal, channel, present.astype(float), setting, n_avg, prnu, level, noise, seed)
        gathered = np.stack([np.take(row, values) for row in lut])
    else:
        unique, index = np.unique(values.ravel(), return_inverse=True)
        stats = value_summaries(cal, channel, unique, setting, n_avg, prnu, level, noise, seed)
        gathered = stats[:, index].reshape((stats.shape[0],) + values.shape)
    median, lower, upper, bound, extrap = gathered
    return Inversion(
        dn=values,
        median=median,
        lower=lower,
        upper=upper,
        bound=bound.astype(np.int8),
        extrapolated=extrap.astype(bool),
        channel=channel,
        setting=setting,
        unit=cal.unit,
        level=level,
    )


def sorted_quantiles(draws: np.ndarray, probs) -> np.ndarray:
    """Quantiles along axis 1 (numpy's default linear rule) from one in-place sort."""
    draws.sort(axis=1)
    n = draws.shape[1]
    pos = np.asarray(probs) * (n - 1)
    lo = np.floor(pos).astype(int)
    hi = np.minimum(lo + 1, n - 1)
    w = pos - lo
    return (draws[:, lo] * (1 - w) + draws[:, hi] * w).T


def _truncated_upper(draws: np.ndarray, rows: np.ndarray, level: float) -> np.ndarray:
    """``level`` quantile of N(mean, sd) of each row's draws truncated to >= 0 (NaN where not ``rows``)."""
    from scipy.stats import truncnorm

    out = np.full(draws.shape[0], np.nan)
    m, sd = draws[rows].mean(axis=1), draws[rows].std(axis=1)
    sd = np.maximum(sd, 1e-300)
    out[rows] = truncnorm.ppf(level, (0.0 - m) / sd, np.inf, loc=m, scale=sd)
    return out


def noise_normals(n_draws: int, seed: int) -> np.ndarray:
    """The standard normals of the reading noise, one per posterior draw (common to every DN value)."""
    return np.random.default_rng(np.random.SeedSequence([seed, 0x1D7E])).standard_normal(n_draws)


def value_summaries(cal, channel, values, setting, n_avg, prnu, level, noise, seed) -> np.ndarray:
    """``(5, V)``: median, lower, upper, bound code, extrapolated flag per distinct value."""
    z = noise_normals(cal.n_draws, seed) if noise else None
    tail = (1.0 - level) / 2.0
    out = np.empty((5, values.size))
    sat = cal.saturation_dn
    max_stim = cal.calibrated.max_effective / setting.ratio(cal.reference)

    def block_of(start: int) -> None:
        v = values[start : start + _CHUNK]
        clipped = v >= sat
        draws = radiance_draws(cal, channel, np.where(clipped, sat, v), setting, n_avg=n_avg, prnu=prnu, z=z)
        q_lo, q_med, q_hi, q1_lo, q1_hi = sorted_quantiles(draws, (tail, 0.5, 1 - tail, 1 - level, level))
        at_dark = ~clipped & (q_lo <= 0.0)
        dark_hi = _truncated_upper(draws, at_dark, level) if at_dark.any() else q1_hi
        block = out[:, start : start + v.size]
        block[0] = np.where(clipped | at_dark, np.nan, q_med)
        block[1] = np.where(clipped, q1_lo, np.where(at_dark, 0.0, q_lo))
        block[2] = np.where(clipped, np.inf, np.where(at_dark, dark_hi, q_hi))
        block[3] = np.where(clipped, 1, np.where(at_dark, 2, 0))
        block[4] = np.where(clipped, q1_lo, q_med) > max_stim * (1 + 1e-9)

    starts = range(0, values.size, _CHUNK)
    if workers(len(starts)) > 1:  # numpy releases the GIL: blocks run on every core
        with ThreadPoolExecutor(max_workers=workers(len(starts))) as pool:
            list(pool.map(block_of, starts))
    else:
        for start in starts:
            block_of(start)
    return out
