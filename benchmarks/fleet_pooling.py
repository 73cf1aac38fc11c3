"""Pooling versus each camera alone, on simulated fleets with known truth.

Fleets from the independent simulator (bayescal.validation.fleet: uniform production
band, ageing that settles, per-campaign jitter, a sphere per campaign, gain steps off
their labels) of 5, 20 and 50 cameras, each swept over 3, 6 or 12 radiance levels in
three yearly campaigns.  Every unit is fitted alone (Laplace, stage one), then the
hierarchy (NUTS on its scales); per unit and channel, against the truth:

- ``gain_rel``: the gain against the sphere's reading in that campaign (what a unit's
  own data pin down), ``gain_abs``: the absolute gain (the sphere's ~3 % scale error
  included: common to every camera of a campaign, pooling cannot remove it),
  ``offset``: A0 at the reference setting (DN);
- RMSE (relative for gains), mean 95 % interval width and 95 % coverage, alone and pooled.

Also the stage-two time (warm) beside the stage-one ``fit_many`` of the same units, in
one run.  Usage: ``python benchmarks/fleet_pooling.py [--quick] [--cameras 50 --levels 6 --seeds 1
--out fleet_pooling_50]``; results in ``benchmarks/results/fleet_pooling.{csv,md}`` (or the ``--out`` stem).
"""

from __future__ import annotations

import argparse
import time
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
LEVELS = {3: (2, 6, 10), 6: (0, 2, 4, 6, 8, 10), 12: tuple(range(12))}


def simulated_fleet(n_cameras: int, n_levels: int, seed: int):
    """A fleet from the independent simulator, every camera swept over ``n_levels`` levels, and its truth."""
    names = tuple(f"SN{i + 1:03d}" for i in range(n_cameras))
    design = FleetDesign(n_cameras=n_cameras, brief=names if n_levels < 12 else (), brief_levels=LEVELS[n_levels])
    table, truth = simulate_fleet(design, seed=seed)
    return fleet_from_frame(table.astype(str), source=f"fleet {n_cameras}x{n_levels} seed {seed}"), truth


def run(n_cameras: int, n_levels: int, seed: int, spec, cold: bool = True) -> tuple[list[dict], dict]:
    """One fleet: per unit and channel the errors, widths and coverage, alone and pooled, and the
    times.  ``cold``: fit stage two once first to time its compilation (a later seed of the same
    structure finds the programs compiled, so only its first seed needs it)."""
    fleet, truth = simulated_fleet(n_cameras, n_levels, seed)
    t0 = time.perf_counter()
    fits = fit_units(fleet, spec, "laplace", seed=seed)
    t1 = time.perf_counter()
    if cold:
        fit_fleet(fleet, spec, fits=fits, seed=seed)  # compile (once per structure)
    t2 = time.perf_counter()
    result = fit_fleet(fleet, spec, fits=fits, seed=seed + 1)
    t3 = time.perf_counter()
    vals = result.unit_values()  # absolute, (S, U, K, C)
    obs = result._physical(np.transpose(result._flat("theta_observed"), (0, 2, 1, 3)))
    rows = []
    for u, unit in enumerate(fleet.units):
        phys = fits.physical(u)
        a_abs = np.asarray(phys["A_abs"]).reshape((-1,) + np.shape(phys["A_abs"])[2:])
        a_rel = np.asarray(phys["A_rel"]).reshape(a_abs.shape)
        for c, ch in enumerate(fits.channels):
            tr = truth[
                (truth.camera == unit.camera)
                & (truth.campaign == unit.campaign.date().isoformat())
                & (truth.channel == ch)
            ].iloc[0]
            cases = {
                "gain_abs": (a_abs[:, c, 1], np.exp(vals[:, u, 0, c]), tr.gain, True),
                "gain_rel": (a_rel[:, c, 1], np.exp(obs[:, u, 0, c]), tr.gain * tr.sphere_scale, True),
                "offset": (a_abs[:, c, 0], vals[:, u, 1, c], tr.offset, False),
            }
            for q, (alone, pooled, true, rel) in cases.items():
                for how, v in (("alone", alone), ("pooled", pooled)):
                    lo, med, hi = np.quantile(v, [0.025, 0.5, 0.975])
                    norm = true if rel else 1.0
                    rows.append(
                        {
                            "cameras": n_cameras,
                            "levels": n_levels,
                            "seed": seed,
                            "campaign": unit.campaign.date().isoformat(),
                            "quantity": q,
                            "method": how,
                            "error": (med - true) / norm,
                            "width": (hi - lo) / norm,
                            "covered": lo <= true <= hi,
                        }
                    )
    d = result.draws.diagnostics
    timing = {
        "cameras": n_cameras,
        "levels": n_levels,
        "seed": seed,
        "units": len(fleet.units),
        "stage1_fit_many_s": t1 - t0,
        "stage2_cold_s": t2 - t1 if cold else float("nan"),
        "stage2_warm_s": t3 - t2,
        "divergences": d["divergences"],
        "max_rhat": d["max_rhat"],
        "min_ess": min(d["min_ess_bulk"], d["min_ess_tail"]),
        # the log gain's excess where the channels move together and where they differ
        "sqrt_kappa_gain_together": float(np.sqrt(np.median(result._excess()[:, 0, 0]))),
        "sqrt_kappa_gain_apart": float(np.sqrt(np.median(result._excess()[:, 0, -1]))),
        "ok": result.ok,
    }
    return rows, timing


