"""Bad input ends in exit 2 with a message naming the file, row, column or key; outputs are never mixed.

Each case is a class of mistakes seen from users (wrong encodings, corrupt files, typos in keys,
impossible values, wrong paths), run through the command line as a user would.
"""

import json
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pandas as pd
import pytest

import bayescal as bc
from bayescal.cli import main
from tests.cli.conftest import laplace_fit_folder
from tests.conftest import MODELS

SPEC = str(MODELS / "seed000_bayer.toml")


@pytest.fixture(scope="module")
def fit_dir(tmp_path_factory, good_csv):
    out = tmp_path_factory.mktemp("fits") / "fit"
    return laplace_fit_folder(good_csv, out)


def _run(capsys, *argv) -> tuple[int, str]:
    try:
        rc = main([str(a) for a in argv])
    except SystemExit as exc:  # argparse's own errors
        rc = exc.code
    return rc, capsys.readouterr().err


def _frame(good_csv) -> pd.DataFrame:
    return pd.read_csv(good_csv)


def test_table_encodings_and_formats(tmp_path, good_csv, capsys):
    df = _frame(good_csv)
    df.to_csv(tmp_path / "utf16.csv", index=False, encoding="utf-16")  # with a BOM: accepted
    assert len(bc.load_table(tmp_path / "utf16.csv")) == len(df)
    df.assign(channel=df.channel.replace("G", "Grün")).to_csv(tmp_path / "latin1.csv", index=False, encoding="latin-1")
    rc, err = _run(capsys, "fit", tmp_path / "latin1.csv", "--model", SPEC, "--backend", "lsq", "--out", tmp_path / "o")
    assert rc == 2 and "latin1.csv: line" in err and "not UTF-8" in err
    (tmp_path / "bad.parquet").write_bytes(b"PAR1 not a parquet file")
    rc, err = _run(capsys, "fit", tmp_path / "bad.parquet", "--model", SPEC, "--out", tmp_path / "o")
    assert rc == 2 and "bad.parquet is not a readable Parquet file" in err
    rc, err = _run(capsys, "fit", tmp_path, "--model", SPEC, "--out", tmp_path / "o")
    assert rc == 2 and "expected a .csv or .parquet" in err
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize(
    ("edit", "expected"),
    [
        (lambda d: d.assign(dn_mean=500.0), "channel 'R' is 500 DN: the channel does not respond"),
        (
            lambda d: d.assign(dn_mean=np.where(d.index == 5, -3.0, d.dn_mean)),
            "row 6, column 'dn_mean': -3 is negative",
        ),
        (lambda d: d.assign(gain=np.where(d.index == 2, "two", d.gain)), "row 3, column 'gain': 'two' is not a number"),
        (lambda d: d.assign(exposure_s=np.where(d.index == 7, 0.0, d.exposure_s)), "row 8, column 'exposure_s'"),
        (lambda d: d.drop(columns="gain"), "column 'gain': missing required column"),
        (lambda d: d.iloc[:0], "has no data rows"),
    ],
)
def test_table_values(tmp_path, good_csv, capsys, edit, expected):
    edit(_frame(good_csv)).to_csv(tmp_path / "t.csv", index=False)
    rc, err = _run(capsys, "fit", tmp_path / "t.csv", "--model", SPEC, "--backend", "lsq", "--out", tmp_path / "o")
    assert rc == 2 and expected in err, err


def test_spec_and_design_keys(tmp_path, good_csv, capsys):
    text = (MODELS / "seed000_bayer.toml").read_text()
    (tmp_path / "utf16.toml").write_text(text.replace("\n", "\n# Grün\n", 1), encoding="latin-1")
    rc, err = _run(capsys, "fit", good_csv, "--model", tmp_path / "utf16.toml", "--out", tmp_path / "o")
    assert rc == 2 and "utf16.toml: line 2 is not UTF-8" in err
    (tmp_path / "warm.toml").write_text(text.replace("warmup = ", "warmup = -5 #"))
    rc, err = _run(capsys, "fit", good_csv, "--model", tmp_path / "warm.toml", "--out", tmp_path / "o")
    assert rc == 2 and "inference.warmup = -5; expected >= 10" in err
    design = (MODELS / "seed000_design.toml").read_text().replace("n_frames", "nframes")
    design = design.replace('spec = "seed000_bayer.toml"', f'spec = "{SPEC}"')
    (tmp_path / "design.toml").write_text(design)
    rc, err = _run(capsys, "simulate", "--design", tmp_path / "design.toml", "--out", tmp_path / "x.csv")
    assert rc == 2 and "unknown key(s) nframes (did you mean 'n_frames'?)" in err
    assert not (tmp_path / "x.csv").exists()
    rc, err = _run(capsys, "fit", good_csv, "--model", tmp_path, "--out", tmp_path / "o")
    assert rc == 2 and "is a directory; expected a model spec" in err


