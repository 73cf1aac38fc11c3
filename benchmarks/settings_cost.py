"""What the setting factors cost: warm fits of the seed 000 example with and without them, same run.

Run: ``python benchmarks/settings_cost.py [--repeats 5]``.  Writes
``benchmarks/results/settings_cost.md``: per backend, the median warm ``bayescal.fit`` time with
the factors (default tolerances) and with exact settings (tolerances 0), and their ratio.
"""

from __future__ import annotations

import argparse
import time
import warnings
from pathlib import Path

import numpy as np

import bayescal as bc

ROOT = Path(__file__).resolve().parent.parent


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--repeats", type=int, default=5)
    args = p.parse_args()
    spec = bc.load_spec(ROOT / "models" / "seed000_bayer.toml")
    design = bc.load_design(ROOT / "models" / "seed000_design.toml")
    table = bc.simulate(spec, design, seed=1).table
    exact = spec.replace(settings={"gain_tolerance": 0.0, "exposure_tolerance": 0.0, "tdi_tolerance": 0.0})
    lines = [
        "| backend | with setting factors s | exact settings s | ratio | parameters with / without |",
        "|---|---|---|---|---|",
    ]
    for backend in ("laplace", "nuts"):
        times = {}
        dims = {}
        for name, s in (("factors", spec), ("exact", exact)):
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                bc.fit(table, s, backend, seed=1)  # compile
                runs = []
                for r in range(args.repeats):
                    t0 = time.perf_counter()
                    fit = bc.fit(table, s, backend, seed=r)
                    runs.append(time.perf_counter() - t0)
            times[name] = float(np.median(runs))
            from bayescal.inference.program import program_for

            dims[name] = program_for(fit.model).dim
        ratio = times["factors"] / times["exact"]
        t_f, t_e, d_f, d_e = times["factors"], times["exact"], dims["factors"], dims["exact"]
        lines.append(f"| {backend} | {t_f:.3f} | {t_e:.3f} | {ratio:.2f} | {d_f} / {d_e} |")
        print(lines[-1], flush=True)
    out = ROOT / "benchmarks" / "results" / "settings_cost.md"
    out.write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
