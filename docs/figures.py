"""Draw the guides' figures (``docs/figures/``) from the shipped example, as a user would get them.

A Laplace fit of the seed-000 example campaign (``bayescal simulate --design seed000 --seed 1``, as in
getting started), its report with ``--figures``, the shipped raw frame inverted with it, and the
shipped EMVA 1288 reference CCD characterised::

    python docs/figures.py
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent / "figures"


def _run(*args: str, cwd: Path) -> None:
    subprocess.run([sys.executable, "-m", "bayescal", *args], cwd=cwd, check=True)


def _inversion(cwd: Path) -> None:
    """The shipped frame's median radiance and its 95 % interval's relative width, side by side."""
    import numpy as np
    import tifffile
    from matplotlib.figure import Figure

    median, lower, upper = (tifffile.imread(cwd / "radiance" / f"{b}.tif") for b in ("median", "lower", "upper"))
    fig = Figure(figsize=(9, 3.2))
    left, right = fig.subplots(1, 2)
    shown = left.imshow(median, cmap="magma")
    fig.colorbar(shown, ax=left, label="radiance (W m$^{-2}$ sr$^{-1}$), median")
    left.set_title("seed000_frame.tif inverted")
    width = right.imshow((upper - lower) / np.where(median > 0, median, np.nan), cmap="viridis")
    fig.colorbar(width, ax=right, label="95 % interval / median")
    right.set_title("its doubt, pixel by pixel")
    for ax in (left, right):
        ax.set(xticks=[], yticks=[])
    fig.tight_layout()
    fig.savefig(HERE / "invert-frame.png", dpi=110)


def main() -> None:
    HERE.mkdir(exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        cwd = Path(tmp)
        _run("simulate", "--design", "seed000", "--out", "data.csv", "--seed", "1", cwd=cwd)
        _run("fit", "data.csv", "--model", "seed000", "--backend", "laplace", "--out", "fit", "--quiet", cwd=cwd)
        _run("report", "fit", "--figures", cwd=cwd)
        for name in ("coefficients", "response", "residuals", "misfit"):
            shutil.copyfile(cwd / "fit" / f"report-{name}.png", HERE / f"report-{name}.png")
        _run("examples", "--copy", "seed000_frame", cwd=cwd)
        _run("invert", "fit", "seed000_frame.tif", "--cfa", "RGGB", "--exposure-s", "0.004", "--out", "radiance", cwd=cwd)
        _inversion(cwd)
        _run("characterize", "emva_refset001_steps", "--out", "ccd", cwd=cwd)
        shutil.copyfile(cwd / "ccd" / "photon_transfer.png", HERE / "emva-photon-transfer.png")
    print(f"wrote {sorted(p.name for p in HERE.glob('*.png'))}")


if __name__ == "__main__":
    main()
