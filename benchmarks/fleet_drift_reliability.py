"""Are a fleet's drift probabilities calibrated?  A reliability table on independently simulated fleets.

Run: ``python benchmarks/fleet_drift_reliability.py [--fleets 6] [--cameras 12]``.

Each fleet (:func:`bayescal.validation.fleet.simulate_fleet`, written apart from the
fleet model) has four campaigns a year apart and gains that walk ``--walk`` (1 %) per
campaign on top of the simulator's settling ageing and campaign jitter.  The fleet is
fitted on its first three campaigns (``fit_fleet``, Laplace per unit, then the
hierarchy) and, for every camera, ``FleetFit.drift_probability(camera, fourth campaign,
p)`` is compared with what happened: whether the camera's true green gain moved by more
than ``p`` % between the third and the fourth campaign.  A calibrated forecast's events
happen as often as it says: the table bins the predicted probabilities and gives the
observed frequency in each bin (with its binomial standard error), and per threshold
the mean predicted probability against the observed rate.

Writes ``benchmarks/results/fleet_drift_reliability.{csv,md}``.
"""

from __future__ import annotations

import argparse
import time
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd

from bayescal import load_spec
from bayescal.fleet import fit_fleet
from bayescal.fleet.units import fleet_from_frame
from bayescal.validation.fleet import FleetDesign, simulate_fleet

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "benchmarks" / "results"
CAMPAIGNS = ("2024-03-01", "2025-03-01", "2026-03-01", "2027-03-01")
THRESHOLDS = (0.5, 1.0, 2.0, 3.0)
BINS = (0.0, 0.1, 0.3, 0.5, 0.7, 0.9, 1.0001)


def one_fleet(seed: int, cameras: int, walk: float, spec, ageing: bool = True) -> list[dict]:
    design = FleetDesign(n_cameras=cameras, campaigns=CAMPAIGNS, walk_rel=walk, n_pixels=64, n_frames=10)
    if not ageing:  # the gains walk and jitter only: no settling trend for a straight one to extrapolate
        design = replace(design, loss_range=(0.0, 0.0))
    table, truth = simulate_fleet(design, seed=seed)
    fitted = table[table.campaign != CAMPAIGNS[-1]]
    fleet = fleet_from_frame(fitted.astype(str), source=f"fleet {seed}")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = fit_fleet(fleet, spec, "laplace", seed=seed)
    g = truth[truth.channel == "G"].pivot(index="camera", columns="campaign", values="gain")
    changes = np.log(g[CAMPAIGNS[-1]] / g[CAMPAIGNS[-2]])
    rows = []
    for camera in result.cameras:
        change = np.expm1(changes[camera])
        against = np.expm1(changes[camera] - changes.mean())  # against the fleet's common change
        for p in THRESHOLDS:
            rows.append(
                {
                    "fleet": seed,
                    "camera": camera,
                    "threshold_pct": p,
                    "predicted": result.drift_probability(camera, CAMPAIGNS[-1], p, seed=seed),
                    "happened": bool(abs(change) > p / 100.0),
                    "predicted_relative": result.drift_probability(camera, CAMPAIGNS[-1], p, seed=seed, relative=True),
                    "happened_relative": bool(abs(against) > p / 100.0),
                    "true_change_pct": 100 * change,
                    "caveat": result.drift_caveat(camera) is not None,
                }
            )
    return rows


def _reliability(df: pd.DataFrame, predicted: str, happened: str) -> pd.DataFrame:
    """Observed frequency (and its binomial se) per bin of predicted probability."""
    bins = pd.cut(df[predicted], BINS, right=False).astype(str)
    rel = (
        df.assign(bin=bins)
        .groupby("bin", sort=True)
        .agg(n=(happened, "size"), mean_predicted=(predicted, "mean"), observed=(happened, "mean"))
        .reset_index()
    )
    rel["observed_se"] = np.sqrt(rel.observed * (1 - rel.observed) / rel.n)
    return rel


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--fleets", type=int, default=6)
    parser.add_argument("--cameras", type=int, default=12)
    parser.add_argument("--walk", type=float, default=0.01, help="gain random walk per campaign (relative sd)")
    parser.add_argument("--no-ageing", dest="ageing", action="store_false", help="no settling ageing")
    parser.add_argument("--name", default="fleet_drift_reliability", help="results file name")
    args = parser.parse_args()
    spec = load_spec(ROOT / "models" / "fleet_seed000.toml")
    rows = []
    t0 = time.perf_counter()
    for k in range(args.fleets):
        rows += one_fleet(100 + k, args.cameras, args.walk, spec, args.ageing)
        print(f"fleet {k + 1}/{args.fleets} done ({time.perf_counter() - t0:.0f} s)", flush=True)
    df = pd.DataFrame(rows)
    OUT.mkdir(parents=True, exist_ok=True)
    df.to_csv(OUT / f"{args.name}.csv", index=False, float_format="%.4g")
    by_p = (
        df.groupby("threshold_pct")
        .agg(
            mean_predicted=("predicted", "mean"),
            observed=("happened", "mean"),
            mean_predicted_vs_fleet=("predicted_relative", "mean"),
            observed_vs_fleet=("happened_relative", "mean"),
            n=("happened", "size"),
        )
        .reset_index()
    )
    lines = [
        f"{args.fleets} fleets x {args.cameras} cameras, gains walking {args.walk:.1%} per campaign (plus "
        + ("the simulator's settling ageing and " if args.ageing else "no ageing, ")
        + "0.2 % campaign jitter); fitted on three campaigns, the fourth predicted "
        f"({time.perf_counter() - t0:.0f} s). The caveat (the fleet's common trend cannot be told from the "
        f"campaigns' spheres) was stated for {df.caveat.mean():.0%} of the cameras.",
        "",
        "Per threshold: P(|gain change| > p) from the third to the fourth campaign, green channel; `vs_fleet`: the "
        "camera's change against the fleet's common change (predicted with `relative=True`; observed against the "
        "fleet's mean true change).",
        "",
        by_p.to_markdown(index=False, floatfmt=".3f"),
        "",
        "Reliability (all thresholds pooled): observed frequency per bin of predicted probability, absolute.",
        "",
        _reliability(df, "predicted", "happened").to_markdown(index=False, floatfmt=".3f"),
        "",
        "The same against the fleet's common change.",
        "",
        _reliability(df, "predicted_relative", "happened_relative").to_markdown(index=False, floatfmt=".3f"),
    ]
    (OUT / f"{args.name}.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
