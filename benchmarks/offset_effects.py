"""The offset effects' own coefficients on the independent bench: coverage, and what happens without them.

Run: ``python benchmarks/offset_effects.py [--datasets 20]``.

Every dataset comes from :mod:`bayescal.validation.bench` (a simulator that imports none of the
model's components) with one departure the model can absorb as an offset effect:

- amplifier glow, ``glow_dn_s2 * share_ch * t^2 * g`` (shares 1.0, 0.4, 1.8 for R, G, B), fitted by
  ``[glow]``: its truth is ``dark_glow_dn_s2`` per channel (DN/s^2 at the reference gain 1);
- a readout bias drifting ``bias_dn_per_c * share_ch`` DN per degC (shares 1.0, -0.6, 0.4) with the
  plan measured at 10, 20 and 30 degC, fitted by ``[offset_temperature]``: its truth is
  ``offset_tc_dn_per_c`` per channel.

Per case: the fraction of fits that pass their checks with the effect and without it, and the coverage of
the 95 % (and 99 %) intervals of each channel's coefficient over every dataset and channel, with its
binomial Monte Carlo sd.  Writes ``benchmarks/results/offset_effects.{csv,md}``.
"""

from __future__ import annotations

import argparse
import time
import warnings
from pathlib import Path

import numpy as np
import pandas as pd

import bayescal as bc
from bayescal.report.text import markdown_table
from bayescal.validation import BenchCamera, Departures, simulate_bench
from bayescal.validation.bench import BIAS_SHARE, GLOW_SHARE

OUT = Path(__file__).resolve().parent / "results"
SPEC = Path(__file__).resolve().parent.parent / "models" / "seed000_bayer.toml"
GLOW_DN_S2 = 1e5
BIAS_DN_PER_C = 0.8
CASES = {
    f"amplifier glow {GLOW_DN_S2:g} DN/s^2": (
        Departures(glow_dn_s2=GLOW_DN_S2),
        BenchCamera(),
        {"glow": {"enabled": True}},
        {"glow": {"enabled": False}},
        "dark_glow_dn_s2",
        [GLOW_DN_S2 * s for s in GLOW_SHARE],
    ),
    f"readout bias {BIAS_DN_PER_C:g} DN/degC at 10, 20, 30 degC": (
        Departures(bias_dn_per_c=BIAS_DN_PER_C),
        BenchCamera(temperatures_c=(10.0, 20.0, 30.0)),
        {"offset_temperature": {"enabled": True}},
        {"offset_temperature": {"enabled": False}},
        "offset_tc_dn_per_c",
        [BIAS_DN_PER_C * s for s in BIAS_SHARE],
    ),
}


def _fit(table, spec, seed):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return bc.fit(table, spec, "laplace", seed=seed)


def run_case(name: str, n: int) -> dict:
    departures, camera, on, off, quantity, truth = CASES[name]
    base = bc.load_spec(SPEC)
    hits = {0.95: [], 0.99: []}
    ok_with, ok_without, t0 = [], [], time.perf_counter()
    for seed in range(n):
        frame, _ = simulate_bench(camera, departures, seed=seed)
        table = bc.MeasurementTable.from_frame(frame)
        fit = _fit(table, base.replace(**on), seed)
        ok_with.append(fit.ok)
        ok_without.append(_fit(table, base.replace(**off), seed).ok)
        draws = fit.draws(quantity)  # (S, C)
        for level in hits:
            lo, hi = np.quantile(draws, [(1 - level) / 2, (1 + level) / 2], axis=0)
            hits[level] += [bool(a <= t <= b) for a, t, b in zip(lo, truth, hi, strict=True)]
    row = {"case": name, "datasets": n, "ok_with": float(np.mean(ok_with)), "ok_without": float(np.mean(ok_without))}
    for level, h in hits.items():
        p = float(np.mean(h))
        row[f"coverage{int(level * 100)}"] = p
        row[f"mc_sd{int(level * 100)}"] = float(np.sqrt(level * (1 - level) / len(h)))
    row["seconds"] = round(time.perf_counter() - t0, 1)
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--datasets", type=int, default=20, help="datasets per case")
    args = parser.parse_args()
    rows = []
    for name in CASES:
        rows.append(run_case(name, args.datasets))
        print(rows[-1], flush=True)
    df = pd.DataFrame(rows)
    OUT.mkdir(exist_ok=True)
    df.to_csv(OUT / "offset_effects.csv", index=False)
    (OUT / "offset_effects.md").write_text(markdown_table(df.round(4)) + "\n")


if __name__ == "__main__":
    main()
