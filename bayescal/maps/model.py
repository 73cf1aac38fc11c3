"""Pass 1 of the maps: each channel's signal, noise and pixel population, and the per-block mapping.

:class:`MapModel` is one channel's fitted model (design, population, noisy-pixel
mixture); :class:`SensorModel` holds one per colour plane.  :func:`map_pixels`
turns every pixel's stack means and variances into its posterior summaries,
in numpy or, compiled, in the streaming pass (:mod:`bayescal.maps.kernel`).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
import pandas as pd
from scipy import stats as sstats

from bayescal.errors import SpecError, TableError
from bayescal.io.cfa import planes as cfa_planes
from bayescal.maps.population import (
    LinearDesign,
    NoiseMixture,
    Population,
    components,
    fit_noise_mixture,
    fit_population,
    mixture_posterior,
    noisy_probability,
    pixel_posterior,
    spread_uncertainty,
)
from bayescal.maps.stacks import Manifest, block_statistics
from bayescal.model.components.dark import Dark
from bayescal.model.quantisation import pixel_rounded_variance

__all__ = ["MapModel", "SensorModel", "PixelMapper", "DEFECT_CODES", "fit_map_model", "map_pixels"]

#: defect codes of the ``defect`` map
DEFECT_CODES = {0: "none", 1: "hot", 2: "dead", 3: "noisy", 4: "bright", 5: "offset"}
#: a pixel is mapped as defective when its posterior defect probability exceeds this
DEFECT_THRESHOLD = 0.5
#: a stack is refused as saturated when more than this fraction of its pixel readings sit at its maximum
SATURATED_FRACTION = 0.01


@dataclass(frozen=True)
class MapModel:
    """Everything pass 2 needs: the design, the population, the noise mixture (small; ships to workers)."""

    design: LinearDesign
    population: Population
    noise: NoiseMixture
    stacks: pd.DataFrame  # one row per stack: kind, exposure_s, condition, frames, variance, signal
    signal_se: np.ndarray  # standard error of each flat condition's channel signal (all-pixel, relative)
    spread_se: np.ndarray
    spread_95: list
    shape: tuple[int, int]
    n_normal: float
    info: dict = field(default_factory=dict)

    @property
    def names(self) -> tuple[str, ...]:
        return self.design.names

    def outputs(self) -> list[str]:
        names = []
        for p in self.names:
            names += [p, f"u_random_{p}", f"lsq_{p}"]
        if "dark_current_dn_s" in self.names:
            names.append("corr_offset_dark")
        return names + ["defect_probability", "noisy_probability", "noise_scale", "defect"]

    def mapper(self) -> PixelMapper:
        """The arrays every pixel's mapping needs (see :func:`map_pixels`)."""
        frames = self.stacks["frames"].to_numpy(float)
        pop = self.population
        return PixelMapper(
            self.design.estimator,
            (frames - 1) / self.stacks["noise_reference"].to_numpy(),
            self.noise.constants(),
            components(pop, self.design.covariance),
            np.log(pop.weights),
            pop.means[0],
            np.maximum(pop.spread, 1e-300),
        )

    def block(self, means: np.ndarray, variances: np.ndarray) -> np.ndarray:
        """Per-pixel maps of one block: ``means``, ``variances`` (S, N) -> (outputs, N) float32 (numpy)."""
        return map_pixels(self.mapper(), means, variances, self.names)


class PixelMapper(NamedTuple):
    """One channel's fitted model as arrays: the argument of the compiled streaming pass."""

    estimator: np.ndarray  # (P, S): theta_hat = estimator @ means (weighted least squares)
    stat_weights: np.ndarray  # (S,): (n_s - 1) / v_s, the noisy-pixel statistic's weights (see _rounding_factor)
    noise: np.ndarray  # NoiseMixture.constants()
    components: tuple  # (normal, defect) population components, diagonalised against the design
    log_weights: np.ndarray  # (2,)
    normal_mean: np.ndarray  # (P,)
    normal_spread: np.ndarray  # (P,)


#: defect code by the parameter that departs most from the normal population, when it departs low / not / high
_CODES = {"offset_dn": (5, 5, 5), "dark_current_dn_s": (5, 5, 1), "relative_gain": (2, 4, 4)}


