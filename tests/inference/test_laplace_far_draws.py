"""The Laplace backend refuses its draws when they reach where the likelihood is far lower than a
Gaussian posterior allows: a parameter the data bound on one side only (a roll-off's knee above every
reading) makes the Gaussian at the mode spill past the cliff where the knee meets the data."""

import warnings

import numpy as np
from scipy.stats import chi2

import bayescal as bc
from bayescal.inference.samplers import FAR_TAIL, far_fraction
from bayescal.validation import BenchCamera, Departures, simulate_bench, with_held_out
from tests.conftest import MODELS


def test_gaussian_draws_are_never_far_and_a_contaminated_share_is_counted():
    """Draws of a d-dimensional Gaussian posterior: -2 log-likelihood ratio ~ chi2_d, beyond the
    1 - 1e-9 quantile with probability 1e-9 each, so none of 4000 is counted; 2 % moved onto a cliff are."""
    rng = np.random.default_rng(7)
    d, n = 30, 4000
    z = rng.standard_normal((n, d))
    loglik = np.repeat(-0.5 * np.sum(z**2, axis=1, keepdims=True) / 5, 5, axis=1)  # 5 rows share it
    assert far_fraction(loglik, d) == 0.0
    limit = 0.5 * chi2.isf(FAR_TAIL, d)
    loglik[:80] -= limit + 1.0  # beyond the limit even from the best draw
    assert far_fraction(loglik, d) == 80 / n
    loglik[80] = -np.inf  # a draw with no finite likelihood counts as far
    assert far_fraction(loglik, d) == 81 / n


def test_a_rolloff_above_the_readings_is_refused_by_laplace_and_a_linear_camera_is_not():
    frame, _ = simulate_bench(with_held_out(BenchCamera(), exposures=(0.01,)), Departures(), seed=1)
    table = bc.MeasurementTable.from_frame(frame)
    spec = bc.load_spec(MODELS / "seed000_bayer.toml")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        plain = bc.fit(table, spec, "laplace", seed=0)
        rolloff = bc.fit(table, spec.replace(response={"rolloff": True}), "laplace", seed=0)
    assert plain.diagnostics.extra["draws_far_off"] == 0.0
    assert rolloff.diagnostics.extra["draws_far_off"] > 0.01  # the knee's lower tail (4 % on this bench)
    assert not rolloff.ok
    assert any(
        "far lower than a Gaussian posterior allows" in p and "use nuts" in p for p in rolloff.diagnostics.problems
    )


def test_a_batch_refuses_far_draws_as_the_single_fit_does():
    """``fit_many`` (SBC, coverage runs) judges each dataset's Laplace draws with the same far-draw check:
    the roll-off bench's draws are refused there too, the linear camera's are not."""
    frame, _ = simulate_bench(with_held_out(BenchCamera(), exposures=(0.01,)), Departures(), seed=1)
    table = bc.MeasurementTable.from_frame(frame)
    spec = bc.load_spec(MODELS / "seed000_bayer.toml")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        plain = bc.fit_many([table], spec, "laplace", seed=0)
        rolloff = bc.fit_many([table], spec.replace(response={"rolloff": True}), "laplace", seed=0)
    assert list(plain.diagnostics["sampled"]) == [True]
    assert list(rolloff.diagnostics["sampled"]) == [False]
