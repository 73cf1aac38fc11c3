"""Smooth drifts over a recorded covariate, in both places of the measurement equation.

A real session drifts in ways no list of named laws foresees: a lamp that warms up and settles, a
sensor whose black level creeps as it warms, a sphere whose output sags over an afternoon.  What is
known is the covariate the drift follows (the time each frame was taken, the rows' order, the sensor
temperature) and where it acts:

- **on the effective stimulus** (``[stimulus_drift]``, a factor): the lamp or sphere radiance, or the
  responsivity, changes by the same fraction in every channel, ``x -> x exp(h(tau))``;
- **added to every reading** (``[offset_drift]``, an offset): the black level or the dark signal
  moves by the same DN in every channel, ``DN -> DN + d(tau)``.

Neither has a fixed shape: each is a Gaussian process over the covariate scaled to the session,
``tau = (c - c_min) / (c_max - c_min)``, with a Matern-3/2 kernel (a warm-up that settles quickly has
a kink a smoother kernel does not reach) of a short length scale, in its Hilbert-space form (Solin &
Sarkka 2020; Riutort-Mayol et al. 2023): sines of a box twice the session's length around it, with
non-centred coefficients whose sds follow the kernel's spectral density::

    h(tau) = sum_k s sqrt(S(w_k; l) / L) z_k (phi_k(tau) - phi_k(tau_ref)),   z_k ~ Normal(0, 1)
    phi_k(tau) = sin(w_k (tau - 1/2 + L)),   w_k = k pi / (2 L),   L = 1
    S(w; l) = 12 sqrt(3) / l^3 (3 / l^2 + w^2)^-2,   l = 0.1

``s`` is the drift's prior scale (its sd over the session).  The length scale is fixed, not fitted: the
curve is then linear in its coefficients and the Laplace approximation exact for it, where a fitted
length scale put 98 % of the Laplace draws outside the Gaussian it assumes.  A line, a sag and a warm-up
over the session's first tenth all lie within the process; the sines' box, twice the session, keeps a
transient at the session's edge as reachable as one in its middle (with eight cosines of the
session's own length, the best fit to an exponential warm-up of time constant 0.3 left 65 times the
residual).

``tau_ref`` is where the drift is zero, the state the calibration refers to: over time or the rows'
order, the lamp settled at the session's end and the sensor at its start (as a linear dark drift,
:mod:`.dark`); over temperature, the dark level's reference temperature.  The constant part of a
drift is not identifiable (the sphere's scale and the offsets absorb it), which the reference point
removes.  Predictions at a camera setting carry the factor and offset at the setting's temperature
for a drift over temperature, and none for a drift over time (it belongs to the session, not the
camera).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar, Literal

import numpy as np

from bayescal.errors import SpecError, TableError
from bayescal.io.checks import require_spread
from bayescal.model.components.base import Effect, FactorEffect, Nuisance, OffsetEffect

__all__ = [
    "StimulusDrift",
    "OffsetDrift",
    "DriftSpec",
    "OffsetDriftSpec",
    "DriftTerm",
    "basis",
    "spectral_sd",
    "session_coordinate",
    "COVARIATES",
]

#: the covariates a drift may follow, and what each is in words
COVARIATES = {
    "time_s": "the time each frame was taken (time_s)",
    "order": "the rows' order in the table",
    "temperature_c": "the sensor temperature (temperature_c)",
}


#: half-width of the box the basis lives on, around the session scaled to [-1/2, 1/2] (the Hilbert-space
#: approximation's boundary factor 2: the box is twice the session)
HALF_WIDTH = 1.0
#: the most basis functions a drift may have
MAX_TERMS = 32


def basis(tau, terms: int, tau_ref: float, xp=np):
    """The sines ``phi_k(tau) - phi_k(tau_ref)``, ``k = 1..terms``, shape ``tau.shape + (terms,)``: zero at
    ``tau_ref``, written against the array namespace ``xp``."""
    w = frequencies(terms)
    return xp.sin(w * (tau[..., None] - 0.5 + HALF_WIDTH)) - xp.sin(w * (tau_ref - 0.5 + HALF_WIDTH))


def frequencies(terms: int) -> np.ndarray:
    """The basis's angular frequencies ``w_k = k pi / (2 L)`` (per unit of the session)."""
    return np.pi * np.arange(1, terms + 1) / (2.0 * HALF_WIDTH)


