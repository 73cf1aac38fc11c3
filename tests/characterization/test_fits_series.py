"""The shipped FITS flat/dark series (models/ccd_fits, written by models/make_fits_series.py from a
datasheet's values): it characterises by name, from a copy, and its posteriors cover the sensor that
made it."""

import importlib.util
import json

import numpy as np
import pytest

import bayescal as bc
from bayescal.cli.app import main
from bayescal.io.resources import example_path

pytestmark = pytest.mark.skipif(importlib.util.find_spec("astropy") is None, reason="needs bayescal[fits]")

#: the simulated sensor (models/make_fits_series.py): DSNU 2 DN at K = 0.28 DN/e-, PRNU 1 %
TRUE = {"K": 0.28, "QE": 45.0, "dark_current_mean": 30.0, "DSNU1288": 2.0 / 0.28, "PRNU1288": 1.0}


def test_the_fits_series_characterises_and_covers_its_sensor():
    res = bc.characterize(bc.load_steps(example_path("ccd_fits", "data")), seed=0)
    q = res.table.set_index("quantity")
    for name, true in TRUE.items():
        assert q.loc[name, "q2.5"] <= true <= q.loc[name, "q97.5"], (name, q.loc[name].to_dict())
    assert res.dark is not None and len(res.dark) == 3  # darks at 20, 100 and 200 ms: a dark current
    assert not res.problems
    assert res.operating["stack_images"] == 16 and res.operating["image_shape"] == [24, 24]


def test_a_copied_series_characterises_from_its_folder(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main(["examples", "--copy", "ccd_fits"]) == 0
    assert (tmp_path / "ccd_fits" / "EMVA1288_Data.txt").is_file()
    assert len(list((tmp_path / "ccd_fits").glob("*.fits"))) == 54 + 2 * 16  # pairs, and the two stacks
    assert main(["characterize", "ccd_fits", "--out", "ccd"]) == 0
    result = json.loads((tmp_path / "ccd" / "characterization.json").read_text())
    k = next(r for r in result["quantities"] if r["quantity"] == "K")
    assert np.isclose(k["standard"], 0.28, rtol=0.1)
    html = (tmp_path / "ccd" / "datasheet.html").read_text()
    plots = ("Dark signal", "Non-uniformity histograms", "Non-uniformity spectrograms", "Non-uniformity profiles")
    for plot in plots:  # every plot of the standard's datasheet
        assert f'<img alt="{plot}"' in html, plot
    # the printable form: a cover page (operating point, quantities) and a page per plot
    pdf = (tmp_path / "ccd" / "datasheet.pdf").read_bytes()
    assert pdf.startswith(b"%PDF")
    import re

    assert len(re.findall(rb"/Type\s*/Page[^s]", pdf)) == 1 + html.count("<img alt=")
