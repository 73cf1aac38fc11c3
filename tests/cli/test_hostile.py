"""Hostile inputs, table-driven so that the next verb, column or spec key cannot ship without them.

- every file-valued output of every verb (read off the parser, not listed by hand) refuses a file
  of the user's before any work, names it and leaves it as it was; ``--force`` replaces it; a file
  bayescal wrote is replaced on a rerun; a symbolic link is never written through;
- every numeric column of a measurement table is checked against its physical limit (read off the
  table's own list of limits), both sides, with the row and the column named;
- spec keys out of range, contradicting sections, and terms switched on that the table cannot
  inform are refused;
- truncated, empty and mislabelled frames, and malformed scheduler addresses, end in exit 2 naming
  the file or the option;
- a write that fails for a full disk or a file-size limit ends in exit 2, leaves nothing behind and
  does not crash the process;
- a region clipped at full scale (temporal variance 0) is data, not bad input.
"""

from __future__ import annotations

import math
import resource
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import bayescal as bc
from bayescal.cli import main
from bayescal.cli.parser import build
from bayescal.errors import SpecError, TableError
from bayescal.io.limits import LIMITS
from bayescal.io.outputs import LEDGER
from bayescal.io.table import COLUMN_LIMITS
from tests.cli.conftest import laplace_fit_folder
from tests.conftest import MODELS

SPEC = str(MODELS / "seed000_bayer.toml")


@pytest.fixture(scope="module")
def inputs(tmp_path_factory, good_csv):
    """A Laplace fit, its table, an image of the right bit depth."""
    root = tmp_path_factory.mktemp("hostile")
    fit = root / "fit"
    laplace_fit_folder(good_csv, fit)
    np.save(root / "frame.npy", np.full((4, 6), 600, np.uint16))
    return {"root": root, "fit": fit, "table": good_csv, "image": root / "frame.npy"}


def _run(capsys, argv) -> tuple[int, str]:
    try:
        rc = main([str(a) for a in argv])
    except SystemExit as exc:  # argparse's own errors
        rc = exc.code
    captured = capsys.readouterr()
    return rc, captured.err + captured.out


# ------------------------------------------------------------------ every verb's file outputs
#: one invocation per verb that writes single files; {out} (and {truth}) are the files it writes
VERB_CASES = {
    "predict": ["predict", "{fit}", "--exposure-s", "0.01", "--radiance", "5", "--out", "{out}"],
    "invert": ["invert", "{fit}", "--dn", "534", "--channel", "G", "--exposure-s", "0.004", "--out", "{out}"],
    "report": ["report", "{fit}", "--out", "{out}"],
    "scene": ["scene", "{image}", "{fit}", "--channel", "G", "--exposure-s", "0.004", "--out", "{out}"],
    "sbc": ["sbc", "{table}", "--model", SPEC, "--sims", "2", "--backend", "laplace", "--out", "{out}"],
    "simulate": ["simulate", "--design", "seed000", "--out", "{out}"],
    "fleet-simulate": ["fleet-simulate", "fleet_seed000_design", "--out", "{out}", "--truth", "{truth}"],
}
#: the names the outputs get in the case's folder (a report's and an SBC stem's siblings follow)
NAMES = {"report": "new.html", "sbc": "stem", "scene": "scene.json"}
#: verbs whose --force run is cheap enough for the default test run
CHEAP = ("predict", "invert", "simulate", "fleet-simulate", "report")


def _verbs_with_file_outputs() -> dict[str, tuple]:
    parser = build()
    sub = next(a for a in parser._actions if a.__class__.__name__ == "_SubParsersAction")
    return {name: p.get_default("file_outputs") for name, p in sub.choices.items() if p.get_default("file_outputs")}


def test_every_verb_with_file_outputs_is_in_the_table():
    assert set(_verbs_with_file_outputs()) == set(VERB_CASES)


def _case(verb, inputs, folder: Path) -> tuple[list[str], list[Path]]:
    """The verb's argv writing into ``folder``, and every file it names (expanded as the parser does)."""
    folder.mkdir(parents=True, exist_ok=True)
    values = dict(inputs, out=folder / NAMES.get(verb, "out.csv"), truth=folder / "truth.csv")
    argv = [a.format(**values) for a in VERB_CASES[verb]]
    args = build().parse_args(argv)
    from bayescal.cli.parser import output_files

    return argv, [Path(p) for p in output_files(args)]


