"""Inversion tables: the stimulus posterior of every integer DN, computed once per calibration and setting.

The posterior of the stimulus behind an integer reading depends only on the
reading's value, its channel, the camera setting and the inversion's options
(pixels averaged, PRNU, credible level, noise, seed;
:func:`bayescal.prediction.invert.invert`).  A camera of ``b`` bits has at
most ``2**b`` such values per channel, so the summaries are computed once per
value and kept as one packed 16-byte record (median, lower, upper as float32;
the bound code, the extrapolation flag and whether the value has been computed
as bytes):

* in memory, on the :class:`~bayescal.posterior.calibration.Calibration`
  (values are added as images need them, so a 16-bit camera never computes the
  65,536 values no frame contains);
* on disk beside a fit's ``posterior.nc`` (``inversion-<key>.npz``, entered in
  the folder's record), so a survey's frames inverted in later processes, or on
  a cluster's workers, reuse the table; a file whose key, posterior hash or
  bayescal version differs is ignored.

An image is then one gather: each pixel's index is its DN plus its channel's
offset in the stacked tables (the colour filter array's period tiled over a
block of rows), and the 16-byte records are copied by ``numpy.take`` on row
blocks in threads (numpy releases the GIL), with a histogram of the indices in
the same pass that counts the pixels clipped, at or below dark, or
extrapolated.  While a table is incomplete, a first pass (the histogram alone)
finds the values the image has, and only those are computed.
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
import threading
import warnings
import weakref
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from bayescal._parallel import workers
from bayescal.model.setting import Setting
from bayescal.posterior.calibration import Calibration

__all__ = ["RECORD", "TableKey", "table", "fill", "gather", "restore_tables", "persist_tables"]

#: one table entry: 16 bytes, so a gather copies one complex128 per pixel
RECORD = np.dtype(
    [
        ("median", "f4"),
        ("lower", "f4"),
        ("upper", "f4"),
        ("bound", "i1"),
        ("extrapolated", "i1"),
        ("known", "u1"),
        ("pad", "V1"),
    ]
)
_ROWS = 64  # image rows per gather block (even: a 2 x 2 colour filter cell never straddles blocks)
_FORMAT = 1  # of the table files


@dataclass(frozen=True)
class TableKey:
    """What an inversion table depends on besides the calibration: channel, setting, options."""

    channel: str
    exposure_s: float
    gain: float
    tdi_stages: float
    temperature_c: float | None
    n_avg: float
    prnu: float
    level: float
    noise: bool
    seed: int

    @classmethod
    def of(
        cls, channel: str, setting: Setting, *, n_avg: float, prnu: float, level: float, noise: bool, seed: int
    ) -> TableKey:
        t = setting.temperature_c
        return cls(
            str(channel),
            float(setting.exposure_s),
            float(setting.gain),
            float(setting.tdi_stages),
            None if t is None else float(t),
            float(n_avg),
            float(prnu),
            float(level),
            bool(noise),
            int(seed),
        )

    def setting(self) -> Setting:
        return Setting(self.exposure_s, self.gain, self.tdi_stages, self.temperature_c)

    def file_name(self) -> str:
        """``inversion-<hash>.npz``: the table file of this key beside a posterior."""
        digest = hashlib.sha256(json.dumps(asdict(self), sort_keys=True).encode()).hexdigest()[:16]
        return f"inversion-{digest}.npz"


_GROWN = "grown"  # the entry of a calibration's cache that lists the keys computed further since read


#: each calibration's tables, {TableKey: records, _GROWN: {TableKey}}, kept while the calibration lives
_TABLES: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
_TABLES_LOCK = threading.Lock()


def _store(cal: Calibration) -> dict:
    """The tables computed for ``cal`` in this process (a cache beside it, not part of it)."""
    with _TABLES_LOCK:
        return _TABLES.setdefault(cal, {})


#: no values to compute: a table as far as it is known
_NOTHING = np.zeros(0, np.int64)


def table(cal: Calibration, key: TableKey, values: np.ndarray | None = None) -> np.ndarray:
    """The records ``(full_scale + 1,)`` of ``key``, computed for (at least) the integer ``values``.

    ``values=None`` computes every DN value.  Values computed before (in this
    process, or read by :func:`restore_tables`) are not computed again.
    """
    from bayescal.prediction.invert import value_summaries

    store = _store(cal)
    size = int(cal.full_scale) + 1
    records = store.get(key)
    if records is None:
        records = store[key] = np.zeros(size, RECORD)
    wanted = np.arange(size) if values is None else np.unique(np.asarray(values, dtype=np.int64))
    missing = wanted[records["known"][wanted] == 0]
    if missing.size:
        stats = value_summaries(
            cal, key.channel, missing.astype(float), key.setting(), key.n_avg, key.prnu, key.level, key.noise, key.seed
        )
        new = records[missing]
        for row, name in enumerate(("median", "lower", "upper")):
            new[name] = stats[row]
        new["bound"] = stats[3]
        new["extrapolated"] = stats[4]
        new["known"] = 1
        records[missing] = new
        store.setdefault(_GROWN, set()).add(key)
    return records


def fill(
    cal: Calibration,
    channels: list[str],
    setting: Setting,
    *,
    n_avg: float = 1.0,
    prnu: float | None = None,
    level: float = 0.95,
    noise: bool = True,
    seed: int = 0,
) -> None:
    """Compute every DN value's record of ``channels`` (the options as :func:`~bayescal.prediction.images.
    invert_image` takes them), so that inversions elsewhere, a cluster's workers, need only read them."""
    from bayescal.prediction.invert import reading_prnu

    prnu = reading_prnu(cal, n_avg, prnu)
    for name in channels:
        cal.channel_index(name)
        table(cal, TableKey.of(name, setting, n_avg=n_avg, prnu=prnu, level=level, noise=noise, seed=seed))


def _cell_offsets(shape: tuple[int, ...], views: list[tuple[tuple, str]], names: list[str], size: int) -> np.ndarray:
    """Each pixel's table offset over one block of ``_ROWS`` rows: the channel layout's period, tiled."""
    period: tuple[int, ...] = (2, 2) if any(isinstance(index[0], slice) for index, _ in views) else (1, 1)
    period = period + shape[2:]
    cells = np.zeros(period, np.int32)
    for index, name in views:
        cells[index] = names.index(name) * size
    reps = (-(-_ROWS // period[0]), -(-shape[1] // period[1])) + (1,) * (len(shape) - 2)
    return np.tile(cells, reps)[(slice(0, _ROWS), slice(0, shape[1]))]


def gather(
    cal: Calibration,
    image: np.ndarray,
    views: list[tuple[tuple, str]],
    setting: Setting,
    *,
    n_avg: float,
    prnu: float,
    level: float,
    noise: bool = True,
    seed: int = 0,
) -> tuple[np.ndarray, dict[str, int]]:
    """Records of every pixel of an integer ``image`` (its shape, :data:`RECORD`) and the flag counts.

    ``views`` say which channel each pixel belongs to
    (:func:`bayescal.prediction.images.channel_views`).  Returns the records
    and ``{"clipped", "below_dark", "extrapolated"}`` pixel counts.
    """
    names = list(dict.fromkeys(name for _, name in views))
    for name in names:
        cal.channel_index(name)  # a clear error for a channel the calibration lacks
    size = int(cal.full_scale) + 1
    keys = [TableKey.of(n, setting, n_avg=n_avg, prnu=prnu, level=level, noise=noise, seed=seed) for n in names]
    offsets = _cell_offsets(image.shape, views, names, size)
    out = np.empty(image.shape, RECORD)
    flat_out = out.view(np.complex128).reshape(image.shape)
    starts = range(0, image.shape[0], _ROWS)
    stacked = None  # the tables as one complex128 array, once every value the image has is computed

    def block(start: int) -> np.ndarray:
        rows = slice(start, min(start + _ROWS, image.shape[0]))
        index = np.add(image[rows], offsets[: rows.stop - start], dtype=np.int32)
        if stacked is not None:
            np.take(stacked, index, out=flat_out[rows], mode="clip")
        return np.bincount(index.ravel(), minlength=len(names) * size)

    def run() -> np.ndarray:
        threads = workers(len(starts))
        if threads > 1:  # numpy's take and bincount release the GIL: row blocks run on every core
            with ThreadPoolExecutor(max_workers=threads) as pool:
                return np.sum(list(pool.map(block, starts)), axis=0)
        return np.sum([block(s) for s in starts], axis=0)

    if not all(table(cal, k, _NOTHING)["known"].all() for k in keys):  # a first pass finds the values to compute
        present = run().reshape(len(names), size) > 0
        for k, p in zip(keys, present, strict=True):
            table(cal, k, np.flatnonzero(p))
    stacked = np.concatenate([table(cal, k, _NOTHING) for k in keys]).view(np.complex128)
    counts = run()  # the gather, with the histogram that counts the flags
    flags = np.concatenate([table(cal, k, _NOTHING)[["bound", "extrapolated"]] for k in keys])
    return out, {
        "clipped": int(counts[flags["bound"] == 1].sum()),
        "below_dark": int(counts[flags["bound"] == 2].sum()),
        "extrapolated": int(counts[flags["extrapolated"] > 0].sum()),
    }


# ------------------------------------------------------------------------ on disk
def _posterior_file(cal: Calibration) -> tuple[Path, str] | None:
    """The posterior file the calibration was read from and its recorded SHA-256 (None: not a fit folder's)."""
    from bayescal.io.outputs import read_marker

    if cal.folder is None or cal.folder.root is None or not cal.folder.posterior_path.is_file():
        return None
    path = cal.folder.posterior_path
    marker = read_marker(path.parent) or {}
    entry = marker.get("files", {}).get(path.name, {})
    return (path, entry["sha256"]) if "sha256" in entry else None


def _identity(sha: str) -> dict:
    from bayescal._version import __version__

    return {"format": _FORMAT, "posterior_sha256": sha, "bayescal_version": __version__}


def restore_tables(cal: Calibration) -> int:
    """Read the tables stored beside the calibration's posterior; returns how many were read.

    A file written for another posterior, format or bayescal version, or one
    that cannot be read, is skipped (the table is computed again).
    """
    found = _posterior_file(cal)
    if found is None:
        return 0
    path, sha = found
    store = _store(cal)
    read = 0
    for file in sorted(path.parent.glob("inversion-*.npz")):
        try:
            with np.load(file, allow_pickle=False) as data:
                meta = json.loads(str(data["meta"]))
                records = data["records"]
        except (OSError, ValueError, KeyError):
            continue
        if meta.get("identity") != _identity(sha) or records.dtype != RECORD:
            continue
        if records.shape != (int(cal.full_scale) + 1,):
            continue
        key = TableKey(**meta["key"])
        if key.file_name() != file.name:
            continue
        store[key] = records.copy()
        read += 1
    return read


def persist_tables(cal: Calibration) -> list[Path]:
    """Write the tables that grew in this process beside the calibration's posterior, in its record.

    Nothing is written for a calibration not read from a fit folder, or
    where the folder cannot be written (a warning says so: the inversion
    itself is unaffected).
    """
    from bayescal.errors import OutputError
    from bayescal.io.outputs import record_file, writing_as

    found = _posterior_file(cal)
    store = _store(cal)
    grown = store.pop(_GROWN, set())
    if found is None or not grown:
        return []
    path, sha = found
    written = []
    for key in sorted(grown, key=lambda k: k.file_name()):
        target = path.parent / key.file_name()
        meta = json.dumps({"identity": _identity(sha), "key": asdict(key)})
        try:
            fd, tmp = tempfile.mkstemp(prefix=".inversion-", suffix=".npz", dir=path.parent)
            with os.fdopen(fd, "wb") as f:
                np.savez(f, records=store[key], meta=np.array(meta))
            with writing_as("inversion tables"):
                kept = record_file(Path(tmp), target)
            if kept:
                written.append(target)
            else:
                Path(tmp).unlink(missing_ok=True)
        except (OSError, OutputError) as exc:
            warnings.warn(
                f"inversion table not kept beside {path} ({exc}); it is computed again next time", stacklevel=2
            )
    return written
