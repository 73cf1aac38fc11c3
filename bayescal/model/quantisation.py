"""The temporal variance of rounded readings: what the ADC's integer codes do to photon transfer.

A pixel whose signal is ``mu + sigma Z`` (DN, ``Z`` standard normal) reads the code
``round(mu + sigma Z)``.  Its temporal variance is ``sigma^2 + 1/12`` (Sheppard's correction)
only while ``sigma`` is well above half a DN; below it the rounding swallows the noise (a
pixel at 4.0 DN with ``sigma = 0.2`` reads 4 almost always) or doubles it (at 4.5 DN it
flips between 4 and 5).  Averaged over pixels whose means spread over a code or more (the
offsets' and gains' non-uniformity dithers them), the expected variance is a function of
``sigma`` alone::

    V(sigma) = E_u[ Var(round(u + sigma Z)) ],  u uniform on [0, 1)

which rises from 0 at ``sigma = 0`` to ``sigma^2 + 1/12`` (within 1e-9 from ``sigma`` = 1.5
DN on).  :func:`unrounded_variance` inverts it, so a measured pair variance gives the noise
variance before the rounding, and :func:`rounding_slope` its derivative, which sets how
much a step's variance tells about that noise.  EMVA 1288 release 4.0 section 6.3 has the
same effect in view when it floors the dark variance at :data:`DARK_FLOOR_DN2` for the
standard's own estimates.
"""

from __future__ import annotations

import functools

import numpy as np
from scipy.special import ndtr

__all__ = ["rounded_variance", "unrounded_variance", "rounding_slope", "pixel_rounded_variance", "DARK_FLOOR_DN2"]

#: EMVA 1288's floor on the dark temporal variance, DN^2 (0.49^2): below it quantisation dominates
DARK_FLOOR_DN2 = 0.24
#: above this noise (DN) the rounding adds exactly 1/12 DN^2 (to within 1e-9)
_EXACT_FROM = 1.5


def pixel_rounded_variance(mu, sigma, xp=np, reach: int | None = None):
    """Temporal variance of ``round(mu + sigma Z)`` for each pixel mean ``mu`` and noise ``sigma`` (DN).

    Sums over the codes within ``reach`` of ``floor(mu)`` (default: 8 ``sigma``; give it under
    ``jax.numpy``, ``xp``, where shapes are static), one code at a time so the memory stays that of
    ``mu``.
    """
    if xp is np:
        mu, sigma = np.broadcast_arrays(np.asarray(mu, float), np.asarray(sigma, float))
        cdf = ndtr
    else:
        from jax.scipy.special import ndtr as cdf
    if reach is None:
        reach = int(np.ceil(8.0 * max(float(np.max(sigma, initial=0.0)), 0.1))) + 1
    frac = mu - xp.floor(mu)
    s = xp.maximum(sigma, 1e-12)
    first = second = 0.0
    below = cdf((-reach - 0.5 - frac) / s)
    for k in range(-reach, reach + 2):
        upto = cdf((k + 0.5 - frac) / s)
        p = upto - below
        first = first + p * k
        second = second + p * (k * k)
        below = upto
    return xp.maximum(second - first * first, 0.0)


@functools.cache
def _table() -> tuple[np.ndarray, np.ndarray]:
    """``V(sigma)`` on a grid of ``sigma`` from 0 to :data:`_EXACT_FROM` (midpoint rule over ``u``)."""
    sigma = np.linspace(0.0, _EXACT_FROM, 601)
    u = (np.arange(400) + 0.5) / 400
    v = pixel_rounded_variance(u[None, :], sigma[:, None]).mean(axis=1)
    return sigma**2, v


def rounded_variance(var) -> np.ndarray:
    """``V``: the expected variance of rounded readings whose noise before rounding has variance ``var`` (DN^2)."""
    var = np.asarray(var, dtype=float)
    s2, v = _table()
    return np.where(var >= s2[-1], var + 1.0 / 12.0, np.interp(var, s2, v))


def unrounded_variance(measured) -> np.ndarray:
    """The noise variance before the rounding (DN^2) whose rounded readings have variance ``measured``."""
    measured = np.asarray(measured, dtype=float)
    s2, v = _table()
    return np.where(measured >= v[-1], measured - 1.0 / 12.0, np.interp(np.maximum(measured, 0.0), v, s2))


def rounding_slope(var) -> np.ndarray:
    """``dV / d var`` at the noise variance ``var``: 1 above 1.5 DN of noise, less below (the rounding hides it)."""
    var = np.asarray(var, dtype=float)
    s2, v = _table()
    slope = np.gradient(v, s2)
    return np.where(var >= s2[-1], 1.0, np.interp(var, s2, slope))
