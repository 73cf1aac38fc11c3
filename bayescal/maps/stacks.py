"""Flat and dark frame stacks: the manifest, lazy readers, and the per-pixel statistics.

A stack directory holds one file per stack (``.npy`` of shape ``(frames, H, W)``,
a multi-page ``.tif``, or a headerless ``.raw`` of little-endian uint16 frames
whose shape the manifest gives) and a ``conditions.csv`` manifest with one row
per stack:

``file``
    the stack's file name, relative to the directory;
``kind``
    ``flat`` (sphere illumination) or ``dark`` (shutter closed);
``exposure_s``
    exposure time in seconds;
``condition``
    an identifier pairing each flat stack with the dark stack taken at the same
    exposure (EMVA 1288 release 4.0, section 6.1: every bright measurement is
    paired with a dark one); a condition holds one dark stack and any number
    of flat stacks at its exposure (an illumination sweep shares one dark);
    a dark stack may stand alone;
``gain`` (optional)
    the gain step (one value per manifest: maps are per gain);
``temperature_c`` (optional)
    the sensor temperature of each stack: with a range of temperatures the
    dark current's doubling temperature is fitted (shared by the pixels);
``height``, ``width`` (``.raw`` only).

Every stack is opened lazily (:class:`LazyStack`: only its path travels to a
dask worker); each row-block task reads all frames of its rows itself, so each
byte is read once, by whichever worker maps that block.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from bayescal.errors import TableError
from bayescal.io.fits import FITS_SUFFIXES, fits_layout

__all__ = [
    "Manifest",
    "LazyStack",
    "load_manifest",
    "load_stacks",
    "block_statistics",
    "write_emva_stacks",
]

MANIFEST = "conditions.csv"
_REQUIRED = ("file", "kind", "exposure_s", "condition")


@dataclass(frozen=True)
class LazyStack:
    """A picklable, lazily opened ``(frames, H, W)`` stack (dask's array protocol: shape, dtype, ``[...]``).

    Every format is stored as contiguous frames from ``offset`` on.  Only the
    path travels to a worker, which reads the rows it needs itself, so a
    distributed reduction ships no pixel data through the scheduler.
    """

    path: str
    shape: tuple[int, int, int]
    dtype: np.dtype
    format: str
    offset: int = 0
    flip: int = 0  # unsigned pixels stored signed (FITS BZERO): the bit to flip after reading

    @property
    def ndim(self) -> int:
        return 3

    def _map(self) -> np.ndarray:
        return np.memmap(self.path, dtype=self.dtype, mode="r", offset=self.offset, shape=self.shape)

    def __getitem__(self, index) -> np.ndarray:
        out = np.asarray(self._map()[index])
        return out ^ out.dtype.type(self.flip) if self.flip else out

    def read_rows(self, r0: int, r1: int, out: np.ndarray | None = None) -> np.ndarray:
        """Rows ``r0:r1`` of every frame, ``(frames, r1 - r0, W)`` in native byte order, read with one
        positioned read per frame (several times faster than copying from a memory map, whose every
        page faults on first touch).  ``out`` (native byte order), when given, is filled in place and
        returned."""
        frames, height, width = self.shape
        if not 0 <= r0 < r1 <= height:
            raise IndexError(f"{self.path}: rows {r0}:{r1} outside 0:{height}")
        native = self.dtype.newbyteorder("=")
        if out is None:
            out = np.empty((frames, r1 - r0, width), native)
        row_bytes = width * native.itemsize
        with open(self.path, "rb", buffering=0) as fh:
            for f in range(frames):
                fh.seek(self.offset + (f * height + r0) * row_bytes)
                target = memoryview(out[f]).cast("B")
                if fh.readinto(target) != len(target):
                    raise TableError(f"{self.path}: the file ends inside frame {f} (truncated?)")
        if not self.dtype.isnative:  # the file's bytes are in the other order: swap them where they lie
            out.byteswap(inplace=True)
        if self.flip:  # unsigned pixels stored signed: flip the sign bit where they lie
            out ^= out.dtype.type(self.flip)
        if out.dtype.kind == "f" and not np.isfinite(out).all():  # a float stack: NaN or inf breaks every fit
            f, r, c = (int(i) for i in np.argwhere(~np.isfinite(out))[0])
            raise TableError(
                f"{self.path}: frame {f}, row {r0 + r}, column {c} is {out[f, r, c].item()}; expected finite DN "
                "in every frame (replace or mask the pixel before mapping)"
            )
        if out.dtype.kind in "if" and (out < 0).any():  # raw DN are never negative (a signed type's wrap)
            f, r, c = (int(i) for i in np.argwhere(out < 0)[0])
            raise TableError(
                f"{self.path}: frame {f}, row {r0 + r}, column {c} is {out[f, r, c].item()}; expected raw DN >= 0 "
                "(a dark-subtracted or wrapped signed stack?)"
            )
        return out


def _open_one(path: Path, row: pd.Series, where: str) -> LazyStack:
    suffix = path.suffix.lower()
    if not path.is_file():
        raise TableError(f"{where}: stack file {path} does not exist")
    try:
        if suffix == ".npy":
            mm = np.load(path, mmap_mode="r")
            if mm.dtype.kind not in "uif":
                raise TableError(f"{where}: {path.name} holds {mm.dtype} values; expected DN as integers or floats")
            if mm.ndim not in (2, 3):
                raise TableError(f"{where}: {path.name} has shape {mm.shape}; expected (frames, height, width)")
            if not mm.flags.c_contiguous:
                raise TableError(f"{where}: {path.name} is Fortran-ordered; save it C-ordered")
            shape = mm.shape if mm.ndim == 3 else (1, *mm.shape)
            stack = LazyStack(str(path), tuple(shape), mm.dtype, "npy", int(mm.offset))
        elif suffix in (".tif", ".tiff"):
            import tifffile

            try:
                mm = tifffile.memmap(str(path), mode="r")
            except Exception as exc:  # tifffile's own errors for a truncated, empty or compressed file
                raise TableError(
                    f"{where}: {path.name} is not an uncompressed contiguous TIFF ({exc}); "
                    "save the stack uncompressed or as .npy"
                ) from None
            shape = mm.shape if mm.ndim == 3 else (1, *mm.shape)
            stack = LazyStack(str(path), tuple(shape), mm.dtype, "tif", int(mm.offset))
        elif suffix == ".raw":
            h, w = (int(row.get(k, 0) or 0) for k in ("height", "width"))
            if h <= 0 or w <= 0:
                raise TableError(f"{where}: a .raw stack needs positive 'height' and 'width' columns")
            frame = h * w * 2
            size = path.stat().st_size
            if size == 0 or size % frame:
                raise TableError(
                    f"{where}: {path.name} has {size} bytes, not a whole number of {h} x {w} uint16 frames"
                )
            stack = LazyStack(str(path), (size // frame, h, w), np.dtype("<u2"), "raw")
        elif suffix in FITS_SUFFIXES:
            layout = fits_layout(path)
            stack = LazyStack(str(path), layout.shape, layout.dtype, "fits", layout.offset, layout.flip)
        else:
            raise TableError(f"{where}: {path.name}: expected a .npy, .tif, .fits or .raw stack")
    except (OSError, ValueError) as exc:
        raise TableError(f"{where}: cannot read stack {path.name} ({exc})") from None
    if not np.issubdtype(stack.dtype, np.integer) and not np.issubdtype(stack.dtype, np.floating):
        raise TableError(f"{where}: {path.name} holds {stack.dtype}; expected integer or float pixel values")
    if stack.shape[0] < 2:
        raise TableError(
            f"{where}: {path.name} has {stack.shape[0]} frame; at least 2 are needed to measure temporal noise"
        )
    return stack


@dataclass(frozen=True)
class Manifest:
    """The validated manifest: one row per stack, and each stack opened lazily."""

    directory: Path
    table: pd.DataFrame  # file, kind, exposure_s, condition, gain
    stacks: tuple[LazyStack, ...]
    source: str = ""  # what the stacks were made from, when not measured as stacks (an EMVA 1288 descriptor)

    @property
    def shape(self) -> tuple[int, int]:
        return self.stacks[0].shape[1:]

    @property
    def bytes(self) -> int:
        """Bytes of pixel data in all stacks (what a full read costs)."""
        return int(sum(np.prod(s.shape) * s.dtype.itemsize for s in self.stacks))


#: the fewest pixels a stack may have: the population's spreads and the defect mixture need many
MIN_PIXELS = 64


def load_manifest(directory: str | os.PathLike, *, source: str = "") -> Manifest:
    """Read and check ``conditions.csv`` in ``directory`` and open every stack lazily.

    ``source`` names what the directory was written from (provenance), e.g.
    the EMVA 1288 descriptor :func:`write_emva_stacks` read.

    Raises
    ------
    TableError
        Naming the file, row and column: a missing column, an unknown kind, a
        non-positive exposure, frames of different shapes, a flat condition
        without its dark stack, more than one gain, an unreadable stack.
    """
    directory = Path(directory)
    path = directory / MANIFEST
    if not path.is_file():
        raise TableError(f"{directory}: no {MANIFEST} manifest (one row per stack: {', '.join(_REQUIRED)})")
    try:
        table = pd.read_csv(path)
    except (UnicodeDecodeError, pd.errors.ParserError, pd.errors.EmptyDataError) as exc:
        raise TableError(f"{path}: not a readable CSV table ({exc})") from None
    missing = [c for c in _REQUIRED if c not in table.columns]
    if missing:
        raise TableError(f"{path}: missing column(s) {', '.join(missing)}; expected {', '.join(_REQUIRED)}")
    if table.empty:
        raise TableError(f"{path}: no stacks listed")
    table = _settings_from_headers(table, directory)
    if "gain" not in table.columns:
        table["gain"] = 1.0
    if "temperature_c" not in table.columns:
        table["temperature_c"] = np.nan
    else:
        temps = pd.to_numeric(table["temperature_c"], errors="coerce")
        bad = np.flatnonzero(~np.isfinite(temps))
        if bad.size:
            i = int(bad[0])
            raise TableError(
                f"{path} row {i + 2}, column temperature_c: {table['temperature_c'][i]!r}; expected a temperature "
                "in degC on every row (or leave the column out)"
            )
        table["temperature_c"] = temps.astype(float)
    table["kind"] = table["kind"].astype(str).str.strip().str.lower()
    for i, row in table.iterrows():
        where = f"{path} row {i + 2}"
        if row["kind"] not in ("flat", "dark"):
            raise TableError(f"{where}, column kind: '{row['kind']}'; expected flat or dark")
        for col in ("exposure_s", "gain"):
            value = pd.to_numeric(pd.Series([row[col]]), errors="coerce").iloc[0]
            dark_zero = col == "exposure_s" and row["kind"] == "dark" and value == 0  # a bias frame (EMVA's d 0)
            if not np.isfinite(value) or value < 0 or (value == 0 and not dark_zero):
                raise TableError(
                    f"{where}, column {col}: {row[col]!r}; expected a positive number"
                    + (" (0 only for a dark stack)" if col == "exposure_s" else "")
                )
    table["exposure_s"] = table["exposure_s"].astype(float)
    table["gain"] = table["gain"].astype(float)
    if table["gain"].nunique() > 1:
        raise TableError(
            f"{path}, column gain: {table['gain'].nunique()} gains; per-pixel maps are fitted per gain, "
            "so give one manifest per gain"
        )
    dup = table.duplicated(["condition", "kind"], keep=False) & (table["kind"] == "dark")
    if dup.any():
        i = int(np.flatnonzero(dup)[0])
        raise TableError(
            f"{path} row {i + 2}: condition {table['condition'][i]!r} has two dark stacks; "
            "a condition holds one dark stack (and one or more flat stacks at its exposure)"
        )
    for cond, rows in table.groupby("condition", sort=False):
        kinds = set(rows["kind"])
        if "flat" in kinds and "dark" not in kinds:
            i = int(rows.index[0])
            raise TableError(
                f"{path} row {i + 2}: flat condition {cond!r} has no dark stack; every flat needs the dark "
                "stack taken at its exposure"
            )
        if rows["exposure_s"].nunique() > 1:
            i = int(rows.index[1])
            raise TableError(f"{path} row {i + 2}, column exposure_s: condition {cond!r} mixes exposures")
    if not (table["kind"] == "flat").any():
        raise TableError(f"{path}: no flat stacks; the relative-gain (PRNU) map needs illuminated frames")
    stacks = tuple(_open_one(directory / str(row["file"]), row, f"{path} row {i + 2}") for i, row in table.iterrows())
    shape = stacks[0].shape[1:]
    if shape[0] * shape[1] < MIN_PIXELS:
        raise TableError(
            f"{path}: the frames are {shape[0]} x {shape[1]} pixels; per-pixel maps fit a population of pixels "
            f"and need at least {MIN_PIXELS} (for a single pixel's response, fit a table with `bayescal fit`)"
        )
    for i, s in enumerate(stacks):
        if s.shape[1:] != shape:
            raise TableError(
                f"{path} row {i + 2}: {table['file'][i]} has {s.shape[1]} x {s.shape[2]} frames; "
                f"the first stack has {shape[0]} x {shape[1]} (all frames must share one shape)"
            )
    return Manifest(directory, table.reset_index(drop=True), stacks, source)


def _settings_from_headers(table: pd.DataFrame, directory: Path) -> pd.DataFrame:
    """Empty ``exposure_s`` cells of FITS stacks filled from their headers (``EXPTIME``...), and a
    ``temperature_c`` column added when the manifest has none and every stack's header records one
    (``CCD-TEMP``...).  A cell the manifest fills is never replaced."""
    is_fits = table["file"].astype(str).str.lower().str.endswith(FITS_SUFFIXES)
    if not is_fits.any():
        return table
    table = table.copy()
    table["exposure_s"] = table["exposure_s"].astype(object)
    temperatures = []
    for i in table.index:
        file = directory / str(table.at[i, "file"])
        settings = fits_layout(file).settings if is_fits[i] and file.is_file() else {}
        if pd.isna(table.at[i, "exposure_s"]) and "exposure_s" in settings:
            table.at[i, "exposure_s"] = settings["exposure_s"]
        temperatures.append(settings.get("temperature_c", np.nan))
    if "temperature_c" not in table.columns and np.isfinite(temperatures).all():
        table["temperature_c"] = temperatures
    return table


#: the public name: a stack directory's validated manifest, every stack opened lazily
load_stacks = load_manifest


def write_emva_stacks(
    source: str | os.PathLike,
    out_dir: str | os.PathLike,
    *,
    max_level: float = 0.7,
    progress: Callable[[int, int], None] | None = None,
) -> Path:
    """An EMVA 1288 image set as a stack directory with its manifest.

    ``source`` is a descriptor (``EMVA1288_Data.txt``: ``n``, ``b``, ``d`` and
    ``i`` lines, its images beside it) or the cropped arrays (``crop128.npz``).
    Both of the standard's layouts are read: an exposure sweep at one
    irradiance (a dark pair per exposure) and an illumination sweep at one
    exposure (one dark pair for all bright pairs).  Every bright group whose
    mean stays below ``max_level`` of full scale (EMVA 1288 release 4.0
    section 8: non-uniformities are measured below saturation) becomes a flat
    stack; it shares a condition with the dark group of its exposure (pairs
    with pairs, stacks of more than two images with stacks).  Darks whose
    condition keeps no flat are left out with their brights, so the per-pixel
    dark line spans the exposures of the flats.

    Raises
    ------
    TableError
        Naming the descriptor line of a bright group with no dark group at its
        exposure, images of another shape than the first, or values outside
        the ADC's range.
    """
    from bayescal.io.emva import read_groups
    from bayescal.io.outputs import staged_directory

    bits, groups = read_groups(source)
    with staged_directory(out_dir, kind="stacks") as stage:  # the set whole, or nothing
        _stacks(groups, bits, stage.root, source, max_level, progress)
    return Path(out_dir)


def _stacks(groups, bits: int, out: Path, source, max_level: float, progress) -> None:
    """The stacks and manifest of :func:`write_emva_stacks`, into the staged folder ``out``."""
    from bayescal.io.emva import ImageGroup

    full = 2**bits - 1
    dtype = np.uint8 if bits <= 8 else np.uint16 if bits <= 16 else np.uint32

    def condition(g: ImageGroup) -> str:
        return f"t{g.texp_ns:.0f}ns" + ("_stack" if g.is_stack else "")

    darks: dict[str, ImageGroup] = {}
    for g in groups:
        if g.kind == "dark":
            if condition(g) in darks:
                raise TableError(
                    f"{g.where}: a second dark group at {g.texp_ns:g} ns (first at {darks[condition(g)].where}); "
                    "give one dark group per exposure"
                )
            darks[condition(g)] = g
    shape = None
    rows: list[dict] = []
    written: set = set()
    flats = [g for g in groups if g.kind == "bright"]
    for k, g in enumerate(flats):
        if condition(g) not in darks:
            raise TableError(
                f"{g.where}: bright group at {g.texp_ns:g} ns has no dark group of "
                f"{'a stack' if g.is_stack else 'a pair'} at its exposure; every bright measurement "
                "needs the dark one taken at its exposure (EMVA 1288 release 4.0, section 6.1)"
            )
        frames = g.stack(bits, shape)
        shape = frames.shape[1:]
        if progress is not None:
            progress(k + 1, len(flats))
        if frames.mean() > max_level * full:
            continue
        cond = condition(g)
        todo = [("flat", g, frames)]
        if cond not in written:  # an illumination sweep's bright groups share their exposure's dark group
            written.add(cond)
            todo.append(("dark", darks[cond], darks[cond].stack(bits, shape)))
        for kind, grp, data in todo:
            name = f"{kind}_{len(rows):03d}.npy"
            np.save(out / name, data.astype(dtype, copy=False))
            rows.append({"file": name, "kind": kind, "exposure_s": grp.texp_ns * 1e-9, "condition": cond, "bits": bits})
    if not rows:
        raise TableError(f"{source}: every bright group is above {max_level:.0%} of full scale; nothing to map")
    pd.DataFrame(rows).to_csv(out / MANIFEST, index=False)


def block_statistics(block, xp=np):
    """Per-pixel mean and unbiased temporal variance over the frames of one ``(frames, rows, W)`` block.

    Integer frames are summed exactly in integers about the first frame
    (``sum d`` and ``sum d^2`` with ``d = x - x_0``), so a 16-bit signal keeps
    its sub-DN variance and the pass moves 4 bytes per value, not 8; float
    frames use a shifted two-pass sum in float64.  ``xp``: numpy, or
    ``jax.numpy`` in the compiled pass (:mod:`bayescal.maps.kernel`).
    """
    n = block.shape[0]
    if np.issubdtype(block.dtype, np.integer) and block.dtype.itemsize <= 2:
        d = block.astype(np.int32) - block[:1].astype(np.int32)
        s1 = d.sum(axis=0, dtype=np.int64)
        if xp is np:
            s2 = np.einsum("f...,f...->...", d, d, dtype=np.int64)
        else:  # XLA fuses the widening into the reduction
            d = d.astype(np.int64)
            s2 = (d * d).sum(axis=0)
        mean = s1 / n
        return mean + block[0], (s2 - s1 * mean) / (n - 1)
    x = block.astype(np.float64)
    x0 = x[0]
    x = x - x0
    mean = x.mean(axis=0)
    x = x - mean
    var = (x * x).sum(axis=0) / (n - 1)
    return mean + x0, var
