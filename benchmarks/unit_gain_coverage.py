"""A unit's own relative-gain interval over hundreds of campaigns: is it calibrated?

The units of one campaign share its sphere's lamp-level errors (0.5 % per level), so a
coverage over a fleet's units is worth a few campaign draws (``fleet_lamp_errors.py``).
Here stage one alone (every unit fitted by itself, Laplace) runs on many small fleets
from the independent simulator (bayescal.validation.fleet): 2 cameras (``--cameras``) x 3 yearly
campaigns per seed, each camera swept over 3 radiance levels, so ``--seeds 150`` gives 450
campaign draws.  Per unit and channel: the standardised error ``z`` of the gain against
the campaign's sphere reading and whether the 95 % interval holds the truth; the summary
gives the coverage with its Monte Carlo sd over campaigns, the rms and mean of ``z``.
``--pixels`` and ``--frames`` set how many readings a row averages (the fleet benchmarks
use 256 x 20; fewer make the readout noise matter beside the lamp errors).

Usage: ``python benchmarks/unit_gain_coverage.py [--seeds 150] [--pixels 256 --frames 20]``;
results in ``benchmarks/results/unit_gain_coverage.{csv,md}`` (one row per setting, appended).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pandas as pd
from fleet_lamp_errors import relative_gain_rows  # run as a script: its folder is on the path

from bayescal import load_spec
from bayescal.fleet.stage1 import fit_units
from bayescal.fleet.units import fleet_from_frame
from bayescal.report.text import markdown_table
from bayescal.validation.fleet import FleetDesign, simulate_fleet

ROOT = Path(__file__).resolve().parents[1]


def run(seed: int, spec, pixels: int, frames: int, cameras: int = 2) -> list[dict]:
    names = tuple(f"SN{i + 1:03d}" for i in range(cameras))
    design = FleetDesign(n_cameras=cameras, brief=names, brief_levels=(2, 6, 10), n_pixels=pixels, n_frames=frames)
    table, truth = simulate_fleet(design, seed=seed)
    fleet = fleet_from_frame(table.astype(str), source=f"fleet {cameras}x3 seed {seed}")
    fits = fit_units(fleet, spec, "laplace", seed=seed)
    return [{"seed": seed} | r for r in relative_gain_rows(fits, truth)]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=150)
    ap.add_argument("--first", type=int, default=1000)
    ap.add_argument("--pixels", type=int, default=256)
    ap.add_argument("--frames", type=int, default=20)
    ap.add_argument("--cameras", type=int, default=2)
    args = ap.parse_args()
    spec = load_spec(ROOT / "models" / "fleet_seed000.toml")
    rows = []
    for seed in range(args.first, args.first + args.seeds):
        rows += run(seed, spec, args.pixels, args.frames, args.cameras)
        if (seed - args.first) % 10 == 9:
            print(f"seed {seed} done", flush=True)
    df = pd.DataFrame(rows)
    by_campaign = df.groupby(["seed", "campaign"])
    summary = {
        "cameras": args.cameras,
        "pixels_x_frames": f"{args.pixels} x {args.frames}",
        "seeds": f"{args.first}-{args.first + args.seeds - 1}",
        "campaigns": by_campaign.ngroups,
        "intervals": len(df),
        "coverage": float(df.covered.mean()),
        "coverage_mc_sd": float(by_campaign.covered.mean().std() / np.sqrt(by_campaign.ngroups)),
        "rms_z": float(np.sqrt(np.mean(df.z**2))),
        "mean_z": float(df.z.mean()),
        "sd_campaign_mean_z": float(by_campaign.z.mean().std()),
    }
    out = ROOT / "benchmarks" / "results" / "unit_gain_coverage"
    csv = out.with_suffix(".csv")
    table = pd.DataFrame([summary])
    if csv.exists():
        old = pd.read_csv(csv)
        same = (old.pixels_x_frames == summary["pixels_x_frames"]) & (old.cameras == args.cameras)
        same &= old.seeds == summary["seeds"]
        table = pd.concat([old[~same], table], ignore_index=True)
    table.to_csv(csv, index=False, float_format="%.5g")
    text = [
        "# A unit's own relative-gain interval over hundreds of campaigns",
        "",
        "Stage one alone (Laplace), `cameras` x 3 campaigns x 3 levels per seed (bayescal.validation.fleet);",
        "the gain against the campaign's sphere reading, per unit and channel. `coverage_mc_sd`: over campaigns",
        "(a campaign's units share its lamp errors). `python benchmarks/unit_gain_coverage.py --pixels P --frames F`.",
        "",
        markdown_table(table),
        "",
    ]
    out.with_suffix(".md").write_text("\n".join(text))
    print("\n".join(text))


if __name__ == "__main__":
    main()
