"""EMVA 1288 input: descriptor files, image pairs and stacks, reduced to per-step statistics.

An EMVA 1288 measurement (release 3.0) sweeps the exposure at a fixed
irradiance; each step has a bright image pair (``b exposure_ns
photons_per_pixel``) and a dark pair (``d exposure_ns``), plus image stacks
for the spatial non-uniformity.  A pair ``A, B`` of ``N`` pixels gives the
mean ``mu = (mean A + mean B) / 2`` and the temporal variance
``s2 = mean((A - B)^2) / 2 - (mean A - mean B)^2 / 2`` (EMVA 1288 eq. 9-10).
Pairs are reduced one at a time, so memory stays bounded by two images.

Inputs: a descriptor (``n``, ``b``, ``d``, ``i`` lines) with its images, the
``crop128.npz`` arrays, or an already reduced ``steps.csv``.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import pandas as pd

from bayescal.errors import TableError
from bayescal.io.resources import did_you_mean

__all__ = [
    "Steps",
    "ImageGroup",
    "steps_of",
    "load_steps",
    "read_groups",
    "read_descriptor",
    "reduce_pair",
    "reduce_stack",
]


@dataclass(frozen=True)
class Steps:
    """Per-step statistics of an EMVA 1288 exposure sweep.

    Attributes
    ----------
    bright, dark : pandas.DataFrame
        One row per exposure step (ascending): ``texp_s``, ``photons`` (per
        pixel; 0 for dark), ``mean_dn``, ``var_dn2`` (temporal), ``n_pixels``,
        ``n_saturated``.
    bits : int
    stack : dict
        Spatial variances of the averaged bright/dark stacks when present:
        ``spatial_var_bright``, ``spatial_var_dark``, ``temporal_var_bright``,
        ``temporal_var_dark``, ``mean_bright``, ``mean_dark``, ``n_images``, ``photons``, and where the
        stacks were read as images, their mean images ``image_bright`` and ``image_dark`` (DN, 2-D).

    Examples
    --------
    >>> import bayescal as bc
    >>> steps = bc.load_steps("emva")
    >>> steps.bits, len(steps.bright), len(steps.dark)
    (12, 50, 50)
    """

    bright: pd.DataFrame
    dark: pd.DataFrame
    bits: int
    source: str = ""
    stack: dict = field(default_factory=dict)


def reduce_pair(a: np.ndarray, b: np.ndarray, saturation: float) -> dict:
    """Mean, temporal variance (EMVA 1288 eq. 9-10), pixel count and saturated count of one image pair."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    if a.shape != b.shape:
        raise TableError(f"image pair shapes differ: {a.shape} vs {b.shape}")
    ma, mb = a.mean(), b.mean()
    var = np.mean((a - b) ** 2) / 2.0 - (ma - mb) ** 2 / 2.0
    return {
        "mean_dn": 0.5 * (ma + mb),
        "var_dn2": var,
        "n_pixels": a.size,
        "n_saturated": int(np.count_nonzero((a >= saturation) | (b >= saturation))),
    }


def reduce_stack(frames, progress: Callable[[int], None] | None = None) -> dict:
    """Streaming mean image and temporal variance of a stack (Welford), then spatial statistics.

    ``frames`` is any iterable of 2-D arrays (read lazily from disk, or an
    array).  Returns the mean of the mean image, the spatial variance of the
    mean image as it is (``spatial_var``, as a reduced table's
    ``spatial_var_of_mean_image_DN2``: the characterisation corrects it once
    for the residual temporal noise, EMVA 1288 eq. 32, ``var(mean image) -
    s2_temporal / L``), the temporal variance, and the mean image itself
    (``mean_image``: the non-uniformity's histograms and spectrograms, EMVA
    1288 release 4.0 section 8).
    """
    n, mean, m2 = 0, np.zeros(0), np.zeros(0)
    for frame in frames:
        x = np.asarray(frame, dtype=np.float64)
        n += 1
        if n == 1:
            mean, m2 = np.zeros_like(x), np.zeros_like(x)
        delta = x - mean
        mean += delta / n
        m2 += delta * (x - mean)
        if progress is not None:
            progress(n)
    if n < 2:
        raise TableError("a stack needs at least 2 images")
    temporal = float(np.mean(m2 / (n - 1)))
    spatial = float(np.var(mean, ddof=1))
    return {
        "mean_dn": float(mean.mean()),
        "spatial_var": spatial,
        "temporal_var": temporal,
        "n_images": n,
        "mean_image": mean,
    }


