"""From frame stacks to per-pixel calibration maps, out of core.

Two passes over the frames, each a dask computation chunked by rows (all
frames of a block of rows in one task), so memory is bounded by a few blocks
whatever the sensor size, and a ``dask.distributed`` client, when one is
active, spreads the blocks over its workers:

1. **population**: the per-pixel statistics of an evenly spaced subsample of
   bands of rows (``fit_pixels`` pixels) give the channel's signal per condition,
   the temporal variance of every stack, and the population (PRNU, DSNU and
   dark-current spreads, defect and noisy-pixel fractions) by maximum marginal
   likelihood (:mod:`bayescal.maps.population`);
2. **maps**: every block is reduced to its per-pixel statistics and each
   pixel's closed-form posterior is written straight to the store.

The store is written by :mod:`bayescal.maps.store`; its attributes come from
:mod:`bayescal.maps.metadata`.
"""

from __future__ import annotations

import hashlib
import json
import os

import numpy as np

from bayescal.errors import optional
from bayescal.maps.kernel import block_maps
from bayescal.maps.metadata import provenance, variable_attrs
from bayescal.maps.model import SensorModel, fit_map_model
from bayescal.maps.stacks import Manifest, load_manifest

__all__ = ["build_maps", "lazy_maps"]


def _block_task(rows: np.ndarray, block_info=None, *, model: SensorModel, stacks, width: int) -> np.ndarray:
    """dask task over a row-index chunk: the task opens the files itself, so no pixel data moves
    between tasks (or between processes and machines): one task per block, in and out."""
    r0, r1 = block_info[0]["array-location"][0]
    return block_maps(model, stacks, r0, r1)


def build_maps(
    stacks: str | os.PathLike | Manifest,
    *,
    fit_pixels: int = 262_144,
    rows_per_chunk: int | None = None,
    calibration: str | None = None,
    cfa: str | None = None,
    channel: str = "M",
):
    """Per-pixel maps of a stack directory, as a lazy :class:`xarray.Dataset` (dask arrays).

    Parameters
    ----------
    stacks : path or Manifest
        A directory with ``conditions.csv`` (see :mod:`bayescal.maps.stacks`).
    fit_pixels : int
        Pixels (whole rows in evenly spaced bands) used to fit the population.
    rows_per_chunk : int, optional
        Rows per block and per store chunk (default: about 2^20 pixels per block).
    calibration : str, optional
        The channel-level fit directory whose absolute response the maps are
        relative to (recorded in the provenance; :func:`bayescal.maps.apply_maps`
        uses it to reach radiance).
    cfa : str, optional
        Bayer pattern of raw mosaic frames (``RGGB``, ...): each colour channel
        gets its own population; default a monochrome sensor.
    channel : str
        The channel name of a monochrome sensor (the calibration's channel).

    Returns
    -------
    xarray.Dataset
        Lazy maps; :func:`write_maps` streams them to a store.
    """
    manifest = stacks if isinstance(stacks, Manifest) else load_manifest(stacks)
    model = fit_map_model(manifest, fit_pixels=fit_pixels, rows_per_chunk=rows_per_chunk, cfa=cfa, channel=channel)
    return lazy_maps(manifest, model, calibration)


def lazy_maps(manifest: Manifest, model: SensorModel, calibration: str | None):
    """The maps as an xarray Dataset of dask arrays: one task per row block."""
    da = optional("dask.array", "per-pixel maps")
    import xarray as xr

    rows = next(iter(model.models.values())).info["rows_per_chunk"]
    names = model.outputs()
    height, width = manifest.shape
    token = hashlib.sha1(json.dumps([str(manifest.directory), rows, names]).encode()).hexdigest()[:12]
    row_index = da.arange(height, chunks=rows)
    maps = da.map_blocks(
        _block_task,
        row_index,
        model=model,
        stacks=manifest.stacks,
        width=width,
        new_axis=[0, 2],
        chunks=((len(names),), row_index.chunks[0], (width,)),
        dtype=np.float32,
        name=f"pixel-maps-{token}",
    )
    data_vars = {}
    for i, name in enumerate(names):
        values = maps[i]
        if name == "defect":
            values = values.astype(np.int8)
        data_vars[name] = (("y", "x"), values, variable_attrs(name))
    ds = xr.Dataset(data_vars, coords={"y": np.arange(height), "x": np.arange(width)})
    ds.attrs.update(provenance(manifest, model, calibration))
    return ds
