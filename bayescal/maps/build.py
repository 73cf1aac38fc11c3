"""From frame stacks to per-pixel calibration maps, out of core.

Two passes over the frames, each a dask computation chunked by rows (all
frames of a block of rows in one task), so memory is bounded by a few blocks
whatever the sensor size, and a ``dask.distributed`` client, when one is
active, spreads the blocks over its workers:

1. **population**: the per-pixel statistics of an evenly spaced subsample of
   row blocks (``fit_pixels`` pixels) give the channel's signal per condition,
   the temporal variance of every stack, and the population (PRNU, DSNU and
   dark-current spreads, defect and noisy-pixel fractions) by maximum marginal
   likelihood (:mod:`bayescal.maps.population`);
2. **maps**: every block is reduced to its per-pixel statistics and each
   pixel's closed-form posterior is written straight to the store.

The store (zarr, or NetCDF) follows the Earth-observation uncertainty
conventions: each mapped quantity names its uncertainty variables in
``unc_comps``, and each uncertainty variable states its error correlation
across pixels in ``err_corr`` (``random``: independent from pixel to pixel;
``systematic``: common to all pixels).
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
from scipy import stats as sstats

from .._version import __version__
from ..errors import SpecError, TableError
from ..io import staged_directory
from .population import (
    LinearDesign,
    NoiseMixture,
    Population,
    combination_spread,
    fit_noise_mixture,
    fit_population,
    pixel_posterior,
    spread_uncertainty,
)
from .stacks import Manifest, block_statistics, load_manifest, open_stacks

__all__ = ["MapModel", "DEFECT_CODES", "build_maps", "fit_map_model", "write_maps", "read_maps"]

#: defect codes of the ``defect`` map
DEFECT_CODES = {0: "none", 1: "hot", 2: "dead", 3: "noisy", 4: "bright", 5: "offset"}
#: a pixel is mapped as defective when its posterior defect probability exceeds this
DEFECT_THRESHOLD = 0.5
#: a stack is refused as saturated when more than this fraction of its pixel readings sit at its maximum
SATURATED_FRACTION = 0.01

_UNITS = {"offset_dn": "DN", "dark_current_dn_s": "DN s-1", "relative_gain": "1"}
_LONG = {
    "offset_dn": "pixel offset (dark level at zero exposure)",
    "dark_current_dn_s": "pixel dark current",
    "relative_gain": "pixel gain relative to the channel (1 + PRNU deviation)",
}


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

    def block(self, means: np.ndarray, variances: np.ndarray) -> np.ndarray:
        """Per-pixel maps of one block: ``means``, ``variances`` (S, N) -> (outputs, N) float32."""
        y = means.T
        theta_hat, _ = self.design.least_squares(y)
        frames = self.stacks["frames"].to_numpy(float)
        stat = np.sum(((frames - 1) / self.stacks["variance"].to_numpy())[:, None] * variances, axis=0)
        q_noisy = self.noise.probability(stat)
        phi = 1.0 + q_noisy * (self.noise.scale - 1.0)
        post = pixel_posterior(theta_hat, phi, self.design.covariance, self.population)
        out = []
        sd = np.sqrt(np.einsum("njj->nj", post.cov))
        for j, _ in enumerate(self.names):
            out += [post.mean[:, j], sd[:, j], theta_hat[:, j]]
        if "dark_current_dn_s" in self.names:
            out.append(post.cov[:, 0, 1] / np.maximum(sd[:, 0] * sd[:, 1], 1e-300))
        p_defect = 1.0 - (1.0 - post.defect_probability) * (1.0 - q_noisy)
        out += [p_defect, q_noisy, phi, self._classify(post, q_noisy, p_defect)]
        return np.stack(out).astype(np.float32)

    def _classify(self, post, q_noisy: np.ndarray, p_defect: np.ndarray) -> np.ndarray:
        """Defect code per pixel: the parameter that departs most from the normal population, or noisy."""
        pop = self.population
        dev = (post.mean - pop.means[0]) / np.maximum(pop.spread, 1e-300)
        code = np.zeros(len(dev))
        idx = {n: j for j, n in enumerate(self.names)}
        which = np.argmax(np.abs(dev), axis=1)
        sign = np.sign(dev[np.arange(len(dev)), which])
        name = np.asarray(self.names)[which]
        code = np.where(name == "offset_dn", 5, code)
        code = np.where(name == "dark_current_dn_s", np.where(sign > 0, 1, 5), code)
        if "relative_gain" in idx:
            code = np.where(name == "relative_gain", np.where(sign < 0, 2, 4), code)
        code = np.where(q_noisy > post.defect_probability, 3, code)
        return np.where(p_defect > DEFECT_THRESHOLD, code, 0)


def _rows_per_chunk(manifest: Manifest, target_bytes: float = 48e6) -> int:
    """Rows per block so that one block of every stack, as float64, stays near ``target_bytes``."""
    frames = sum(s.shape[0] for s in manifest.stacks)
    width = manifest.shape[1]
    return int(max(1, min(manifest.shape[0], target_bytes // (8 * frames * width))))


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


def _stack_variances(variances: np.ndarray, frames: np.ndarray, rounds: int = 3) -> tuple[np.ndarray, NoiseMixture]:
    """Each stack's temporal variance for a normal pixel, and the noisy-pixel mixture.

    Starts from the trimmed estimate, then alternates: fit the noisy-pixel
    mixture, and take each stack's variance as the mean ``s^2`` weighted by
    the probability that a pixel is not noisy.  The mean (not a median or a
    trimmed mean) is what the pixels' scatter holds when their temporal
    variances differ (dark shot noise, mild telegraph noise): a trimmed
    estimate then reads low and inflates the fitted non-uniformity.
    """
    var = np.array([_robust_variance(variances[s], frames[s]) for s in range(len(frames))])
    dof = float(np.sum(frames - 1))
    for _ in range(rounds):
        stat = np.sum(((frames - 1) / var)[:, None] * variances, axis=0)
        noise = fit_noise_mixture(stat, dof)
        w = 1.0 - noise.probability(stat)
        var = variances @ w / w.sum()
    stat = np.sum(((frames - 1) / var)[:, None] * variances, axis=0)
    return var, fit_noise_mixture(stat, dof)


def _sample_rows(height: int, rows: int, fit_pixels: int, width: int) -> list[tuple[int, int]]:
    """Evenly spaced row blocks holding about ``fit_pixels`` pixels (every block when the sensor is small)."""
    blocks = [(r, min(r + rows, height)) for r in range(0, height, rows)]
    want = max(1, int(np.ceil(fit_pixels / (rows * width))))
    if want >= len(blocks):
        return blocks
    pick = np.unique(np.linspace(0, len(blocks) - 1, want).round().astype(int))
    return [blocks[i] for i in pick]


def _statistics(manifest: Manifest, r0: int, r1: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Means and variances (S, N) of rows ``r0:r1`` of every stack, and each stack's saturated fraction."""
    means, variances, saturated = [], [], []
    for stack in manifest.stacks:
        block = stack[:, r0:r1]
        m, v = block_statistics(block)
        means.append(m.ravel())
        variances.append(v.ravel())
        top = block.max()
        saturated.append(float(np.mean(block == top)) if top > 0 else 0.0)
    return np.stack(means), np.stack(variances), np.asarray(saturated)


