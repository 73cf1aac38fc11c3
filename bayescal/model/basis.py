"""Polynomial bases: fit in a scaled orthogonal basis, report monomials.

The response is fitted on the scaled linear signal ``v`` in [0, 1] with
nonlinearity terms built from shifted Legendre polynomials,
``p_k(v) = P_k(2 v - 1) - P_k(-1)``, which keeps the normal equations well
conditioned (docs/architecture.md, section 5).  Each ``p_k`` vanishes at ``v = 0``, so the
gain ``G`` is exactly the small-signal slope and the map from ``(G, eta)`` to
the polynomial is one-to-one (with ``P_k`` itself, ``G (1 - eta)`` and ``eta
G^2`` admit two solutions and the posterior is bimodal).  Reports convert to
the papers' monomials ``DN = A0 + A1 L + ... + Ap L^p`` (seed 000 eq. 5, seed
002 eq. 6), draw by draw, so that their joint covariance is carried through.
"""

from __future__ import annotations

from functools import cache

import numpy as np
from numpy.polynomial import Legendre, Polynomial

__all__ = ["shifted_legendre_monomials", "response_monomials", "rescale_monomials"]


@cache
def shifted_legendre_monomials(order: int) -> np.ndarray:
    """Monomial coefficients of ``p_k(v) = P_k(2v - 1) - P_k(-1)`` for ``k = 1..order-1``.

    Returns an array ``Q`` of shape ``(order - 1, order)`` with
    ``p_k(v) = sum_j Q[k - 1, j] v**j`` and ``Q[:, 0] == 0``.
    """
    out = np.zeros((max(order - 1, 0), order))
    for k in range(1, order):
        poly = Legendre.basis(k, domain=[0.0, 1.0]).convert(kind=Polynomial)
        out[k - 1, : k + 1] = poly.coef
        out[k - 1, 0] = 0.0
    out.setflags(write=False)
    return out


def response_monomials(gain, eta, order: int, xp=np):
    """Coefficients ``c_m`` of the signal ``S(u) = sum_m c_m u^m``, ``m = 0..order``.

    The signal is ``S = v (1 + sum_k eta_k p_k(v))`` with ``v = gain * u``.

    Parameters
    ----------
    gain : array (...,)
        Scaled linear gain ``G`` (signal per unit scaled stimulus).
    eta : array (..., order - 1) or None
        Nonlinearity coefficients (``None`` for a linear response).
    order : int
        Polynomial order p.
    xp : module
        Array namespace (``numpy``, or ``jax.numpy`` inside the model).

    Returns
    -------
    array (..., order + 1)
        Monomial coefficients in ``u``; ``c_0 = 0`` (the offset is the dark model's).
    """
    gain = xp.asarray(gain, dtype=float)
    unit = np.zeros(order)
    unit[0] = 1.0  # the linear term, v
    c_v = xp.broadcast_to(xp.asarray(unit), gain.shape + (order,))
    if order > 1 and eta is not None:
        # v * p_k(v): each p_k shifted up one power (p_k(0) = 0, so nothing reaches the constant)
        c_v = c_v + xp.einsum("...k,kj->...j", xp.asarray(eta, dtype=float), shifted_legendre_monomials(order))
    c_v = xp.concatenate([xp.zeros(gain.shape + (1,)), c_v], axis=-1)
    return c_v * gain[..., None] ** np.arange(order + 1)


def rescale_monomials(coef: np.ndarray, scale: float | np.ndarray) -> np.ndarray:
    """Coefficients in ``x = u * scale`` from coefficients in ``u``: ``a_m = c_m / scale^m``."""
    coef = np.asarray(coef, dtype=float)
    scale = np.asarray(scale, dtype=float)
    powers = np.arange(coef.shape[-1])
    return coef / scale[..., None] ** powers
