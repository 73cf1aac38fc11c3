"""Per-pixel maps: known truth from an independent sensor simulator, the EMVA 1288 crop, bad input, the CLI.

The sensor (:mod:`bayescal.validation.sensor`) draws Poisson electrons, Normal
read noise, a log-normal dark-current spread and hot, dead and noisy pixels,
none of which the per-pixel model's code wrote.  Bounds come from Monte Carlo
error: with ~36,800 normal pixels, the sd of a coverage rate is ~0.0011, and
the 0.93-0.97 window is much wider than that.
"""

import json
import shutil

import numpy as np
import pandas as pd
import pytest

import bayescal as bc
from bayescal.maps.apply import apply_maps
from bayescal.maps.build import build_maps
from bayescal.maps.metadata import channel_attrs
from bayescal.maps.model import fit_map_model
from bayescal.maps.stacks import load_manifest, write_emva_stacks
from bayescal.maps.store import make_maps, read_maps, write_maps
from bayescal.validation.sensor import PixelSensor, write_stacks
from tests.conftest import DATA, MODELS

PHOTONS = [0.0, 3000.0, 10000.0, 30000.0]
EXPOSURES = [0.05, 0.1, 0.2, 0.4]
SENSOR = PixelSensor(height=192, width=192)


@pytest.fixture(scope="module")
def sensor(tmp_path_factory):
    root = tmp_path_factory.mktemp("stacks")
    truth = write_stacks(SENSOR, root, photons=PHOTONS, exposure_s=EXPOSURES, frames=4, seed=3)
    return root, truth


@pytest.fixture(scope="module")
def maps(sensor):
    root, _ = sensor
    return build_maps(root).load()


PARAMS = (("relative_gain", "relative_gain"), ("offset_dn", "offset_dn"), ("dark_current_dn_s", "dark_current_dn_s"))


def test_per_pixel_intervals_cover_and_beat_least_squares(sensor, maps):
    _, truth = sensor
    normal = truth.defect == 0
    for name, attr in PARAMS:
        true = getattr(truth, attr)
        est, sd, lsq = (maps[k].to_numpy() for k in (name, f"u_random_{name}", f"lsq_{name}"))
        cover = np.mean(np.abs(est - true)[normal] <= 1.96 * sd[normal])
        rmse = np.sqrt(np.mean((est - true)[normal] ** 2))
        rmse_lsq = np.sqrt(np.mean((lsq - true)[normal] ** 2))
        print(f"\n{name}: coverage {cover:.4f}, RMSE {rmse:.4g} (least squares {rmse_lsq:.4g})")
        assert 0.93 <= cover <= 0.97, name
        assert rmse < rmse_lsq, name  # shrinkage toward the population never loses on average
    # the dark current is weakly measured per pixel: pooling more than halves its error
    assert np.sqrt(np.mean((maps["dark_current_dn_s"] - truth.dark_current_dn_s).to_numpy()[normal] ** 2)) < 0.5 * (
        np.sqrt(np.mean((maps["lsq_dark_current_dn_s"] - truth.dark_current_dn_s).to_numpy()[normal] ** 2))
    )


def test_population_spreads_match_the_truth(sensor, maps):
    _, truth = sensor
    normal = truth.defect == 0
    for name, attr in PARAMS:
        true_sd = getattr(truth, attr)[normal].std()
        est, se = maps.attrs[f"spread_{name}"], maps.attrs[f"spread_{name}_se"]
        # the sample sd of the true values is itself within ~sd/sqrt(2N) of the population's: 5 se
        assert abs(est - true_sd) <= 5 * se + 3 * true_sd / np.sqrt(2 * normal.sum()), (name, est, se, true_sd)


def test_defects_are_found_and_classified(sensor, maps):
    _, truth = sensor
    defect = maps["defect"].to_numpy()
    for code, name in ((1, "hot"), (2, "dead"), (3, "noisy")):
        mine = truth.defect == code
        assert mine.sum() >= 10
        assert np.mean(defect[mine] > 0) >= 0.9, name
        assert np.mean(defect[mine] == code) >= 0.8, (name, np.bincount(defect[mine], minlength=6))
    assert np.sum(defect[truth.defect == 0] > 0) <= 5  # of ~36,800 normal pixels
    p = maps["defect_probability"].to_numpy()
    assert np.all((p >= 0) & (p <= 1))


