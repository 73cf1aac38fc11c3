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


def _with_doubt(fit_folder, tmp_path, other_spec):
    """The half campaign's fit, saved again with a MODEL DOUBT whose other structure is ``other_spec``."""
    from bayescal.io.fit_folder import FitFolder

    folder = FitFolder.at(fit_folder, "test")
    spec, table = folder_spec_and_table(folder)
    fit = bc.fit(table, spec, backend="laplace")
    doubt = {"candidate": "a soft roll-off towards full scale", "moved_sd": {"R A1": 2.5}, "elpd_diff": -0.4}
    doubt |= {"dse": 1.1, "carried": False, "other_spec": other_spec.to_toml()}
    diag = fit.diagnostics.with_check("structure", [], doubt)
    out = tmp_path / "doubt"
    dataclasses.replace(fit, diagnostics=diag).save(out)
    return out, spec


def folder_spec_and_table(folder):
    import tomllib

    spec = bc.ModelSpec.from_dict(tomllib.loads(folder.posterior.attrs["spec_toml"]), source="fit")
    return spec, bc.MeasurementTable.from_frame(folder.measurements)


def test_design_after_a_model_doubt_proposes_the_rows_that_tell_the_structures_apart(half_fit, tmp_path, capsys):
    """A fit that could not tell its response from one with a roll-off towards full scale: the group that
    tells them apart best reads in the top half of full scale, where a roll-off bends the response (a
    setting never measured tells less: its factor's own doubt widens both predictions); a dark group tells
    nothing.  Against itself, no group tells anything."""
    from bayescal.campaign.design import design

    spec, protocol = bc.load_spec("seed000"), bc.load_design("seed000")
    rolled = spec.replace(response={"rolloff": True})
    out, spec = _with_doubt(half_fit, tmp_path, rolled)
    plan = design(protocol, after=out)
    told = plan.telling_apart
    assert told is not None and told.other == "a soft roll-off towards full scale"
    t = told.table
    assert len(t) == len(plan.grid) and (t["log_bf"] >= 0).all()
    top = t.iloc[0]
    assert max(top[f"dn_{c}"] for c in ("R", "G", "B")) > 0.5 * spec.full_scale, t.head()
    darks = t[t["group"].str.startswith("dark")]
    assert darks["log_bf"].max() < 0.05 * t["log_bf"].max()  # 0.03 measured: the offsets move a little
    # the CLI prints it and writes it beside the design
    code = main(["design", "seed000", "--after", str(out), "--quiet", "--out", str(tmp_path / "next")])
    printed = capsys.readouterr().out
    assert code in (0, 3) and "MODEL DOUBT: the fit could not tell" in printed
    assert (tmp_path / "next" / "telling_apart.csv").is_file()
    # the same structure twice: nothing to tell apart
    same, _ = _with_doubt(half_fit, tmp_path / "same", spec)
    assert design(protocol, after=same).telling_apart.table["log_bf"].max() < 1e-6