def fit_map_model(manifest: Manifest, *, fit_pixels: int = 262_144, rows_per_chunk: int | None = None) -> MapModel:
    """Pass 1: the channel signal per condition, stack variances and the pixel population."""
    table = manifest.table
    rows = rows_per_chunk or _rows_per_chunk(manifest)
    parts = [
        _statistics(manifest, r0, r1) for r0, r1 in _sample_rows(manifest.shape[0], rows, fit_pixels, manifest.shape[1])
    ]
    means = np.concatenate([p[0] for p in parts], axis=1)
    variances = np.concatenate([p[1] for p in parts], axis=1)
    saturated = np.max(np.stack([p[2] for p in parts]), axis=0)
    for s, frac in enumerate(saturated):
        if frac > SATURATED_FRACTION and table["kind"][s] == "flat":
            raise TableError(
                f"{manifest.directory / 'conditions.csv'} row {s + 2}: stack {table['file'][s]} is saturated "
                f"({frac:.1%} of its pixel readings sit at its maximum); use a lower sphere level or exposure"
            )
    frames = np.array([st.shape[0] for st in manifest.stacks])
    var, noise = _stack_variances(variances, frames)
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
    columns = [np.ones(len(frames))]
    names = ["offset_dn"]
    if np.unique(exposures).size > 1:
        columns.append(exposures)
        names.append("dark_current_dn_s")
    columns.append(np.where(table["kind"] == "flat", signal, 0.0))
    names.append("relative_gain")
    design = LinearDesign(np.stack(columns, axis=1), var / frames, tuple(names))  # noise of each stack mean
    if np.linalg.matrix_rank(design.X) < design.X.shape[1]:
        raise SpecError("the stacks do not determine every pixel parameter (need a dark stack and a flat stack)")
    stat = np.sum(((frames - 1) / var)[:, None] * variances, axis=0)
    theta_hat, _ = design.least_squares(means.T)
    population = fit_population(theta_hat, noise.phi(stat), design.covariance)
    post = pixel_posterior(theta_hat, noise.phi(stat), design.covariance, population)
    n_normal = float(np.sum(1.0 - post.defect_probability))
    stacks = table[["file", "kind", "exposure_s", "condition", "gain"]].copy()
    stacks["frames"] = frames
    stacks["variance"] = var
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
        {"fit_pixels": int(means.shape[1]), "rows_per_chunk": rows},
    )


