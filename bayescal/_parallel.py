"""Two pieces of one computation at once, where that helps: ``pairwise_map``."""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterable
from concurrent.futures import ThreadPoolExecutor

__all__ = ["pairwise_map"]

#: threads one computation splits into
THREADS = 2


def pairwise_map[T, R](fn: Callable[[T], R], items: Iterable[T]) -> list[R]:
    """``[fn(x) for x in items]``, two at a time in threads when called from the main thread.

    Meant for independent pieces whose work runs outside the interpreter's lock (a compiled JAX
    program, a LAPACK call): on two cores, two blocks of draws or two refits at once.  Called from
    another thread (the diagnosis already fits two candidates at once), it runs them one after the
    other: threads inside threads only made the two cores share four computations and LAPACK's own
    threads.  The results are those of the loop, in order.
    """
    items = list(items)
    if len(items) < 2 or threading.current_thread() is not threading.main_thread():
        return [fn(x) for x in items]
    with ThreadPoolExecutor(THREADS) as pool:
        return list(pool.map(fn, items))
