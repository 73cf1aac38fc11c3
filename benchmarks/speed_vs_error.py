"""Speed against error: every backend on several scenarios with known truth.

Run: ``python benchmarks/speed_vs_error.py [--reps 200] [--emcee-reps 1] [--only NAME]``.

Per scenario and backend: the first ``bayescal.fit`` call of the run (compiled
programs come from the persistent cache when it is warm), the warm single-fit
wall time (median of 3), the per-dataset time of ``fit_many`` over all
replications (laplace, nuts; lsq and emcee fit them one by one, and their warm
time is the median over the replications), the error of the posterior mean of the true
absolute gains ``A1`` (per channel, in posterior sds, averaged), 95 % interval
coverage of those gains over the replications, and bulk ESS per second
(MCMC backends).  LSQ's "sd" is its standard error and its interval the
classical 95 % confidence interval at the reference setting.  Each scenario
simulates its own datasets; the backends share them.  Writes
``benchmarks/results/speed_vs_error.{csv,md,png}``.
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
from bayescal.fitting.batch import fit_many
from bayescal.io.design import Block

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"


def scenarios():
    s0, d0 = bc.load_spec(ROOT / "models/seed000_bayer.toml"), bc.load_design(ROOT / "models/seed000_design.toml")
    s2, d2 = bc.load_spec(ROOT / "models/seed002_tdi.toml"), bc.load_design(ROOT / "models/seed002_design.toml")
    no_sphere = dataclasses.replace(d0, truth=dataclasses.replace(d0.truth, common_rel=0.0))
    saturating = dataclasses.replace(d0, illuminated=(Block((0.01,), (1.0,)), Block((0.008,), (3.0, 4.0))))
    # a 6 % compressive nonlinearity at the top radiance level (the shipped truth has 0.6 %)
    curved = {c: [a[0], 10 * a[1]] for c, a in d0.truth.response.items()}
    nonlinear = dataclasses.replace(d0, truth=dataclasses.replace(d0.truth, response=curved))
    two_levels = dataclasses.replace(d0, levels=d0.levels[:2], illuminated=(Block((0.004,)),))
    collinear = dataclasses.replace(
        d0,
        illuminated=(Block((0.004,), (1.0,)), Block((0.008,), (2.0,)), Block((0.01,), (3.0,))),
        dark=(Block((0.004,), (1.0,)), Block((0.008,), (2.0,)), Block((0.01,), (3.0,))),
    )
    return {
        "seed000 (3 % sphere)": (s0, d0),
        "seed000, no sphere error": (s0.replace(sphere={"common_rel": 0.0}), no_sphere),
        "seed000 saturating": (s0, saturating),
        "seed000 6 % nonlinearity": (s0, nonlinear),
        "seed002 TDI": (s2, d2),
        "8-bit, 2-12 DN single pixels": eight_bit(),
        "seed000, two levels (order 1)": (s0.replace(response={"order": 1}), two_levels),
        "seed000, exposure and gain collinear": (s0, collinear),
    }


def eight_bit():
    """``models/8bit_near_dark``: one channel of an 8-bit camera read as single pixels of 2-12 DN,
    quantised to integers (read noise 0.6 DN: quantisation is a large part of the noise)."""
    return bc.load_spec(ROOT / "models/8bit_near_dark.toml"), bc.load_design(ROOT / "models/8bit_near_dark_design.toml")


def _truth_gain(sim, chans):
    return np.array([sim.truth.response[c][0] for c in chans])


def run(backend, spec, design, reps, seed0):
    """One row of the table: ``reps`` datasets fitted one by one (lsq, emcee) or with
    ``fit_many`` (laplace, nuts); warm single-fit time measured separately on 3 datasets."""
    sims = [bc.simulate(spec, design, seed=seed0 + r) for r in range(reps)]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        t = time.perf_counter()
        bc.fit(sims[0].table, spec, backend, seed=0)
        first = time.perf_counter() - t
        warm = []
        for sim in sims[1 : min(4, reps)] if backend in ("laplace", "nuts") else ():
            t = time.perf_counter()
            bc.fit(sim.table, spec, backend, seed=1)
            warm.append(time.perf_counter() - t)
        rows = []
        if backend in ("laplace", "nuts"):
            t = time.perf_counter()
            batch = fit_many([s.table for s in sims], spec, backend, seed=0)
            per_fit = (time.perf_counter() - t) / reps
            for i, sim in enumerate(sims):
                g = batch.physical(i)["gain"].reshape(-1, len(batch.models[i].layout.channels))
                ess = batch.diagnostics["min_ess_bulk"][i] if backend == "nuts" else np.nan
                rows.append(_score(g, _truth_gain(sim, batch.models[i].layout.channels), ess, per_fit, batch.ok[i]))
        else:
            per_fit = np.nan
            for r, sim in enumerate(sims):
                t = time.perf_counter()
                fit = bc.fit(sim.table, spec, backend, seed=r)
                dt = time.perf_counter() - t
                chans = fit.model.layout.channels
                if backend == "lsq":
                    mean, lo, hi = _lsq_gain(fit, spec, chans)
                    rows.append(_interval_score(mean, lo, hi, _truth_gain(sim, chans), np.nan, dt, True))
                else:
                    ess = fit.diagnostics.min_ess_bulk
                    rows.append(_score(fit.draws("gain"), _truth_gain(sim, chans), ess, dt, fit.ok))
    df = pd.DataFrame(rows)
    if not warm:  # lsq, emcee: the replications are fitted one by one, warm
        warm = df.seconds.tolist()
    return df, first, float(np.median(warm)), per_fit


def _score(g, true, ess, seconds, ok):
    lo, hi = np.quantile(g, [0.025, 0.975], axis=0)
    return _interval_score(g.mean(axis=0), lo, hi, true, ess, seconds, ok, sd=g.std(axis=0))


def _interval_score(mean, lo, hi, true, ess, seconds, ok, sd=None):
    sd = (hi - lo) / (2 * 1.96) if sd is None else sd
    return {
        "seconds": seconds,
        "error_sd": float(np.mean(np.abs(mean - true) / sd)),
        "covered": float(np.mean((lo <= true) & (true <= hi))) if np.all(np.isfinite([lo, hi])) else np.nan,
        "ess_per_s": (ess / seconds) if ess == ess else np.nan,
        "ok": bool(ok),
    }


def _lsq_gain(fit, spec, chans):
    """LSQ slope A1 at the reference setting; where it was not measured, the nearest exposure at the reference
    gain and TDI scaled by the exposure ratio (seed 000 section 5.3's derived fit)."""
    ref = spec.reference
    lsq = fit.lsq
    if "order" not in lsq:  # too few points per setting for a least-squares interval (e.g. two levels)
        nan = np.full(len(chans), np.nan)
        return nan, nan, nan
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
    parser.add_argument("--reps", type=int, default=200, help="replications for lsq, laplace and nuts")
    parser.add_argument("--emcee-reps", type=int, default=1)
    parser.add_argument("--only", help="run only scenarios whose name contains this")
    args = parser.parse_args()
    reps = {"lsq": args.reps, "laplace": args.reps, "nuts": args.reps, "emcee": args.emcee_reps}
    out = []
    for k, (name, (spec, design)) in enumerate(scenarios().items()):
        if args.only and args.only not in name:
            continue
        for backend in ("lsq", "laplace", "nuts", "emcee"):
            if reps[backend] == 0:
                continue
            # every scenario gets its own datasets (seeds differ by scenario), the backends the same ones
            df, first, warm, per_fit = run(backend, spec, design, reps[backend], 20_000 + 1000 * k)
            row = {
                "scenario": name,
                "backend": backend,
                "reps": len(df),
                "first_s": first,
                "warm_s": warm,
                "batch_s_per_fit": per_fit,
                "error_sd": df.error_sd.mean(),
                "coverage95": df.covered.mean(),
                "ess_per_s": df.ess_per_s.median(),
                "failed_fits": int((~df.ok).sum()),
            }
            out.append(row)
            print(row, flush=True)
            write(_merged(pd.DataFrame(out)))  # after every row: a crash loses nothing measured


def _merged(df: pd.DataFrame) -> pd.DataFrame:
    """The new rows, replacing rows of the same scenario and backend in the last CSV (``--only`` runs)."""
    path = RESULTS / "speed_vs_error.csv"
    if not path.exists():
        return df
    old = pd.read_csv(path)
    keep = ~old.set_index(["scenario", "backend"]).index.isin(df.set_index(["scenario", "backend"]).index)
    order = {name: k for k, name in enumerate(scenarios())}
    both = pd.concat([old[keep], df], ignore_index=True)
    return both.sort_values("scenario", key=lambda s: s.map(order), kind="stable").reset_index(drop=True)


def write(df: pd.DataFrame) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    RESULTS.mkdir(parents=True, exist_ok=True)
    df.to_csv(RESULTS / "speed_vs_error.csv", index=False, float_format="%.4g")
    lines = [
        "| scenario | backend | reps | first s | warm s | fit_many s/fit | error of mean (sd) | 95 % coverage "
        "| ESS/s | failed fits |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in df.itertuples():
        lines.append(
            f"| {r.scenario} | {r.backend} | {r.reps} | {r.first_s:.3g} | {r.warm_s:.3g} | {r.batch_s_per_fit:.3g} | "
            f"{r.error_sd:.2f} | {r.coverage95:.3f} | {r.ess_per_s:.0f} | {r.failed_fits} |"
        )
    (RESULTS / "speed_vs_error.md").write_text("\n".join(lines) + "\n")
    fig, ax = plt.subplots(figsize=(7, 4.5))
    markers = {"lsq": "s", "laplace": "o", "nuts": "^", "emcee": "D"}
    for k, (name, grp) in enumerate(df.groupby("scenario", sort=False)):
        colour = f"C{k}"
        grp = grp[grp.reps >= 20].sort_values("warm_s")  # coverage from a handful of fits means nothing
        ax.plot(grp.warm_s, abs(grp.coverage95 - 0.95), lw=0.8, alpha=0.6, color=colour, label=name)
        for r in grp.itertuples():
            ax.scatter(r.warm_s, abs(r.coverage95 - 0.95), marker=markers[r.backend], color=colour, s=40)
    for b, m in markers.items():
        ax.scatter([], [], marker=m, color="0.3", label=b)
    ax.set(
        xscale="log",
        xlabel="warm wall time per fit (s)",
        ylabel="|95 % coverage - 0.95| of true gains",
        title="backends with >= 20 replications (200 each here; emcee's 1 is left out)",
    )
    ax.title.set_fontsize(8)
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