def _block_task(*blocks, model: MapModel) -> np.ndarray:
    """dask task: all stacks' frames of one row block -> (outputs, rows, W) maps."""
    rows, width = blocks[0].shape[1:]
    stats = [block_statistics(b) for b in blocks]
    means = np.stack([m.ravel() for m, _ in stats])
    variances = np.stack([v.ravel() for _, v in stats])
    return model.block(means, variances).reshape(-1, rows, width)


def build_maps(
    stacks: str | os.PathLike | Manifest,
    *,
    fit_pixels: int = 262_144,
    rows_per_chunk: int | None = None,
    calibration: str | None = None,
):
    """Per-pixel maps of a stack directory, as a lazy :class:`xarray.Dataset` (dask arrays).

    Parameters
    ----------
    stacks : path or Manifest
        A directory with ``conditions.csv`` (see :mod:`bayescal.maps.stacks`).
    fit_pixels : int
        Pixels (whole row blocks, evenly spaced) used to fit the population.
    rows_per_chunk : int, optional
        Rows per block (default: about 48 MB of float64 frames per block).
    calibration : str, optional
        The channel-level fit directory whose absolute response the maps are
        relative to (recorded in the provenance; :func:`bayescal.maps.apply_maps`
        uses it to reach radiance).

    Returns
    -------
    xarray.Dataset
        Lazy maps; :func:`write_maps` streams them to a store.
    """
    import dask.array as da
    import xarray as xr

    manifest = stacks if isinstance(stacks, Manifest) else load_manifest(stacks)
    rows = rows_per_chunk or _rows_per_chunk(manifest)
    model = fit_map_model(manifest, fit_pixels=fit_pixels, rows_per_chunk=rows)
    arrays = open_stacks(manifest, rows)
    names = model.outputs()
    height, width = manifest.shape
    token = hashlib.sha1(json.dumps([str(manifest.directory), rows, names]).encode()).hexdigest()[:12]
    maps = da.map_blocks(
        _block_task,
        *arrays,
        model=model,
        chunks=((len(names),), arrays[0].chunks[1], (width,)),
        dtype=np.float32,
        name=f"pixel-maps-{token}",
    )
    data_vars = {}
    for i, name in enumerate(names):
        values = maps[i]
        if name == "defect":
            values = values.astype(np.int8)
        data_vars[name] = (("y", "x"), values, _attrs(name, model))
    ds = xr.Dataset(data_vars, coords={"y": np.arange(height), "x": np.arange(width)})
    ds.attrs.update(_provenance(manifest, model, calibration))
    return ds


def _attrs(name: str, model: MapModel) -> dict:
    base = name.removeprefix("u_random_").removeprefix("lsq_")
    if name in _UNITS:
        attrs = {"units": _UNITS[name], "long_name": _LONG[name] + ", posterior mean"}
        comps = [f"u_random_{name}"]
        if name == "relative_gain":
            comps.append("u_systematic_relative_gain")
        attrs["unc_comps"] = comps
        return attrs
    if name.startswith("u_random_"):
        return {
            "units": _UNITS[base],
            "long_name": f"per-pixel posterior standard deviation of {base}",
            "err_corr": json.dumps([{"dim": ["y", "x"], "form": "random", "params": [], "units": []}]),
            "pdf_shape": "gaussian",
        }
    if name.startswith("lsq_"):
        return {"units": _UNITS[base], "long_name": f"{base}, per-pixel weighted least squares (baseline)"}
    return {
        "corr_offset_dark": {"units": "1", "long_name": "posterior correlation of offset and dark current"},
        "defect_probability": {"units": "1", "long_name": "posterior probability that the pixel is defective"},
        "noisy_probability": {"units": "1", "long_name": "posterior probability of excess temporal noise"},
        "noise_scale": {"units": "1", "long_name": "expected temporal-variance scale of the pixel"},
        "defect": {
            "long_name": "defect class",
            "flag_values": list(DEFECT_CODES),
            "flag_meanings": " ".join(DEFECT_CODES.values()),
        },
    }[name]


