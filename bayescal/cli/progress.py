"""Progress on long work: stage messages and tqdm bars (tqdm decides whether stderr is a terminal)."""

from __future__ import annotations

import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager

__all__ = ["progress_bar", "stage_reporter"]


@contextmanager
def progress_bar(total: int, desc: str, quiet: bool = False) -> Iterator[Callable[..., None] | None]:
    """Yield ``tick(done, new_total=None)`` that advances a tqdm bar to ``done``, or None when quiet.

    tqdm draws nothing when stderr is not a terminal (``disable=None``).
    """
    if quiet:
        yield None
        return
    from tqdm import tqdm

    bar = tqdm(total=total, desc=desc, unit="it", leave=False, disable=None, file=sys.stderr)

    def tick(done: int, new_total: int | None = None) -> None:
        if new_total is not None and new_total != bar.total:  # a total known only once the work is planned
            bar.total = new_total
        bar.update(max(0, min(done, bar.total) - bar.n))

    try:
        yield tick
    finally:
        bar.close()


def stage_reporter(quiet: bool = False) -> Callable[[str], None]:
    """``stage(message)``: one line on stderr per stage of a long run, with the seconds elapsed."""
    start = time.perf_counter()

    def stage(message: str) -> None:
        if not quiet:
            print(f"[{time.perf_counter() - start:6.1f} s] {message}", file=sys.stderr, flush=True)

    return stage
