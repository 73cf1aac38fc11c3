"""``bayescal design`` on the seed-000 protocol: the design meets the protocol's widths with fewer rows,
keeps the model's checks, round-trips through its file, and its expected widths are those the Laplace
backend reports (the Fisher information against the Hessian; simulated campaigns)."""

import numpy as np
import pytest

import bayescal as bc
from bayescal.campaign.design import _nominal, design
from bayescal.campaign.grid import Grid
from bayescal.campaign.information import Targets, linearise
from bayescal.cli.app import main
from bayescal.io.design import load_design
from bayescal.validation.design import check_design


@pytest.fixture(scope="module")
def plan(seed000):
    spec, protocol = seed000
    return design(protocol, spec)


def test_the_design_reaches_every_protocol_width_with_fewer_rows(plan, seed000):
    spec, protocol = seed000
    w = plan.widths
    assert plan.met
    assert np.all(w["design_sd"] <= w["goal_sd"] * (1 + 1e-9))
    np.testing.assert_allclose(w["goal_sd"], w["protocol_sd"])
    assert plan.protocol_rows == 192  # the protocol's own rows: 64 groups x 3 channels
    assert plan.rows < plan.protocol_rows
    assert plan.bound_rows <= plan.rows
    # 9 coefficients and one prediction per channel and protocol setting (6 settings), clear of clipping
    assert list(w["target"][:3]) == ["A0[R]", "A1[R]", "A2[R]"]
    assert len(w) == 9 + 6 * 3


def test_the_design_keeps_every_check_the_protocol_makes(plan):
    assert plan.checks and all(c.supported for c in plan.checks)
    assert {c.name for c in plan.checks} >= {"misfit of the response's shape", "dark current"}


def test_the_design_file_reads_back_as_the_same_campaign(plan, tmp_path):
    out = plan.save(tmp_path / "designed")
    again = load_design(out / "design.toml")
    np.testing.assert_array_equal(Grid.of(plan.grid.protocol).counts(again), plan.counts)
    assert again.truth == plan.grid.protocol.truth
    table = bc.simulate(bc.load_spec(again.spec), again, seed=1).table
    assert len(table) == plan.rows


def test_fisher_information_is_the_hessian_the_laplace_fit_inverts(seed000, float64):
    """At the nominal camera's mode, the prior's precision plus every grid row's Fisher information is the
    Hessian of the negative log posterior of the grid table (the data's noise averages out of it)."""
    spec, protocol = seed000
    grid = Grid.of(protocol)
    state = _nominal(grid, spec, seed=0, say=lambda m: None)
    lin = linearise(state.program, state.model, np.asarray(state.mode.mode)[None], Targets(), state.groups, len(grid))
    precision = lin.precision(np.ones(len(grid)))[0]
    hessian = np.asarray(state.mode.cov)
    cov = np.linalg.inv(precision)
    # the coefficients' widths through either matrix agree to the noise of one dataset (~1 %)
    grad = lin.gradients[0]
    from_fisher = np.sqrt(np.einsum("td,de,te->t", grad, cov, grad))
    from_hessian = np.sqrt(np.einsum("td,de,te->t", grad, hessian, grad))
    np.testing.assert_allclose(from_fisher, from_hessian, rtol=0.03)


def test_simulated_campaigns_give_the_widths_the_design_expected(plan):
    """Five campaigns of the design, simulated and fitted by the Laplace backend: the posterior sds they
    report are those expected, within 10 % (the benchmark's 50 campaigns: within 5 %)."""
    check = check_design(plan, campaigns=5, seed=100)
    assert check.failed == 0
    assert check.worst_ratio < 0.10
    assert check.coverage > 0.8  # 135 intervals; the benchmark pins coverage down over 1350


def test_the_command_writes_the_design_and_refuses_unknown_targets(tmp_path, capsys):
    assert main(["design", "seed000", "--out", str(tmp_path / "d"), "--quiet"]) == 0
    assert "The design measures" in capsys.readouterr().out
    assert (tmp_path / "d" / "design.toml").is_file() and (tmp_path / "d" / "widths.csv").is_file()
    assert main(["design", "seed000", "--goal", "A9[R]=1", "--quiet"]) == 2
    assert "no such target" in capsys.readouterr().err