@pytest.mark.parametrize("verb", sorted(VERB_CASES))
def test_a_users_file_is_never_replaced(verb, inputs, tmp_path, capsys):
    """Each file the verb would write, held by the user in turn: exit 2 before any work, the file named
    and unchanged, nothing else written."""
    argv, files = _case(verb, inputs, tmp_path)
    assert files, verb
    for target in files:
        for f in tmp_path.iterdir():
            f.unlink()
        target.write_text("the user's own notes\n")
        rc, err = _run(capsys, argv)
        assert rc == 2, (verb, target, err)
        assert f"refusing to overwrite {target}" in err and "--force" in err, err
        assert target.read_text() == "the user's own notes\n"
        assert sorted(p.name for p in tmp_path.iterdir()) == [target.name], (verb, list(tmp_path.iterdir()))


@pytest.mark.parametrize("verb", CHEAP)
def test_force_replaces_and_a_rerun_replaces_its_own(verb, inputs, tmp_path, capsys):
    argv, files = _case(verb, inputs, tmp_path)
    for target in files:
        target.write_text("mine\n")
    rc, err = _run(capsys, [*argv, "--force"])
    assert rc == 0, err
    assert all(f.read_text() != "mine\n" for f in files)
    assert (tmp_path / LEDGER).is_file()
    rc, err = _run(capsys, argv)  # the files are bayescal's own now, unchanged: replaced without --force
    assert rc == 0, err
    with files[0].open("a") as f:  # edited since bayescal wrote it: the user's now
        f.write("an edit\n")
    rc, err = _run(capsys, argv)
    assert rc == 2 and f"refusing to overwrite {files[0]}: it was changed after bayescal wrote it" in err, err


def test_links_are_not_written_through(inputs, tmp_path, capsys):
    elsewhere = tmp_path / "elsewhere.csv"
    elsewhere.write_text("precious\n")
    (tmp_path / "link.csv").symlink_to(elsewhere)
    (tmp_path / "dangling").symlink_to(tmp_path / "nowhere")
    argv = ["predict", inputs["fit"], "--exposure-s", "0.01", "--radiance", "5", "--out", tmp_path / "link.csv"]
    for extra in ([], ["--force"]):
        rc, err = _run(capsys, argv + extra)
        assert rc == 2 and "is a symbolic link" in err and "link.csv" in err, err
    assert elsewhere.read_text() == "precious\n"
    rc, err = _run(
        capsys, ["fit", inputs["table"], "--model", SPEC, "--backend", "lsq", "--out", tmp_path / "dangling"]
    )
    assert rc == 2 and f"{tmp_path / 'dangling'} is a symbolic link" in err and "staging" not in err, err
    assert not (tmp_path / "nowhere").exists()


def test_two_outputs_naming_one_file_are_refused(tmp_path, capsys):
    out = tmp_path / "t.csv"
    rc, err = _run(capsys, ["fleet-simulate", "fleet_seed000_design", "--out", out, "--truth", out])
    assert rc == 2 and "two outputs of this command name the same file" in err, err
    assert not out.exists()


# ------------------------------------------------------------------------- column ranges
def _outside(name: str) -> list[float]:
    """Values just outside limit ``name`` on each side it has (and one far beyond)."""
    lim = LIMITS[name]
    values = [lim.low if lim.low_open else lim.low - max(abs(lim.low), 1.0) * 1e-3]
    if math.isfinite(lim.high):
        values.append(lim.high * 1.5 if lim.high > 0 else lim.high + 1.0)
    return values


COLUMN_CASES = [(col, v) for col, name in COLUMN_LIMITS.items() for v in _outside(name)]


@pytest.mark.parametrize(("column", "value"), COLUMN_CASES, ids=lambda v: str(v))
def test_every_column_is_checked_against_its_limit(good_csv, column, value):
    frame = pd.read_csv(good_csv)
    if column == "irradiance":
        frame = frame.rename(columns={"radiance": "irradiance"})
    if column not in frame:
        frame[column] = {"time_s": np.arange(len(frame)) * 10.0, "temperature_c": 20.0, "radiance_u_rel": 0.01}.get(
            column, 1.0
        )
    frame[column] = frame[column].astype(float)
    frame.loc[4, column] = value
    with pytest.raises(
        TableError, match=rf"row 5, column '{column}': .*expected .*{LIMITS[COLUMN_LIMITS[column]].quantity}"
    ):
        bc.MeasurementTable.from_frame(frame)


