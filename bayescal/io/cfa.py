"""Colour filter arrays: which channel each pixel of a raw Bayer mosaic belongs to.

A pattern (``RGGB``, ``BGGR``, ``GRBG``, ``GBRG``) names the colours of the
top-left 2 x 2 cell, row by row; the cell repeats over the sensor.
"""

from __future__ import annotations

import numpy as np

from bayescal.errors import SpecError

__all__ = ["CFA_PATTERNS", "cfa_cells", "channel_map", "planes"]

CFA_PATTERNS = ("RGGB", "BGGR", "GRBG", "GBRG")


def cfa_cells(cfa: str) -> dict[tuple[int, int], str]:
    """``{(row, col) offset in the 2 x 2 cell: channel letter}`` of a Bayer pattern."""
    cfa = cfa.upper()
    if cfa not in CFA_PATTERNS:
        raise SpecError(f"unknown CFA pattern '{cfa}'; expected one of {', '.join(CFA_PATTERNS)}")
    return {(i // 2, i % 2): letter for i, letter in enumerate(cfa)}


def channel_map(shape: tuple[int, int], cfa: str) -> np.ndarray:
    """Channel letter of every pixel of a Bayer mosaic with pattern ``cfa``."""
    cells = cfa_cells(cfa)
    cell = np.array([[cells[(0, 0)], cells[(0, 1)]], [cells[(1, 0)], cells[(1, 1)]]])
    h, w = shape
    return np.tile(cell, ((h + 1) // 2, (w + 1) // 2))[:h, :w]


def planes(cfa: str | None, channel: str = "M") -> tuple[int, list[tuple[str, int, int]]]:
    """``(step, [(channel, row offset, column offset)])``: the strided planes ``a[dy::step, dx::step]``.

    A monochrome sensor (``cfa=None``) is one plane named ``channel``.
    """
    if cfa is None:
        return 1, [(channel, 0, 0)]
    return 2, [(name, dy, dx) for (dy, dx), name in cfa_cells(cfa).items()]
