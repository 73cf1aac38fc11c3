"""Images in, radiance maps out: TIFF/PNG/NPY readers, Bayer mosaics, NetCDF/TIFF writers.

A raw Bayer mosaic maps each pixel to its colour channel through a named CFA
pattern (``RGGB``, ``BGGR``, ``GRBG``, ``GBRG``: the colours of the top-left
2 x 2 cell, row by row).  Every channel's pixels are inverted with that
channel's posterior (:func:`bayescal.prediction.invert.invert`, once per distinct DN
value) and the maps are written with the settings recorded.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import xarray as xr

from bayescal.errors import SpecError, TableError
from bayescal.io.cfa import CFA_PATTERNS, cfa_cells, channel_map
from bayescal.io.files import read_image
from bayescal.io.outputs import staged_directory, write_netcdf
from bayescal.model.setting import Setting
from bayescal.posterior.calibration import Calibration
from bayescal.prediction.invert import BOUND_NAMES, invert, reading_prnu
from bayescal.prediction.tables import gather

__all__ = ["read_image", "channel_map", "channel_views", "invert_image", "write_radiance_maps", "CFA_PATTERNS"]


def invert_image(
    cal: Calibration,
    image: np.ndarray,
    setting: Setting,
    *,
    cfa: str | None = None,
    channel: str | None = None,
    channels: list[str] | None = None,
    n_avg: float = 1.0,
    prnu: float | None = None,
    level: float = 0.95,
    seed: int = 0,
) -> xr.Dataset:
    """Radiance maps (median, lower, upper as float32; bound, extrapolated flags) of an image.

    Integer images: each channel's posterior is computed once per DN value and
    kept on the calibration (:mod:`bayescal.prediction.tables`); the pixels
    are gathered from it in one threaded pass, so a survey's later frames
    cost only the gather.  The maps of an integer image are views of one
    packed record array (float32 median, lower, upper; int8 flags).

    Exactly one of ``cfa`` (2-D Bayer mosaic), ``channel`` (2-D single
    channel) or ``channels`` (3-D ``(H, W, C)`` stack, one name per plane)
    says which channel each pixel belongs to.

    Examples
    --------
    >>> import numpy as np
    >>> import bayescal as bc
    >>> cal = bc.Calibration.from_coefficients({"G": [45.0, 30.0]}, reference=bc.Reference(0.004), bits=12)
    >>> radiance = bc.invert_image(cal, np.full((2, 2), 645.0), bc.Setting(0.008), channel="G")
    >>> radiance["median"].dtype, round(float(radiance["median"].max()), 3), radiance.attrs["unit"]
    (dtype('float32'), 10.004, 'W m^-2 sr^-1')
    """
    image = np.asarray(image)
    views = channel_views(image, cfa=cfa, channel=channel, channels=channels)
    prnu = reading_prnu(cal, n_avg, prnu)
    if np.issubdtype(image.dtype, np.integer):
        if image.size and (image.min() < 0 or image.max() > cal.full_scale):
            raise TableError(f"image DN values must lie in 0..{cal.full_scale:g} for a {cal.bits}-bit camera")
        records, counts = gather(cal, image, views, setting, n_avg=n_avg, prnu=prnu, level=level, seed=seed)
        out = {k: records[k] for k in ("median", "lower", "upper")}  # views of the packed records
        bound, extrap = records["bound"], records["extrapolated"]
    else:
        out = {k: np.empty(image.shape, np.float32) for k in ("median", "lower", "upper")}
        bound, extrap = np.zeros(image.shape, np.int8), np.zeros(image.shape, np.int8)
        for index, name in views:
            res = invert(cal, image[index], name, setting, n_avg=n_avg, prnu=prnu, level=level, seed=seed)
            for k in out:
                out[k][index] = getattr(res, k)
            bound[index] = res.bound
            extrap[index] = res.extrapolated
        counts = {
            "clipped": int(np.sum(bound == 1)),
            "below_dark": int(np.sum(bound == 2)),
            "extrapolated": int(np.sum(extrap)),
        }
    dims = ("y", "x", "channel") if image.ndim == 3 else ("y", "x")
    ds = xr.Dataset(
        {
            "median": (dims, out["median"], {"units": cal.unit, "long_name": f"posterior median {cal.stimulus}"}),
            "lower": (dims, out["lower"], {"units": cal.unit, "long_name": f"{level:.0%} interval lower end"}),
            "upper": (dims, out["upper"], {"units": cal.unit, "long_name": f"{level:.0%} interval upper end"}),
            "bound": (dims, bound, {"flag_values": list(BOUND_NAMES), "flag_meanings": " ".join(BOUND_NAMES.values())}),
            "extrapolated": (dims, extrap),
        }
    )
    if image.ndim == 3:
        ds = ds.assign_coords(channel=[name for _, name in views])
    ds.attrs.update(
        stimulus=cal.stimulus,
        unit=cal.unit,
        exposure_s=setting.exposure_s,
        gain=setting.gain,
        tdi_stages=setting.tdi_stages,
        cfa=cfa or "",
        channel=channel or "",
        n_avg=n_avg,
        credible_level=level,
        seed=seed,
        calibration=cal.source,
        n_saturated=counts["clipped"],
        n_below_dark=counts["below_dark"],
        n_extrapolated=counts["extrapolated"],
    )
    return ds


def channel_views(
    image: np.ndarray, *, cfa: str | None = None, channel: str | None = None, channels: list[str] | None = None
) -> list[tuple[tuple, str]]:
    """``[(index, channel name)]``: the strided view of each channel's pixels (``image[index]``).

    Exactly one of ``cfa`` (2-D Bayer mosaic), ``channel`` (2-D single
    channel) or ``channels`` (3-D ``(H, W, C)`` stack) must be given.
    """
    given = sum(v is not None for v in (cfa, channel, channels))
    if given != 1:
        raise SpecError("say how pixels map to channels: give exactly one of cfa=, channel= or channels=")
    if image.ndim == 3:
        if channels is None or len(channels) != image.shape[2]:
            raise SpecError(f"a {image.shape} stack needs channels= with {image.shape[2]} names")
        return [((Ellipsis, i), name) for i, name in enumerate(channels)]
    if channels is not None:
        raise SpecError("channels= is for (H, W, C) stacks; use cfa= or channel= for a 2-D image")
    if cfa is not None:
        return [((slice(dy, None, 2), slice(dx, None, 2)), name) for (dy, dx), name in cfa_cells(cfa).items()]
    assert channel is not None  # exactly one of the three was given
    return [((Ellipsis,), channel)]


def write_radiance_maps(ds: xr.Dataset, out_dir: str | os.PathLike) -> Path:
    """Write ``radiance.nc`` and ``median/lower/upper.tif`` (float32) and ``bound.tif`` (uint8), atomically.

    The settings go into the NetCDF attributes and each TIFF's description (JSON).
    """
    import tifffile

    out_dir = Path(out_dir)
    meta = json.dumps({k: (v.item() if hasattr(v, "item") else v) for k, v in ds.attrs.items()})
    with staged_directory(out_dir, kind="radiance") as stage:
        write_netcdf(ds, stage("radiance.nc"))
        for name in ("median", "lower", "upper"):
            tifffile.imwrite(stage(f"{name}.tif"), ds[name].to_numpy().astype(np.float32), description=meta)
        tifffile.imwrite(stage("bound.tif"), ds["bound"].to_numpy().astype(np.uint8), description=meta)
    return out_dir