def _provenance(manifest: Manifest, model: MapModel, calibration: str | None) -> dict:
    pop = model.population
    names = model.names
    spread = pop.spread
    flats = model.stacks["kind"] == "flat"
    systematic = float(np.sqrt(np.mean(model.signal_se[flats.to_numpy()] ** 2)))
    digest = hashlib.sha256((manifest.directory / "conditions.csv").read_bytes()).hexdigest()
    attrs = {
        "title": "bayescal per-pixel calibration maps",
        "bayescal_version": __version__,
        "created": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
        "stacks": str(manifest.directory),
        "manifest_sha256": digest,
        "calibration": calibration or "",
        "parameters": list(names),
        "population_weights": pop.weights.tolist(),
        "population_mean": pop.means[0].tolist(),
        "population_cov": pop.covs[0].ravel().tolist(),
        "defect_mean": pop.means[1].tolist(),
        "defect_cov": pop.covs[1].ravel().tolist(),
        "em_iterations": pop.iterations,
        "em_converged": int(pop.converged),
        "noisy_fraction": model.noise.fraction,
        "noisy_scale": model.noise.scale,
        "fit_pixels": model.info["fit_pixels"],
        "stacks_table": model.stacks.to_json(orient="records"),
        "design_X": model.design.X.ravel().tolist(),
        "design_var": model.design.var.tolist(),
        "u_systematic_relative_gain": systematic,
        "u_systematic_relative_gain_err_corr": json.dumps(
            [{"dim": ["y", "x"], "form": "systematic", "params": [], "units": []}]
        ),
    }
    for j, name in enumerate(names):
        attrs[f"spread_{name}"] = float(spread[j])
        attrs[f"spread_{name}_se"] = float(model.spread_se[j])
        attrs[f"spread_{name}_95"] = list(model.spread_95[j])
    # the dark signal non-uniformity at each dark exposure (EMVA 1288 section 8.2, pixel part): sd of o + D t
    exposures = np.unique(model.stacks.loc[model.stacks["kind"] == "dark", "exposure_s"].to_numpy(float))
    dsnu = [
        combination_spread(
            pop, model.design.covariance, np.r_[1.0, [t] * ("dark_current_dn_s" in names), 0.0], model.n_normal
        )
        for t in exposures
    ]
    attrs["dsnu_exposure_s"] = exposures.tolist()
    attrs["dsnu_dn"] = [d[0] for d in dsnu]
    attrs["dsnu_dn_se"] = [d[1] for d in dsnu]
    attrs["dsnu_dn_95"] = [list(d[2]) for d in dsnu]
    return attrs


def write_maps(ds, out: str | os.PathLike, *, netcdf: bool = False, progress=None) -> Path:
    """Stream the lazy maps to a zarr store (or a NetCDF file), atomically.

    An interrupted or failed run leaves no half-written store: the maps are
    staged beside ``out`` and moved into place only when complete.

    Parameters
    ----------
    progress : callable, optional
        ``progress(done, total)`` after each row block (local scheduler).
    """
    import dask
    from dask.callbacks import Callback

    out = Path(out)
    total = len(ds["defect"].data.chunks[0])
    done = [0]

    class _Blocks(Callback):
        def _posttask(self, key, result, dsk, state, worker_id):
            name = key[0] if isinstance(key, tuple) else key
            if isinstance(name, str) and name.startswith("pixel-maps-") and progress is not None:
                done[0] += 1
                progress(done[0], total)

    with staged_directory(out, kind="maps") as stage, _Blocks(), dask.config.set(num_workers=os.cpu_count()):
        if netcdf:
            ds.to_netcdf(stage("maps.nc"), engine="h5netcdf")
        else:
            ds.to_zarr(str(stage.root / "maps.zarr"), mode="w", consolidated=False, zarr_format=3)
    return out


def read_maps(path: str | os.PathLike):
    """Open maps written by :func:`write_maps` (a directory holding ``maps.zarr`` or ``maps.nc``)."""
    import xarray as xr

    path = Path(path)
    if (path / "maps.zarr").exists():
        try:
            return xr.open_zarr(str(path / "maps.zarr"), consolidated=False)
        except Exception as exc:  # zarr raises many types for a damaged store
            raise TableError(f"{path}/maps.zarr: not a readable maps store ({type(exc).__name__}: {exc})") from None
    if (path / "maps.nc").exists():
        try:
            return xr.open_dataset(path / "maps.nc", engine="h5netcdf")
        except (OSError, ValueError) as exc:
            raise TableError(f"{path}/maps.nc: not a readable maps file ({exc})") from None
    raise TableError(f"{path}: no maps.zarr or maps.nc (expected a directory written by `bayescal maps`)")
