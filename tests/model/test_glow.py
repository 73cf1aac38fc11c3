"""Amplifier glow (a dark signal in t^2 per channel; an offset effect, added as one component file and
one registry line): fitted from dark frames at several exposures, covering its truth, carried into the
papers' A0 and into predictions, needed (without it the fit fails), and read from specs that still
name it ``[dark] glow``."""

import dataclasses

import numpy as np
import pytest

import bayescal as bc
from bayescal.model.components.glow import Glow
from tests.conftest import quiet_fit

TRUE = {"R": 6e4, "G": 2e4, "B": 4e4}  # DN/s^2 at the reference gain: 6, 2, 4 DN at 10 ms and gain 1


@pytest.fixture(scope="module")
def glowing(seed000):
    """Seed 000 (dark frames at 2.7, 4, 8 and 10 ms and four gains) with a glow in every channel."""
    spec, design = seed000
    truth = dataclasses.replace(design.truth, effects={"glow": {"dn_s2": dict(TRUE)}})
    sim = bc.simulate(spec, dataclasses.replace(design, truth=truth), seed=7)
    spec = spec.replace(glow={"enabled": True})
    return spec, sim, quiet_fit(sim.table, spec, seed=7)


def test_the_glow_is_fitted_and_covers_its_truth(glowing):
    _, _, fit = glowing
    assert fit.ok, fit.diagnostics.verdict
    assert any(isinstance(e, Glow) for e in fit.model.parts.effects)
    draws = fit.draws("dark_glow_dn_s2")
    for c, channel in enumerate(fit.model.layout.channels):
        lo, hi = np.quantile(draws[:, c], [0.0005, 0.9995])  # |z| < 3.3: a sure check on one dataset
        assert lo <= TRUE[channel] <= hi, (channel, lo, hi)
        assert hi - lo < 3e4  # ~2e4 measured: 1/70 of the prior's (0.05 full scale at 10 ms: sd 2e6)


def test_a0_and_predictions_carry_it(glowing):
    """A0 is the offset terms at the reference setting (1/250 s: the glow adds c t_ref^2, 0.96 DN in R);
    a prediction at gain 2 and 10 ms adds c t^2 g / g_ref to the dark level."""
    spec, sim, fit = glowing
    truth, t_ref = sim.truth, spec.reference.exposure_s
    a0 = fit.draws("A_rel")[..., 0]
    cal = bc.Calibration.from_fit(fit)
    setting = bc.Setting(0.01, 2.0)
    for c, channel in enumerate(fit.model.layout.channels):
        dark = truth.dark_offset[1.0] + truth.channel_offset[channel] + truth.dark_slope[1.0] * t_ref
        lo, hi = np.quantile(a0[:, c], [0.0005, 0.9995])
        assert lo <= dark + TRUE[channel] * t_ref**2 <= hi, (channel, lo, hi, dark)
        glow = cal.dark_dn(channel, setting) - cal.dark.offset(channel, setting, cal.n_draws)
        lo, hi = np.quantile(glow, [0.0005, 0.9995])
        assert lo <= TRUE[channel] * 0.01**2 * 2.0 <= hi, (channel, lo, hi)


def test_without_it_the_fit_fails(glowing):
    spec, sim, _ = glowing
    assert not quiet_fit(sim.table, spec.replace(glow={"enabled": False}), seed=7).ok  # channels 8-24 DN apart at 10 ms


def test_a_spec_that_names_it_in_the_dark_section_still_reads(seed000):
    spec, _ = seed000
    old = spec.to_dict()
    old.pop("glow")
    old["dark"] = old["dark"] | {"glow": True}
    assert bc.ModelSpec.from_dict(old).effect("glow").enabled is True
    both = old | {"glow": {"enabled": False}}  # the two names contradict each other: refused
    with pytest.raises(bc.SpecError, match="dark.glow = True and glow.enabled = False contradict each other"):
        bc.ModelSpec.from_dict(both)
    assert bc.ModelSpec.from_dict(old | {"glow": {"enabled": True}}).effect("glow").enabled is True
    with pytest.raises(bc.SpecError, match="glow"):
        bc.ModelSpec.from_dict(old | {"glow": {"prior_sd": -1.0}})