def test_one_moment_holds_one_setting(good_csv):
    frame = pd.read_csv(good_csv)
    frame["time_s"] = np.arange(len(frame)) * 10.0
    bc.MeasurementTable.from_frame(frame)
    frame.loc[7, "time_s"] = frame.loc[3, "time_s"]
    with pytest.raises(TableError, match=r"row 8, column 'time_s': time 30 s is also the time of row 4"):
        bc.MeasurementTable.from_frame(frame)


# --------------------------------------------------------------------------- spec values
SPEC_CASES = [
    ({"offset_temperature": {"reference_c": -300.0}}, "offset_temperature.reference_c = -300.0; expected -273.15 <"),
    ({"responsivity": {"reference_c": float("nan")}}, "responsivity.reference_c = nan"),
    ({"shutter": {"offset_prior_s": float("inf")}}, "shutter.offset_prior_s = inf; expected a finite number"),
    ({"glow": {"prior_sd": float("nan")}}, "glow.prior_sd"),
    ({"dark": {"temperature_ref_c": -500.0}}, "dark.temperature_ref_c = -500.0"),
    ({"dark": {"doubling_c": 1e6}}, "dark.doubling_c"),
    ({"reference": {"exposure_s": 1e308}}, "reference.exposure_s"),
    ({"dark": {"glow": True}, "glow": {"enabled": False}}, "dark.glow = True and glow.enabled = False contradict"),
]


@pytest.mark.parametrize(("change", "fragment"), SPEC_CASES, ids=lambda v: str(v)[:40])
def test_spec_values_out_of_range_are_refused(change, fragment):
    data = bc.load_spec(SPEC).to_dict()
    for section, keys in change.items():
        data.setdefault(section, {}).update(keys)
    with pytest.raises(SpecError, match=fragment.replace("(", r"\(").replace("[", r"\[")):
        bc.ModelSpec.from_dict(data)


def test_agreeing_old_and_new_keys_are_accepted():
    data = bc.load_spec(SPEC).to_dict() | {"glow": {"enabled": True}}
    data["dark"] = dict(data["dark"], glow=True)
    assert bc.ModelSpec.from_dict(data).effect("glow").enabled is True


UNINFORMED = [
    ({"responsivity": {"temperature": True}}, "temperature_c", "responsivity.temperature = true"),
    ({"offset_temperature": {"enabled": True}}, "temperature_c", "offset_temperature.enabled = true"),
    ({"dark": {"temperature": True}}, "temperature_c", "dark.temperature = true"),
]


@pytest.mark.parametrize(("change", "column", "fragment"), UNINFORMED, ids=lambda v: str(v)[:30])
def test_a_term_the_table_cannot_inform_is_refused(good_csv, change, column, fragment):
    frame = pd.read_csv(good_csv).assign(**{column: 25.0})
    table = bc.MeasurementTable.from_frame(frame)
    spec = bc.load_spec(SPEC).replace(**change)
    with pytest.raises(TableError, match=rf"{fragment}, but the table's '{column}' holds one value \(25\)"):
        bc.build_model(table, spec)


def test_auto_terms_stay_off_with_one_value(good_csv):
    frame = pd.read_csv(good_csv).assign(temperature_c=25.0)
    model = bc.build_model(bc.MeasurementTable.from_frame(frame), bc.load_spec(SPEC))
    assert not model.parts.effects


def test_one_time_for_every_row_is_not_a_session(good_csv):
    """A drift over time needs two or more moments; one time for every row is not a record of when each
    frame was taken (two settings at one moment), and is refused by the table before any term."""
    frame = pd.read_csv(good_csv).assign(time_s=100.0)
    with pytest.raises(TableError, match="time 100 s is also the time of row 1, which differs in"):
        bc.MeasurementTable.from_frame(frame)
    from bayescal.io.checks import require_spread

    with pytest.raises(TableError, match=r"dark.drift = true, but the table's 'time_s' holds one value \(100\)"):
        require_spread(np.full(5, 100.0), "dark.drift", "time_s")


