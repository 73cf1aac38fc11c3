"""The real 12-bit EMVA 1288 reference CCD (data set 001, central 128 x 128 crop) read at 8 bits.

Every frame is divided by 16 and truncated to uint8, as an 8-bit readout of the same sensor would
deliver it: the dark noise (3.07 DN at 12 bits) falls to 0.19 DN, below the quantisation step.  The
reference implementation's values at 12 bits give the truth at 8 bits: K / 16, QE and sigma_d
unchanged.  ``bayescal characterize`` is run on the requantised crop and each quantity's interval
compared with that truth.

    python benchmarks/emva_requantised.py

Writes ``benchmarks/results/emva_requantised.md``.
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
SET = ROOT / "tests" / "data" / "emva1288" / "refset001_ccd_12bit"
STEP = 16


def main() -> None:
    ref = json.loads((SET / "emva1288_reference_results.json").read_text())["emva1288_results"]
    truth = {
        "K": ref["K"] / STEP,
        "QE": ref["QE"],
        "sigma_d": ref["sigma_d"],
        "sigma_y_dark": ref["sigma_y_dark"] / STEP,
    }
    with tempfile.TemporaryDirectory() as tmp:
        arrays = dict(np.load(SET / "crop128.npz"))
        for key in ("bright_pairs", "dark_pairs", "bright_stack", "dark_stack"):
            arrays[key] = (arrays[key] // STEP).astype(np.uint8)
        arrays["bits"] = np.int64(8)
        np.savez(Path(tmp) / "crop8.npz", **arrays)
        run = subprocess.run(
            [sys.executable, "-m", "bayescal", "characterize", str(Path(tmp) / "crop8.npz"), "--out", f"{tmp}/out"],
            capture_output=True,
            text=True,
        )
        table = pd.read_csv(f"{tmp}/out/characterization.csv").set_index("quantity") if run.returncode == 0 else None
    lines = [
        "# The reference CCD read at 8 bits",
        "",
        f"`bayescal characterize` on the 12-bit crop divided by {STEP}: exit {run.returncode}.",
        "",
        "| quantity | truth (12-bit reference) | standard | posterior median [95 %] | covers |",
        "|---|---|---|---|---|",
    ]
    for name, value in truth.items():
        if table is None:
            break
        r = table.loc[name]
        covers = r["q2.5"] <= value <= r["q97.5"]
        lines.append(
            f"| {name} | {value:.4g} | {r['standard']:.4g} | {r['median']:.4g} [{r['q2.5']:.4g}, {r['q97.5']:.4g}] "
            f"| {'yes' if covers else 'NO'} |"
        )
    text = "\n".join(lines) + "\n"
    (ROOT / "benchmarks" / "results" / "emva_requantised.md").write_text(text)
    print(text)


if __name__ == "__main__":
    main()
