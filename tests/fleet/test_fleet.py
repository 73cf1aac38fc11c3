"""Fleets: table validation, the stage-two algebra against dense closed forms, a small fleet
with known truth from the independent simulator, and the command line.

The coverage of the fleet's intervals over 5-50 cameras and 3-12 levels is measured by
``benchmarks/fleet_pooling.py`` (results in ``benchmarks/results/fleet_pooling.md``).
"""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pandas as pd
import pytest

from bayescal import load_spec
from bayescal.errors import SpecError, TableError
from bayescal.fleet.conditional import conditional_draws
from bayescal.fleet.data import design_of, fleet_data
from bayescal.fleet.excess import weighted
from bayescal.fleet.marginal import _integrated, block_scales, integrated_value, log_marginal
from bayescal.fleet.plan import Plan
from bayescal.fleet.spec import FleetSpec
from bayescal.fleet.units import fleet_from_frame
from bayescal.inference.phases import Phased
from bayescal.model.spec import InferenceSpec
from bayescal.validation.fleet import SMALL_FLEET, FleetDesign, simulate_fleet
from tests.conftest import MODELS

SPEC = MODELS / "fleet_seed000.toml"


def _small_design(**kw) -> FleetDesign:
    return dataclasses.replace(SMALL_FLEET, **kw)


def _spec(draws: int | None = None):
    """The shipped fleet spec (``draws`` per chain: the default unless given)."""
    spec = load_spec(SPEC)
    return spec if draws is None else spec.replace(fleet={"draws": draws})


@pytest.fixture(scope="module")
def small_fleet():
    table, truth = simulate_fleet(_small_design(), seed=7)
    return table, truth


@pytest.fixture(scope="module")
def fitted(small_fleet):
    from bayescal.fleet import fit_fleet

    table, truth = small_fleet
    fleet = fleet_from_frame(table.astype(str), source="small fleet")
    return fleet, fit_fleet(fleet, _spec(), "laplace", seed=3), truth


# ----------------------------------------------------------------------------- bad input
def _frame(small_fleet) -> pd.DataFrame:
    return small_fleet[0].astype(str).copy()


def test_campaign_without_camera_names_the_column(small_fleet):
    df = _frame(small_fleet).drop(columns=["camera"])
    with pytest.raises(TableError, match="column 'camera'.*'campaign' column needs a 'camera'"):
        fleet_from_frame(df, source="t.csv")


def test_unparseable_date_names_row_and_column(small_fleet):
    df = _frame(small_fleet)
    df.loc[41, "campaign"] = "2025-13-45"
    with pytest.raises(TableError, match=r"row 42, column 'campaign'.*'2025-13-45' does not parse"):
        fleet_from_frame(df, source="t.csv")


def test_one_camera_is_not_a_fleet(small_fleet):
    df = _frame(small_fleet)
    df = df[df["camera"] == "SN001"]
    with pytest.raises(TableError, match="column 'camera'.*at least two cameras"):
        fleet_from_frame(df, source="t.csv")


def test_camera_without_illuminated_rows_names_its_first_row(small_fleet):
    df = _frame(small_fleet)
    unit = (df["camera"] == "SN003") & (df["campaign"] == "2025-03-01")
    df = df[~unit | (df["radiance"].astype(float) == 0.0)].reset_index(drop=True)
    first = int(np.flatnonzero(((df["camera"] == "SN003") & (df["campaign"] == "2025-03-01")).to_numpy())[0]) + 1
    with pytest.raises(TableError, match=rf"row {first}, column 'radiance'.*SN003.*no illuminated rows"):
        fleet_from_frame(df, source="t.csv")


def test_a_bad_cell_reports_its_row_in_the_fleet_file(small_fleet):
    df = _frame(small_fleet)
    df.loc[100, "dn_mean"] = "abc"
    with pytest.raises(TableError, match=r"row 101, column 'dn_mean'"):
        fleet_from_frame(df, source="t.csv")


# ------------------------------------------------------------------ stage two, closed form
class _Fits:
    """A stand-in for stage one: units' Gaussian summaries drawn at random."""

    def __init__(self, fleet, n_kinds: int, rng):
        u, c = len(fleet.units), len(fleet.units[0].table.channels)
        self.fleet = fleet
        spread = np.array([0.05, 3.0, 1e-3])[:n_kinds]
        self.mean = rng.normal(size=(u, n_kinds, c)) * spread[:, None]
        a = rng.normal(size=(u, n_kinds * c, n_kinds * c))
        s = np.repeat(spread, c)
        self.cov = (a @ np.swapaxes(a, 1, 2) + n_kinds * c * np.eye(n_kinds * c)) * np.outer(s, s) * 0.003


def _unit_rows(plan, data, hyper, k, u, design):
    """Kind ``k`` of unit ``u`` densely: its rows of ``H`` (global, then every camera's block, each
    slot times its scale; the camera's shared error times ``T``) and its error covariance
    ``T Sigma T``, with ``T = sqrt(kappa_1) P_1 + sqrt(kappa_2) P_2`` built here from its definition."""
    h_g, h_m, active = design
    sc = block_scales(plan, hyper)[:, None, :] * active  # (K, M, B)
    c_n = plan.n_channels
    kappa = np.ones(2) if "excess" not in hyper else np.asarray(hyper["excess"]).reshape(plan.n_kinds, -1)[k]
    mean = np.full((c_n, c_n), 1.0 / c_n)
    t = np.sqrt(kappa[0]) * mean + np.sqrt(kappa[-1]) * (np.eye(c_n) - mean)
    rows = np.zeros((c_n, plan.n_global + plan.n_cameras * plan.block))
    rows[:, : plan.n_global] = h_g[k, u]
    m = data.camera[u]
    block = h_m[k, u] * sc[k, m]
    if plan.shared:
        block[:, plan.shared_base :] = t @ block[:, plan.shared_base :]
    rows[:, plan.n_global + m * plan.block : plan.n_global + (m + 1) * plan.block] = block
    sl = slice(k * c_n, (k + 1) * c_n)
    cov_u = (data.chol[u] @ data.chol[u].T)[sl, sl]
    return rows, t @ cov_u @ t


