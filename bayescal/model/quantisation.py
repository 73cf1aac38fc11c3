"""The temporal variance of rounded readings: what the ADC's integer codes do to a variance.

A pixel whose signal is ``mu + sigma Z`` (DN, ``Z`` standard normal) reads the code
``round(mu + sigma Z)``.  Its temporal variance is ``sigma^2 + 1/12`` (Sheppard's correction)
only while ``sigma`` is well above half a DN; below it the rounding swallows the noise (a
pixel at 4.0 DN with ``sigma = 0.2`` reads 4 almost always) or doubles it (at 4.5 DN it
flips between 4 and 5): :func:`pixel_rounded_variance`.  EMVA 1288 release 4.0 section 6.3
has the same effect in view when it floors the dark variance at :data:`DARK_FLOOR_DN2` for the
standard's own estimates.
"""

from __future__ import annotations

import numpy as np
from scipy.special import ndtr

__all__ = ["pixel_rounded_variance", "DARK_FLOOR_DN2"]

#: EMVA 1288's floor on the dark temporal variance, DN^2 (0.49^2): below it quantisation dominates
DARK_FLOOR_DN2 = 0.24


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
        from bayescal.model.normal import ndtr as cdf
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
