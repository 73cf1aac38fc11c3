"""One-sided bounds, image inversion (Bayer mosaic, LUT equals per-value), predict/invert/plan CLI, bad input."""

import json

import numpy as np
import pytest
import tifffile
import xarray as xr

import bayescal as bc
from bayescal.cli import main
from bayescal.io.cfa import channel_map


@pytest.fixture(scope="module")
def calibrated(seed000, tmp_path_factory):
    spec, design = seed000
    sim = bc.simulate(spec, design, seed=21)
    fit = bc.fit(sim.table, spec, "laplace", seed=21)
    out = tmp_path_factory.mktemp("fit")
    fit.save(out)
    return spec, sim, bc.Calibration.from_fit(fit), out


def test_saturated_and_below_dark_are_one_sided(calibrated):
    spec, sim, cal, _ = calibrated
    setting = bc.Setting(0.004, 1.0)
    res = bc.invert(cal, np.array([4095, 4095.0, 20.0, 0.0]), "R", setting)
    assert list(res.bound) == [1, 1, 2, 2]
    assert np.all(np.isnan(res.median))
    assert np.all(np.isinf(res.upper[:2])) and np.all(res.lower[2:] == 0)
    # the lower bound of a clipped pixel lies below the radiance that just clips it, and is positive
    clip_l = (4095 - 52) / sim.truth.response["R"][0]
    assert 0.8 * clip_l < res.lower[0] < clip_l * 1.1
    # a bright true radiance that clips: the bound is honest (below the truth)
    rng = np.random.default_rng(0)
    dn = sim.reading(spec, "R", np.array([200.0]), 0.004, 1.0, rng=rng)
    assert dn[0] == 4095
    assert bc.invert(cal, dn, "R", setting).lower[0] <= 200.0
    # below dark: the upper bound is small and positive
    assert 0 < res.upper[2] < 1.0


def test_integer_image_lut_equals_per_value(calibrated):
    _, _, cal, _ = calibrated
    rng = np.random.default_rng(1)
    img = rng.integers(40, 4096, size=(64, 48)).astype(np.uint16)
    lut = bc.invert(cal, img, "G", seed=3)
    direct = bc.invert(cal, img.astype(float), "G", seed=3)
    for name in ("median", "lower", "upper", "bound"):
        np.testing.assert_array_equal(getattr(lut, name), getattr(direct, name))
    assert lut.median.shape == img.shape


def test_bayer_mosaic_inversion_recovers_flat_field(calibrated, tmp_path):
    spec, sim, cal, fitdir = calibrated
    rng = np.random.default_rng(2)
    h, w, true_l = 64, 80, 12.0
    letters = channel_map((h, w), "RGGB")
    img = np.zeros((h, w), np.uint16)
    for c in "RGB":
        m = letters == c
        img[m] = sim.reading(spec, c, np.full(m.sum(), true_l), 0.004, 1.0, rng=rng)
    ds = bc.invert_image(cal, img, bc.Setting(0.004, 1.0), cfa="RGGB")
    inside = (ds["lower"] <= true_l) & (true_l <= ds["upper"])
    assert float(inside.mean()) > 0.9
    assert abs(float(np.median(ds["median"])) / true_l - 1) < 0.05
    # through the CLI, from a TIFF, with the settings recorded
    tifffile.imwrite(tmp_path / "frame.tif", img)
    rc = main(
        [
            "invert",
            str(fitdir),
            str(tmp_path / "frame.tif"),
            "--cfa",
            "RGGB",
            "--exposure-s",
            "0.004",
            "--out",
            str(tmp_path / "maps"),
        ]
    )
    assert rc == 0
    nc = xr.open_dataset(tmp_path / "maps" / "radiance.nc", engine="h5netcdf")
    assert nc.attrs["exposure_s"] == 0.004 and nc.attrs["cfa"] == "RGGB"
    np.testing.assert_allclose(nc["median"].values, ds["median"].values)
    med = tifffile.TiffFile(tmp_path / "maps" / "median.tif")
    assert json.loads(med.pages[0].description)["gain"] == 1.0
    np.testing.assert_allclose(med.asarray(), ds["median"].values.astype(np.float32))


def test_predict_and_plan_cli(calibrated, tmp_path, capsys):
    _, _, cal, fitdir = calibrated
    out = tmp_path / "pred.csv"
    assert main(["predict", str(fitdir), "--exposure-s", "0.02", "--radiance", "10", "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert "EXTRAPOLATION" in err and "exposure 0.02 s outside the" in err and "measured with light" in err
    import pandas as pd

    table = pd.read_csv(out)
    g = table[table.channel == "G"].iloc[0]
    assert g.ci_lo < g.dn_median < g.ci_hi and g.pi_lo <= g.ci_lo and g.extrapolated
    expected = np.median(cal.expected_dn("G", 10.0, bc.Setting(0.02)))
    assert g.dn_median == pytest.approx(expected, rel=1e-6)
    assert (
        main(
            [
                "plan",
                str(fitdir),
                "--channel",
                "G",
                "--dn",
                "534",
                "--current",
                "0.004,1",
                "--exposures",
                "0.004,0.01",
                "--gains",
                "1,2",
            ]
        )
        == 0
    )
    assert "best: exposure 0.01 s, gain 1" in capsys.readouterr().out


def test_bad_prediction_inputs(calibrated, tmp_path):
    _, _, cal, fitdir = calibrated
    with pytest.raises(bc.TableError, match="channel 'X' was not calibrated"):
        bc.invert(cal, 100.0, "X")
    with pytest.raises(bc.TableError, match="0..4095"):
        bc.invert(cal, 5000.0, "G")
    with pytest.raises(bc.SpecError, match="gain 1.5 has no dark calibration"):
        bc.predict(cal, 10.0, bc.Setting(0.004, 1.5))
    with pytest.raises(bc.SpecError, match="exposure_s must be a positive"):
        bc.Setting(-1.0)
    with pytest.raises(bc.SpecError, match="clipped"):
        bc.plan_exposure(cal, "G", dn=4095.0, current=bc.Setting(0.004), exposures=[0.001])
    assert main(["invert", str(fitdir), "--dn", "100"]) == 2  # --dn without --channel
    assert main(["invert", str(tmp_path / "nowhere"), "--dn", "100", "--channel", "G"]) == 2
