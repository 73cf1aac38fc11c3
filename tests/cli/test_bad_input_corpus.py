"""A corpus of bad inputs for the verbs beyond ``fit``: each gives exit 2 and a message that names
the option, file or key and the real cause, never a traceback; nothing is accepted silently.

Each case is (name, arguments, fragment of the message).  The arguments are built from a few
real inputs (a Laplace fit, a stack folder, a fleet table) so that the case isolates one fault.
"""

import numpy as np
import pandas as pd
import pytest

import bayescal as bc
from bayescal.cli import main
from bayescal.io.outputs import staged_directory
from bayescal.validation.fleet import FleetDesign, simulate_fleet
from bayescal.validation.sensor import PixelSensor, write_stacks
from tests.cli.conftest import laplace_fit_folder
from tests.conftest import MODELS

SPEC = str(MODELS / "seed000_bayer.toml")


@pytest.fixture(scope="module")
def inputs(tmp_path_factory, seed000):
    """Real inputs to break: a fit folder, a stack folder, a fleet table, a maps-kind folder."""
    root = tmp_path_factory.mktemp("inputs")
    spec, design = seed000
    table = root / "camera.csv"
    bc.simulate(spec, design, seed=5).table.write_csv(table)
    fit = root / "fit"
    laplace_fit_folder(table, fit)
    stacks = root / "stacks"
    write_stacks(PixelSensor(height=16, width=16), stacks, photons=[0.0, 3000.0], exposure_s=[0.1, 0.2], frames=2)
    fleet_table, _ = simulate_fleet(
        FleetDesign(n_cameras=2, campaigns=("2024-03-01", "2025-03-01"), n_pixels=16, n_frames=4), seed=1
    )
    fleet_table.to_csv(root / "fleet.csv", index=False)
    maps = root / "maps"
    with staged_directory(maps, kind="maps") as stage:
        stage("maps.nc").write_text("pixels")
    return {"root": root, "fit": fit, "stacks": stacks, "fleet": root / "fleet.csv", "maps": maps, "table": table}


def _run(capsys, argv) -> tuple[int, str]:
    try:
        rc = main([str(a) for a in argv])
    except SystemExit as exc:  # argparse's own errors
        rc = exc.code
    captured = capsys.readouterr()
    return rc, captured.err + captured.out


