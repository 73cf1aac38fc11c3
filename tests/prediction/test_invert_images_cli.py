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
    assert main(["predict", str(fitdir), "--exposure-s", "0.02", "--radiance", "10,15.9973", "--out", str(out)]) == 0
    printed = capsys.readouterr()
    err = printed.err
    assert "15.9973" in printed.out  # the radiance asked for, not rounded to 16
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
    # a gain the calibration has no dark level for is not ranked, and the plan says so, by setting
    plan = bc.plan_exposure(cal, "G", stimulus=5.0, exposures=[0.004], gains=[1.0, 7.0])
    assert list(plan.table.gain) == [1.0] and list(plan.dropped.gain) == [7.0]
    assert "7" in plan.dropped.why.iloc[0]
    argv = ["plan", str(fitdir), "--channel", "G", "--radiance", "5", "--exposures", "0.004", "--gains", "1,7"]
    assert main(argv) == 0
    assert "DROPPED: exposure 0.004 s, gain 7, TDI 1:" in capsys.readouterr().err


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


# ------------------------------------------------------------------ per-DN tables, surveys of frames
def _per_value(cal, image, views, setting):
    """Each channel's pixels inverted value by value (float64), cast as the maps are."""
    expect = {k: np.full(image.shape, np.nan, np.float32) for k in ("median", "lower", "upper")}
    bound = np.zeros(image.shape, np.int8)
    for index, name in views:
        res = bc.invert(cal, image[index], name, setting)
        for k in expect:
            expect[k][index] = getattr(res, k)
        bound[index] = res.bound
    return expect, bound


@pytest.mark.parametrize("layout", ["RGGB odd width", "GBRG", "stack", "mono"])
def test_gathered_maps_equal_per_value_inversion(calibrated, layout):
    from bayescal.prediction.images import channel_views

    _, _, cal, _ = calibrated
    rng = np.random.default_rng(5)
    setting = bc.Setting(0.004, 1.0)
    if layout == "stack":
        image, kw = rng.integers(0, 4096, size=(37, 29, 3), dtype=np.uint16), {"channels": ["B", "G", "R"]}
    elif layout == "mono":
        image, kw = rng.integers(0, 4096, size=(130, 9)).astype(np.int64), {"channel": "G"}
    else:
        image, kw = rng.integers(0, 4096, size=(131, 47), dtype=np.uint16), {"cfa": layout.split()[0]}
    image.flat[:3] = [4095, 4095, 0]  # clipped and dark pixels in every layout
    ds = bc.invert_image(cal, image, setting, **kw)
    expect, bound = _per_value(cal, image, channel_views(image, **kw), setting)
    for k in expect:
        np.testing.assert_array_equal(ds[k].values, expect[k])
    np.testing.assert_array_equal(ds["bound"].values, bound)
    assert ds.attrs["n_saturated"] == int(np.sum(bound == 1)) > 0
    assert ds.attrs["n_below_dark"] == int(np.sum(bound == 2)) > 0
    assert ds.attrs["n_extrapolated"] == int(ds["extrapolated"].values.astype(bool).sum())


def test_tables_are_computed_once_and_only_for_present_values(calibrated, monkeypatch):
    from bayescal.prediction import invert as inv
    from bayescal.prediction.tables import TableKey, table

    _, _, cal0, _ = calibrated
    cal = bc.Calibration(**{f: getattr(cal0, f) for f in cal0.__dataclass_fields__ if f != "tables"})
    setting = bc.Setting(0.004, 1.0)
    image = np.random.default_rng(6).integers(300, 420, size=(40, 40), dtype=np.uint16)
    first = bc.invert_image(cal, image, setting, channel="R")
    key = TableKey.of("R", setting, n_avg=1.0, prnu=cal.prnu, level=0.95, noise=True, seed=0)
    assert int(table(cal, key, [])["known"].sum()) == len(np.unique(image))  # a 16-bit camera never fills 65,536
    monkeypatch.setattr(inv, "value_summaries", lambda *a, **k: pytest.fail("the table was computed again"))
    again = bc.invert_image(cal, image[::-1], setting, channel="R")
    np.testing.assert_array_equal(again["median"].values, first["median"].values[::-1])


