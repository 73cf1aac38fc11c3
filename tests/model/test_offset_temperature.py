"""An offset that changes with temperature (an additive effect, added as one component file and one
registry line): fitted when the dark rows span temperatures, covering its truth, carried into the
dark level of predictions at temperatures never measured, and needed (without it the fit fails)."""

import dataclasses

import numpy as np
import pytest

import bayescal as bc
from bayescal.model.components.offset_temperature import OffsetTemperature
from bayescal.model.setting import Setting
from tests.conftest import quiet_fit

TRUE = {"R": 0.8, "G": -0.5, "B": 0.3}  # DN per degC
TEMPERATURES = (10.0, 20.0, 30.0)


def thermal(spec, design):
    """Seed 000 with its dark frames and sweeps at three sensor temperatures, its offsets following them."""
    blocks = tuple(dataclasses.replace(b, temperature_c=TEMPERATURES) for b in design.illuminated)
    dark = tuple(dataclasses.replace(b, temperature_c=TEMPERATURES) for b in design.dark)
    truth = dataclasses.replace(design.truth, effects={"offset_temperature": {"dn_per_c": dict(TRUE)}})
    return spec.replace(offset_temperature={"enabled": "auto"}), dataclasses.replace(
        design, illuminated=blocks, dark=dark, truth=truth
    )


@pytest.fixture(scope="module")
def thermal_fit(seed000):
    spec, design = thermal(*seed000)
    sim = bc.simulate(spec, design, seed=5)
    return spec, sim, quiet_fit(sim.table, spec, seed=5)


def test_the_offset_is_fitted_and_covers_its_truth(thermal_fit):
    _, _, fit = thermal_fit
    assert fit.ok, fit.diagnostics.verdict
    assert any(isinstance(e, OffsetTemperature) for e in fit.model.parts.effects)
    draws = fit.draws("offset_tc_dn_per_c")
    for c, channel in enumerate(fit.model.layout.channels):
        lo, hi = np.quantile(draws[:, c], [0.0005, 0.9995])  # |z| < 3.3: a sure check on one dataset
        assert lo <= TRUE[channel] <= hi, (channel, lo, hi)
        assert hi - lo < 0.2  # dark frames 20 degC apart pin it to ~0.03 DN/degC


def test_predictions_carry_it_into_the_dark_level(thermal_fit):
    """The dark level at 25 degC (never measured) minus that at 10 degC is 15 o_ch DN per draw."""
    _, _, fit = thermal_fit
    cal = bc.Calibration.from_fit(fit)
    ref = cal.reference
    at = {t: Setting(ref.exposure_s, ref.gain, ref.tdi_stages, temperature_c=t) for t in (10.0, 25.0)}
    for channel, true in TRUE.items():
        step = cal.dark_dn(channel, at[25.0]) - cal.dark_dn(channel, at[10.0])
        lo, hi = np.quantile(step, [0.0005, 0.9995])
        assert lo <= 15 * true <= hi, (channel, lo, hi)
    unstated = Setting(ref.exposure_s, ref.gain, ref.tdi_stages)  # the reference temperature: no offset added
    at_reference = Setting(ref.exposure_s, ref.gain, ref.tdi_stages, temperature_c=20.0)
    assert np.allclose(cal.dark_dn("R", unstated), cal.dark_dn("R", at_reference))


def test_without_it_the_fit_fails_and_auto_leaves_it_out_at_one_temperature(thermal_fit, seed000):
    spec, sim, _ = thermal_fit
    plain = quiet_fit(sim.table, spec.replace(offset_temperature={"enabled": False}), seed=5)
    assert not plain.ok  # readings 8 DN off at 10 and 30 degC
    one = sim.table.to_frame()
    one = one[one["temperature_c"] == 20.0].reset_index(drop=True)
    model = bc.build_model(bc.MeasurementTable.from_frame(one), spec)
    assert not any(isinstance(e, OffsetTemperature) for e in model.parts.effects)
