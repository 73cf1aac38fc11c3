"""Model only what the data support: PSIS-LOO comparison of specs, the least-squares F-test beside it.

Every Bayesian fit stores the pointwise log-likelihood of each table row, so
candidate specs (polynomial orders, components switched on or off) are
compared by the expected log predictive density from Pareto-smoothed
importance-sampling leave-one-out cross-validation (arviz ``loo`` /
``compare``).  The baseline is the classical nested F-test of polynomial
order per channel at the reference setting (the papers fit orders 1-4 and
quote R^2, seed 000 Table 1).
"""

from __future__ import annotations

import warnings

import numpy as np
import pandas as pd
from scipy import stats

from bayescal.errors import SpecError
from bayescal.fitting.fit import fit
from bayescal.inference.lsq import polyfit
from bayescal.io.table import MeasurementTable
from bayescal.model.spec import ModelSpec

__all__ = ["compare_specs", "order_candidates", "f_test_orders"]


def order_candidates(
    spec: ModelSpec, orders=(1, 2, 3), extra_off: tuple[str, ...] = (), domains: bool = False
) -> dict[str, ModelSpec]:
    """Candidate specs: each polynomial order, and the spec without each named component.

    ``extra_off`` may name ``"level_errors"`` (per-level sphere errors),
    ``"excess"`` (excess scatter) or ``"exposure_slope"`` (dark slope).  ``domains`` adds, for
    every nonlinear order, the nonlinearity of the other domain (the charge's before the gain,
    the output's after it: :class:`~bayescal.model.components.response.ResponseSpec`); only a
    table with several illuminated gains can tell them apart.
    """
    out = {f"order {o}": spec.replace(response={"order": o}) for o in orders}
    if domains:
        other = "output" if spec.response.nonlinearity_domain == "charge" else "charge"
        for o in orders:
            if o >= 2:
                out[f"order {o}, nonlinearity of the {other}"] = spec.replace(
                    response={"order": o, "nonlinearity_domain": other}
                )
    switches: dict[str, dict[str, dict]] = {
        "level_errors": {"sphere": {"per_level_rel": 0.0}},
        "excess": {"noise": {"excess_dn": 0.0}},
        "exposure_slope": {"dark": {"exposure_slope": False}},
    }
    for name in extra_off:
        if name not in switches:
            raise SpecError(f"unknown component '{name}'; expected one of {', '.join(switches)}")
        out[f"without {name}"] = spec.replace(**switches[name])
    return out


def compare_specs(
    table: MeasurementTable, specs: dict[str, ModelSpec], backend: str = "nuts", seed: int = 0
) -> pd.DataFrame:
    """Fit every candidate and rank them by PSIS-LOO elpd (best first).

    Columns: elpd_loo, se, elpd_diff (this model minus the best, <= 0),
    dse (se of the difference), p_loo (effective parameters), n_high_k (rows with Pareto
    k > 0.7, where the LOO estimate of that row is unreliable), weight
    (stacking), fit_ok.
    """
    if backend == "lsq":
        raise SpecError("model comparison needs a Bayesian backend (nuts, laplace or emcee)")
    import arviz_stats

    trees, ok, high_k = {}, {}, {}
    for name, spec in specs.items():
        result = fit(table, spec, backend, seed=seed)
        trees[name], ok[name] = result.posterior, result.ok
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)
            loo = arviz_stats.loo(result.posterior, pointwise=True)
        high_k[name] = int(np.sum(np.asarray(loo.pareto_k) > 0.7))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        table_cmp = arviz_stats.compare(trees, round_to="none")
    cols = {"elpd": "elpd_loo", "p": "p_loo", "elpd_diff": "elpd_diff", "dse": "dse", "se": "se", "weight": "weight"}
    out = table_cmp.rename(columns=cols)[[c for c in cols.values() if c in table_cmp.rename(columns=cols)]]
    out["n_high_k"] = [high_k[i] for i in out.index]
    out["fit_ok"] = [ok[i] for i in out.index]
    return out


def f_test_orders(table: MeasurementTable, spec: ModelSpec, max_order: int = 4) -> pd.DataFrame:
    """Nested F-tests of polynomial order per channel at the reference setting (least squares).

    For each order ``p`` against ``p - 1``: ``F = (SSE_{p-1} - SSE_p) / (SSE_p / dof_p)``
    and its p-value; the chosen order is the highest one whose term is
    significant at 5 % (all lower ones significant too).  Clipped rows are
    excluded, as the papers did by hand.
    """
    ref = spec.reference
    df = table.frame
    rows = []
    for ch in table.channels:
        m = (
            (df["channel"] == ch)
            & np.isclose(df["exposure_s"], ref.exposure_s)
            & np.isclose(df["gain"], ref.gain)
            & (df["dn_mean"] < spec.full_scale - spec.saturation.margin_dn)
        )
        x, y = df.loc[m, "stimulus"].to_numpy(), df.loc[m, "dn_mean"].to_numpy()
        chosen, previous = 1, polyfit(x, y, 1)
        for order in range(2, max_order + 1):
            if np.unique(x).size <= order + 1:
                break
            current = polyfit(x, y, order)
            f = (previous.sse - current.sse) / (current.sse / current.dof)
            p = float(stats.f.sf(f, 1, current.dof))
            rows.append({"channel": ch, "order": order, "F": f, "p_value": p, "dof": current.dof})
            if p < 0.05 and chosen == order - 1:
                chosen = order
            previous = current
        for r in rows:
            if r["channel"] == ch:
                r["chosen_order"] = chosen
    return pd.DataFrame(rows)
