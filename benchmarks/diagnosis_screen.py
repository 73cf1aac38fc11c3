"""Does the diagnosis's screen keep out only candidates that could not have been adopted?

The diagnosis (:mod:`bayescal.fitting.diagnosis`) screens each candidate by its in-sample gain at its mode
(:mod:`bayescal.fitting.modegain`) before a full fit, and skips those whose gain is at most
``SCREEN_SE`` standard errors.  Here every candidate of the first step is also fully fitted (Laplace,
PSIS-LOO, as the diagnosis judges it), on datasets of the two independent simulators: the cameras nobody
described (:mod:`bayescal.validation.wild`, its seeds) and the bench's one departure at a time
(:mod:`bayescal.validation.bench`, the misspecification benchmark's cases).  Per candidate: the in-sample
gain and its se, the elpd_loo gain and its se, whether it was screened out, and whether PSIS-LOO would have
adopted it (gain above 2 se).  A screened-out candidate that PSIS-LOO would have adopted is a miss.

    python benchmarks/diagnosis_screen.py [--wild 0 1 2 ...] [--bench-seed 10000]

Writes ``benchmarks/results/diagnosis_screen.{csv,md}``.
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import pandas as pd

import bayescal as bc
from bayescal.fitting import diagnosis as dg
from bayescal.fitting.diagnosis import trials
from bayescal.fitting.modegain import mode_fit, screen
from bayescal.report.text import markdown_table
from bayescal.validation import BenchCamera, simulate_bench, with_held_out
from bayescal.validation.wild import simulate_wild

sys.path.insert(0, str(Path(__file__).resolve().parent))
from misspecification import CASES, NO_TIME, SPEC  # noqa: E402

OUT = Path(__file__).resolve().parent / "results"


def judged(name: str, table: bc.MeasurementTable, spec, seed: int) -> list[dict]:
    """Every first-step candidate of ``table``: screened by its mode, and fitted and judged by PSIS-LOO."""
    base_spec = dg.laplace_proxy(spec)
    base = trials.quiet_fit(table, base_spec, "laplace", seed)
    base_loo, base_mode = trials.psis_loo(base), mode_fit(table, base_spec)
    rows = []
    for candidate, changes in dg.candidates(spec, table).items():
        trial = dg.laplace_proxy(spec.replace(**changes)).replace(inference={"holdout_check": False})
        t0 = time.perf_counter()
        own = mode_fit(table, trial)
        t_mode = time.perf_counter() - t0
        by = screen(base_mode, own)
        t0 = time.perf_counter()
        result = trials.quiet_fit(table, trial, "laplace", seed)
        loo_gain, loo_se = trials.difference(base_loo, trials.psis_loo(result))
        rows.append(
            {
                "dataset": name,
                "candidate": candidate,
                "mode_gain": by.gain,
                "mode_dse": by.se,
                "loo_gain": loo_gain,
                "loo_dse": loo_se,
                "screened": by.out,
                "would_adopt": loo_gain > dg.EVIDENCE_SE * loo_se,
                "mode_s": t_mode,
                "full_s": time.perf_counter() - t0,
            }
        )
    return rows


def datasets(wild: list[int], bench_seed: int):
    for seed in wild:
        frame, _ = simulate_wild(seed)
        yield f"wild seed {seed}", bc.MeasurementTable.from_frame(frame), seed
    for case, dep in CASES.items():
        if "sessions at" in case:  # the thermal case needs the bench's temperatures
            continue
        camera = with_held_out(BenchCamera(), exposures=(0.01,))
        frame, _ = simulate_bench(camera, dep, seed=bench_seed)
        if case in NO_TIME:
            frame = frame.drop(columns="time_s")
        yield f"bench: {case}", bc.MeasurementTable.from_frame(frame), bench_seed


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--wild", type=int, nargs="*", default=list(range(8)))
    p.add_argument("--bench-seed", type=int, default=10_000)
    args = p.parse_args()
    spec = bc.load_spec(SPEC)
    rows: list[dict] = []
    OUT.mkdir(exist_ok=True)
    for name, table, seed in datasets(args.wild, args.bench_seed):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            rows += judged(name, table, spec, seed)
        df = pd.DataFrame(rows)
        print(name, f"{len(df)} candidates, misses {int((df.screened & df.would_adopt).sum())}", flush=True)
        df.to_csv(OUT / "diagnosis_screen.csv", index=False, float_format="%.4g")
        (OUT / "diagnosis_screen.md").write_text(_markdown(df))


def _markdown(df: pd.DataFrame) -> str:
    screened = df[df.screened]
    kept = df[~df.screened]
    summary = pd.DataFrame(
        [
            {
                "datasets": df.dataset.nunique(),
                "candidates": len(df),
                "screened out": len(screened),
                "screened out that PSIS-LOO would adopt (misses)": int(screened.would_adopt.sum()),
                "adopted by PSIS-LOO, kept": int(kept.would_adopt.sum()),
                "in-sample gain >= elpd_loo gain": f"{float(np.mean(df.mode_gain >= df.loo_gain)):.3f}",
                "largest elpd_loo gain screened out (se)": (
                    f"{float((screened.loo_gain / screened.loo_dse).max()):.2f}" if len(screened) else "-"
                ),
                "seconds: mode only / full fits": f"{df.mode_s.sum():.0f} / {df.full_s.sum():.0f}",
            }
        ]
    )
    cols = ["dataset", "candidate", "mode_gain", "mode_dse", "loo_gain", "loo_dse", "screened", "would_adopt"]
    detail = df[cols].round(1)
    return markdown_table(summary) + "\n\nEvery candidate:\n\n" + markdown_table(detail) + "\n"


if __name__ == "__main__":
    main()