def test_store_round_trip_with_units_and_error_correlation(sensor, maps, tmp_path):
    root, _ = sensor
    ds = build_maps(root, rows_per_chunk=40)  # uneven blocks: 192 = 4 x 40 + 32
    ticks = []
    write_maps(ds, tmp_path / "m", progress=lambda done, total: ticks.append((done, total)))
    back = read_maps(tmp_path / "m")
    assert ticks[-1] == (5, 5)
    np.testing.assert_allclose(back["relative_gain"].to_numpy(), maps["relative_gain"].to_numpy(), rtol=1e-6)
    assert back["relative_gain"].attrs["units"] == "1"
    assert back["relative_gain"].attrs["unc_comps"] == ["u_random_relative_gain", "u_systematic_relative_gain"]
    assert json.loads(back["u_random_offset_dn"].attrs["err_corr"])[0]["form"] == "random"
    assert json.loads(back.attrs["u_systematic_relative_gain_err_corr"])[0]["form"] == "systematic"
    assert back.attrs["bayescal_version"] == bc.__version__
    direct = make_maps(root, tmp_path / "k", rows_per_chunk=40)  # one task reads, maps and writes each block
    np.testing.assert_array_equal(direct["relative_gain"].to_numpy(), back["relative_gain"].to_numpy())
    write_maps(ds, tmp_path / "n", netcdf=True)
    nc = read_maps(tmp_path / "n")
    np.testing.assert_allclose(nc["offset_dn"].to_numpy(), maps["offset_dn"].to_numpy(), rtol=1e-6)


def test_interrupted_write_leaves_nothing(sensor, tmp_path):
    root, _ = sensor
    ds = build_maps(root)

    def boom(done, total):
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        write_maps(ds, tmp_path / "m", progress=boom)
    assert not (tmp_path / "m").exists()
    assert not [p for p in tmp_path.iterdir() if "staging" in p.name]


def test_corrected_image_intervals_cover(sensor, maps, tmp_path):
    """A new flat frame from the true sensor: each normal pixel's corrected signal interval covers
    the channel signal (what the pixel would read with the mean gain)."""
    _, truth = sensor
    new = tmp_path / "new"
    photons = 15000.0
    write_stacks(SENSOR, new, photons=[photons], exposure_s=0.15, frames=2, seed=3)  # same truth (seed 3)
    frame = np.load(new / "c00_flat.npy")[0]
    s = SENSOR
    normal = (truth.defect == 0) & (maps["defect"].to_numpy() == 0)
    true_signal = s.system_gain * s.qe * photons * truth.relative_gain[truth.defect == 0].mean()
    res = apply_maps(maps, frame, 0.15)
    lo, hi = res["lower"].to_numpy(), res["upper"].to_numpy()
    cover = np.mean((lo <= true_signal) & (true_signal <= hi), where=normal)
    print(f"\ncorrected-signal coverage {cover:.4f}; median half-width {np.nanmedian(hi - lo) / 2:.2f} DN")
    assert 0.93 <= cover <= 0.97
    assert np.all(np.isnan(res["median"].to_numpy()[maps["defect"].to_numpy() > 0]))


def test_radiance_through_a_channel_calibration_covers(sensor, maps, tmp_path):
    """With a (fixed, published-style) channel calibration the maps give radiance: L = photons / (1e5 t)."""
    from bayescal.model.spec import Reference

    _, truth = sensor
    new = tmp_path / "new"
    t, radiance = 0.15, 1.0
    write_stacks(SENSOR, new, photons=[1e5 * radiance * t], exposure_s=t, frames=2, seed=3)
    frame = np.load(new / "c00_flat.npy")[1]
    s = SENSOR
    names = list(maps.attrs["parameters"])
    mean = maps.attrs["population_mean"]
    dark = mean[names.index("offset_dn")] + mean[names.index("dark_current_dn_s")] * t
    a1 = s.system_gain * s.qe * 1e5 * t * truth.relative_gain[truth.defect == 0].mean()
    cal = bc.Calibration.from_coefficients({"M": [dark, a1]}, reference=Reference(t), bits=s.bits)
    res = apply_maps(maps, frame, t, calibration=cal)
    normal = (truth.defect == 0) & (maps["defect"].to_numpy() == 0)
    lo, hi = res["lower"].to_numpy(), res["upper"].to_numpy()
    cover = np.mean((lo <= radiance) & (radiance <= hi), where=normal)
    print(f"\nradiance coverage {cover:.4f}; median {np.nanmedian(res['median'].to_numpy()):.4f}")
    assert 0.93 <= cover <= 0.97
    assert res["median"].attrs["units"] == cal.unit