def _dense(plan, data, hyper):
    """``y ~ N(0, H V H' + T Sigma T)`` built densely: the reference for the block algebra."""
    design = design_of(plan, data)
    total = 0.0
    u_n, c_n = plan.n_units, plan.n_channels
    for k in range(plan.n_kinds):
        parts = [_unit_rows(plan, data, hyper, k, u, design) for u in range(u_n)]
        h = np.concatenate([p[0] for p in parts])
        noise = np.zeros((u_n * c_n, u_n * c_n))
        for u in range(u_n):
            noise[u * c_n : (u + 1) * c_n, u * c_n : (u + 1) * c_n] = parts[u][1]
        v = np.concatenate([data.prior_var_g[k], np.ones(plan.n_cameras * plan.block)])
        cov = h @ np.diag(v) @ h.T + noise
        y = data.y.reshape(u_n, plan.n_kinds, c_n)[:, k].ravel()
        sign, logdet = np.linalg.slogdet(cov)
        total += -0.5 * (y @ np.linalg.solve(cov, y) + logdet)
    return total


def test_channel_inflation_in_closed_form():
    """``sqrt(diag(T Sigma T) / diag(Sigma))``: with ``Sigma = I`` (3 channels) and kappa 4 together,
    1 apart, ``T^2 = 4 P_1 + P_2`` has diagonal 4/3 + 2/3 = 2; with channels fully correlated
    (``Sigma = 1 1'``) only the common direction counts: sqrt(4) = 2."""
    from bayescal.fleet.excess import channel_inflation
    from bayescal.fleet.plan import Plan

    plan = Plan(2, 3, 2, 2, 1, 0, 0, False, False, "partial", 1.0, 0.5, 0.3)
    cov = np.zeros((2, 6, 6))
    cov[:, :3, :3] = np.eye(3)
    cov[:, 3:, 3:] = np.ones((3, 3)) + 1e-12 * np.eye(3)
    out = channel_inflation(plan, cov, np.array([[4.0, 1.0], [4.0, 9.0]]))
    np.testing.assert_allclose(out, [np.sqrt(2.0), 2.0], rtol=1e-6)


def test_marginal_likelihood_matches_the_dense_gaussian(small_fleet, float64):
    import jax.numpy as jnp

    fleet = fleet_from_frame(_frame(small_fleet), source="small")
    rng = np.random.default_rng(0)
    data, plan = fleet_data(_Fits(fleet, 3, rng), FleetSpec(), 0.03)
    assert plan.drift and plan.walk and plan.n_spheres == 3
    values = []
    for scale in (0.3, 1.7):
        hyper = {k: np.full(n, scale) for k, n in plan.sampled().items()}
        hyper["excess"] = np.array([1.0, 2.5, 1.3, 4.0, 1.1, 1.9]) * scale  # per kind: together, apart
        fast = float(log_marginal(plan, {k: jnp.asarray(v) for k, v in hyper.items()}, data.arrays()))
        values.append((fast, _dense(plan, data, hyper)))
    # equal up to a constant (y' Sigma^-1 y terms and prior determinants cancel in the difference)
    (f1, d1), (f2, d2) = values
    assert f2 - f1 == pytest.approx(d2 - d1, rel=1e-7, abs=1e-6)


def test_marginal_gradient_matches_the_dense_gaussian(small_fleet, float64):
    """The closed-form gradient (posterior mean and covariance blocks, no reverse pass through
    the factors) against central differences of the dense Gaussian, in the sampled coordinates."""
    import jax
    import jax.numpy as jnp

    from bayescal.fleet.sampling import _unpack

    fleet = fleet_from_frame(_frame(small_fleet), source="small")
    rng = np.random.default_rng(4)
    data, plan = fleet_data(_Fits(fleet, 3, rng), FleetSpec(), 0.03)
    arrays = {k: jnp.asarray(v) for k, v in data.arrays().items()}
    dim = sum(plan.sampled().values())
    u0 = np.log(0.6) + 0.4 * rng.standard_normal(dim)
    d = data.walk_interval
    grad = np.asarray(jax.grad(lambda u: log_marginal(plan, _unpack(plan, u, d, jnp), arrays))(jnp.asarray(u0)))
    h = 1e-5
    fd = np.array(
        [
            (_dense(plan, data, _unpack(plan, u0 + h * e, d)) - _dense(plan, data, _unpack(plan, u0 - h * e, d)))
            / (2 * h)
            for e in np.eye(dim)
        ]
    )
    # central differences of a ~1e3 log density: truncation ~h^2, rounding ~1e-13 / h
    np.testing.assert_allclose(grad, fd, rtol=1e-5, atol=1e-6 * np.max(np.abs(fd)))
    # and against reverse-mode differentiation through the factorisations (the path it replaces),
    # for the slots' scales and every Gram array (the prior's variances included)
    sc = jnp.asarray(rng.uniform(0.1, 2.0, data.active.shape)) * arrays["active"]
    eff = weighted(plan, arrays, jnp.asarray(rng.uniform(1.0, 3.0, (plan.n_kinds, plan.n_directions))), jnp)
    closed = jax.tree_util.tree_leaves(jax.grad(_integrated(), argnums=(0, 1))(sc, eff))
    autodiff = jax.tree_util.tree_leaves(jax.grad(lambda s, a: integrated_value(s, a)[0], argnums=(0, 1))(sc, eff))
    for a, b in zip(closed, autodiff, strict=True):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-8, atol=1e-10 * float(jnp.max(jnp.abs(b))))