def map_pixels(m: PixelMapper, means, variances, names: tuple[str, ...], xp=np):
    """Every pixel's posterior summaries from its stack means and variances (S, N) -> (outputs, N) float32.

    The outputs, in :meth:`MapModel.outputs` order: per parameter its posterior
    mean, sd and least-squares estimate; the offset-dark-current correlation;
    the defect and noisy probabilities, the noise scale and the defect code.
    ``xp`` is the array module: numpy, or ``jax.numpy`` in the compiled pass
    (:mod:`bayescal.maps.kernel`).
    """
    theta_hat = m.estimator @ means  # (P, N): pixels last, see population.Component.terms
    stat = m.stat_weights @ variances
    q_noisy = noisy_probability(stat, m.noise, xp)
    phi = 1.0 + q_noisy * (m.noise[1] - 1.0)
    post = mixture_posterior(m.components, m.log_weights, theta_hat, phi, xp)
    sd = xp.sqrt(xp.stack([post.cov[j, j] for j in range(len(names))]))
    out = []
    for j, _ in enumerate(names):
        out += [post.mean[j], sd[j], theta_hat[j]]
    if "dark_current_dn_s" in names:
        out.append(post.cov[0, 1] / xp.maximum(sd[0] * sd[1], 1e-300))
    p_defect = 1.0 - (1.0 - post.defect_probability) * (1.0 - q_noisy)
    # defect code: the parameter that departs most from the normal population, or noisy
    dev = (post.mean - m.normal_mean[:, None]) / m.normal_spread[:, None]
    which = xp.argmax(xp.abs(dev), axis=0)
    sign = xp.sign(xp.take_along_axis(dev, which[None, :], axis=0)[0]).astype(int)
    table = xp.asarray(np.array([_CODES[n] for n in names], float))
    code = table[which, sign + 1]
    code = xp.where(q_noisy > post.defect_probability, 3.0, code)
    out += [p_defect, q_noisy, phi, xp.where(p_defect > DEFECT_THRESHOLD, code, 0.0)]
    return xp.stack(out).astype(np.float32)