def _cluster_sd(g: pd.DataFrame) -> float:
    """Monte Carlo sd of a coverage whose values are correlated within a (seed, campaign) cluster:
    the sandwich estimate ``sqrt(sum_j (sum_i (c_i - p))^2) / n``."""
    c = g["covered"].to_numpy(float)
    dev = pd.Series(c - c.mean()).groupby([g["seed"].to_numpy(), g["campaign"].to_numpy()]).sum()
    return float(np.sqrt(np.sum(dev.to_numpy() ** 2)) / len(c))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="5 and 20 cameras only")
    ap.add_argument("--seeds", type=int, default=2, help="fleets per cell (seeds 100 + first-seed, ...)")
    ap.add_argument("--first-seed", type=int, default=0)
    ap.add_argument("--cameras", help="fleet sizes, comma-separated (default 5,20,50; --quick: 5,20)")
    ap.add_argument("--levels", default="3,6,12", help="radiance levels per brief camera, comma-separated")
    ap.add_argument("--out", default="fleet_pooling", help="result stem under benchmarks/results/")
    args = ap.parse_args()
    spec = load_spec(ROOT / "models" / "fleet_seed000.toml")
    sizes = (5, 20) if args.quick else (5, 20, 50)
    if args.cameras:
        sizes = tuple(int(v) for v in args.cameras.split(","))
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    rows, timings = [], []
    for n in sizes:
        for levels in (int(v) for v in args.levels.split(",")):
            for seed in seeds:
                r, t = run(n, levels, 100 + seed, spec, cold=seed == seeds[0])
                rows += r
                timings.append(t)
                print(t, flush=True)
    df = pd.DataFrame(rows)
    out = ROOT / "benchmarks" / "results"
    df.to_csv(out / f"{args.out}.csv", index=False, float_format="%.6g")
    summary = (
        df.groupby(["quantity", "cameras", "levels", "method"])
        .agg(
            rmse=("error", lambda e: float(np.sqrt(np.mean(e**2)))),
            width=("width", "mean"),
            coverage=("covered", "mean"),
            n=("covered", "size"),
        )
        .reset_index()
    )
    # a campaign's sphere (its lamp levels' errors) is shared by every unit measured in it, so
    # the coverage's Monte Carlo error counts campaign realisations, not units x channels
    spread = df.groupby(["quantity", "cameras", "levels", "method"]).apply(_cluster_sd, include_groups=False)
    summary = summary.merge(spread.rename("coverage_mc_sd").reset_index())
    wide = summary.pivot_table(
        index=["quantity", "cameras", "levels"],
        columns="method",
        values=["rmse", "width", "coverage", "coverage_mc_sd"],
    )
    wide.columns = [f"{a}_{b}" for a, b in wide.columns]
    tim = pd.DataFrame(timings)
    text = [
        "# Fleet pooling versus each camera alone",
        "",
        f"Simulated fleets (bayescal.validation.fleet), 3 yearly campaigns, seeds {[100 + s for s in seeds]}; "
        "RMSE and widths relative to the true gain (offsets in DN); coverage of 95 % intervals "
        f"over units x channels (n = {int(summary['n'].min())}-{int(summary['n'].max())} per cell). "
        f"Every unit of a campaign shares its sphere's lamp-level errors, so the coverage's Monte Carlo "
        f"sd (`coverage_mc_sd`) is taken over the {len(seeds) * 3} campaign realisations (seeds x 3), "
        "not over units.",
        "",
        markdown_table(wide.reset_index()),
        "",
        "## Time and diagnostics (2 cores; stage two warm = a second fit of the same structure)",
        "",
        markdown_table(tim),
        "",
    ]
    (out / f"{args.out}.md").write_text("\n".join(text))
    print("\n".join(text))


if __name__ == "__main__":
    main()