def test_bayer_mosaic_gets_one_population_per_colour(tmp_path):
    """A raw RGGB mosaic whose colours differ by 2.3x in signal: one population per colour, so the
    relative gains are relative to each colour's own signal and cover the truth."""
    sensor = PixelSensor(height=128, width=128, bayer="RGGB")
    truth = write_stacks(
        sensor, tmp_path, photons=[0.0, 3000.0, 8000.0, 20000.0], exposure_s=EXPOSURES, frames=4, seed=5
    )
    ds = build_maps(tmp_path, cfa="RGGB", rows_per_chunk=25).load()  # odd request: blocks start on whole cells
    assert ds.attrs["channels"] == ["R", "G", "B"] and ds.attrs["cfa"] == "RGGB"
    normal = truth.defect == 0
    est, sd = ds["relative_gain"].to_numpy(), ds["u_random_relative_gain"].to_numpy()
    assert 0.93 <= np.mean((np.abs(est - truth.relative_gain) <= 1.96 * sd)[normal]) <= 0.97
    for channel in ("R", "G", "B"):
        assert abs(channel_attrs(ds, channel)["spread_relative_gain"] - 0.01) < 0.002, channel
    signal = {c: json.loads(channel_attrs(ds, c)["stacks_table"])[-1]["signal_dn"] for c in "RGB"}
    assert signal["G"] / signal["B"] == pytest.approx(0.50 / 0.22, rel=0.02)
    res = apply_maps(ds, np.load(tmp_path / "c03_flat.npy")[0], 0.4)  # each plane through its own maps
    assert np.nanmedian(res["median"].to_numpy()[0::2, 0::2]) == pytest.approx(signal["R"], rel=0.02)


def test_dark_current_temperature_is_fitted_and_applied(tmp_path):
    """Darks at 10, 20 and 30 degC from a sensor whose dark current doubles every 7 degC: the shared
    doubling temperature is recovered, per-pixel intervals cover, and a frame taken at 30 degC is
    corrected with its own dark current (ignoring the temperature, half the intervals miss)."""
    sensor = PixelSensor(height=128, width=128, dark_current_e_s=200.0, doubling_c=7.0)
    photons, exposures, temps = [0, 0, 0, 3000, 10000, 30000], [0.4, 0.4, 0.4, 0.1, 0.2, 0.4], [10, 20, 30, 20, 20, 20]
    truth = write_stacks(sensor, tmp_path / "s", photons=photons, exposure_s=exposures, temperatures_c=temps, seed=2)
    ds = build_maps(tmp_path / "s").load()
    assert ds.attrs["temperature_ref_c"] == 20.0
    assert abs(ds.attrs["doubling_c"] - 7.0) < max(4 * ds.attrs["doubling_c_se"], 0.05)
    normal = truth.defect == 0
    for name in ("offset_dn", "dark_current_dn_s", "relative_gain"):
        est, sd = ds[name].to_numpy(), ds[f"u_random_{name}"].to_numpy()
        assert 0.93 <= np.mean((np.abs(est - getattr(truth, name)) <= 1.96 * sd)[normal]) <= 0.97, name
    write_stacks(sensor, tmp_path / "hot", photons=[5000], exposure_s=0.3, temperatures_c=[30], frames=2, seed=2)
    frame = np.load(tmp_path / "hot" / "c00_flat.npy")[0]
    true_signal = sensor.system_gain * sensor.qe * 5000 * truth.relative_gain[normal].mean()
    ok = normal & (ds["defect"].to_numpy() == 0)

    def cover(res):
        return np.mean(((res["lower"] <= true_signal) & (true_signal <= res["upper"])).to_numpy()[ok])

    assert 0.93 <= cover(apply_maps(ds, frame, 0.3, temperature_c=30.0)) <= 0.97
    assert cover(apply_maps(ds, frame, 0.3)) < 0.7


def test_same_maps_on_a_distributed_cluster(sensor, maps):
    """The row blocks computed in another process (tasks and results serialised), two at a time on its
    threads; one worker process, not two, keeps the test run's memory within its budget."""
    distributed = pytest.importorskip("distributed")
    root, _ = sensor
    with (
        distributed.LocalCluster(n_workers=1, threads_per_worker=2, processes=True, dashboard_address=None) as cluster,
        distributed.Client(cluster),
    ):
        remote = build_maps(root, rows_per_chunk=48).compute()
    np.testing.assert_allclose(remote["relative_gain"].to_numpy(), maps["relative_gain"].to_numpy(), rtol=1e-6)
    np.testing.assert_array_equal(remote["defect"].to_numpy(), maps["defect"].to_numpy())


