"""Settings are measurements: effective gain, exposure and TDI factors, and misfit that is never absorbed."""

import warnings

import jax.numpy as jnp
import numpy as np
import pytest

import bayescal as bc
from bayescal.fitting.misfit import crossed_residuals, group_residuals, runs_z
from bayescal.model.components.settings import SettingFactors
from bayescal.model.spec import SettingsSpec


def _gain_step_off(table, factor: float, gain: float = 2.0):
    """The same table as if gain step ``gain`` were really ``factor`` x its label (truth offsets of seed 000)."""
    df = table.to_frame()
    lit = (df.gain == gain) & (df.radiance > 0)
    dark = 150.0 + 400.0 * df.loc[lit, "exposure_s"]  # the design's true offset and dark current at gain 2
    df.loc[lit, "dn_mean"] = dark + (df.loc[lit, "dn_mean"] - dark) * factor
    return bc.MeasurementTable.from_frame(df)


@pytest.fixture(scope="module")
def off_table(seed000):
    spec, design = seed000
    return _gain_step_off(bc.simulate(spec, design, seed=7).table, 0.95)


def test_log_factors_numpy_and_jax_agree():
    comp = SettingFactors(
        SettingsSpec(), (("gain", 4), ("exposure", 3), ("tdi", 1)), (("gain", 0), ("exposure", 1), ("tdi", 0))
    )
    assert comp.active() == ["gain", "exposure"]  # one TDI value, the reference: nothing to free
    logf = np.array([[0.01, -0.02]])
    np.testing.assert_array_equal(comp.log_factors("exposure", logf, xp=np), [[0.01, 0.0, -0.02]])
    np.testing.assert_allclose(np.asarray(comp.log_factors("exposure", jnp.asarray(logf))), [[0.01, 0.0, -0.02]])


def test_exact_settings_are_flagged_not_absorbed(seed000, off_table):
    """Gain step 2 really 1.9: a model that takes settings as exact must fail loudly and say where."""
    spec, _ = seed000
    exact = spec.replace(settings={"gain_tolerance": 0.0, "exposure_tolerance": 0.0})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", bc.FitFailedWarning)
        fit = bc.fit(off_table, exact, "laplace", seed=1)
    assert not fit.ok
    verdict = fit.diagnostics.verdict
    assert "excess scatter" in verdict and "x the noise floor" in verdict
    assert "gain 2 rows sit" in verdict and "below the model" in verdict and "settings.gain_tolerance" in verdict
    assert fit.diagnostics.extra["misfit"]["excess_ratio"] > 50


@pytest.mark.parametrize("backend", ["laplace", "nuts"])
def test_gain_factor_is_learned(seed000, off_table, backend):
    """With the default tolerances the fit passes, and the gain-2 factor's interval holds 0.95."""
    spec, _ = seed000
    fit = bc.fit(off_table, spec, backend, seed=1)
    assert fit.ok, fit.diagnostics.verdict
    f2 = fit.draws("setting_factor_gain")[:, 1]
    lo, hi = np.quantile(f2, [0.005, 0.995])
    assert lo <= 0.95 <= hi and hi - lo < 0.01  # pinned to well under 1 % by the sphere sweep
    assert np.all(fit.draws("setting_factor_gain")[:, 0] == 1.0)  # the reference step


def test_unmeasured_setting_carries_the_population_spread(seed000):
    """Prediction at an exposure never measured with light draws its factor from the population: wider than
    at a measured exposure of the same signal, reproducible, and exactly nominal at the reference."""
    spec, design = seed000
    cal = bc.Calibration.from_fit(bc.fit(bc.simulate(spec, design, seed=2).table, spec, "laplace", seed=2))
    measured = cal.ratio(bc.Setting(0.008)) / 2.0
    unmeasured = cal.ratio(bc.Setting(0.006)) / 1.5
    assert np.std(unmeasured) > 10 * np.std(measured)
    spread = cal.setting_factors[[f.kind for f in cal.setting_factors].index("exposure")].spread
    assert np.std(np.log(unmeasured)) == pytest.approx(np.sqrt(np.mean(spread**2)), rel=0.1)
    np.testing.assert_array_equal(cal.ratio(bc.Setting(0.006)), cal.ratio(bc.Setting(0.006)))
    np.testing.assert_array_equal(cal.ratio(bc.Setting(0.004)), 1.0)
    # against the sphere's own scale (its common 3 % would dominate both), the same expected signal:
    wide = bc.predict(cal, [15.0], bc.Setting(0.006), ["G"], n_avg=20480, relative=True)
    narrow = bc.predict(cal, [11.25], bc.Setting(0.008), ["G"], n_avg=20480, relative=True)
    assert (wide.pi_hi - wide.pi_lo).iloc[0] > 3 * (narrow.pi_hi - narrow.pi_lo).iloc[0]


def test_runs_statistic():
    alternating = np.array([1.0, -1.0] * 20)
    blocks = np.r_[np.ones(20), -np.ones(20)]
    assert runs_z(alternating) > 5 and runs_z(blocks) < -5
    rng = np.random.default_rng(0)
    z = np.array([runs_z(rng.standard_normal(40)) for _ in range(2000)])
    assert abs(z.mean()) < 0.1 and 0.9 < z.std() < 1.1  # ~Normal(0, 1) under independence


