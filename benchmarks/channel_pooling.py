"""Pooling the colour channels of one camera: does it sample, does it cover, does it help?

Run: ``python benchmarks/channel_pooling.py [--seeds 16]``.

Datasets come from :mod:`bayescal.validation.bench` (written apart from the model), the
seed-000 camera and bench, in two cases: the bench's own compression, the same per DN in
every channel (the sense node is shared: the channels' nonlinearities agree, the pooling sd
is near zero), and one whose channels compress differently per DN (the pooling sd is large).
Each dataset is fitted with NUTS by the shipped seed-000 spec (channels unpooled) and by the
same spec with ``response.pooled`` and ``dark.pooled`` on, as one ``fit_many`` batch each.
Per case and model: fits that pass their diagnostics, divergences left, reruns, coverage of
the 95 % intervals of the sphere-relative ``A0, A1, A2`` at the reference setting (3
channels) and of ``A2`` alone, per channel the median width of the ``A2`` interval and the RMSE
of its median against the unpooled fits of the same datasets, and the wall time of the batch
against the unpooled batch's.
Writes ``benchmarks/results/channel_pooling.{csv,md}``.
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
from bayescal.validation import BenchCamera, simulate_bench

OUT = Path(__file__).resolve().parent / "results"
SPEC = Path(__file__).resolve().parent.parent / "models" / "seed000_bayer.toml"
#: DN per (W m^-2 sr^-1)^2 at gain 1: the bench's own (the same per DN: -0.012 / 62.09^2 ~ -0.003 / 30.18^2),
#: and channels that differ per DN by a factor of ~4 either way
CASES = {
    "nonlinearity shared (bench default)": BenchCamera(),
    "nonlinearity differs by channel": BenchCamera(compression={"R": -0.012, "G": -0.0008, "B": -0.003}),
}


def one_batch(camera: BenchCamera, spec, seeds: list[int]) -> tuple[dict, list[dict]]:
    data = [simulate_bench(camera, seed=s) for s in seeds]
    tables = [bc.MeasurementTable.from_frame(frame) for frame, _ in data]
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        batch = bc.fit_many(tables, spec, "nuts", seeds=seeds)
        fits = [batch.fit(i) for i in range(len(seeds))]
    seconds = time.perf_counter() - t0
    rows = []
    for fit, (_, real), seed in zip(fits, data, seeds, strict=True):
        rel = fit.draws("A_rel")
        for ci, c in enumerate(fit.model.layout.channels):
            truth = real.true_coefficients(c, relative=True)
            lo, hi = np.quantile(rel[:, ci, :3], [0.025, 0.975], axis=0)
            rows.append(
                {
                    "seed": seed,
                    "channel": c,
                    "ok": fit.ok,
                    "divergences": fit.diagnostics.divergences,
                    "rerun": "retried" in fit.diagnostics.extra,
                    "hit": (lo <= truth) & (truth <= hi),
                    "a2_width": hi[2] - lo[2],
                    "a2_error": float(np.median(rel[:, ci, 2]) - truth[2]),
                }
            )
    return {"seconds": seconds}, rows


def summarise(case: str, model: str, timing: dict, rows: list[dict], base: pd.DataFrame | None) -> dict:
    df = pd.DataFrame(rows)
    hits = np.stack(df["hit"].to_numpy())
    fits = df.drop_duplicates("seed")
    out = {
        "case": case,
        "model": model,
        "datasets": len(fits),
        "ok": int(fits["ok"].sum()),
        "divergences_left": int(fits["divergences"].sum()),
        "reruns": int(fits["rerun"].sum()),
        "coverage_A0_A1_A2": float(hits.mean()),
        "coverage_A2": float(hits[:, 2].mean()),
        "seconds": timing["seconds"],
    }
    if base is not None:
        ratio = df["a2_width"].to_numpy() / base["a2_width"].to_numpy()
        for c in sorted(set(df["channel"]), key=list(df["channel"]).index):
            here, there = df["channel"] == c, base["channel"] == c
            out[f"a2_width_vs_unpooled_{c}"] = float(np.median(ratio[here.to_numpy()]))
            out[f"a2_rmse_vs_unpooled_{c}"] = float(
                np.sqrt(np.mean(df.loc[here, "a2_error"] ** 2) / np.mean(base.loc[there, "a2_error"] ** 2))
            )
        out["seconds_vs_unpooled"] = out["seconds"] / base.attrs["seconds"]
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seeds", type=int, default=16, help="bench datasets per case")
    args = p.parse_args()
    unpooled = bc.load_spec(SPEC)
    pooled = unpooled.replace(response={"pooled": True}, dark={"pooled": True})
    seeds = [20_000 + i for i in range(args.seeds)]
    results = []
    for case, camera in CASES.items():
        timing, rows = one_batch(camera, unpooled, seeds)
        results.append(summarise(case, "unpooled", timing, rows, None))
        base = pd.DataFrame(rows)
        base.attrs["seconds"] = timing["seconds"]
        print(results[-1], flush=True)
        timing, rows = one_batch(camera, pooled, seeds)
        results.append(summarise(case, "pooled", timing, rows, base))
        print(results[-1], flush=True)
    OUT.mkdir(exist_ok=True)
    table = pd.DataFrame(results)
    table.to_csv(OUT / "channel_pooling.csv", index=False)
    (OUT / "channel_pooling.md").write_text(
        "# Pooling the colour channels of one camera (NUTS, independent bench)\n\n"
        f"{args.seeds} bench datasets per case (seed-000 camera, 3 channels, 12 levels); "
        "coverage of the 95 % intervals of A0, A1, A2 (sphere-relative, reference setting) and of "
        "A2 alone; per channel, the median width of A2's interval and the RMSE of its median against "
        "the unpooled fits of the same datasets; "
        "wall time of each `fit_many` batch (2 cores).\n\n" + markdown_table(table) + "\n"
    )


if __name__ == "__main__":
    main()
