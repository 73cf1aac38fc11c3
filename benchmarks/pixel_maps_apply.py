"""Correct and invert a 24-megapixel frame with per-pixel maps; compare with a plain LUT gather.

Run: ``python benchmarks/pixel_maps_apply.py [--megapixels 24] [--repeats 5]``.

One run, one machine, two timings:

* ``maps``: :func:`bayescal.apply_maps` with a channel calibration -- per pixel,
  dark subtraction, flat-fielding, the map's and the reading's random
  variance, the calibration's inverse (median and systematic bounds from a
  2048-point table, linear interpolation) and the 95 % bounds;
* ``gather``: ``np.take`` of three lookup-table outputs (median, lower,
  upper) at the frame's uint16 values -- the least work any per-pixel
  inversion with bounds can do.

The maps are synthetic (1 % PRNU, 2 DN DSNU, 0.1 % defects): only the
arithmetic is timed.  Memory: the peak RSS above the inputs, for two frame
sizes (flat in image size means the same overhead for both).
Writes ``benchmarks/results/pixel_maps_apply.md``.
"""

from __future__ import annotations

import argparse
import json
import resource
import time
from pathlib import Path

import numpy as np

import bayescal as bc
from bayescal.maps.apply import MapSet, apply_maps
from bayescal.model.spec import Reference

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"


def synthetic_maps(h: int, w: int, seed: int = 0) -> MapSet:
    rng = np.random.default_rng(seed)
    f = np.float32
    shape = (h, w)
    defect = (rng.random(shape) < 1e-3).astype(np.int8)
    return MapSet(
        relative_gain=(1 + 0.01 * rng.standard_normal(shape)).astype(f),
        offset=(100 + 2 * rng.standard_normal(shape)).astype(f),
        dark=(8 + 2 * rng.standard_normal(shape)).astype(f),
        var_gain=np.full(shape, 1e-5, f),
        var_offset=np.full(shape, 0.5, f),
        var_dark=np.full(shape, 4.0, f),
        cov_offset_dark=np.full(shape, -0.5, f),
        defect=defect,
        dark_var=(10.0, 5.0),
        shot_k=0.28,
        systematic_rel=1e-4,
        mean_offset=100.0,
        mean_dark=8.0,
        source="synthetic",
    )


def best_of(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return min(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--megapixels", type=float, default=24.0)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    h = int(np.sqrt(args.megapixels * 1e6 * 2 / 3))
    w = int(args.megapixels * 1e6 / h)
    npix = h * w
    maps = synthetic_maps(h, w)
    rng = np.random.default_rng(1)
    frame = rng.integers(200, 3800, size=(h, w), dtype=np.uint16)
    cal = bc.Calibration.from_coefficients({"M": [140.0, 1890.0]}, reference=Reference(0.15), bits=12)
    lut = rng.random((3, 4096)).astype(np.float32)

    def gather():
        return [np.take(lut[i], frame) for i in range(3)]

    apply_maps(synthetic_maps(256, 256), frame[:256, :256], 0.15, calibration=cal)  # compile the kernel once
    t_gather = best_of(gather, args.repeats)
    t_maps = best_of(lambda: apply_maps(maps, frame, 0.15, calibration=cal), args.repeats)
    fresh = iter(0.15 + 1e-4 * np.arange(1, args.repeats + 1))  # a new exposure each time: dark and map
    t_first = best_of(lambda: apply_maps(maps, frame, next(fresh), calibration=cal), args.repeats)  # variance anew
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    rows = {
        "megapixels": npix / 1e6,
        "gather_s": t_gather,
        "gather_mpix_s": npix / 1e6 / t_gather,
        "maps_s": t_maps,
        "maps_mpix_s": npix / 1e6 / t_maps,
        "ratio_maps_to_gather": t_maps / t_gather,
        "maps_new_exposure_s": t_first,
        "maps_new_exposure_mpix_s": npix / 1e6 / t_first,
        "peak_rss_mb": rss,
    }
    print(json.dumps(rows, indent=1))
    RESULTS.mkdir(parents=True, exist_ok=True)
    lines = [
        "# Correcting and inverting a frame with per-pixel maps",
        "",
        "`python benchmarks/pixel_maps_apply.py` (best of "
        f"{args.repeats}; {npix / 1e6:.1f} Mpix uint16 frame; 2-core machine)",
        "",
        "| method | seconds | Mpix/s |",
        "|---|---|---|",
        f"| plain gather of 3 LUT outputs | {t_gather:.3f} | {rows['gather_mpix_s']:.0f} |",
        f"| `apply_maps` (correct, invert, 95 % bounds, defects) | {t_maps:.3f} | {rows['maps_mpix_s']:.0f} |",
        f"| `apply_maps`, first frame at a new exposure (dark and map variance at t computed) | {t_first:.3f} | "
        f"{rows['maps_new_exposure_mpix_s']:.0f} |",
        "",
        f"Ratio maps / gather: {rows['ratio_maps_to_gather']:.2f}. Peak RSS of the process: {rss:.0f} MB "
        "(maps and frame themselves: "
        f"{(maps.relative_gain.nbytes * 7 + maps.defect.nbytes + frame.nbytes) / 1e6:.0f} MB; outputs 5 x float32).",
    ]
    (RESULTS / "pixel_maps_apply.md").write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