# ---------------------------------------------------------------------------- options
OPTION_CASES = [
    (["predict", "{fit}", "--exposure-s", "0.01", "--radiance", "-5"], "--radiance/--stimulus: '-5'; expected 0 <="),
    (["predict", "{fit}", "--exposure-s", "0.01", "--temperature-c", "-300"], "above absolute zero"),
    (["predict", "{fit}", "--exposure-s", "1e308"], "--exposure-s: '1e308'; expected 0 < exposure <= 86400 s"),
    (["plan", "{fit}", "--channel", "G", "--dn", "1e308", "--current", "0.004", "--exposures", "0.01"], "exceeds"),
    (["plan", "{fit}", "--channel", "G", "--dn", "500", "--current", "0.004,1,1,-400", "--exposures", "1"], "absolute"),
    (["fit", "{table}", "--model", SPEC, "--backend", "lsq", "--report", "--out", "{root}/o"], "no posterior"),
    (
        ["invert", "{fit}", "{image}", "{image}", "--channel", "G", "--out", "{root}/s", "--scheduler", "nonsense"],
        "argument --scheduler: 'nonsense'",
    ),
    (["maps", "{root}", "--out", "{root}/m", "--scheduler", "tcp://host:99999"], "scheduler address"),
    (["maps", "{root}", "--out", "{root}/m", "--scheduler", "tcp://host"], "names no port"),
]


@pytest.mark.parametrize(("argv", "fragment"), OPTION_CASES, ids=lambda v: " ".join(map(str, v))[:50])
def test_options_out_of_range(inputs, capsys, argv, fragment):
    rc, err = _run(capsys, [a.format(**inputs) for a in argv])
    assert rc == 2 and fragment in err and "Traceback" not in err, err
    assert not (inputs["root"] / "o").exists()


def test_plan_beyond_the_polynomial_is_flagged_not_zero(inputs, capsys):
    rc, out = _run(
        capsys, ["plan", inputs["fit"], "--channel", "G", "--dn", "534", "--current", "0.004", "--exposures", "1,10"]
    )
    assert rc == 0, out
    assert "EXTRAPOLATION: exposure 10 s outside" in out and "signal beyond the calibrated range" in out
    table = out.split("extrapolated\n")[1].splitlines()[:2]
    assert all(line.split()[4] == "4095" for line in table), table  # it saturates; it does not read 0


# ------------------------------------------------------------------------------ frames
def _tiff(path: Path) -> bytes:
    import tifffile

    tifffile.imwrite(path, np.full((8, 8), 700, np.uint16))
    return path.read_bytes()


