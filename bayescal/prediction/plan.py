"""Exposure planning: the setting most likely to put the next frame's DN in a target window.

Seed 000 section 6: a frame read 534 DN at gain 1, 1/250 s; the radiance
was inverted and the exposure chosen so that the next frame lands in the
best-exposure window (1080-1920 DN for 12 bits).  Seed 002 section 6 does
the same with TDI stages and video gain (eq. 12).

Here the scene's stimulus is a posterior (from inverting the current reading
with :func:`~bayescal.prediction.invert.radiance_draws`, or a given value), and for
every allowed setting the next reading is drawn per posterior draw::

    DN_s = clip(dark_s + f_s(L_s * ratio(setting)) + noise_s)

The chosen setting maximises ``P(lo <= DN <= hi)``; ties go to the lower
gain (less noise and dark), then the shorter exposure (less motion blur),
then fewer TDI stages.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from bayescal.errors import SpecError
from bayescal.model.setting import Setting
from bayescal.posterior.calibration import Calibration
from bayescal.prediction.invert import radiance_draws

__all__ = ["Plan", "plan_exposure", "default_window"]


def default_window(bits: int) -> tuple[float, float]:
    """Target DN window: seed 000's 1080-1920 DN for 12 bits, the same fractions of full scale otherwise.

    Examples
    --------
    >>> import bayescal as bc
    >>> bc.default_window(12)
    (1080.0, 1920.0)
    """
    fs = 2**bits - 1
    return (1080.0 / 4095.0 * fs, 1920.0 / 4095.0 * fs)


@dataclass(frozen=True)
class Plan:
    """Ranked settings with the probability of landing in the window.

    Attributes
    ----------
    table : pandas.DataFrame
        One row per allowed setting, best first: exposure_s, gain,
        tdi_stages, p_in_window, predicted DN median and 95 % predictive
        interval, p_saturated, extrapolated.
    stimulus : numpy.ndarray
        Draws of the scene's stimulus used for the prediction.
    window : tuple of float
    dropped : pandas.DataFrame
        The settings asked for that were not ranked, each with why (exposure_s, gain, tdi_stages, why):
        a gain the calibration has no dark level for, or an extrapolation where none was allowed.

    Examples
    --------
    >>> import bayescal as bc
    >>> cal = bc.Calibration.from_coefficients({"G": [45.0, 30.0]}, reference=bc.Reference(0.004), bits=12)
    >>> plan = bc.plan_exposure(cal, "G", stimulus=10.0, exposures=[0.004, 0.016])
    >>> plan.table[["exposure_s", "p_in_window"]].values.tolist()  # best first
    [[0.016, 1.0], [0.004, 0.0]]
    """

    table: pd.DataFrame
    stimulus: np.ndarray
    window: tuple[float, float]
    channel: str
    dropped: pd.DataFrame = field(
        default_factory=lambda: pd.DataFrame(columns=["exposure_s", "gain", "tdi_stages", "why"])
    )

    @property
    def best(self) -> Setting:
        """The chosen setting."""
        r = self.table.iloc[0]
        return Setting(float(r.exposure_s), float(r.gain), float(r.tdi_stages))

    @property
    def probability(self) -> float:
        """Probability that the next reading at :attr:`best` lands in the window."""
        return float(self.table.iloc[0].p_in_window)


def plan_exposure(
    cal: Calibration,
    channel: str,
    *,
    dn: float | None = None,
    current: Setting | None = None,
    stimulus: float | None = None,
    exposures: list[float],
    gains: Sequence[float] = (1.0,),
    tdi_stages: Sequence[float] = (1.0,),
    window: tuple[float, float] | None = None,
    n_avg: float = 1.0,
    allow_extrapolation: bool = True,
    seed: int = 0,
) -> Plan:
    """Rank the allowed settings by the probability that the next reading lands in ``window``.

    Give the scene either as a reading ``dn`` at ``current`` settings (its
    stimulus posterior is inverted with the reading's noise) or as a known
    ``stimulus``.  ``n_avg`` is the number of pixels x frames averaged in
    the readings (both the current one and the next).

    Examples
    --------
    >>> import bayescal as bc
    >>> cal = bc.Calibration.from_coefficients({"G": [45.0, 30.0]}, reference=bc.Reference(0.004), bits=12)
    >>> plan = bc.plan_exposure(cal, "G", stimulus=10.0, exposures=[0.002, 0.004, 0.008, 0.016])
    >>> plan.window, plan.best.exposure_s  # the DN window asked for, the setting most likely to land in it
    ((1080.0, 1920.0), 0.016)
    """
    if (dn is None) == (stimulus is None):
        raise SpecError("give the scene as dn= (with current=) or as stimulus=, not both")
    bounds = tuple(window) if window is not None else default_window(cal.bits)
    if not (len(bounds) == 2 and 0 <= bounds[0] < bounds[1] <= cal.full_scale):
        raise SpecError(f"window must be (low, high) DN with 0 <= low < high <= {cal.full_scale:g}, got {bounds}")
    low, high = float(bounds[0]), float(bounds[1])
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0x9A1]))
    if stimulus is None:  # the scene is a reading
        assert dn is not None  # one of the two is given (checked above)
        if current is None:
            raise SpecError("dn= needs the current= setting it was read at")
        if dn > cal.full_scale:
            raise SpecError(
                f"the current reading {dn:g} DN exceeds the calibration's full scale of {cal.full_scale:g} DN "
                f"({cal.bits} bits): is it from another camera, or another bit depth?"
            )
        if dn >= cal.saturation_dn:
            raise SpecError(
                f"the current reading {dn:g} DN is clipped; its stimulus has only a lower bound. "
                "Plan from a shorter exposure or lower gain"
            )
        z = rng.standard_normal(cal.n_draws)
        stim = np.maximum(radiance_draws(cal, channel, np.array([dn]), current, n_avg=n_avg, z=z)[0], 0.0)
    else:
        stim = np.full(cal.n_draws, float(stimulus))
    rows, dropped = [], []
    for t, g, m in itertools.product(exposures, gains, tdi_stages):
        setting = Setting(float(t), float(g), float(m))
        where = {"exposure_s": setting.exposure_s, "gain": setting.gain, "tdi_stages": setting.tdi_stages}
        try:
            reading = cal.sample_dn(channel, stim, setting, rng, n_avg, per_draw=True)  # one stimulus per draw
        except SpecError as exc:  # a gain without dark calibration cannot be planned for
            dropped.append(where | {"why": str(exc)})
            continue
        why = cal.flags(setting, float(np.median(stim)))
        if why and not allow_extrapolation:
            dropped.append(where | {"why": "extrapolated, and extrapolation was not allowed: " + "; ".join(why)})
            continue
        lo, med, hi = np.quantile(reading, [0.025, 0.5, 0.975])
        rows.append(
            {
                "exposure_s": setting.exposure_s,
                "gain": setting.gain,
                "tdi_stages": setting.tdi_stages,
                "p_in_window": float(np.mean((reading >= low) & (reading <= high))),
                "dn_median": med,
                "dn_lo": lo,
                "dn_hi": hi,
                "p_saturated": float(np.mean(reading >= cal.saturation_dn)),
                "extrapolated": bool(why),
                "why": "; ".join(why),
            }
        )
    if not rows:
        first = f" (the first: {dropped[0]['why']})" if dropped else ""
        raise SpecError(f"none of the {len(dropped)} settings asked for can be planned{first}")
    table = pd.DataFrame(rows).sort_values(
        ["p_in_window", "gain", "exposure_s", "tdi_stages"], ascending=[False, True, True, True], kind="stable"
    )
    gone = pd.DataFrame(dropped, columns=["exposure_s", "gain", "tdi_stages", "why"])
    return Plan(table.reset_index(drop=True), stim, (low, high), channel, gone)
