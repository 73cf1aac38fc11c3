"""Speed against error: every backend on several scenarios with known truth.

Run: ``python benchmarks/speed_vs_error.py [--reps 200] [--nuts-reps 50] [--emcee-reps 5]``.

Per scenario and backend: warm wall time of ``bayescal.fit`` (median), error of
the posterior mean of the true absolute gains ``A1`` (per channel, in posterior
sds, averaged), 95 % interval coverage of those gains over the replications,
and bulk ESS per second (MCMC backends).  LSQ's "sd" is its standard error
and its interval the classical 95 % confidence interval at the reference
setting.  Writes ``benchmarks/results/speed_vs_error.{csv,md,png}``.
"""

from __future__ import annotations

import argparse
import dataclasses
import time
import warnings
from pathlib import Path

import numpy as np
import pandas as pd

import bayescal as bc
from bayescal.design import Block

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"


def scenarios():
    s0, d0 = bc.load_spec(ROOT / "models/seed000_bayer.toml"), bc.load_design(ROOT / "models/seed000_design.toml")
    s2, d2 = bc.load_spec(ROOT / "models/seed002_tdi.toml"), bc.load_design(ROOT / "models/seed002_design.toml")
    no_sphere = dataclasses.replace(d0, truth=dataclasses.replace(d0.truth, common_rel=0.0))
    saturating = dataclasses.replace(d0, illuminated=(Block((0.01,), (1.0,)), Block((0.008,), (3.0, 4.0))))
    return {
        "seed000 (3 % sphere)": (s0, d0),
        "seed000, no sphere error": (s0.replace(sphere={"common_rel": 0.0}), no_sphere),
        "seed000 saturating": (s0, saturating),
        "seed002 TDI": (s2, d2),
    }


def run(backend, spec, design, reps, seed0):
    rows = []
    for r in range(reps):
        sim = bc.simulate(spec, design, seed=seed0 + r)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            t = time.perf_counter()
            fit = bc.fit(sim.table, spec, backend, seed=r)
            dt = time.perf_counter() - t
        chans = fit.model.layout.channels
        true = np.array([sim.truth.response[c][0] for c in chans])
        if backend == "lsq":
            mean, lo, hi = _lsq_gain(fit, spec, chans)
            sd = (hi - lo) / (2 * 1.96)
            ess = np.nan
        else:
            g = fit.draws("gain")
            mean, sd = g.mean(axis=0), g.std(axis=0)
            lo, hi = np.quantile(g, [0.025, 0.975], axis=0)
            ess = fit.diagnostics.min_ess_bulk if backend != "laplace" else np.nan
        rows.append(
            {
                "seconds": dt,
                "error_sd": float(np.mean(np.abs(mean - true) / sd)),
                "covered": float(np.mean((lo <= true) & (true <= hi))),
                "ess_per_s": (ess / dt) if ess == ess else np.nan,
                "ok": fit.ok,
            }
        )
    return pd.DataFrame(rows)


def _lsq_gain(fit, spec, chans):
    """LSQ slope A1 at the reference setting; where it was not measured, the nearest exposure at the reference
    gain and TDI scaled by the exposure ratio (seed 000 section 5.3's derived fit)."""
    ref = spec.reference
    lsq = fit.lsq
    rows = lsq[
        (lsq.order == spec.response.order) & np.isclose(lsq.gain, ref.gain) & np.isclose(lsq.tdi_stages, ref.tdi_stages)
    ]
    mean, lo, hi = [], [], []
    for c in chans:
        mine = rows[rows.channel == c]
        r = mine.iloc[int(np.argmin(np.abs(np.log(mine.exposure_s / ref.exposure_s))))]
        k = ref.exposure_s / r.exposure_s
        mean.append(r.A1 * k)
        lo.append(r.A1_lo * k)
        hi.append(r.A1_hi * k)
    return np.array(mean), np.array(lo), np.array(hi)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--reps", type=int, default=200, help="replications for lsq and laplace")
    parser.add_argument("--nuts-reps", type=int, default=50)
    parser.add_argument("--emcee-reps", type=int, default=5)
    args = parser.parse_args()
    reps = {"lsq": args.reps, "laplace": args.reps, "nuts": args.nuts_reps, "emcee": args.emcee_reps}
    out = []
    for name, (spec, design) in scenarios().items():
        for backend in ("lsq", "laplace", "nuts", "emcee"):
            if reps[backend] == 0:
                continue
            run(backend, spec, design, 1, 10_000)  # warm the compiled program
            df = run(backend, spec, design, reps[backend], 20_000)
            row = {
                "scenario": name,
                "backend": backend,
                "reps": len(df),
                "warm_s": df.seconds.median(),
                "error_sd": df.error_sd.mean(),
                "coverage95": df.covered.mean(),
                "ess_per_s": df.ess_per_s.median(),
                "failed_fits": int((~df.ok).sum()),
            }
            out.append(row)
            print(row, flush=True)
    write(pd.DataFrame(out))


def write(df: pd.DataFrame) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    RESULTS.mkdir(parents=True, exist_ok=True)
    df.to_csv(RESULTS / "speed_vs_error.csv", index=False, float_format="%.4g")
    lines = [
        "| scenario | backend | reps | warm s | error of mean (sd) | 95 % coverage | ESS/s | failed fits |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in df.itertuples():
        lines.append(
            f"| {r.scenario} | {r.backend} | {r.reps} | {r.warm_s:.3g} | {r.error_sd:.2f} | {r.coverage95:.3f} | "
            f"{r.ess_per_s:.0f} | {r.failed_fits} |"
        )
    (RESULTS / "speed_vs_error.md").write_text("\n".join(lines) + "\n")
    fig, ax = plt.subplots(figsize=(7, 4.5))
    markers = {"lsq": "s", "laplace": "o", "nuts": "^", "emcee": "D"}
    for k, (name, grp) in enumerate(df.groupby("scenario", sort=False)):
        colour = f"C{k}"
        grp = grp.sort_values("warm_s")
        ax.plot(grp.warm_s, abs(grp.coverage95 - 0.95), lw=0.8, alpha=0.6, color=colour, label=name)
        for r in grp.itertuples():
            ax.scatter(r.warm_s, abs(r.coverage95 - 0.95), marker=markers[r.backend], color=colour, s=40)
    for b, m in markers.items():
        ax.scatter([], [], marker=m, color="0.3", label=b)
    ax.set(xscale="log", xlabel="warm wall time per fit (s)", ylabel="|95 % coverage - 0.95| of true gains")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(RESULTS / "speed_vs_error.png", dpi=110)
    print("\n".join(lines))


if __name__ == "__main__":
    import sys

    if "--replot" in sys.argv:  # redraw the table and plot from the last CSV
        write(pd.read_csv(RESULTS / "speed_vs_error.csv"))
    else:
        main()