FRAME_CASES = {
    "truncated.tif": lambda whole: whole[: len(whole) // 3],
    "empty.tif": lambda whole: b"",
    "text.tif": lambda whole: b"not an image at all\n" * 20,
    "truncated.png": lambda whole: b"\x89PNG\r\n\x1a\n" + whole[8:40],
    "truncated.npy": lambda whole: b"\x93NUMPY\x01\x00v\x00{'descr': '<u2', 'fortran_order': False, 'shape': (8, 8), }",
}


@pytest.mark.parametrize("name", sorted(FRAME_CASES))
def test_broken_frames_are_named(inputs, tmp_path, capsys, name):
    whole = _tiff(tmp_path / "good.tif")
    path = tmp_path / name
    path.write_bytes(FRAME_CASES[name](whole))
    single = ["invert", inputs["fit"], path, "--channel", "G", "--exposure-s", "0.004", "--out", tmp_path / "one"]
    survey = ["invert", inputs["fit"], tmp_path / "good.tif", path, "--channel", "G", "--exposure-s", "0.004"]
    for argv in (single, [*survey, "--out", tmp_path / "many"]):
        rc, err = _run(capsys, argv)
        assert rc == 2 and str(path) in err and "Traceback" not in err, err
        assert "truncated" in err or "empty" in err or "not a readable" in err, err
    assert not (tmp_path / "one").exists()


# --------------------------------------------------------------------- a disk that fills up
def _limited(argv: list[str], cwd: Path, max_bytes: int) -> subprocess.CompletedProcess:
    def limit():
        resource.setrlimit(resource.RLIMIT_FSIZE, (max_bytes, max_bytes))

    return subprocess.run(
        [sys.executable, "-m", "bayescal", *map(str, argv)],
        cwd=cwd,
        capture_output=True,
        text=True,
        preexec_fn=limit,
        timeout=600,
    )


def test_a_file_size_limit_ends_in_exit_2_and_leaves_nothing(inputs, tmp_path):
    """A fit's posterior (megabytes) and a simulated table (kilobytes) written under a file-size limit
    below their size: exit 2 naming the output, no traceback, no crash at exit, nothing left behind."""
    fit = _limited(
        ["fit", inputs["table"], "--model", SPEC, "--backend", "laplace", "--no-diagnose", "--quiet", "--out", "f"],
        tmp_path,
        200_000,
    )
    assert fit.returncode == 2, (fit.returncode, fit.stderr[-2000:])
    assert "cannot write f: File too large" in fit.stderr and "Traceback" not in fit.stderr
    table = _limited(["simulate", "--design", "seed000", "--out", "t.csv"], tmp_path, 2_000)
    assert table.returncode == 2 and "cannot write t.csv: File too large" in table.stderr, table.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == [], list(tmp_path.iterdir())


# ------------------------------------------------------------------- clipped regions are data
def test_a_clipped_region_with_no_temporal_noise_is_data(good_csv):
    frame = pd.read_csv(good_csv)
    frame["dn_var"] = 2.0 + 0.25 * frame["dn_mean"]
    top = frame["dn_mean"].idxmax()
    frame.loc[top, ["dn_mean", "dn_var"]] = [4095.0, 0.0]
    spec = bc.load_spec(SPEC).replace(noise={"kind": "measured"})
    model = bc.build_model(bc.MeasurementTable.from_frame(frame), spec)
    assert model.data.var_meas[top] == pytest.approx(1.0 / 12.0 / 4095.0**2)
    frame.loc[3, "dn_var"] = 0.0  # not clipped: no region measures no noise
    with pytest.raises(TableError, match=r"row 4, column 'dn_var': a temporal variance of 0 in a region that is not"):
        bc.build_model(bc.MeasurementTable.from_frame(frame), spec)


# ------------------------------------------------------------------- pooled channels and NUTS
def test_the_domain_of_a_pooled_spec_is_decided_by_fits_laplace_can_make(seed000):
    """The seed-000 spec with pooled channels: the domain decision (gains are swept) runs on the
    unpooled Laplace fits that stand for it, and hands the pooled spec to the user's backend."""
    from bayescal.fitting.diagnosis import decide_domain, laplace_proxy

    spec, design = seed000
    pooled = spec.replace(response={"pooled": True})
    table = bc.simulate(spec, design, seed=2).table
    assert laplace_proxy(spec) is spec and laplace_proxy(pooled).response.pooled is False
    chosen, info, laplace = decide_domain(table, pooled, seed=1)
    assert chosen.response.pooled and info is not None and info["chosen"] == "charge"
    assert laplace is None  # no Laplace fit of the pooled model exists to reuse


@pytest.mark.slow
def test_the_pooled_seed000_nuts_fit_exits_0(tmp_path, good_csv):
    pooled = tmp_path / "pooled.toml"
    pooled.write_text(Path(SPEC).read_text().replace("pooled = false       # three", "pooled = true       # three"))
    assert (
        main(
            ["fit", str(good_csv), "--model", str(pooled), "--backend", "nuts", "--out", str(tmp_path / "f"), "--quiet"]
        )
        == 0
    )


def test_a_bright_step_without_photons_is_named(tmp_path, capsys):
    """EMVA 1288 steps whose bright rows say 0 photons: the row and the column named (it crashed a
    least-squares fit of the photon transfer before)."""
    steps = pd.read_csv(MODELS / "emva_refset001_steps.csv")
    steps.loc[steps["kind"] == "bright", "photons_per_pixel"] = 0
    steps.to_csv(tmp_path / "steps.csv", index=False)
    rc, err = _run(capsys, ["characterize", tmp_path / "steps.csv", "--out", tmp_path / "ch"])
    assert rc == 2 and "column 'photons_per_pixel'" in err and "has 0 photons per pixel" in err, err
    assert not (tmp_path / "ch").exists()
