"""EMVA 1288 on quantisation-limited sensors: do K and QE cover on 8- and 10-bit sensors?

Run: ``python benchmarks/emva_lowbit.py [--sensors 300] [--seed 0]``.

Sensors come from :mod:`bayescal.validation.lowbit`, written from the standard's sensor model
apart from the characterisation (pixel by pixel: Poisson electrons, Gaussian read noise, the
system gain, per-pixel offsets and gains, rounding to integer codes, clipping): 8 or 10 bits,
dark noise 0.2-1 DN, full wells 3,000-40,000 e-, QE 30-80 %, offsets 2-12 DN, DSNU
0.05-1.5 DN, PRNU 0.3-1.5 %; every third sensor measured as an illumination sweep (one dark
pair for all bright pairs), the others as exposure sweeps.  The first sensor is the default
8-bit CMOS sensor (K 0.0206 DN/e-, QE 55 %, 0.33 DN of dark noise, dark level at a half code).
Per sensor: the standard's K and QE, the posterior median and 95 % interval, and whether the
characterisation reported a problem.  Writes ``benchmarks/results/emva_lowbit.{csv,md}``.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd

from bayescal.characterization.emva1288 import characterize
from bayescal.io.emva import load_steps
from bayescal.report.text import markdown_table
from bayescal.validation.lowbit import LowBitSensor, random_lowbit, real_8bit, simulate_lowbit

OUT = Path(__file__).resolve().parent / "results"


def run(n: int, seed: int, concave: int = 0) -> pd.DataFrame:
    """``n`` linear sensors (the default 8-bit one first), then ``concave`` sensors with a V/Q knee (the real
    8-bit sensor first, :func:`~bayescal.validation.lowbit.real_8bit`), drawn from a generator of their own."""
    rng = np.random.default_rng(seed)
    bent = np.random.default_rng([seed, 0xBE7])
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(n + concave):
            if i < n:
                sensor = LowBitSensor() if i == 0 else random_lowbit(rng)
            else:
                sensor = real_8bit() if i == n else _knee(random_lowbit(bent), bent)
            layout = "illumination" if i % 3 == 2 else "exposure"
            table, truth = simulate_lowbit(sensor, layout=layout, seed=seed * 100_000 + i)
            path = Path(tmp) / "steps.csv"
            table.to_csv(path, index=False)
            res = characterize(load_steps(path), seed=i)
            t = res.table.set_index("quantity")
            row = {
                "sensor": i,
                "bits": sensor.bits,
                "layout": layout,
                "concave": bool(np.isfinite(sensor.knee_e)),
                "module": res.module,
                "sigma_y_dark_dn": sensor.sigma_y_dark,
                "dsnu_dn": sensor.dsnu_dn,
                "problems": len(res.problems),
            }
            for q in ("K", "QE"):
                row |= {
                    f"{q}_true": truth[q],
                    f"{q}_standard": t.loc[q, "standard"],
                    f"{q}_median": t.loc[q, "median"],
                    f"{q}_lo": t.loc[q, "q2.5"],
                    f"{q}_hi": t.loc[q, "q97.5"],
                }
                row[f"{q}_covered"] = bool(row[f"{q}_lo"] <= truth[q] <= row[f"{q}_hi"])
            rows.append(row)
    return pd.DataFrame(rows)


def _knee(sensor: LowBitSensor, rng: np.random.Generator) -> LowBitSensor:
    """``sensor`` with a V/Q knee that takes 10-30 % off the conversion gain at full scale."""
    full_q = (sensor.full_scale - sensor.offset_dn) / sensor.k
    drop = rng.uniform(0.10, 0.30)  # the slope at full scale is (1 - drop) of the small-signal one
    return replace(sensor, knee_e=full_q / (1.0 / np.sqrt(1.0 - drop) - 1.0))


def concave_summary(df: pd.DataFrame) -> str:
    """On the concave sensors: K and QE flagged not determinable (General), covered, or tight and wrong."""
    part = df[df.concave]
    if not len(part):
        return ""
    general = part["module"] == "General"
    covered = ~general & part["K_covered"] & part["QE_covered"]
    wrong = ~general & ~covered
    first = part.iloc[0]
    return (
        f"\n{len(part)} concave sensors (a V/Q knee taking 10-30 % off the conversion gain at full scale; the first "
        "is the real 8-bit sensor's features, `real_8bit`): K and QE reported as not determinable (Release 4 "
        f"General) on {int(general.sum())}, covering the small-signal truth on {int(covered.sum())}, tight and wrong "
        f"on {int(wrong.sum())}.  The real 8-bit sensor's features (small-signal K 0.0245 DN/e-, QE 55 %): module "
        f"{first.module}.\n"
    )


def summary(df: pd.DataFrame) -> pd.DataFrame:
    out = []
    for name, part in [("all", df), *((f"{b}-bit", df[df.bits == b]) for b in (8, 10))]:
        for q in ("K", "QE"):
            cover = (part[f"{q}_covered"] & (part["module"] == "Linear")).mean()
            rel = (part[f"{q}_median"] / part[f"{q}_true"] - 1).abs()
            std = (part[f"{q}_standard"] / part[f"{q}_true"] - 1).abs()
            width = ((part[f"{q}_hi"] - part[f"{q}_lo"]) / part[f"{q}_true"]).median()
            out.append(
                {
                    "sensors": name,
                    "quantity": q,
                    "n": len(part),
                    "coverage": cover,
                    "mc_sd": float(np.sqrt(cover * (1 - cover) / len(part))),
                    "median relative error, posterior": rel.median(),
                    "median relative error, standard": std.median(),
                    "median 95 % width / truth": width,
                    "problems reported": int((part.problems > 0).sum()),
                }
            )
    return pd.DataFrame(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sensors", type=int, default=300)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--concave", type=int, default=60, help="sensors with a V/Q knee after the linear ones")
    args = ap.parse_args()
    t0 = time.perf_counter()
    df = run(args.sensors, args.seed, args.concave)
    elapsed = time.perf_counter() - t0
    OUT.mkdir(exist_ok=True)
    df.to_csv(OUT / "emva_lowbit.csv", index=False, float_format="%.6g")
    s = summary(df[~df.concave])
    first = df.iloc[0]
    text = (  # no title: the docs include the file as it is (docs/validation/index.md)
        f"{args.sensors} simulated 8- and 10-bit sensors (`benchmarks/emva_lowbit.py --sensors {args.sensors} "
        f"--seed {args.seed}`, {elapsed:.0f} s): coverage of the 95 % intervals of K and QE, with its Monte Carlo "
        "sd, and the median relative error of the posterior median and of the standard's estimate.\n\n"
        + markdown_table(s)
        + "\n\nThe default 8-bit sensor (K 0.0206 DN/e-, QE 55 %, dark noise 0.33 DN at a half code): "
        f"K {first.K_median:.4g} [{first.K_lo:.4g}, {first.K_hi:.4g}] (standard {first.K_standard:.4g}), "
        f"QE {first.QE_median:.3g} % [{first.QE_lo:.3g}, {first.QE_hi:.3g}] (standard {first.QE_standard:.3g} %).  "
        f"Linear sensors taken for General (a false alarm): {int((df[~df.concave].module == 'General').sum())}.\n"
        + concave_summary(df)
    )
    (OUT / "emva_lowbit.md").write_text(text)
    print(text)


if __name__ == "__main__":
    main()