# --------------------------------------------------------------- options out of their domain
OPTION_CASES = [
    ("predict n-avg 0", ["predict", "{fit}", "--exposure-s", "0.01", "--n-avg", "0"], "above 0"),
    ("predict n-avg negative", ["predict", "{fit}", "--exposure-s", "0.01", "--n-avg", "-2"], "above 0"),
    (
        "predict exposure 0",
        ["predict", "{fit}", "--exposure-s", "0"],
        "--exposure-s: '0'; expected 0 < exposure <= 86400 s",
    ),
    ("predict exposure negative", ["predict", "{fit}", "--exposure-s", "-0.01"], "0 < exposure"),
    ("predict gain 0", ["predict", "{fit}", "--exposure-s", "0.01", "--gain", "0"], "--gain"),
    ("predict tdi negative", ["predict", "{fit}", "--exposure-s", "0.01", "--tdi-stages", "-2"], "--tdi-stages"),
    ("predict seed negative", ["predict", "{fit}", "--exposure-s", "0.01", "--seed", "-1"], "whole number >= 0"),
    ("predict seed text", ["predict", "{fit}", "--exposure-s", "0.01", "--seed", "abc"], "--seed"),
    ("predict exposure text", ["predict", "{fit}", "--exposure-s", "fast"], "expected a number"),
    ("invert n-avg 0", ["invert", "{fit}", "--dn", "500", "--channel", "G", "--n-avg", "0"], "--n-avg"),
    ("invert n-avg nan", ["invert", "{fit}", "--dn", "500", "--channel", "G", "--n-avg", "nan"], "finite"),
    ("invert dn inf", ["invert", "{fit}", "--dn", "inf", "--channel", "G"], "finite numbers"),
    ("maps fit-pixels 0", ["maps", "{stacks}", "--out", "{root}/m", "--fit-pixels", "0"], "--fit-pixels"),
    ("maps fit-pixels negative", ["maps", "{stacks}", "--out", "{root}/m", "--fit-pixels", "-5"], "whole number >= 1"),
    ("maps fit-pixels fraction", ["maps", "{stacks}", "--out", "{root}/m", "--fit-pixels", "2.5"], "whole number"),
    ("maps rows negative", ["maps", "{stacks}", "--out", "{root}/m", "--rows-per-chunk", "-5"], "--rows-per-chunk"),
    ("maps rows 0", ["maps", "{stacks}", "--out", "{root}/m", "--rows-per-chunk", "0"], "whole number >= 1"),
    ("maps rows text", ["maps", "{stacks}", "--out", "{root}/m", "--rows-per-chunk", "many"], "whole number"),
    (
        "plan exposure negative",
        ["plan", "{fit}", "--channel", "G", "--dn", "500", "--exposures", "0.004,-1"],
        "--exposures: '-1'; expected 0 < exposure",
    ),
    (
        "plan gain 0",
        ["plan", "{fit}", "--channel", "G", "--dn", "500", "--exposures", "0.004", "--gains", "0"],
        "--gains: '0'; expected 0 < gain",
    ),
    (
        "plan tdi 0",
        ["plan", "{fit}", "--channel", "G", "--dn", "5", "--exposures", "1", "--tdi-stages", "0"],
        "1 <= TDI",
    ),
    (
        "plan window reversed",
        ["plan", "{fit}", "--channel", "G", "--dn", "5", "--exposures", "1", "--window", "9,2"],
        "LOW",
    ),
    ("plan window one", ["plan", "{fit}", "--channel", "G", "--dn", "5", "--exposures", "1", "--window", "100"], "LOW"),
    ("plan top 0", ["plan", "{fit}", "--channel", "G", "--dn", "5", "--exposures", "1", "--top", "0"], "--top"),
    ("plan n-avg 0", ["plan", "{fit}", "--channel", "G", "--dn", "5", "--exposures", "1", "--n-avg", "0"], "--n-avg"),
    ("plan dn negative", ["plan", "{fit}", "--channel", "G", "--dn", "-5", "--exposures", "1"], "at least 0"),
    ("plan stimulus 0", ["plan", "{fit}", "--channel", "G", "--stimulus", "0", "--exposures", "1"], "above 0"),
    ("query probability 1.5", ["fleet-query", "{root}", "--camera", "A", "--probability", "1.5"], "between 0 and 1"),
    ("query probability 0", ["fleet-query", "{root}", "--camera", "A", "--probability", "0"], "between 0 and 1"),
    ("query probability negative", ["fleet-query", "{root}", "--camera", "A", "--probability", "-0.1"], "between"),
    ("query date words", ["fleet-query", "{root}", "--camera", "A", "--date", "next tuesday"], "is not a date"),
    ("query date impossible", ["fleet-query", "{root}", "--camera", "A", "--date", "2024-13-45"], "is not a date"),
    ("query date empty", ["fleet-query", "{root}", "--camera", "A", "--date", ""], "is not a date"),
    ("query drift 0", ["fleet-query", "{root}", "--camera", "A", "--drift-percent", "0"], "--drift-percent"),
    ("query drift negative", ["fleet-query", "{root}", "--camera", "A", "--drift-percent", "-3"], "above 0"),
    ("query drift new camera", ["fleet-query", "{root}", "--new-camera", "--drift-percent", "2"], "needs --camera"),
    (
        "query drift no date",
        ["fleet-query", "{root}", "--camera", "A", "--drift-percent", "2"],
        "needs --camera and --date",
    ),
    ("sbc sims 0", ["sbc", "{table}", "--model", SPEC, "--sims", "0", "--out", "{root}/s"], "--sims"),
    ("scene tol 0", ["scene", "{table}", "{fit}", "--tol", "0"], "--tol"),
    ("invert nothing", ["invert", "{fit}"], "give an IMAGE or --dn"),
    ("invert dn without channel", ["invert", "{fit}", "--dn", "500"], "--dn needs --channel"),
    ("invert image without out", ["invert", "{fit}", "{root}/img_ok.npy"], "needs --out DIR"),
]


