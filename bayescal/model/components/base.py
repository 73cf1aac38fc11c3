"""What a component is (docs/architecture.md, section 3).

A component is one physical effect of the measurement equation.  It owns

- its section of the model spec (a frozen dataclass in its own module),
- its numpyro sampling (``sample``: the sites it draws, in the model's scaled units),
- its forward function, written against an array namespace ``xp`` (``jax.numpy`` while
  sampling, ``numpy`` for predictions and simulation), so the physics is written once,
- its conversion of scaled draws to reported quantities in physical units (``physical``),
- the names and dims of its sampled sites and reported quantities (``sites``, ``reported``).

Every component fills a place (its ``role``) in the one skeleton of the measurement equation,
:func:`bayescal.model.equation.reading`::

    DN = sum(offset terms) + R(u f_settings prod(factor terms)) (+ noise, observed through the ADC)

The six core components are the response (``"response"``), the dark level (an ``"offset"``), the
sphere's level errors (a ``"factor"``), the settings' effective factors (``"settings"``), the noise
(``"noise"``) and the ADC's clipping (``"observation"``).  An :class:`Effect` is an optional term
with a spec section of its own, in one of the three open places: a factor on the effective stimulus
(:class:`FactorEffect`), a level added to every reading in DN (:class:`OffsetEffect`, present at zero
exposure and zero light) or a variance added to every reading (:class:`NoiseEffect`).  It is added to
the model by one line in
:data:`bayescal.model.components.EFFECTS`, and the spec, the data, the assembly, the reported
quantities, predictions (:class:`~bayescal.posterior.calibration.Calibration`, through its
:class:`FactorTerm`, :class:`OffsetTerm` or :class:`NoiseTerm`) and the simulator all reach it through
this protocol.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, ClassVar, Literal, Protocol

import numpy as np

if TYPE_CHECKING:
    import pandas as pd

    from bayescal.model.data import Layout, ModelData
    from bayescal.model.setting import Setting
    from bayescal.model.spec import ModelSpec

__all__ = [
    "Component",
    "Context",
    "Effect",
    "FactorEffect",
    "FactorTerm",
    "NoiseEffect",
    "NoiseTerm",
    "Nuisance",
    "OffsetEffect",
    "OffsetTerm",
    "StimulusFactor",
]


@dataclass(frozen=True)
class Nuisance:
    """A sampled site that stands for an imperfection of the bench or the camera the user stated a prior
    for (a sphere level's error, a setting's departure from its label, a drift), checked after a fit
    against that prior (:mod:`bayescal.fitting.nuisance`): a posterior far out in its prior's tail has
    absorbed a misfit rather than measured the imperfection.

    Attributes
    ----------
    sd : float or array
        The prior's standard deviation about 0, in the site's own units (broadcast over its elements).
    what : str
        What one element is, in words, with ``{}`` where the element's label goes.
    dims : tuple of str
        The coordinates (:func:`bayescal.fitting.result` coords) that label the site's elements.
    size : float or array
        Multiplies the site's value into the size messages state (``level_z`` times its level's sigma).
    unit : str
        The unit of that size: ``"%"`` (a relative size, shown in per cent) or a unit's name.
    """

    sd: Any
    what: str
    dims: tuple[str, ...] = ()
    size: Any = 1.0
    unit: str = "%"


@dataclass(frozen=True)
class Context:
    """What the conversion of scaled draws to physical units needs beside the draws."""

    layout: Layout
    level_sigma: np.ndarray
    seed: int

    def rng(self, salt: int) -> np.random.Generator:
        """A generator for the draws a conversion makes (reproducible from the fit's seed)."""
        return np.random.default_rng(np.random.SeedSequence([self.seed, salt]))


class Component(ABC):
    """One physical effect; concrete components are frozen dataclasses (hashable: part of the key of a
    compiled model structure)."""

    #: the component's section of the model spec
    section: ClassVar[str]
    #: its place in the measurement equation (:data:`bayescal.model.equation.ROLES`)
    role: ClassVar[str]
    #: sampled sites -> their dims beyond (chain, draw)
    sites: ClassVar[Mapping[str, tuple[str, ...]]] = {}
    #: reported quantities (physical units) -> their dims beyond (chain, draw), in report order
    reported: ClassVar[Mapping[str, tuple[str, ...]]] = {}

    @abstractmethod
    def describe(self) -> str:
        """One line saying what this component contributes to the model."""

    def nuisances(self, level_sigma: np.ndarray) -> Mapping[str, Nuisance]:
        """Its sampled sites that stand for an imperfection with a stated prior (``level_sigma``: each
        sphere level's relative sd), checked after a fit against that prior (empty: none)."""
        return {}

    def physical(self, draws: Mapping[str, np.ndarray], ctx: Context) -> dict[str, np.ndarray]:
        """Reported quantities from the scaled draws (leading dims chain, draw)."""
        return {}


class StimulusFactor(Component):
    """A multiplicative factor on the effective stimulus: the equation's ``S(x f_1 f_2 ...)``."""

    @abstractmethod
    def sample(self, data: ModelData) -> Any:
        """The factor of every row (a JAX array, or 1.0 when the component adds nothing)."""


class FactorTerm(Protocol):
    """An effect's posterior as predictions use it: its factor per draw at a camera setting."""

    def factor(self, channel: str | None, setting: Setting, n_draws: int) -> np.ndarray:
        """Factor on the effective stimulus per draw at ``setting``, shape ``(n_draws,)``; ``channel``
        names the channel for effects that differ by channel (None: the camera's, or the first)."""
        ...

    def flags(self, setting: Setting) -> list[str]:
        """Why a prediction at ``setting`` extrapolates this effect (empty: it does not)."""
        ...


class OffsetTerm(Protocol):
    """An offset effect's posterior as predictions use it: the DN it adds per draw at a camera setting."""

    def offset(self, channel: str | None, setting: Setting, n_draws: int) -> np.ndarray:
        """DN added to a reading per draw at ``setting``, shape ``(n_draws,)``."""
        ...

    def flags(self, setting: Setting) -> list[str]:
        """Why a prediction at ``setting`` extrapolates this effect (empty: it does not)."""
        ...


class NoiseTerm(Protocol):
    """A noise effect's posterior as predictions use it: the variance it adds to a reading per draw."""

    def variance(self, channel: str | None, setting: Setting, signal: np.ndarray) -> np.ndarray:
        """Variance (DN^2) added to a reading of ``signal`` (DN, the draws on its first axis) at
        ``setting``, broadcast against ``signal``."""
        ...

    def flags(self, setting: Setting) -> list[str]:
        """Why a prediction at ``setting`` extrapolates this effect (empty: it does not)."""
        ...


class Effect(Component):
    """An optional term with a spec section of its own (registered in ``EFFECTS``): a
    :class:`FactorEffect` (a factor on the effective stimulus), an :class:`OffsetEffect` (DN added to
    every reading) or a :class:`NoiseEffect` (variance added to every reading).  Code that treats them
    apart asks which of the classes an effect is."""

    #: the dataclass of its spec section (defaults must describe the effect switched off or automatic)
    spec_class: ClassVar[type]
    #: where it enters the measurement equation: "factor" (on the effective stimulus), "offset" (DN added)
    #: or "noise" (variance added)
    role: ClassVar[Literal["factor", "offset", "noise"]]
    #: keys of older specs that this section now holds: ``"section.key"`` -> its field here
    renamed: ClassVar[Mapping[str, str]] = {}

    @classmethod
    @abstractmethod
    def build(cls, section: Any, spec: ModelSpec, frame: pd.DataFrame) -> Effect | None:
        """The configured component for a table, or None when the model leaves it out (``section``: the
        spec's section of this effect, an instance of :attr:`spec_class`)."""

    def inputs(self, frame: pd.DataFrame) -> dict[str, np.ndarray]:
        """Per-row inputs the component reads from the table (into ``ModelData.extra``)."""
        return {}

    def coords(self) -> dict[str, list]:
        """Coordinates of the dims its sites have beyond the model's own (channel, ...)."""
        return {}

    @classmethod
    def candidates(cls, section: Any, spec: ModelSpec, frame: pd.DataFrame) -> dict[str, dict]:
        """What the diagnosis (:func:`bayescal.fitting.diagnosis.candidates`) may try when a model without
        this effect does not fit ``frame``: a name -> the spec change that adds it, for each form the table
        can measure (empty: none, or it is already in the model)."""
        return {}

    @classmethod
    def term(
        cls, section: Any, spec: ModelSpec, draws: Mapping[str, np.ndarray], frame: pd.DataFrame
    ) -> FactorTerm | OffsetTerm | NoiseTerm | None:
        """The effect in a calibration's predictions, from its reported draws (None: not in them)."""
        return None

    @classmethod
    @abstractmethod
    def truth(cls, params: Mapping[str, Any], rows: pd.DataFrame, spec: ModelSpec) -> np.ndarray:
        """The simulator's value for every row of a simulated table (``params``: the design's
        ``[truth.effects.<section>]`` table; ``rows``: channel, exposure_s, gain, tdi_stages,
        temperature_c of every row)."""


class FactorEffect(Effect, StimulusFactor):
    """An effect that multiplies the effective stimulus: ``sample`` gives each row's factor, ``term`` a
    :class:`FactorTerm`, ``truth`` the simulator's factor (1 where the design gives none)."""

    role: ClassVar[Literal["factor", "offset", "noise"]] = "factor"

    @classmethod
    def term(
        cls, section: Any, spec: ModelSpec, draws: Mapping[str, np.ndarray], frame: pd.DataFrame
    ) -> FactorTerm | None:
        """The factor in a calibration's predictions (None: not in them)."""
        return None

    @classmethod
    def truth(cls, params: Mapping[str, Any], rows: pd.DataFrame, spec: ModelSpec) -> np.ndarray:
        """The simulator's factor (1: the effect is absent from the truth)."""
        return np.ones(len(rows))


class OffsetEffect(Effect):
    """An effect that adds DN to every reading, dark or lit: ``sample`` gives each row's DN (the assembly
    scales it), ``term`` an :class:`OffsetTerm`, ``truth`` the simulator's DN (0 where the design gives
    none)."""

    role: ClassVar[Literal["factor", "offset", "noise"]] = "offset"

    @abstractmethod
    def sample(self, data: ModelData) -> Any:
        """The DN each row's reading gains (a JAX array, in DN: the assembly scales it)."""

    @classmethod
    def term(
        cls, section: Any, spec: ModelSpec, draws: Mapping[str, np.ndarray], frame: pd.DataFrame
    ) -> OffsetTerm | None:
        """The offset in a calibration's predictions (None: not in them)."""
        return None

    @classmethod
    def truth(cls, params: Mapping[str, Any], rows: pd.DataFrame, spec: ModelSpec) -> np.ndarray:
        """The simulator's DN (0: the effect is absent from the truth)."""
        return np.zeros(len(rows))


class NoiseEffect(Effect):
    """An effect that adds variance to every reading, beside the read, shot and quantisation noise and the
    excess scatter of :class:`~bayescal.model.components.noise.Noise`: ``variance`` gives each row's, in the
    model's scaled units, at the row's signal; ``term`` a :class:`NoiseTerm`; ``truth`` the simulator's
    variance in DN^2 (``rows`` then carries each row's true signal, ``signal_dn``; 0 where the design gives
    none).  The observation (:mod:`bayescal.model.observation`) adds it to the reading's variance in the
    model, the predictions and the simulator alike."""

    role: ClassVar[Literal["factor", "offset", "noise"]] = "noise"

    @abstractmethod
    def variance(self, data: ModelData, signal: Any) -> Any:
        """The variance each row's reading gains, in the model's scaled units (DN / full scale)^2, at the
        rows' ``signal`` (same units), sampling the effect's sites."""

    @classmethod
    def term(
        cls, section: Any, spec: ModelSpec, draws: Mapping[str, np.ndarray], frame: pd.DataFrame
    ) -> NoiseTerm | None:
        """The variance in a calibration's predictions (None: not in them)."""
        return None

    @classmethod
    def truth(cls, params: Mapping[str, Any], rows: pd.DataFrame, spec: ModelSpec) -> np.ndarray:
        """The simulator's variance (DN^2) at ``rows["signal_dn"]`` (0: the effect is absent)."""
        return np.zeros(len(rows))
