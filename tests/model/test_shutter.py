"""The shutter offset, an effect added as its own file, one registration line and this test file: fitted on
data from the independent bench, it covers the true offset and predicts an exposure never measured from
one physical number, more sharply than the generic exposure factors."""

import dataclasses
import warnings

import numpy as np
import pytest

import bayescal as bc
from bayescal.model.components.shutter import ShutterOffset
from bayescal.validation import BenchCamera, Departures, simulate_bench, with_held_out
from tests.conftest import MODELS

OFFSET_S = 3e-4  # the bench's sensor integrates 0.3 ms longer than it is set to


@pytest.fixture(scope="module")
def spec():
    return bc.load_spec(MODELS / "seed000_bayer.toml")


def _fit(spec, data, seed=0):
    table = data if isinstance(data, bc.MeasurementTable) else bc.MeasurementTable.from_frame(data)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", bc.FitFailedWarning)
        return bc.fit(table, spec, "laplace", seed=seed)


def test_off_unless_asked_for(spec):
    frame, _ = simulate_bench(seed=1)
    table = bc.MeasurementTable.from_frame(frame)
    assert not any(isinstance(e, ShutterOffset) for e in bc.build_model(table, spec).parts.effects)
    auto = spec.replace(shutter={"enabled": "auto"})
    assert any(isinstance(e, ShutterOffset) for e in bc.build_model(table, auto).parts.effects)


@pytest.mark.slow  # six cameras fitted twice (about a minute); test_simulated_with_a_true_offset stays by default
def test_the_offset_is_recovered_and_an_unmeasured_exposure_predicted(spec):
    """Calibrated at 4 and 10 ms only, 6 bench cameras x 3 channels x 2 radiances read at 8 ms: the shutter
    model's 95 % predictive intervals hold the bench's readings (>= 30 of 36; P ~ 2e-3 at the nominal rate)
    and, on the first three cameras, are narrower than those of exposures taken as free factors; its offset
    interval covers 0.3 ms (>= 4 of 6; P ~ 2e-3)."""
    camera = with_held_out(BenchCamera(), exposures=(0.008,))
    shutter = spec.replace(shutter={"enabled": True}, settings={"exposure_tolerance": 0.0})
    rng = np.random.default_rng(5)
    hits, offset_hits, widths = [], 0, {True: [], False: []}
    benches = [simulate_bench(camera, Departures(shutter_offset_s=OFFSET_S), seed=2100 + seed) for seed in range(6)]
    tables = [bc.MeasurementTable.from_frame(frame) for frame, _ in benches]
    with warnings.catch_warnings():  # one compiled program per model for all cameras
        warnings.simplefilter("ignore", bc.FitFailedWarning)
        batches = {
            True: bc.fit_many(tables, shutter, "laplace", seeds=range(6)),
            False: bc.fit_many(tables[:3], spec, "laplace", seeds=range(3)),
        }
    for seed, (_, real) in enumerate(benches):
        for model_shutter in (True, False)[: 2 if seed < 3 else 1]:
            fit = batches[model_shutter].fit(seed)
            assert fit.ok, fit.diagnostics.verdict
            cal = bc.Calibration.from_fit(fit)
            pred = bc.predict(cal, [6.0, 18.0], bc.Setting(0.008), n_avg=camera.n_frames * camera.n_pixels, seed=seed)
            widths[model_shutter] += list(pred.pi_hi - pred.pi_lo)
            if model_shutter:
                lo, hi = np.quantile(fit.draws("shutter_offset_s"), [0.025, 0.975])
                offset_hits += lo <= OFFSET_S <= hi
                for r in pred.itertuples():
                    hits.append(
                        r.pi_lo <= real.read(r.channel, r.stimulus * real.sphere_scale, 0.008, 1.0, rng) <= r.pi_hi
                    )
    assert np.sum(hits) >= 30, np.mean(hits)
    assert offset_hits >= 4, offset_hits
    assert np.median(widths[True]) < 0.5 * np.median(widths[False]), {k: np.median(v) for k, v in widths.items()}


@pytest.mark.slow  # a fit of bayescal's own simulator (11 s); the independent bench's shutter runs by default
def test_simulated_with_a_true_offset(spec, seed000):
    """bayescal's own simulator carries the effect too (``[truth.effects.shutter]``): the fit finds it."""
    _, design = seed000
    design = dataclasses.replace(
        design, truth=dataclasses.replace(design.truth, effects={"shutter": {"offset_s": 4e-4}})
    )
    s = spec.replace(shutter={"enabled": True}, settings={"exposure_tolerance": 0.0})
    fit = _fit(s, bc.simulate(s, design, seed=9).table, 9)
    row = fit.summary.loc["shutter_offset_s"]
    assert row["q2.5"] <= 4e-4 <= row["q97.5"] and row["q97.5"] - row["q2.5"] < 2e-4
    with pytest.raises(bc.SpecError, match="truth.effects.shutter"):
        bad = dataclasses.replace(design.truth, effects={"shutter": {"offset": 1e-4}})
        bc.simulate(s, dataclasses.replace(design, truth=bad), seed=1)