# ------------------------------------------------------------------------------ images
def _images(root):
    """Image files, one fault each; returns name -> expected fragment."""
    cases = {
        "img_object.npy": (np.array([[1, "a"], [2, None]], dtype=object), "not an array of numbers"),
        "img_complex.npy": (np.ones((4, 4), complex), "complex values"),
        "img_empty.npy": (np.zeros((0, 0), np.uint16), "the image is empty"),
        "img_nan.npy": (np.where(np.eye(4) > 0, np.nan, 100.0), "are NaN or infinite (the first at (0, 0))"),
        "img_inf.npy": (np.full((4, 4), np.inf), "16 pixel(s) are NaN or infinite"),
        "img_negative.npy": (np.full((4, 4), -3.0), "are negative"),
        "img_negative_int.npy": (np.full((4, 4), -3, np.int16), "expected raw DN >= 0"),
        "img_1d.npy": (np.ones(8, np.uint16), "expected a 2-D image"),
        "img_4d.npy": (np.ones((2, 2, 2, 2), np.uint16), "expected a 2-D image"),
        "img_bool.npy": (np.ones((4, 4), bool), "boolean values"),
        "img_text.npy": (np.array([["a", "b"], ["c", "d"]]), "text values"),
        "img_above.npy": (np.full((4, 4), 65535, np.uint16), "exceed the calibration's full scale of 4095"),
    }
    np.save(root / "img_ok.npy", np.full((4, 4), 500, np.uint16))
    for name, (array, _) in cases.items():
        np.save(root / name, array, allow_pickle=True)
    (root / "img.jpg").write_bytes(b"\xff\xd8")
    return {name: fragment for name, (_, fragment) in cases.items()} | {"img.jpg": "unsupported image type"}


IMAGE_NAMES = [
    "img_object.npy",
    "img_complex.npy",
    "img_empty.npy",
    "img_nan.npy",
    "img_inf.npy",
    "img_negative.npy",
    "img_negative_int.npy",
    "img_1d.npy",
    "img_4d.npy",
    "img_bool.npy",
    "img_text.npy",
    "img_above.npy",
    "img.jpg",
]


# ------------------------------------------------------------------------ fleet designs
DESIGN_CASES = [
    ("n_frames = -3", "n_frames = -3; expected a whole number >= 1"),
    ("campaigns = []", "expected one or more ISO dates"),
    ('n_cameras = "twenty"', "n_cameras = 'twenty'; expected a whole number >= 2"),
    ("n_cameras = 1", "n_cameras = 1; expected a whole number >= 2"),
    ("n_cameras = true", "n_cameras = True"),
    ("n_pixels = 0", "n_pixels = 0"),
    ("n_frames = 2.5", "n_frames = 2.5"),
    ('campaigns = ["2024-13-45"]', "'2024-13-45' is not a date"),
    ('campaigns = ["2025-01-01", "2024-01-01"]', "in increasing order"),
    ("levels = []", "levels = []"),
    ("levels = [1.0, -2.0]", "levels entry = -2.0; expected a number above 0"),
    ("settle_years = 0", "settle_years = 0; expected a number above 0"),
    ("loss_range = [0.06, 0.01]", "expected LOW <= HIGH"),
    ("loss_range = [0.01]", "expected [LOW, HIGH]"),
    ("production_band = -0.1", "production_band = -0.1; expected at least 0"),
    ('campaign_jitter = "big"', "campaign_jitter = 'big'; expected a number"),
    ('brief = ["SN099"]', "camera 'SN099' is not among the design's cameras"),
    ('absent = [["SN001", "2030-01-01"]]', "absent campaign 2030-01-01 is not one of the campaigns"),
    ('brief = ["SN001"]\nbrief_levels = [99]', "index past the 12 levels"),
    ("levels = 5", "levels = 5; expected a list"),
]


# ------------------------------------------------------------------------ fleet tables
TABLE_CASES = [
    ("2124-01-01", "campaign date 2124-01-01 is in the future"),
    ("1900-01-01", "campaign date 1900-01-01 is before 1950"),
    ("next tuesday", "campaign date 'next tuesday' does not parse"),
]


# ------------------------------------------------------------------- folders of the wrong kind
FOLDER_CASES = [
    ("predict on maps", ["predict", "{maps}", "--exposure-s", "0.01"], "holds per-pixel maps"),
    ("invert on maps", ["invert", "{maps}", "--dn", "500", "--channel", "G"], "holds per-pixel maps"),
    ("plan on maps", ["plan", "{maps}", "--channel", "G", "--dn", "5", "--exposures", "1"], "holds per-pixel maps"),
    ("fleet-query on a fit", ["fleet-query", "{fit}", "--camera", "A"], "no fleet posterior"),
    (
        "report on maps",
        ["report", "{maps}"],
        "holds per-pixel maps (`bayescal maps`); `bayescal report` needs a calibration fit",
    ),
    ("report on a file", ["report", "{table}"], "is not a folder"),
    ("report on nothing", ["report", "{root}/nowhere"], "is not a folder"),
    (
        "invert maps is a fit",
        ["invert", "{fit}", "{root}/img_ok.npy", "--maps", "{fit}", "--exposure-s", "0.1", "--out", "{root}/r"],
        "holds a calibration fit",
    ),
    ("fit into maps", ["fit", "{table}", "--model", SPEC, "--backend", "lsq", "--out", "{maps}"], "holds per-pixel"),
    ("maps into a fit", ["maps", "{stacks}", "--out", "{fit}"], "holds a calibration fit"),
]


