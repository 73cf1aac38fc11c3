"""fit_many (one compilation for many datasets) and simulation-based calibration (Talts et al. 2018).

Reduced sizes here; ``benchmarks/sbc.py`` runs 200 datasets per model and backend.
Bounds: with ``n`` datasets and 10 rank bins, a chi-square p <= 1e-3 for some
parameter happens by chance with probability <= 35 x 1e-3 (Bonferroni); the
95 % coverage averaged over parameters has a Monte Carlo sd of about
sqrt(0.0475 / n) (parameters within a dataset are correlated, so the
independent-parameter sd would be too small).
"""

import dataclasses

import numpy as np
import pytest

import bayescal as bc
from bayescal.fitting.batch import fit_many, fit_models
from bayescal.validation.sbc import CAMERA_CLASS_PRIORS, prior_datasets, rank_statistics, run_sbc
from tests.conftest import MODELS


@pytest.fixture(scope="module")
def tables(seed000):
    spec, design = seed000
    return [bc.simulate(spec, design, seed=200 + i).table for i in range(3)]


def test_fit_many_laplace_equals_fit(seed000, tables):
    spec, _ = seed000
    batch = fit_many(tables, spec, "laplace", seed=11)
    assert batch.ok.all() and batch.seeds == (11, 12, 13)
    for i, table in enumerate(tables):
        single = bc.fit(table, spec, "laplace", seed=11 + i)
        np.testing.assert_allclose(batch.draws["G"][i], single.posterior["posterior"]["G"], rtol=1e-9)
    full = batch.fit(1)  # a full Fit on demand: same draws, physical quantities, summary
    np.testing.assert_allclose(full.draws("G"), batch.draws["G"][1].reshape(-1, 3), rtol=1e-12)
    assert "gain[R]" in full.summary.index
    np.testing.assert_allclose(batch.physical(1)["gain"], full.posterior["posterior"]["gain"], rtol=1e-12)


@pytest.mark.slow  # the accelerator's batched search (13 s); benchmarks/batched_map.py measures it
def test_vectorised_map_matches_one_by_one(seed000, tables):
    """The vmapped MAP search (one program over the batch) lands on the same modes."""
    spec, _ = seed000
    models = [bc.build_model(t, spec) for t in tables]
    one = fit_models(models, "laplace", [0, 1, 2], vectorize=False)
    vec = fit_models(models, "laplace", [0, 1, 2], vectorize=True)
    for a, b in zip(one.modes, vec.modes, strict=True):
        assert a.converged and b.converged
        sd = np.sqrt(np.diag(a.cov))
        assert np.max(np.abs(a.mode - b.mode) / sd) < 1e-8  # the same Newton steps, batched


@pytest.mark.filterwarnings("ignore::bayescal.FitFailedWarning")  # 2 x 300 draws: R-hat may reach 1.015
def test_fit_many_nuts_equals_fit(seed000, tables):
    """Dataset i of fit_many gets exactly the chains fit(..., seed=seeds[i]) runs."""
    spec, _ = seed000
    spec = spec.replace(inference={"chains": 2, "draws": 300, "warmup": 300, "min_ess": 100})
    batch = fit_many(tables[:2], spec, "nuts", seeds=[5, 9])
    single = bc.fit(tables[1], spec, "nuts", seed=9)
    np.testing.assert_array_equal(batch.draws["G"][1], np.asarray(single.posterior["posterior"]["G"]))
    assert batch.diagnostics["divergences"].tolist() == [0, 0]
    # the same draws give the same R-hat up to the summation order of arviz's vectorised call
    assert batch.diagnostics["max_rhat"][1] == pytest.approx(single.diagnostics.max_rhat, abs=1e-3)


def test_fit_many_rejects_mixed_structures(seed000, tables):
    spec, design = seed000
    fewer = dataclasses.replace(design, illuminated=design.illuminated[:1])
    other = bc.simulate(spec, fewer, seed=1).table
    with pytest.raises(bc.SpecError, match="table 1 has structure"):
        fit_many([tables[0], other], spec, "laplace")
    with pytest.raises(bc.SpecError, match="unknown backend 'gibbs'; expected one of nuts, laplace"):
        fit_many(tables, spec, "gibbs")


def _model(spec_file, design_file, **changes):
    spec = bc.load_spec(MODELS / spec_file).replace(**CAMERA_CLASS_PRIORS, **changes)
    design = bc.load_design(MODELS / design_file)
    return bc.build_model(bc.simulate(spec, design, seed=1).table, spec)


