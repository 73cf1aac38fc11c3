"""``bayescal design --after``: the next block of a half-finished seed-000 campaign, from its fit."""

import dataclasses

import numpy as np
import pytest

import bayescal as bc
from bayescal.cli.app import main
from bayescal.io.design import Block

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def half_fit(seed000, tmp_path_factory):
    """Gain 1 at 4 and 8 ms and the darks at gain 1 measured; gains 2-4 and 10 ms not yet."""
    spec, protocol = seed000
    half = dataclasses.replace(
        protocol, illuminated=(Block((0.004, 0.008), (1.0,)),), dark=(Block((0.0027, 0.004, 0.008, 0.01), (1.0,)),)
    )
    folder = tmp_path_factory.mktemp("half") / "fit"
    bc.fit(bc.simulate(spec, half, seed=4).table, spec, backend="laplace").save(folder)
    return folder


def test_the_next_block_narrows_the_targets_more_than_the_protocols_next_block(half_fit, seed000):
    from bayescal.campaign.design import design

    spec, protocol = seed000
    plan = design(protocol, after=half_fit)
    w = plan.widths
    assert not plan.done
    assert plan.rows == int(plan.protocol_next.sum()) * 3 == 36  # the protocol's next block: 10 ms, 12 levels
    proposed = np.sum((w["design_sd"] / w["goal_sd"]) ** 2)
    protocol_next = np.sum((w["protocol_next_sd"] / w["goal_sd"]) ** 2)
    assert proposed < protocol_next
    assert np.all(w["design_sd"] <= w["now_sd"] * (1 + 1e-9))  # a block never widens a target
    assert plan.measured.sum() == 28  # 24 lit groups and 4 darks measured


def test_a_campaign_that_meets_its_goals_is_told_to_stop(half_fit, capsys):
    # goals a million times the protocol's widths: what is measured already meets them
    code = main(["design", "seed000", "--after", str(half_fit), "--goal-scale", "1e6", "--quiet"])
    assert code == 0
    assert "stop measuring" in capsys.readouterr().out


def test_a_budget_too_small_for_goals_asked_is_reported_loudly(capsys):
    assert main(["design", "seed000", "--budget-rows", "60", "--goal-scale", "1", "--quiet"]) == 3
    assert "stay wider than their goal" in capsys.readouterr().out
    # a budget alone asks for the narrowest design it buys: reported, not a failure
    assert main(["design", "seed000", "--budget-rows", "60", "--quiet"]) == 0
