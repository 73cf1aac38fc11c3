"""Residuals in twice the working precision (error-free transformations).

A least-squares fit whose residuals are ``1e-12`` of its readings loses the
residuals' leading digits when they are formed as ``y - X b`` in float64:
the rounding error of ``X b`` is ~1e-16 of the readings, i.e. 1e-4 of the
residuals, and the residual sd, every standard error and the iterative
refinement of ``b`` inherit it.  Forming them with error-free
transformations (Dekker's split and product, Knuth's two-sum; Ogita, Rump
and Oishi's ``Dot2``; Graillat's compensated Horner scheme) gives results as
accurate as if computed in twice the precision, with plain float64
operations: no extended-precision type, the same on every platform.
"""

from __future__ import annotations

import numpy as np

__all__ = ["two_sum", "two_prod", "residual_dot2", "residual_horner"]

_SPLITTER = 2.0**27 + 1.0


def two_sum(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``s + e == a + b`` exactly, ``s = fl(a + b)`` (Knuth)."""
    s = a + b
    bb = s - a
    return s, (a - (s - bb)) + (b - bb)


def _split(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    c = _SPLITTER * a
    hi = c - (c - a)
    return hi, a - hi


def two_prod(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``p + e == a * b`` exactly, ``p = fl(a * b)`` (Dekker; no FMA needed)."""
    p = a * b
    ah, al = _split(a)
    bh, bl = _split(b)
    return p, al * bl - (((p - ah * bh) - al * bh) - ah * bl)


def residual_dot2(design: np.ndarray, coef: np.ndarray, y: np.ndarray) -> np.ndarray:
    """``y - design @ coef``, accumulated in double-double (``Dot2``) row by row."""
    s = np.asarray(y, dtype=float).copy()
    c = np.zeros_like(s)
    for j in range(design.shape[1]):
        p, pe = two_prod(-design[:, j], np.full_like(s, coef[j]))
        s, se = two_sum(s, p)
        c = c + (pe + se)
    return s + c


def residual_horner(x: np.ndarray, coef: np.ndarray, y: np.ndarray) -> np.ndarray:
    """``y - sum_k coef[k] x^k`` with the polynomial evaluated by compensated Horner (lowest power first)."""
    x = np.asarray(x, dtype=float)
    s = np.full_like(x, coef[-1])
    err = np.zeros_like(x)
    for c in coef[-2::-1]:
        p, pe = two_prod(s, x)
        s, se = two_sum(p, np.full_like(x, c))
        err = err * x + (pe + se)
    d, de = two_sum(np.asarray(y, dtype=float), -s)
    return d + (de - err)
