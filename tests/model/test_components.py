"""Each component's forward function: the same under numpy and jax.numpy, and right against closed forms;
the sampling model and the posterior's predictions evaluate one measurement equation."""

import warnings

import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import integrate, stats

import bayescal as bc
from bayescal.model.basis import response_monomials, shifted_legendre_monomials
from bayescal.model.components import EFFECTS, Dark, Noise, Response, Saturation, SettingFactors, Sphere
from bayescal.model.components.glow import Glow
from bayescal.model.components.offset_temperature import OffsetTemperature
from bayescal.model.components.responsivity import ResponsivityTemperature

finite = st.floats(-3.0, 3.0, allow_nan=False)
positive = st.floats(0.05, 5.0, allow_nan=False)


def both(fn, *args):
    """``fn`` evaluated with numpy and with jax.numpy (float64) on the same inputs."""
    with bc.numerics():
        return np.asarray(fn(*args, np)), np.asarray(fn(*[jnp.asarray(a) for a in args], jnp))


@settings(max_examples=40, deadline=None)
@given(st.lists(finite, min_size=1, max_size=4), st.lists(positive, min_size=1, max_size=6))
def test_response_signal_is_the_polynomial_in_both_namespaces(coef, x):
    coef, x = np.asarray(coef), np.asarray(x)
    a, b = both(lambda c, v, xp: Response.signal(c, v, xp), coef, x)
    np.testing.assert_allclose(a, np.polyval(np.r_[coef[::-1], 0.0], x), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(b, a, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("order", [1, 2, 3, 4])
def test_response_inverse_undoes_the_signal(order):
    rng = np.random.default_rng(order)
    gain = rng.uniform(0.5, 1.0, 50)  # scaled units: the brightest row reads 50-100 % of full scale
    eta = rng.normal(0, 0.03, (50, order - 1)) if order > 1 else None
    coef = response_monomials(gain, eta, order)[:, 1:]  # a gently nonlinear response, monotone on [0, 1]
    x = rng.uniform(0.01, 1.0, (7, 50))
    y = np.stack([Response.signal(coef, xi) for xi in x])
    np.testing.assert_allclose(Response.inverse(coef, y), x, rtol=1e-10)


def test_response_inverse_stays_on_the_rising_branch():
    """A cubic that turns over: a reading below its maximum inverts to the root on the rising branch
    (not the larger one beyond the turn), a reading above the maximum to the turning point."""
    coef = np.array([[1.0, 0.0, -1.0 / 3.0]])  # S = x - x^3 / 3: rising to 2/3 at x = 1, falling after
    y = np.array([[0.5], [2.0 / 3.0], [0.9], [-0.1]])
    x = Response.inverse(coef, y).ravel()
    root = [r.real for r in np.roots([-1 / 3, 0, 1, -0.5]) if abs(r.imag) < 1e-12 and 0 < r.real < 1][0]
    np.testing.assert_allclose(x[0], root, rtol=1e-12)
    np.testing.assert_allclose(x[1:3], 1.0, atol=1e-7)
    np.testing.assert_allclose(Response.signal(coef[0], x[3]), -0.1, rtol=1e-12)


def test_response_monomials_agree_with_the_legendre_basis():
    """``S = v (1 + sum eta_k p_k(v))``, ``v = G u``, evaluated directly from the basis polynomials."""
    g, eta, u = 0.7, np.array([0.05, -0.02, 0.01]), np.linspace(0, 1.3, 9)
    q = shifted_legendre_monomials(4)
    v = g * u
    direct = v * (1 + sum(eta[k] * np.polyval(q[k][::-1], v) for k in range(3)))
    a, b = both(lambda gg, e, xp: response_monomials(gg, e, 4, xp), np.array(g), eta)
    np.testing.assert_allclose(Response.signal(a[1:], u), direct, rtol=1e-13)
    np.testing.assert_allclose(b, a, rtol=1e-14)


@settings(max_examples=40, deadline=None)
@given(finite, finite, positive, positive, st.floats(-20, 20), st.floats(3, 12), finite, positive)
def test_dark_level_in_both_namespaces(offset, slope, t, g, dt, doubling, drift, time):
    def level(o, s, tt, gg, d, xp):
        return Dark.level(o, s, tt, gg, Dark.doubling(d, doubling, xp), drift, time)

    a, b = both(level, *(np.asarray(v) for v in (offset, slope, t, g, dt)))
    assert a == pytest.approx((offset + slope * t * 2 ** (dt / doubling)) * g + drift * time, rel=1e-12, abs=1e-12)
    np.testing.assert_allclose(b, a, rtol=1e-12, atol=1e-12)


@settings(max_examples=40, deadline=None)
@given(positive, positive, positive, st.floats(-10, 4000), st.floats(1, 400), positive, st.floats(0, 0.05))
def test_noise_variance_in_both_namespaces(read, k, g, signal, n_avg, excess, prnu):
    a, b = both(lambda r, kk, gg, s, xp: Noise.pixel_variance(r, kk, gg, s, xp), *map(np.asarray, (read, k, g, signal)))
    s = max(signal, 0.0)
    assert a == pytest.approx((read * g) ** 2 + 1 / 12 + k * g * s, rel=1e-12)
    np.testing.assert_allclose(b, a, rtol=1e-12)
    total = Noise.reading_variance(a, n_avg, excess, prnu, s)
    assert total == pytest.approx(a / n_avg + excess**2 + (prnu * s) ** 2, rel=1e-12)


@pytest.mark.parametrize("mu, sigma", [(0.5, 0.1), (0.98, 0.05), (1.0, 0.02), (1.3, 0.1), (0.2, 0.3)])
def test_clipped_mean_is_the_mean_of_the_clipped_normal(mu, sigma):
    """``E[min(Y, fs)]`` by quadrature, and the share of readings below full scale."""

    def integrand(y):
        return min(y, 1.0) * stats.norm.pdf(y, mu, sigma)

    expected = integrate.quad(integrand, mu - 12 * sigma, mu + 12 * sigma, points=[1.0], limit=200)[0]
    a, b = both(lambda m, s, xp: Saturation.clipped_mean(m, s, 1.0, xp), np.asarray(mu), np.asarray(sigma))
    assert a == pytest.approx(expected, rel=1e-9)
    np.testing.assert_allclose(b, a, rtol=1e-12)
    frac = Saturation.unclipped_fraction(mu, sigma, 1.0)
    assert frac == pytest.approx(stats.norm.cdf(1.0, mu, sigma), rel=1e-12)


def test_adc_clips_and_rounds():
    np.testing.assert_array_equal(Saturation.adc(np.array([-3.2, 1.4, 1.6, 5000.0]), 4095.0), [0, 1.4, 1.6, 4095])
    np.testing.assert_array_equal(
        Saturation.adc(np.array([-3.2, 1.4, 1.6, 5000.0]), 4095.0, integer=True), [0, 1, 2, 4095]
    )


def test_stimulus_factors_in_both_namespaces():
    logf = np.array([[0.01, -0.02], [0.0, 0.05]])
    a, b = both(lambda v, xp: SettingFactors.factor(v, xp), logf)
    np.testing.assert_allclose(a, np.exp(logf.sum(axis=1)), rtol=1e-14)
    np.testing.assert_allclose(b, a, rtol=1e-14)
    a, b = both(
        lambda c, d, xp: ResponsivityTemperature.forward(c, d, xp), np.array([0.003, -0.001]), np.array([5.0, -10.0])
    )
    np.testing.assert_allclose(a, np.exp([0.015, 0.01]), rtol=1e-14)
    np.testing.assert_allclose(b, a, rtol=1e-14)
    assert Sphere.factor(0.02) == pytest.approx(1.02)


def test_every_component_declares_the_dims_of_what_it_samples_and_reports(seed000):
    """The sites and quantities of a fit carry the dims their component declares (no hand-kept list)."""
    spec, design = seed000
    table = bc.simulate(spec, design, seed=4).table
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", bc.FitFailedWarning)
        fit = bc.fit(table, spec, "laplace", seed=0)
    post = fit.posterior["posterior"]
    declared = {}
    for c in fit.model.parts.components:
        declared |= dict(c.sites) | dict(c.reported)
    for name in post.data_vars:
        assert name in declared, name
        assert post[name].dims[2:] == tuple(declared[name]), name
    assert {e.section for e in EFFECTS} <= {name for name, _ in fit.model.spec.effects}


def test_the_model_and_the_posterior_evaluate_one_equation(seed000):
    """Every row's expected reading as the numpyro model computes it (scaled, jax) equals what
    :class:`~bayescal.Calibration` predicts for that row's channel, stimulus and setting (physical, numpy),
    draw by draw: the settings' factors, a factor effect, dark, two offset effects and the response
    included."""
    import dataclasses

    from bayescal.inference.program import program_for

    spec, design = seed000
    spec = spec.replace(
        saturation={"censor": False},
        sphere={"per_level_rel": 0.0},
        offset_temperature={"enabled": True},
        glow={"enabled": True},
    )
    temperatures = (12.0, 20.0, 31.0)
    blocks = tuple(dataclasses.replace(b, temperature_c=temperatures) for b in design.illuminated)
    dark = tuple(dataclasses.replace(b, temperature_c=temperatures) for b in design.dark)
    effects = {
        "responsivity": {"coefficient_per_c": 0.004},
        "offset_temperature": {"dn_per_c": {"R": 0.5, "G": -0.3}},
        "glow": {"dn_s2": {"R": 3e4, "B": 1e4}},
    }
    truth = dataclasses.replace(design.truth, effects=effects)
    design = dataclasses.replace(design, illuminated=blocks, dark=dark, truth=truth)
    table = bc.simulate(spec, design, seed=5).table
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", bc.FitFailedWarning)
        fit = bc.fit(table, spec, "laplace", seed=0)
    model = fit.model
    assert [type(e) for e in model.parts.effects] == [ResponsivityTemperature, OffsetTemperature, Glow]
    post = fit.posterior["posterior"]
    n = 30
    with bc.numerics():
        program = program_for(model)
        values = {k: np.asarray(post[k]).reshape((-1,) + post[k].shape[2:])[:n] for k in program.unravel(program.z0)}
        z = np.stack([program.unconstrain({k: v[s] for k, v in values.items()}, model.data) for s in range(n)])
        row_mean = np.asarray(program.constrain(z, model.data)["row_mean"]) * model.layout.dn_scale
    cal = bc.Calibration.from_fit(fit)
    frame = model.table.frame
    for i in range(0, len(frame), 7):  # lit rows and dark ones
        r = frame.iloc[i]
        setting = bc.Setting(r.exposure_s, r.gain, r.tdi_stages, temperature_c=r.temperature_c)
        predicted = cal.expected_dn(r.channel, r.stimulus, setting, relative=True)[:n]
        np.testing.assert_allclose(predicted, row_mean[:, i], rtol=1e-9)


def test_rolloff_compresses_monotonically_and_is_undone():
    """S / (1 + (S/K)^p)^(1/p): linear far below the knee, monotone, below K; expand inverts it (inf past K);
    its derivatives to second order are finite at S = 0 and far above the knee (the Laplace fit's Hessian)."""
    import jax
    import jax.numpy as jnp

    from bayescal._config import numerics
    from bayescal.model.components.rolloff import compress, expand

    knee = np.array([6000.0, 4.0])
    s = np.linspace(-50.0, 40_000.0, 4001)
    out = compress(s, "knee", knee)
    assert np.all(np.diff(out) > 0) and np.all(out < 6000.0)
    assert out[3000] == pytest.approx(s[3000] * (1 + (s[3000] / 6000.0) ** 4) ** -0.25, rel=1e-12)
    assert np.allclose(out[s <= 0], s[s <= 0])
    assert compress(np.array([100.0]), "knee", knee)[0] == pytest.approx(100.0, rel=1e-7)  # linear far below
    np.testing.assert_allclose(expand(out, "knee", knee), s, rtol=1e-9, atol=1e-9)
    assert np.isinf(expand(np.array([6000.0, 7000.0]), "knee", knee)).all()
    with numerics():
        f = lambda v: jnp.sum(compress(jnp.array([0.0, 1e-9, 0.5, 30.0]), "knee", v, jnp))
        hess = jax.hessian(f)(jnp.array([1.2, 3.0]))
        grad_s = jax.jacfwd(jax.grad(lambda x: compress(x, "knee", jnp.array([1.2, 3.0]), jnp)))(0.0)
    assert np.isfinite(np.asarray(hess)).all() and np.isfinite(float(grad_s))


def test_the_monotone_rolloff_draws_other_shapes_and_is_undone():
    """The monotone shape with only its linear weight is the exponential saturation T (1 - exp(-S / T))
    (closed form, to the quadrature's accuracy); with any weights it rises everywhere with slope 1 at 0,
    and expand inverts it, per draw, with the draws on the last axis."""
    import jax
    import jax.numpy as jnp

    from bayescal._config import numerics
    from bayescal.model.components.rolloff import compress, expand, n_params

    full = 4095.0
    top = 1.3 * full
    params = np.zeros(n_params("monotone"))
    params[0], params[1] = full, full / top  # phi(u) = u FS / T
    s = np.linspace(-20.0, 2.0 * full, 2001)
    out = compress(s, "monotone", params)
    expected = np.where(s > 0, top * -np.expm1(-s / top), s)
    np.testing.assert_allclose(out, expected, rtol=1e-10, atol=1e-8 * full)
    rng = np.random.default_rng(5)
    draws = np.concatenate([np.full((50, 1), full), rng.normal(0.0, 1.0, (50, n_params("monotone") - 1))], axis=1)
    grid = np.linspace(0.0, 1.5 * full, 301)[:, None]  # (V, 1) against 50 draws
    y = compress(grid, "monotone", draws)
    assert np.all(np.diff(y, axis=0) > 0)  # rising, whatever the weights' signs
    np.testing.assert_allclose(
        expand(y, "monotone", draws), np.broadcast_to(grid, y.shape), rtol=1e-6, atol=1e-6 * full
    )
    with numerics():
        slope0 = jax.grad(lambda x: compress(x, "monotone", jnp.asarray(draws[3]), jnp))(0.0 + 1e-12)
        hess = jax.hessian(lambda w: jnp.sum(compress(jnp.array([0.0, 10.0, 4000.0]), "monotone", w, jnp)))(
            jnp.asarray(draws[3])
        )
    assert float(slope0) == pytest.approx(1.0, abs=1e-9)
    assert np.isfinite(np.asarray(hess)).all()


def test_every_component_fills_a_place_of_the_equation():
    """The core components fill every place of the skeleton, one each; the effects take the three open ones."""
    from bayescal.model.components import CORE
    from bayescal.model.equation import ROLES

    assert sorted(c.role for c in CORE) == sorted(ROLES)
    assert {e.role for e in EFFECTS} == {"factor", "offset", "noise"}
    # an effect is a factor, an offset or a noise by its class, and its role says the same
    from bayescal.model.components import FactorEffect, NoiseEffect, OffsetEffect

    kinds = {"factor": FactorEffect, "offset": OffsetEffect, "noise": NoiseEffect}
    for e in EFFECTS:
        assert [role for role, base in kinds.items() if issubclass(e, base)] == [e.role], e


def test_the_turning_point_of_a_vanishing_curvature():
    """A curvature so small that the companion matrix overflows (found by the inverse's property test):
    the response rises for ever in range, and a tiny negative one turns where its closed form says."""
    turn = Response.turning_point(np.array([[1.0, 1.1e-308], [1.0, 0.0], [1.0, -1e-300], [1.0, -0.25]]))
    np.testing.assert_allclose(turn, [np.inf, np.inf, 0.5e300, 2.0], rtol=1e-12)
