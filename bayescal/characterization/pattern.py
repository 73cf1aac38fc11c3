"""The spatial non-uniformity as pictures: the DSNU and PRNU images, their histograms and spectrograms.

EMVA 1288 (release 4.0, section 8) reads the fixed pattern from the mean images of a dark and a bright
stack of ``L`` frames. The DSNU image is the dark mean image less its mean (DN); the PRNU image is the
bright mean image less the dark one, less its mean, in % of that mean. The standard shows each as a
histogram (its tails are the defective pixels) and as horizontal and vertical spectrograms (a periodic
pattern, such as column fixed-pattern noise, is a peak; a white pattern is flat at its standard
deviation).

The posterior says what a Gaussian white pattern of the fitted DSNU and PRNU would look like in these
pictures: each mean image keeps a residual temporal variance ``s2_temporal / L`` (EMVA 1288 eq. 32), so
its spatial standard deviation is ``sqrt(s2_spatial + s2_temporal / L)``, with ``s2_spatial`` from the
posterior's ``DSNU1288 K`` (DN) and ``PRNU1288 (mu_bright - mu_dark)`` (DN; differencing the mean images
removes the dark pattern). Pixels outside that band, and peaks above it, are what the single numbers hide.
"""

from __future__ import annotations

import numpy as np

__all__ = ["pattern_images", "pattern_sd_draws", "profile", "spectrogram"]


def pattern_images(stack: dict) -> dict[str, np.ndarray] | None:
    """The DSNU image (DN) and the PRNU image (% of the mean bright signal) from a set's mean images.

    Parameters
    ----------
    stack : dict
        :attr:`bayescal.io.emva.Steps.stack`, with the mean images ``image_bright`` and ``image_dark``.

    Returns
    -------
    dict or None
        ``{"DSNU": dark - mean(dark), "PRNU": 100 (b - d - mean(b - d)) / mean(b - d)}``; None where the
        set's stacks were given as statistics only (a reduced table).
    """
    if "image_bright" not in stack or "image_dark" not in stack:
        return None
    dark = np.asarray(stack["image_dark"], dtype=np.float64)
    lit = np.asarray(stack["image_bright"], dtype=np.float64) - dark
    return {"DSNU": dark - dark.mean(), "PRNU": 100.0 * (lit - lit.mean()) / lit.mean()}


def spectrogram(image: np.ndarray, axis: int) -> tuple[np.ndarray, np.ndarray]:
    """The amplitude spectrum of ``image`` along ``axis``, averaged over the other axis.

    ``sqrt(mean_rows |FFT(row)|^2 / N)`` at the frequencies ``0 ... 0.5`` cycles per pixel (the zero
    frequency left out: the image is centred). A white pattern of standard deviation ``s`` reads ``s`` at
    every frequency (Parseval), so a peak above that level is a periodic pattern. ``axis=1`` is the
    horizontal spectrogram (along each row), ``axis=0`` the vertical one (along each column).

    Returns
    -------
    frequency, amplitude : numpy.ndarray
        In cycles per pixel, and in the image's unit.
    """
    x = np.asarray(image, dtype=np.float64)
    x = x - x.mean()
    n = x.shape[axis]
    power = np.abs(np.fft.rfft(x, axis=axis)) ** 2 / n
    mean_power = power.mean(axis=1 - axis)
    return np.fft.rfftfreq(n)[1:], np.sqrt(mean_power[1:])


def pattern_sd_draws(stack: dict, draws: dict) -> dict[str, np.ndarray] | None:
    """Posterior draws of each pattern image's spatial standard deviation, residual temporal noise included.

    Parameters
    ----------
    stack : dict
        The set's stack statistics (``temporal_var_*``, ``mean_*``, ``n_images``).
    draws : dict
        The characterisation's draws of ``DSNU1288`` (e-), ``K`` (DN/e-) and ``PRNU1288`` (%).

    Returns
    -------
    dict or None
        ``{"DSNU": DN, "PRNU": %}`` per draw; None without the draws or the stack statistics.
    """
    needed = ("temporal_var_dark", "temporal_var_bright", "mean_bright", "mean_dark", "n_images")
    if any(k not in stack for k in needed) or any(k not in draws for k in ("DSNU1288", "PRNU1288", "K")):
        return None
    n = float(stack["n_images"])
    signal = float(stack["mean_bright"] - stack["mean_dark"])
    dsnu_dn = np.asarray(draws["DSNU1288"]) * np.asarray(draws["K"])
    prnu_dn = np.asarray(draws["PRNU1288"]) / 100.0 * signal
    residual_dark = stack["temporal_var_dark"] / n
    residual_lit = (stack["temporal_var_bright"] + stack["temporal_var_dark"]) / n
    return {
        "DSNU": np.sqrt(dsnu_dn**2 + residual_dark),
        "PRNU": 100.0 * np.sqrt(prnu_dn**2 + residual_lit) / signal,
    }


def profile(image: np.ndarray, axis: int) -> np.ndarray:
    """The standard's profile of a pattern image: the mean of each column (``axis=0``: the horizontal
    profile, one value per column) or of each row (``axis=1``: the vertical profile, one per row).  A white
    pattern of standard deviation ``s`` gives a flat profile whose values scatter by ``s / sqrt(n)`` (``n``
    the pixels averaged); shading or column and row patterns stand out of that band."""
    return np.asarray(image, dtype=np.float64).mean(axis=axis)
