"""The example notebooks run top to bottom (Laplace backend for speed) and their key cells hold numbers."""

from pathlib import Path

import nbformat
import pytest
from nbclient import NotebookClient

NOTEBOOKS = Path(__file__).resolve().parents[2] / "notebooks"


def _run(name: str, monkeypatch) -> nbformat.NotebookNode:
    monkeypatch.setenv("BAYESCAL_NB_BACKEND", "laplace")
    nb = nbformat.read(NOTEBOOKS / name, as_version=4)
    NotebookClient(nb, timeout=600, kernel_name="python3", resources={"metadata": {"path": str(NOTEBOOKS)}}).execute()
    return nb


def _text(nb) -> str:
    out = []
    for cell in nb.cells:
        for o in cell.get("outputs", []):
            if o.get("output_type") == "error":
                pytest.fail(f"{o['ename']}: {o['evalue']}")
            out.append(o.get("text", "") or o.get("data", {}).get("text/plain", ""))
    return "\n".join(out)


def test_quickstart_runs(monkeypatch):
    text = _text(_run("quickstart_seed000.ipynb", monkeypatch))
    assert "ok | timings" in text and "report.html" in text
    assert "true A1  30.180" in text


@pytest.mark.slow  # executed in the slow suite; the quickstart runs in the default one
def test_seed002_notebook_runs(monkeypatch):
    text = _text(_run("seed002_tdi_planning.ipynb", monkeypatch))
    assert "405 DN -> E = 0.11664" in text
    assert "eq. 12 at M = 96, g = 1.26: 899.8 DN" in text


@pytest.mark.slow
def test_ccd_notebook_runs(monkeypatch):
    text = _text(_run("ccd_emva1288.ipynb", monkeypatch))
    assert "compatible: True" in text
    assert "K                  ours    0.28006   reference    0.28006" in text


@pytest.mark.slow
def test_pixel_maps_notebook_runs(monkeypatch):
    text = _text(_run("pixel_maps_emva1288.ipynb", monkeypatch))
    assert "PRNU standard, crop 0.2641 %" in text
    assert "PRNU1288_pixel, full frame (reference implementation) 0.2652 %" in text


def test_every_notebook_uses_the_public_api_and_shows_a_plot():
    """A notebook teaches what a user can write: ``import bayescal as bc`` and ``bc.NAME``, no module of the
    package's insides; and each draws at least one figure (its committed outputs hold a PNG)."""
    import re

    for path in sorted(NOTEBOOKS.glob("*.ipynb")):
        nb = nbformat.read(path, as_version=4)
        code = "\n".join(cell.source for cell in nb.cells if cell.cell_type == "code")
        assert not re.search(r"^\s*(from|import) bayescal\.", code, re.M), path.name
        pngs = [o for c in nb.cells for o in c.get("outputs", []) if "image/png" in o.get("data", {})]
        assert pngs, f"{path.name} shows no plot"
