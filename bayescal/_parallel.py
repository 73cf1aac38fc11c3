"""The one thread policy: how many cores a computation may use (``cores``, ``workers``), and independent
pieces of one computation at once where that helps (``parallel_map``).

Every thread pool of the package sizes itself here: the cores this process may run on (its CPU affinity,
which a container or ``taskset`` narrows), or ``$BAYESCAL_THREADS`` where a user or a cluster's worker says
so; nothing is sized by a core count written in the code.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable, Iterable
from concurrent.futures import ThreadPoolExecutor

__all__ = ["cores", "workers", "parallel_map"]


def cores() -> int:
    """The cores this process may use: ``$BAYESCAL_THREADS`` when set (a positive integer), else the number
    of CPUs in its affinity mask (``os.cpu_count()`` where the platform has no mask)."""
    given = os.environ.get("BAYESCAL_THREADS", "").strip()
    if given:
        from bayescal.errors import SpecError  # exit 2 on the command line, naming the variable

        if not given.isdigit() or int(given) < 1:
            raise SpecError(f"BAYESCAL_THREADS = {given!r}; expected a positive integer (the threads to use)")
        return int(given)
    try:
        return len(os.sched_getaffinity(0)) or 1
    except AttributeError:  # no affinity on this platform
        return os.cpu_count() or 1


def workers(n: int, at_most: int | None = None) -> int:
    """Threads for ``n`` independent pieces: one per core, no more than the pieces (nor ``at_most``)."""
    return max(1, min(n, cores(), at_most if at_most is not None else n))


def parallel_map[T, R](fn: Callable[[T], R], items: Iterable[T]) -> list[R]:
    """``[fn(x) for x in items]``, on :func:`workers` threads when called from the main thread.

    Meant for independent pieces whose work runs outside the interpreter's lock (a compiled JAX
    program, a LAPACK call): two blocks of draws or two refits at once on two cores.  Called from
    another thread (the diagnosis already fits candidates at once), it runs them one after the
    other: threads inside threads only made the cores share twice the computations and LAPACK's own
    threads.  The results are those of the loop, in order.
    """
    items = list(items)
    n = workers(len(items))
    if n < 2 or threading.current_thread() is not threading.main_thread():
        return [fn(x) for x in items]
    with ThreadPoolExecutor(n) as pool:
        return list(pool.map(fn, items))
