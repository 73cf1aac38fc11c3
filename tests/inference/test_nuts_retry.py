"""The NUTS rerun policy after divergent transitions, with the sampler replaced by a stand-in
whose divergences depend only on the target acceptance (so the rule, not a posterior, is tested)."""

from types import SimpleNamespace

import numpy as np
import pytest

from bayescal.inference import chains, nuts
from bayescal.inference.transitions import Transitions
from bayescal.model.spec import InferenceSpec

DRAWS, DIM = 1000, 2


def _stand_in(left_at_retry: float):
    """``chain_program`` whose chains diverge in 6 % of draws at 0.8, ``left_at_retry`` at 0.95, none at 0.99."""
    fraction = {0.8: 0.06, 0.95: left_at_retry, 0.99: 0.0}

    def compiled(potential, chain):
        draws = chain.draws

        def run(run_number, index, key, w0, step, imm, target, data, center, chol):
            diverging = np.arange(draws) < round(fraction[float(target)] * draws)
            zeros = np.zeros(draws)
            x = np.zeros((draws, DIM))
            return Transitions(x[-1], 0.1, 0, 0, x, diverging, zeros + 3, zeros + target, zeros, zeros + 0.1)

        return run

    return compiled


@pytest.mark.parametrize(
    ("left", "final_target", "final_divergences"),
    [
        # a few left, as the pooled seed-000 channels left 1.25 % at 0.95: one last run at 0.99 mends them
        (0.0125, chains.LAST_RETRY_ACCEPT, 0),
        (0.03, 0.95, 4 * 30),  # more than LAST_RETRY_MAX_FRACTION (2 %): no last run; the fit keeps them and fails
    ],
)
def test_a_last_rerun_only_for_a_few_divergences(monkeypatch, left, final_target, final_divergences):
    monkeypatch.setattr(nuts, "chain_program", _stand_in(left))
    settings = InferenceSpec(chains=4, draws=DRAWS, warmup=10, target_accept=0.8, retry_target_accept=0.95)
    program = SimpleNamespace(potential=None)
    (out,) = nuts._run_many(1, program, [None], [np.zeros(DIM)], [np.eye(DIM)], settings, [0], None)
    assert out.first_divergences == 4 * 60  # the first run's count is what the verdict reports as retried
    assert out.rerun_at == pytest.approx(final_target)
    assert int(out.diverging.sum()) == final_divergences


@pytest.mark.parametrize(
    ("target", "retry", "fraction", "expected"),
    [
        (0.8, 0.95, 0.0, None),  # no divergence: the run stands
        (0.8, 0.95, 0.3, 0.95),  # any: the spec's retry, however many
        (0.8, 0.0, 0.3, None),  # retries switched off
        (0.95, 0.95, 0.02, chains.LAST_RETRY_ACCEPT),  # the retry left a few: one last run
        (0.95, 0.95, 0.021, None),  # ... not when more than LAST_RETRY_MAX_FRACTION are left
        (0.99, 0.95, 0.01, None),  # the last run stands
        (0.99, 0.99, 0.01, None),
        (0.95, 0.9, 0.01, chains.LAST_RETRY_ACCEPT),  # a run above the spec's retry counts as the retry
    ],
)
def test_the_one_retry_policy(target, retry, fraction, expected):
    """What a camera's NUTS fit and the fleet's stage two both decide by."""
    assert chains.retry_target(target, retry, fraction) == expected


def test_the_retry_loop_reruns_only_the_items_that_diverged():
    """Items run together; those that diverged are rerun, together, at the policy's target, with new seeds."""
    calls = []

    def run(items, target, attempt):
        calls.append((list(items), target, attempt))
        # item 1 diverges in 5 % of its draws at the first target, 1 % at the retry, none at the last
        left = {0.8: 50, 0.95: 10, chains.LAST_RETRY_ACCEPT: 0}[target]
        return [(left if i == 1 else 0, target) for i in items]

    out = chains.with_retries(run, 3, 0.8, 0.95, lambda o: (o[0], 1000))
    assert calls == [([0, 1, 2], 0.8, 0), ([1], 0.95, 1), ([1], chains.LAST_RETRY_ACCEPT, 2)]
    assert [o.out[1] for o in out] == [0.8, chains.LAST_RETRY_ACCEPT, 0.8]
    assert [o.first_divergences for o in out] == [0, 50, 0]
    assert [o.rerun_at for o in out] == [0.0, chains.LAST_RETRY_ACCEPT, 0.0]


def test_a_rerun_seed_is_new_and_reproducible():
    seeds = [chains.attempt_seed(s, k) for s in range(20) for k in range(3)]
    assert chains.attempt_seed(7, 0) == 7 and chains.attempt_seed(7, 1) == chains.attempt_seed(7, 1)
    assert len(set(seeds)) == len(seeds)  # no rerun reuses another dataset's (or attempt's) chains


def test_each_run_reports_to_its_own_progress_channel():
    """Two runs in flight at once: each compiled chain's callback reaches its own run's listener only, and a
    run's channel closes with it."""
    heard: dict[int, list[int]] = {1: [], 2: []}
    with (
        chains.progress_channel(heard[1].append, 2) as first,
        chains.progress_channel(heard[2].append, 1, 10) as second,
    ):
        chains.report(first, 0, 49)
        chains.report(second, 0, 49)
        chains.report(first, 1, 99)
        chains.report(first + second + 1, 0, 49)  # a run nobody listens to
    chains.report(first, 0, 149)  # closed: nobody hears it
    assert heard == {1: [0, 50], 2: [60]}  # the slowest chain of each run (the second after a warmup of 10)