def _fill(argv, inputs):
    return [a.format(**inputs) if isinstance(a, str) else a for a in argv]


def test_the_corpus_is_large_enough():
    """The issue's floor: at least 80 bad inputs for the newer verbs."""
    n = len(OPTION_CASES) + len(IMAGE_NAMES) + len(DESIGN_CASES) + len(TABLE_CASES) + len(FOLDER_CASES) + 4
    assert n >= 80, n


@pytest.mark.parametrize(("name", "argv", "fragment"), OPTION_CASES + FOLDER_CASES, ids=lambda v: v)
def test_bad_options_and_folders(inputs, capsys, name, argv, fragment):
    _images(inputs["root"])
    rc, err = _run(capsys, _fill(argv, inputs))
    assert rc == 2, (name, err)
    assert fragment in err, (name, err)
    assert "Traceback" not in err


def test_bad_images_name_the_file_and_the_cause(inputs, capsys):
    fragments = _images(inputs["root"])
    for name in IMAGE_NAMES:
        path = inputs["root"] / name
        rc, err = _run(capsys, ["invert", inputs["fit"], path, "--channel", "G", "--out", inputs["root"] / "r"])
        assert rc == 2 and str(path) in err and fragments[name] in err, (name, err)
        assert not (inputs["root"] / "r").exists()


@pytest.mark.parametrize(("text", "fragment"), DESIGN_CASES)
def test_bad_fleet_designs_name_the_key(tmp_path, capsys, text, fragment):
    design = tmp_path / "design.toml"
    design.write_text(text + "\n")
    rc, err = _run(capsys, ["fleet-simulate", design, "--out", tmp_path / "t.csv"])
    assert rc == 2 and fragment in err and "design.toml" in err, err
    assert not (tmp_path / "t.csv").exists()


@pytest.mark.parametrize(("date", "fragment"), TABLE_CASES)
def test_bad_campaign_dates_name_row_and_column(inputs, tmp_path, capsys, date, fragment):
    frame = pd.read_csv(inputs["fleet"])
    frame["campaign"] = frame["campaign"].astype(str)
    frame.loc[3, "campaign"] = date
    frame.to_csv(tmp_path / "fleet.csv", index=False)
    rc, err = _run(capsys, ["fleet", tmp_path / "fleet.csv", "--model", SPEC, "--out", tmp_path / "f", "--quiet"])
    assert rc == 2 and fragment in err and "row 4, column 'campaign'" in err, err


def test_bad_stacks_name_the_file_frame_and_pixel(inputs, tmp_path, capsys):
    """Non-finite and negative pixels and object arrays in a stack folder (4 cases)."""
    conditions = pd.read_csv(inputs["stacks"] / "conditions.csv")
    first = conditions["file"].iloc[-1]
    original = np.load(inputs["stacks"] / first)

    def broken(array, fragment):
        work = tmp_path / f"s{len(list(tmp_path.iterdir()))}"
        work.mkdir()
        for name in conditions["file"]:
            (work / name).write_bytes((inputs["stacks"] / name).read_bytes())
        conditions.to_csv(work / "conditions.csv", index=False)
        np.save(work / first, array, allow_pickle=True)
        rc, err = _run(capsys, ["maps", work, "--out", tmp_path / "m", "--quiet"])
        assert rc == 2 and fragment in err and first in err and "Traceback" not in err, err
        assert not (tmp_path / "m").exists()

    nan = original.astype(np.float32)
    nan[1, 2, 3] = np.nan
    broken(nan, "frame 1, row 2, column 3 is nan")
    inf = original.astype(np.float64)
    inf[0, 5, 0] = -np.inf
    broken(inf, "frame 0, row 5, column 0 is -inf")
    negative = original.astype(np.int16)
    negative[0, 0, 1] = -7
    broken(negative, "expected raw DN >= 0")
    broken(original.astype(object), "object")
