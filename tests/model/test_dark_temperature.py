"""Dark current against temperature (seed 002: doubles about every 7 degC): fitted doubling temperature,
dark predictions at unmeasured temperatures, flagged when extrapolating."""

import dataclasses
import warnings

import numpy as np
import pytest

import bayescal as bc
from bayescal.io.design import Block


def thermal_camera(spec, design):
    """Seed 000 with a dark current doubling every 7 degC and dark frames at 10, 20 and 30 degC."""
    spec = spec.replace(dark={"temperature": True, "temperature_ref_c": 20.0})
    truth = dataclasses.replace(
        design.truth,
        dark_doubling_c=7.0,
        temperature_ref_c=20.0,
        dark_slope={1.0: 2000.0, 2.0: 4000.0, 3.0: 6000.0, 4.0: 8000.0},
    )
    blocks = tuple(dataclasses.replace(b, temperature_c=(20.0,)) for b in design.illuminated)
    dark = (Block((0.0027, 0.004, 0.008, 0.01), (1.0, 2.0, 3.0, 4.0), temperature_c=(10.0, 20.0, 30.0)),)
    return spec, dataclasses.replace(design, illuminated=blocks, dark=dark, truth=truth)


@pytest.fixture(scope="module")
def thermal(seed000):
    spec, design = thermal_camera(*seed000)
    sim = bc.simulate(spec, design, seed=61)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", bc.FitFailedWarning)
        fit = bc.fit(sim.table, spec, "laplace", seed=61)
    return spec, sim, fit


def test_doubling_temperature_recovered(thermal):
    _, _, fit = thermal
    assert fit.ok, fit.diagnostics.verdict
    row = fit.summary.loc["doubling_c"]
    assert row["q2.5"] <= 7.0 <= row["q97.5"]
    assert row["q97.5"] - row["q2.5"] < 2.0  # three temperatures pin it to about +-0.5 degC


def test_dark_prediction_at_unmeasured_temperature(thermal):
    spec, sim, fit = thermal
    cal = bc.Calibration.from_fit(fit)
    hot = bc.Setting(0.01, 4.0, temperature_c=25.0)
    dark = cal.dark_dn("G", hot)
    true = 460.0 - 1.0 + 8000.0 * 0.01 * 2 ** (5 / 7)  # offset + channel offset + slope t 2^((T - 20) / 7)
    lo, hi = np.quantile(dark, [0.005, 0.995])
    assert lo <= true <= hi
    assert cal.flags(hot) == []
    assert any("temperature 40" in f for f in cal.flags(bc.Setting(0.01, 4.0, temperature_c=40.0)))


def test_temperature_column_required(seed000):
    spec, design = seed000
    sim = bc.simulate(spec, design, seed=62)  # no temperatures recorded
    with pytest.raises(bc.TableError, match="temperature_c"):
        bc.fit(sim.table, spec.replace(dark={"temperature": True}), "laplace")


@pytest.mark.slow  # 12 calibrations; the default run recovers T_d on one (test_doubling_temperature_recovered)
def test_doubling_temperature_coverage(seed000):
    """12 simulated cameras with T_d = 7 degC: the 95 % intervals cover it at the nominal rate."""
    spec, design = thermal_camera(*seed000)
    hits = []
    sims = [bc.simulate(spec, design, seed=700 + seed) for seed in range(12)]
    quick = spec.replace(inference={"holdout_check": False})  # coverage is the point here, not the misfit checks
    batch = bc.fit_many([sim.table for sim in sims], quick, "laplace", seeds=range(12))  # one vmapped program
    for seed in range(12):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", bc.FitFailedWarning)
            fit = batch.fit(seed)
        lo, hi = np.quantile(fit.draws("doubling_c"), [0.025, 0.975])
        hits.append(lo <= 7.0 <= hi)
    print(f"\nT_d 95 % coverage over 12 cameras: {np.mean(hits):.2f}")
    assert np.sum(hits) >= 9  # nominal 0.95: P(at most 8 of 12) = 0.002