def spectral_sd(lengthscale, terms: int, xp=np):
    """The sd of each basis coefficient for a unit-variance Matern-3/2 process of length scale
    ``lengthscale`` (any leading shape): ``sqrt(S(w_k) / L)``, shape ``lengthscale.shape + (terms,)``."""
    w2 = frequencies(terms) ** 2
    ell = lengthscale[..., None]
    density = 12.0 * np.sqrt(3.0) / ell**3 / (3.0 / ell**2 + w2) ** 2
    return xp.sqrt(density / HALF_WIDTH)


def session_coordinate(frame, over: str) -> np.ndarray:
    """The covariate ``over`` of every row scaled to ``[0, 1]`` over the table."""
    if over == "order":
        return np.arange(len(frame), dtype=float) / max(len(frame) - 1, 1)
    values = frame[over].to_numpy(dtype=float)
    low, high = float(np.nanmin(values)), float(np.nanmax(values))
    return np.where(np.isfinite(values), (values - low) / max(high - low, 1e-300), 0.0)


@dataclass(frozen=True)
class DriftSpec:
    """``[stimulus_drift]`` or ``[offset_drift]``: a smooth drift over one covariate.

    ``enabled``: fit it (``"auto"``: when the table records the covariate at two or more values).
    ``over``: ``"time_s"``, ``"order"`` (the rows as listed are the order of measurement) or
    ``"temperature_c"``.  ``terms``: basis functions (12 reach a warm-up over the first tenth of the
    session; fewer, smoother curves only).  ``prior_scale``: the drift's prior sd over the session, a
    fraction of the stimulus (``[stimulus_drift]``, default 0.03) or DN (``[offset_drift]``, default 5).
    ``lengthscale``: the process's length scale, a fraction of the covariate's range (0.1: a warm-up over
    the session's first tenth is within reach; a line or a sag needs no more).
    ``reference_c``: for a drift over temperature, the temperature the calibration refers to.
    """

    enabled: Literal[True, False, "auto"] = False
    over: Literal["time_s", "order", "temperature_c"] = "time_s"
    terms: int = 12
    prior_scale: float = 0.0  # 0: the effect's own default
    lengthscale: float = 0.1
    reference_c: float = 20.0

    def __post_init__(self) -> None:
        if self.enabled not in (True, False, "auto"):
            raise SpecError(f'drift enabled = {self.enabled!r}; expected true, false or "auto"')
        if self.over not in COVARIATES:
            raise SpecError(f"drift over = {self.over!r}; expected one of {sorted(COVARIATES)}")
        if not 1 <= self.terms <= MAX_TERMS:
            raise SpecError(f"drift terms = {self.terms}; expected 1..{MAX_TERMS} basis functions")
        if not 0.02 <= self.lengthscale <= 10.0:
            raise SpecError(f"drift lengthscale = {self.lengthscale}; expected 0.02..10 (a fraction of the range)")
        if not self.prior_scale >= 0:
            raise SpecError("drift prior_scale must be >= 0 (0: the effect's default)")