@dataclass(frozen=True)
class ImageGroup:
    """One bright or dark group of an EMVA 1288 set: a pair of images, or a longer stack.

    Attributes
    ----------
    kind : {"bright", "dark"}
    texp_ns : float
        Exposure time in nanoseconds.
    photons : float
        Mean photons per pixel (0 for dark).
    images : tuple
        The image files (resolved against the descriptor's folder), or 2-D
        arrays already in memory (the cropped arrays).
    where : str
        Where the group is written (descriptor line or array key), for messages.
    """

    kind: str
    texp_ns: float
    photons: float
    images: tuple
    where: str

    @property
    def is_stack(self) -> bool:
        """More than a pair: a stack for the spatial non-uniformity (EMVA 1288 section 8)."""
        return len(self.images) > 2

    def frames(self, bits: int | None = None, shape: tuple[int, ...] | None = None) -> Iterator[np.ndarray]:
        """The images one at a time (files read lazily); with ``bits``, each checked to be a 2-D image of
        ``shape`` (or of the group's first image's) with values within ``0 .. 2**bits - 1``.

        Raises
        ------
        TableError
            Naming the group and the image: another dimensionality or shape, or values outside the ADC's range.
        """
        from bayescal.io.files import read_image

        for k, image in enumerate(self.images):
            frame = read_image(image) if isinstance(image, Path) else np.asarray(image)
            if bits is not None:
                name = str(image) if isinstance(image, Path) else f"image {k}"
                _check_frame(frame, bits, shape, f"{self.where}: {name}")
                shape = frame.shape
            yield frame

    def stack(self, bits: int, shape: tuple[int, int] | None = None) -> np.ndarray:
        """All images as one ``(frames, H, W)`` array, checked as :meth:`frames` checks them."""
        return np.stack(list(self.frames(bits, shape)))


def _check_frame(frame: np.ndarray, bits: int, shape: tuple[int, ...] | None, where: str) -> None:
    if frame.ndim != 2:
        kind = "a cube of planes" if frame.ndim == 3 else f"{frame.ndim}-D"
        raise TableError(
            f"{where} has shape {frame.shape} ({kind}); expected a 2-D monochrome image, one frame per file"
        )
    if shape is not None and frame.shape != shape:
        raise TableError(
            f"{where} has shape {frame.shape[0]} x {frame.shape[1]}; expected {shape[0]} x {shape[1]} like the "
            "set's first image (every image of an EMVA 1288 set has one size)"
        )
    full = 2**bits - 1
    if frame.size and (frame.min() < 0 or frame.max() > full):
        raise TableError(f"{where} holds values outside 0..{full} of a {bits}-bit ADC")


