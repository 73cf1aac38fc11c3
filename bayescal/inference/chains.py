"""Chain driving shared by every NUTS run: one thread pool, the one retry loop, and NUTS in phases on a
potential.

**Threads** (:func:`map_chains`).  Chains run side by side on threads (XLA releases the GIL while a
chain runs); each is blocked on in its thread, so JAX's asynchronous dispatch does not queue them on one
core; Ctrl-C returns at once (a running chain cannot be interrupted, and is not waited for).

**Progress** (:func:`progress_channel`, :func:`report`).  A compiled chain reports its iterations by a
host callback with its run's number (an argument of the program, so reporting costs no recompilation);
each run listens on its own channel, so two fits in flight on two threads keep their progress apart.

**Retries** (:func:`retry_target`).  Divergent transitions mark a region of high curvature (a scale
near zero) that the adapted step size overshoots.  A run with any is run again, with new chains,
at the spec's ``retry_target_accept`` (smaller steps); a run that already was that retry gets one
last run at :data:`LAST_RETRY_ACCEPT` when only a few of its draws diverged (more: a posterior that
smaller steps will not mend).  :func:`with_retries` is the loop, with one seed rule
(:func:`attempt_seed`): a camera's fit (:mod:`bayescal.inference.nuts`, many datasets at once) and the
fleet's stage two (:mod:`bayescal.fleet.sampling`) both run through it.

The one NUTS program is :mod:`bayescal.inference.transitions`; the fleet's phases on it are
:mod:`bayescal.inference.phases`.
"""

from __future__ import annotations

import itertools
import threading
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from typing import Any, NamedTuple

import numpy as np

__all__ = [
    "LAST_RETRY_ACCEPT",
    "LAST_RETRY_MAX_FRACTION",
    "Retried",
    "attempt_seed",
    "map_chains",
    "progress_channel",
    "report",
    "retry_target",
    "with_retries",
]

#: the last rerun's target acceptance: a few divergences left after the spec's retry get one more run here
LAST_RETRY_ACCEPT = 0.99
#: ... when they are at most this fraction of the draws (more: a posterior smaller steps will not mend).
#: The pooled seed-000 channels (model-simulated seed 5) left 50 of 4000 (1.25 %) at 0.95 and none at 0.99
LAST_RETRY_MAX_FRACTION = 0.02


def retry_target(target_accept: float, retry_target_accept: float, diverging_fraction: float) -> float | None:
    """The target acceptance a run should be repeated at, or None when it stands.

    Parameters
    ----------
    target_accept : float
        The run's own target acceptance.
    retry_target_accept : float
        The spec's retry target (0: no retries).
    diverging_fraction : float
        Share of the run's draws that were divergent transitions.
    """
    if diverging_fraction <= 0:
        return None
    target = retry_target_accept
    if target_accept >= target > 0:  # this run was the spec's retry: one last, smaller-step one
        if diverging_fraction > LAST_RETRY_MAX_FRACTION:
            return None
        target = LAST_RETRY_ACCEPT
    return target if target > target_accept else None


class _Channel:
    """One run's progress: the iterations of each of its chains; the listener hears the slowest."""

    def __init__(self, callback: Callable[[int], None], chains: int, offset: int):
        self.callback, self.done, self.offset, self.lock = callback, [0] * chains, offset, threading.Lock()

    def tick(self, chain: int, i: int) -> None:
        with self.lock:
            self.done[chain] = self.offset + i + 1
            slowest = min(self.done)
        self.callback(slowest)


_CHANNELS: dict[int, _Channel] = {}
_NUMBERS = itertools.count(1)


@contextmanager
def progress_channel(callback: Callable[[int], None] | None, chains: int, offset: int = 0) -> Iterator[int]:
    """A run's number, its chains' iterations reported to ``callback`` (the slowest chain's count plus
    ``offset``, e.g. a warmup already done) while the block runs; None: nobody listens."""
    number = next(_NUMBERS)
    if callback is not None:
        _CHANNELS[number] = _Channel(callback, chains, offset)
    try:
        yield number
    finally:
        _CHANNELS.pop(number, None)


def report(run: Any, chain: Any, i: Any) -> None:
    """The chains' host callback: iteration ``i`` of ``chain`` in run ``run`` (unheard when nobody listens)."""
    channel = _CHANNELS.get(int(run))
    if channel is not None:
        channel.tick(int(chain), int(i))


def attempt_seed(seed: int, attempt: int) -> int:
    """The seed of a run's ``attempt`` (0: the first run, the user's ``seed`` itself; a rerun gets new chains
    from a seed derived from both, which no other dataset's own seed collides with)."""
    if attempt == 0:
        return int(seed)
    return int(np.random.SeedSequence([int(seed), int(attempt)]).generate_state(1)[0])


class Retried(NamedTuple):
    """What :func:`with_retries` returns for each item: its final run, the divergent transitions of its
    first run when it was rerun (0: it was not), and the target acceptance of its final run when that was
    a rerun (0.0: none)."""

    out: Any
    first_divergences: int
    rerun_at: float


def with_retries[T](
    run: Callable[[Sequence[int], float, int], Sequence[T]],
    n: int,
    target_accept: float,
    retry_target_accept: float,
    divergences: Callable[[T], tuple[int, int]],
) -> list[Retried]:
    """The one retry loop of every NUTS run (:func:`retry_target`), over ``n`` items run together.

    Parameters
    ----------
    run : callable
        ``run(items, target, attempt)``: the runs of those item indices at that target acceptance, their
        chains seeded for ``attempt`` (:func:`attempt_seed`; 0 is the first run).
    n : int
        Number of items (datasets, or one fleet).
    target_accept, retry_target_accept : float
        The first run's target and the spec's retry target (0: no retries).
    divergences : callable
        ``divergences(out) -> (divergent transitions, draws)`` of one item's run.

    Items are rerun together: their targets depend on the settings alone, so every item rerun at one
    attempt gets the same one.
    """
    outs = list(run(list(range(n)), target_accept, 0))
    first, at = [0] * n, [0.0] * n
    pending, current, attempt = list(range(n)), target_accept, 0
    while True:
        targets = {}
        for i in pending:
            bad, total = divergences(outs[i])
            targets[i] = retry_target(current, retry_target_accept, bad / max(total, 1))
        pending = [i for i, t in targets.items() if t is not None]
        if not pending:
            return [Retried(o, f, a) for o, f, a in zip(outs, first, at, strict=True)]
        target = targets[pending[0]]
        assert target is not None  # pending items have one
        current, attempt = target, attempt + 1
        for i, out in zip(pending, run(pending, current, attempt), strict=True):
            first[i] = first[i] or divergences(outs[i])[0]
            outs[i], at[i] = out, current


def map_chains[T](one: Callable[[int], T], n: int, threads: int | None = None) -> list[T]:
    """``[one(0), ..., one(n - 1)]`` on a thread pool of ``threads`` (default: one per core,
    :func:`bayescal._parallel.workers`), each result blocked on in its thread; Ctrl-C raises at once, not
    waiting for the running chains."""
    import jax

    from bayescal._parallel import workers

    pool = ThreadPoolExecutor(max_workers=workers(n, threads))
    try:
        out = list(pool.map(lambda i: jax.block_until_ready(one(i)), range(n)))
    except BaseException:
        pool.shutdown(wait=False, cancel_futures=True)
        raise
    pool.shutdown()
    return out