def test_emva_crop_prnu_beside_the_standard(tmp_path):
    """refset001 crop: the PRNU posterior beside the standard's formula on the same pixels and the
    reference implementation's pixel PRNU of the full frame (0.2652 %)."""
    npz = DATA / "emva1288" / "refset001_ccd_12bit" / "crop128.npz"
    z = np.load(npz)
    ds = build_maps(write_emva_stacks(npz, tmp_path))
    assert (pd.read_csv(tmp_path / "conditions.csv").kind == "flat").sum() == 28  # 27 pairs below 70 % + the stack
    reference = json.loads((DATA / "emva1288" / "refset001_ccd_12bit" / "emva1288_reference_results.json").read_text())
    prnu, se = ds.attrs["spread_relative_gain"], ds.attrs["spread_relative_gain_se"]
    b, d = z["bright_stack"].astype(float), z["dark_stack"].astype(float)
    n = b.shape[0]
    s2y = b.mean(0).var() - b.var(0, ddof=1).mean() / n  # EMVA 1288 eq. 44-45, temporal part removed
    s2d = d.mean(0).var() - d.var(0, ddof=1).mean() / n
    standard_crop = np.sqrt(s2y - s2d) / (b.mean() - d.mean())
    print(
        f"\nPRNU {100 * prnu:.4f} % +- {100 * se:.4f}; standard on the crop {100 * standard_crop:.4f} %; "
        f"reference pixel PRNU (full frame) {reference['emva1288_results']['PRNU1288_pixel']:.4f} %"
    )
    assert abs(prnu - standard_crop) <= 4 * se + 0.02 * standard_crop
    assert abs(100 * prnu - reference["emva1288_results"]["PRNU1288_pixel"]) <= 0.1 * 100 * prnu
    # the dark non-uniformity of this CCD is far below its temporal noise: the stack exposure's DSNU is small
    i = int(np.argmin(np.abs(np.array(ds.attrs["dsnu_exposure_s"]) - float(z["dark_stack_texp"]) * 1e-9)))
    assert ds.attrs["dsnu_dn"][i] < 0.2