def test_prior_datasets_follow_the_prior():
    """Simulated truths are prior draws (kept only where the readings are possible)."""
    model = _model("seed000_bayer.toml", "seed000_design.toml")
    models, truths, rejected = prior_datasets(model, 60, seed=3)
    assert len(models) == 60 and rejected > 0
    for m in models:
        y = np.asarray(m.data.y)
        assert y.min() >= 0 and y.max() <= 1.0
        assert m.structure_key == model.structure_key
    # level errors are independent of what makes a reading impossible: still standard normal
    z = truths["level_z"].ravel()
    assert abs(z.mean()) < 4 / np.sqrt(z.size) and abs(z.std() - 1) < 0.1


#: chance that a correctly calibrated posterior fails a rank-uniformity test below (Bonferroni over its
#: parameters: each p-value is compared with FAMILY_ALPHA / number of parameters)
FAMILY_ALPHA = 1e-3
#: datasets of the reduced seed 000 Laplace SBC (the full runs, 200 per model, are benchmarks/sbc.py)
SBC_LAPLACE_N = 60


@pytest.fixture(scope="module")
def laplace_sbc():
    # 1000 Laplace draws per dataset, not 4000: the ranks read 99 of them and the draws are independent,
    # so the test means the same at a quarter of the memory the batch holds
    model = _model("seed000_bayer.toml", "seed000_design.toml", inference={"laplace_draws": 1000})
    return run_sbc(model, SBC_LAPLACE_N, "laplace", seed=21, bins=10)


@pytest.mark.slow  # an SBC run; test_sbc_cli runs a small one by default
def test_sbc_laplace_seed000(laplace_sbc):
    res = laplace_sbc
    summ = res.summary()
    # 35 response/dark/sphere parameters + the log factors of gain steps 2-4 and exposures 8, 10 ms
    assert len(summ) == 40 and summ.index.str.startswith(("gain_log", "exposure_log")).sum() == 5
    assert summ.p_uniform.min() > FAMILY_ALPHA / len(summ), summ.sort_values("p_uniform").head()
    assert abs(float(res.covered.to_numpy().mean()) - 0.95) < 3 * np.sqrt(0.0475 / SBC_LAPLACE_N)
    assert res.batch.converged.all()


@pytest.mark.slow  # 25 NUTS fits; the 200-dataset runs are benchmarks/results/sbc_seed002_nuts*.md
def test_sbc_nuts_seed002():
    model = _model("seed002_tdi.toml", "seed002_design.toml")
    spec = model.spec.replace(inference={"chains": 2, "draws": 500, "warmup": 300, "min_ess": 200})
    model = dataclasses.replace(model, spec=spec)
    res = run_sbc(model, 25, "nuts", seed=5, bins=5)  # 5 datasets per bin: the chi-square test holds
    summ = res.summary()
    assert res.divergence_free >= 24 / 25
    assert summ.p_uniform.min() > FAMILY_ALPHA / len(summ), summ.sort_values("p_uniform").head()
    assert abs(float(res.covered.to_numpy().mean()) - 0.95) < 3 * np.sqrt(0.0475 / 25)


@pytest.mark.slow  # shares the SBC run above
def test_sbc_detects_a_wrong_posterior(laplace_sbc):
    """Negative control: posteriors shrunk to half their width around their means give
    U-shaped ranks and low coverage, which the statistics flag."""
    res = laplace_sbc
    shrunk = {}
    for k, v in res.batch.draws.items():
        mean = v.mean(axis=(1, 2), keepdims=True)
        shrunk[k] = mean + 0.5 * (v - mean)
    ranks, covered = rank_statistics(shrunk, res.truths, res.n_draws)
    bad = dataclasses.replace(res, ranks=ranks, covered=covered)
    assert bad.p_values().median() < 1e-3
    assert float(covered.to_numpy().mean()) < 0.75


@pytest.mark.slow  # an SBC run (13 s); the SBC suite is slow
def test_sbc_cli(tmp_path, capsys):
    """``bayescal sbc`` on a user's table and spec writes the rank table, report and histograms."""
    from bayescal.cli import main

    model = _model("seed002_tdi.toml", "seed002_design.toml")
    spec_file, table_file = tmp_path / "spec.toml", tmp_path / "table.csv"
    spec_file.write_text(model.spec.to_toml())
    model.table.write_csv(table_file)
    stem = tmp_path / "sbc"
    args = ["sbc", str(table_file), "--model", str(spec_file), "--sims", "30", "--backend", "laplace"]
    assert main([*args, "--out", str(stem)]) == 0
    out = capsys.readouterr().out
    assert "SBC: 30 datasets" in out and "smallest uniformity p-value" in out
    for suffix in (".csv", ".md", ".png"):
        assert (tmp_path / f"sbc{suffix}").stat().st_size > 0
    import pandas as pd

    from bayescal.inference.program import program_for

    summary = pd.read_csv(tmp_path / "sbc.csv", index_col="parameter")
    assert {"p_uniform", "coverage95"} <= set(summary.columns)
    assert len(summary) == program_for(model).dim  # one row per scalar parameter
    assert summary["p_uniform"].between(0, 1).all()
