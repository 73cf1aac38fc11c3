"""Per-pixel maps against known truth: a 2048 x 2048 sensor at 2, 4 and 8 frames per level.

Run: ``python benchmarks/pixel_maps_truth.py [--size 2048] [--frames 2,4,8]``.

The sensor comes from :mod:`bayescal.validation.sensor` (written apart from
the model: Poisson electrons, Normal read noise, log-normal dark current,
integer rounding): PRNU 1 %, DSNU 2 DN, 0.1 % defects (hot, dead, noisy in
equal parts), four illumination levels (one dark-only) at four exposures.

For each frame count, beside per-pixel weighted least squares:

* RMSE of the relative gain, offset and dark current over the normal pixels;
* coverage of the 95 % per-pixel intervals (posterior mean +- 1.96 sd);
* defect detection: ROC area and the true-positive rate at the false-positive
  rates 1e-4 and 1e-3, for the posterior defect probability and for the
  EMVA-style threshold rule (a pixel's deviation from the median of the
  longest dark mean image and of the brightest flat-minus-dark mean image, in
  robust standard deviations; EMVA 1288 release 4.0 section 8.8 flags
  pixels by such thresholds on mean images).

Writes ``benchmarks/results/pixel_maps_truth.{csv,md}``.
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

from bayescal.maps.build import build_maps
from bayescal.validation.sensor import PixelSensor, write_stacks

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
PHOTONS = [0.0, 3000.0, 10000.0, 30000.0]
EXPOSURES = [0.05, 0.1, 0.2, 0.4]


def roc(score: np.ndarray, positive: np.ndarray) -> dict:
    """ROC area (Mann-Whitney) and TPR at FPR 1e-4, 1e-3."""
    from scipy.stats import rankdata

    ranks = rankdata(score)
    n1, n0 = positive.sum(), (~positive).sum()
    auc = (ranks[positive].sum() - n1 * (n1 + 1) / 2) / (n1 * n0)
    neg = np.sort(score[~positive])[::-1]
    out = {"auc": auc}
    for fpr in (1e-4, 1e-3):
        k = int(np.floor(fpr * n0))
        threshold = neg[k] if k < neg.size else -np.inf
        out[f"tpr_at_fpr_{fpr:g}"] = float(np.mean(score[positive] > threshold))
    return out


def emva_rule(root: Path, table: pd.DataFrame) -> np.ndarray:
    """Deviation (robust sd units) of each pixel in the longest dark and brightest flat-minus-dark images."""
    dark = table[table.kind == "dark"].sort_values("exposure_s").iloc[-1]
    flat = table[table.kind == "flat"].sort_values("photons").iloc[-1]
    flat_dark = table[(table.kind == "dark") & (table.condition == flat.condition)].iloc[0]
    d = np.load(root / dark.file, mmap_mode="r").mean(axis=0)
    f = np.load(root / flat.file, mmap_mode="r").mean(axis=0) - np.load(root / flat_dark.file, mmap_mode="r").mean(
        axis=0
    )

    def z(img):
        med = np.median(img)
        return np.abs(img - med) / (1.4826 * np.median(np.abs(img - med)))

    return np.maximum(z(d), z(f))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=2048)
    parser.add_argument("--frames", default="2,4,8")
    parser.add_argument("--seed", type=int, default=7)
    args = parser.parse_args()
    sensor = PixelSensor(height=args.size, width=args.size, prnu=0.01, dsnu_dn=2.0, defect_fraction=0.001)
    rows = []
    for frames in (int(f) for f in args.frames.split(",")):
        work = Path(tempfile.mkdtemp(prefix="pixel_maps_truth."))
        try:
            t0 = time.perf_counter()
            truth = write_stacks(sensor, work, photons=PHOTONS, exposure_s=EXPOSURES, frames=frames, seed=args.seed)
            t_sim = time.perf_counter() - t0
            t0 = time.perf_counter()
            ds = build_maps(work).compute()
            t_fit = time.perf_counter() - t0
            normal = truth.defect == 0
            row = {"frames": frames, "pixels": truth.defect.size, "simulate_s": t_sim, "maps_s": t_fit}
            for name in ("relative_gain", "offset_dn", "dark_current_dn_s"):
                true = getattr(truth, name)
                est, sd, lsq = (ds[k].to_numpy() for k in (name, f"u_random_{name}", f"lsq_{name}"))
                row[f"{name}_rmse"] = float(np.sqrt(np.mean((est - true)[normal] ** 2)))
                row[f"{name}_rmse_lsq"] = float(np.sqrt(np.mean((lsq - true)[normal] ** 2)))
                row[f"{name}_coverage"] = float(np.mean((np.abs(est - true) <= 1.96 * sd)[normal]))
                row[f"{name}_spread"] = ds.attrs[f"spread_{name}"]
                row[f"{name}_spread_true"] = float(true[normal].std())
            positive = truth.defect > 0
            ours = roc(ds["defect_probability"].to_numpy().ravel(), positive.ravel())
            table = pd.read_csv(work / "conditions.csv")
            rule = roc(emva_rule(work, table).ravel(), positive.ravel())
            row.update({f"bayescal_{k}": v for k, v in ours.items()})
            row.update({f"emva_rule_{k}": v for k, v in rule.items()})
            flagged = ds["defect"].to_numpy() > 0
            row["flagged_true_positive"] = float(np.mean(flagged[positive]))
            row["flagged_false_positive"] = int(np.sum(flagged[~positive]))
            for code, kind in ((1, "hot"), (2, "dead"), (3, "noisy")):
                row[f"found_{kind}"] = float(np.mean(flagged[truth.defect == code]))
            rows.append(row)
            print(row, flush=True)
        finally:
            shutil.rmtree(work, ignore_errors=True)
    df = pd.DataFrame(rows)
    RESULTS.mkdir(parents=True, exist_ok=True)
    df.to_csv(RESULTS / "pixel_maps_truth.csv", index=False)
    lines = [
        f"# Per-pixel maps against known truth ({args.size} x {args.size} sensor)",
        "",
        f"`python benchmarks/pixel_maps_truth.py --size {args.size} --frames {args.frames}`: PRNU 1 %, DSNU 2 DN, "
        "0.1 % defects (hot, dead, noisy), 4 levels x 4 exposures, seed "
        f"{args.seed}. RMSE and coverage over the normal pixels; least squares is the per-pixel weighted fit.",
        "",
        "| frames/level | gain RMSE (bayescal / LSQ) | offset RMSE DN | dark current RMSE DN/s "
        "| 95 % coverage gain / offset / dark | defect ROC area (bayescal / EMVA rule) "
        "| TPR at FPR 1e-4 (bayescal / rule) | flagged: found, false | seconds |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['frames']} | {r['relative_gain_rmse']:.5f} / {r['relative_gain_rmse_lsq']:.5f} "
            f"| {r['offset_dn_rmse']:.3f} / {r['offset_dn_rmse_lsq']:.3f} "
            f"| {r['dark_current_dn_s_rmse']:.2f} / {r['dark_current_dn_s_rmse_lsq']:.2f} "
            f"| {r['relative_gain_coverage']:.4f} / {r['offset_dn_coverage']:.4f} "
            f"/ {r['dark_current_dn_s_coverage']:.4f} "
            f"| {r['bayescal_auc']:.4f} / {r['emva_rule_auc']:.4f} "
            f"| {r['bayescal_tpr_at_fpr_0.0001']:.3f} / {r['emva_rule_tpr_at_fpr_0.0001']:.3f} "
            f"| {r['flagged_true_positive']:.3f}, {r['flagged_false_positive']} "
            f"| {r['maps_s']:.0f} |"
        )
    lines += [
        "",
        "Found by kind (flagged): "
        + "; ".join(
            f"{r['frames']} frames: hot {r['found_hot']:.2f}, dead {r['found_dead']:.2f}, noisy {r['found_noisy']:.2f}"
            for r in rows
        ),
    ]
    (RESULTS / "pixel_maps_truth.md").write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