def _rows_per_chunk(manifest: Manifest, target_pixels: int = 1 << 20) -> int:
    """Rows per block (and per chunk of the store): about ``target_pixels`` pixels, a 4 MB chunk of each
    float32 map, so the store's per-chunk cost stays small beside the pixels' work.  The frames are read
    in sub-blocks (:mod:`bayescal.maps.kernel`), so the block size does not set the memory."""
    return int(max(1, min(manifest.shape[0], target_pixels // manifest.shape[1])))


def _robust_variance(var: np.ndarray, frames: int, keep: float = 0.995) -> float:
    """A channel's temporal variance from its pixels' sample variances, unmoved by noisy or hot pixels.

    The mean of the ``s^2`` below their ``keep`` quantile, corrected for the
    trimming: for ``X ~ chi2_k``, ``E[X | X < c] = k F_{k+2}(c) / F_k(c)``
    (``k = frames - 1``).  A median would be biased for integer readings, whose
    two-frame ``s^2`` take only the values ``d^2 / 2``.
    """
    k = frames - 1
    q = np.quantile(var, keep)
    c = sstats.chi2.ppf(keep, k)
    return float(np.mean(var[var <= q]) * keep / sstats.chi2.cdf(c, k + 2))


def _stack_variances(
    variances: np.ndarray, frames: np.ndarray, rounds: int = 3, means: np.ndarray | None = None
) -> tuple[np.ndarray, NoiseMixture, np.ndarray]:
    """Each stack's temporal variance for a normal pixel, the noisy-pixel mixture, and each stack's
    factor on its variance for the noisy-pixel test (1; with ``means``, above 1 on quantisation-limited
    stacks: :func:`_rounding_factor`, found once from the first estimate).

    Starts from the trimmed estimate, then alternates: fit the noisy-pixel
    mixture, and take each stack's variance as the mean ``s^2`` weighted by
    the probability that a pixel is not noisy.  The mean (not a median or a
    trimmed mean) is what the pixels' scatter holds when their temporal
    variances differ (dark shot noise, mild telegraph noise): a trimmed
    estimate then reads low and inflates the fitted non-uniformity.
    """
    var = np.array([_robust_variance(variances[s], frames[s]) for s in range(len(frames))])
    dof = float(np.sum(frames - 1))
    factor = np.ones(len(frames)) if means is None else _rounding_factor(means, var)
    for _ in range(rounds):
        stat = np.sum(((frames - 1) / (factor * var))[:, None] * variances, axis=0)
        noise = fit_noise_mixture(stat, dof)
        w = 1.0 - noise.probability(stat)
        var = variances @ w / w.sum()
    stat = np.sum(((frames - 1) / (factor * var))[:, None] * variances, axis=0)
    return var, fit_noise_mixture(stat, dof), factor


#: stacks whose channel variance is below this (DN^2; noise under ~0.6 DN) are quantisation-limited
ROUNDING_VAR_DN2 = 0.45


def _rounding_factor(means: np.ndarray, var: np.ndarray, sample: int = 20_000) -> np.ndarray:
    """Per stack, the largest variance the rounding gives a normal pixel over the channel's variance
    (1 where the noise exceeds ~0.6 DN): what the noisy-pixel test judges a pixel against is the
    channel's variance times it.

    With 0.2-0.3 DN of noise a pixel whose level sits at a half code flips between two codes and shows
    about twice the channel's variance, one at a whole code almost none (the noisy-pixel test called half
    of such a sensor's pixels noisy).  Judged against the rounded variance of a pixel at a half code,
    ``max_u V(u, sigma)`` (:func:`bayescal.model.quantisation.pixel_rounded_variance`), with ``sigma`` the
    noise whose rounded variance averaged over the pixels' levels is the channel's, no normal pixel
    exceeds its reference, and a noisy one (several times the noise) still stands out.
    """
    levels = means[:, :: max(1, means.shape[1] // sample)]
    half = np.linspace(0.0, 1.0, 101)
    factor = np.ones(len(var))
    for s in np.flatnonzero(var < ROUNDING_VAR_DN2):
        lo, hi = 1e-3, 1.0
        for _ in range(40):  # bisection: the noise whose rounded variance, over these levels, is var[s]
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if np.mean(pixel_rounded_variance(levels[s], mid)) < var[s] else (lo, mid)
        factor[s] = max(1.0, float(np.max(pixel_rounded_variance(half, 0.5 * (lo + hi)))) / var[s])
    return factor


#: the population's subsample is spread over at least this many bands of rows
SAMPLE_BANDS = 32


def _sample_rows(height: int, step: int, fit_pixels: int, width: int) -> list[tuple[int, int]]:
    """Evenly spaced bands of rows (whole colour cells) holding about ``fit_pixels`` pixels, at least
    :data:`SAMPLE_BANDS` of them (every row when the sensor is small)."""
    rows = _even(max(1, fit_pixels // (SAMPLE_BANDS * width)), step)
    blocks = [(r, min(r + rows, height)) for r in range(0, height, rows)]
    want = max(1, int(np.ceil(fit_pixels / (rows * width))))
    if want >= len(blocks):
        return blocks
    pick = np.unique(np.linspace(0, len(blocks) - 1, want).round().astype(int))
    return [blocks[i] for i in pick]


def _statistics(manifest: Manifest, r0: int, r1: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Means and variances (S, rows, W) of rows ``r0:r1`` of every stack, and per stack its smallest and
    largest reading and the fraction of readings at the largest ``(S, 3)``."""
    means, variances, extremes = [], [], []
    for stack in manifest.stacks:
        block = stack.read_rows(r0, r1)
        m, v = block_statistics(block)
        means.append(m)
        variances.append(v)
        top = block.max()
        extremes.append((float(block.min()), float(top), float(np.mean(block == top))))
    return np.stack(means), np.stack(variances), np.asarray(extremes)


def _check_flats(manifest: Manifest, extremes: np.ndarray) -> None:
    """Refuse flat stacks that cannot be mapped, naming the real cause: constant frames, or
    saturation, judged against the sensor's full scale (``2^bits - 1`` from the manifest's ``bits``
    column; without it, the highest reading of all stacks when that is an ADC's ``2^k - 1``, k >= 8),
    never against a dim stack's own maximum."""
    table = manifest.table
    lowest, highest, at_top = extremes[:, 0], extremes[:, 1], extremes[:, 2]
    if "bits" in table.columns:
        full = float(2 ** int(table["bits"].iloc[0]) - 1)
    else:
        top = float(np.max(highest))
        full = top if top >= 255 and float(np.log2(top + 1)).is_integer() else np.inf
    where = manifest.directory / "conditions.csv"
    for s in np.flatnonzero(table["kind"].to_numpy() == "flat"):
        name = table["file"][s]
        if at_top[s] > SATURATED_FRACTION and highest[s] >= full:
            raise TableError(
                f"{where} row {s + 2}: stack {name} is saturated ({at_top[s]:.1%} of its pixel readings sit at "
                f"full scale, {full:g} DN); use a lower sphere level or exposure"
            )
        if lowest[s] == highest[s]:
            raise TableError(
                f"{where} row {s + 2}: every pixel of stack {name} reads {highest[s]:g} DN in every frame; "
                "constant frames carry no pixel-to-pixel or temporal statistics (a synthetic or stuck stack?)"
            )


@dataclass(frozen=True)
class SensorModel:
    """One :class:`MapModel` per colour channel, and the strided plane each channel's pixels occupy."""

    models: dict[str, MapModel]
    step: int  # 1: monochrome; 2: a Bayer mosaic
    planes: tuple[tuple[str, int, int], ...]  # (channel, row offset, column offset)
    cfa: str | None

    def outputs(self) -> list[str]:
        return next(iter(self.models.values())).outputs()

    @functools.cached_property
    def mappers(self) -> dict[str, PixelMapper]:
        """Each channel's :meth:`MapModel.mapper`, computed once."""
        return {name: m.mapper() for name, m in self.models.items()}


def _plane_values(parts, index: int, step: int, dy: int, dx: int) -> np.ndarray:
    return np.concatenate([p[index][:, dy::step, dx::step].reshape(p[index].shape[0], -1) for p in parts], axis=1)


def fit_map_model(
    manifest: Manifest,
    *,
    fit_pixels: int = 262_144,
    rows_per_chunk: int | None = None,
    cfa: str | None = None,
    channel: str = "M",
) -> SensorModel:
    """Pass 1: per channel, the signal per condition, stack variances and the pixel population.

    ``cfa`` names the Bayer pattern of a raw mosaic: every colour channel then
    gets its own signal, noise and population (both green planes share one).
    """
    step, planes = cfa_planes(cfa, channel)
    rows = _even(rows_per_chunk or _rows_per_chunk(manifest), step)
    parts = [
        _statistics(manifest, r0, r1) for r0, r1 in _sample_rows(manifest.shape[0], step, fit_pixels, manifest.shape[1])
    ]
    extremes = np.stack([p[2] for p in parts])  # (blocks, S, 3)
    _check_flats(
        manifest,
        np.stack([extremes[:, :, 0].min(0), extremes[:, :, 1].max(0), extremes[:, :, 2].max(0)], axis=1),
    )
    models = {}
    for name in dict.fromkeys(n for n, _, _ in planes):
        mine = [(dy, dx) for n, dy, dx in planes if n == name]
        means = np.concatenate([_plane_values(parts, 0, step, dy, dx) for dy, dx in mine], axis=1)
        variances = np.concatenate([_plane_values(parts, 1, step, dy, dx) for dy, dx in mine], axis=1)
        models[name] = _fit_channel(manifest, means, variances, rows)
    return SensorModel(models, step, tuple(planes), cfa)


def _even(rows: int, step: int) -> int:
    """Row blocks start on a whole Bayer cell."""
    return max(step, rows - rows % step)


def _fit_channel(manifest: Manifest, means: np.ndarray, variances: np.ndarray, rows: int) -> MapModel:
    """One channel's model from its pixels' statistics (S, N)."""
    table = manifest.table
    frames = np.array([st.shape[0] for st in manifest.stacks])
    var, noise, factor = _stack_variances(variances, frames, means=means)
    dark_of = {c: s for s, (c, k) in enumerate(zip(table["condition"], table["kind"], strict=True)) if k == "dark"}
    signal = np.zeros(len(frames))
    signal_se = np.zeros(len(frames))
    for s, (c, k) in enumerate(zip(table["condition"], table["kind"], strict=True)):
        if k == "flat":
            diff = means[s] - means[dark_of[c]]
            signal[s] = sstats.trim_mean(diff, 0.05)
            signal_se[s] = float(np.std(diff) / np.sqrt(diff.size) / max(abs(signal[s]), 1e-300))
            if signal[s] <= 0:
                raise TableError(
                    f"{manifest.directory / 'conditions.csv'} row {s + 2}: flat stack {table['file'][s]} reads no "
                    f"more than its dark stack (mean signal {signal[s]:.3g} DN); check the kinds"
                )
    exposures = table["exposure_s"].to_numpy()
    flat_signal = np.where(table["kind"] == "flat", signal, 0.0)
    thermal = _thermal(table, exposures, flat_signal, var / frames, means)
    design = _design(exposures, flat_signal, var / frames, thermal)
    if np.linalg.matrix_rank(design.X) < design.X.shape[1]:
        raise SpecError("the stacks do not determine every pixel parameter (need a dark stack and a flat stack)")
    stat = np.sum(((frames - 1) / (factor * var))[:, None] * variances, axis=0)
    theta_hat, _ = design.least_squares(means.T)
    population = fit_population(theta_hat, noise.phi(stat), design.covariance)
    post = pixel_posterior(theta_hat, noise.phi(stat), design.covariance, population)
    n_normal = float(np.sum(1.0 - post.defect_probability))
    stacks = table[["file", "kind", "exposure_s", "condition", "gain", "temperature_c"]].copy()
    stacks["frames"] = frames
    stacks["variance"] = var
    stacks["noise_reference"] = factor * var
    stacks["signal_dn"] = signal
    return MapModel(
        design,
        population,
        noise,
        stacks,
        signal_se,
        *spread_uncertainty(population, design.covariance, n_normal),
        manifest.shape,
        n_normal,
        {"fit_pixels": int(means.shape[1]), "rows_per_chunk": rows, "thermal": thermal},
    )


def _design(exposures, flat_signal, var, thermal: dict | None) -> LinearDesign:
    """``dark: o + D t k(T)``, ``flat: ... + r S_c`` with ``k(T) = 2^((T - T_ref) / T_d)`` (1 without
    a temperature term): the dark current doubles every ``T_d`` degrees (EMVA 1288 release 4.0, eq. 7)."""
    columns = [np.ones(len(exposures))]
    names = ["offset_dn"]
    if np.unique(exposures).size > 1 or thermal is not None:
        factor = 1.0 if thermal is None else thermal["factor"]
        columns.append(exposures * factor)
        names.append("dark_current_dn_s")
    columns.append(flat_signal)
    names.append("relative_gain")
    return LinearDesign(np.stack(columns, axis=1), var, tuple(names))


def doubling_factor(temperature_c, temperature_ref_c: float, doubling_c: float):
    """``2^((T - T_ref) / T_d)``: the dark current at ``T`` relative to ``T_ref`` (the dark component's law)."""
    return Dark.doubling(np.asarray(temperature_c, float) - temperature_ref_c, doubling_c)


def _thermal(table, exposures, flat_signal, var, means) -> dict | None:
    """The dark-current doubling temperature shared by the pixels, by profile least squares.

    Given ``T_d`` every pixel's model is linear; the summed weighted residual
    ``chi2(T_d)`` over the subsample is minimised over ``log T_d`` and its
    curvature (scaled by the residual variance per degree of freedom) gives
    the standard error.  None when the stacks span no temperature range.
    """
    from scipy import optimize

    temps = table["temperature_c"].to_numpy(float)
    if np.all(np.isnan(temps)) or np.nanmax(temps) - np.nanmin(temps) < 1.0:
        return None
    ref = float(np.median(temps))
    keep = np.ones(means.shape[1], bool)

    def fit(log_td: float):
        th = {"factor": doubling_factor(temps, ref, np.exp(log_td))}
        return _design(exposures, flat_signal, var, th).least_squares(means[:, keep].T)

    def chi2(log_td: float) -> float:
        return float(fit(log_td)[1].sum())

    res = optimize.minimize_scalar(chi2, bounds=(np.log(1.0), np.log(200.0)), method="bounded")
    # refit on the pixels the model describes: hot (often clipped), noisy and other defects would pull T_d
    theta, per_pixel = fit(res.x)
    dark = theta[:, 1]
    mad = 1.4826 * np.median(np.abs(dark - np.median(dark)))
    dof_pixel = means.shape[0] - 3
    keep[keep] = (per_pixel < sstats.chi2.ppf(0.999, dof_pixel)) & (np.abs(dark - np.median(dark)) < 6 * mad)
    res = optimize.minimize_scalar(chi2, bounds=(np.log(1.0), np.log(200.0)), method="bounded")
    h = 1e-3
    curv = (chi2(res.x + h) - 2 * res.fun + chi2(res.x - h)) / h**2
    dof = keep.sum() * dof_pixel
    scale = res.fun / max(dof, 1)
    se_log = float(np.sqrt(2 * scale / curv)) if curv > 0 else float("inf")
    td = float(np.exp(res.x))
    return {
        "factor": doubling_factor(temps, ref, td),
        "temperature_ref_c": ref,
        "doubling_c": td,
        "doubling_c_se": td * se_log,
    }
