"""Draw the guides' figures (``docs/figures/``) from the shipped example, as a user would get them.

A Laplace fit of the seed-000 example campaign (``bayescal simulate --design seed000 --seed 1``, as in
getting started), its report with ``--figures``, the shipped raw frame inverted with it, the shipped
EMVA 1288 reference CCD characterised (and its image stacks' non-uniformity), the same campaign fitted
with too low an order (the misfit a wrong model shows), the film example's report, a simulated fleet's
report and the maps of a simulated sensor's stacks (each figure taken from the report's page as a user
sees it)::

    python docs/figures.py
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent / "figures"


def _run(*args: str, cwd: Path, check: bool = True) -> None:
    subprocess.run([sys.executable, "-m", "bayescal", *args], cwd=cwd, check=check)


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


def _report_figure(html: Path, alt: str, name: str) -> None:
    """Save the figure of a report page whose ``alt`` text starts with ``alt`` as ``name``."""
    import base64
    import re

    text = html.read_text()
    for found in re.finditer(r'<img alt="([^"]*)" src="data:image/png;base64,([^"]+)">', text):
        if found.group(1).startswith(alt):
            (HERE / name).write_bytes(base64.b64decode(found.group(2)))
            return
    raise SystemExit(f"{html} has no figure '{alt}'")


def _wrong_order(cwd: Path) -> None:
    """The seed-000 campaign fitted with a linear response (its truth is quadratic), no diagnosis."""
    _run("examples", "--copy", "seed000_bayer", cwd=cwd)
    spec = cwd / "seed000_bayer.toml"
    spec.write_text(spec.read_text().replace("order = 2 ", "order = 1 "))
    _run(
        "fit",
        "data.csv",
        "--model",
        str(spec),
        "--backend",
        "laplace",
        "--out",
        "linear",
        "--quiet",
        "--no-diagnose",
        cwd=cwd,
        check=False,
    )
    _run("report", "linear", "--figures", cwd=cwd)
    shutil.copyfile(cwd / "linear" / "report-misfit.png", HERE / "model-choice-misfit.png")


def _maps(cwd: Path) -> None:
    """Maps of a simulated 128 x 128 sensor (bayescal.validation.sensor: PRNU, DSNU, defects)."""
    from bayescal.validation.sensor import PixelSensor, write_stacks

    write_stacks(PixelSensor(height=128, width=128, defect_fraction=0.003), cwd / "stacks", seed=1)
    _run("maps", "stacks", "--out", "maps", "--report", cwd=cwd)
    _report_figure(cwd / "maps" / "maps_report.html", "", "maps-report.png")


def _nonuniformity(cwd: Path) -> None:
    """The reference CCD's 50-frame stacks (its 128 x 128 crop in the test data): the datasheet's
    histograms and spectrograms of the DSNU and PRNU images."""
    crop = Path(__file__).resolve().parent.parent / "tests/data/emva1288/refset001_ccd_12bit/crop128.npz"
    _run("characterize", str(crop), "--out", "ccd-stacks", cwd=cwd)
    _report_figure(cwd / "ccd-stacks" / "datasheet.html", "Non-uniformity histograms", "emva-histograms.png")
    _report_figure(cwd / "ccd-stacks" / "datasheet.html", "Non-uniformity spectrograms", "emva-spectrograms.png")


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
        _run(
            "invert", "fit", "seed000_frame.tif", "--cfa", "RGGB", "--exposure-s", "0.004", "--out", "radiance", cwd=cwd
        )
        _inversion(cwd)
        _run("characterize", "emva_refset001_steps", "--out", "ccd", cwd=cwd)
        shutil.copyfile(cwd / "ccd" / "photon_transfer.png", HERE / "emva-photon-transfer.png")
        _report_figure(cwd / "ccd" / "datasheet.html", "Signal-to-noise ratio", "emva-snr.png")
        _report_figure(cwd / "ccd" / "datasheet.html", "Linearity", "emva-linearity.png")
        _nonuniformity(cwd)
        _wrong_order(cwd)
        _run("examples", "--copy", "seed003", cwd=cwd)
        _run("fit", "seed003_film_example.csv", "--model", "seed003_film.toml", "--out", "film", "--quiet", cwd=cwd)
        _run("report", "film", cwd=cwd)
        _report_figure(cwd / "film" / "report.html", "characteristic curves", "film-curves.png")
        _run("fleet-simulate", "fleet", "--out", "fleet.csv", "--truth", "truth.csv", cwd=cwd)
        _run("fleet", "fleet.csv", "--model", "fleet", "--out", "fleet", "--report", "--quiet", cwd=cwd)
        _report_figure(cwd / "fleet" / "fleet_report.html", "", "fleet-report.png")
        _maps(cwd)
    print(f"wrote {sorted(p.name for p in HERE.glob('*.png'))}")


if __name__ == "__main__":
    main()
