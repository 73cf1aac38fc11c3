"""Model only what a scene needs: the cheapest response whose inversion matches the full model's.

A calibration may carry a high-order response (seed 000 Table 1 fits order 4)
whose inversion needs Newton iterations per posterior draw, while the image
at hand may cover only a DN range where a linear or quadratic response
inverts to the same radiance.  Seed 000 inverted its huge images with the
linear fit for exactly this reason, without checking what that cost.  Here
the check is explicit: every candidate calibration (e.g. fits of orders 1-4)
inverts every distinct DN value the scene contains, per channel, and its
posterior median and interval ends are compared with the full model's,
in units of the full model's posterior sd (the same noise draws for every
model, so the comparison carries little Monte Carlo noise).  The cheapest candidate (lowest response
order, then measured inversion time of the whole scene) whose largest
deviation stays within ``tol`` (default 0.1 sd) is chosen, and the speed
gained (measured) is reported.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
import pandas as pd

from bayescal._parallel import cores
from bayescal.errors import SpecError
from bayescal.model.setting import Setting
from bayescal.posterior.calibration import Calibration
from bayescal.prediction.images import channel_views, invert_image
from bayescal.prediction.invert import noise_normals, radiance_draws, sorted_quantiles

__all__ = ["SceneChoice", "choose_for_scene"]


@dataclass(frozen=True)
class SceneChoice:
    """Which calibration a scene needs, and what the cheaper ones would cost in accuracy.

    Attributes
    ----------
    table : pandas.DataFrame
        One row per candidate: ``max_dev_sd`` (largest deviation of median
        or interval end from the full model's, in its posterior sds, over
        the scene's DN values and channels), ``mean_dev_sd`` (pixel-weighted
        mean), ``worst_channel``/``worst_dn`` (where the maximum is),
        ``seconds`` (inverting the whole scene), ``speedup`` (full model's
        time over this one's) and ``within_tol``.
    chosen, full : str
        The chosen candidate and the reference (full) one.
    tol : float
        Tolerance in posterior sds.
    dn_range : dict
        Per channel: smallest and largest DN in the scene, the number of distinct
        values, and how many of them invert beyond the calibrated range (flagged
        as extrapolated and left out of the comparison).
    """

    table: pd.DataFrame
    chosen: str
    full: str
    tol: float
    dn_range: dict[str, tuple[float, float, int, int]]

    @property
    def speedup(self) -> float:
        """Inversion speed of the chosen model over the full model's (>= 1 means faster)."""
        return float(self.table.loc[self.chosen, "speedup"])

    def to_dict(self) -> dict:
        """JSON-ready form."""
        return {
            "chosen": self.chosen,
            "full": self.full,
            "tol_sd": self.tol,
            "speedup": self.speedup,
            "dn_range": {k: list(v) for k, v in self.dn_range.items()},
            "candidates": self.table.reset_index(names="candidate").to_dict("records"),
        }

    def __str__(self) -> str:
        ranges = ", ".join(
            f"{c} {lo:g}-{hi:g} DN ({n} values, {x} beyond the calibrated range)"
            for c, (lo, hi, n, x) in self.dn_range.items()
        )
        return (
            f"scene covers {ranges}\n"
            + self.table.to_string(float_format="%.4g")
            + f"\nchosen: {self.chosen} (within {self.tol:g} posterior sd of {self.full} over the scene; "
            f"{self.speedup:.1f}x the full model's inversion speed)"
        )


def choose_for_scene(
    candidates: Mapping[str, Calibration],
    image: np.ndarray,
    setting: Setting | None = None,
    *,
    full: str | None = None,
    tol: float = 0.1,
    cfa: str | None = None,
    channel: str | None = None,
    channels: list[str] | None = None,
    n_avg: float = 1.0,
    seed: int = 0,
    repeats: int = 2,
) -> SceneChoice:
    """Pick the cheapest calibration whose inversion of ``image`` matches the full model's.

    Parameters
    ----------
    candidates : mapping of name to Calibration
        Calibrations of the same camera (e.g. fits of response orders 1-4).
    image : ndarray
        The scene (integer DN), or any array of its DN values (a histogram's
        support works too); pixels map to channels through ``cfa``,
        ``channel`` or ``channels`` as in :func:`bayescal.invert_image`.
    setting : Setting, optional
        Exposure, gain and TDI of the scene (default: the full model's reference).
    full : str, optional
        The reference candidate (default: the one with the highest response order).
    tol : float
        Largest allowed deviation, in posterior sds of the full model.
    repeats : int
        Each scene inversion is timed this many times; the fastest counts.
    """
    if not candidates:
        raise SpecError("choose_for_scene needs at least one candidate calibration")
    if tol <= 0:
        raise SpecError(f"tol = {tol}; expected > 0 (posterior sds)")
    names = list(candidates)
    full = full or max(names, key=lambda n: candidates[n].coef.shape[-1])
    if full not in candidates:
        raise SpecError(f"full model '{full}' is not among the candidates {names}")
    ref = candidates[full]
    setting = setting or Setting(ref.reference.exposure_s, ref.reference.gain, ref.reference.tdi_stages)
    image = np.asarray(image)
    views = channel_views(image, cfa=cfa, channel=channel, channels=channels)
    values, counts = _scene_values(image, views)
    prnu = ref.prnu if n_avg == 1 else 0.0
    max_stim = ref.calibrated.max_effective / setting.ratio(ref.reference)
    ref_q = {ch: _quantile_table(ref, ch, v, setting, n_avg, prnu, seed) for ch, v in values.items()}
    clipped = {ch: v >= ref.saturation_dn for ch, v in values.items()}
    # beyond the calibrated range the inversion is flagged as extrapolated, not compared: no model is right there
    beyond = {ch: ~clipped[ch] & (ref_q[ch][1] > max_stim) for ch in values}
    rows = {}
    for name, cal in candidates.items():
        worst, worst_at, weighted, total = 0.0, ("", np.nan), 0.0, 0.0
        for ch, v in values.items():
            if name == full:
                dev = np.zeros(v.size)
            else:
                dev = _deviation(ref_q[ch], _quantile_table(cal, ch, v, setting, n_avg, prnu, seed), clipped[ch])
            dev = np.where(beyond[ch], 0.0, dev)
            i = int(np.argmax(dev))
            if dev[i] > worst:
                worst, worst_at = float(dev[i]), (ch, float(v[i]))
            weighted += float(np.sum(dev * counts[ch]))
            total += float(np.sum(counts[ch][~beyond[ch]]))
        seconds = min(_timed(cal, image, setting, cfa, channel, channels, n_avg, seed) for _ in range(repeats))
        rows[name] = {
            "order": cal.coef.shape[-1],
            "max_dev_sd": worst,
            "mean_dev_sd": weighted / total if total else np.nan,
            "worst_channel": worst_at[0],
            "worst_dn": worst_at[1],
            "seconds": seconds,
        }
    table = pd.DataFrame.from_dict(rows, orient="index")
    table["speedup"] = table.loc[full, "seconds"] / table["seconds"]
    table["within_tol"] = table["max_dev_sd"] <= tol
    table.loc[full, "within_tol"] = True
    passing = table[table["within_tol"]].sort_values(["order", "seconds"])
    chosen = str(passing.index[0])  # fewest coefficients: closed-form inversion up to order 2, Newton above
    dn_range = {ch: (float(v.min()), float(v.max()), int(v.size), int(beyond[ch].sum())) for ch, v in values.items()}
    return SceneChoice(table=table, chosen=chosen, full=full, tol=tol, dn_range=dn_range)


def _scene_values(image: np.ndarray, views) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """Distinct DN values per channel and how many pixels hold each (non-integer data: 512
    quantiles, equally weighted)."""
    values, counts = {}, {}
    for name in dict.fromkeys(n for _, n in views):
        pixels = np.concatenate([image[index].ravel() for index, n in views if n == name])
        if np.issubdtype(pixels.dtype, np.integer):
            if pixels.size and pixels.min() < 0:
                raise SpecError(f"channel {name}: negative DN {pixels.min()} in the scene")
            hist = np.bincount(pixels)
            values[name] = np.flatnonzero(hist)
            counts[name] = hist[values[name]].astype(float)
        else:
            values[name] = np.unique(np.quantile(pixels, np.linspace(0, 1, 512)))
            counts[name] = np.ones(values[name].size)
    return values, counts


def _quantile_table(cal: Calibration, channel: str, dn: np.ndarray, setting, n_avg, prnu, seed) -> np.ndarray:
    """``(5, V)``: the 2.5/50/97.5/5 % radiance quantiles and the sd per DN value.

    Quantiles of the raw draws are compared, not the reported bounds, so a
    reading near dark that one model reports one-sided and the other
    two-sided is compared by what the posteriors say.  Every model uses the
    same noise normals (as :func:`bayescal.prediction.invert.invert` does), so the
    comparison carries little Monte Carlo noise.
    """
    z = noise_normals(cal.n_draws, seed)
    out = np.empty((5, dn.size))
    sat = cal.saturation_dn

    def block(start: int) -> None:
        v = dn[start : start + _BLOCK].astype(float)
        draws = radiance_draws(cal, channel, np.minimum(v, sat), setting, n_avg=n_avg, prnu=prnu, z=z)
        out[4, start : start + v.size] = draws.std(axis=1)
        out[:4, start : start + v.size] = sorted_quantiles(draws, _PROBS)

    with ThreadPoolExecutor(max_workers=cores()) as pool:  # numpy releases the GIL
        list(pool.map(block, range(0, dn.size, _BLOCK)))
    return out


def _deviation(ref_q: np.ndarray, cand_q: np.ndarray, clipped: np.ndarray) -> np.ndarray:
    """Largest |difference| of the central quantiles (clipped readings: the 5 % quantile,
    their reported lower bound) in the reference's posterior sds."""
    diff = np.abs(cand_q[:4] - ref_q[:4])
    return np.where(clipped, diff[3], diff[:3].max(axis=0)) / ref_q[4]


_PROBS = (0.025, 0.5, 0.975, 0.05)
_BLOCK = 256


def _timed(cal, image, setting, cfa, channel, channels, n_avg, seed) -> float:
    t = time.perf_counter()
    invert_image(cal, image, setting, cfa=cfa, channel=channel, channels=channels, n_avg=n_avg, seed=seed)
    return time.perf_counter() - t
