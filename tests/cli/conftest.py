from pathlib import Path

import pytest

import bayescal as bc
from bayescal.cli import main
from tests.conftest import MODELS


@pytest.fixture(scope="module")
def good_csv(tmp_path_factory, seed000):
    """A well-formed measurement table of the seed 000 camera (the model's own simulator), as a file."""
    spec, design = seed000
    path = tmp_path_factory.mktemp("data") / "good.csv"
    bc.simulate(spec, design, seed=3).table.write_csv(path)
    return path


def laplace_fit_folder(table: Path, out: Path) -> Path:
    """``bayescal fit TABLE --backend laplace --no-diagnose`` of the seed 000 spec into ``out``: a fit folder
    for the tests that read or break one (the diagnosis, which they do not exercise, is tested apart)."""
    argv = ["fit", str(table), "--model", str(MODELS / "seed000_bayer.toml"), "--backend", "laplace"]
    assert main([*argv, "--no-diagnose", "--out", str(out), "--quiet"]) == 0
    return out
