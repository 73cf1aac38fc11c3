"""Ctrl-C at every stage of writing an output, the last second included: the old output or the
new one is left whole, the message says truthfully which, and nothing is left behind."""

import json
import os
import subprocess
import sys

import pytest

from bayescal.cli import main
from bayescal.io.outputs import MARKER, verify_output
from tests.conftest import MODELS

SPEC = str(MODELS / "seed000_bayer.toml")

#: runs the CLI with a SIGINT raised at one named point of writing the output
SCRIPT = """
import signal, sys
from bayescal.io.outputs import interrupts
from bayescal.cli import main

def checkpoint(name):
    if name == sys.argv[1]:
        signal.raise_signal(signal.SIGINT)

interrupts.checkpoint = checkpoint
sys.exit(main(sys.argv[2:]))
"""


def _run_id(folder):
    return json.loads((folder / MARKER).read_text())["run_id"]


@pytest.mark.parametrize(
    ("stage", "replaced"),
    [
        ("staged", False),  # the new files are written, not yet in place
        ("swap", True),  # between moving the old folder away and the new one in: held back to the end
        ("committed", True),  # the new output in place, the old one not yet removed
        ("cleaned", True),  # the last moment of writing; the command is about to print and exit
    ],
)
def test_ctrl_c_leaves_one_whole_output_and_says_which(tmp_path, good_csv, stage, replaced):
    out = tmp_path / "fit"
    assert main(["fit", str(good_csv), "--model", SPEC, "--backend", "lsq", "--out", str(out), "--quiet"]) == 0
    old = _run_id(out)
    cmd = [sys.executable, "-c", SCRIPT, stage, "fit", str(good_csv), "--model", SPEC, "--backend", "lsq"]
    proc = subprocess.run(
        cmd + ["--out", str(out), "--quiet"],
        capture_output=True,
        text=True,
        timeout=300,
        env=dict(os.environ, PYTHONUNBUFFERED="1"),
    )
    assert proc.returncode == 130, proc.stderr
    assert "Traceback" not in proc.stderr
    info = verify_output(out, ("fit",), needs=("summary.json", "lsq.csv"))  # whole: every listed file as written
    assert (info.run_id != old) == replaced
    if replaced:
        assert f"interrupted after the output was put in place, whole: {out}/" in proc.stderr
    else:
        assert "no output was written or replaced" in proc.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fit"]  # no staging, no old folder
