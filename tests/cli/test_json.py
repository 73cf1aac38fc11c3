"""``--json``: every verb prints one JSON document on stdout for a script, holding what its text printed (the
text goes to stderr) and the JSON files of the folders it wrote; an error is a document too."""

import json

import pytest

from bayescal.cli import main
from bayescal.cli.parser import build
from tests.cli.conftest import laplace_fit_folder


def _document(capsys, argv) -> tuple[int, dict, str]:
    code = main([*argv, "--json"])
    captured = capsys.readouterr()
    lines = captured.out.strip().splitlines()
    assert len(lines) == 1, captured.out  # one document, nothing else on stdout
    return code, json.loads(lines[0]), captured.err


def test_every_verb_takes_json():
    parser = build()
    verbs = next(a for a in parser._actions if a.dest == "func" or a.__class__.__name__ == "_SubParsersAction")
    for name, verb in verbs.choices.items():
        assert any("--json" in a.option_strings for a in verb._actions), name


@pytest.fixture(scope="module")
def fitted(tmp_path_factory, good_csv):
    return laplace_fit_folder(good_csv, tmp_path_factory.mktemp("fit") / "FIT")


def test_a_fit_predictions_and_an_inversion_as_json(fitted, good_csv, tmp_path, capsys):
    argv = ["fit", str(good_csv), "--model", "seed000", "--backend", "laplace", "--no-diagnose", "--quiet"]
    code, doc, err = _document(capsys, [*argv, "--out", str(tmp_path / "F")])
    assert code == doc["exit"] == 0 and doc["verb"] == "fit" and doc["error"] is None and doc["ok"] is True
    (folder,) = doc["outputs"]
    summary = json.loads((tmp_path / "F" / "summary.json").read_text())
    assert folder["path"] == str(tmp_path / "F") and folder["json"]["summary.json"] == summary
    assert "Diagnostics" in err  # the text a person reads, on stderr

    code, doc, _ = _document(
        capsys, ["predict", str(fitted), "--exposure-s", "0.004", "--radiance", "10,20", "--channel", "R"]
    )
    assert code == 0 and [r["stimulus"] for r in doc["predictions"]] == [10, 20]
    row = doc["predictions"][0]
    assert row["pi_lo"] < row["ci_lo"] < row["dn_median"] < row["ci_hi"] < row["pi_hi"]
    assert doc["setting"]["exposure_s"] == 0.004

    dn = row["dn_median"]
    code, doc, _ = _document(
        capsys, ["invert", str(fitted), "--exposure-s", "0.004", "--dn", str(dn), "--channel", "R"]
    )
    assert code == 0 and len(doc["inversions"]) == 1
    (inv,) = doc["inversions"]
    assert inv["lower"] < 10 < inv["upper"] and inv["bound"] == "two-sided"  # the stimulus of that median


def test_examples_and_an_error_as_json(capsys, tmp_path):
    code, doc, _ = _document(capsys, ["examples"])
    assert code == 0 and {"seed000_bayer", "seed000_design"} <= {e["name"] for e in doc["examples"]}
    code, doc, err = _document(
        capsys, ["fit", str(tmp_path / "missing.csv"), "--model", "seed000", "--out", str(tmp_path / "F")]
    )
    assert code == doc["exit"] == 2 and "missing.csv" in doc["error"] and doc["outputs"] == []
    assert "missing.csv" in err
    with pytest.raises(SystemExit):  # not even a command line: still one document for the script
        main(["predict", "--json"])
    doc = json.loads(capsys.readouterr().out)
    assert doc["exit"] == 2 and "not understood" in doc["error"]
