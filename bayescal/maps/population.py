"""The hierarchical per-pixel model, conditionally conjugate: no MCMC per pixel.

Pixel ``i`` of a channel has parameters ``theta_i`` (its offset in DN, its dark
current in DN/s, its relative gain ``1 + PRNU deviation``).  Its mean reading
in every flat and dark stack is linear in them (EMVA 1288 release 4.0,
eq. 2 and section 8):

``dark stack at exposure t:  y = o_i + D_i t``
``flat stack at exposure t:  y = o_i + D_i t + r_i S_c``

where ``S_c`` is the channel's mean signal in condition ``c`` above dark (the
channel response, nonlinearity included, so ``r_i`` is relative to it).  The
noise of a stack mean is the channel's temporal variance in that stack over
its frame count, times the pixel's own noise scale ``phi_i`` (1 for a normal
pixel, larger for a noisy one).

The pixels' parameters are drawn from a two-component population: *normal*
pixels ``N(mu_n, V_n)`` (``V_n``: the PRNU, DSNU and dark-current spreads and
their correlations) and *defects* ``N(mu_d, V_d)``, much wider (hot, dead,
bright or offset pixels).  Given the population, every pixel's posterior is a
two-component Normal mixture in closed form; the population itself is
fitted on the marginal likelihood of a subsample of pixels by expectation
maximisation with per-pixel measurement error (deconvolution).  All pixels
share one design, so one generalized eigen-decomposition per component
diagonalises every pixel's posterior at once.

Noisy pixels (random telegraph noise, which a mean image cannot see) are a
second mixture on the temporal variances: ``sum_s (n_s - 1) s2_is / v_s`` is
chi-square with ``sum_s (n_s - 1)`` degrees of freedom for a normal pixel and
``lambda`` times that for a noisy one.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
from scipy import linalg, special

__all__ = [
    "LinearDesign",
    "Population",
    "NoiseMixture",
    "fit_population",
    "fit_noise_mixture",
    "pixel_posterior",
    "mixture_posterior",
    "noisy_probability",
    "Component",
    "components",
    "combination_spread",
]

#: a defect component at least this many times the normal spread (sd) in every parameter
DEFECT_WIDTH = 5.0


@dataclass(frozen=True)
class LinearDesign:
    """One design for every pixel: ``y = X theta``, measurement variances ``var`` (a normal pixel's)."""

    X: np.ndarray  # (M, P)
    var: np.ndarray  # (M,)
    names: tuple[str, ...]

    @property
    def weights(self) -> np.ndarray:
        return 1.0 / self.var

    @property
    def covariance(self) -> np.ndarray:
        """``C0 = (X' W X)^-1``: a normal pixel's least-squares covariance."""
        return np.linalg.inv(self.X.T @ (self.X * self.weights[:, None]))

    @property
    def estimator(self) -> np.ndarray:
        """``A = C0 X' W`` (P, M): ``theta_hat = y @ A.T`` is each pixel's weighted least squares."""
        return self.covariance @ (self.X.T * self.weights[None, :])

    def least_squares(self, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per-pixel weighted least squares of ``y`` (N, M): estimates (N, P) and chi-square (N,)."""
        theta = y @ self.estimator.T
        resid = y - theta @ self.X.T
        return theta, np.einsum("nm,nm->n", resid * self.weights, resid)


@dataclass(frozen=True)
class Population:
    """The two-component population of pixel parameters (index 0: normal, 1: defect)."""

    weights: np.ndarray  # (2,)
    means: np.ndarray  # (2, P)
    covs: np.ndarray  # (2, P, P)
    n_pixels: int
    iterations: int
    converged: bool

    @property
    def spread(self) -> np.ndarray:
        """Standard deviations of the normal pixels' parameters (PRNU, DSNU, dark-current spread)."""
        return np.sqrt(np.diag(self.covs[0]))


@dataclass(frozen=True)
class NoiseMixture:
    """Noisy pixels: ``fraction`` of the pixels have temporal variance ``scale`` times the channel's."""

    fraction: float
    scale: float
    dof: float

    def probability(self, stat: np.ndarray) -> np.ndarray:
        """Posterior probability that each pixel is noisy, from its variance statistic."""
        return noisy_probability(stat, self.constants())

    def phi(self, stat: np.ndarray) -> np.ndarray:
        """Each pixel's expected noise scale given its statistic."""
        q = self.probability(stat)
        return 1.0 + q * (self.scale - 1.0)

    def constants(self) -> np.ndarray:
        """``(fraction, scale, dof, ln Gamma(dof / 2))``: what :func:`noisy_probability` needs, as one array."""
        return np.array([self.fraction, self.scale, self.dof, special.gammaln(self.dof / 2.0)])


def _chi2_logpdf(x, dof, lgamma_half_dof, xp=np):
    k = dof / 2.0
    x = xp.maximum(x, 1e-300)
    return (k - 1.0) * xp.log(x) - x / 2.0 - k * np.log(2.0) - lgamma_half_dof


def noisy_probability(stat, constants, xp=np):
    """Posterior probability that a pixel is noisy given its variance statistic ``stat``.

    ``constants``: :meth:`NoiseMixture.constants`.  ``xp`` is the array module
    (numpy, or ``jax.numpy`` inside the compiled streaming pass).
    """
    fraction, scale, dof, lgamma = (constants[i] for i in range(4))
    ln = xp.log1p(-fraction) + _chi2_logpdf(stat, dof, lgamma, xp)
    lq = xp.log(fraction) + _chi2_logpdf(stat / scale, dof, lgamma, xp) - xp.log(scale)
    return xp.exp(lq - xp.logaddexp(ln, lq))


def fit_noise_mixture(stat: np.ndarray, dof: float, *, iterations: int = 200) -> NoiseMixture:
    """Maximum-likelihood fraction and variance scale of noisy pixels (EM on the variance statistic)."""
    fraction, scale = 1e-3, 10.0
    lgamma = special.gammaln(dof / 2.0)
    for _ in range(iterations):
        q = noisy_probability(stat, (fraction, scale, dof, lgamma))
        new_fraction = float(np.clip(q.mean(), 1e-7, 0.5))
        new_scale = float(max(np.sum(q * stat) / max(np.sum(q) * dof, 1e-300), 1.5))
        done = abs(new_fraction - fraction) <= 1e-9 + 1e-6 * fraction and abs(new_scale - scale) <= 1e-6 * scale
        fraction, scale = new_fraction, new_scale
        if done:
            break
    return NoiseMixture(fraction, scale, float(dof))


class Component(NamedTuple):
    """A population component diagonalised against the design: ``U' C0 U = I``, ``U' V U = diag(gamma)``.

    A tuple of arrays, so the compiled streaming pass takes it as an argument
    (one compilation serves every population of the same shape).
    """

    mean: np.ndarray
    gamma: np.ndarray
    U: np.ndarray
    Uinv: np.ndarray
    logdet_c0: np.ndarray

    @classmethod
    def of(cls, mean, cov, c0) -> Component:
        gamma, U = linalg.eigh(cov, c0)
        gamma = np.maximum(gamma, 0.0)
        return cls(mean, gamma, U, np.linalg.inv(U), np.asarray(np.linalg.slogdet(c0)[1]))

    def terms(self, theta, phi, xp=np):
        """Marginal log density of each pixel's estimate (N,), posterior means (P, N), and the
        posterior covariances' eigenvalues in this component's basis (P, N): see :meth:`cov`.

        ``theta`` holds the pixels' estimates pixels-last, ``(P, N)``: the long axis is the
        contiguous one, which XLA vectorises (about 3x faster than ``(N, P)``)."""
        z = self.U.T @ (theta - self.mean[:, None])
        s = self.gamma[:, None] + phi[None, :]
        P = z.shape[0]
        loglik = -0.5 * (P * np.log(2 * np.pi) + self.logdet_c0 + xp.sum(xp.log(s) + z * z / s, axis=0))
        mean = self.mean[:, None] + self.Uinv.T @ (z * (self.gamma[:, None] / s))
        shrunk = self.gamma[:, None] * phi[None, :] / s
        return loglik, mean, shrunk

    def cov(self, shrunk, xp=np):
        """Posterior covariances (P, P, N): ``U^-T diag(shrunk) U^-1`` per pixel."""
        P = self.Uinv.shape[0]
        return xp.stack([xp.stack([(self.Uinv[:, a] * self.Uinv[:, b]) @ shrunk for b in range(P)]) for a in range(P)])


def components(pop: Population, c0: np.ndarray) -> tuple[Component, Component]:
    """The normal (0) and defect (1) components of ``pop``, diagonalised against the design covariance ``c0``."""
    return Component.of(pop.means[0], pop.covs[0], c0), Component.of(pop.means[1], pop.covs[1], c0)


def _robust_start(theta_hat: np.ndarray, c0: np.ndarray) -> Population:
    """Moment start: robust (median, MAD) scatter of the estimates minus their noise.

    EM moves a variance component slowly when it is small beside the noise,
    so the start must already be close: a floor of ``1e-4`` of the noise
    lets a spread that is truly near zero (a CCD's pixel DSNU) start there.
    """
    med = np.median(theta_hat, axis=0)
    mad = 1.4826 * np.median(np.abs(theta_hat - med), axis=0)
    var = np.maximum(mad**2 - np.diag(c0), 1e-4 * np.diag(c0))
    normal = np.diag(var)
    defect = np.diag((DEFECT_WIDTH * 4) ** 2 * (var + np.diag(c0)))
    return Population(
        np.array([0.99, 0.01]), np.stack([med, med]), np.stack([normal, defect]), len(theta_hat), 0, False
    )


def _psd_in_metric(cov: np.ndarray, c0: np.ndarray, floor: float = 1e-8) -> np.ndarray:
    """The nearest covariance with eigenvalues ``>= floor`` relative to ``c0`` (``eigh(cov, c0)`` clipped)."""
    gamma, U = linalg.eigh(0.5 * (cov + cov.T), c0)
    left = c0 @ U
    return (left * np.maximum(gamma, floor)) @ left.T


def fit_population(
    theta_hat: np.ndarray, phi: np.ndarray, c0: np.ndarray, *, iterations: int = 500, tol: float = 1e-9
) -> Population:
    """Maximum marginal likelihood population (EM with per-pixel error ``phi_i C0``).

    E-step: each pixel's responsibilities.  M-step, per component: the
    weighted mean, and the weighted scatter of the estimates minus their
    weighted noise ``phi C0``, clipped to a valid covariance.  For pixels that
    share one noise covariance this is the exact maximiser of the weighted
    marginal likelihood, so a spread that is small beside the noise (a
    CCD's pixel DSNU) is found in a few iterations; the textbook
    deconvolution update creeps there at a rate that vanishes with the
    spread.  The defect component is kept at least ``DEFECT_WIDTH`` normal
    standard deviations wide in every parameter, so the skewed tail of a
    normal population is not called defective.
    """
    pop = _robust_start(theta_hat, c0)
    n = len(theta_hat)
    theta = np.ascontiguousarray(theta_hat.T)  # (P, N): see Component.terms
    last = -np.inf
    converged = False
    it = 0
    for it in range(1, iterations + 1):
        comps = components(pop, c0)
        terms = [c.terms(theta, phi) for c in comps]
        logp = np.stack([np.log(pop.weights[k]) + terms[k][0] for k in range(2)])
        norm = np.logaddexp(logp[0], logp[1])
        q = np.exp(logp - norm)
        total = float(norm.sum())
        weights = np.clip(q.mean(axis=1), 1e-7, None)
        weights = np.array([max(weights[0], 0.5), min(weights[1], 0.5)])
        weights /= weights.sum()
        means, covs = [], []
        for k in range(2):
            w = q[k] / max(q[k].sum(), 1e-300)
            m = theta @ w
            d = theta - m[:, None]
            scatter = (d * w) @ d.T
            covs.append(_psd_in_metric(scatter - (w @ phi) * c0, c0))
            means.append(m)
        floor = DEFECT_WIDTH**2 * np.diag(covs[0])
        covs[1] = covs[1] + np.diag(np.maximum(floor - np.diag(covs[1]), 0.0))
        pop = Population(weights, np.stack(means), np.stack(covs), n, it, False)
        if abs(total - last) <= tol * abs(total):
            converged = True
            break
        last = total
    return Population(pop.weights, pop.means, pop.covs, n, it, converged)


@dataclass
class PixelPosterior:
    """Per-pixel posterior summaries (mixture over the two components), pixels last."""

    mean: np.ndarray  # (P, N)
    cov: np.ndarray  # (P, P, N)
    defect_probability: np.ndarray  # (N,): the wide component's responsibility


def pixel_posterior(theta_hat: np.ndarray, phi: np.ndarray, c0: np.ndarray, pop: Population) -> PixelPosterior:
    """Every pixel's posterior given the population: a two-component Normal mixture in closed form.

    ``theta_hat`` (N, P): the pixels' least-squares estimates; the summaries come pixels last.
    """
    return mixture_posterior(components(pop, c0), np.log(pop.weights), np.ascontiguousarray(theta_hat.T), phi)


def mixture_posterior(comps, log_weights, theta, phi, xp=np) -> PixelPosterior:
    """:func:`pixel_posterior` from the diagonalised components and estimates ``theta`` (P, N), in the
    array module ``xp``."""
    terms = [c.terms(theta, phi, xp) for c in comps]
    logp = [log_weights[k] + terms[k][0] for k in range(2)]
    norm = xp.logaddexp(logp[0], logp[1])
    q = [xp.exp(lp - norm) for lp in logp]
    mean = q[0] * terms[0][1] + q[1] * terms[1][1]
    cov: Any = 0.0
    for k in range(2):
        d = terms[k][1] - mean
        cov = cov + q[k] * (comps[k].cov(terms[k][2], xp) + d[:, None, :] * d[None, :, :])
    return PixelPosterior(mean, cov, q[1])


def combination_spread(
    pop: Population, c0: np.ndarray, v: np.ndarray, n_normal: float
) -> tuple[float, float, tuple[float, float]]:
    """Spread (sd) of ``v . theta`` over the normal pixels, its standard error and 95 % interval.

    For estimates that scatter as ``N(mu, sigma^2 + c)`` over ``n`` pixels,
    the maximum-likelihood ``sigma^2`` has standard error
    ``sqrt(2 / n) (sigma^2 + c)``; the interval is that of ``sigma^2``
    (clipped at zero), square-rooted, so it stays valid when the spread is
    near zero, where the delta-method error of ``sigma`` is not.
    E.g. ``v = (1, t, 0)``: the dark signal non-uniformity (DSNU) at exposure ``t``.
    """
    var = float(v @ pop.covs[0] @ v)
    c = float(v @ c0 @ v)
    sd = np.sqrt(max(var, 0.0))
    se_var = np.sqrt(2.0 / max(n_normal, 1.0)) * (var + c)
    interval = (float(np.sqrt(max(var - 1.96 * se_var, 0.0))), float(np.sqrt(var + 1.96 * se_var)))
    return float(sd), float(se_var / (2.0 * max(sd, 1e-300))), interval


def spread_uncertainty(pop: Population, c0: np.ndarray, n_normal: float) -> tuple[np.ndarray, list]:
    """Standard errors and 95 % intervals of the normal spreads, per parameter (see :func:`combination_spread`)."""
    rows = [combination_spread(pop, c0, np.eye(len(c0))[j], n_normal) for j in range(len(c0))]
    return np.array([r[1] for r in rows]), [r[2] for r in rows]
