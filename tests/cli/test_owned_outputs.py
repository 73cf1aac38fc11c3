"""No output of bayescal's own is replaced by accident, no record can be forged, every verb ends.

Table-driven by class, so that the next verb, member or record cannot ship without its case:

- every member of a bayescal output folder, named by every verb's file-valued ``--out``: refused, with
  ``--force`` too, the member unchanged;
- forged records (a ledger entry or a folder marker written by hand, with a size and time, with the
  file's true SHA-256, with a digest copied from another entry, made under another account's key, a
  real record copied onto another file): never authorise a replacement;
- a command's inputs, named directly or read on the way (a spec a design names, frames a glob
  matches): never written, with ``--force`` or without;
- ``design``: unreachable goals and an unpayable budget end at once in exit 3, named; negative or
  non-finite physical values of a design's truth are refused like a spec's;
- refusals name the file and the cause (dimensionality, shape, saturation, separator, a record that is
  a folder), with paths as the user gave them;
- a survey of frames owns its output folder.
"""

from __future__ import annotations

import hashlib
import json
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from bayescal.cli import main
from bayescal.cli.parser import build, output_files
from bayescal.errors import SpecError
from bayescal.io.outputs import LEDGER, MARKER, read_marker, verify_output
from bayescal.io.outputs.seal import seal, sealed
from tests.cli.conftest import laplace_fit_folder
from tests.cli.test_hostile import VERB_CASES
from tests.conftest import MODELS

SPEC = str(MODELS / "seed000_bayer.toml")


@pytest.fixture(scope="module")
def inputs(tmp_path_factory, good_csv):
    """A Laplace fit and a characterisation (two kinds of output folder), the fit's table, a frame."""
    root = tmp_path_factory.mktemp("owned")
    fit = laplace_fit_folder(good_csv, root / "fit")
    assert main(["characterize", "emva_refset001_steps", "--out", str(root / "ccd")]) == 0
    np.save(root / "frame.npy", np.full((4, 6), 600, np.uint16))
    return {"root": root, "fit": fit, "ccd": root / "ccd", "table": good_csv, "image": root / "frame.npy"}


def _run(capsys, argv) -> tuple[int, str]:
    try:
        rc = main([str(a) for a in argv])
    except SystemExit as exc:
        rc = exc.code
    captured = capsys.readouterr()
    return rc, captured.err + captured.out


def _snapshot(folder: Path) -> dict[str, bytes]:
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in folder.rglob("*") if p.is_file()}


# ------------------------------------------------------------- members of an output folder
def _naming(verb: str, member: Path, inputs) -> list[str] | None:
    """The verb's argv whose file outputs include ``member`` (None: no value of its --out names it)."""
    template = VERB_CASES[verb]
    stem = member.with_suffix("")
    for value in (member, stem, member.with_suffix(".html")):  # a file, an SBC stem, a report's siblings
        values = dict(inputs, out=value, truth=inputs["root"] / "truth.csv")
        argv = [a.format(**values) for a in template]
        try:
            named = [Path(p) for p in output_files(build().parse_args(argv))]
        except SpecError:  # two of its outputs would be one file (a report's .json named as the report)
            continue
        if member in named:
            return argv
    return None


#: the suffixes an SBC stem's files have (the only members its --out can name)
_SBC_SUFFIXES = (".csv", ".md", ".png")
MEMBER_CASES = [
    (verb, folder, name)
    for verb in sorted(VERB_CASES)
    for folder, names in (
        ("fit", ("posterior.nc", "summary.json", "summary.csv", "lsq.csv")),
        ("ccd", ("characterization.csv", "characterization.json", "curves.csv")),
    )
    for name in names
    if verb != "sbc" or name.endswith(_SBC_SUFFIXES)
]


@pytest.mark.parametrize(("verb", "folder", "name"), MEMBER_CASES, ids=lambda v: str(v))
def test_a_member_of_an_output_folder_is_never_a_file_output(verb, folder, name, inputs, capsys):
    member = inputs[folder] / name
    argv = _naming(verb, member, inputs)
    assert argv is not None, f"no --out of {verb} names a file called {name}"
    before = _snapshot(inputs[folder])
    for extra in ([], ["--force"]):
        rc, err = _run(capsys, [*argv, *extra])
        assert rc == 2, (verb, member, err)
        assert f"refusing to overwrite {member}: it is part of {inputs[folder]}" in err, err
        assert "--force does not apply" in err
    assert _snapshot(inputs[folder]) == before
    verify_output(inputs[folder], (read_marker(inputs[folder])["kind"],))


