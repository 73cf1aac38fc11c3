"""The monotone roll-off on a shape its knee family cannot draw: an exponential saturation
``T (1 - exp(-S / T))`` from the independent simulator (:mod:`bayescal.validation.wild`, seed 1: T = 1.7
full scale, no other departure).  The knee family refused this dataset (residual runs z = -4.4, A1 of R
7.6 sd off); the monotone shape is fitted by Laplace, covers the offsets and gains, and inverts a reading
near full scale to the radiance that made it."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import bayescal as bc
from bayescal.validation.wild import simulate_wild
from tests.conftest import quiet_fit


@pytest.mark.slow  # a diagnosis on a full table; test_components checks the monotone shape by default
def test_an_exponential_saturation_is_drawn_by_the_monotone_shape():
    frame, session = simulate_wild(1)
    assert session.label() == "rolloff: exponential"
    table = bc.MeasurementTable.from_frame(frame)
    spec = bc.load_spec("seed000").replace(response={"rolloff": "monotone"})
    result = quiet_fit(table, spec, "laplace", seed=1)
    assert result.ok, result.diagnostics.problems
    truth = session.truth().set_index("channel")
    rel = result.draws("A_rel")
    for c, channel in enumerate(result.model.layout.channels):
        lo, hi = np.quantile(rel[:, c, :2], [0.005, 0.995], axis=0)
        t = truth.loc[channel, ["A0", "A1"]].to_numpy(float)
        assert np.all((lo <= t) & (t <= hi)), (channel, lo, t, hi)
    weights = result.draws("rolloff_weights")
    assert np.mean(weights[:, 0] > 0) > 0.99  # the slope falls from the start: the linear term, positive
    # a bright reading of the table inverts to its radiance (the sphere's 3 % scale is in the interval)
    cal = bc.Calibration.from_fit(result)
    lit = frame[(frame.channel == "G") & (frame.radiance > 0) & (frame.dn_mean < 0.9 * spec.full_scale)]
    row = lit.loc[lit.dn_mean.idxmax()]
    assert row.dn_mean > 0.6 * spec.full_scale
    setting = bc.Setting(float(row.exposure_s), float(row.gain))
    inv = bc.invert(cal, [float(row.dn_mean)], "G", setting, n_avg=float(row.n_frames * row.n_pixels), level=0.99)
    assert inv.lower[0] < row.radiance < inv.upper[0], (inv.lower[0], row.radiance, inv.upper[0])
    linear = bc.invert(dataclasses.replace(cal, rolloff=None), [float(row.dn_mean)], "G", setting)
    assert linear.median[0] < inv.median[0]  # undoing the compression raises the radiance


def test_the_monotone_integral_matches_adaptive_quadrature():
    """The Gauss-Legendre integral of the monotone shape against scipy's adaptive quadrature, for weights
    drawn at twice the prior's sd over 0 to 1.2 of full scale: within 1e-6 of full scale (4e-3 DN at 12
    bits; measured 2.4e-7)."""
    from scipy.integrate import quad

    from bayescal.model.components import rolloff

    rng = np.random.default_rng(7)
    weights = rng.normal(0.0, 2 * rolloff.WEIGHT_SD, (20, rolloff.n_params("monotone") - 1))
    u = np.linspace(0.02, 1.2, 15)
    params = np.concatenate([np.ones((20, 1)), weights], axis=1)  # scale 1: the signal in full scales
    got = rolloff.compress(u[None, :], "monotone", params[:, None, :])
    for w, row in zip(weights, got, strict=True):
        slope = lambda x, w=w: float(np.exp(-rolloff.log_slope(np.asarray(x), w)))  # noqa: E731
        want = [quad(slope, 0.0, v, epsabs=1e-13, epsrel=1e-13, limit=200)[0] for v in u]
        np.testing.assert_allclose(row, want, rtol=0, atol=1e-6)
