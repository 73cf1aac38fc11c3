"""Which nonlinearity does a sensor have: V/Q (charge to voltage) or DN/V (voltage to code)?

Seed 004 (a patent on remote-sensing camera electronics): both bend the video
response curve (mean DN against irradiance, dark to saturation), but only
V/Q acts pixel by pixel.  A pixel's sense capacitance falls with its own
voltage, so a brighter pixel is compressed more, and the PRNU factor
(spatial std / mean of a flat field, dark-subtracted and temporally averaged)
falls as irradiance rises.  DN/V nonlinearity (amplifier/ADC gain changing
with amplitude) is common to all pixels of one flat field, cancels in the
ratio, and leaves the PRNU curve flat.

Models, with ``s = a E`` the linear signal (DN, dark-subtracted):

* ``linear``: ``mu = s``, ``prnu = p``
* ``dn_v``:   ``mu = s (1 + b s)``, ``prnu = p``
* ``v_q``:    ``mu = s (1 - c s)``, ``prnu = p (1 - 2 c s) / (1 - c s)``
  (``h(Q) = Q - c Q^2``, so a pixel's relative spread scales by ``Q h' / h``)
* ``both``:   ``v = s (1 - c s)``, ``mu = v (1 + b v)``, prnu as ``v_q``

The **baseline** is the patent's procedure: is the response curve nonlinear
(F-test of a quadratic term)? If so, is the PRNU curve flat (t-test of its
slope)? Flat -> DN/V; falling -> V/Q (possibly with DN/V).  The
**Bayesian** comparison fits all four and returns posterior model
probabilities from Laplace approximations of the marginal likelihoods
(equal prior odds), and for the chosen model a correction DN -> linear signal.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import lru_cache

import jax
import jax.numpy as jnp
import numpy as np
from scipy import optimize, stats

from bayescal._config import computes
from bayescal.errors import TableError

__all__ = ["MODELS", "NonlinearityCurves", "simulate_curves", "patent_baseline", "compare_nonlinearity"]

MODELS = ("linear", "dn_v", "v_q", "both")
_PARAMS = {"linear": ("a", "p"), "dn_v": ("a", "p", "b"), "v_q": ("a", "p", "c"), "both": ("a", "p", "b", "c")}
COEF_PRIOR_SD = 0.5  # b and c in units of 1 / full scale: up to ~50 % compression at full scale


@dataclass(frozen=True)
class NonlinearityCurves:
    """Video response and PRNU curves: per irradiance step, with their standard errors."""

    irradiance: np.ndarray
    mean_dn: np.ndarray  # dark-subtracted mean DN
    mean_se: np.ndarray
    prnu: np.ndarray  # spatial std / mean (fraction)
    prnu_se: np.ndarray
    full_scale: float


def _truth_fn(model: str, a, p, b, c):
    def pixel(e, eps):
        s = a * e * (1 + p * eps)
        v = s * (1 - c * s) if model in ("v_q", "both") else s
        return v

    def common(v_mean):
        return 1 + b * v_mean if model in ("dn_v", "both") else 1.0

    return pixel, common


@computes
def simulate_curves(
    model: str,
    irradiance: np.ndarray,
    *,
    a: float = 4000.0,
    p: float = 0.01,
    b: float = 0.0,
    c: float = 0.0,
    n_pixels: int = 4096,
    n_frames: int = 16,
    read_noise: float = 2.0,
    conversion_gain: float = 0.1,
    full_scale: float = 4095.0,
    seed: int = 0,
) -> NonlinearityCurves:
    """Flat fields from dark to near saturation for a sensor with the given nonlinearity.

    ``b``, ``c`` are per DN (the tests use values like ``0.1 / full_scale``).
    Each step averages ``n_frames`` frames (temporal noise shrinks), subtracts
    dark, and measures the spatial mean and std over ``n_pixels`` pixels.

    Examples
    --------
    >>> import numpy as np
    >>> import bayescal as bc
    >>> curves = bc.simulate_curves("linear", np.linspace(0.05, 0.9, 10), seed=0)
    >>> type(curves).__name__
    'NonlinearityCurves'
    """
    if model not in MODELS:
        raise TableError(f"unknown model '{model}'; expected one of {MODELS}")
    rng = np.random.default_rng(seed)
    eps = rng.standard_normal(n_pixels)  # fixed pattern: the same pixels at every step
    pixel, common = _truth_fn(model, a, p, b, c)
    means: list[float] = []
    stds: list[float] = []
    se_std: list[float] = []
    for e in irradiance:
        v = pixel(e, eps)
        gain = common(v.mean())
        signal = v * gain
        temporal = np.sqrt(read_noise**2 + conversion_gain * np.maximum(signal, 0)) / np.sqrt(n_frames)
        img = signal + temporal * rng.standard_normal(n_pixels)
        means.append(img.mean())
        # temporal noise left after averaging is removed from the spatial variance (EMVA 1288 eq. 32)
        total = img.var(ddof=1)
        std = np.sqrt(max(total - np.mean(temporal**2), 1e-12))
        stds.append(std)
        # sampling sd of the std: var(s^2) = 2 sigma_total^4 / (n - 1), so sd(s) ~ sigma_total^2 / (s sqrt(2 (n - 1)))
        se_std.append(total / (std * np.sqrt(2 * (n_pixels - 1))))
    mean, std = np.array(means), np.array(stds)
    return NonlinearityCurves(
        irradiance=np.asarray(irradiance, dtype=float),
        mean_dn=mean,
        mean_se=std / np.sqrt(n_pixels) + 0.5,  # spatial sampling + a 0.5 DN level repeatability
        prnu=std / mean,
        prnu_se=np.array(se_std) / mean,
        full_scale=full_scale,
    )


def _predict(model: str, theta, e, fs):
    """Mean DN and PRNU factor of ``model`` at irradiance ``e`` (JAX)."""
    names = _PARAMS[model]
    par = dict(zip(names, theta, strict=True))
    a, p = par["a"], par["p"]
    b, c = par.get("b", 0.0) / fs, par.get("c", 0.0) / fs
    s = a * e
    v = s * (1 - c * s)
    mu = v * (1 + b * v)
    prnu = p * (1 - 2 * c * s) / (1 - c * s)
    return mu, prnu


@lru_cache(maxsize=8)
def _log_post(model: str) -> tuple[Callable, Callable, Callable]:
    def lp(theta, e, y, y_se, r, r_se, fs):
        mu, prnu = _predict(model, theta, e, fs)
        ll = -0.5 * jnp.sum(((y - mu) / y_se) ** 2) - 0.5 * jnp.sum(((r - prnu) / r_se) ** 2)
        extra = theta[2:]  # b, c: Normal(0, COEF_PRIOR_SD) in units of 1 / full scale
        prior = -0.5 * jnp.sum((extra / COEF_PRIOR_SD) ** 2) - extra.size * jnp.log(
            COEF_PRIOR_SD * jnp.sqrt(2 * jnp.pi)
        )
        return ll + prior

    return jax.jit(lp), jax.jit(jax.grad(lp)), jax.jit(jax.hessian(lp))


def _laplace_evidence(model: str, curves: NonlinearityCurves) -> dict:
    lp, grad, hess = _log_post(model)
    c = curves
    args = tuple(jnp.asarray(v) for v in (c.irradiance, c.mean_dn, c.mean_se, c.prnu, c.prnu_se)) + (c.full_scale,)
    lin = np.polyfit(c.irradiance, c.mean_dn, 1)[0]
    start = np.array([lin, float(np.median(c.prnu))] + [0.0] * (len(_PARAMS[model]) - 2))
    scale = np.abs(start) + np.r_[0.0, 0.0, np.ones(len(start) - 2)]
    f = lambda u: -float(lp(jnp.asarray(u * scale), *args))  # noqa: E731
    g = lambda u: -np.asarray(grad(jnp.asarray(u * scale), *args)) * scale  # noqa: E731
    sol = optimize.minimize(
        f,
        np.ones_like(start) * np.sign(start + (start == 0)),
        jac=g,
        method="BFGS",
        options={"gtol": 1e-10, "maxiter": 2000},
    )
    theta = sol.x * scale
    h = -np.asarray(hess(jnp.asarray(theta), *args))
    sign, logdet = np.linalg.slogdet(h)
    if sign <= 0:
        return {"theta": theta, "log_evidence": -np.inf, "cov": None}
    k = theta.size
    # flat prior on a and p over a wide box: its log density is a constant common to all models and cancels
    log_ev = float(lp(jnp.asarray(theta), *args)) + 0.5 * k * np.log(2 * np.pi) - 0.5 * logdet
    return {"theta": theta, "log_evidence": log_ev, "cov": np.linalg.inv(h)}


@computes
def compare_nonlinearity(curves: NonlinearityCurves) -> dict:
    """Posterior probabilities of {linear, dn_v, v_q, both} and the chosen model's parameters.

    Returns ``{"probabilities": {...}, "chosen": name, "parameters": {...},
    "sd": {...}, "correct": callable}``; ``correct(dn)`` maps dark-subtracted
    mean DN back to the linear signal ``a E`` under the chosen model.
    """
    fits = {m: _laplace_evidence(m, curves) for m in MODELS}
    log_ev = np.array([fits[m]["log_evidence"] for m in MODELS])
    w = np.exp(log_ev - np.max(log_ev))
    probs = dict(zip(MODELS, (w / w.sum()).tolist(), strict=True))
    chosen = max(probs, key=lambda m: probs[m])
    theta = fits[chosen]["theta"]
    cov = fits[chosen]["cov"]
    names = _PARAMS[chosen]
    fs = curves.full_scale

    def correct(dn):
        grid = np.linspace(0, curves.irradiance.max() * 1.2, 4001)
        mu, _ = _predict(chosen, jnp.asarray(theta), jnp.asarray(grid), fs)
        return np.interp(np.asarray(dn, dtype=float), np.asarray(mu), theta[0] * grid)

    return {
        "probabilities": probs,
        "chosen": chosen,
        "parameters": dict(zip(names, theta.tolist(), strict=True)),
        "sd": dict(zip(names, np.sqrt(np.diag(cov)).tolist(), strict=True)) if cov is not None else {},
        "correct": correct,
    }


def patent_baseline(curves: NonlinearityCurves, alpha: float = 0.01) -> dict:
    """The patent's decision procedure (steps 5-6) as hypothesis tests.

    Step 5: quadratic term of the (weighted) video response fit significant
    at ``alpha``? Step 6: slope of the PRNU curve against irradiance
    significant at ``alpha``?  Returns the classification and both p-values:
    ``linear``, ``dn_v`` (nonlinear response, flat PRNU) or ``v_q`` (falling
    PRNU; "possibly with DN/V" -- the procedure cannot tell ``both`` apart).

    Examples
    --------
    >>> import numpy as np
    >>> import bayescal as bc
    >>> steps = np.linspace(0.05, 0.9, 10)
    >>> bc.patent_baseline(bc.simulate_curves("dn_v", steps, b=0.1 / 4095, seed=0))["classification"]
    'dn_v'
    >>> bc.patent_baseline(bc.simulate_curves("linear", steps, seed=0))["classification"]
    'linear'
    """
    c = curves
    w = 1 / c.mean_se
    x = np.column_stack([c.irradiance, c.irradiance**2])
    lin = np.linalg.lstsq(x[:, :1] * w[:, None], c.mean_dn * w, rcond=None)
    quad = np.linalg.lstsq(x * w[:, None], c.mean_dn * w, rcond=None)
    sse1 = float(np.sum((c.mean_dn * w - (x[:, :1] * w[:, None]) @ lin[0]) ** 2))
    sse2 = float(np.sum((c.mean_dn * w - (x * w[:, None]) @ quad[0]) ** 2))
    dof = c.irradiance.size - 2
    p_response = float(stats.f.sf((sse1 - sse2) / (sse2 / dof), 1, dof))
    slope = stats.linregress(c.irradiance, c.prnu)
    p_prnu = float(slope.pvalue)
    if p_response >= alpha:
        verdict = "linear"
    elif p_prnu < alpha and slope.slope < 0:
        verdict = "v_q"
    else:
        verdict = "dn_v"
    return {"classification": verdict, "p_response_nonlinear": p_response, "p_prnu_slope": p_prnu}