def test_an_addition_is_replaced_by_its_own_product_alone(inputs, tmp_path, capsys):
    fit = tmp_path / "fit"
    shutil.copytree(inputs["fit"], fit)
    predict = ["predict", fit, "--exposure-s", "0.01", "--radiance", "5", "--out", fit / "table.csv"]
    assert _run(capsys, predict)[0] == 0
    assert read_marker(fit)["files"]["table.csv"]["added"] == "predict"
    assert _run(capsys, predict)[0] == 0  # the same product, unchanged: replaced
    assert _run(capsys, ["report", fit])[0] == 0
    rc, err = _run(capsys, [*predict[:-1], fit / "report.html"])  # another product's file
    assert rc == 2 and "it is the report output added to" in err and "writes a predict output" in err, err
    assert _run(capsys, ["report", fit])[0] == 0  # a report replaces a report
    with (fit / "table.csv").open("a") as f:
        f.write("an edit\n")
    rc, err = _run(capsys, predict)
    assert rc == 2 and "it was changed after bayescal wrote it" in err, err
    assert _run(capsys, [*predict, "--force"])[0] == 0


# ------------------------------------------------------------------------ forged records
def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _ledger(folder: Path, entries: dict) -> None:
    (folder / LEDGER).write_text(json.dumps({"format": 1, "files": entries}))


def _marker(folder: Path, entries: dict, run_id: str = "0" * 32) -> None:
    marker = {"format": 2, "kind": "fit", "run_id": run_id, "bayescal_version": "0.1.0", "files": entries}
    (folder / MARKER).write_text(json.dumps(marker))


def _size_mtime(f: Path) -> dict:
    return {"size": f.stat().st_size, "mtime_ns": f.stat().st_mtime_ns}


def _true_sha(f: Path) -> dict:
    return {"size": f.stat().st_size, "sha256": _sha(f)}


FORGERIES = {
    "ledger: size and time": lambda d, f: _ledger(d, {f.name: _size_mtime(f)}),
    "ledger: the true SHA-256": lambda d, f: _ledger(d, {f.name: _true_sha(f)}),
    "ledger: a digest copied from another entry": lambda d, f: _ledger(
        d, {f.name: _true_sha(f) | {"mac": seal("files", "other.csv", {"size": 1, "sha256": "0" * 64})["mac"]}}
    ),
    "ledger: a digest for another name": lambda d, f: _ledger(d, {f.name: seal("files", "x.csv", _true_sha(f))}),
    "marker: the name only": lambda d, f: _marker(d, {f.name: {}}),
    "marker: an addition with the true SHA-256": lambda d, f: _marker(
        d, {f.name: _true_sha(f) | {"added": "simulate"}}
    ),
    "marker: an addition sealed for another run": lambda d, f: _marker(
        d, {f.name: seal("another run", f.name, _true_sha(f) | {"added": "simulate"})}
    ),
}


@pytest.mark.parametrize("forgery", sorted(FORGERIES))
def test_a_forged_record_authorises_nothing(forgery, tmp_path, capsys):
    mine = tmp_path / "notes.csv"
    mine.write_text("the user's table\n")
    FORGERIES[forgery](tmp_path, mine)
    rc, err = _run(capsys, ["simulate", "--design", "seed000", "--out", mine])
    assert rc == 2 and f"refusing to overwrite {mine}" in err, err
    assert mine.read_text() == "the user's table\n"


def test_a_record_made_under_another_key_authorises_nothing(tmp_path, capsys, monkeypatch):
    out = tmp_path / "t.csv"
    assert _run(capsys, ["simulate", "--design", "seed000", "--out", out])[0] == 0
    assert _run(capsys, ["simulate", "--design", "seed000", "--out", out, "--seed", "2"])[0] == 0  # its own: replaced
    written = out.read_bytes()
    monkeypatch.setenv("BAYESCAL_KEY_FILE", str(tmp_path / "elsewhere" / "record.key"))  # another account
    rc, err = _run(capsys, ["simulate", "--design", "seed000", "--out", out])
    assert rc == 2 and "was not written by bayescal under this account" in err, err
    assert out.read_bytes() == written


