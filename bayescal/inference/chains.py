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

**Phases** (:func:`run_phases`).  NUTS on a potential ``potential(u, arrays)`` whose scale is known
in advance (a diagonal inverse mass matrix from a Laplace approximation), with only the step size
adapted, by dual averaging toward the target acceptance, in two halves of the warmup: the second
restarts from the first's average once the chains have left their starting points, and the
chains then share the geometric mean of their averaged steps.  The draws follow; while they do not
pass ``mixed`` the chains continue from their last state with the same step and mass, ``extend``
times at most.  Each phase is one program compiled per (potential, length, adaptation), so every
dataset of one structure shares it; chains run on threads (XLA releases the GIL while a chain runs).

A camera's fit adapts its mass matrix as well (numpyro's windowed adaptation, in coordinates whitened
by the Laplace covariance): its posterior's scales span orders of magnitude that a fixed diagonal
does not capture.  The fleet's scales are few and near-Gaussian after the latents are integrated
out, and step-only adaptation took 2.1x fewer gradient evaluations there
(``benchmarks/results/fleet_speed.md``).
"""

from __future__ import annotations

import itertools
import threading
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from functools import lru_cache
from typing import Any, NamedTuple

import numpy as np

__all__ = [
    "LAST_RETRY_ACCEPT",
    "LAST_RETRY_MAX_FRACTION",
    "Phased",
    "Retried",
    "attempt_seed",
    "map_chains",
    "progress_channel",
    "report",
    "retry_target",
    "run_phases",
    "step_program",
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


class Phased(NamedTuple):
    """Draws of :func:`run_phases`: unconstrained ``z`` ``(chain, draw, dim)``, the divergent transitions
    among them, and the gradient evaluations of every phase (warmup included)."""

    z: np.ndarray
    divergences: int
    gradients: int


@lru_cache(maxsize=64)
def step_program(potential: Callable, n: int, adapt: bool):
    """``n`` NUTS transitions from ``u`` with a fixed diagonal inverse mass matrix ``imm``, compiled once
    per (potential, ``n``, ``adapt``): ``run(key, u, imm, step, target, arrays) -> (u_last, step, z,
    diverging, steps)``.  With ``adapt`` the step size follows dual averaging toward the target
    acceptance and the returned step is its average (warmup); else it stays (draws)."""
    import jax
    import jax.numpy as jnp
    from numpyro.infer.hmc import hmc
    from numpyro.infer.hmc_util import dual_averaging

    da_init, da_update = dual_averaging()

    def run(key, u, imm, step, target, arrays):
        init_kernel, sample_kernel = hmc(potential_fn=lambda x: potential(x, arrays), algo="NUTS")
        state = init_kernel(
            u,
            num_warmup=0,
            step_size=step,
            inverse_mass_matrix=imm,
            adapt_step_size=False,
            adapt_mass_matrix=False,
            rng_key=key,
        )

        def transition(carry, _):
            st, da = carry
            st = sample_kernel(st)
            if adapt:
                da = da_update(target - st.accept_prob, da)
                st = st._replace(adapt_state=st.adapt_state._replace(step_size=jnp.exp(da[0])))
            return (st, da), (st.z, st.diverging, st.num_steps)

        (state, da), out = jax.lax.scan(transition, (state, da_init(jnp.log(10.0 * step))), None, length=n)
        return (state.z, jnp.exp(da[1]) if adapt else step, *out)

    return jax.jit(run)


def run_phases(
    potential: Callable,
    arrays: Any,
    u0: np.ndarray,
    imm: np.ndarray,
    *,
    warmup: int,
    draws: int,
    target_accept: float,
    seed: int,
    extend: int = 0,
    mixed: Callable[[np.ndarray], bool] | None = None,
    threads: int | None = None,
) -> Phased:
    """NUTS in phases (the module's docstring) from the chains' starts ``u0`` ``(chain, dim)``.

    Parameters
    ----------
    potential : callable
        ``potential(u, arrays)``, minus the log density; the same object for one structure (it keys
        the compiled programs).
    arrays : pytree
        The data, an argument of the compiled programs.
    imm : array (dim,)
        Diagonal inverse mass matrix, kept throughout.
    mixed : callable, optional
        ``mixed(z)`` on the draws so far ``(chain, draw, dim)``: True when they are enough; until then
        every chain continues for another ``draws`` draws, ``extend`` times at most.
    """
    import jax

    chains = int(u0.shape[0])
    key = jax.random.PRNGKey(seed)

    def phase(n: int, adapt: bool, us, steps, tag: int):
        run = step_program(potential, n, adapt)
        target = np.float64(target_accept)
        keys = jax.random.split(jax.random.fold_in(key, tag), chains)
        return map_chains(lambda c: run(keys[c], us[c], imm, steps[c], target, arrays), chains, threads)

    half = warmup // 2
    # with the Laplace variances as the mass, the posterior is about unit scale: a first step of 0.5
    settle = phase(half, True, u0, np.full(chains, 0.5), 0)
    warm = phase(warmup - half, True, [o[0] for o in settle], [o[1] for o in settle], 1)
    steps = np.full(chains, np.exp(np.mean([np.log(o[1]) for o in warm])))  # one for all: they share the mass
    outs = phase(draws, False, [o[0] for o in warm], steps, 2)
    z = [[np.asarray(o[2])] for o in outs]
    divergences = int(sum(np.sum(np.asarray(o[3])) for o in outs))
    gradients = int(sum(np.sum(np.asarray(o[4])) for o in settle + warm + outs))
    for i in range(extend if mixed is not None else 0):
        assert mixed is not None  # the loop runs only with it
        if mixed(np.stack([np.concatenate(c) for c in z])):
            break
        outs = phase(draws, False, [o[0] for o in outs], steps, 3 + i)  # the chains go on
        for c, o in enumerate(outs):
            z[c].append(np.asarray(o[2]))
        divergences += int(sum(np.sum(np.asarray(o[3])) for o in outs))
        gradients += int(sum(np.sum(np.asarray(o[4])) for o in outs))
    return Phased(np.stack([np.concatenate(c) for c in z]), divergences, gradients)
