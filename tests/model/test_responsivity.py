"""The responsivity's temperature coefficient (an effect added as one component file): fitted when the
illuminated rows span temperatures, covering its truth, predicting readings at temperatures never
measured, left out when the table cannot inform it."""

import dataclasses

import numpy as np
import pytest
from scipy import stats

import bayescal as bc
from bayescal.model.components.responsivity import ResponsivityTemperature
from tests.conftest import quiet_fit

TRUE = {"R": 0.004, "G": 0.002, "B": -0.001}  # per degC: red rises fastest with temperature
TEMPERATURES = (10.0, 20.0, 30.0)


def thermal(spec, design, coefficients=TRUE, temperatures=TEMPERATURES):
    """Seed 000 with its sweeps repeated at three sensor temperatures and gains that follow them."""
    blocks = tuple(dataclasses.replace(b, temperature_c=temperatures) for b in design.illuminated)
    dark = tuple(dataclasses.replace(b, temperature_c=(20.0,)) for b in design.dark)
    truth = dataclasses.replace(design.truth, effects={"responsivity": {"coefficient_per_c": dict(coefficients)}})
    return spec, dataclasses.replace(design, illuminated=blocks, dark=dark, truth=truth)


@pytest.fixture(scope="module")
def thermal_fit(seed000):
    spec, design = thermal(*seed000)
    sim = bc.simulate(spec, design, seed=31)
    return spec, sim, quiet_fit(sim.table, spec, seed=31)


def test_the_effect_is_fitted_and_reported(thermal_fit):
    _, _, fit = thermal_fit
    assert fit.ok, fit.diagnostics.verdict
    assert any(isinstance(e, ResponsivityTemperature) for e in fit.model.parts.effects)
    assert any(
        line.startswith("responsivity: temperature coefficient") for line in fit.to_dict()["model"]["components"]
    )
    for channel, true in TRUE.items():
        row = fit.summary.loc[f"responsivity_tc[{channel}]"]
        assert row["q2.5"] <= true <= row["q97.5"], (channel, row)
        assert row["q97.5"] - row["q2.5"] < 0.002  # three temperatures 20 degC apart pin it to ~0.1 %/K


@pytest.mark.slow  # 12 calibrations; the default run checks the fitted effect and its predictions on one
def test_intervals_cover_the_truth_over_repeated_calibrations(seed000):
    """12 simulated calibrations x 3 channels: 95 % intervals of the coefficient cover at the nominal rate
    (at least 30 of 36; P = 0.004 for a correctly calibrated interval to fall below)."""
    spec, design = thermal(*seed000)
    tables = [bc.simulate(spec, design, seed=100 + i).table for i in range(12)]
    batch = bc.fit_many(tables, spec, "laplace", seed=100)
    covered = 0
    for i in range(len(tables)):
        draws = batch.physical(i)["responsivity_tc"].reshape(-1, 3)
        lo, hi = np.quantile(draws, [0.025, 0.975], axis=0)
        truth = np.array([TRUE[c] for c in batch.models[i].layout.channels])
        covered += int(np.sum((lo <= truth) & (truth <= hi)))
    assert stats.binom.cdf(29, 36, 0.95) < 0.005
    assert covered >= 30, covered


def test_readings_at_a_temperature_never_measured_are_predicted(thermal_fit):
    """At 25 degC, which the calibration never saw, fresh readings of the true camera fall inside the
    95 % predictive intervals at the nominal rate; without the coefficient they would not."""
    spec, sim, fit = thermal_fit
    cal = bc.Calibration.from_fit(fit)
    rng = np.random.default_rng(7)
    setting = bc.Setting(0.008, 1.0, temperature_c=25.0)
    inside, n = 0, 0
    for channel in ("R", "G", "B"):
        stim = np.linspace(3.0, 25.0, 12)
        pred = bc.predict(cal, stim, setting, [channel], n_avg=20480.0, seed=3)
        true_stim = stim * sim.sphere_scale
        fresh = sim.reading(spec, channel, true_stim, 0.008, 1.0, temperature_c=25.0, n_avg=20480.0, rng=rng)
        inside += int(np.sum((pred.pi_lo.to_numpy() <= fresh) & (fresh <= pred.pi_hi.to_numpy())))
        n += stim.size
    assert inside >= 0.85 * n, (inside, n)
    assert cal.flags(setting) == []
    assert any("temperature 45" in why for why in cal.flags(bc.Setting(0.008, temperature_c=45.0)))


def test_left_out_when_the_table_cannot_inform_it(seed000):
    spec, design = thermal(*seed000, temperatures=(20.0,))
    table = bc.simulate(spec, design, seed=32).table
    assert "temperature_c" in table.frame
    model = bc.build_model(table, spec)
    assert model.parts.effects == ()  # one temperature says nothing about a temperature coefficient
    plain = bc.simulate(*seed000, seed=33).table
    with pytest.raises(bc.TableError, match="temperature_c"):
        bc.build_model(plain, spec.replace(responsivity={"temperature": True}))


def test_spec_section_round_trips_and_rejects_typos(seed000, tmp_path):
    spec, _ = seed000
    changed = spec.replace(responsivity={"reference_c": 25.0, "coefficient_prior_sd": 0.02})
    path = tmp_path / "spec.toml"
    path.write_text(changed.to_toml())
    again = bc.load_spec(path)
    assert again.effect("responsivity") == changed.effect("responsivity")
    assert "[responsivity]" in path.read_text()
    path.write_text(changed.to_toml().replace("reference_c", "referense_c"))
    with pytest.raises(bc.SpecError, match="responsivity.referense_c.*did you mean 'responsivity.reference_c'"):
        bc.load_spec(path)


def test_a_model_without_it_does_not_fit_a_camera_that_has_it(seed000):
    """Leaving a 1 %/K coefficient out is not silently absorbed: the fit fails its misfit checks."""
    spec, design = thermal(*seed000, coefficients={"R": 0.01, "G": 0.01, "B": 0.01})
    table = bc.simulate(spec, design, seed=34).table
    fit = quiet_fit(table, spec.replace(responsivity={"temperature": False}))
    assert not fit.ok
    assert "misfit" in fit.diagnostics.verdict or "outlying" in fit.diagnostics.verdict