def test_a_real_record_copied_onto_another_file_authorises_nothing(tmp_path, capsys):
    ours, theirs = tmp_path / "a", tmp_path / "b"
    ours.mkdir()
    theirs.mkdir()
    assert _run(capsys, ["simulate", "--design", "seed000", "--out", ours / "t.csv"])[0] == 0
    (theirs / "t.csv").write_text("the user's\n")
    shutil.copy(ours / LEDGER, theirs / LEDGER)
    rc, err = _run(capsys, ["simulate", "--design", "seed000", "--out", theirs / "t.csv"])
    assert rc == 2 and "it was changed after bayescal wrote it" in err, err
    assert (theirs / "t.csv").read_text() == "the user's\n"


def test_an_output_folder_with_a_forged_marker_is_not_replaced(inputs, tmp_path, capsys):
    """A folder whose marker lists every file with its true SHA-256 but no seal (written by hand, or by
    another account) is not bayescal's to replace; the same folder with the real marker is."""
    fit = tmp_path / "fit"
    shutil.copytree(inputs["fit"], fit)
    argv = ["fit", inputs["table"], "--model", SPEC, "--backend", "lsq", "--out", fit]
    marker = read_marker(fit)
    _marker(fit, {n: {k: v for k, v in e.items() if k != "mac"} for n, e in marker["files"].items()}, marker["run_id"])
    before = _snapshot(fit)
    rc, err = _run(capsys, argv)
    assert rc == 2 and "its record carries no seal of this account's" in err, err
    assert _snapshot(fit) == before
    (fit / MARKER).write_text(json.dumps(marker))  # the marker bayescal wrote
    assert _run(capsys, argv)[0] == 0
    assert verify_output(fit, ("fit",)).run_id != marker["run_id"]


def test_seals_bind_every_field(tmp_path, monkeypatch):
    monkeypatch.setenv("BAYESCAL_KEY_FILE", str(tmp_path / "key"))
    entry = seal("run", "a.csv", {"size": 3, "sha256": "ab" * 32})
    assert sealed("run", "a.csv", entry)
    assert (tmp_path / "key").stat().st_mode & 0o077 == 0  # the user's alone
    for changed in ({"size": 4}, {"sha256": "cd" * 32}, {"added": "report"}):
        assert not sealed("run", "a.csv", entry | changed)
    assert not sealed("another run", "a.csv", entry) and not sealed("run", "b.csv", entry)
    monkeypatch.setenv("BAYESCAL_KEY_FILE", str(tmp_path / "other"))
    assert not sealed("run", "a.csv", entry)


# ---------------------------------------------------------------------------- inputs
def _copied_design(root: Path) -> Path:
    assert main(["examples", "--copy", "seed000", "--to", str(root)]) == 0
    return root / "seed000_design.toml"


INPUT_CASES = {
    "the design, named": lambda r, i: (["simulate", "--design", _copied_design(r), "--out", "{design}"], "{design}"),
    "the spec a design names": lambda r, i: (
        ["simulate", "--design", _copied_design(r), "--out", r / "seed000_bayer.toml"],
        r / "seed000_bayer.toml",
    ),
    "the table, in the output folder": lambda r, i: (
        ["fit", shutil.copy(i["table"], r / "m.csv"), "--model", SPEC, "--backend", "lsq", "--out", r],
        r / "m.csv",
    ),
    "the frames of a glob, in the survey's folder": lambda r, i: (
        ["invert", i["fit"], str(r / "f*.npy"), "--channel", "G", "--exposure-s", "0.004", "--out", r],
        _frames(r, 2)[0],
    ),
    "the fleet design": lambda r, i: (
        ["fleet-simulate", shutil.copy(MODELS / "fleet_seed000_design.toml", r / "fd.toml"), "--out", r / "fd.toml"],
        r / "fd.toml",
    ),
}


def _frames(root: Path, n: int) -> list[Path]:
    paths = [root / f"f{k}.npy" for k in range(n)]
    for p in paths:
        np.save(p, np.full((4, 6), 600, np.uint16))
    return paths


