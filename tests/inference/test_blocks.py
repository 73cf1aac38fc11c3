"""Draws evaluated in blocks, two blocks at once: the numbers of one draw at a time, in order."""

import threading
from typing import NamedTuple

import numpy as np
import numpyro
import numpyro.distributions as dist
import pytest
from scipy import stats

import bayescal as bc
from bayescal._parallel import parallel_map
from bayescal.inference.program import BLOCK, program_of


class Line(NamedTuple):
    x: np.ndarray
    y: np.ndarray


def line(data: Line) -> None:
    a = numpyro.sample("a", dist.Normal(0.0, 10.0))
    b = numpyro.sample("b", dist.Normal(0.0, 10.0))
    s = numpyro.sample("s", dist.HalfNormal(1.0))
    numpyro.sample("obs", dist.Normal(a + b * data.x, s), obs=data.y)


def test_parallel_map_keeps_order_and_runs_serially_inside_a_thread():
    assert parallel_map(lambda v: v * v, range(7)) == [v * v for v in range(7)]
    seen: list[str] = []

    def record(v):
        seen.append(threading.current_thread().name)
        return v

    worker = threading.Thread(target=lambda: parallel_map(record, range(5)), name="outer")
    worker.start()
    worker.join()
    assert seen == ["outer"] * 5  # inside a thread: no threads of its own


def test_blocks_at_once_give_each_draws_own_numbers():
    rng = np.random.default_rng(3)
    x = np.linspace(0.0, 1.0, 25)
    data = Line(x, 1.0 + 0.5 * x + 0.2 * rng.standard_normal(25))
    z = rng.standard_normal((2 * BLOCK + 37, 3))  # three blocks, the last padded
    with bc.numerics():
        program = program_of(line, data)
        both = program.constrain(z, data, loglik=True)
        picks = [0, BLOCK - 1, BLOCK, 2 * BLOCK + 36]
        one = [program.constrain(z[i : i + 1], data, loglik=True) for i in picks]
    for name in ("a", "b", "s", "__loglik__"):
        assert np.shape(both[name])[0] == z.shape[0]
        np.testing.assert_array_equal(np.asarray(both[name])[picks], np.concatenate([np.asarray(o[name]) for o in one]))
    # the log-likelihood is the Normal's, draw by draw (the blocks were put back in order)
    a, b, s = (np.asarray(both[k])[:, None] for k in ("a", "b", "s"))
    expected = stats.norm.logpdf(data.y, a + b * x, s)
    np.testing.assert_allclose(np.asarray(both["__loglik__"]), expected, rtol=1e-10)


def test_one_thread_policy_sizes_every_pool(monkeypatch):
    """Pools size themselves from the cores the process may use, or from ``$BAYESCAL_THREADS``; a bad value
    is an error that names the variable."""
    from bayescal._parallel import cores, workers
    from bayescal.errors import SpecError

    monkeypatch.setenv("BAYESCAL_THREADS", "3")
    assert cores() == 3 and workers(10) == 3 and workers(2) == 2 and workers(10, at_most=1) == 1
    assert workers(0) == 1
    monkeypatch.setenv("BAYESCAL_THREADS", "1")
    assert parallel_map(lambda v: v + 1, range(4)) == [1, 2, 3, 4]  # one core: the loop
    for bad in ("0", "two", "-1"):
        monkeypatch.setenv("BAYESCAL_THREADS", bad)
        with pytest.raises(SpecError, match="BAYESCAL_THREADS"):
            cores()
    monkeypatch.delenv("BAYESCAL_THREADS")
    import os

    assert cores() == len(os.sched_getaffinity(0))
