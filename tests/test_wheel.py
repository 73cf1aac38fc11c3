"""The built wheel installs into a clean environment and works there (issue: adoptable as a library).

Slow suite: it builds the wheel, creates a new virtual environment from the interpreter that runs the
tests (none of the test environment's packages visible), installs the wheel with the core dependencies
only (from the package index, pinned by ``.ci/constraints.txt``), and runs ``bayescal demo`` and ``python -m
bayescal --help`` from a folder outside the repository.
"""

import json
import re
import shlex
import subprocess
import sys
import venv
import zipfile
from pathlib import Path

import pytest

from tests.cli.test_docs_commands import GUIDES, _blocks
from tests.conftest import ROOT

pytestmark = pytest.mark.slow


def _run(cmd: list, cwd: Path, timeout: float = 900) -> subprocess.CompletedProcess:
    done = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, timeout=timeout)
    assert done.returncode == 0, f"{cmd}: exit {done.returncode}\n{done.stdout[-3000:]}\n{done.stderr[-3000:]}"
    return done


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("dist")
    built = _run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-v", "-w", str(out), str(ROOT)], cwd=out)
    # no packaging warning (a data folder that Python sees as a package must be listed as one)
    assert "Package would be ignored" not in built.stdout + built.stderr
    (found,) = out.glob("bayescal-*.whl")
    return found


def test_the_wheel_carries_the_licences_and_the_examples(wheel):
    names = zipfile.ZipFile(wheel).namelist()
    licences = [n for n in names if ".dist-info/licenses/" in n]
    assert any(n.endswith("/LICENSE") for n in licences), licences
    # the notice of the CC BY-SA reference data shipped among the examples
    assert any(n.endswith("models/README.md") for n in licences), licences
    assert "bayescal/models/seed000_bayer.toml" in names and "bayescal/models/emva_refset001_steps.csv" in names
    assert "bayescal/__main__.py" in names and "bayescal/fitting/diagnosis/search.py" in names
    assert "bayescal/models/ccd_fits/flat00a.fits" in names
    # nothing of the repository's tests or benchmarks
    assert not [n for n in names if n.startswith(("tests/", "benchmarks/"))]


@pytest.fixture(scope="module")
def env_dir(wheel, tmp_path_factory) -> Path:
    """A new virtual environment with the wheel and its core dependencies alone installed."""
    env_dir = tmp_path_factory.mktemp("env")
    venv.EnvBuilder(with_pip=True, clear=True).create(env_dir)
    py = env_dir / "bin" / "python"
    _run([str(py), "-m", "pip", "install", "-q", "-c", str(ROOT / ".ci" / "constraints.txt"), str(wheel)], env_dir)
    return env_dir


def test_the_wheel_runs_the_demo_in_a_clean_environment(env_dir, tmp_path):
    py = env_dir / "bin" / "python"
    # the core only: none of the extras came with it
    extras = ("dask", "zarr", "emcee", "blackjax", "astropy")
    probe = f"import importlib.util as u; print([m for m in {extras!r} if u.find_spec(m)])"
    assert _run([str(py), "-c", probe], tmp_path).stdout.strip() == "[]"

    elsewhere = tmp_path / "lab"
    elsewhere.mkdir()
    helped = _run([str(py), "-m", "bayescal", "--help"], elsewhere)
    assert "fit a calibration model to a measurement table" in helped.stdout
    _run([str(env_dir / "bin" / "bayescal"), "demo", "--out", "demo", "--quiet"], elsewhere)
    summary = json.loads((elsewhere / "demo" / "summary.json").read_text())
    assert summary["status"] == "ok", summary["status"]
    assert (elsewhere / "demo" / "report.html").stat().st_size > 10_000


@pytest.mark.parametrize("page", ["README.md", *(f"docs/{g}" for g in GUIDES)])
def test_a_newcomer_runs_the_readme_and_every_guide_from_the_wheel(env_dir, tmp_path, page):
    """Every command of the README (after its set-up) and of each guide's runnable blocks, as written, by the
    installed ``bayescal`` of a clean environment, in a folder outside the repository: each ends in exit 0
    and writes what the page says it writes."""
    path = ROOT / page
    blocks = _blocks(path, marked=page != "README.md")
    if page == "README.md":  # the set-up lines are the clone's; the wheel stands in for them here
        blocks = [b for b in blocks if not any(line.startswith("bash .ci/setup") for line in b)]
    lines = [line for block in blocks for line in block]  # every runnable block, in the page's order
    assert lines, page
    lab = tmp_path / "lab"
    lab.mkdir()
    for line in lines:
        args = shlex.split(line)
        assert args[0] == "bayescal", line
        done = _run([str(env_dir / "bin" / "bayescal"), *args[1:]], lab)
        assert "Traceback" not in done.stderr, line
    written = {p.name for p in lab.iterdir()}
    promised = set(re.findall(r"--out ([\w./-]+)", " ".join(lines)))
    assert {Path(p).name for p in promised} <= written, (promised, written)
