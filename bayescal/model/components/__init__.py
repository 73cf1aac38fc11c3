"""Model components: one physical effect each (docs/architecture.md, section 3).

Roles in the measurement equation (docs/architecture.md, section 2)::

    DN = dark(gain, t, T) + S(x (1 + e_level) f_gain f_exposure f_tdi f_effects) (clipped at full scale) + noise

The six core components fill their places in it; the optional effects in :data:`EFFECTS` are
further factors on the effective stimulus or levels added to the reading (their ``role``), each
configured from a spec section of its own.
Adding an effect is its module, its tests and one line here (see :mod:`.base`).
"""

from collections.abc import Mapping
from typing import Any

import numpy as np

from bayescal.model.components.base import (
    Component,
    Context,
    Effect,
    FactorEffect,
    FactorTerm,
    NoiseEffect,
    NoiseTerm,
    OffsetEffect,
    OffsetTerm,
    StimulusFactor,
)
from bayescal.model.components.dark import Dark, DarkSpec, DarkTerm
from bayescal.model.components.drift import OffsetDrift, StimulusDrift
from bayescal.model.components.frame_offset import FrameOffset
from bayescal.model.components.glow import Glow
from bayescal.model.components.lamp_colour import LampColour
from bayescal.model.components.noise import Noise, NoiseSpec
from bayescal.model.components.offset_temperature import OffsetTemperature
from bayescal.model.components.response import Response, ResponseSpec
from bayescal.model.components.responsivity import ResponsivityTemperature
from bayescal.model.components.saturation import Saturation, SaturationSpec
from bayescal.model.components.scatter import RelativeScatter
from bayescal.model.components.settings import SettingFactors, SettingsSpec
from bayescal.model.components.shutter import ShutterOffset
from bayescal.model.components.sphere import Sphere, SphereSpec
from bayescal.model.components.stray import StrayLight

__all__ = [
    "CORE",
    "EFFECTS",
    "Component",
    "FactorEffect",
    "NoiseEffect",
    "NoiseTerm",
    "OffsetEffect",
    "Context",
    "Dark",
    "DarkSpec",
    "Effect",
    "FactorTerm",
    "Noise",
    "NoiseSpec",
    "OffsetTerm",
    "Response",
    "ResponseSpec",
    "Saturation",
    "SaturationSpec",
    "SettingFactors",
    "SettingsSpec",
    "Sphere",
    "SphereSpec",
    "StimulusFactor",
    "effect",
    "effect_terms",
    "offset_terms",
    "reported_dims",
    "site_dims",
]

#: the core components, in the order their quantities are reported
CORE: tuple[type[Component], ...] = (Response, Dark, Sphere, Noise, Saturation, SettingFactors)

#: the optional effects with a spec section of their own: factors on the effective stimulus, or offsets (their role)
EFFECTS: tuple[type[Effect], ...] = (
    ResponsivityTemperature,
    ShutterOffset,
    OffsetTemperature,
    Glow,
    StimulusDrift,
    OffsetDrift,
    RelativeScatter,
    StrayLight,
    FrameOffset,
    LampColour,
)


def effect(section: str) -> type[Effect]:
    """The registered effect whose spec section is ``section``."""
    return {e.section: e for e in EFFECTS}[section]


def effect_terms(spec: Any, draws: Mapping[str, np.ndarray], frame: Any, kind: type) -> tuple[Any, ...]:
    """The effects of one kind (:class:`FactorEffect`, :class:`OffsetEffect` or :class:`NoiseEffect`) in a
    calibration's predictions, from the reported draws ``(chain, draw, ...)`` and the table they were
    fitted to (:meth:`Effect.term`: a :class:`FactorTerm`, :class:`OffsetTerm` or :class:`NoiseTerm`)."""
    terms = (c.term(spec.effect(c.section), spec, draws, frame) for c in EFFECTS if issubclass(c, kind))
    return tuple(t for t in terms if t is not None)


def offset_terms(
    spec: Any, draws: Mapping[str, np.ndarray], channels: tuple[str, ...], gains: tuple[float, ...], frame: Any
) -> tuple[DarkTerm, tuple[OffsetTerm, ...]]:
    """The terms a calibration adds to every reading, from the reported draws ``(chain, draw, ...)``: the
    dark level (``gains``: the gain of each fitted dark column) and the offset effects."""
    return Dark.term(spec, draws, channels, gains), effect_terms(spec, draws, frame, OffsetEffect)


def site_dims() -> Mapping[str, tuple[str, ...]]:
    """Every component's sampled sites and their dims (beyond chain, draw)."""
    return {name: dims for c in CORE + EFFECTS for name, dims in c.sites.items()}


def reported_dims() -> Mapping[str, tuple[str, ...]]:
    """Every component's reported quantities and their dims, in report order."""
    return {name: dims for c in CORE + EFFECTS for name, dims in c.reported.items()}