def test_arguments(fit_dir, good_csv, capsys):
    rc, err = _run(capsys, "select", good_csv, "--model", SPEC, "--orders", "1.5,2")
    assert rc == 2 and "expected response orders among 1,2,3,4" in err
    rc, err = _run(
        capsys, "plan", fit_dir, "--channel", "G", "--dn", "534", "--current", "0.004,1,1,1,1", "--exposures", "0.004"
    )
    assert rc == 2 and "1 to 4 numbers), got 5" in err
    rc, err = _run(capsys, "predict", fit_dir, "--exposure-s", "nan")
    assert rc == 2
    rc, err = _run(capsys, "invert", fit_dir, "--dn", "500,x", "--channel", "G")
    assert rc == 2 and "expected comma-separated numbers" in err


def test_corrupt_fit_directories(tmp_path, fit_dir, capsys):
    broken = tmp_path / "broken"
    broken.mkdir()
    for p in fit_dir.iterdir():  # a copy of the fit folder, its record of files included
        (broken / p.name).write_bytes(p.read_bytes())
    (broken / "posterior.nc").write_bytes((fit_dir / "posterior.nc").read_bytes()[:3000])
    rc, err = _run(capsys, "predict", broken, "--exposure-s", "0.01")
    assert rc == 2 and "posterior.nc is 3000 bytes where a calibration fit" in err and "truncated" in err
    lone = tmp_path / "lone.nc"  # a posterior file outside any output folder is read on its own
    lone.write_bytes(np.random.default_rng(0).bytes(5000))
    rc, err = _run(capsys, "invert", lone, "--dn", "500", "--channel", "G")
    assert rc == 2 and "not a readable posterior file" in err
    (broken / "posterior.nc").write_bytes((fit_dir / "posterior.nc").read_bytes())
    (broken / "summary.json").write_text("{bad")
    rc, err = _run(capsys, "report", broken)
    assert rc == 2 and "summary.json is 4 bytes where" in err
    rc, err = _run(capsys, "predict", tmp_path / "nowhere", "--exposure-s", "0.01")
    assert rc == 2 and "no posterior at" in err


def test_report_refuses_folders_of_two_runs_older_formats_and_fleets(tmp_path, good_csv, fit_dir, capsys):
    lsq = tmp_path / "lsq"
    assert _run(capsys, "fit", good_csv, "--model", SPEC, "--backend", "lsq", "--out", lsq)[0] == 0
    rc, err = _run(capsys, "report", lsq)
    assert rc == 2 and "holds a least-squares fit" in err
    (lsq / "posterior.nc").write_bytes((fit_dir / "posterior.nc").read_bytes())  # a Laplace posterior beside it
    for verb in (["report", lsq], ["predict", lsq, "--exposure-s", "0.01"]):
        rc, err = _run(capsys, *verb)
        assert rc == 2 and "posterior.nc was not written by the run that wrote" in err, err
    old = tmp_path / "old"  # an older release's fit folder: no record, a summary without seed or backend
    old.mkdir()
    (old / "summary.json").write_text(json.dumps({"status": "ok", "diagnostics": {"verdict": "ok"}}))
    (old / "posterior.nc").write_bytes((fit_dir / "posterior.nc").read_bytes())
    rc, err = _run(capsys, "report", old)
    assert rc == 2 and "older bayescal" in err and "Traceback" not in err
    (old / ".bayescal-output").write_text(json.dumps({"kind": "fit", "bayescal_version": "0.5"}))
    rc, err = _run(capsys, "report", old)
    assert rc == 2 and "bayescal 0.5 in an older output format" in err
    fleet = tmp_path / "fleet"
    from bayescal.io.outputs import staged_directory

    with staged_directory(fleet, kind="fleet") as stage:
        stage("fleet.nc").write_text("x")
    rc, err = _run(capsys, "report", fleet)
    assert rc == 2 and "holds a fleet fit" in err and "least-squares" not in err


