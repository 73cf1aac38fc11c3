"""Ordinary lab facts the equation needs, and the checks that see them: nuisances against their priors, a
stimulus the darks do not see (stray light), a black level that jitters from frame to frame.

The departures come from the independent simulator (:mod:`bayescal.validation.wild`, which shares no code
with the model): a light leak of 4-20 % of the lowest level, a frame-common offset of 0.7-2.5 DN.
"""

import warnings

import numpy as np
import pandas as pd
import pytest

import bayescal as bc
from bayescal.fitting.misfit import frame_correlation
from bayescal.fitting.nuisance import CONFLICT_SD
from bayescal.validation.wild import FAMILIES, simulate_wild

SPEC = bc.load_spec("seed000")
#: sessions of the independent simulator with one departure (every family): a leak, a jittering black level
LEAK, JITTER = 38, 24


def _session(seed):
    frame, session = simulate_wild(seed, 1, families=tuple(FAMILIES))
    return bc.MeasurementTable.from_frame(frame), session


def _fit(table, spec):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return bc.fit(table, spec, "laplace", seed=1)


def _covers(fit, session) -> np.ndarray:
    truth = session.truth().set_index("channel")
    rel = fit.draws("A_rel")[..., :2]
    lo, hi = np.quantile(rel, [0.025, 0.975], axis=0)
    true = np.array([[truth.loc[c, "A0"], truth.loc[c, "A1"]] for c in fit.model.layout.channels])
    return (lo <= true) & (true <= hi)


@pytest.fixture(scope="module")
def leak():
    table, session = _session(LEAK)
    assert session.members["stray"] == "leak" and session.label() == "stray: leak"
    return table, session


def test_a_level_error_far_from_its_prior_fails_the_fit(leak):
    """Without a stray-light term the leak goes into the lowest levels' errors, which no other check sees
    here: the nuisance check names the level, its size and its prior, and the fit fails."""
    table, session = leak
    fit = _fit(table, SPEC)
    assert not fit.ok
    (problem,) = [p for p in fit.diagnostics.problems if p.startswith("nuisances far from their priors")]
    assert "the radiance error of sphere level L0 comes out +" in problem and "prior sd is 0.50%" in problem
    assert fit.diagnostics.extra["nuisances"]["sites"]["level_z"]["max_abs_sd"] > CONFLICT_SD
    assert not _covers(fit, session).all()


def test_stray_light_calibrates_the_leak(leak):
    table, session = leak
    fit = _fit(table, SPEC.replace(stray_light={"enabled": True}))
    assert fit.ok, fit.diagnostics.problems
    assert _covers(fit, session).all()
    stray = fit.draws("stray_stimulus")
    true = session.params["leak"] / session.sphere_scale  # in the sphere's nominal units
    z = (stray.mean(axis=0) - true) / stray.std(axis=0)
    assert np.all(np.abs(z) < 4.0), z
    assert fit.diagnostics.extra["nuisances"]["sites"]["level_z"]["max_abs_sd"] < CONFLICT_SD


@pytest.mark.slow
def test_the_diagnosis_adopts_stray_light(leak):
    table, session = leak
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fit, found = bc.fit_diagnosed(table, SPEC, "laplace", seed=1)
    assert fit.ok and found is not None
    assert found.adopted == ("stray light (a stimulus the dark frames do not see, per channel)",)
    assert _covers(fit, session).all()


def test_no_nuisance_conflict_on_the_models_own_data():
    """On data the model generated, no nuisance is far from its prior (two datasets of seed 000)."""
    design = bc.load_design("seed000")
    for seed in range(2):
        fit = _fit(bc.simulate(SPEC, design, seed=seed).table, SPEC)
        largest = max(s["max_abs_sd"] for s in fit.diagnostics.extra["nuisances"]["sites"].values())
        assert largest < CONFLICT_SD, (seed, fit.diagnostics.extra["nuisances"])


