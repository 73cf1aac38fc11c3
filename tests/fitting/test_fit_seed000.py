"""Seed 000 camera with known truth: NUTS diagnostics, coverage, Laplace agreement, LSQ beside it."""

import numpy as np
import pytest

import bayescal as bc


@pytest.fixture(scope="module")
def fits(seed000):
    spec, design = seed000
    sim = bc.simulate(spec, design, seed=11)
    return sim, bc.fit(sim.table, spec, "nuts", seed=11), bc.fit(sim.table, spec, "laplace", seed=11)


def test_nuts_diagnostics(fits):
    _, nuts, _ = fits
    d = nuts.diagnostics
    assert d.ok, d.verdict
    assert d.divergences == 0 and d.max_rhat <= 1.01 and d.min_ess_bulk >= 400


def test_the_verdict_on_the_reported_quantities_is_the_verdict_on_every_site(fits):
    """The sampler is judged on what is reported; the sampled sites (every one reported again through a
    monotone map or combined into reported quantities) move neither the worst R-hat nor the least ESS."""
    from bayescal.inference.diagnostics import mcmc_diagnostics
    from bayescal.inference.samplers import chains_dataset

    _, nuts, _ = fits
    post = nuts.posterior["posterior"].to_dataset()
    every = mcmc_diagnostics(chains_dataset({k: post[k].values for k in post.data_vars}), 0, nuts.model.spec.inference)
    d = nuts.diagnostics
    assert d.max_rhat == pytest.approx(every.max_rhat, abs=1e-4)
    assert d.min_ess_bulk == pytest.approx(every.min_ess_bulk, rel=0.02)
    assert d.min_ess_tail == pytest.approx(every.min_ess_tail, rel=0.02)


def test_intervals_contain_truth_and_lsq_beside(fits):
    sim, nuts, _ = fits
    s = nuts.summary
    for ch, coef in sim.truth.response.items():
        for k, value in enumerate(coef, start=1):
            row = s.loc[f"A_abs[{ch}, {k}]"]
            assert row["q2.5"] <= value <= row["q97.5"], (ch, k, value, row)
    cmp = nuts.comparison
    assert {"lsq", "lsq_lo", "lsq_hi", "bayes_abs"} <= set(cmp.columns)
    assert cmp["lsq"].notna().all()


def test_laplace_matches_nuts(fits):
    _, nuts, lap = fits
    for name in ("A_rel", "dark_offset", "nonlinearity", "gain", "excess_dn"):
        a, b = nuts.draws(name), lap.draws(name)
        sd = a.std(axis=0)
        assert np.all(np.abs(a.mean(axis=0) - b.mean(axis=0)) <= 0.1 * sd), name
        # the excess scatter is integrated numerically (a Gaussian at the joint mode is ~10 % too narrow)
        assert np.all(np.abs(a.std(axis=0) - b.std(axis=0)) <= 0.1 * sd), name


@pytest.mark.slow  # the default run checks emcee against a closed-form posterior (tests/test_laplace_closed_form.py)
def test_emcee_matches_nuts(fits, seed000):
    sim, nuts, _ = fits
    spec, _ = seed000
    # a fifth of the default chain length: ESS ~350 against NUTS's ~1000, so the Monte Carlo error of
    # a difference of means is ~0.06 sd and 0.25 sd is 4 of them
    emc = bc.fit(sim.table, spec.replace(inference={"emcee_steps": 1200, "emcee_burn": 400}), "emcee", seed=11)
    assert emc.diagnostics.ok, emc.diagnostics.verdict
    for name in ("A_rel", "gain", "dark_offset", "nonlinearity"):
        a, b = nuts.draws(name), emc.draws(name)
        z = np.abs(a.mean(axis=0) - b.mean(axis=0)) / a.std(axis=0)
        assert np.all(z <= 0.25), (name, z.max())


def test_saved_outputs_match_summary(fits, tmp_path):
    import json

    import arviz as az

    _, nuts, _ = fits
    nuts.save(tmp_path)
    js = json.loads((tmp_path / "summary.json").read_text())
    assert js["status"] == "ok"
    first = js["parameters"][0]
    assert first["parameter"] == nuts.summary.index[0]
    assert first["mean"] == pytest.approx(nuts.summary.iloc[0]["mean"], rel=1e-12)
    dt = az.from_netcdf(tmp_path / "posterior.nc")
    assert float(dt["posterior"]["gain"].mean()) == pytest.approx(float(nuts.posterior["posterior"]["gain"].mean()))