@dataclass(frozen=True)
class _Drift(Effect):
    """What both drifts share: the covariate, its reference point, the smooth basis, the coefficients."""

    spec_class = DriftSpec
    #: the prior scale when the spec gives 0, and its unit in words
    default_scale: ClassVar[float]
    unit: ClassVar[str]
    #: where along time or the rows' order the drift is zero (0: the session's start, 1: its end)
    session_reference: ClassVar[float]
    #: the place in the equation, in words
    place: ClassVar[str]

    spec: DriftSpec
    tau_ref: float
    low: float  # the covariate's range over the table (time: seconds; order: rows; temperature: degC)
    high: float

    @property
    def scale(self) -> float:
        return self.spec.prior_scale or self.default_scale

    @property
    def site(self) -> str:
        return f"{self.section}_coef"

    @property
    def z_site(self) -> str:
        return f"{self.section}_z"

    @property
    def input(self) -> str:
        return f"{self.section}.tau"

    @classmethod
    def build(cls, section: DriftSpec, spec, frame):
        if section.enabled is False:
            return None
        if section.enabled == "auto" and (
            section.over == "order" or section.over not in frame or frame[section.over].nunique() < 2
        ):
            return None
        if section.over != "order":
            if section.over not in frame:
                raise TableError(
                    f"{cls.section}.over = '{section.over}' needs a '{section.over}' column", column=section.over
                )
            require_spread(frame[section.over].to_numpy(dtype=float), f"{cls.section}.enabled", section.over)
        values = np.arange(len(frame), dtype=float) if section.over == "order" else frame[section.over].to_numpy(float)
        low, high = float(np.nanmin(values)), float(np.nanmax(values))
        if section.over == "temperature_c":
            tau_ref = (section.reference_c - low) / max(high - low, 1e-300)
        else:
            tau_ref = cls.session_reference
        return cls(section, float(tau_ref), low, high)

    @classmethod
    def candidates(cls, section: DriftSpec, spec, frame) -> dict[str, dict]:
        """Offered over ``time_s`` when the table records two or more times, else over the rows' order
        (not when it is on already)."""
        if section.enabled is True or cls.build(section, spec, frame) is not None:
            return {}
        over = "time_s" if "time_s" in frame and frame["time_s"].nunique() > 1 else "order"
        return {cls.candidate_name(over): {cls.section: {"enabled": True, "over": over}}}

    @classmethod
    def candidate_name(cls, over: str) -> str:
        raise NotImplementedError

    def inputs(self, frame) -> dict[str, np.ndarray]:
        return {self.input: session_coordinate(frame, self.spec.over)}

    def curve(self, data, xp):
        """The drift of every row (sampling its standardised coefficients)."""
        import numpyro
        import numpyro.distributions as dist

        z = numpyro.sample(self.z_site, dist.Normal(0.0, 1.0).expand([self.spec.terms]).to_event(1))
        return basis(data.extra[self.input], self.spec.terms, self.tau_ref, xp) @ (self.coef_sd * z)

    @property
    def coef_sd(self) -> np.ndarray:
        """The prior sd of each basis coefficient, in the spec's unit."""
        return self.scale * spectral_sd(np.asarray(self.spec.lengthscale), self.spec.terms)

    def physical(self, draws, ctx) -> dict[str, np.ndarray]:
        """The basis coefficients, in the spec's unit."""
        return {self.site: self.coef_sd * np.asarray(draws[self.z_site], dtype=float)}

    def coords(self) -> dict[str, list]:
        return {f"{self.section}_term": list(range(1, self.spec.terms + 1))}

    def nuisances(self, level_sigma) -> dict[str, Nuisance]:
        """The drift's standardised coefficients, against its prior scale."""
        what = f"term {{}} of the drift {self.place}"
        unit = "%" if isinstance(self, FactorEffect) else self.unit
        return {self.z_site: Nuisance(1.0, what, (f"{self.section}_term",), self.scale, unit)}

    def describe(self) -> str:
        return (
            f"{self.place}: a smooth drift over {COVARIATES[self.spec.over]}, {self.spec.terms} terms, "
            f"prior scale {self.scale:g} {self.unit}"
        )

    @classmethod
    def term(cls, section: DriftSpec, spec, draws, frame):
        site = f"{cls.section}_coef"
        if site not in draws or section.over != "temperature_c":
            return None  # a drift over the session is the bench's, not the camera's: no term in predictions
        built = cls.build(section, spec, frame)
        coef = np.asarray(draws[site], dtype=float)
        return DriftTerm(coef.reshape(-1, coef.shape[-1]), built.tau_ref, built.low, built.high)


