"""The observed reading: the expected reading's noise and the ADC's clipping, composed once
(docs/architecture.md, section 2).

After :func:`bayescal.model.equation.reading` gives the expected reading ``mean = sum(offsets) + S``,
what the camera outputs is::

    var     = pixel variance / n_avg + excess^2 + (prnu S)^2        (Noise.reading_variance)
              + the noise effects' variances                        (NoiseEffect)
    reading = ADC(mean + sqrt(var) z)                                (Saturation.adc)

and, for a region mean near full scale whose pixels clip one by one (pixel values spread by their
temporal noise and a PRNU fraction ``f``, seed 000 section 5.3)::

    spread  = sqrt(pixel variance + (f S)^2)
    reading = ADC(E[min(Y, fs)] + sqrt(var of the unclipped share) z)

Two forms of the same observation live here, so no other module composes noise and clipping:

- :func:`draw` (numpy): readings drawn from the expected ones; the calibration's posterior predictive
  (:meth:`~bayescal.posterior.calibration.Calibration.sample_dn`, which the planner and the report
  use) and the simulator (:mod:`bayescal.model.simulate`) call it;
- :func:`score` (numpyro): the likelihood of the table's readings given the expected ones, the site
  ``obs`` of the model (:func:`bayescal.model.assemble.numpyro_model`), with its clipping handled by
  :class:`~bayescal.model.components.saturation.Saturation`.

:func:`expected` is the noiseless reading the ADC would output.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from bayescal.model.components.noise import Noise
from bayescal.model.components.saturation import Saturation
from bayescal.model.equation import Reading

if TYPE_CHECKING:
    from bayescal.model.data import ModelData

__all__ = ["draw", "expected", "score", "variance"]


def expected(mean: Any, full_scale: float, xp: Any = np) -> Any:
    """The expected reading as the ADC outputs it: ``mean`` clipped to ``0..full_scale``."""
    return Saturation.adc(mean, full_scale, xp)


def variance(
    pixel_variance: Any, signal: Any, *, n_avg: float = 1.0, excess: Any = 0.0, prnu: float = 0.0, extra: Any = 0.0
) -> Any:
    """The variance of one reading (DN^2, numpy): the pixels' temporal variance averaged over ``n_avg``
    pixels x frames, the excess scatter, a single pixel's PRNU at its ``signal``
    (:meth:`~bayescal.model.components.noise.Noise.reading_variance`) and the noise effects' ``extra``."""
    return Noise.reading_variance(pixel_variance, n_avg, excess, prnu, np.maximum(signal, 0.0)) + extra


def draw(
    reading: Reading,
    pixel_variance: Any,
    normals: np.ndarray,
    full_scale: float,
    *,
    n_avg: float = 1.0,
    excess: Any = 0.0,
    prnu: float = 0.0,
    integer: bool = False,
    pixel_prnu: float | None = None,
    extra: Any = 0.0,
) -> np.ndarray:
    """Readings drawn from the expected ones (numpy, broadcast shapes).

    Parameters
    ----------
    reading : Reading
        The expected reading and its signal (:func:`bayescal.model.equation.reading`), in DN.
    pixel_variance : array
        Temporal variance of one pixel reading (DN^2; :meth:`~bayescal.model.components.noise.Noise.pixel_variance`).
    normals : array
        Standard normals, one per reading (broadcast against ``reading.mean``).
    full_scale : float
        The ADC's largest code.
    n_avg : float
        Pixels x frames averaged into a reading.
    excess : float or array
        Extra scatter of a reading (DN) that averaging does not shrink.
    prnu : float
        Response non-uniformity of a single pixel, added to its noise as ``prnu S``.
    integer : bool
        Round to whole codes (a single reading).
    pixel_prnu : float, optional
        For a region mean: the PRNU fraction that spreads its pixels, which then clip one by one
        near full scale (the mean falls to ``E[min(Y, fs)]`` and only the unclipped share of the
        pixels carries noise).  None: the mean is clipped as a whole.
    extra : float or array
        Variance the noise effects add to the reading (DN^2).
    """
    signal = np.maximum(reading.signal, 0.0)
    mean = reading.mean
    if pixel_prnu is not None:
        spread = np.sqrt(pixel_variance + (pixel_prnu * signal) ** 2)
        kept = Saturation.unclipped_fraction(mean, spread, full_scale)
        mean = Saturation.clipped_mean(mean, spread, full_scale)
        pixel_variance = pixel_variance * kept
        excess = excess * np.sqrt(kept)
    var = variance(pixel_variance, signal, n_avg=n_avg, excess=excess, prnu=prnu, extra=extra)
    return Saturation.adc(mean + np.sqrt(var) * normals, full_scale, integer=integer)


def score(noise: Noise, saturation: Saturation, data: ModelData, reading: Reading, extra: tuple[Any, ...] = ()) -> None:
    """The model's likelihood of the table's readings (numpyro site ``obs``): the noise of each row's mean
    (sampling its excess scatter, plus the noise effects' variances ``extra``) and the clipping near full
    scale, given the expected ``reading`` in the model's scaled units."""
    import jax.numpy as jnp

    var_mean = noise.sample(data, reading.signal)
    for variance in extra:
        var_mean = var_mean + variance
    var_pix = noise.nominal_pixel_variance(data, reading.signal, jnp)
    saturation.observe(data, reading.mean, reading.signal, var_pix, var_mean)
