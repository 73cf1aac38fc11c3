"""The README's main command: ``bayescal demo`` on the embedded example, from any working directory."""

import json
import re

from bayescal.cli import main
from bayescal.io.resources import models_dir


def test_shipped_models_are_found():
    assert (models_dir() / "seed000_design.toml").is_file()
    assert (models_dir() / "seed000_bayer.toml").is_file()


def test_demo_runs_on_the_embedded_example(tmp_path, capsys, monkeypatch):
    """Run outside the repository (the package finds its shipped models); the printed absolute gain
    intervals hold the simulated camera's true gains."""
    monkeypatch.chdir(tmp_path)
    assert main(["demo", "--backend", "laplace", "--quiet"]) == 0
    out = tmp_path / "demo-out"
    assert json.loads((out / "summary.json").read_text())["status"] == "ok"
    assert (out / "report.html").stat().st_size > 10_000
    printed = capsys.readouterr().out
    truth = dict(re.findall(r"\b([RGB]) ([\d.]+)", printed.split("True gains", 1)[1].splitlines()[0]))
    assert sorted(truth) == ["B", "G", "R"]
    for channel, value in truth.items():
        row = re.search(rf"^\s+{channel}\s+A1\s.*\[([-\d.e]+), ([-\d.e]+)\]\s*$", printed, re.MULTILINE)
        lo, hi = float(row.group(1)), float(row.group(2))  # the last bracket: Bayes absolute
        assert lo <= float(value) <= hi, (channel, value, lo, hi)
