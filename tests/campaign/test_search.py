"""The design arithmetic against closed forms: a linear Gaussian model, where the Fisher information is
exact and the best design is known."""

import numpy as np
import pytest

from bayescal.campaign.checks import checks_of, missing
from bayescal.campaign.grid import Group
from bayescal.campaign.information import Linearisation
from bayescal.campaign.search import Costs, cost_of, greedy, pruned, relaxed, trimmed


def _linear(prior: np.ndarray, rows: np.ndarray, targets: np.ndarray) -> Linearisation:
    """A linear model with unit-noise rows ``rows`` (one per group): group ``k``'s information is
    ``rows[k] rows[k]'``; the targets are linear in the parameters."""
    k, d = rows.shape
    factors = np.zeros((1, k, 2, d))
    factors[0, :, 0] = rows
    return Linearisation(
        names=tuple(f"t{i}" for i in range(len(targets))),
        values=np.zeros((1, len(targets))),
        gradients=targets[None],
        prior=prior[None],
        factors=factors,
        clipped=np.zeros(k),
    )


def test_widths_are_the_conjugate_posterior_of_a_linear_model():
    rng = np.random.default_rng(1)
    x = rng.normal(size=(7, 3))
    prior = np.diag([0.5, 2.0, 1.0])
    targets = rng.normal(size=(4, 3))
    lin = _linear(prior, x, targets)
    counts = np.array([0, 2, 1, 0, 3, 1, 1])
    cov = np.linalg.inv(prior + x.T @ np.diag(counts) @ x)  # closed-form posterior covariance
    np.testing.assert_allclose(lin.sd(counts), np.sqrt(np.diag(targets @ cov @ targets.T)), rtol=1e-10)


def test_one_more_measurement_lowers_each_variance_as_a_full_update_does():
    rng = np.random.default_rng(2)
    x = rng.normal(size=(5, 4))
    lin = _linear(np.eye(4) * 0.3, x, rng.normal(size=(3, 4)))
    counts = np.array([1, 0, 2, 0, 1])
    cov = lin.covariance(counts)
    before = lin.variances(cov)[0]
    reductions = lin.reductions(cov)[0]
    for k in range(5):
        after = lin.variances(lin.covariance(counts + np.eye(5, dtype=int)[k]))[0]
        np.testing.assert_allclose(before - reductions[k], after, rtol=1e-9, atol=1e-14)


def test_relaxed_design_spends_on_the_cheapest_information():
    """One parameter, prior precision p0, group k adds f_k at cost c_k: the cheapest design reaching
    variance g^2 measures only the group of largest f_k / c_k, (1/g^2 - p0) / f_k times."""
    f = np.array([1.0, 4.0, 2.0])
    costs = np.array([1.0, 3.0, 1.0])  # information per cost: 1, 4/3, 2 -> group 2
    lin = _linear(np.array([[0.1]]), np.sqrt(f)[:, None], np.array([[1.0]]))
    goal = np.array([0.2])
    w = relaxed(lin, np.zeros(3), goal, costs, np.ones(3, dtype=bool))
    np.testing.assert_allclose(w, [0.0, 0.0, (1 / 0.04 - 0.1) / 2.0], atol=1e-4)


def test_relaxed_design_within_a_budget_narrows_the_targets_most():
    """Two independent parameters with the same prior: a budget of b rows split to minimise
    1/(p + w1) + 1/(p + w2) is split evenly."""
    rows = np.eye(2)
    lin = _linear(np.eye(2) * 0.5, rows, np.eye(2))
    w = relaxed(lin, np.zeros(2), np.ones(2), np.ones(2), np.ones(2, dtype=bool), budget=6.0)
    np.testing.assert_allclose(w, [3.0, 3.0], atol=1e-3)


def test_greedy_meets_the_goals_and_pruning_takes_back_what_is_not_needed():
    rows = np.eye(3)
    lin = _linear(np.eye(3) * 0.01, rows, np.eye(3))
    goals = np.array([0.5, 0.5, 1.0])  # variances 0.25, 0.25, 1: about 4, 4 and 1 measurements
    settings = [(1.0,), (2.0,), (3.0,)]
    costs = Costs(rows_per_group=1)
    counts, spent = greedy(lin, np.zeros(3, int), goals, costs, settings, eligible=np.ones(3, bool))
    assert np.all(lin.sd(counts) <= goals)
    np.testing.assert_array_equal(counts, [4, 4, 1])
    assert spent == cost_of(counts, costs, settings) == 9
    more = counts + np.array([2, 0, 3])
    np.testing.assert_array_equal(pruned(lin, more, goals, costs, settings, np.zeros(3, int)), counts)


