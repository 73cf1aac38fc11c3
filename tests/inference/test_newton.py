"""The MAP search's Newton steps on a stiff calibration: quadratic convergence, not a crawl."""

import numpy as np

import bayescal as bc
from bayescal.fitting.holdout import holdout_groups
from bayescal.inference.laplace import NEWTON_STEPS, _newton
from bayescal.inference.program import program_for
from bayescal.inference.start import initial_point
from bayescal.validation import Departures, simulate_bench


def test_newton_converges_quadratically_on_a_stiff_calibration(seed000):
    """A seed-000 bench table spans 12 decades of curvature (dark rows ~1e12 in scaled units, the
    excess-scatter scale ~1): the whitening must keep the small eigenvalues, or Newton creeps
    (a floor at 1e-10 of the largest took all 60 steps and left the mode to BFGS).  From the start
    point and from the full fit's mode with each setting left out (the misfit check's refits) the
    mode is reached in a few steps."""
    spec, _ = seed000
    frame, _ = simulate_bench(departures=Departures(gain_step_error=0.08), seed=500)
    model = bc.build_model(bc.MeasurementTable.from_frame(frame), spec)
    program = program_for(model)
    with bc.numerics():
        z, converged, steps, _ = _newton(program, model.data, np.asarray(initial_point(model, program)))
        hess = np.linalg.eigvalsh(np.asarray(program.hessian(z, model.data)))
        assert converged and steps < NEWTON_STEPS // 2, steps
        assert hess.max() / hess.min() > 1e10  # the stiffness this test is about
        table = model.table.frame
        refits = []
        for _, _, mask in holdout_groups(table, table["stimulus"].to_numpy() > 0):
            held = model.data._replace(keep=np.asarray(model.data.keep) & ~mask)
            refits.append(_newton(program, held, z)[1:3])
    assert all(ok for ok, _ in refits) and max(n for _, n in refits) < 20, refits


def test_integrated_draws_without_a_finite_mode_fall_back_flagged():
    """A mode search that left the density (NaN mode) gives flagged Gaussian draws, not a KeyError
    from a NaN grid point, and the Laplace verdict names the cause."""
    from bayescal.inference.laplace import LaplaceResult, integrated_draws
    from bayescal.inference.samplers import laplace_problems

    result = LaplaceResult(np.array([0.1, np.nan, 0.3]), np.eye(3), np.nan, True, 5, True)
    z, info = integrated_draws(None, None, result, 1, 40, seed=0)
    assert z.shape == (40, 3) and "no finite mode" in info["failed"]
    problems = laplace_problems(result, {"integrated_scale_failed": info["failed"]})
    assert problems == ["the excess-scatter integration failed (no finite mode or scale); use nuts"]


def test_a_stalled_batched_search_is_searched_on_from_where_it_stopped(monkeypatch, float64):
    """``laplace_many``: a dataset the batched Newton steps leave unconverged (here: one step allowed)
    is searched on by ``laplace`` from the point the batch reached, and lands on the mode the one-by-one
    search finds (a Student-t line, three datasets)."""
    import jax.numpy as jnp

    from bayescal.inference import laplace as lp
    from bayescal.inference.program import program_of
    from tests.inference.test_persist import Line, line

    rng = np.random.default_rng(4)
    x = np.linspace(0.0, 1.0, 30)
    datas = [Line(x, a + 2.0 * x + 0.3 * rng.standard_normal(30)) for a in (0.5, -1.0, 3.0)]
    program = program_of(line, datas[0])
    starts = [jnp.zeros(3)] * 3
    serial = [lp.laplace(program, d, s) for d, s in zip(datas, starts, strict=True)]

    searched_from = []
    laplace = lp.laplace

    def spy(program, data, z0=None, **kw):
        searched_from.append(np.asarray(z0))
        return laplace(program, data, z0, **kw)

    monkeypatch.setattr(lp, "NEWTON_STEPS", 1)  # read when the batched program is traced
    monkeypatch.setattr(lp, "laplace", spy)
    lp._batched_newton.cache_clear()
    try:
        batched = lp.laplace_many(program, datas, starts)
    finally:
        lp._batched_newton.cache_clear()
    assert len(searched_from) == 3 and all(np.any(z != 0.0) for z in searched_from)  # from the batch's point
    for a, b in zip(serial, batched, strict=True):
        assert a.converged and b.converged
        assert np.max(np.abs(a.mode - b.mode) / np.sqrt(np.diag(a.cov))) < 1e-3
