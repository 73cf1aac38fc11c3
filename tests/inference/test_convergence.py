"""R-hat and ESS over every element at once, against arviz-stats variable by variable and known chains."""

import numpy as np
import pytest


def _chains(seed: int = 0, chains: int = 4, draws: int = 1000, phi: float = 0.0, shift: float = 0.0):
    """AR(1) chains of unit variance (``phi`` their lag-one autocorrelation), the last chain's mean moved by
    ``shift``: a (chain, draw, 3) variable and a scalar one, one of whose elements is constant."""
    rng = np.random.default_rng(seed)
    e = rng.normal(size=(chains, draws, 4))
    x = np.empty_like(e)
    x[:, 0] = e[:, 0]
    for t in range(1, draws):
        x[:, t] = phi * x[:, t - 1] + np.sqrt(1 - phi**2) * e[:, t]
    x[-1] += shift
    vector = x[..., :3].copy()
    vector[..., 1] = 2.5  # a constant element (a reference setting): NaN to arviz, ignored
    return {"vector": vector, "scalar": x[..., 3]}


@pytest.mark.filterwarnings("ignore:invalid value encountered:RuntimeWarning")  # arviz on the constant element
def test_the_stacked_statistics_equal_arviz_variable_by_variable():
    import arviz_stats
    import xarray as xr

    from bayescal.inference.diagnostics import convergence

    draws = _chains(phi=0.5, shift=0.05)
    ds = xr.Dataset({k: (("chain", "draw", *(f"{k}_{i}" for i in range(v.ndim - 2))), v) for k, v in draws.items()})

    def over(result, reducer):
        return reducer(np.concatenate([np.ravel(result[v]) for v in result.data_vars]))

    rhat, bulk, tail = convergence(draws)
    assert rhat == pytest.approx(over(arviz_stats.rhat(ds), np.nanmax), rel=1e-12)
    assert bulk == pytest.approx(over(arviz_stats.ess(ds, method="bulk"), np.nanmin), rel=1e-12)
    assert tail == pytest.approx(over(arviz_stats.ess(ds, method="tail"), np.nanmin), rel=1e-12)


def test_known_chains_pass_and_fail_as_they_should():
    from bayescal.inference.diagnostics import convergence, mcmc_diagnostics
    from bayescal.model.spec import InferenceSpec

    # independent draws: ESS near the 4000 draws (its sd over seeds is ~3 %), R-hat near 1
    rhat, bulk, tail = convergence(_chains(seed=1))
    assert rhat < 1.005 and 3400 < bulk < 4700 and 3000 < tail < 5000
    # AR(1) with phi = 0.9: ESS = N (1 - phi) / (1 + phi), 211 of 4000
    _, bulk, _ = convergence(_chains(seed=2, phi=0.9))
    assert 150 < bulk < 290
    # one chain off by a standard deviation: R-hat near 1.1, and the verdict says so
    d = mcmc_diagnostics(_chains(seed=3, shift=1.0), 0, InferenceSpec())
    assert not d.ok and d.max_rhat > 1.05 and any("R-hat" in p for p in d.problems)
    # nothing varies: no statistic, NaN rather than an error
    assert all(np.isnan(convergence({"c": np.ones((4, 100))})))