def test_tables_kept_beside_the_posterior(calibrated, tmp_path, monkeypatch):
    import shutil

    from bayescal.io.outputs import verify_output
    from bayescal.prediction import invert as inv
    from bayescal.prediction import tables

    _, _, _, fitdir = calibrated
    mine = tmp_path / "fit"
    shutil.copytree(fitdir, mine)
    setting = bc.Setting(0.004, 1.0)
    image = np.random.default_rng(7).integers(0, 4096, size=(20, 30), dtype=np.uint16)
    cal = bc.Calibration.load(mine)
    assert cal.folder is not None and cal.folder.root == mine  # the tables' place: the folder it was read from
    assert "posterior" not in vars(cal.folder)  # its address only: the opened posterior is not held open
    first = bc.invert_image(cal, image, setting, cfa="BGGR")
    written = tables.persist_tables(cal)
    assert len(written) == 3 and all(p.parent == mine for p in written)
    assert oct(written[0].stat().st_mode & 0o777) == oct(0o666 & ~_current_umask())
    info = verify_output(mine, ("fit",), verb="test")  # the tables are the run's own files now
    assert {p.name for p in written} <= set(info.files)
    assert tables.persist_tables(cal) == []  # nothing grew since
    again = bc.Calibration.load(mine)
    assert tables.restore_tables(again) == 3
    monkeypatch.setattr(inv, "value_summaries", lambda *a, **k: pytest.fail("a kept table was computed again"))
    np.testing.assert_array_equal(bc.invert_image(again, image, setting, cfa="BGGR")["upper"], first["upper"])
    monkeypatch.undo()
    # tables of another posterior (or another bayescal) are not used
    monkeypatch.setattr(tables, "_identity", lambda sha: {"format": 1, "posterior_sha256": "0" * 64})
    assert tables.restore_tables(bc.Calibration.load(mine)) == 0


def _current_umask() -> int:
    import os

    mask = os.umask(0)
    os.umask(mask)
    return mask


def _frames(tmp_path, n=3):
    rng = np.random.default_rng(8)
    paths = []
    for k in range(n):
        paths.append(tmp_path / "survey" / f"f{k}.npy")
        paths[-1].parent.mkdir(exist_ok=True)
        np.save(paths[-1], rng.integers(0, 4096, size=(24, 32), dtype=np.uint16))
    return paths


def test_survey_of_frames_one_folder_each(calibrated, tmp_path, capsys):
    from bayescal.io.outputs import verify_output

    _, _, cal, fitdir = calibrated
    paths = _frames(tmp_path)
    out = tmp_path / "out"
    args = ["invert", str(fitdir), str(tmp_path / "survey" / "f*.npy"), "--cfa", "RGGB", "--exposure-s", "0.004"]
    assert main([*args, "--out", str(out)]) == 0
    assert "inverted 3 frames (2304 pixels)" in capsys.readouterr().out
    for p in paths:
        verify_output(out / p.stem, ("radiance",), needs=("radiance.nc",), verb="test")
        nc = xr.open_dataset(out / p.stem / "radiance.nc", engine="h5netcdf")
        direct = bc.invert_image(cal, np.load(p), bc.Setting(0.004, 1.0), cfa="RGGB")
        np.testing.assert_array_equal(nc["median"].values, direct["median"].values)
        assert nc.attrs["image"] == str(p)
    # a folder of the user's at one frame's target stops the survey before any frame is written
    (tmp_path / "out2" / "f1").mkdir(parents=True)
    (tmp_path / "out2" / "f1" / "notes.txt").write_text("mine")
    assert main([*args, "--out", str(tmp_path / "out2")]) == 2
    assert sorted(p.name for p in (tmp_path / "out2").iterdir()) == ["f1"]
    assert (tmp_path / "out2" / "f1" / "notes.txt").read_text() == "mine"
    # two frames with one name would write one folder
    (tmp_path / "other").mkdir()
    np.save(tmp_path / "other" / "f0.npy", np.load(paths[0]))
    rc = main(
        [
            "invert",
            str(fitdir),
            str(paths[0]),
            str(tmp_path / "other" / "f0.npy"),
            "--cfa",
            "RGGB",
            "--out",
            str(tmp_path / "out3"),
        ]
    )
    assert rc == 2 and "distinct names" in capsys.readouterr().err
    assert main([*args[:2], str(tmp_path / "survey" / "g*.npy"), "--cfa", "RGGB", "--out", str(out)]) == 2


