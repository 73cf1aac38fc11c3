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
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from bayescal.errors import TableError

__all__ = ["Steps", "steps_of", "load_steps", "read_descriptor", "reduce_pair", "reduce_stack"]


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
        ``temporal_var_dark``, ``mean_bright``, ``mean_dark``, ``n_images``, ``photons``.
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
    mean image corrected for the residual temporal noise (EMVA 1288 eq. 32:
    ``s2_spatial = var(mean image) - s2_temporal / L``), and the temporal
    variance.
    """
    n, mean, m2 = 0, None, None
    for frame in frames:
        x = np.asarray(frame, dtype=np.float64)
        n += 1
        if mean is None:
            mean, m2 = np.zeros_like(x), np.zeros_like(x)
        delta = x - mean
        mean += delta / n
        m2 += delta * (x - mean)
        if progress is not None:
            progress(n)
    if n < 2:
        raise TableError("a stack needs at least 2 images")
    temporal = float(np.mean(m2 / (n - 1)))
    spatial = float(np.var(mean, ddof=1) - temporal / n)
    return {"mean_dn": float(mean.mean()), "spatial_var": spatial, "temporal_var": temporal, "n_images": n}


def read_descriptor(path: str | os.PathLike, progress: Callable[[int], None] | None = None) -> Steps:
    """Read an EMVA 1288 descriptor and reduce its images (pairs as pairs, longer groups as stacks)."""
    path = Path(path)
    bits, groups = None, []
    for lineno, raw in enumerate(path.read_text(errors="replace").splitlines(), start=1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        tag, *rest = line.split()
        try:
            if tag == "n":
                bits = int(rest[0])
            elif tag == "b":
                groups.append({"kind": "bright", "texp_ns": float(rest[0]), "photons": float(rest[1]), "images": []})
            elif tag == "d":
                groups.append({"kind": "dark", "texp_ns": float(rest[0]), "photons": 0.0, "images": []})
            elif tag == "i":
                if not groups:
                    raise ValueError("an image line before any b/d line")
                groups[-1]["images"].append(path.parent / " ".join(rest).replace("\\", "/"))
        except (IndexError, ValueError) as exc:
            raise TableError(
                f"{path}: line {lineno} '{line}': {exc}; expected 'n bits w h', 'b t p', 'd t' or 'i file'"
            ) from None
    if bits is None:
        raise TableError(f"{path}: no 'n bits width height' line")
    missing = [img for g in groups for img in g["images"] if not img.exists()]
    if missing:
        raise TableError(
            f"{path}: {len(missing)} image(s) listed in the descriptor are missing, e.g. {missing[0]}; "
            "characterize the cropped arrays (crop128.npz) or a reduced steps.csv instead"
        )
    from bayescal.io.files import read_image

    sat = 2**bits - 1
    rows, stacks = [], {}
    for k, g in enumerate(groups):
        if len(g["images"]) == 2:
            rows.append(
                {
                    "kind": g["kind"],
                    "texp_s": g["texp_ns"] * 1e-9,
                    "photons": g["photons"],
                    **reduce_pair(read_image(g["images"][0]), read_image(g["images"][1]), sat),
                }
            )
        elif len(g["images"]) > 2:
            stacks[g["kind"]] = (g, reduce_stack(read_image(p) for p in g["images"]))
        if progress is not None:
            progress(k + 1)
    return steps_of(rows, stacks, bits, str(path))


def load_steps(path: str | os.PathLike) -> Steps:
    """Load a descriptor (``.txt``), the cropped arrays (``.npz``) or a reduced table (``.csv``)."""
    path = Path(path)
    if not path.is_file():
        raise TableError(f"no such EMVA 1288 input: {path}" if not path.exists() else f"{path} is not a file")
    suffix = path.suffix.lower()
    if suffix == ".npz":
        return _from_npz(path)
    if suffix == ".csv":
        return _from_csv(path)
    return read_descriptor(path)


_NPZ_KEYS = ("bits", "bright_texp", "bright_photons", "bright_pairs", "dark_texp", "dark_pairs")


def _from_npz(path: Path) -> Steps:
    try:
        d = np.load(path)
    except (OSError, ValueError, EOFError) as exc:
        raise TableError(f"{path} is not a readable .npz archive ({exc})") from None
    missing = [k for k in _NPZ_KEYS if k not in d]
    if missing:
        raise TableError(
            f"{path}: missing array(s) {missing}; expected the keys of crop128.npz ({', '.join(_NPZ_KEYS)})"
        )
    bits = int(d["bits"])
    sat = 2**bits - 1
    rows = []
    for kind in ("bright", "dark"):
        photons = d["bright_photons"] if kind == "bright" else np.zeros(len(d["dark_texp"]))
        for texp, p, pair in zip(d[f"{kind}_texp"], photons, d[f"{kind}_pairs"], strict=True):
            rows.append(
                {"kind": kind, "texp_s": float(texp) * 1e-9, "photons": float(p), **reduce_pair(pair[0], pair[1], sat)}
            )
    stacks = {}
    for kind in ("bright", "dark"):
        if f"{kind}_stack" in d:
            g = {"texp_ns": float(d[f"{kind}_stack_texp"]), "photons": float(d[f"{kind}_stack_photons"])}
            stacks[kind] = (g, reduce_stack(iter(d[f"{kind}_stack"])))
    return steps_of(rows, stacks, bits, str(path))


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
            "n_pixels": np.nan,
            "n_saturated": getattr(r, "n_sat_pixels", 0),
        }
        for r in pairs.itertuples()
    ]
    stacks = {}
    if "n_images" in df:
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
    bright = df[df.kind == "bright"].drop(columns="kind").sort_values("texp_s").reset_index(drop=True)
    dark = df[df.kind == "dark"].drop(columns="kind").sort_values("texp_s").reset_index(drop=True)
    stack = {}
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
    return Steps(bright, dark, bits, source, stack)
