"""Published numbers (seeds 000 and 002) through the prediction code, from fixed published coefficients."""

import pytest

import bayescal as bc
from bayescal.model.spec import Reference

SEED000_T1 = {"R": [92.71, 62.09], "G": [51.2, 30.18], "B": [60.29, 17.87]}  # Table 1, gain 1, 1/250 s


@pytest.fixture(scope="module")
def seed000():
    return bc.Calibration.from_coefficients(SEED000_T1, reference=Reference(1 / 250, 1.0, 1.0), bits=12)


def test_seed000_inversion_534_dn(seed000):
    # section 6: 534 DN (G, gain 1, 1/250 s) -> 15.9973 W m^-2 sr^-1
    res = bc.invert(seed000, 534.0, "G", noise=False)
    assert round(float(res.median), 4) == 15.9973
    assert res.bound == 0


def test_seed000_derived_setting_1_100_s(seed000):
    # Table 2 derived fit: slope x 2.5, offset kept -> 1258 DN at 15.9973
    derived = bc.predict(seed000, 15.9973, bc.Setting(1 / 100, 1.0), ["G"])
    assert round(float(derived["dn_mean"].iloc[0])) == 1258
    assert not derived["extrapolated"].iloc[0] or "exposure" in derived["why"].iloc[0]
    # Table 2 experimental fit at 1/100 s: G = 49.73 + 85.4 L -> 1416 DN
    measured = bc.Calibration.from_coefficients({"G": [49.73, 85.4]}, reference=Reference(1 / 100, 1, 1), bits=12)
    assert round(float(measured.expected_dn("G", 15.9973, bc.Setting(1 / 100)).item())) == 1416


def test_seed000_window_contains_both_predictions():
    lo, hi = bc.default_window(12)
    assert (lo, hi) == pytest.approx((1080, 1920))
    assert lo <= 1258 <= hi and lo <= 1416 <= hi


@pytest.fixture(scope="module")
def seed002():
    ref = Reference(105e-6, 1.0, 48)
    quad = bc.Calibration.from_coefficients(
        {"pan": [2.154, 3755.0, -2582.0]}, reference=ref, bits=10, stimulus="irradiance"
    )
    # eq. 12: DN = g (0.583 E M T_int[us] + 28.72); at M = 48, T = 105 us the slope is 0.583 * 48 * 105
    eq12 = bc.Calibration.from_coefficients(
        {"pan": [28.72, 0.583 * 48 * 105]}, reference=ref, bits=10, stimulus="irradiance", dark_proportional=True
    )
    return quad, eq12


def test_seed002_inversion_and_eq12(seed002):
    quad, eq12 = seed002
    e1 = float(bc.invert(quad, 405.0, "pan", noise=False).median)
    # eq. 10 as printed (-2582, 3755, 2.154) gives 0.11664; the paper prints 0.1167 (it computed with
    # unrounded coefficients: rounding the printed ones moves the root by only ~2e-5).  Pin both.
    assert e1 == pytest.approx(0.116637, abs=2e-6)
    assert abs(e1 - 0.1167) < 1e-4
    dn = eq12.expected_dn("pan", 0.1167, bc.Setting(105e-6, 1.26, 96)).item()
    assert round(dn / 10) * 10 == 900  # "choose M = 96, g = 1.26" to reach 900 DN
    assert dn == pytest.approx(1.26 * (0.583 * 0.1167 * 96 * 105 + 28.72), rel=1e-12)
    e2 = float(bc.invert(quad, 120.0, "pan", noise=False).median)
    assert round(e2, 3) == 0.032
    dn2 = eq12.expected_dn("pan", 0.032, bc.Setting(105e-6, 1.7, 72)).item()
    assert round(dn2) == 289  # what eq. 12 gives for M = 72, g = 1.7 (the paper aimed at 300, measured 273.6)


def test_seed002_planning_picks_published_setting(seed002):
    _, eq12 = seed002
    # a narrow window around 900 DN over the camera's grid of M and g at T = 105 us
    plan = bc.plan_exposure(
        eq12,
        "pan",
        stimulus=0.1167,
        exposures=[105e-6],
        gains=[1.0, 1.26, 1.5, 1.7, 2.0],
        tdi_stages=[8, 16, 32, 48, 72, 96],
        window=(880, 920),
    )
    assert plan.best == bc.Setting(105e-6, 1.26, 96)
    assert plan.probability == 1.0