def test_bad_stacks_are_refused_by_name(sensor, tmp_path):
    root, _ = sensor
    work = tmp_path / "bad"
    shutil.copytree(root, work)
    table = pd.read_csv(work / "conditions.csv")

    def expect(match, frame=None):
        (frame if frame is not None else table).to_csv(work / "conditions.csv", index=False)
        with pytest.raises(bc.TableError, match=match):
            fit_map_model(load_manifest(work))

    expect("no dark stack", table[~((table.kind == "dark") & (table.condition == 2))])
    expect("column kind", table.assign(kind=table.kind.where(table.index != 1, "bright")))
    expect("column exposure_s", table.assign(exposure_s=table.exposure_s.where(table.index != 2, -1)))
    expect("per gain", table.assign(gain=np.where(table.index == 0, 2.0, 1.0)))
    np.save(work / "small.npy", np.zeros((4, 10, 10), np.uint16))
    expect("all frames must share one shape", table.assign(file=table.file.where(table.index != 3, "small.npy")))
    np.save(work / "one.npy", np.zeros((1, 192, 192), np.uint16))
    expect("at least 2", table.assign(file=table.file.where(table.index != 3, "one.npy")))
    data = (work / table.file[1]).read_bytes()
    (work / "cut.npy").write_bytes(data[: len(data) // 2])
    expect("cut.npy", table.assign(file=table.file.where(table.index != 1, "cut.npy")))
    np.save(work / "sat.npy", np.full((4, 192, 192), 4095, np.uint16))
    flat = int(np.flatnonzero(table.kind == "flat")[0])
    expect("saturated", table.assign(file=table.file.where(table.index != flat, "sat.npy")))
    np.save(work / "flat100.npy", np.full((4, 192, 192), 100, np.uint16))  # constant, far below full scale
    expect(
        "reads 100 DN in every frame; constant frames",
        table.assign(file=table.file.where(table.index != flat, "flat100.npy")),
    )
    clipped = np.minimum(np.random.default_rng(1).normal(4000, 200, (4, 192, 192)), 4095).astype(np.uint16)
    np.save(work / "clip.npy", clipped)  # 31 % of the readings at the 12-bit full scale
    expect(
        r"saturated \(3\d\.\d% of its pixel readings sit at full scale, 4095 DN\)",
        table.assign(file=table.file.where(table.index != flat, "clip.npy")),
    )
    np.save(work / "tiny.npy", np.ones((4, 1, 1), np.uint16))
    with pytest.raises(bc.TableError, match="1 x 1 pixels; per-pixel maps fit a population"):
        tiny = table.assign(file="tiny.npy")
        tiny.to_csv(work / "conditions.csv", index=False)
        load_manifest(work)
    expect("missing column", table.drop(columns="kind"))
    expect("column temperature_c", table.assign(temperature_c=["warm"] + [20.0] * (len(table) - 1)))
    (work / "conditions.csv").unlink()
    with pytest.raises(bc.TableError, match="no conditions.csv"):
        load_manifest(work)


def read_radiance(path):
    import xarray as xr

    return xr.open_dataset(path, engine="h5netcdf")


def _published_fit(path):
    """A tiny Laplace fit to stand in for the channel calibration the CLI loads."""
    spec = bc.load_spec(MODELS / "seed000_bayer.toml")
    design = bc.load_design(MODELS / "seed000_design.toml")
    bc.fit(bc.simulate(spec, design, seed=1).table, spec, "laplace").save(path)


def test_cli_maps_then_invert(sensor, tmp_path, capsys):
    from bayescal.cli import main

    root, _ = sensor
    assert main(["maps", str(root), "--out", str(tmp_path / "maps"), "--quiet", "--report"]) == 0
    assert "defects:" in capsys.readouterr().out
    page = (tmp_path / "maps" / "maps_report.html").read_text()
    assert page.count("data:image/png;base64,") == 3 and "spread of relative_gain" in page
    # a directory of someone else's files is refused before any work
    (tmp_path / "theirs").mkdir()
    (tmp_path / "theirs" / "notes.txt").write_text("keep me")
    assert main(["maps", str(root), "--out", str(tmp_path / "theirs"), "--quiet"]) == 2
    assert main(["maps", str(tmp_path / "nowhere"), "--out", str(tmp_path / "m2"), "--quiet"]) == 2
    # invert --maps needs the image's exposure; a wrong-shaped image is named
    np.save(tmp_path / "img.npy", np.full((10, 10), 500, np.uint16))
    fit_dir = tmp_path / "fit"
    _published_fit(fit_dir)
    args = [
        "invert",
        str(fit_dir),
        str(tmp_path / "img.npy"),
        "--maps",
        str(tmp_path / "maps"),
        "--out",
        str(tmp_path / "r"),
    ]
    assert main(args) == 2
    assert main([*args, "--exposure-s", "0.1"]) == 2
    assert "maps are 192 x 192" in capsys.readouterr().err
    np.save(tmp_path / "frame.npy", np.load(root / "c02_flat.npy")[0])
    args[2] = str(tmp_path / "frame.npy")
    assert main([*args, "--exposure-s", "0.2", "--channel", "G"]) == 0
    out = read_radiance(tmp_path / "r" / "radiance.nc")
    assert out.attrs["n_defective"] == int((read_maps(tmp_path / "maps")["defect"] > 0).sum())
    assert np.isfinite(out["median"].to_numpy()).mean() > 0.99


def test_quantisation_limited_sensor_has_no_false_noisy_pixels(tmp_path):
    """An 8-bit sensor with 0.2 DN of dark noise and levels spread over the codes: a pixel at a half code
    flips between two codes (about twice the channel's variance), one at a whole code shows almost none.
    The noisy-pixel test called half such pixels noisy; judged against what the rounding gives a normal
    pixel, none of the 16,220 normal pixels is noisy and every one of the 54 truly noisy pixels (8x the
    noise) is found."""
    sensor = PixelSensor(
        height=128,
        width=128,
        bits=8,
        system_gain=0.02,
        read_noise_e=10.0,
        offset_dn=4.5,
        dsnu_dn=1.0,
        prnu=0.01,
        dark_current_e_s=20.0,
        defect_fraction=0.01,
    )
    truth = write_stacks(sensor, tmp_path, photons=[0.0, 500.0, 2000.0], exposure_s=[0.05, 0.1, 0.1], frames=4, seed=1)
    maps = build_maps(tmp_path).load()
    found = maps["defect"].to_numpy() == 3
    noisy = truth.defect == 3
    assert noisy.sum() == 54
    assert found[noisy].mean() >= 0.95
    assert found[~noisy].sum() <= 5  # measured 0 (the old test: 9,531)