def test_survey_on_a_dask_cluster(calibrated, tmp_path):
    distributed = pytest.importorskip("distributed")
    import shutil

    from bayescal.prediction.frames import FrameJob, invert_frames

    _, _, _, fitdir = calibrated
    mine = tmp_path / "fit"
    shutil.copytree(fitdir, mine)
    cal = bc.Calibration.load(mine)
    paths = _frames(tmp_path, 2)
    jobs = [
        FrameJob(str(mine), str(p), str(tmp_path / "out" / p.stem), 0.004, 1.0, 1.0, None, cfa="GRBG") for p in paths
    ]
    with distributed.LocalCluster(n_workers=1, threads_per_worker=2, processes=False, dashboard_address=":0") as lc:
        results = invert_frames(cal, jobs, scheduler=lc.scheduler_address)
    assert [r["image"] for r in results] == [str(p) for p in paths]
    assert len(list(mine.glob("inversion-*.npz"))) == 3  # every value computed once, before the workers start
    for p in paths:
        nc = xr.open_dataset(tmp_path / "out" / p.stem / "radiance.nc", engine="h5netcdf")
        direct = bc.invert_image(cal, np.load(p), bc.Setting(0.004, 1.0), cfa="GRBG")
        np.testing.assert_array_equal(nc["lower"].values, direct["lower"].values)


@pytest.mark.parametrize("name", ["seed000_frame.tif", "seed000_frame.fits"])
def test_the_shipped_frame_inverts_to_its_scene(calibrated, tmp_path, name):
    """The example raw frame (``models/make_frames.py``: a radiance ramp with a darker disc, read by the
    seed-000 camera) inverted with a fit of that camera: the 95 % intervals of its 3072 pixels cover the
    scene at least at their nominal rate less 0.05 (binomial sd 0.004; they share the sphere's 3 % scale
    doubt, so they may cover more), and are not wider than a third of the radiance for most pixels, as
    TIFF and as FITS."""
    import importlib.util

    import tifffile

    from bayescal.io.resources import models_dir

    _, _, _, fitdir = calibrated
    spec = importlib.util.spec_from_file_location("make_frames", models_dir() / "make_frames.py")
    make = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(make)
    y, x = np.mgrid[0 : make.HEIGHT, 0 : make.WIDTH]
    scene = 2.0 + 38.0 * x / (make.WIDTH - 1)
    scene = np.where((y - make.HEIGHT / 2) ** 2 + (x - make.WIDTH / 2) ** 2 < 10**2, 0.5 * scene, scene)
    argv = ["invert", str(fitdir), str(models_dir() / name), "--cfa", "RGGB", "--exposure-s", "0.004"]
    assert main([*argv, "--gain", "1", "--out", str(tmp_path / "radiance")]) == 0
    lower, upper = (tifffile.imread(tmp_path / "radiance" / f"{b}.tif") for b in ("lower", "upper"))
    covered = np.mean((lower <= scene) & (scene <= upper))
    assert covered >= 0.9, covered
    assert np.percentile((upper - lower) / scene, 90) < 1 / 3  # measured: 0.15 median, 0.26 at the 95th