@pytest.mark.parametrize("case", sorted(INPUT_CASES))
def test_no_command_writes_over_its_input(case, inputs, tmp_path, capsys):
    argv, victim = INPUT_CASES[case](tmp_path, inputs)
    design = tmp_path / "seed000_design.toml"
    argv = [str(a).format(design=design) for a in argv]
    victim = Path(str(victim).format(design=design))
    before = _snapshot(tmp_path)
    forces = [["--force"]] if "force" in vars(build().parse_args(argv)) else [[]]
    for extra in forces:  # --force is for a file of the user's, never for an input
        rc, err = _run(capsys, [*argv, *extra])
        assert rc == 2 and "an input of this command" in err, (case, err)
    assert victim.is_file() and _snapshot(tmp_path) == before


# --------------------------------------------------------------------------- every verb ends
@pytest.mark.parametrize(
    ("argv", "said"),
    [
        (
            ["--goal-scale", "0.01"],
            ["UNREACHABLE: A1[R] cannot be narrowed", "no campaign of this grid takes it below"],
        ),
        (["--budget-rows", "3"], ["OVER BUDGET: the design costs 30 rows, more than the budget of 3"]),
    ],
    ids=["unreachable goals", "unpayable budget"],
)
def test_design_ends_in_exit_3_when_it_cannot_do_what_is_asked(argv, said, tmp_path, capsys):
    rc, out = _run(capsys, ["design", "seed000", *argv, "--out", tmp_path / "d"])
    assert rc == 3, out
    assert all(s in out for s in said), out


TRUTH_CASES = [
    ("read_noise_dn", "-3", "truth.read_noise_dn = -3.0; expected 0 <= noise"),
    ("conversion_gain", "0", "truth.conversion_gain = 0.0; expected 0 < value"),
    ("excess_dn", "nan", "truth.excess_dn = nan"),
    ("prnu", "-0.01", "truth.prnu = -0.01"),
    ("common_rel", "inf", "truth.common_rel = inf"),
    ("level_rel", "0.9", "truth.level_rel = 0.9"),
    ("dark_doubling_c", "-7", "truth.dark_doubling_c = -7.0"),
    ("dark_offset", '{ "1.0" = nan }', "truth.dark_offset.1.0 = nan"),
    ("response", "{ R = [62.09, inf], G = [30.0], B = [17.0] }", "truth.response.R[1] = inf"),
]
BLOCK_CASES = [
    ("exposure_s", "[0.004, -0.008]", "exposure_s[1] = -0.008; expected 0 < exposure"),
    ("gain", "[nan]", "gain = nan"),
    ("levels", "[1.5, -3.0]", "levels[1] = -3.0"),
]


@pytest.mark.parametrize(("key", "value", "fragment"), TRUTH_CASES + BLOCK_CASES, ids=lambda v: str(v)[:30])
def test_a_design_with_impossible_physics_is_refused(key, value, fragment, tmp_path, capsys):
    text = (MODELS / "seed000_design.toml").read_text()
    lines = text.splitlines()
    if key == "levels":
        i = next(k for k, line in enumerate(lines) if line.startswith("levels ="))
    else:
        section = "[truth]" if (key, value, fragment) in TRUTH_CASES else "[[illuminated]]"
        start = lines.index(next(line for line in lines if line.startswith(section)))
        i = next((k for k in range(start, len(lines)) if lines[k].startswith(f"{key} ")), None)
        if i is None:
            lines.insert(start + 1, "")
            i = start + 1
    lines[i] = f"{key} = {value}"
    path = tmp_path / "d.toml"
    path.write_text("\n".join(lines).replace('spec = "seed000_bayer.toml"', f'spec = "{SPEC}"') + "\n")
    rc, err = _run(capsys, ["simulate", "--design", path, "--out", tmp_path / "t.csv"])
    assert rc == 2 and str(path) in err and fragment in err, err
    assert not (tmp_path / "t.csv").exists()


# --------------------------------------------------------------- refusals name file and cause
def _descriptor(root: Path, second: np.ndarray) -> Path:
    """An EMVA 1288 descriptor whose every group is an 8x8 pair, but one image is ``second``."""
    np.save(root / "a.npy", np.full((8, 8), 100, np.uint16))
    np.save(root / "odd.npy", second)
    lines = ["n 12 8 8", "b 1000 100", "i a.npy", "i odd.npy", "d 1000", "i a.npy", "i a.npy"]
    (root / "set.txt").write_text("\n".join(lines) + "\n")
    return root / "set.txt"