def read_groups(path: str | os.PathLike) -> tuple[int, list[ImageGroup]]:
    """The ADC's bit depth and every image group of an EMVA 1288 set, in the set's order.

    ``path`` is a descriptor (``n``, ``b``, ``d`` and ``i`` lines, images
    beside it; every listed image is checked to exist) or the cropped arrays
    (``crop128.npz``: pairs and stacks as arrays).

    Raises
    ------
    TableError
        Naming the line of a malformed tag, the missing images or array keys.
    """
    path = Path(path)
    if not path.is_file():
        raise TableError(
            f"no such EMVA 1288 input: {path}{did_you_mean(path)}" if not path.exists() else f"{path} is not a file"
        )
    if path.suffix.lower() == ".npz":
        return _npz_groups(path)
    bits, groups = None, []
    for lineno, raw in enumerate(path.read_text(errors="replace").splitlines(), start=1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        tag, *rest = line.split()
        try:
            if tag == "n":
                bits = int(rest[0])
                if not 1 <= bits <= 24:
                    raise ValueError(f"{bits} bits; expected 1-24")
            elif tag in ("b", "d"):
                texp = _non_negative(rest[0], "exposure (ns)")
                photons = _non_negative(rest[1], "photons per pixel") if tag == "b" else 0.0
                kind = "bright" if tag == "b" else "dark"
                groups.append(ImageGroup(kind, texp, photons, (), f"{path} line {lineno}"))
            elif tag == "i":
                if not groups:
                    raise ValueError("an image line before any b/d line")
                if not rest:
                    raise ValueError("no file name")
                image = path.parent / " ".join(rest).replace("\\", "/")
                groups[-1] = replace(groups[-1], images=(*groups[-1].images, image))
            elif tag != "v":  # 'v': the descriptor format's version
                raise ValueError(f"unknown tag '{tag}'")
        except (IndexError, ValueError) as exc:
            raise TableError(
                f"{path}: line {lineno} '{line}': {exc}; expected 'v version', 'n bits w h', 'b t p', 'd t' or 'i file'"
            ) from None
    if bits is None:
        raise TableError(f"{path}: no 'n bits width height' line")
    for g in groups:
        if len(g.images) < 2:
            raise TableError(
                f"{g.where}: the {g.kind} group has {len(g.images)} image(s); EMVA 1288 measures each step "
                "with a pair of images (2) or a stack (more than 2)"
            )
    missing = [img for g in groups for img in g.images if not img.exists()]
    if missing:
        raise TableError(
            f"{path}: {len(missing)} image(s) listed in the descriptor are missing, e.g. {missing[0]} "
            "(image paths are relative to the descriptor's folder)"
        )
    return bits, groups


def _non_negative(text: str, what: str) -> float:
    value = float(text)
    if not np.isfinite(value) or value < 0:
        raise ValueError(f"{what} {text}; expected a finite number >= 0")
    return value


_NPZ_KEYS = ("bits", "bright_texp", "bright_photons", "bright_pairs", "dark_texp", "dark_pairs")


def _npz_groups(path: Path) -> tuple[int, list[ImageGroup]]:
    """The groups of the cropped arrays (``crop128.npz`` keys): each bright pair, its dark pair, the stacks."""
    try:
        z = np.load(path)
    except (OSError, ValueError, EOFError) as exc:
        raise TableError(f"{path} is not a readable .npz archive ({exc})") from None
    missing = [k for k in _NPZ_KEYS if k not in z.files]
    if missing:
        raise TableError(
            f"{path}: missing array(s) {missing}; expected the keys of crop128.npz ({', '.join(_NPZ_KEYS)})"
        )
    for kind, n in (("bright", len(np.atleast_1d(z["bright_texp"]))), ("dark", len(np.atleast_1d(z["dark_texp"])))):
        pairs = z[f"{kind}_pairs"]
        if pairs.ndim != 4 or pairs.shape[0] != n or pairs.shape[1] != 2:
            raise TableError(
                f"{path}: {kind}_pairs has shape {pairs.shape}; expected ({n}, 2, height, width): one image pair "
                f"per entry of {kind}_texp ({n})"
            )
    if len(np.atleast_1d(z["bright_photons"])) != len(np.atleast_1d(z["bright_texp"])):
        raise TableError(f"{path}: bright_photons and bright_texp differ in length; expected one value per bright pair")
    groups = []
    for kind in ("bright", "dark"):  # one dark pair may serve every bright pair (an illumination sweep)
        texp = np.atleast_1d(z[f"{kind}_texp"])
        photons = np.atleast_1d(z["bright_photons"]) if kind == "bright" else np.zeros(len(texp))
        for i in range(len(texp)):
            pair = tuple(z[f"{kind}_pairs"][i])
            groups.append(ImageGroup(kind, float(texp[i]), float(photons[i]), pair, f"{path} {kind}_pairs[{i}]"))
    if "bright_stack" in z.files:
        texp, photons = float(z["bright_stack_texp"]), float(z["bright_stack_photons"])
        groups.append(ImageGroup("bright", texp, photons, tuple(z["bright_stack"]), f"{path} bright_stack"))
        if "dark_stack" in z.files:
            texp = float(z["dark_stack_texp"]) if "dark_stack_texp" in z.files else texp
            groups.append(ImageGroup("dark", texp, 0.0, tuple(z["dark_stack"]), f"{path} dark_stack"))
    return int(z["bits"]), groups


def read_descriptor(path: str | os.PathLike, progress: Callable[[int], None] | None = None) -> Steps:
    """Read an EMVA 1288 set (descriptor or cropped arrays) and reduce it: pairs as pairs, longer groups as stacks."""
    bits, groups = read_groups(path)
    sat = 2**bits - 1
    rows, stacks = [], {}
    shape = None  # every image of the set has the first one's size
    for k, g in enumerate(groups):
        if g.is_stack:
            stacks[g.kind] = ({"texp_ns": g.texp_ns, "photons": g.photons}, reduce_stack(g.frames(bits, shape)))
        elif len(g.images) == 2:
            a, b = g.frames(bits, shape)
            shape = a.shape
            rows.append({"kind": g.kind, "texp_s": g.texp_ns * 1e-9, "photons": g.photons, **reduce_pair(a, b, sat)})
        if progress is not None:
            progress(k + 1)
    return steps_of(rows, stacks, bits, str(path))


def load_steps(path: str | os.PathLike) -> Steps:
    """Load a descriptor (``.txt``, or the folder that holds ``EMVA1288_Data.txt``), the cropped arrays
    (``.npz``) or a reduced table (``.csv``); or a shipped set by name (``"emva"``, ``"ccd_fits"``).

    Examples
    --------
    >>> import bayescal as bc
    >>> steps = bc.load_steps("emva")  # the real CCD's reduced table (EMVA 1288 reference set 001)
    >>> len(steps.bright), steps.bits
    (50, 12)
    """
    from bayescal.io.resources import DESCRIPTOR, example_path

    path = example_path(path, "data")
    if path.is_dir() and (path / DESCRIPTOR).is_file():
        path = path / DESCRIPTOR
    if not path.is_file():
        raise TableError(
            f"no such EMVA 1288 input: {path}{did_you_mean(path)}" if not path.exists() else f"{path} is not a file"
        )
    if path.suffix.lower() == ".csv":
        return _from_csv(path)
    return read_descriptor(path)


_CSV_NUMERIC = ("texp_ns", "photons_per_pixel", "mean_DN", "var_temporal_DN2")


def _from_csv(path: Path) -> Steps:
    import io

    from bayescal.io.files import read_text

    try:
        df = pd.read_csv(io.StringIO(read_text(path, TableError, "EMVA 1288 steps table (CSV)")), comment="#")
    except (pd.errors.EmptyDataError, pd.errors.ParserError) as exc:
        raise TableError(f"{path} is empty or not a CSV table ({exc}); expected a reduced steps.csv") from None
    need = {"kind", *_CSV_NUMERIC}
    missing = need - set(df.columns)
    if missing:
        raise TableError(
            f"{path}: missing column(s) {sorted(missing)}; expected a reduced EMVA 1288 steps table with "
            f"columns kind, texp_ns, photons_per_pixel, n_images, mean_DN, var_temporal_DN2",
            column=sorted(missing)[0],
        )
    if len(df) == 0:
        raise TableError(f"{path} has no data rows")
    for i, kind in enumerate(df["kind"]):
        if kind not in ("bright", "dark"):
            raise TableError(f"{path}: kind '{kind}'; expected 'bright' or 'dark'", row=i + 1, column="kind")
    for col in _CSV_NUMERIC + (("n_images",) if "n_images" in df else ()):
        values = pd.to_numeric(df[col], errors="coerce")
        bad = np.flatnonzero(~np.isfinite(values.to_numpy(dtype=float)))
        if bad.size:
            raise TableError(f"{path}: '{df[col].iloc[bad[0]]}' is not a finite number", row=bad[0] + 1, column=col)
        if col != "photons_per_pixel" and np.any(values < 0):
            row = int(np.flatnonzero(values < 0)[0]) + 1
            raise TableError(f"{path}: negative value; expected >= 0", row=row, column=col)
        df[col] = values
    pairs = df[df["n_images"] == 2] if "n_images" in df else df
    rows = [
        {
            "kind": r.kind,
            "texp_s": r.texp_ns * 1e-9,
            "photons": r.photons_per_pixel,
            "mean_dn": r.mean_DN,
            "var_dn2": r.var_temporal_DN2,
            "n_pixels": getattr(r, "n_pixels", np.nan),
            "n_saturated": getattr(r, "n_sat_pixels", 0),
        }
        for r in pairs.itertuples()
    ]
    stacks = {}
    if "n_images" in df and (df["n_images"] > 2).any():
        column = "spatial_var_of_mean_image_DN2"
        if column not in df:
            row = int(np.flatnonzero(df["n_images"].to_numpy() > 2)[0]) + 1
            raise TableError(
                f"{path}: a stack row (n_images > 2) needs the spatial variance of its mean image",
                row=row,
                column=column,
            )
        spatial = pd.to_numeric(df[column], errors="coerce")
        bad = np.flatnonzero((df["n_images"].to_numpy() > 2) & ~np.isfinite(spatial.to_numpy(dtype=float)))
        if bad.size:
            raise TableError(
                f"{path}: '{df[column].iloc[bad[0]]}' is not a finite number", row=bad[0] + 1, column=column
            )
        df[column] = spatial
    if "n_images" in df:
        bad = np.flatnonzero(df["n_images"].to_numpy() < 2)
        if bad.size:
            raise TableError(
                f"{path}: n_images = {df['n_images'].iloc[bad[0]]:g}; a step is a pair (2) or a stack (more)",
                row=bad[0] + 1,
                column="n_images",
            )
        for r in df[df["n_images"] > 2].itertuples():
            g = {"texp_ns": r.texp_ns, "photons": r.photons_per_pixel}
            stacks[r.kind] = (
                g,
                {
                    "mean_dn": r.mean_DN,
                    "spatial_var": r.spatial_var_of_mean_image_DN2,
                    "temporal_var": r.var_temporal_DN2,
                    "n_images": int(r.n_images),
                },
            )
    bits = _bits(df, path)
    return steps_of(rows, stacks, bits, str(path))


def _bits(df: pd.DataFrame, path: Path) -> int:
    """The ADC bit depth: a ``bits`` column, or the smallest common depth whose full scale holds every mean.

    (Guessing 12 for anything below 4096 DN made an 8-bit camera's saturation meaningless.)
    """
    if "bits" in df:
        values = pd.to_numeric(df["bits"], errors="coerce").dropna().unique()
        if values.size != 1 or not 1 <= values[0] <= 24:
            raise TableError(f"{path}: the 'bits' column must hold one bit depth (1-24)", column="bits")
        return int(values[0])
    top = float(df["mean_DN"].max())
    for bits in (8, 10, 12, 14, 16):
        if top <= 2**bits - 1:
            return bits
    raise TableError(f"{path}: mean_DN up to {top:g} exceeds a 16-bit range; give a 'bits' column", column="mean_DN")


def steps_of(rows: list[dict], stacks: dict, bits: int, source: str) -> Steps:
    """:class:`Steps` from per-step rows (``kind``, ``texp_s``, ``photons``, ``mean_dn``, ``var_dn2``, ...) and
    optional image stacks; both a bright and a dark step are needed."""
    df = pd.DataFrame(rows)
    for kind in ("bright", "dark"):
        if not (df["kind"] == kind).any():
            raise TableError(f"{source}: no {kind} image pairs; EMVA 1288 needs both bright and dark steps")
    unlit = np.flatnonzero((df["kind"] == "bright").to_numpy() & ~(df["photons"].to_numpy(dtype=float) > 0))
    if unlit.size:
        r = df.iloc[unlit[0]]
        raise TableError(
            f"{source}: the bright step at {r.texp_s * 1e9:g} ns has {r.photons:g} photons per pixel "
            f"({unlit.size} bright step(s) so); expected the photons each bright step received (> 0): a step "
            "without light is a dark step",
            row=int(unlit[0]) + 1,
            column="photons_per_pixel",
        )
    bright = df[df.kind == "bright"].drop(columns="kind").sort_values("texp_s").reset_index(drop=True)
    dark = df[df.kind == "dark"].drop(columns="kind").sort_values("texp_s").reset_index(drop=True)
    stack: dict = {}
    if "bright" in stacks and "dark" in stacks:
        gb, sb = stacks["bright"]
        _, sd = stacks["dark"]
        stack = {
            "mean_bright": sb["mean_dn"],
            "mean_dark": sd["mean_dn"],
            "spatial_var_bright": sb["spatial_var"],
            "spatial_var_dark": sd["spatial_var"],
            "temporal_var_bright": sb["temporal_var"],
            "temporal_var_dark": sd["temporal_var"],
            "n_images": sb["n_images"],
            "photons": gb["photons"],
        }
        if "mean_image" in sb and "mean_image" in sd:  # reduced from images (a table of statistics has none)
            stack |= {"image_bright": sb["mean_image"], "image_dark": sd["mean_image"]}
    return Steps(bright, dark, bits, source, stack)
