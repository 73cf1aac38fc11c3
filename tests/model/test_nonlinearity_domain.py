"""Where the nonlinearity arises: the sense node's charge (before the gain) or the output (after it).

The bench (:mod:`bayescal.validation.bench`, written apart from the model) compresses the charge,
``S = g (R e + C e^2)``, as a CCD's sense node does (seed 004's V/Q nonlinearity): at gain 4 a
reading of 2000 DN is a quarter of the charge of one at gain 1 and is compressed a quarter as
much.  A response whose nonlinearity is a function of the DN sees the gain sweep's bright rows
as too straight and pulls its quadratic term toward zero.
"""

import dataclasses
import warnings

import numpy as np
import pytest

import bayescal as bc
from bayescal.fitting.select import compare_specs, order_candidates
from bayescal.model.components import Response, ResponseSpec
from bayescal.model.spec import Reference
from bayescal.prediction.invert import radiance_draws
from bayescal.validation import BenchCamera, Departures, simulate_bench


def test_charge_coefficients_are_g_times_s_of_x_over_g():
    rng = np.random.default_rng(0)
    coef = np.array([30.0, -0.004, 2e-5])  # A1, A2, A3
    x = rng.uniform(0.0, 120.0, 50)
    for g in (0.5, 1.0, 2.0, 4.0):
        direct = g * Response.signal(coef, x / g)
        assert np.allclose(Response.signal(Response.at_gain(coef, np.asarray(g)), x), direct, rtol=1e-12)
    # at the reference gain both domains are the same response; only the charge's moves with the gain
    gains = np.array([1.0, 3.0])
    charge = Response(ResponseSpec(order=3, nonlinearity_domain="charge"), 1)
    output = Response(ResponseSpec(order=3), 1)
    rows = np.tile(coef, (2, 1))
    assert np.allclose(charge.coefficients_at(rows, gains)[0], coef)
    assert np.allclose(charge.coefficients_at(rows, gains)[1], [30.0, -0.004 / 3, 2e-5 / 9])
    assert np.array_equal(output.coefficients_at(rows, gains), rows)


def test_predictions_and_inversion_follow_the_charge():
    ref = Reference(exposure_s=0.004)
    cal = bc.Calibration.from_coefficients({"G": [50.0, 30.0, -0.01]}, reference=ref, bits=12, dark_proportional=True)
    charge = dataclasses.replace(cal, charge_nonlinearity=True)
    radiance = np.array([5.0, 20.0, 40.0])
    for gain in (1.0, 2.0, 4.0):
        setting = bc.Setting(ref.exposure_s, gain)
        e = radiance  # radiance-equivalent charge at the reference exposure
        by_hand = 50.0 * gain + gain * (30.0 * e - 0.01 * e**2)
        assert np.allclose(charge.expected_dn("G", radiance, setting)[0], by_hand, rtol=1e-12)
        out = 50.0 * gain + 30.0 * gain * e - 0.01 * (gain * e) ** 2
        assert np.allclose(cal.expected_dn("G", radiance, setting)[0], out, rtol=1e-12)
        # the inversion is the prediction's inverse in both domains
        for c in (cal, charge):
            dn = c.expected_dn("G", radiance, setting)[0]
            assert np.allclose(radiance_draws(c, "G", dn, setting)[:, 0], radiance, rtol=1e-10)


@pytest.fixture(scope="module")
def sense_node_bench(seed000):
    """One bench camera (gain steps 1-4, 12 levels), exact sphere so only the response is in question."""
    spec, _ = seed000
    cam = BenchCamera(n_pixels=256, n_frames=10)
    frame, real = simulate_bench(cam, Departures(), seed=0, sphere_scale=1.0, level_errors=np.zeros(len(cam.levels)))
    return spec, bc.MeasurementTable.from_frame(frame, source="bench seed 0"), real


def _compression_z(table, spec, real) -> np.ndarray:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", bc.FitFailedWarning)
        cal = bc.Calibration.from_fit(bc.fit(table, spec, "laplace", seed=0))
    z = []
    for c, ch in enumerate(cal.channels):
        a2 = cal.coef_rel[:, c, 1]
        z.append((np.median(a2) - real.true_coefficients(ch, relative=True)[2]) / np.std(a2))
    return np.array(z)


def test_the_charge_domain_recovers_a_sense_node_compression(sense_node_bench):
    """Measured on bench seeds 0-2: charge |z| <= 1.7 per channel; output z 2.0-5.1, mean 3.9-4.0
    (the quadratic term pulled 27-57 % toward zero, and A1 0.05-0.12 % low with it)."""
    spec, table, real = sense_node_bench
    z_charge = _compression_z(table, spec.replace(response={"nonlinearity_domain": "charge"}), real)
    z_output = _compression_z(table, spec.replace(response={"nonlinearity_domain": "output"}), real)
    print("\ncompression z: charge", z_charge.round(2), "output", z_output.round(2))
    assert np.all(np.abs(z_charge) < 2.5)
    assert np.mean(z_output) > 2.5 and np.all(z_output > 1.0)


def test_loo_tells_the_domains_apart(sense_node_bench):
    """Measured on bench seeds 0-2: the charge domain leads by 186-215 elpd, 4.5-5.7 times its se."""
    spec, table, _ = sense_node_bench
    specs = order_candidates(spec.replace(response={"nonlinearity_domain": "output"}), (2,), domains=True)
    assert set(specs) == {"order 2", "order 2, nonlinearity of the charge"}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", bc.FitFailedWarning)
        cmp = compare_specs(table, specs, backend="laplace")
    print("\n", cmp)
    assert cmp.index[0] == "order 2, nonlinearity of the charge"
    assert -cmp.loc["order 2", "elpd_diff"] > 3 * cmp.loc["order 2", "dse"]


def test_the_domain_decision_takes_the_true_domain_and_screens_the_other(sense_node_bench):
    """decide_domain on the sense-node bench (the compression is the charge's): from the output spec the
    charge is taken by PSIS-LOO (its in-sample gain at the mode passes the screen); from the charge spec
    the output is not taken, and when the screen keeps it out its in-sample gain is at most one se."""
    from bayescal.fitting.diagnosis import decide_domain
    from bayescal.fitting.modegain import SCREEN_SE

    spec, table, _ = sense_node_bench
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        chosen, info, fit = decide_domain(table, spec.replace(response={"nonlinearity_domain": "output"}), seed=0)
        assert chosen.response.nonlinearity_domain == "charge" and not info["screened"], info
        assert info["elpd_diff_other"] > 2 * info["dse"] and fit.model.spec.response.nonlinearity_domain == "charge"
        chosen, info, _ = decide_domain(table, spec.replace(response={"nonlinearity_domain": "charge"}), seed=0)
    assert chosen.response.nonlinearity_domain == "charge", info
    assert not info["screened"] or info["mode_gain"] <= SCREEN_SE * info["mode_dse"]