def test_trimming_removes_the_least_useful_measurement_first():
    rows = np.eye(2)
    lin = _linear(np.eye(2) * 0.01, rows, np.eye(2))
    settings = [(1.0,), (2.0,)]
    trimmed_counts = trimmed(lin, np.array([6, 2]), np.ones(2), Costs(1), settings, 6.0, np.zeros(2, int))
    np.testing.assert_array_equal(trimmed_counts, [4, 2])  # 1/4 + 1/2 < 1/6 + 1/1... removals from the rich group


def test_setting_changes_are_paid_once_per_setting():
    settings = [(1.0,), (1.0,), (2.0,)]
    costs = Costs(rows_per_group=3, setting_change=10.0)
    assert cost_of(np.array([1, 2, 0]), costs, settings) == 3 * 3 + 10
    assert cost_of(np.array([1, 0, 1]), costs, settings) == 2 * 3 + 20
    np.testing.assert_array_equal(costs.of(settings, {(1.0,)}), [3.0, 3.0, 13.0])


def _g(t, gain, level):
    return Group(t, gain, 1.0, None, level)


@pytest.mark.parametrize(
    ("counts", "supported"),
    [
        ([1, 1, 1, 1, 1, 0, 1, 1, 1, 1, 1], {"misfit", "holdout", "dark", "domain"}),
        ([1, 1, 1, 1, 0, 0, 1, 1, 1, 1, 1], {"holdout", "dark", "domain"}),  # 4 levels: too few for order 2
        ([1, 1, 1, 1, 1, 0, 1, 1, 1, 1, 0], {"misfit", "holdout", "domain"}),  # one dark exposure at gain 2
        ([1, 1, 1, 1, 1, 0, 0, 1, 1, 0, 0], {"misfit", "dark"}),  # one setting, one gain
    ],
)
def test_checks_follow_the_rows_they_need(counts, supported):
    lit = [*(_g(0.01, 1.0, i) for i in range(5)), _g(0.02, 1.0, 0), _g(0.01, 2.0, 0)]
    groups = lit + [_g(0.01, 1.0, -1), _g(0.02, 1.0, -1), _g(0.01, 2.0, -1), _g(0.02, 2.0, -1)]
    protocol = np.ones(11, int)
    names = {"misfit": "misfit of", "holdout": "leave-one", "dark": "dark current", "domain": "nonlinearity"}
    got = {
        key
        for key, prefix in names.items()
        for c in checks_of(groups, np.array(counts), 2, protocol)
        if c.name.startswith(prefix) and c.supported
    }
    assert got == supported
    repairs = missing(groups, np.array(counts), 2, protocol)
    assert len(repairs) == 4 - len(supported)
    for mask in repairs:  # every repair names groups not yet measured or another setting
        assert mask.any()


def test_integrating_the_noise_scale_gives_the_students_t_widths_of_a_linear_model():
    """y = X b + e with the noise sd unknown (flat priors): the posterior variance of b averages to
    sigma^2 (X'X)^-1 (n - p) / (n - p - 3) over data sets (sigma^2 given RSS is inverse gamma; E[RSS] =
    (n - p) sigma^2).  The design's integral reaches that from the expected residuals alone."""
    from bayescal.campaign.scale import NoiseScale

    rng = np.random.default_rng(3)
    n, p, sigma = 12, 3, 0.4
    x = rng.normal(size=(n, p))
    factors = np.zeros((1, n, 2, p + 1))
    factors[0, :, 0, :p] = x / sigma  # the mean's gradient over the noise sd
    factors[0, :, 1, p] = np.sqrt(2.0)  # the sd's gradient in theta = log sd, over the sd, times sqrt 2
    prior = np.diag([1e-9] * p + [1e-9])
    noise = NoiseScale(index=p, excess=np.array([sigma]), prior_scale=1e6, row_sd=np.full((1, n, 1), sigma))
    lin = Linearisation(
        names=("b0", "b1", "b2"),
        values=np.zeros((1, p)),
        gradients=np.eye(p, p + 1)[None],
        prior=prior[None],
        factors=factors,
        clipped=np.zeros(n),
        noise=noise,
    )
    exact = np.sqrt(sigma**2 * np.diag(np.linalg.inv(x.T @ x)) * (n - p) / (n - p - 3))
    np.testing.assert_allclose(lin.sd(np.ones(n)), exact, rtol=0.01)
    np.testing.assert_allclose(lin.at_scale().sd(np.ones(n)), exact * np.sqrt((n - p - 3) / (n - p)), rtol=1e-6)