def test_a_jittering_black_level_is_seen_and_calibrated():
    table, session = _session(JITTER)
    assert session.members["black_level"] == "jitter"
    plain = _fit(table, SPEC)
    assert plain.diagnostics.extra["misfit"]["frame_z"] > 4.0
    assert any("the channels of one frame move together" in p for p in plain.diagnostics.problems)
    fit = _fit(table, SPEC.replace(frame_offset={"enabled": True}))
    assert fit.ok, fit.diagnostics.problems
    assert abs(fit.diagnostics.extra["misfit"]["frame_z"]) < 4.0
    assert _covers(fit, session).all()
    # the spread is learned from the offsets' draws, each of which carries its own estimation error (three
    # rows a frame): an upper estimate, within a factor of two of the jitter here (1.4 DN against 0.92)
    median = float(np.median(fit.draws("frame_offset_sd_dn")))
    assert 0.5 < median / session.params["jitter_dn"] < 2.0, (median, session.params["jitter_dn"])


def test_the_frame_correlation_statistic_is_standard_normal_under_the_model():
    """Independent residuals: over 400 tables of 64 frames of 3 channels, the statistic's mean and sd are
    0 and 1 within their Monte Carlo bounds (4 standard errors); a shared offset of one residual sd per
    frame moves it far out."""
    rng = np.random.default_rng(7)
    frame = pd.DataFrame({"time_s": np.repeat(np.arange(64.0), 3), "stimulus": 1.0})
    usable = np.ones(len(frame), dtype=bool)
    stats = np.array([frame_correlation(frame, rng.standard_normal(len(frame)), usable) for _ in range(400)])
    assert abs(stats.mean()) < 4 / np.sqrt(400)
    assert abs(stats.std() - 1.0) < 4 * np.sqrt(0.5 / 400) * 1.5  # sd of a sample sd, kurtosis allowed
    shared = np.repeat(rng.standard_normal(64), 3)
    assert frame_correlation(frame, rng.standard_normal(len(frame)) + shared, usable) > 4.0


def test_a_lamp_whose_colour_follows_its_level_is_calibrated():
    """The lamp's colour temperature falls as it is dimmed (Wien's law per band, in the independent
    simulator): each channel's stimulus trends over the levels, red against blue.  The lamp-colour term
    (linear in the log of the level) recovers each channel's change over the levels' range, and every
    coefficient lies within 3 posterior sds of the truth."""
    table, session = _session(17)
    assert session.members["lamp_colour"] == "tilt"
    fit = _fit(table, SPEC.replace(lamp_colour={"enabled": True}))
    assert fit.ok, fit.diagnostics.problems
    change = fit.draws("lamp_colour_change")
    true = session.lamp_colour(len(session.level_error) - 1) / session.lamp_colour(0) - 1.0
    z = (change.mean(axis=0) - true) / change.std(axis=0)
    assert np.all(np.abs(z) < 4.0), (change.mean(axis=0), true)
    assert change.mean(axis=0)[0] < 0 < change.mean(axis=0)[2]  # red falls against blue as the lamp brightens
    truth = session.truth().set_index("channel")
    rel = fit.draws("A_rel")[..., :2]
    expected = np.array([[truth.loc[c, "A0"], truth.loc[c, "A1"]] for c in fit.model.layout.channels])
    assert np.all(np.abs(rel.mean(axis=0) - expected) < 3.0 * rel.std(axis=0))


def test_the_variances_are_checked_against_the_noise_the_spec_implies():
    """The table's temporal variances against the spec's photon transfer: on the model's own data every
    group's ratio is 1 within 2 %; with a conversion gain 46 % high (the real 8-bit sensor's error) every
    channel's variances are named as about 30 % below and the fit fails."""
    table = bc.simulate(SPEC, bc.load_design("seed000"), seed=4).table
    fit = _fit(table, SPEC)
    groups = fit.diagnostics.extra["variance"]["groups"]
    assert len(groups) >= 6 and all(abs(g["ratio"] - 1.0) < 0.02 for g in groups), groups
    wrong = _fit(table, SPEC.replace(noise={"conversion_gain": 0.25 * 1.46}))
    assert not wrong.ok
    named = [p for p in wrong.diagnostics.problems if "the measured temporal variances (dn_var) sit" in p]
    assert len(named) == 3 and all("below what the spec's noise implies" in p for p in named), named
