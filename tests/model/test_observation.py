"""The observed reading (noise and clipping, :mod:`bayescal.model.observation`) against Monte Carlo of pixels
drawn and clipped one by one, and the equation's inverse against its forward form."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bayescal.model import equation, observation
from bayescal.model.components import Noise, Response
from bayescal.model.equation import Reading

FS = 4095.0


def test_a_reading_far_from_full_scale_has_the_noise_variance():
    """Mean and variance of many draws against the reading variance, within their Monte Carlo error."""
    n = 200_000
    signal = np.full(n, 1500.0)
    expected = Reading(signal, signal + 100.0)
    pixel = Noise.pixel_variance(2.0, 0.1, 1.0, signal)
    normals = np.random.default_rng(5).standard_normal(n)
    out = observation.draw(expected, pixel, normals, FS, n_avg=20.0, excess=3.0, prnu=0.01)
    var = 152.0 / 20.0 + (2.0**2 + 1 / 12) / 20.0 + 9.0 + 15.0**2
    assert abs(out.mean() - 1600.0) < 4 * np.sqrt(var / n)
    assert abs(out.var() / var - 1) < 4 * np.sqrt(2 / n)


def test_a_region_mean_near_full_scale_is_the_mean_of_pixels_clipping_one_by_one():
    """The region form against pixels drawn (temporal noise and PRNU) and clipped separately.  Its mean is
    the expectation over regions of pixels (each region its own PRNU pattern), within the Monte Carlo error
    of 4000 regions; its sd is that of one region read again (the pattern fixed, the temporal noise drawn
    anew), within 10 %."""
    rng = np.random.default_rng(11)
    mean, read, k, prnu, n_pix = 4085.0, 3.0, 0.05, 0.01, 400
    signal = mean - 100.0
    temporal = (read**2 + 1 / 12) + k * signal
    regions = 4000

    def region_means(gains):
        pixels = 100.0 + signal * gains + np.sqrt(temporal) * rng.standard_normal((regions, n_pix))
        return np.minimum(pixels, FS).mean(axis=1)

    over_regions = region_means(1.0 + prnu * rng.standard_normal((regions, n_pix)))
    one_region = region_means(1.0 + prnu * rng.standard_normal(n_pix))

    expected = Reading(np.full(regions, signal), np.full(regions, mean))
    out = observation.draw(expected, temporal, rng.standard_normal(regions), FS, n_avg=n_pix, pixel_prnu=prnu)
    se = np.sqrt(over_regions.var() / regions + out.var() / regions)
    assert abs(out.mean() - over_regions.mean()) < 4 * se
    assert over_regions.mean() < mean - 10.0  # the clipping loss is material here: the check can fail
    # only the unclipped share of the pixels carries temporal noise
    assert abs(out.std() / one_region.std() - 1) < 0.1


def test_a_single_reading_is_a_whole_code_within_the_adc():
    n = 1000
    signal = np.linspace(-50, 5000, n)
    expected = Reading(signal, signal + 10.0)
    normals = np.random.default_rng(0).standard_normal(n)
    out = observation.draw(expected, Noise.pixel_variance(2.0, 0.1, 1.0, signal), normals, FS, integer=True)
    assert np.all(out == np.round(out)) and out.min() >= 0 and out.max() == FS


@settings(max_examples=30, deadline=None)
@given(
    st.floats(0.5, 3.0),
    st.floats(-0.3, 0.3),
    st.floats(0.7, 1.4),
    st.floats(0.0, 300.0),
    st.floats(0.0, 1.0),
)
def test_the_inverse_undoes_the_reading(a1, curvature, factor, offset, noise_sd):
    """``stimulus`` returns the ``u`` whose ``reading`` (with the same offsets, factors and noise) is ``dn``."""
    coef = np.array([a1, curvature * a1 / 2000.0])
    u = np.linspace(0.0, 800.0, 9)
    x_max = Response.turning_point(coef[None, :])[0]
    u = u[u * factor < 0.9 * x_max]
    noise = lambda s: noise_sd * np.sqrt(4.0 + 0.1 * np.maximum(s, 0.0))
    fwd = equation.reading(u, (factor,), lambda x: Response.forward(coef, x), (offset, 5.0))
    dn = fwd.mean + noise(fwd.signal)
    # the noise is a function of the signal the inversion recovers only at noise_sd = 0; invert exactly
    # the expected reading and, separately, the reading with the noise taken at the inverted signal
    back = equation.stimulus(
        fwd.mean, (factor,), lambda s: Response.inverse(coef[None, :], s[:, None])[:, 0], (offset, 5.0)
    )
    np.testing.assert_allclose(back, u, rtol=1e-9, atol=1e-9)
    with_noise = equation.stimulus(
        dn,
        (factor,),
        lambda s: Response.inverse(coef[None, :], s[:, None])[:, 0],
        (offset, 5.0),
        noise=lambda s: noise(fwd.signal),
    )
    np.testing.assert_allclose(with_noise, u, rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("offsets", [(), (12.0,), (12.0, np.array([1.0, 2.0, 3.0]))])
def test_the_inverse_subtracts_every_offset(offsets):
    dn = np.array([110.0, 220.0, 330.0])
    x = equation.stimulus(dn, (2.0,), lambda s: s / 1.5, offsets)
    np.testing.assert_allclose(x, (dn - sum(offsets, 0.0)) / 1.5 / 2.0)