@dataclass(frozen=True)
class StimulusDriftSpec(DriftSpec):
    """``[stimulus_drift]``: as :class:`DriftSpec`.  A lamp that warms up or settles during
    a session whose settings are measured one block after another is absorbed by the settings' effective
    factors and passes every check of the residuals while the coefficients relative to the sphere miss their
    truth.  The data can rarely tell the two structures apart, so the screen of a fit that passes
    (:func:`bayescal.fitting.diagnosis.structure_doubt`) reports the drift's model, whose intervals carry the
    lamp's doubt, whenever it moves a coefficient; a design that repeats a sphere level at the start, the
    middle and the end of the session measures the drift and narrows them."""

    enabled: Literal[True, False, "auto"] = False


@dataclass(frozen=True)
class StimulusDrift(_Drift, FactorEffect):
    """``exp(h(tau))`` on the effective stimulus of every row, the same in every channel."""

    section = "stimulus_drift"
    spec_class = StimulusDriftSpec
    sites = {"stimulus_drift_z": ("stimulus_drift_term",)}
    reported = {"stimulus_drift_coef": ("stimulus_drift_term",)}
    default_scale = 0.03
    unit = "(fraction of the stimulus)"
    session_reference = 1.0  # a lamp warms up and settles: the calibration refers to its settled state
    place = "on the stimulus"

    @classmethod
    def candidate_name(cls, over: str) -> str:
        return f"a stimulus that drifts smoothly over {COVARIATES[over]}, shared by every channel (lamp or sphere)"

    def sample(self, data):
        import jax.numpy as jnp

        return jnp.exp(self.curve(data, jnp))

    @classmethod
    def truth(cls, params, rows, spec) -> np.ndarray:
        """``params``: ``relative`` (a list: the factor at the rows in their order, minus 1) — the simulator's
        drift is given per row, not as a basis."""
        return 1.0 + np.asarray(params.get("relative", np.zeros(len(rows))), dtype=float)


@dataclass(frozen=True)
class OffsetDriftSpec(DriftSpec):
    """``[offset_drift]``: as :class:`DriftSpec`, on by default wherever the table records ``time_s`` (a
    black level that creeps as the sensor settles is the rule, and a linear dark drift alone leaves a
    settling one's start biased: on the independent simulator its A0 missed in 3 of 6 coefficient-fits)."""

    enabled: Literal[True, False, "auto"] = "auto"


@dataclass(frozen=True)
class OffsetDrift(_Drift, OffsetEffect):
    """``d(tau)`` DN added to every reading, the same in every channel."""

    section = "offset_drift"
    spec_class = OffsetDriftSpec
    sites = {"offset_drift_z": ("offset_drift_term",)}
    reported = {"offset_drift_coef": ("offset_drift_term",)}
    default_scale = 5.0
    unit = "DN"
    session_reference = 0.0  # offsets refer to the start of the run, as a linear dark drift's
    place = "added to every reading"

    @classmethod
    def candidate_name(cls, over: str) -> str:
        return f"an offset that drifts smoothly over {COVARIATES[over]}, shared by every channel"

    def sample(self, data):
        import jax.numpy as jnp

        return self.curve(data, jnp)

    @classmethod
    def truth(cls, params, rows, spec) -> np.ndarray:
        """``params``: ``dn`` (a list: the DN added at the rows in their order)."""
        return np.asarray(params.get("dn", np.zeros(len(rows))), dtype=float)


@dataclass(frozen=True)
class DriftTerm:
    """A drift over temperature as predictions use it: coefficients ``(S, K)`` evaluated at a setting's
    temperature (its reference when not given)."""

    coef: np.ndarray
    tau_ref: float
    low: float
    high: float

    def _curve(self, setting) -> np.ndarray:
        temperature = setting.temperature_c
        if temperature is None:
            return np.zeros(self.coef.shape[0])
        tau = np.array((temperature - self.low) / max(self.high - self.low, 1e-300))
        return basis(tau, self.coef.shape[1], self.tau_ref) @ self.coef.T

    def factor(self, channel, setting, n_draws: int) -> np.ndarray:
        return np.exp(self._curve(setting))

    def offset(self, channel, setting, n_draws: int) -> np.ndarray:
        return self._curve(setting)

    def flags(self, setting) -> list[str]:
        t = setting.temperature_c
        if t is not None and not self.low <= t <= self.high:
            return [f"temperature {t:g} degC outside the {self.low:g}-{self.high:g} degC the drift was measured over"]
        return []
