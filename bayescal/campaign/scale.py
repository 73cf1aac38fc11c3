"""The noise scale a design will estimate, integrated out of its expected widths (docs/guides/design.md).

At a fixed noise scale the expected widths are those of a Gaussian at the nominal camera
(:mod:`bayescal.campaign.information`).  A fit does not know that scale: the Laplace backend
integrates the excess scatter's scale ``theta = log e`` numerically (an integrated nested Laplace
approximation in one dimension, :func:`bayescal.inference.laplace.integrated_draws`), and with few rows
per parameter its posterior is wide and skewed, so the widths the fit reports are wider than at the
scale's true value (by 1.9 times at 24 rows on the seed-002 protocol's grid).

Here the same integral is taken in expectation over the data a design would give.  Row ``r`` of noise
sd ``s_r(theta) = sqrt(v_r + e^2)`` (``v_r`` its pixel part) leaves an expected squared residual
``s_r^2 (1 - h_r)`` at the conditional mode (``h_r`` its leverage, the degrees of freedom the other
parameters take; Harville 1974, REML), so::

    log p(theta | design) ~ sum_r n_r [ -s_r0^2 (1 - h_r) / (2 s_r(theta)^2) - log s_r(theta) ]
                            - 1/2 log det H_rest(theta) + log prior(theta)

and each target's expected variance is ``sum_j p(theta_j) v_t(theta_j)`` over a grid of ``theta``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["NoiseScale", "integrated_variances"]

#: the grid over theta = log e around the nominal scale: from a twelfth of it to 33 times it (with few rows
#: per parameter the posterior's tail reaches several times the nominal scale; the prior bounds it)
GRID = np.linspace(-2.5, 3.5, 121)


@dataclass(frozen=True)
class NoiseScale:
    """The excess scatter's coordinate and what the integral needs at each point of the linearisation.

    Attributes
    ----------
    index : int
        Its position in the unconstrained parameters (``theta = log e``, scaled units).
    excess : array (S,)
        Its value at each point.
    prior_scale : float
        The half-normal prior's scale (scaled units).
    row_sd : array (S, K, J)
        The noise sd of each group's rows at each point (0 where a group has fewer rows).
    """

    index: int
    excess: np.ndarray
    prior_scale: float
    row_sd: np.ndarray


def integrated_variances(
    prior: np.ndarray, factors: np.ndarray, gradients: np.ndarray, noise: NoiseScale, counts: np.ndarray
) -> np.ndarray:
    """The targets' expected variances ``(S, T)`` with the noise scale integrated over its expected
    posterior under the design ``counts`` (``prior``, ``factors``, ``gradients`` as in
    :class:`~bayescal.campaign.information.Linearisation`)."""
    counts = np.asarray(counts, dtype=float)
    out = []
    i = noise.index
    for s in range(prior.shape[0]):
        u = factors[s]  # (K, 2J, d): mean row, sd row, per row of the group
        s0 = noise.row_sd[s]  # (K, J)
        e0 = float(noise.excess[s])
        valid = s0 > 0
        pixel = np.where(valid, np.maximum(s0**2 - e0**2, 1e-12 * s0**2), 1.0)
        precision = prior[s] + np.einsum("k,kmd,kme->de", counts, u, u)
        cov = np.linalg.inv(precision)
        mean_rows = u[:, 0::2]  # (K, J, d)
        leverage = np.einsum("kjd,de,kje->kj", mean_rows, cov, mean_rows)
        thetas = np.log(e0) + GRID
        rest = np.delete(np.arange(precision.shape[0]), i)
        logp, variances = [], []
        for theta in thetas:
            e = np.exp(theta)
            sd = np.sqrt(pixel + e**2)
            ratio = np.where(valid, s0 / sd, 0.0)
            scaled = u * np.repeat(ratio, 2, axis=1)[:, :, None]
            p = prior[s] + np.einsum("k,kmd,kme->de", counts, scaled, scaled)
            fit = -(s0**2) * (1.0 - leverage) / (2 * sd**2) - np.log(sd)
            _, logdet = np.linalg.slogdet(p[np.ix_(rest, rest)])
            logp.append(
                float(np.sum(counts[:, None] * np.where(valid, fit, 0.0)))
                - 0.5 * logdet
                - e**2 / (2 * noise.prior_scale**2)
                + theta
            )
            variances.append(np.einsum("td,de,te->t", gradients[s], np.linalg.inv(p), gradients[s]))
        w = np.exp(np.asarray(logp) - max(logp))
        out.append(np.einsum("j,jt->t", w / w.sum(), np.asarray(variances)))
    return np.asarray(out)
