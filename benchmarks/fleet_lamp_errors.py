"""What a unit's own relative-gain error is made of: its campaign's lamp-level errors.

Fleets of 5 cameras swept over 3 radiance levels in three yearly campaigns, from the
independent simulator (bayescal.validation.fleet), with the sphere's lamp-level errors
(0.5 % per level, shared by every unit of a campaign) as designed and switched off.  Per
unit and channel the standardised error ``z`` of the relative gain (against the
campaign's sphere reading), alone (stage one) and pooled (stage two): its rms, how much of
it the campaign's units share (sd of the campaign means against the sd within a
campaign), the 95 % coverage and the mean posterior sd.  A coverage over these units is
a handful of campaign draws, not hundreds of values.

The coverage's Monte Carlo sd (``coverage_mc_sd``) is taken over campaigns (the units
of one campaign share its lamp errors), so settling whether a coverage of 0.88 is short
of 0.95 takes a hundred-odd campaigns, not the 24 of the pooling benchmark.

Usage: ``python benchmarks/fleet_lamp_errors.py [--seeds 6] [--first 100] [--lamp-only] [--out STEM]``;
results in ``benchmarks/results/fleet_lamp_errors.{csv,md}`` (or the ``--out`` stem).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pandas as pd

from bayescal import load_spec
from bayescal.fleet import fit_fleet
from bayescal.fleet.stage1 import fit_units
from bayescal.fleet.units import fleet_from_frame
from bayescal.report.text import markdown_table
from bayescal.validation.fleet import FleetDesign, simulate_fleet

ROOT = Path(__file__).resolve().parents[1]
NAMES = tuple(f"SN{i + 1:03d}" for i in range(5))


def run(seed: int, level_rel: float, spec) -> list[dict]:
    design = FleetDesign(n_cameras=5, brief=NAMES, brief_levels=(2, 6, 10), sphere_level_rel=level_rel)
    table, truth = simulate_fleet(design, seed=seed)
    fleet = fleet_from_frame(table.astype(str), source=f"fleet 5x3 seed {seed}")
    fits = fit_units(fleet, spec, "laplace", seed=seed)
    result = fit_fleet(fleet, spec, fits=fits, seed=seed + 1)
    pooled = np.exp(result.unit_values(relative=True)[:, :, 0, :])  # (S, U, C)
    rows = relative_gain_rows(fits, truth, pooled)
    return [{"lamp_errors": level_rel > 0, "seed": seed} | r for r in rows]


def relative_gain_rows(fits, truth: pd.DataFrame, pooled: np.ndarray | None = None) -> list[dict]:
    """Per unit and channel, for the unit's own fit (``alone``) and, given its draws ``(S, U, C)``,
    the fleet's (``pooled``): the campaign, ``z`` (posterior mean - truth) / sd, ``sd_rel`` and
    whether the 95 % interval holds the gain against the campaign's sphere reading."""
    t = truth.set_index(["camera", "campaign", "channel"])
    rows = []
    for u, unit in enumerate(fits.fleet.units):
        day = unit.campaign.date().isoformat()
        a_rel = np.asarray(fits.physical(u)["A_rel"])
        a_rel = a_rel.reshape((-1,) + a_rel.shape[2:])
        for c, ch in enumerate(fits.channels):
            true = t.loc[(unit.camera, day, ch), "gain"] * t.loc[(unit.camera, day, ch), "sphere_scale"]
            draws = [("alone", a_rel[:, c, 1])] + ([] if pooled is None else [("pooled", pooled[:, u, c])])
            for how, v in draws:
                lo, hi = np.quantile(v, [0.025, 0.975])
                rows.append(
                    {
                        "campaign": day,
                        "method": how,
                        "z": (v.mean() - true) / v.std(),
                        "sd_rel": v.std() / true,
                        "covered": lo <= true <= hi,
                    }
                )
    return rows


def summarise(df: pd.DataFrame) -> pd.DataFrame:
    out = []
    for (lamp, how), g in df.groupby(["lamp_errors", "method"]):
        by_campaign = g.groupby(["seed", "campaign"]).z
        out.append(
            {
                "lamp_errors": lamp,
                "method": how,
                "campaigns": by_campaign.ngroups,
                "rms_z": float(np.sqrt(np.mean(g.z**2))),
                "sd_campaign_mean_z": float(by_campaign.mean().std()),
                "sd_z_within_campaign": float(by_campaign.std().mean()),
                "coverage": float(g.covered.mean()),
                "coverage_mc_sd": float(
                    g.groupby(["seed", "campaign"]).covered.mean().std() / np.sqrt(by_campaign.ngroups)
                ),
                "mean_sd_rel": float(g.sd_rel.mean()),
            }
        )
    return pd.DataFrame(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=6)
    ap.add_argument("--first", type=int, default=100, help="first simulator seed")
    ap.add_argument("--out", default="fleet_lamp_errors", help="results stem under benchmarks/results")
    ap.add_argument("--lamp-only", action="store_true", help="only the fleets with lamp errors (no control)")
    args = ap.parse_args()
    spec = load_spec(ROOT / "models" / "fleet_seed000.toml")
    rows = []
    for level_rel in (0.005,) if args.lamp_only else (0.005, 0.0):
        for seed in range(args.first, args.first + args.seeds):
            rows += run(seed, level_rel, spec)
            print(f"lamp errors {level_rel}: seed {seed} done", flush=True)
    table = summarise(pd.DataFrame(rows))
    out = ROOT / "benchmarks" / "results" / args.out
    table.to_csv(out.with_suffix(".csv"), index=False, float_format="%.5g")
    seeds = list(range(args.first, args.first + args.seeds))
    text = [
        "# A unit's relative-gain error: its campaign's lamp-level errors",
        "",
        f"Fleets of 5 cameras x 3 levels x 3 campaigns (bayescal.validation.fleet), seeds {seeds[0]}-{seeds[-1]};",
        "the spec (models/fleet_seed000.toml) keeps `per_level_rel = 0.005` in every row. `z`:",
        "(posterior mean - truth) / posterior sd of the gain against the campaign's sphere reading, per unit and",
        "channel; `coverage_mc_sd`:",
        "the coverage's Monte Carlo sd over campaigns (a campaign's units share its lamp errors).",
        "",
        markdown_table(table),
        "",
    ]
    out.with_suffix(".md").write_text("\n".join(text))
    print("\n".join(text))


if __name__ == "__main__":
    main()