CAUSE_CASES = {
    "a cube of planes": (
        lambda r: _descriptor(r, np.full((3, 8, 8), 100, np.uint16)),
        ["odd.npy has shape (3, 8, 8) (a cube of planes); expected a 2-D monochrome image"],
    ),
    "another frame size": (
        lambda r: _descriptor(r, np.full((8, 9), 100, np.uint16)),
        ["odd.npy has shape 8 x 9; expected 8 x 8 like the set's first image"],
    ),
    "a flat at full scale": (
        lambda r: _saturated(r),
        ["bright steps are saturated", "full scale of a 12-bit ADC"],
    ),
}


def _saturated(root: Path) -> Path:
    steps = pd.read_csv(MODELS / "emva_refset001_steps.csv")
    bright = steps["kind"] == "bright"
    steps.loc[bright, "mean_DN"] = 4095.0
    steps.loc[bright, "var_temporal_DN2"] = 0.0
    steps.to_csv(root / "steps.csv", index=False)
    return root / "steps.csv"


@pytest.mark.parametrize("case", sorted(CAUSE_CASES))
def test_a_refusal_names_the_file_and_the_cause(case, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    make, said = CAUSE_CASES[case]
    given = make(Path("."))  # relative, as a user types it
    rc, err = _run(capsys, ["characterize", given, "--out", "ccd"])
    assert rc == 2 and "Traceback" not in err and "RuntimeWarning" not in err, err
    assert all(s in err for s in said), err
    assert str(tmp_path) not in err  # paths as the user gave them
    assert not (tmp_path / "ccd").exists()


@pytest.mark.parametrize(("sep", "name"), [(";", "semicolons"), ("\t", "tabs")])
def test_a_table_with_another_separator_is_named(sep, name, good_csv, tmp_path, capsys):
    path = tmp_path / "t.csv"
    path.write_text(good_csv.read_text().replace(",", sep))
    rc, err = _run(capsys, ["fit", path, "--model", SPEC, "--backend", "lsq", "--out", tmp_path / "o"])
    assert rc == 2 and f"{path}: the header row" in err and f"separated by {name}" in err, err


def test_a_record_that_is_a_folder_stops_the_write_before_it(tmp_path, capsys):
    (tmp_path / LEDGER).mkdir()
    rc, err = _run(capsys, ["simulate", "--design", "seed000", "--out", tmp_path / "t.csv"])
    assert rc == 2 and f"{tmp_path / LEDGER}, where bayescal records" in err and "is not a file" in err, err
    assert ".tmp" not in err and sorted(p.name for p in tmp_path.iterdir()) == [LEDGER]


def test_a_shipped_example_is_named_not_its_installed_path(capsys):
    from bayescal.io.resources import models_dir

    rc, err = _run(capsys, ["fleet-simulate", "seed000", "--out", "never.csv"])
    assert rc == 2 and "seed000_design.toml (a shipped example)" in err, err
    assert str(models_dir()) not in err


# ---------------------------------------------------------------------------- surveys
def test_a_survey_owns_its_output_folder(inputs, tmp_path, capsys):
    frames = _frames(tmp_path, 2)
    survey = ["invert", inputs["fit"], *frames, "--channel", "G", "--exposure-s", "0.004", "--out"]
    out = tmp_path / "survey"
    assert _run(capsys, [*survey, out])[0] == 0
    info = verify_output(out, ("survey",))
    assert sorted(info.files) == sorted(
        f"{f.stem}/{n}" for f in frames for n in ("radiance.nc", "median.tif", "lower.tif", "upper.tif", "bound.tif")
    )
    assert _run(capsys, [*survey, out])[0] == 0  # a rerun replaces its own survey
    assert verify_output(out, ("survey",)).run_id != info.run_id
    fit = tmp_path / "fit"
    shutil.copytree(inputs["fit"], fit)
    before = _snapshot(fit)
    rc, err = _run(capsys, [*survey, fit])  # another run's folder
    assert rc == 2 and "holds a calibration fit" in err, err
    assert _snapshot(fit) == before
    (out / "notes.txt").write_text("mine")
    rc, err = _run(capsys, [*survey, out])
    assert rc == 2 and "notes.txt" in err, err
