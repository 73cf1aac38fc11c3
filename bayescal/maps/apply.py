"""Applying per-pixel maps to a new image: flat-field, dark-subtract, invert, with every uncertainty.

For pixel ``i`` read at exposure ``t`` (EMVA 1288 release 4.0, eq. 2, per pixel):

``s_i = (DN_i - o_i - D_i t) / r_i``

is its signal in the channel's units (DN above dark that the channel's mean
pixel would read).  Its random variance, independent from pixel to pixel, is

``[ (v_dark(t) + K (DN_i - o_i - D_i t)) / n + var(o_i) + t^2 var(D_i) + 2 t cov(o_i, D_i) + s_i^2 var(r_i) ] / r_i^2``

(the reading's temporal noise, from the stacks' photon transfer; the map's
posterior uncertainty), and its systematic relative variance, common to all
pixels, is the normalisation error of the relative gain.  With a channel
calibration, ``dark + s_i`` is inverted to radiance through the channel's
posterior (which carries the sphere's and the response's uncertainty, common
to all pixels) and the per-pixel random part is propagated through the
inverse's slope; the two are combined in quadrature.  Defective pixels are
masked (NaN) and flagged.

The work is elementwise over blocks of ``BLOCK`` pixels, on every core
(numpy releases the GIL), so memory stays flat in the image size.
"""

from __future__ import annotations

import functools
import json
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy import stats as sstats

from bayescal._config import computes
from bayescal._parallel import workers
from bayescal.errors import TableError
from bayescal.model.components.dark import Dark
from bayescal.model.components.noise import Noise

__all__ = ["MapSet", "SensorMaps", "apply_maps", "noise_model"]


def noise_model(stacks: pd.DataFrame) -> tuple[np.ndarray, np.ndarray, float]:
    """Photon transfer from the stacks: dark variance vs exposure (a line) and ``K`` (DN per DN of signal).

    Returns ``(intercept, slope)`` of the dark temporal variance against
    exposure and the shot-noise slope ``K`` of flat variance above dark
    against signal (least squares through the origin; EMVA 1288 eq. 9).
    """
    dark = stacks[stacks["kind"] == "dark"]
    t, v = dark["exposure_s"].to_numpy(float), dark["variance"].to_numpy(float)
    line = np.polyfit(t, v, 1) if np.unique(t).size > 1 else np.array([0.0, v.mean()])
    flats = stacks[stacks["kind"] == "flat"]
    dark_var = dict(zip(dark["condition"], dark["variance"], strict=True))
    above = flats["variance"].to_numpy(float) - np.array([dark_var[c] for c in flats["condition"]])
    signal = flats["signal_dn"].to_numpy(float)
    k = float(np.sum(above * signal) / np.sum(signal * signal))
    return line[1], line[0], k


