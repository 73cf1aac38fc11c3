"""Cold and warm wall time per backend on the seed 000 dataset, with the ratio to LSQ.

The two NUTS implementations (numpyro's and BlackJAX's, on the same compiled potential
in the same whitened coordinates) run side by side with their effective sample size
per second (the smaller of bulk and tail ESS over every reported quantity).

Run: ``python benchmarks/fit_speed.py [--repeats 3]``.

*Cold* is a fresh Python process with the persistent compilation cache
disabled (``BAYESCAL_NO_CACHE=1``): import, trace, compile, fit.  *Cached* is
a fresh process with the persistent cache warm.  *Warm* is a repeated
``fit()`` in one process (the compiled program is reused; the median of
``--repeats`` calls).  All times are for the full ``bayescal.fit`` call
(model assembly, LSQ baseline, MAP, the backend, diagnostics, posterior
tree).  Results go to ``benchmarks/results/fit_speed.{csv,md}`` (``--out`` another stem,
``--backends lsq,nuts,blackjax`` a subset).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
BACKENDS = ("lsq", "laplace", "nuts", "blackjax", "emcee")

CHILD = """
import json, sys, time, warnings
t0 = time.perf_counter()
import bayescal as bc
spec = bc.load_spec(sys.argv[1]); design = bc.load_design(sys.argv[2])
table = bc.simulate(spec, design, seed=0).table
t1 = time.perf_counter()
with warnings.catch_warnings():
    warnings.simplefilter("ignore")
    bc.fit(table, spec, sys.argv[3], seed=0)
t2 = time.perf_counter()
print(json.dumps({"import_s": t1 - t0, "fit_s": t2 - t1}))
"""


def fresh_process(backend: str, cache: bool) -> float:
    env = dict(os.environ)
    env.pop("BAYESCAL_NO_CACHE", None)
    if not cache:
        env["BAYESCAL_NO_CACHE"] = "1"
    args = [
        sys.executable,
        "-c",
        CHILD,
        str(ROOT / "models/seed000_bayer.toml"),
        str(ROOT / "models/seed000_design.toml"),
    ]
    out = subprocess.run(args + [backend], env=env, capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])["fit_s"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--backends", default=",".join(BACKENDS), help="comma-separated, lsq first (the ratio's base)")
    parser.add_argument("--out", default="fit_speed", help="results stem under benchmarks/results")
    args = parser.parse_args()
    chosen = [b.strip() for b in args.backends.split(",") if b.strip()]

    import warnings

    import bayescal as bc

    spec = bc.load_spec(ROOT / "models/seed000_bayer.toml")
    design = bc.load_design(ROOT / "models/seed000_design.toml")
    table = bc.simulate(spec, design, seed=0).table
    rows = []
    for backend in chosen:
        cold = fresh_process(backend, cache=False)
        cached = fresh_process(backend, cache=True)
        warm, stages = [], {}
        for r in range(args.repeats + 1):
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                t = time.perf_counter()
                result = bc.fit(table, spec, backend, seed=r)
                dt = time.perf_counter() - t
            if r:  # the first in-process call may still compile
                warm.append(dt)
                stages = result.timings
        rows.append(
            {
                "backend": backend,
                "cold_s": cold,
                "cached_s": cached,
                "warm_s": float(np.median(warm)),
                "sampler_s": float(stages.get(backend, np.nan)),
                "min_ess": _min_ess(result),
                "ok": result.ok,
            }
        )
        print(rows[-1], flush=True)
    lsq = rows[0]["warm_s"]
    for row in rows:
        row["warm_ratio_to_lsq"] = row["warm_s"] / lsq
        row["ess_per_s_warm"] = row["min_ess"] / row["warm_s"]
    write(rows, spec, args.out)


def _min_ess(result) -> float:
    """The smaller of bulk and tail ESS (emcee: from its autocorrelation time; NaN without draws)."""
    d = result.diagnostics
    values = [getattr(d, k, None) for k in ("min_ess_bulk", "min_ess_tail")]
    values = [float(v) for v in values if v is not None and np.isfinite(v)]
    return min(values) if values and result.backend in ("nuts", "blackjax", "emcee") else float("nan")


def write(rows: list[dict], spec, stem: str = "fit_speed") -> None:
    import pandas as pd

    RESULTS.mkdir(parents=True, exist_ok=True)
    df = pd.DataFrame(rows)
    df.to_csv(RESULTS / f"{stem}.csv", index=False, float_format="%.4g")
    inf = spec.inference
    lines = [
        f"Seed 000 dataset (192 rows, 3 channels); NUTS {inf.chains} chains x {inf.draws} draws "
        f"(+{inf.warmup} warmup); emcee {inf.emcee_steps} steps (+{inf.emcee_burn} burn); "
        f"{os.cpu_count()} CPU cores.",
        "",
        "| backend | cold (no cache) s | fresh process, cached s | warm s | sampler only s | warm / lsq | min ESS "
        "| ESS / s (warm) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['backend']} | {r['cold_s']:.2f} | {r['cached_s']:.2f} | {r['warm_s']:.3f} | "
            f"{r['sampler_s']:.3f} | {r['warm_ratio_to_lsq']:.0f} | {r['min_ess']:.0f} | {r['ess_per_s_warm']:.0f} |"
        )
    (RESULTS / f"{stem}.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