def test_walk_and_jitter_are_sampled_as_their_total_and_ratio(small_fleet, float64):
    """Where a kind has a random walk and a campaign jitter, NUTS samples the log of their total
    sd over the mean campaign interval and their log ratio: the map back to the two scales'
    logs, its unit Jacobian (so the potential is the posterior of those logs, unchanged), and
    the potential against the prior and marginal written in the scales' own logs."""
    import jax
    import jax.numpy as jnp
    from jax.scipy.stats import norm

    from bayescal.fleet.sampling import _log_scales, _potential, scale_priors

    fleet = fleet_from_frame(_frame(small_fleet), source="small")
    rng = np.random.default_rng(5)
    data, plan = fleet_data(_Fits(fleet, 3, rng), FleetSpec(), 0.03)
    d = float(data.walk_interval)
    assert plan.walk and plan.jitter and d > 0.5  # campaigns about a year apart
    sizes = plan.sampled()
    dim = sum(sizes.values())
    names = [n for n, k in sizes.items() for _ in range(k)]
    walk_at, jitter_at = names.index("walk_sd"), names.index("jitter_sd")
    u = np.log(0.6) + 0.8 * rng.standard_normal(dim)
    logs = _log_scales(plan, u, d)
    walk, jitter = np.exp(logs["walk_sd"]), np.exp(logs["jitter_sd"])
    s, q = u[walk_at : walk_at + 2], u[jitter_at : jitter_at + 2]
    np.testing.assert_allclose(0.5 * np.log(walk**2 * d + jitter**2), s, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(np.log(walk * np.sqrt(d) / jitter), q, rtol=1e-12, atol=1e-12)

    def flat(v):
        out = _log_scales(plan, v, d, jnp)
        return jnp.concatenate([out[n] for n in sizes])

    jac = np.asarray(jax.jacfwd(flat)(jnp.asarray(u)))
    assert abs(np.linalg.det(jac)) == pytest.approx(1.0, rel=1e-10)

    arrays = {k: jnp.asarray(v) for k, v in data.arrays().items()}
    priors = scale_priors(plan)
    hyper = {n: 1.0 + np.exp(v) if n == "excess" else np.exp(v) for n, v in logs.items()}
    direct = sum(float(np.sum(norm.logpdf(np.exp(v), 0.0, priors[n]) + v)) for n, v in logs.items())
    direct += float(log_marginal(plan, {n: jnp.asarray(v) for n, v in hyper.items()}, arrays))
    assert -float(_potential(plan)(jnp.asarray(u), arrays)) == pytest.approx(direct, rel=1e-12, abs=1e-9)


def test_leave_one_unit_out_matches_the_dense_gaussian_conditional(small_fleet, float64):
    """``log p(y_u | y_-u, h)`` in closed form (numpy and compiled) against the conditional of the
    dense joint Gaussian of every unit's values, per kind."""
    from bayescal.fleet.conditional import draw_scales
    from bayescal.fleet.loo import loo_log_predictive, loo_pieces, loo_predictive

    fleet = fleet_from_frame(_frame(small_fleet), source="small")
    data, plan = fleet_data(_Fits(fleet, 2, np.random.default_rng(2)), FleetSpec(), 0.03)
    hyper = {k: np.full((1, n), 0.7) for k, n in plan.sampled().items()}
    hyper["excess"] = np.array([[1.4, 2.6, 1.1, 1.8]])
    one = {name: v[0] for name, v in hyper.items()}
    design = design_of(plan, data)
    u_n, c_n = plan.n_units, plan.n_channels
    reference = np.zeros(u_n)
    for k in range(plan.n_kinds):
        parts = [_unit_rows(plan, data, one, k, u, design) for u in range(u_n)]
        h = np.concatenate([p[0] for p in parts])
        v = np.concatenate([data.prior_var_g[k], np.ones(plan.n_cameras * plan.block)])
        cov = h @ np.diag(v) @ h.T
        for u in range(u_n):
            cov[u * c_n : (u + 1) * c_n, u * c_n : (u + 1) * c_n] += parts[u][1]
        y = data.y.reshape(u_n, plan.n_kinds, c_n)[:, k].ravel()
        for u in range(u_n):
            own = np.zeros(u_n * c_n, bool)
            own[u * c_n : (u + 1) * c_n] = True
            gain = cov[np.ix_(own, ~own)] @ np.linalg.inv(cov[np.ix_(~own, ~own)])
            mean = gain @ y[~own]
            var = cov[np.ix_(own, own)] - gain @ cov[np.ix_(~own, own)]
            resid = y[own] - mean
            reference[u] += -0.5 * (resid @ np.linalg.solve(var, resid) + np.linalg.slogdet(var)[1])
            reference[u] -= 0.5 * c_n * np.log(2 * np.pi)
    sc, kappa = draw_scales(plan, hyper, data.arrays())
    fast = loo_log_predictive(plan, data.camera, sc, kappa, data.arrays(), loo_pieces(plan, data))[0]
    np.testing.assert_allclose(fast, reference, rtol=1e-8, atol=1e-8)
    compiled = loo_predictive(plan, data, np.repeat(sc, 3, axis=0), np.repeat(kappa, 3, axis=0))
    np.testing.assert_allclose(compiled, np.repeat(reference[None], 3, axis=0), rtol=1e-8, atol=1e-8)


def test_conditional_draws_match_the_dense_posterior_mean(small_fleet):
    fleet = fleet_from_frame(_frame(small_fleet), source="small")
    rng = np.random.default_rng(1)
    data, plan = fleet_data(_Fits(fleet, 2, rng), FleetSpec(walk=False), 0.03)
    hyper = {k: np.full((1, n), 0.8) for k, n in plan.sampled().items()}
    hyper["excess"] = np.array([[1.5, 3.0, 1.2, 2.0]])  # per kind: channels together, apart
    n = 4000
    g, cam = conditional_draws(plan, {k: np.repeat(v, n, axis=0) for k, v in hyper.items()}, data.arrays(), rng)
    # dense posterior of kind 0's latents: precision H' S^-1 H + V^-1
    design = design_of(plan, data)
    one = {name: v[0] for name, v in hyper.items()}
    sc = block_scales(plan, one)[:, None, :] * design[2]
    c_n, k = plan.n_channels, 0
    n_lat = plan.n_global + plan.n_cameras * plan.block
    prec = np.diag(np.concatenate([1.0 / data.prior_var_g[k], np.ones(plan.n_cameras * plan.block)]))
    info = np.zeros(n_lat)
    y = data.y.reshape(plan.n_units, plan.n_kinds, c_n)[:, k]
    for u in range(plan.n_units):
        h, noise = _unit_rows(plan, data, one, k, u, design)  # the camera slots standardised (times their scale)
        s_inv = np.linalg.inv(noise)
        prec += h.T @ s_inv @ h
        info += h.T @ s_inv @ y[u]
    cov = np.linalg.inv(prec)
    mean = cov @ info
    sd = np.sqrt(np.diag(cov))
    draws = np.concatenate([g[:, k], (cam[:, k] / np.where(sc[k] > 0, sc[k], 1.0)).reshape(n, -1)], axis=1)
    live = np.concatenate([np.ones(plan.n_global, bool), (sc[k] > 0).ravel()])
    z = (draws.mean(axis=0) - mean)[live] / (sd[live] / np.sqrt(n))
    assert np.max(np.abs(z)) < 5.0  # Monte Carlo error of 4000 exact draws
    ratio = draws.std(axis=0)[live] / sd[live]
    assert np.all(np.abs(ratio - 1.0) < 0.1)


@pytest.mark.slow  # the fleet sampler's continuation (14 s); the fleet CLI test samples in the default run
def test_chains_continue_until_the_ess_target(small_fleet):
    """Below the ESS target every chain continues from its adapted state, ``extend`` times at most,
    and the compiled conditional draws equal numpy's for the same normal variates."""
    from bayescal._config import numerics
    from bayescal.fleet.conditional import draw_scales, latent_draws, standard_normals
    from bayescal.fleet.sampling import _latents, sample_fleet

    fleet = fleet_from_frame(_frame(small_fleet), source="small")
    data, plan = fleet_data(_Fits(fleet, 2, np.random.default_rng(1)), FleetSpec(walk=False), 0.03)
    spec = FleetSpec(walk=False, chains=2, warmup=40, draws=30, extend=2)
    unreachable = sample_fleet(data, plan, spec, seed=1, inference=InferenceSpec(min_ess=1e9))
    met = sample_fleet(data, plan, spec, seed=1, inference=InferenceSpec(min_ess=0.0, max_rhat=10.0))
    assert unreachable.draws["sigma_camera"].shape[:2] == (2, 90)  # 30 draws, then 2 x 30 more
    assert met.draws["sigma_camera"].shape[:2] == (2, 30)
    # the extension continues the chains: their first 30 draws are the unextended run's
    np.testing.assert_allclose(unreachable.draws["sigma_camera"][:, :30], met.draws["sigma_camera"], rtol=1e-7)
    hyper = {k: v.reshape(-1, v.shape[-1])[:40] for k, v in met.draws.items() if k in plan.sampled()}
    args = data.arrays()
    with numerics():
        g_jit, cam_jit = _latents(plan, hyper, args, np.random.default_rng(5))
    sc, kappa = draw_scales(plan, hyper, args)
    g, cam = latent_draws(plan, sc, kappa, args, *standard_normals(plan, 40, np.random.default_rng(5)))
    np.testing.assert_allclose(g_jit, g, rtol=1e-6, atol=1e-9 * np.abs(g).max())
    np.testing.assert_allclose(cam_jit, cam, rtol=1e-6, atol=1e-9 * np.abs(cam).max())


def test_the_laplace_start_is_the_mode_and_its_curvature(small_fleet):
    """The chains' start and mass matrix: at the returned point the potential's gradient
    vanishes, and the covariance is the inverse of a central-difference Hessian of the
    gradient (not the automatic one the sampler uses)."""
    import jax

    from bayescal._config import numerics
    from bayescal.fleet.sampling import _potential, laplace_start

    fleet = fleet_from_frame(_frame(small_fleet), source="small")
    data, plan = fleet_data(_Fits(fleet, 2, np.random.default_rng(1)), FleetSpec(walk=False), 0.03)
    with numerics():
        arrays = {k: jax.numpy.asarray(v) for k, v in data.arrays().items()}
        mode, cov = laplace_start(plan, arrays)
        grad = jax.jit(jax.grad(lambda u: _potential(plan)(u, arrays)))
        g0 = np.asarray(grad(mode))
        h = 1e-5
        eye = np.eye(mode.size)
        fd = np.stack([(np.asarray(grad(mode + h * e)) - np.asarray(grad(mode - h * e))) / (2 * h) for e in eye])
    assert np.max(np.abs(g0)) < 1e-4 * max(1.0, np.max(np.abs(np.diag(fd))))
    np.testing.assert_allclose(cov @ (0.5 * (fd + fd.T)), eye, atol=1e-4)


@pytest.mark.slow  # a Monte Carlo comparison of two samplers (12 s)
def test_without_a_usable_mode_the_chains_sample_the_same_posterior(small_fleet, monkeypatch):
    """The fallback (dispersed starts, unit mass matrix) and the Laplace start give the same
    posterior of the log scales: means within 4 Monte Carlo standard errors of their difference."""
    import arviz as az

    import bayescal.fleet.sampling as sampling
    from bayescal._config import numerics

    fleet = fleet_from_frame(_frame(small_fleet), source="small")
    data, plan = fleet_data(_Fits(fleet, 2, np.random.default_rng(1)), FleetSpec(walk=False), 0.03)
    spec = FleetSpec(walk=False, chains=2, warmup=80, draws=250, extend=0)
    args = data.arrays()
    with numerics():
        with_mode, _, _ = sampling._run_chains(plan, spec, args, seed=3)
        monkeypatch.setattr(sampling, "laplace_start", lambda plan_, arrays: None)
        without, _, _ = sampling._run_chains(plan, spec, args, seed=4)
    for a, b in ((with_mode[..., i], without[..., i]) for i in range(with_mode.shape[-1])):
        se = np.sqrt(a.var() / float(az.ess(a)) + b.var() / float(az.ess(b)))
        assert abs(a.mean() - b.mean()) < 4 * se


def test_chains_with_a_divergence_are_run_again_at_the_retry_target(small_fleet, monkeypatch):
    """The policy of a unit's own NUTS fit: new chains at ``retry_target_accept``, whose diagnostics
    decide, with the first run's count kept (the sampler is replaced: no seed has to diverge)."""
    import bayescal.fleet.sampling as sampling

    fleet = fleet_from_frame(_frame(small_fleet), source="small")
    data, plan = fleet_data(_Fits(fleet, 2, np.random.default_rng(1)), FleetSpec(walk=False), 0.03)
    spec = FleetSpec(walk=False, chains=2, warmup=20, draws=20, extend=0)
    dim = sum(plan.sampled().values())
    targets = []

    def chains(plan_, spec_, args, seed, inference):
        targets.append(spec_.target_accept)
        draws = np.log(0.5) + 0.1 * np.random.default_rng(seed).standard_normal((2, 20, dim))
        return Phased(draws, 3 - 3 * (len(targets) > 1), 1000)

    monkeypatch.setattr(sampling, "_run_chains", chains)
    out = sampling.sample_fleet(data, plan, spec, seed=1, inference=InferenceSpec(retry_target_accept=0.97))
    assert targets == [spec.target_accept, 0.97]
    assert out.diagnostics["divergences"] == 0 and out.diagnostics["first_divergences"] == 3
    assert out.diagnostics["gradients"] == 2000  # both runs counted
    targets.clear()
    off = sampling.sample_fleet(data, plan, spec, seed=1, inference=InferenceSpec(retry_target_accept=0.0))
    assert targets == [spec.target_accept] and off.diagnostics["divergences"] == 3


def test_a_few_divergences_left_after_the_retry_get_the_last_run(small_fleet, monkeypatch):
    """The one retry loop (inference.chains.with_retries), as a unit's fit has it: 1 divergence in 100
    draws after the retry (under 2 %) gets one last run at 0.99, with new chains (its own seed)."""
    import bayescal.fleet.sampling as sampling
    from bayescal.inference.chains import LAST_RETRY_ACCEPT, attempt_seed

    fleet = fleet_from_frame(_frame(small_fleet), source="small")
    data, plan = fleet_data(_Fits(fleet, 2, np.random.default_rng(1)), FleetSpec(walk=False), 0.03)
    spec = FleetSpec(walk=False, chains=2, warmup=20, draws=50, extend=0)
    dim = sum(plan.sampled().values())
    left = {spec.target_accept: 3, 0.95: 1, LAST_RETRY_ACCEPT: 0}
    runs = []

    def chains(plan_, spec_, args, seed, inference):
        runs.append((spec_.target_accept, seed))
        draws = np.log(0.5) + 0.1 * np.random.default_rng(seed).standard_normal((2, 50, dim))
        return Phased(draws, left[spec_.target_accept], 1000)

    monkeypatch.setattr(sampling, "_run_chains", chains)
    out = sampling.sample_fleet(data, plan, spec, seed=1, inference=InferenceSpec(retry_target_accept=0.95))
    seeds = [attempt_seed(1, k) for k in range(3)]  # the one seed rule of every rerun
    assert runs == list(zip([spec.target_accept, 0.95, LAST_RETRY_ACCEPT], seeds, strict=True))
    assert out.diagnostics["first_divergences"] == 3 and out.diagnostics["retried_at"] == LAST_RETRY_ACCEPT
    assert out.diagnostics["divergences"] == 0 and out.diagnostics["gradients"] == 3000


# ---------------------------------------------------------------- a fleet with known truth
@pytest.mark.slow  # the small fleet's fit (a minute cold); the CLI test fits a fleet in the default run
def test_leave_one_unit_out_is_reliable_on_the_small_fleet(fitted):
    """With every latent integrated out, PSIS reweights only the scales: few units have Pareto
    k > 0.7, where the conditional log-likelihood (each unit's own jitter and walk step in it)
    gives most of them (16 of 17 on this fleet)."""
    import arviz as az

    from bayescal.fleet.sampling import loo_of

    _, result, _ = fitted
    loo = loo_of(result.plan, result.data, result.draws)
    ll = result.draws.log_likelihood
    conditional = az.loo(az.from_dict({"posterior": {"d": np.zeros(ll.shape[:2])}, "log_likelihood": {"y": ll}}))
    assert loo["n_high_k"] <= 4 < 8 <= int(np.sum(np.asarray(conditional.pareto_k) > 0.7))
    assert np.isfinite(loo["elpd_loo"]) and loo["pointwise"].shape == (result.plan.n_units,)


@pytest.mark.slow  # the small fleet's fit (a minute cold); the CLI test fits a fleet in the default run
def test_small_fleet_samples_cleanly_and_covers_the_truth(fitted):
    fleet, result, truth = fitted
    d = result.draws.diagnostics
    assert d["divergences"] == 0
    assert d["max_rhat"] <= 1.02
    assert min(d["min_ess_bulk"], d["min_ess_tail"]) >= 200  # the verdict asks 400; here a margin for the seed
    hyper = result.hyperparameters()
    widening = hyper[hyper.parameter == "interval inflation of one channel"]
    assert list(widening.quantity) == list(result.kinds) and np.all(np.isfinite(widening["median"]))
    s = result.summary().merge(truth, on=["camera", "campaign", "channel"], suffixes=("", "_true"))
    assert len(s) == 3 * (6 * 3 - 1)
    # the gain against each campaign's sphere reading (the absolute gain adds the sphere's 3 % scale
    # error, one draw per campaign shared by every unit: its coverage needs many fleets, see the benchmark)
    rel = np.exp(result.unit_values(relative=True)[:, :, 0, :])  # (S, U, C)
    lo, hi = np.quantile(rel, [0.025, 0.975], axis=0)
    keys = [(u.camera, u.campaign.date().isoformat()) for u in fleet.units]
    t = truth.set_index(["camera", "campaign", "channel"])
    true_rel = np.array(
        [
            [t.loc[(cam, day, ch), "gain"] * t.loc[(cam, day, ch), "sphere_scale"] for ch in result.channels]
            for cam, day in keys
        ]
    )
    covered = {"gain_rel": (lo <= true_rel) & (true_rel <= hi)}
    covered["offset"] = ((s["offset_lo"] <= s["offset_true"]) & (s["offset_true"] <= s["offset_hi"])).to_numpy()
    for q, c in covered.items():
        # 51 correlated values; honest 95 % intervals cover >= 40 of them with probability > 0.99 here
        assert c.sum() >= 40, (q, c.mean())
    # where the channels move together the excess and the campaign's own state add one variance per unit
    # each and are not identified apart: the state carries it, so the fleet does not widen a unit's relative
    # gain much beyond its own interval (median 1.11x; with the excess's wide prior there, 1.60x)
    own_sd = np.sqrt(np.diagonal(result.unit_cov, axis1=1, axis2=2)[:, : len(result.channels)])  # (U, C)
    assert np.median(np.log(rel).std(axis=0) / own_sd) < 1.25
    # the brief camera (3 levels) borrows the fleet's nonlinearity: narrower than alone
    brief = s[s.camera == "SN006"]
    assert np.all((brief.eta1_hi - brief.eta1_lo) < 2 * 1.96 * brief.eta1_alone_sd)


def test_the_excess_where_the_channels_move_together_yields_to_the_jitter(tmp_path):
    """The tight prior sits only where the excess and the campaign jitter are the same value per unit."""
    base = dict(n_channels=3, n_cameras=4, n_units=12, n_spheres=3, n_walk=8, max_walk=2, drift=True, walk=True)
    base |= dict(pooling="partial", spread_prior=1.0, rate_prior=0.5, walk_prior=0.3, excess_prior=2.0)
    plan = Plan(n_kinds=3, max_units=3, excess_together_prior=0.1, **base)
    np.testing.assert_array_equal(plan.excess_priors(), [0.1, 2.0, 0.1, 2.0, 2.0, 2.0])  # eta has no jitter
    no_jitter = Plan(n_kinds=3, max_units=0, excess_together_prior=0.1, **base)
    np.testing.assert_array_equal(no_jitter.excess_priors(), np.full(6, 2.0))
    bad = tmp_path / "fleet.toml"
    bad.write_text(SPEC.read_text().replace("\n[fleet]\n", "\n[fleet]\nexcess_together_prior = 0.0\n"))
    with pytest.raises(SpecError, match="excess_together_prior"):
        load_spec(bad)


@pytest.mark.slow  # the small fleet's fit (a minute cold); the CLI test fits a fleet in the default run
def test_predictions_for_new_cameras_dates_and_drift(fitted):
    fleet, result, truth = fitted
    last = result.at("SN001", "2026-03-01")
    ahead = result.at("SN001", "2029-03-01")
    new = result.at(None, "2026-03-01")
    width = lambda v: np.subtract(*np.quantile(v, [0.975, 0.025]))  # noqa: E731
    k = result.kinds.index("offset")
    assert width(ahead[:, k, 0]) > width(last[:, k, 0])  # the band grows with time
    assert width(new[:, k, 0]) > 3 * width(last[:, k, 0])  # a camera never measured: the population
    p_small = result.drift_probability("SN001", "2026-04-01", 5.0)
    p_large = result.drift_probability("SN001", "2030-03-01", 5.0)
    assert 0.0 <= p_small < p_large <= 1.0
    # every camera of a campaign shares its sphere: the fleet's common trend is known only as well as the
    # spheres' 3 % scale errors allow, a camera's trend against the fleet far better; the caveat says so
    absolute, relative = result.trend_sd("SN001")
    assert absolute > 2 * relative > 0
    assert "cannot be told apart from the campaigns' sphere scale errors" in result.drift_caveat("SN001")
    p_rel = result.drift_probability("SN001", "2027-03-01", 2.0, relative=True)
    assert p_rel < result.drift_probability("SN001", "2027-03-01", 2.0)


@pytest.mark.slow  # the command-line test saves, loads and exports a fleet in the default run
def test_fleet_directory_round_trip_and_calibration_export(fitted, tmp_path):
    from bayescal.fleet import FleetFit
    from bayescal.fleet.export import write_calibration
    from bayescal.model.setting import Setting
    from bayescal.posterior.calibration import Calibration

    fleet, result, truth = fitted
    result.save(tmp_path / "fleet")
    loaded = FleetFit.load(tmp_path / "fleet")
    assert loaded.cameras == result.cameras
    np.testing.assert_allclose(loaded.unit_values(), result.unit_values())
    assert loaded.drift_probability("SN002", "2027-03-01", 2.0, seed=5) == result.drift_probability(
        "SN002", "2027-03-01", 2.0, seed=5
    )
    write_calibration(tmp_path / "fleet", tmp_path / "cal", "SN002", "2026-03-01")
    cal = Calibration.load(tmp_path / "cal")
    ref = cal.reference
    tr = truth[(truth.camera == "SN002") & (truth.campaign == "2026-03-01")].set_index("channel")
    for c, ch in enumerate(cal.channels):
        lo, hi = np.quantile(cal.coef[:, c, 0], [0.001, 0.999])
        assert lo < tr.loc[ch, "gain"] < hi
    dn = cal.expected_dn("G", np.array([10.0]), Setting(ref.exposure_s, ref.gain, ref.tdi_stages, None))
    assert np.all(np.isfinite(dn))


# ------------------------------------------------------------------------- command line
def test_cli_simulate_fit_query_and_predict(tmp_path, capsys):
    from bayescal.cli import main

    design = tmp_path / "design.toml"
    design.write_text(
        'n_cameras = 3\ncampaigns = ["2024-03-01", "2025-09-01"]\nn_pixels = 32\nn_frames = 10\nbrief = ["SN003"]\n'
    )
    spec = tmp_path / "fleet.toml"
    spec.write_text(_spec(draws=800).to_toml())  # a tiny fleet: cheap draws, ESS well over the verdict's 400
    table = tmp_path / "fleet.csv"
    assert main(["fleet-simulate", str(design), "--out", str(table), "--seed", "2"]) == 0
    out = tmp_path / "fit"
    code = main(["fleet", str(table), "--model", str(spec), "--out", str(out), "--quiet", "--report"])
    assert (out / "fleet.nc").is_file() and (out / "fleet_report.html").stat().st_size > 10_000
    html = (out / "fleet_report.html").read_text()
    assert "How well the drift is known" in html and "trend sd, against the fleet" in html
    assert code == 0, capsys.readouterr().err
    cal = tmp_path / "cal"
    args = ["fleet-query", str(out), "--camera", "SN001", "--date", "2026-09-01", "--drift-percent", "3"]
    assert main([*args, "--calibration", str(cal)]) == 0
    captured = capsys.readouterr()
    printed = captured.out
    assert "P(gain drifted by more than 3 %" in printed
    assert "against the fleet's common trend) = " in printed
    assert "recalibrate by" in printed or "risk stays below" in printed
    assert main(["predict", str(cal), "--channel", "G", "--exposure-s", "0.004", "--stimulus", "5"]) == 0
    # the exported calibration's summary is of the one schema: every key the report reads, the fleet's verdict
    from bayescal.io.fit_folder import FitFolder

    assert FitFolder.at(cal).summary.stimulus_unit and FitFolder.at(cal).summary.lsq
    exported = json.loads((cal / "summary.json").read_text())
    assert exported["backend"] == "fleet" and exported["source"]["camera"] == "SN001"
    gains = [p for p in exported["parameters"] if p["parameter"].startswith("gain[")]
    assert len(gains) == 3 and all(p["q2.5"] < p["mean"] < p["q97.5"] for p in gains)
    assert main(["fleet-query", str(out), "--new-camera", "--date", "2026-09-01"]) == 0
    # bad input: exit 2 with the key named
    design.write_text("n_cameras = 4\nnframes = 3\n")
    assert main(["fleet-simulate", str(design), "--out", str(table)]) == 2
    assert "unknown key 'nframes'" in capsys.readouterr().err
    assert main(["fleet-query", str(out), "--camera", "SN999"]) == 2
    capsys.readouterr()
    # dates: parsed, refused far outside the campaigns (2024-03 to 2025-09: 5 years' reach), warned
    # outside them, and a drift asked at a date before the camera's last campaign is refused
    for argv, fragment in [
        (["--camera", "SN001", "--date", "1900-01-01"], "years outside the campaigns (2024-03-01 to 2025-09-01)"),
        (["--camera", "SN001", "--date", "2300-01-01"], "the fleet answers up to 5 years beyond them"),
        (["--camera", "SN001", "--date", "2024-06-01", "--drift-percent", "2"], "is not after camera 'SN001''s last"),
        (["--new-camera", "--drift-percent", "2", "--date", "2026-01-01"], "--drift-percent needs --camera"),
        (["--camera", "SN001", "--date", "next tuesday"], "is not a date"),
    ]:
        try:
            rc = main(["fleet-query", str(out), *argv])
        except SystemExit as exc:  # argparse's own check of the date
            rc = exc.code
        assert rc == 2, argv
        captured = capsys.readouterr()
        assert fragment in captured.err and captured.out == "", (argv, captured)  # refused before any table
    assert main(["fleet-query", str(out), "--camera", "SN001", "--date", "2027-01-01"]) == 0
    assert "EXTRAPOLATION: 2027-01-01 is 1.33 years outside the campaigns" in capsys.readouterr().err


def test_laplace_refuses_pooled_channels_before_any_work(seed000):
    import bayescal as bc
    from bayescal.errors import SpecError

    spec, design = seed000
    sim = bc.simulate(spec, design, seed=0)
    pooled = spec.replace(response={"pooled": True})
    with pytest.raises(SpecError, match="laplace backend cannot fit pooled channels.*bayescal fleet"):
        bc.fit(sim.table, pooled, "laplace")
    with pytest.raises(SpecError, match="laplace backend cannot fit pooled channels"):
        bc.fit_many([sim.table], pooled, "laplace")


@pytest.mark.slow
def test_select_compares_poolings_by_loo(tmp_path, capsys):
    from bayescal.cli import main

    table, _ = simulate_fleet(_small_design(n_cameras=4, brief=()), seed=5)
    path = tmp_path / "fleet.csv"
    table.to_csv(path, index=False)
    spec = tmp_path / "fleet.toml"
    spec.write_text(_spec().to_toml())
    assert main(["select", str(path), "--model", str(spec), "--pooling"]) == 0
    out = capsys.readouterr().out
    rows = [line.split()[0] for line in out.splitlines()[2:5]]
    assert sorted(rows) == ["complete", "none", "partial"]
    assert rows[-1] == "complete"  # cameras 8 % apart are not one camera


def test_refitting_the_same_reports_rebuilds_the_same_blocks(small_fleet):
    """``with_units`` (what simulation-based calibration refits) rebuilds every data block of the
    likelihood from the units' reports: the fleet's own reports give back the fleet's blocks."""
    from bayescal.fleet.data import with_units

    fleet = fleet_from_frame(_frame(small_fleet), source="small")
    data, plan = fleet_data(_Fits(fleet, 3, np.random.default_rng(5)), FleetSpec(), 0.03)
    again = with_units(plan, data, data.y.reshape(plan.n_units, plan.n_kinds, plan.n_channels))
    for name in ("g_gg", "g_gm", "g_mm", "b_g", "b_m", "yy"):
        a, b = getattr(data, name), getattr(again, name)
        np.testing.assert_allclose(b, a, rtol=1e-8, atol=1e-10 * np.abs(a).max(), err_msg=name)


def test_the_sphere_scale_means_what_it_means_for_one_camera(small_fleet):
    """``[sphere] common_rel`` is the sd of the log of the sphere's scale for a camera
    (:func:`bayescal.model.components.sphere.fold_common_scale`) and for the fleet alike: the fleet's
    prior on a campaign's sphere, back in log-gain units, has that sd (it read ``log1p(common_rel)``)."""
    from bayescal.model.components.sphere import fold_common_scale

    fleet = fleet_from_frame(_frame(small_fleet), source="small")
    for rel in (0.03, 0.2):
        data, _ = fleet_data(_Fits(fleet, 3, np.random.default_rng(5)), FleetSpec(), rel)
        assert data.sphere_sd * data.scale[0] == pytest.approx(rel, rel=1e-12)
        # the camera: A1_abs = A1_rel / s, so log A1_abs has the same sd as log s
        a, _ = fold_common_scale(np.ones((200_000, 1, 2)), rel, np.random.default_rng(0))
        assert np.log(a[..., 1]).std() == pytest.approx(rel, rel=0.01)  # MC sd of an sd: 0.16 %


@pytest.mark.slow
def test_stage_two_passes_simulation_based_calibration():
    """Fleets drawn from stage two's own prior (20 of them; benchmarks/fleet_sbc.py runs 100):
    rank histograms uniform (5 bins, Bonferroni over quantities) and mean 95 % coverage within
    3 Monte Carlo sd (sqrt(0.0475 / 20)) of nominal."""
    from bayescal.fleet.stage1 import fit_units
    from bayescal.validation.fleet_sbc import run_fleet_sbc

    table, _ = simulate_fleet(_small_design(), seed=7)
    fleet = fleet_from_frame(table.astype(str), source="small")
    spec = _spec()
    fits = fit_units(fleet, spec, "laplace", seed=7)
    data, plan = fleet_data(fits, spec.fleet, spec.sphere.common_rel)
    res = run_fleet_sbc(plan, data, spec.fleet, 20, seed=11, inference=spec.inference, bins=5)
    summ = res.summary()
    assert summ.p_uniform.min() > 0.01 / len(summ), summ.sort_values("p_uniform").head()
    assert abs(summ.coverage95.mean() - 0.95) < 3 * np.sqrt(0.0475 / 20), summ.coverage95.describe()


def test_fleet_sbc_statistics_flag_a_too_narrow_posterior(tmp_path):
    """The rank statistics on constructed ranks: ranks of a correct posterior (uniform on
    0..L) pass, and those of a posterior half as wide as it should be (truths outside the
    draws' central half land in the edge bins: a U shape, coverage ~0.67) fail; the rank
    histogram figure is written."""
    from scipy import stats

    from bayescal.validation.fleet_sbc import FleetSBC

    rng = np.random.default_rng(3)
    n, draws = 400, 599
    q = rng.uniform(size=n)
    narrow = np.clip(stats.norm.cdf(2.0 * stats.norm.ppf(q)), 0, 1)  # the truth's quantile under a half-width posterior
    ranks = pd.DataFrame({"good": np.floor(q * (draws + 1)).astype(int), "narrow": np.floor(narrow * (draws + 1))})
    covered = pd.DataFrame({"good": np.abs(q - 0.5) < 0.475, "narrow": np.abs(narrow - 0.5) < 0.475})
    res = FleetSBC(
        ranks=ranks.astype(int),
        covered=covered,
        n_draws=draws,
        bins=10,
        diagnostics=pd.DataFrame({"divergences": np.zeros(n)}),
    )
    summ = res.summary()
    assert summ.loc["good", "p_uniform"] > 1e-3 and summ.loc["narrow", "p_uniform"] < 1e-6
    assert abs(summ.loc["good", "mean_rank"] - 0.5) < 4 * np.sqrt(1 / 12 / n)
    assert summ.loc["narrow", "coverage95"] < 0.75 < summ.loc["good", "coverage95"]
    counts = res.histograms()
    assert counts.sum().tolist() == [n, n] and counts["narrow"].iloc[[0, -1]].min() > 2 * n / 10
    res.plot(tmp_path / "ranks.png")
    assert (tmp_path / "ranks.png").stat().st_size > 0


def test_a_filtered_frame_reads_as_its_rows(small_fleet):
    """A frame with rows left out (labels that are not positions) is read by position, not by label."""
    table, _ = small_fleet
    kept = table[table.campaign != "2026-03-01"].astype(str)
    assert kept.index[-1] >= len(kept)  # its labels run past its length
    fleet = fleet_from_frame(kept, source="filtered")
    assert sum(len(u.table.frame) for u in fleet.units) == len(kept)
    assert {u.campaign.date().isoformat() for u in fleet.units} == {"2024-03-01", "2025-03-01"}


def test_the_named_latent_slots_tile_the_vectors_and_the_scales_follow_them():
    """Every global and camera slot is named once (no overlap, no gap), and the slot scales come in
    the camera slots' order, so design, scales, draws and SBC read one layout."""
    from bayescal.fleet.marginal import block_scales
    from bayescal.fleet.plan import Plan

    plan = Plan(
        n_kinds=3, n_channels=3, n_cameras=4, n_units=8, n_spheres=2, n_walk=3, max_walk=2, drift=True,
        walk=True, pooling="partial", spread_prior=1.0, rate_prior=1.0, walk_prior=1.0, max_units=3,
        shared=True, n_campaigns=3,
    )  # fmt: skip

    def indices(slots):
        return [i for s in slots for i in ([s] if isinstance(s, int) else range(s.start, s.stop))]

    assert sorted(indices(plan.g)) == list(range(plan.n_global))
    assert sorted(indices(plan.m)) == list(range(plan.block))
    m = plan.m
    assert (len(range(m.walk.start, m.walk.stop)), len(range(m.jitter.start, m.jitter.stop))) == (2, 3)
    hyper = {
        "sigma_camera": np.full(3, 0.1), "sigma_channel": np.full(3, 0.2), "rate_sd": np.full(2, 0.3),
        "walk_sd": np.full(2, 0.4), "jitter_sd": np.full(2, 0.5),
    }  # fmt: skip
    scales = block_scales(plan, hyper)
    assert scales.shape == (3, plan.block)
    assert np.all(scales[:2, m.a] == 0.1) and np.all(scales[:2, m.b] == 0.2) and np.all(scales[:2, m.r] == 0.3)
    assert (
        np.all(scales[:2, m.walk] == 0.4) and np.all(scales[:2, m.jitter] == 0.5) and np.all(scales[:, m.shared] == 1)
    )


@pytest.mark.slow  # stage one and three stage-two fits (about a minute)
def test_partial_pooling_wins_on_a_fleet_that_has_a_spread(small_fleet):
    """The small fleet's cameras differ by a spread: partial pooling ranks first by arviz's compare,
    no pooling and complete pooling behind it by more than 2 se of the difference."""
    from bayescal.fleet.posterior import compare_pooling

    fleet = fleet_from_frame(small_fleet[0].astype(str), source="small fleet")
    table = compare_pooling(fleet, _spec(), seed=3)
    assert list(table.index)[0] == "partial" and table.loc["partial", "elpd_diff"] == 0.0
    for other in ("none", "complete"):
        assert -table.loc[other, "elpd_diff"] > 2 * table.loc[other, "dse"], table
    assert np.isclose(table["weight"].sum(), 1.0)


def test_the_fleet_section_belongs_to_the_fleet_package():
    """``[fleet]`` is read into the fleet's own spec class, round-trips, takes ``replace``, names a bad key,
    defaults where a spec has none, and loading a camera's spec does not import the fleet."""
    import subprocess
    import sys

    spec = _spec()
    assert type(spec.fleet) is FleetSpec and spec.fleet.draws == 500
    again = type(spec).from_dict(__import__("tomllib").loads(spec.to_toml()))
    assert again.fleet == spec.fleet
    assert spec.replace(fleet={"draws": 40}).fleet.draws == 40
    assert load_spec(MODELS / "seed000_bayer.toml").fleet == FleetSpec()  # the defaults
    bad = spec.to_dict()
    bad["fleet"] = bad["fleet"] | {"warmup": 3}
    with pytest.raises(SpecError, match="fleet.warmup = 3"):
        type(spec).from_dict(bad)
    code = "import sys, bayescal; bayescal.load_spec('seed000'); print('bayescal.fleet' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


@pytest.mark.slow  # the small fleet's fit (a minute cold); the CLI test fits a fleet in the default run
def test_the_pooled_quantities_come_from_a_units_reported_draws_and_back(fitted):
    """What stage one pools (``log A1``, ``A0``, ``eta``) is read from a unit's reported draws by the model
    layer, and the export's inverse gives those draws back."""
    from bayescal.model.physical import POOLED, pooled_quantities, reported_from_pooled

    _, fit, _ = fitted
    phys = fit.fits.physical(0)
    pooled = pooled_quantities(phys)
    assert tuple(pooled)[:2] == POOLED and tuple(pooled)[2:] == tuple(fit.fits.kinds)[2:]
    back = reported_from_pooled(pooled, fit.spec)
    order = fit.spec.response.order
    assert np.allclose(back["A_rel"], phys["A_rel"][..., : order + 1], rtol=1e-10, atol=1e-9)
    assert np.allclose(back["gain_rel"], phys["gain_rel"], rtol=1e-12)
    assert np.allclose(back["nonlinearity"], phys["nonlinearity"])
