"""Roll-off towards full scale: the output compressed where a sense node, amplifier or ADC leaves its
linear range (seed 004: the sense node's V/Q and the ADC's DN/V nonlinearity near the top codes).

Two shapes, each a rising map ``S -> S_out`` with ``S_out = S`` below zero and slope 1 at ``S = 0`` (the
small-signal gain is the polynomial's):

``knee``
    ``S / (1 + (S / K)^p)^(1/p)``: a knee ``K`` (the level the output approaches) and its sharpness
    ``p``; two numbers, one family.
``monotone``
    any smooth rising shape: ``S_out = int_0^S exp(-phi(u)) du`` with ``phi(0) = 0``,
    ``phi(u) = w_0 u + w_1 u^2 + sum_j w_j h [softplus((u - c_j) / h) - softplus(-c_j / h)]`` (``u`` as a
    fraction of full scale, hinges at :data:`KNOTS`).  Whatever the weights' signs the slope
    ``exp(-phi)`` stays positive, so the map rises everywhere and has one inverse; positive weights
    compress (an exponential saturation ``T (1 - exp(-S / T))`` is the linear term alone, a tanh starts
    as the square, a knee of any sharpness is followed by the hinges), negative ones expand.  The weights'
    prior is Normal(0, :data:`WEIGHT_SD`): the shape's posterior is nearly Gaussian in
    them, which the Laplace backend needs (log-normal weights left 18 % of its draws far off).  The
    integral is Gauss-Legendre on :data:`NODES` points (a smooth integrand: against adaptive quadrature,
    the shapes of weights drawn at the prior's sd are integrated to 6e-8 of full scale, at three times
    it to 1e-6; 32 nodes doubled the cost of every evaluation for errors no reading can see).

Parameters are stored per draw in signal units (DN in a calibration, the model's scaled units in the
model): ``knee``: ``(K, p)``; ``monotone``: ``(scale, w_0, ..., w_{J+1})`` with ``scale`` the signal of
full scale.
"""

from __future__ import annotations

import numpy as np

__all__ = ["KNOTS", "SHAPES", "compress", "expand", "n_params"]

#: the shapes a roll-off can take
SHAPES = ("knee", "monotone")
#: hinge positions of the monotone shape's slope, as fractions of full scale
KNOTS = (0.3, 0.5, 0.7, 0.9, 1.1)
#: the smooth terms before the hinges: ``u`` and ``u^2``
N_SMOOTH = 2
#: width of each hinge (fraction of full scale): the shortest bend the shape draws
HINGE_WIDTH = 0.08
#: prior sd of each monotone weight (log slope lost per full scale)
WEIGHT_SD = 0.5
#: Gauss-Legendre nodes of the monotone shape's integral
NODES = 16

_T, _A = np.polynomial.legendre.leggauss(NODES)
_T, _A = (_T + 1.0) / 2.0, _A / 2.0  # on [0, 1]


def n_params(shape: str) -> int:
    """Parameters per draw of ``shape`` (scale included for ``monotone``)."""
    return 2 if shape == "knee" else 1 + N_SMOOTH + len(KNOTS)


def _softplus(z, xp):
    return xp.logaddexp(0.0, z)


def log_slope(u, weights, xp=np):
    """``phi(u)`` of the monotone shape (``u``: fraction of full scale; ``weights``
    ``(..., N_SMOOTH + J)`` broadcast against ``u[..., None]``)."""
    knots = xp.asarray(KNOTS)
    hinge = HINGE_WIDTH * (_softplus((u[..., None] - knots) / HINGE_WIDTH, xp) - _softplus(-knots / HINGE_WIDTH, xp))
    smooth = weights[..., 0] * u + weights[..., 1] * u * u
    return smooth + xp.sum(weights[..., N_SMOOTH:] * hinge, axis=-1)


def _monotone(signal, params, xp):
    scale = params[..., 0]
    weights = params[..., 1:]
    u = xp.maximum(signal, 0.0) / scale
    nodes = u[..., None] * xp.asarray(_T)  # (..., NODES)
    slope = xp.exp(-log_slope(nodes, weights[..., None, :], xp))
    out = scale * u * xp.sum(xp.asarray(_A) * slope, axis=-1)
    return xp.where(signal > 0, out, signal)


def _knee(signal, params, xp):
    knee, power = params[..., 0], params[..., 1]
    positive = signal > 0
    ratio = xp.where(positive, signal / knee, 1.0)  # both branches finite: the gradients of each stay finite
    factor = xp.exp(-xp.logaddexp(0.0, power * xp.log(ratio)) / power)  # (1 + ratio^p)^(-1/p), no overflow
    return signal * xp.where(positive, factor, 1.0)


def compress(signal, shape: str, params, xp=np):
    """The output ``S_out`` of a signal ``S`` (``params`` ``(..., P)``, broadcast against ``signal``)."""
    return _knee(signal, params, xp) if shape == "knee" else _monotone(signal, params, xp)


def expand(output: np.ndarray, shape: str, params: np.ndarray) -> np.ndarray:
    """Inverse of :func:`compress`: the signal behind an output (numpy); ``inf`` where no signal reaches
    it (at or above the knee's asymptote)."""
    output = np.asarray(output, dtype=float)
    params = np.asarray(params, dtype=float)
    if shape == "knee":
        knee, power = params[..., 0], params[..., 1]
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            ratio = np.maximum(output, 0.0) / knee
            out = output / (1.0 - ratio**power) ** (1.0 / power)
        return np.where(ratio >= 1.0, np.inf, out)
    # rising: Newton's method kept inside a bracket [lo, hi] that holds the root (bisection where it leaves)
    scale, weights = params[..., 0], params[..., 1:]
    target = np.maximum(output, 0.0)
    cap = 1e3 * scale
    lo = np.zeros(np.broadcast_shapes(target.shape, scale.shape))
    hi = 1e-3 * scale + lo
    for _ in range(24):  # double until the output at hi reaches the target: the root within a factor 2
        short = compress(hi, shape, params) < target
        if not short.any():
            break
        lo = np.where(short, hi, lo)
        hi = np.where(short, np.minimum(2.0 * hi, cap), hi)
    reached = compress(hi, shape, params) >= target
    s = 0.5 * (lo + hi)
    for _ in range(100):
        gap = compress(s, shape, params) - target
        lo, hi = np.where(gap < 0, s, lo), np.where(gap >= 0, s, hi)
        newton = s - gap / np.exp(-log_slope(s / scale, weights))
        s = np.where((newton > lo) & (newton < hi), newton, 0.5 * (lo + hi))
        if np.all(np.abs(gap) <= 1e-10 * scale):
            break
    return np.where(output > 0, np.where(reached, s, np.inf), output)