def test_characterize_bad_inputs(tmp_path, capsys):
    (tmp_path / "empty.csv").write_text("")
    (tmp_path / "nan.csv").write_text("kind,texp_ns,photons_per_pixel,mean_DN,var_temporal_DN2\nbright,1,2,nan,4\n")
    (tmp_path / "kind.csv").write_text("kind,texp_ns,photons_per_pixel,mean_DN,var_temporal_DN2\nflat,1,2,3,4\n")
    (tmp_path / "foreign.npz").write_bytes(b"not an archive")
    head = "kind,texp_ns,photons_per_pixel,n_images,mean_DN,var_temporal_DN2\n"
    (tmp_path / "stack.csv").write_text(head + "bright,1,2,2,3,4\ndark,1,0,2,1,1\nbright,1,2,16,3,4\n")
    (tmp_path / "single.csv").write_text(head + "bright,1,2,1,3,4\ndark,1,0,2,1,1\n")
    same = "".join(f"bright,{t},{t},2,500,40\ndark,{t},0,2,100,4\n" for t in range(1, 9))
    (tmp_path / "same.csv").write_text(head + same)
    cases = {
        "stack.csv": "row 3, column 'spatial_var_of_mean_image_DN2': ",
        "single.csv": "row 1, column 'n_images'",
        "same.csv": "every bright step reads the same signal (400 DN above dark)",
        "empty.csv": "is empty or not a CSV table",
        "nan.csv": "row 1, column 'mean_DN'",
        "kind.csv": "kind 'flat'; expected 'bright' or 'dark'",
        "foreign.npz": "is not a readable .npz archive",
        "missing.csv": "no such EMVA 1288 input",
    }
    for name, expected in cases.items():
        rc, err = _run(capsys, "characterize", tmp_path / name, "--out", tmp_path / "c")
        assert rc == 2 and expected in err, (name, err)
    assert not (tmp_path / "c").exists()


def test_outputs_are_never_mixed(tmp_path, good_csv, fit_dir, capsys):
    out = tmp_path / "fit"
    out.mkdir()
    for p in fit_dir.iterdir():  # a former Bayesian fit directory
        (out / p.name).write_bytes(p.read_bytes())
    assert (out / "posterior.nc").exists()
    rc, _ = _run(capsys, "fit", good_csv, "--model", SPEC, "--backend", "lsq", "--out", out)
    assert rc == 0
    assert not (out / "posterior.nc").exists()  # the old posterior went with the old fit
    assert json.loads((out / "summary.json").read_text())["backend"] == "lsq"
    rc, err = _run(capsys, "predict", out, "--exposure-s", "0.01")
    assert rc == 2 and "holds a least-squares fit" in err
    # an output of another kind is not replaced by a fit (the maps stay)
    from bayescal.io.outputs import staged_directory

    maps = tmp_path / "maps"
    with staged_directory(maps, kind="maps") as stage:
        stage("maps.nc").write_text("pixels")
    rc, err = _run(capsys, "fit", good_csv, "--model", SPEC, "--backend", "lsq", "--out", maps)
    assert rc == 2 and "holds per-pixel maps" in err and (maps / "maps.nc").read_text() == "pixels"
    # a directory bayescal did not write is refused before any work; a file as --out too
    foreign = tmp_path / "thesis"
    foreign.mkdir()
    (foreign / "chapter1.tex").write_text("keep me")
    rc, err = _run(capsys, "fit", good_csv, "--model", SPEC, "--backend", "lsq", "--out", foreign)
    assert rc == 2 and "refusing to replace" in err and "files bayescal did not write (chapter1.tex)" in err
    assert [p.name for p in foreign.iterdir()] == ["chapter1.tex"]
    rc, err = _run(capsys, "fit", good_csv, "--model", SPEC, "--backend", "lsq", "--out", good_csv)
    assert rc == 2 and "is a file; expected a folder" in err
    # nothing staged is left behind
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


def test_interrupt_exits_130_and_writes_nothing(tmp_path, good_csv):
    """Ctrl-C during sampling: exit status 130, no output directory, no staging left behind."""
    out = tmp_path / "fit"
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    cmd = [sys.executable, "-m", "bayescal.cli", "fit", str(good_csv), "--model", SPEC, "--out", str(out)]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env, text=True)
    time.sleep(4.0)  # into model building or sampling; where exactly does not matter
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    assert "interrupted" in err and "Traceback" not in err
    assert not out.exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]