def test_group_residuals_closed_form():
    import pandas as pd

    frame = pd.DataFrame({"gain": [1.0, 1.0, 2.0, 2.0], "channel": ["R", "G", "R", "G"], "stimulus": [1, 1, 1, 0]})
    z = np.array([1.0, 1.0, -2.0, 5.0])
    g = group_residuals(frame, z, np.array([0.1, 0.2, -0.3, 9.0]), frame.stimulus.to_numpy() > 0)
    g1 = g[(g.column == "gain") & (g.value == 1.0)].iloc[0]
    assert g1.n == 2 and g1.z == pytest.approx(2 / np.sqrt(2)) and g1.rel_dev == pytest.approx(0.15)
    assert not ((g.column == "gain") & (g.value == 2.0)).any()  # one lit row: no group


def test_dark_rows_keep_distinct_level_labels(seed000):
    spec, design = seed000
    df = bc.simulate(spec, design, seed=1).table.to_frame()
    dark = df[df.radiance == 0]
    twice = dark.assign(level="dark1", dn_mean=dark.dn_mean + 0.2)
    df = df.assign(level=np.where(df.radiance == 0, "dark0", df.level))
    both = bc.MeasurementTable.from_frame(pd_concat(df, twice))
    assert len(both) == len(df) + len(dark)
    with pytest.raises(bc.TableError, match="repeats row"):
        bc.MeasurementTable.from_frame(pd_concat(df, dark.assign(level="dark0")))


def pd_concat(*frames):
    import pandas as pd

    return pd.concat(frames, ignore_index=True)


def test_fit_many_applies_the_misfit_checks_like_fit(seed000, off_table):
    """A dataset that fit() fails for misfit fails in fit_many too, with the same problems."""
    spec, _ = seed000
    exact = spec.replace(settings={"gain_tolerance": 0.0, "exposure_tolerance": 0.0})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", bc.FitFailedWarning)
        single = bc.fit(off_table, exact, "laplace", seed=3)
        batch = bc.fit_many([off_table], exact, "laplace", seeds=[3])
    assert not single.ok and not batch.ok.any()
    assert "gain 2 rows sit" in batch.diagnostics["misfit"].iloc[0]


def _grid_frame():
    """Three channels x four exposures x five levels, every row lit."""
    import pandas as pd

    rows = [(c, e, lv) for c in "RGB" for e in (0.004, 0.008, 0.01, 0.02) for lv in range(5)]
    return pd.DataFrame(rows, columns=["channel", "exposure_s", "level"]).assign(stimulus=1.0)


def test_crossed_groups_in_closed_form():
    frame = _grid_frame()
    z = np.zeros(len(frame))
    cell = (frame.channel == "G").to_numpy() & (frame.exposure_s == 0.01).to_numpy()
    z[cell] = 3.0  # five rows at +3 sd: the group's sum / sqrt(n) is 3 sqrt(5)
    rel = np.where(cell, 0.02, 0.0)
    crossed = crossed_residuals(frame, z, rel, np.ones(len(frame), bool))
    g = crossed[(crossed.channel == "G") & (crossed.column == "exposure_s") & (crossed.value == 0.01)].iloc[0]
    assert g.n == 5 and g.z == pytest.approx(3 * np.sqrt(5)) and g.rel_dev == pytest.approx(0.02)
    assert g["name"] == "channel G, exposure 0.01 s rows"
    # 3 channels x (4 exposures + 5 levels) groups, none from a column the frame lacks
    assert len(crossed) == 27 and set(crossed.column) == {"exposure_s", "level"}


def _checks(frame, z, excess_ratio):
    from bayescal.fitting.misfit import misfit_checks

    n = len(frame)
    ones = np.ones(n)
    excess = np.full(n, excess_ratio * 0.1)
    return misfit_checks(frame, z, np.zeros(n), ones, 100 * ones, 0.1 * ones, excess, np.zeros(n, bool))


def test_a_failing_fit_says_which_channel_at_which_setting_and_a_passing_one_is_not_failed_by_it():
    frame = _grid_frame()
    z = 0.05 * (-1.0) ** np.arange(len(frame))  # signs alternating: no runs along the signal or the order
    cell = (frame.channel == "G").to_numpy() & (frame.exposure_s == 0.01).to_numpy()
    z[cell] = 1.9  # the cell: z = 4.2; the exposure's rows 2.5, the channel's 2.1: neither fires alone
    problems, info = _checks(frame, z, excess_ratio=50.0)  # failed anyway: its scatter is inflated
    assert problems[0].startswith("the fitted excess scatter")
    assert len(problems) == 2 and problems[1].startswith("where it sits: channel G, exposure 0.01 s rows read")
    assert len(info["crossed_groups"]) == 27
    passing, _ = _checks(frame, z, excess_ratio=1.0)
    assert passing == []  # a crossed group alone never fails a fit
    z[(frame.exposure_s == 0.01).to_numpy()] = 1.9  # the whole exposure: its own group says it, not a channel
    problems, _ = _checks(frame, z, excess_ratio=50.0)
    assert not any(p.startswith("where it sits") for p in problems), problems


def test_a_channels_error_at_one_exposure_is_located_when_the_fit_fails(seed000):
    """The seed-000 campaign with G's readings at the 10 ms exposure 3 % high (no term draws a channel's error
    at one exposure): the fit fails for its inflated scatter and names that channel at that exposure."""
    spec, design = seed000
    df = bc.simulate(spec, design, seed=5).table.to_frame()
    cell = (df.channel == "G") & (df.exposure_s == 0.01) & (df.radiance > 0)
    df.loc[cell, "dn_mean"] *= 1.03
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = bc.fit(bc.MeasurementTable.from_frame(df), spec, "laplace", seed=0)
    assert not result.ok
    located = [p for p in result.diagnostics.problems if p.startswith("where it sits")]
    assert located and located[0].startswith("where it sits: channel G, exposure 0.01 s rows read"), located
