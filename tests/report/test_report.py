"""Report: numbers equal summary.json, a failed fit is flagged, and the HTML renders in headless Chromium."""

import json
import re
import shutil
import subprocess

import numpy as np
import pytest

import bayescal as bc
from bayescal.cli import main
from bayescal.report.html import write_report


@pytest.fixture(scope="module")
def report_dir(seed000, tmp_path_factory):
    spec, design = seed000
    sim = bc.simulate(spec, design, seed=31)
    out = tmp_path_factory.mktemp("fit")
    bc.fit(sim.table, spec, "laplace", seed=31).save(out)
    assert main(["report", str(out)]) == 0
    return out


def test_report_numbers_equal_summary(report_dir):
    summary = json.loads((report_dir / "summary.json").read_text())
    report = json.loads((report_dir / "report.json").read_text())
    params = {p["parameter"]: p for p in summary["parameters"]}
    assert report["status"] == summary["status"] == "ok"
    for row in report["coefficients"]:
        p = params[f"A_abs[{row['channel']}, {row['coefficient'][1:]}]"]
        assert (row["mean"], row["q2.5"], row["q97.5"]) == (p["mean"], p["q2.5"], p["q97.5"])
    lsq = {(r["channel"], r["order"]): r for r in summary["lsq"] if r["exposure_s"] == 0.004 and r["gain"] == 1.0}
    for row in report["lsq_at_reference"]:
        assert row["r2"] == lsq[(row["channel"], row["order"])]["r2"]
        assert row["A1"] == lsq[(row["channel"], row["order"])]["A1"]
    html = (report_dir / "report.html").read_text()
    g1 = params["A_abs[G, 1]"]
    for value in (g1["mean"], g1["q2.5"], g1["q97.5"]):
        assert f"{value:.5g}" in html
    assert html.count("data:image/png;base64,") == 5  # coefficients, response, residuals, misfit, budget (no chains)
    assert "no chains to compare" in html
    md = (report_dir / "report.md").read_text()
    assert f"{g1['mean']:.5g}" in md
    # the budget's shares add up, and the sphere dominates bright pixels (3 % vs sub-percent noise)
    budget = report["uncertainty_budget"]
    for row in budget:
        assert row["share_parameters"] + row["share_sphere"] + row["share_noise"] == pytest.approx(1.0, abs=0.05)
    bright = [r for r in budget if r["dn"] > 3000]
    assert all(r["share_sphere"] > 0.5 for r in bright)


def test_failed_fit_is_flagged(seed000, tmp_path):
    spec, design = seed000
    sim = bc.simulate(spec, design, seed=32)
    short = spec.replace(inference={"chains": 2, "draws": 20, "warmup": 20})
    with pytest.warns(bc.FitFailedWarning):
        fit = bc.fit(sim.table, short, "nuts", seed=1)
    fit.save(tmp_path)
    write_report(tmp_path)
    html = (tmp_path / "report.html").read_text()
    assert 'class="failed"' in html and "FIT FAILED" in html and "Do not use these numbers" in html
    assert html.count("data:image/png;base64,") == 7 and 'alt="rank plots"' in html  # NUTS: arviz's chain plots
    assert json.loads((tmp_path / "report.json").read_text())["status"] == "FAILED"


def _chromium() -> str | None:
    return next((p for p in map(shutil.which, ("chromium", "chromium-browser", "google-chrome")) if p), None)


def test_report_renders_in_headless_chromium(report_dir):
    browser = _chromium()
    if browser is None:
        pytest.skip("no Chromium installed (.ci/run installs the Debian package); the browser check did not run")
    url = (report_dir / "report.html").as_uri()
    flags = ["--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars"]
    shot = report_dir / "screenshot.png"
    subprocess.run(
        [browser, *flags, f"--screenshot={shot}", "--window-size=1400,2400", url],
        check=True,
        capture_output=True,
        timeout=120,
    )
    dom = subprocess.run(
        [browser, *flags, "--dump-dom", url], check=True, capture_output=True, text=True, timeout=120
    ).stdout
    # every embedded figure decoded (the page's own check after load), key numbers present in the rendered DOM
    n_images = (report_dir / "report.html").read_text().count("data:image/png;base64,")
    assert n_images == 5 and re.search(rf'data-images="{n_images}/{n_images}"', dom), "broken or missing images"
    summary = json.loads((report_dir / "summary.json").read_text())
    g1 = next(p for p in summary["parameters"] if p["parameter"] == "A_abs[G, 1]")
    assert f"{g1['mean']:.5g}" in dom and "Diagnostics passed" in dom
    from PIL import Image

    img = np.asarray(Image.open(shot).convert("L"), dtype=float)
    assert img.shape[0] >= 2000 and img.std() > 10  # not a blank page


def test_report_leaves_matplotlib_state_alone(report_dir, tmp_path):
    """Writing a report neither switches the user's matplotlib backend nor leaves pyplot figures open."""
    import matplotlib
    import matplotlib.pyplot as plt

    before = matplotlib.get_backend()
    plt.switch_backend("svg")  # a user's own choice, and not the Agg that headless runs default to
    try:
        figures = plt.get_fignums()
        write_report(report_dir, tmp_path / "again.html")
        assert matplotlib.get_backend() == "svg" and plt.get_fignums() == figures
    finally:
        plt.switch_backend(before)


def test_import_changes_no_global_state():
    """``import bayescal`` (and the CLI's parser) leave JAX's precision, its compilation cache and matplotlib's
    backend as they were; float64 is switched on where bayescal computes (a fit), not on import."""
    code = (
        "import json, jax, matplotlib\n"
        "state = lambda: [jax.config.jax_enable_x64, jax.config.jax_compilation_cache_dir, matplotlib.get_backend()]\n"
        "before = state()\n"
        "import bayescal, bayescal.cli\n"
        "bayescal.__version__\n"
        "print(json.dumps([before, state()]))\n"
    )
    import sys

    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=120)
    before, after = json.loads(out.stdout.strip().splitlines()[-1])
    assert before == after and before[0] is False, (before, after)


def test_the_figures_are_written_as_pngs_beside_the_report(report_dir, tmp_path):
    """``--figures``: each figure the page embeds is also a PNG file (a Laplace fit has no chains, so no
    trace or rank plot), the same image as the page's; a PNG of the user's named like one is refused
    before any drawing."""
    import base64

    from bayescal.report.html import figure_paths

    out = tmp_path / "cal.html"
    assert main(["report", str(report_dir), "--out", str(out), "--figures"]) == 0
    written = sorted(p.name for p in tmp_path.glob("cal-*.png"))
    assert written == [
        "cal-budget.png",
        "cal-coefficients.png",
        "cal-misfit.png",
        "cal-residuals.png",
        "cal-response.png",
    ]
    page = out.read_text()
    for path in figure_paths(out)[:5]:
        assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        assert base64.b64encode(path.read_bytes()).decode() in page  # the page's own image
    mine = tmp_path / "other"
    mine.mkdir()
    (mine / "r-response.png").write_bytes(b"a figure of my own")
    assert main(["report", str(report_dir), "--out", str(mine / "r.html"), "--figures"]) == 2
    assert (mine / "r-response.png").read_bytes() == b"a figure of my own" and not (mine / "r.html").exists()