@dataclass(frozen=True)
class MapSet:
    """Maps in memory (float32) with what correcting an image needs."""

    relative_gain: np.ndarray
    offset: np.ndarray
    dark: np.ndarray
    var_gain: np.ndarray
    var_offset: np.ndarray
    var_dark: np.ndarray
    cov_offset_dark: np.ndarray
    defect: np.ndarray
    dark_var: tuple[float, float]  # dark temporal variance = a + b t
    shot_k: float
    systematic_rel: float
    mean_offset: float
    mean_dark: float
    source: str
    temperature_ref_c: float = float("nan")  # the dark maps' temperature (NaN: no temperature term)
    doubling_c: float = float("nan")

    @functools.cached_property
    def inverse_gain(self) -> np.ndarray:
        """``1 / relative_gain``, NaN at defects (so every output there is NaN), computed once."""
        inv = (np.float32(1.0) / self.relative_gain).astype(np.float32)
        inv[self.defect > 0] = np.nan
        return inv

    @functools.cached_property
    def _exposures(self) -> dict:
        return {}

    def dark_factor(self, temperature_c: float | None) -> float:
        """Dark current at ``temperature_c`` relative to the maps' (1 without a temperature term or temperature)."""
        if temperature_c is None or not np.isfinite(self.doubling_c):
            return 1.0
        return float(Dark.doubling(temperature_c - self.temperature_ref_c, self.doubling_c))

    def at_exposure(self, t: float, temperature_c: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Dark level ``o + D t'`` and map variance ``var(o) + t'^2 var(D) + 2 t' cov`` with ``t' = t k(T)``
        (the dark current's temperature factor folded into the exposure; the latest one cached)."""
        key = (float(t), temperature_c)
        t = float(t) * self.dark_factor(temperature_c)
        if key not in self._exposures:
            if self._exposures:  # one exposure kept: two float32 maps
                self._exposures.pop(next(iter(self._exposures)))
            f = np.float32
            dark = Dark.level(self.offset, self.dark, f(t))
            var = self.var_offset + self.var_dark * f(t * t)
            var += self.cov_offset_dark * f(2 * t)
            self._exposures[key] = (dark.astype(f), var.astype(f))
        return self._exposures[key]

    @classmethod
    def from_dataset(cls, ds, channel: str | None = None) -> MapSet:
        """One channel's maps (``ds`` already cut to that channel's plane for a mosaic)."""
        from bayescal.maps.metadata import channel_attrs

        attrs = channel_attrs(ds, channel)

        def arr(name, fill=0.0):
            if name not in ds:
                return np.full(ds["relative_gain"].shape, fill, np.float32)
            return np.ascontiguousarray(ds[name].to_numpy(), dtype=np.float32)

        stacks = pd.DataFrame(json.loads(attrs["stacks_table"]))
        a, b, k = noise_model(stacks)
        sd_o, sd_d = arr("u_random_offset_dn"), arr("u_random_dark_current_dn_s")
        names = list(attrs["parameters"])
        mean = attrs["population_mean"]
        return cls(
            arr("relative_gain", 1.0),
            arr("offset_dn"),
            arr("dark_current_dn_s"),
            arr("u_random_relative_gain") ** 2,
            sd_o**2,
            sd_d**2,
            arr("corr_offset_dark") * sd_o * sd_d,
            np.ascontiguousarray(ds["defect"].to_numpy(), dtype=np.int8),
            (float(a), float(b)),
            k,
            float(attrs["u_systematic_relative_gain"]),
            float(mean[names.index("offset_dn")]),
            float(mean[names.index("dark_current_dn_s")]) if "dark_current_dn_s" in names else 0.0,
            str(ds.attrs.get("stacks", "")),
            float(attrs.get("temperature_ref_c", np.nan)),
            float(attrs.get("doubling_c", np.nan)),
        )

    @property
    def shape(self) -> tuple[int, int]:
        return self.relative_gain.shape


@dataclass(frozen=True)
class SensorMaps:
    """A sensor's maps in memory: one :class:`MapSet` per colour plane (one plane for a monochrome sensor)."""

    step: int
    planes: tuple[tuple[str, int, int, MapSet], ...]  # (channel, row offset, column offset, maps)
    shape: tuple[int, int]

    @classmethod
    def from_dataset(cls, ds) -> SensorMaps:
        from bayescal.io.cfa import planes

        channels = list(ds.attrs.get("channels", ["M"]))
        step, layout = planes(ds.attrs.get("cfa") or None, channels[0])
        cut = [(name, dy, dx, ds.isel(y=slice(dy, None, step), x=slice(dx, None, step))) for name, dy, dx in layout]
        return cls(
            step, tuple((n, dy, dx, MapSet.from_dataset(d, n)) for n, dy, dx, d in cut), tuple(ds["defect"].shape)
        )


#: pixels per compiled block (the last block is padded, so one program serves every image size)
BLOCK = 1 << 17


@functools.cache
def _kernel(parts: bool):
    """The per-pixel correction and inversion as one fused XLA program (float32, one pass over memory)."""
    import jax
    import jax.numpy as jnp

    def kernel(dn, r_inv, dark, var_map, var_gain, tables, scalars):
        n_frames, shot_k, dark_var, sys_rel, x0, dx, z = (scalars[i] for i in range(7))
        above = dn.astype(jnp.float32) - dark
        s = above * r_inv
        var = Noise.reading_variance(Noise.temporal_variance(above, dark_var, shot_k, jnp), n_frames)
        rand = jnp.sqrt((var + var_map + s * s * var_gain) * (r_inv * r_inv))
        med_t, lo_t, hi_t = tables[0], tables[1], tables[2]
        last = med_t.shape[0] - 1
        pos = jnp.clip((s - x0) / dx, 0, last)
        j = jnp.minimum(pos.astype(jnp.int32), last - 1)
        w = pos - j
        m0, m1 = med_t[j], med_t[j + 1]
        med = m0 + w * (m1 - m0)
        slope = (m1 - m0) / dx
        lo_sys = med - (lo_t[j] + w * (lo_t[j + 1] - lo_t[j]))
        hi_sys = (hi_t[j] + w * (hi_t[j + 1] - hi_t[j])) - med
        rand = rand * slope
        rel = s * sys_rel * slope
        lo_sys = jnp.sqrt(lo_sys * lo_sys + rel * rel)
        hi_sys = jnp.sqrt(hi_sys * hi_sys + rel * rel)
        zr = z * rand
        bounds = (med, med - jnp.sqrt(zr * zr + lo_sys * lo_sys), med + jnp.sqrt(zr * zr + hi_sys * hi_sys))
        return bounds + ((rand, 0.5 * (lo_sys + hi_sys) / z) if parts else ())

    return jax.jit(kernel)


@computes
def apply_maps(
    maps,
    image: np.ndarray,
    exposure_s: float,
    *,
    n_frames: float = 1.0,
    level: float = 0.95,
    calibration=None,
    channel: str | None = None,
    setting=None,
    grid: int = 2048,
    parts: bool = False,
    temperature_c: float | None = None,
):
    """Correct (and, with a calibration, invert) ``image`` pixel by pixel.

    Parameters
    ----------
    maps : SensorMaps, MapSet or xarray.Dataset
        From :func:`bayescal.maps.build_maps` / :func:`bayescal.maps.read_maps`
        (convert once with :meth:`SensorMaps.from_dataset` to apply many frames).
    image : ndarray
        ``(H, W)`` readings (DN), the maps' shape (a raw mosaic for Bayer
        maps); a mean of ``n_frames`` frames.
    exposure_s : float
        The image's exposure.
    calibration : Calibration, optional
        The channel-level posterior; without it the output is the corrected
        signal in DN (channel units), with it radiance.  A mosaic's planes
        are inverted with the calibration's channel of the same name.
    channel : str, optional
        The calibration's channel of monochrome maps (default: the maps'
        channel if calibrated, else the calibration's first).
    setting : Setting, optional
        The image's setting for the calibration (default: ``exposure_s`` at
        the reference gain).
    parts : bool
        Also return the random (per-pixel) and systematic (all-pixel)
        standard uncertainties ``u_random``, ``u_systematic``.
    temperature_c : float, optional
        Sensor temperature of the image: maps fitted over a temperature range
        scale each pixel's dark current by ``2^((T - T_ref) / T_d)``; default
        the maps' reference temperature.

    Returns
    -------
    xarray.Dataset
        ``median``, ``lower``, ``upper`` (float32; NaN at defects), with
        ``parts`` ``u_random`` and ``u_systematic``, and ``defect`` (int8 codes).
    """
    import xarray as xr

    if isinstance(maps, MapSet):
        sensor = SensorMaps(1, (("M", 0, 0, maps),), maps.shape)
    elif isinstance(maps, SensorMaps):
        sensor = maps
    else:
        sensor = SensorMaps.from_dataset(maps)
    image = np.asarray(image)
    if image.shape != sensor.shape:
        raise TableError(f"image has shape {image.shape}; the maps are {sensor.shape[0]} x {sensor.shape[1]}")
    if not (np.isfinite(exposure_s) and exposure_s > 0):
        raise TableError(f"exposure {exposure_s!r}: expected a positive number of seconds")
    names = ("median", "lower", "upper", "u_random", "u_systematic")[: 5 if parts else 3]
    out = {k: np.empty(sensor.shape, np.float32) for k in names}
    defect = np.empty(sensor.shape, np.int8)
    k = sensor.step
    for name, dy, dx, m in sensor.planes:
        which = _calibration_channel(name, channel, calibration, mosaic=k > 1)
        plane = image if k == 1 else np.ascontiguousarray(image[dy::k, dx::k])
        res = _apply_plane(
            m, plane, exposure_s, n_frames, level, calibration, which, setting, grid, names, temperature_c
        )
        for key in names:
            out[key][dy::k, dx::k] = res[key]
        defect[dy::k, dx::k] = m.defect
    unit = "DN" if calibration is None else calibration.unit
    dims = ("y", "x")
    ds = xr.Dataset(
        {key: (dims, v, {"units": unit}) for key, v in out.items()}
        | {"defect": (dims, defect, {"long_name": "defect class from the maps"})}
    )
    ds["median"].attrs["long_name"] = (
        "corrected signal (channel DN above dark)"
        if calibration is None
        else (f"posterior median {calibration.stimulus}")
    )
    for key, form in (("u_random", "random"), ("u_systematic", "systematic")):
        if key in ds:
            ds[key].attrs["err_corr"] = json.dumps([{"dim": ["y", "x"], "form": form, "params": [], "units": []}])
    ds.attrs.update(
        exposure_s=exposure_s,
        n_frames=n_frames,
        credible_level=level,
        maps=sensor.planes[0][3].source,
        n_defective=int(np.count_nonzero(defect)),
    )
    return ds


def _calibration_channel(name: str, channel: str | None, calibration, mosaic: bool) -> str:
    """The calibration channel a plane is inverted with: a mosaic plane's own colour; for monochrome
    maps the one asked for, else the maps' channel when calibrated, else the calibration's first."""
    if mosaic or calibration is None:
        return name
    if channel:
        return channel
    return name if name in calibration.channels else calibration.channels[0]


def _apply_plane(
    m: MapSet, image, exposure_s, n_frames, level, calibration, channel, setting, grid, names, temperature_c=None
) -> dict:
    """One colour plane: the fused kernel over blocks of pixels, on two cores."""
    z = float(sstats.norm.ppf(0.5 + level / 2))
    n = image.size
    out = {k: np.empty(n, np.float32) for k in names}
    if calibration is None:  # the identity table: corrected signal in DN, systematic part relative only
        top = 4.0 * (float(np.max(np.abs(image))) + 1.0 if image.size else 1.0)
        tables = np.array([[-top, top]] * 3, np.float32)
        x0, dx = -top, 2.0 * top
    else:
        x0, dx, med_t, lo_t, hi_t = _radiance_lut(m, calibration, channel, setting, exposure_s, grid)
        tables = np.stack([med_t, lo_t, hi_t])
    dark_var = m.dark_var[0] + m.dark_var[1] * exposure_s
    scalars = np.array([n_frames, m.shot_k, dark_var, m.systematic_rel, x0, dx, z], np.float32)
    kernel = _kernel(len(names) == 5)
    maps_flat = [a.reshape(-1) for a in (m.inverse_gain, *m.at_exposure(exposure_s, temperature_c), m.var_gain)]
    flat_image = np.ascontiguousarray(image).reshape(-1)

    def work(start: int) -> None:
        stop = min(start + BLOCK, n)
        args = [flat_image[start:stop]] + [a[start:stop] for a in maps_flat]
        if stop - start < BLOCK:  # pad the last block: one compiled program for every image size
            args = [np.pad(a, (0, BLOCK - (stop - start))) for a in args]
        res = kernel(*args, tables, scalars)
        for key, v in zip(out, res, strict=True):
            out[key][start:stop] = np.asarray(v)[: stop - start]

    starts = range(0, n, BLOCK)
    threads = workers(len(starts))
    if threads > 1:  # XLA releases the GIL: a block in flight per core keeps them busy
        with ThreadPoolExecutor(max_workers=threads) as pool:
            list(pool.map(work, starts))
    else:
        for start in starts:
            work(start)
    return {key: v.reshape(m.shape) for key, v in out.items()}


def _radiance_lut(m: MapSet, cal, channel, setting, exposure_s, grid):
    """Channel signal above dark -> radiance median and systematic bounds, on a uniform grid."""
    from bayescal.model.setting import Setting
    from bayescal.prediction.invert import invert

    cal.channel_index(channel)  # a clear error for a channel the calibration does not hold
    setting = setting or Setting(exposure_s, cal.reference.gain, cal.reference.tdi_stages)
    dark = Dark.level(m.mean_offset, m.mean_dark, exposure_s)
    top = float(cal.saturation_dn) - dark
    xs = np.linspace(0.0, top, grid)
    res = invert(cal, dark + xs, channel, setting, noise=False)
    med = np.where(np.isfinite(res.median), res.median, 0.0)
    lo = np.where(np.isfinite(res.lower), res.lower, 0.0)
    hi = np.where(np.isfinite(res.upper), res.upper, med)
    f32 = np.float32
    return f32(0.0), f32(xs[1] - xs[0]), med.astype(f32), lo.astype(f32), hi.astype(f32)
