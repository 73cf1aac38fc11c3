"""Response: polynomial in the effective stimulus, linear gain times relative nonlinearity.

Physics: DN = g k L t M R (1 + nonlinearity) + dark (seeds 000 eq. 3-5, 002 eq. 5-6/11).  With
``v = G u`` the linear signal as a fraction of full scale, ``S = v (1 + sum_k eta_k p_k(v))``
(``p_k(0) = 0``, see :mod:`bayescal.model.basis`): the nonlinearity is a function of the signal
level (sense-node V/Q and ADC DN/V nonlinearity, seed 004), so pooling it across colour channels
is physically motivated.  The signal is a polynomial without constant term, ``S(x) = sum_k A_k
x^k`` (the offset is the dark component's): :meth:`Response.signal` evaluates it and
:meth:`Response.inverse` solves it for ``x``, whatever the units of ``A`` and ``x`` (scaled in
the model, physical in predictions and simulation).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any, Literal

import numpy as np

import bayescal.model.components.rolloff as roll
from bayescal.model.basis import response_monomials
from bayescal.model.components.base import Component
from bayescal.model.components.priors import guide_inputs, pooled_normal, scale_prior

__all__ = ["Response", "ResponseSpec"]

#: prior scale of the pooled nonlinearity's spread across channels
ETA_TAU_SD = 0.02
#: the "normal" gain prior's sd, in units of its median: nearly flat (linear-Gaussian when the response is linear)
NORMAL_GAIN_SD_FACTOR = 10.0


#: prior median of the roll-off's knee, as a fraction of full scale
ROLLOFF_KNEE_MEDIAN = 1.5
#: prior log-sd of the roll-off's knee
ROLLOFF_KNEE_LOG_SD = 0.5


@dataclass(frozen=True)
class ResponseSpec:
    """Polynomial response in the effective stimulus x = L t M g (seeds 000 eq. 5, 002 eq. 6/11).

    ``order`` 1 is linear; order p adds a relative nonlinearity of degree p-1
    in the linear signal (fraction of full scale), ``DN = S (1 + n(S))`` with
    ``S = G x`` (docs/architecture.md, section 2).  ``pooled`` partially pools the
    nonlinearity across channels (it is a property of the sense node and ADC,
    shared by all colours); ``gain_prior = "pooled"`` also pools the
    per-channel log gains.  The pooled values are drawn in coordinates whitened
    by what the data alone say of them (:func:`~bayescal.model.components.priors.pooled_normal`,
    guided by the unpooled model's Laplace fit), so NUTS samples them whether the channels agree
    or differ; the Laplace backend refuses them (the Gaussian at the joint mode has no honest
    width for a pooling scale from three channels).  Pooling is off by default: with three
    colour channels and a full radiance sweep it buys little (README, "Pooling channels within
    one camera").  Cameras of a fleet are pooled by :class:`~bayescal.fleet.spec.FleetSpec`
    (``bayescal fleet``).

    Priors, in the model's scaled units (docs/architecture.md, section 5): the gain ``G``
    is the linear signal at the brightest stimulus of the table as a
    fraction of full scale, log-normal with median ``gain_prior_median``
    and log-sd ``gain_prior_log_sd`` (``"normal"``: Normal(median,
    10 median), nearly flat); each nonlinearity coefficient is
    Normal(0, ``nonlinearity_prior_sd``).  The defaults are weakly
    informative; a lab that knows its camera class can say so (the SBC runs
    do, see :mod:`bayescal.validation.sbc`).

    ``nonlinearity_domain`` says where the nonlinearity arises (seed 004's two sources):
    ``"output"`` (DN/V: the amplifier and ADC, after the programmable gain) makes it a
    function of the DN whatever the gain; ``"charge"`` (V/Q: the sense node, before the
    gain) makes it a function of the collected charge, so at gain ``g`` (relative to the
    reference, its effective factor included) the signal is ``g S(x / g)`` and the
    coefficients are ``A_k g^(1-k)`` (:meth:`Response.at_gain`).  With one gain the two are
    the same; with a gain sweep they differ, and ``bayescal select`` compares them by LOO.

    ``rolloff`` adds a smooth compression towards full scale that no polynomial of low order
    follows (a sense node or amplifier leaving its linear range, an ADC's top codes):
    ``S_out = S / (1 + (S / K)^p)^(1/p)`` (:func:`~bayescal.model.components.rolloff.compress`), the same curve in DN at
    every setting, with the knee ``K`` (DN: the level the output approaches; a signal ``S = K``
    reads ``K / 2^(1/p)``) and the sharpness ``p`` posterior quantities.  Priors: ``K / full scale``
    log-normal with median :data:`ROLLOFF_KNEE_MEDIAN` and log-sd :data:`ROLLOFF_KNEE_LOG_SD`
    (a knee at full scale or above: a camera whose roll-off starts low saturates early, which
    the window likelihood handles), ``p - 1`` log-normal with median 3 and log-sd 0.6.
    ``rolloff = "monotone"`` draws any smooth rising shape instead (an exponential saturation, a
    tanh, a knee of any sharpness: :mod:`~bayescal.model.components.rolloff`), its slope's log
    changing by weights with Normal(0, :data:`~bayescal.model.components.rolloff.WEIGHT_SD`)
    priors; ``true`` is ``"knee"``.  Off by
    default: the misfit diagnosis (:mod:`bayescal.fitting.diagnosis`) tries both shapes when the
    data ask for one.
    """

    order: int = 1
    pooled: bool = False
    gain_prior: Literal["lognormal", "normal", "pooled"] = "lognormal"
    gain_prior_median: float = 0.5
    gain_prior_log_sd: float = 2.0
    nonlinearity_prior_sd: float = 0.1
    nonlinearity_domain: Literal["output", "charge"] = "output"
    rolloff: bool | Literal["knee", "monotone"] = False

    @property
    def rolloff_shape(self) -> str | None:
        """The roll-off's shape (``"knee"`` or ``"monotone"``), or None without one."""
        if self.rolloff is False:
            return None
        return "knee" if self.rolloff is True else str(self.rolloff)


@dataclass(frozen=True)
class Response(Component):
    """Per-channel gain and (optionally pooled) nonlinearity of order ``order``."""

    section = "response"
    role = "response"
    sites = {
        "G": ("channel",),
        "eta": ("channel", "nl_term"),
        "logG_mu": (),
        "logG_tau": (),
        "logG": ("channel",),
        "logG_w": ("channel",),
        "logG_mu_w": (),
        "eta_mu": ("nl_term",),
        "eta_tau": ("nl_term",),
        "eta_w": ("channel", "nl_term"),
        "eta_mu_w": ("nl_term",),
        "rolloff_knee": (),
        "rolloff_sharpness": (),
        "rolloff_weight": ("rolloff_term",),
    }
    reported = {
        "gain": ("channel",),
        "gain_rel": ("channel",),
        "A_abs": ("channel", "power"),
        "A_rel": ("channel", "power"),
        "nonlinearity": ("channel", "nl_term"),
        "rolloff_knee_dn": (),
        "rolloff_power": (),
        "rolloff_weights": ("rolloff_term",),
    }

    spec: ResponseSpec
    n_channels: int

    @property
    def n_terms(self) -> int:
        """Number of nonlinearity coefficients per channel."""
        return self.spec.order - 1

    # ------------------------------------------------------------------ physics
    @staticmethod
    def signal(coef, x, xp=np):
        """``S(x) = sum_k A_k x^k`` (no constant term) with ``coef[..., k - 1] = A_k``, broadcast against
        ``x`` (Horner's scheme, which also keeps ``dS/dx`` finite at ``x = 0``)."""
        out = xp.zeros_like(x * coef[..., 0])
        for k in range(coef.shape[-1] - 1, -1, -1):
            out = (out + coef[..., k]) * x
        return out

    @staticmethod
    def forward(coef, x, rolloff=None, xp=np):
        """The response's signal at effective stimulus ``x``: the polynomial :meth:`signal`, then the
        roll-off towards full scale when ``rolloff = (shape, params)`` is given
        (:func:`~bayescal.model.components.rolloff.compress`)."""
        signal = Response.signal(coef, x, xp)
        return signal if rolloff is None else roll.compress(signal, rolloff[0], rolloff[1], xp)

    @staticmethod
    def turning_point(coef: np.ndarray) -> np.ndarray:
        """The first ``x > 0`` where the polynomial :meth:`signal` stops rising, per draw (``coef`` (S, P);
        ``inf`` where it rises for ever).  A sensor's response never falls as the light grows: past this
        point a prediction holds the polynomial's largest value (:meth:`Calibration.signal_dn
        <bayescal.posterior.calibration.Calibration.signal_dn>`) instead of following it down."""
        coef = np.asarray(coef, dtype=float)
        n = coef.shape[-1]
        turn = np.full(coef.shape[:-1], np.inf)
        if n == 1:
            return turn
        slope = coef * np.arange(1, n + 1)  # dS/dx = sum_k k A_k x^(k-1): slope[k] multiplies x^k
        top = slope[..., -1]
        ok = top != 0
        companion = np.zeros(coef.shape[:-1] + (n - 1, n - 1))
        with np.errstate(over="ignore"):
            first = -slope[..., -2::-1] / np.where(ok, top, 1.0)[..., None]
        # a leading coefficient so small against the rest that the companion overflows puts every root
        # beyond any float: the polynomial rises for ever in range
        ok = ok & np.all(np.isfinite(first), axis=-1)
        companion[..., 0, :] = np.where(ok[..., None], first, 0.0)
        if n > 2:
            companion[..., np.arange(1, n - 1), np.arange(n - 2)] = 1.0
        roots = np.linalg.eigvals(companion)
        real = np.abs(roots.imag) <= 1e-9 * np.maximum(np.abs(roots.real), 1e-300)
        positive = np.where(real & (roots.real > 0), roots.real, np.inf).min(axis=-1)
        return np.where(ok, positive, turn)

    @staticmethod
    def inverse(coef: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Root ``x`` of ``S(x) = y`` on the rising branch of the response, per draw (``coef`` (S, P),
        ``y`` (V, S)).

        Order 1 and 2 in closed form (the stable branch of the quadratic through the origin); higher
        orders by Newton's method safeguarded by bisection on a bracket ``lo < x < hi``: a point
        below the reading on the rising branch raises ``lo``, one above it or past the first turning
        point lowers ``hi``, so the root found is the one on the rising branch from the origin, not
        another root beyond a turning point.  A reading above the response's maximum gets the
        turning point (where the signal is largest).
        """
        a1 = coef[None, :, 0]
        if coef.shape[1] == 1:
            return y / a1
        a2 = coef[None, :, 1]
        disc = a1 * a1 + 4.0 * a2 * y
        with np.errstate(invalid="ignore", divide="ignore"):
            turn = np.where(a2 < 0, -a1 / (2.0 * a2), np.inf)
            x = np.where(disc >= 0, 2.0 * y / (a1 + np.sqrt(np.maximum(disc, 0.0))), turn)
        if coef.shape[1] == 2:
            return x
        powers = np.arange(1, coef.shape[1] + 1)
        slope = coef * powers  # coefficients of dS/dx: slope[k] multiplies x^k

        def value_and_slope(v):
            f, df = np.zeros_like(v), np.zeros_like(v)
            for k in range(coef.shape[1] - 1, -1, -1):  # Horner for S (no constant) and for dS/dx
                f = (f + coef[None, :, k]) * v
                df = df * v + slope[None, :, k]
            return f - y, df

        x = y / a1  # the linear root: on the rising branch for a gently nonlinear response
        lo = np.where(y < 0, -np.inf, 0.0)
        hi = np.full_like(x, np.inf)
        for _ in range(100):
            f, df = value_and_slope(x)
            rising = df > 0
            lo = np.where(rising & (f < 0), np.maximum(lo, x), lo)
            hi = np.where(~rising | (f > 0), np.minimum(hi, x), hi)
            with np.errstate(invalid="ignore", divide="ignore"):
                newton = x - f / np.where(rising, df, 1.0)
                # bisect a finite bracket; widen a one-sided one
                mid = np.where(np.isfinite(lo), 0.5 * (lo + hi), hi - 2.0 * np.abs(hi - x) - 1e-300)
            inside = rising & (newton > lo) & (newton < hi)
            fallback = np.where(np.isfinite(hi), mid, 2.0 * np.maximum(x, 1e-300))
            step = np.where(inside, newton, fallback) - x
            x = x + step
            if np.all(np.abs(step) <= 1e-13 * np.maximum(np.abs(x), 1e-300)):
                break
        return x

    @staticmethod
    def at_gain(coef, gain, xp=np):
        """Coefficients of a charge-domain response at effective gain ``gain`` (relative to the
        reference): ``A_k g^(1-k)``, so that ``S_g(x) = g S(x / g)`` (``coef[..., k - 1] = A_k``,
        ``gain`` broadcast against ``coef[..., 0]``)."""
        powers = xp.arange(coef.shape[-1])
        return coef * xp.asarray(gain)[..., None] ** (-powers)

    def coefficients_at(self, coef, gain, xp=np, charge=None):
        """The response's coefficients at effective gain ``gain``: :meth:`at_gain` for a nonlinearity
        of the charge, ``coef`` unchanged for one of the output (or a linear response).

        ``charge`` (the model's data: 1 for the charge, 0 for the output) overrides the spec, so
        both domains share one compiled program: ``A_k g^((1-k) charge)``."""
        if not self.n_terms:
            return coef
        if charge is not None:
            powers = xp.arange(coef.shape[-1])
            return coef * xp.asarray(gain)[..., None] ** (-powers * charge)
        if self.spec.nonlinearity_domain == "charge":
            return self.at_gain(coef, gain, xp)
        return coef

    @property
    def structure(self) -> Response:
        """This component with the domain left to the data (:meth:`coefficients_at`'s ``charge``)."""
        return replace(self, spec=replace(self.spec, nonlinearity_domain="output"))

    # ----------------------------------------------------------------- sampling
    @property
    def pools_gain(self) -> bool:
        """The channels' log gains are pooled."""
        return self.spec.gain_prior == "pooled"

    @property
    def pools_nonlinearity(self) -> bool:
        """The channels' nonlinearity coefficients are pooled."""
        return self.spec.pooled and self.n_channels > 1 and self.n_terms > 0

    def guides(self) -> dict[str, np.ndarray]:
        """Neutral guides of the pooled sites (``ModelData.extra``; see :func:`pooled_normal`)."""
        out = guide_inputs("logG", (self.n_channels,)) if self.pools_gain else {}
        if self.pools_nonlinearity:
            out |= guide_inputs("eta", (self.n_channels, self.n_terms))
        return out

    def sample(self, data):
        """Sample gains ``G`` (C,) and nonlinearity ``eta`` (C, order-1); returns the monomial
        coefficients ``A_1..A_p`` of every channel's signal in the scaled stimulus, (C, p)."""
        import jax.numpy as jnp
        import numpyro
        import numpyro.distributions as dist

        c = self.n_channels
        if self.spec.gain_prior == "lognormal":
            log_median = float(np.log(self.spec.gain_prior_median))
            gain = numpyro.sample("G", dist.LogNormal(log_median, self.spec.gain_prior_log_sd).expand([c]).to_event(1))
        elif self.spec.gain_prior == "pooled":
            tau = numpyro.sample("logG_tau", scale_prior(1.0))
            gain = numpyro.deterministic("G", jnp.exp(pooled_normal("logG", 0.0, 2.0, tau, data, (c,))))
        else:
            median = self.spec.gain_prior_median
            gain = numpyro.sample("G", dist.Normal(median, NORMAL_GAIN_SD_FACTOR * median).expand([c]).to_event(1))
        eta = None
        if self.n_terms:
            k = self.n_terms
            if self.pools_nonlinearity:
                tau = numpyro.sample("eta_tau", scale_prior(ETA_TAU_SD).expand([k]).to_event(1))
                eta = pooled_normal("eta", 0.0, self.spec.nonlinearity_prior_sd, tau, data, (c, k))
            else:
                prior = dist.Normal(0.0, self.spec.nonlinearity_prior_sd).expand([c, k]).to_event(2)
                eta = numpyro.sample("eta", prior)
        return response_monomials(gain, eta, self.spec.order, xp=jnp)[..., 1:]

    def sample_rolloff(self) -> tuple[str, Any] | None:
        """The roll-off's shape and parameters in the model's units (full scale 1: the knee ``(K, p)``,
        the monotone shape ``(1, w_0, ..., w_J)``), or None without one."""
        shape = self.spec.rolloff_shape
        if shape is None:
            return None
        import jax.numpy as jnp
        import numpyro
        import numpyro.distributions as dist

        if shape == "monotone":
            prior = dist.Normal(0.0, roll.WEIGHT_SD).expand([roll.n_params(shape) - 1]).to_event(1)
            weights = numpyro.sample("rolloff_weight", prior)
            return shape, jnp.concatenate([jnp.ones(1), weights])
        knee = numpyro.sample("rolloff_knee", dist.LogNormal(float(np.log(ROLLOFF_KNEE_MEDIAN)), ROLLOFF_KNEE_LOG_SD))
        sharpness = numpyro.sample("rolloff_sharpness", dist.LogNormal(float(np.log(3.0)), 0.6))
        return shape, jnp.stack([knee, 1.0 + sharpness])

    @staticmethod
    def rolloff_params(draws: dict, spec) -> np.ndarray | None:
        """The roll-off's parameters per draw in DN (:mod:`~bayescal.model.components.rolloff`) from the
        reported draws (:meth:`physical`, flattened to ``(S, ...)``) of a model ``spec``, or None without one."""
        if "rolloff_knee_dn" in draws:
            return np.stack([draws["rolloff_knee_dn"], draws["rolloff_power"]], axis=-1)
        if "rolloff_weights" in draws:
            weights = np.asarray(draws["rolloff_weights"], dtype=float)
            return np.concatenate([np.full((weights.shape[0], 1), float(spec.full_scale)), weights], axis=-1)
        return None

    # ---------------------------------------------------------------- reporting
    def describe(self) -> str:
        out = f"response: order {self.spec.order}"
        if self.n_terms:
            out += f", nonlinearity of the {self.spec.nonlinearity_domain}" + (", pooled" if self.spec.pooled else "")
        if self.spec.rolloff_shape == "monotone":
            out += ", monotone roll-off towards full scale (any smooth shape)"
        elif self.spec.rolloff_shape:
            out += ", soft roll-off towards full scale"
        return out

    def physical(self, draws, ctx) -> dict[str, np.ndarray]:
        """Monomials ``A_rel`` (DN per stimulus unit^k at the reference setting; ``A0`` left 0, the dark
        component's) relative to the sphere's scale (what its readings say), and the nonlinearity.
        :mod:`bayescal.model.physical` adds ``A0`` and folds in the sphere's common scale."""
        layout = ctx.layout
        coef_u = response_monomials(draws["G"], draws.get("eta"), self.spec.order)
        coef = coef_u * layout.dn_scale / layout.x_scale ** np.arange(self.spec.order + 1)
        out = {"A_rel": coef, "gain_rel": coef[..., 1]}
        if "eta" in draws:
            out["nonlinearity"] = draws["eta"]
        if "rolloff_knee" in draws:
            out["rolloff_knee_dn"] = draws["rolloff_knee"] * layout.dn_scale
            out["rolloff_power"] = 1.0 + draws["rolloff_sharpness"]
        if "rolloff_weight" in draws:
            out["rolloff_weights"] = draws["rolloff_weight"]
        return out
