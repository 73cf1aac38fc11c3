"""Progress bars on a terminal, silent otherwise (not a TTY, or ``--quiet``)."""

from __future__ import annotations

import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager

__all__ = ["progress_bar"]


@contextmanager
def progress_bar(total: int, desc: str, quiet: bool = False) -> Iterator[Callable[[int], None] | None]:
    """Yield ``tick(done)`` that advances a tqdm bar to ``done``, or None when silent."""
    if quiet or not sys.stderr.isatty():
        yield None
        return
    from tqdm import tqdm

    bar = tqdm(total=total, desc=desc, unit="it", leave=False)

    def tick(done: int) -> None:
        bar.update(max(0, min(done, total) - bar.n))

    try:
        yield tick
    finally:
        bar.close()
