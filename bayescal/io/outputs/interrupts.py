"""Ctrl-C while an output is written: the steps that put files in place run with SIGINT held back, and
the process knows which outputs it has put in place (for a truthful message) and which staging folders
to remove."""

from __future__ import annotations

import contextlib
import shutil
import signal
import threading
from collections.abc import Iterator
from pathlib import Path

__all__ = ["interrupts_held", "committed", "discard_staging", "staging", "commit", "inside", "in_staging", "checkpoint"]

#: staging folders of outputs being written in this process (removed on an interrupt)
_STAGING: set[Path] = set()
#: output folders put in place (or added to) by this process, in order
_COMMITTED: list[Path] = []


def checkpoint(name: str) -> None:
    """A named point in writing an output (tests interrupt the process here by replacing this function)."""


@contextlib.contextmanager
def interrupts_held() -> Iterator[None]:
    """Hold back SIGINT (Ctrl-C) for the block and act on it right after.

    In the main thread the current handler is swapped for one that only notes the
    signal; on leaving, the previous handler is put back and, if a signal came, called
    (or ``KeyboardInterrupt`` raised, for the default handler).  Elsewhere the block
    runs as it is (signals are only delivered to the main thread).
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught: list[int] = []
    previous = signal.signal(signal.SIGINT, lambda signum, frame: caught.append(signum))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
        if caught:
            if callable(previous):
                previous(signal.SIGINT, None)
            elif previous != signal.SIG_IGN:
                raise KeyboardInterrupt


@contextlib.contextmanager
def staging(path: Path) -> Iterator[Path]:
    """Register ``path`` as a folder being written for the block (removed by :func:`discard_staging`)."""
    _STAGING.add(path)
    try:
        yield path
    finally:
        _STAGING.discard(path)


def inside(path: Path, folder: Path) -> bool:
    """``path`` lies in ``folder`` (or is it)."""
    return path.absolute().is_relative_to(folder.absolute())


def in_staging(path: Path) -> bool:
    """``path`` lies in a folder this process is staging (its record is written when the folder is put
    in place, not file by file)."""
    return any(inside(path, s) for s in _STAGING)


def commit(folder: Path) -> None:
    """Note that ``folder`` was put in place or added to, unless it lies in another run's staging folder
    (not yet out)."""
    if folder not in _COMMITTED and not in_staging(folder):
        _COMMITTED.append(folder)


def committed() -> list[Path]:
    """Output folders this process has put in place or added to, in order."""
    return list(_COMMITTED)


def discard_staging() -> None:
    """Remove the staging folders of outputs still being written (an interrupted run leaves none)."""
    for path in list(_STAGING):
        shutil.rmtree(path, ignore_errors=True)
        _STAGING.discard(path)
