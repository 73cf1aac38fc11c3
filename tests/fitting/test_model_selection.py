"""Model selection: PSIS-LOO picks the order the truth has; the least-squares F-test beside it."""

import dataclasses
import warnings

import numpy as np
import pytest

import bayescal as bc
from bayescal.fitting.select import compare_specs, f_test_orders, order_candidates


@pytest.fixture(scope="module")
def quadratic(seed000):
    spec, design = seed000
    return spec, bc.simulate(spec, design, seed=51)


@pytest.mark.slow  # two NUTS fits; LOO between domains runs by default in test_nonlinearity_domain
def test_loo_prefers_the_true_quadratic(quadratic):
    spec, sim = quadratic
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", bc.FitFailedWarning)
        cmp = compare_specs(sim.table, order_candidates(spec, (1, 2, 3)), backend="laplace")
    print("\n", cmp)
    assert cmp.index[0] in ("order 2", "order 3")
    # the linear model is far worse (the 1.3 % compression at 4000 DN is resolved by 20-frame means)
    lin = cmp.loc["order 1"]
    assert -lin["elpd_diff"] > 10 * lin["dse"]
    # and the cubic term buys nothing: within 2 se of the quadratic
    d = abs(cmp.loc["order 3", "elpd_loo"] - cmp.loc["order 2", "elpd_loo"])
    assert d < 2 * max(cmp.loc["order 3", "dse"], cmp.loc["order 2", "dse"], 1.0)


def test_linear_truth_is_not_overfitted(seed000):
    spec, design = seed000
    truth = dataclasses.replace(design.truth, response={c: (v[0],) for c, v in design.truth.response.items()})
    sim = bc.simulate(spec, dataclasses.replace(design, truth=truth), seed=52)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", bc.FitFailedWarning)
        cmp = compare_specs(sim.table, order_candidates(spec, (1, 2)), backend="laplace")
    print("\n", cmp)
    if cmp.index[0] == "order 2":  # a quadratic may win by noise, but not decisively
        assert -cmp.loc["order 1", "elpd_diff"] < 2 * max(cmp.loc["order 1", "dse"], 1.0)
    ft = f_test_orders(sim.table, spec, max_order=3)
    # the baseline, for the record: 12 points per channel at the reference setting, and the sphere's
    # 0.5 % level errors look like curvature to a least-squares F-test
    print("F-test chosen orders:", ft.groupby("channel")["chosen_order"].first().to_dict())


def test_f_test_on_exact_polynomials():
    rng = np.random.default_rng(0)
    x = np.linspace(1, 30, 12)
    rows = []
    for ch, coef in (("Q", [50.0, 30.0, -0.05]), ("L", [50.0, 30.0, 0.0])):
        y = np.polyval(coef[::-1], x) + rng.normal(0, 0.5, x.size)
        rows += [
            {"channel": ch, "radiance": xi, "exposure_s": 0.004, "gain": 1.0, "dn_mean": yi}
            for xi, yi in zip(x, y, strict=True)
        ]
    import pandas as pd

    table = bc.MeasurementTable.from_frame(pd.DataFrame(rows))
    from tests.conftest import MODELS

    spec = bc.load_spec(MODELS / "seed000_bayer.toml")
    ft = f_test_orders(table, spec, max_order=3)
    chosen = ft.groupby("channel")["chosen_order"].first()
    assert chosen["Q"] == 2 and chosen["L"] == 1
    q2 = ft[(ft.channel == "Q") & (ft.order == 2)].iloc[0]
    assert q2["p_value"] < 1e-6 and np.all(ft["p_value"].between(0, 1))
