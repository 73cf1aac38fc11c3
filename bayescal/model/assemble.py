"""Assemble a numpyro model from components (docs/architecture.md, section 3).

The model function is built once per *structure* (the components, which are
hashable) and takes the data pytree as its only argument, so one compiled
program serves every dataset of the same shape.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from functools import lru_cache

import numpy as np
import numpyro

from bayescal.io.table import MeasurementTable
from bayescal.model import observation
from bayescal.model.components import (
    EFFECTS,
    Component,
    Dark,
    Effect,
    FactorEffect,
    Noise,
    NoiseEffect,
    OffsetEffect,
    Response,
    Saturation,
    SettingFactors,
    Sphere,
    StimulusFactor,
)
from bayescal.model.components.settings import KINDS
from bayescal.model.data import Layout, ModelData, prepare
from bayescal.model.equation import reading
from bayescal.model.spec import ModelSpec

__all__ = ["Parts", "CalibrationModel", "build_model", "numpyro_model"]


@dataclass(frozen=True)
class Parts:
    """The components of one model structure (hashable: a cache key)."""

    response: Response
    dark: Dark
    noise: Noise
    sphere: Sphere
    saturation: Saturation
    settings: SettingFactors
    effects: tuple[Effect, ...] = ()

    @classmethod
    def from_spec(cls, spec: ModelSpec, layout: Layout, level_sigma: np.ndarray, frame=None) -> Parts:
        """Pick and configure the components the spec asks for (the effects the table supports)."""
        n_levels = len(layout.levels)
        effects = () if frame is None else _effects(spec, frame)
        return cls(
            response=Response(spec.response, len(layout.channels)),
            dark=Dark(spec.dark, len(layout.channels), len(layout.gain_values), layout.dn_scale),
            noise=Noise(spec.noise, layout.dn_scale),
            sphere=Sphere(spec.sphere, n_levels, bool(np.any(level_sigma > 0)), len(layout.channels)),
            saturation=Saturation(spec.saturation),
            settings=_settings(spec, layout),
            effects=effects,
        )

    @property
    def components(self) -> tuple[Component, ...]:
        """Every component, in report order."""
        return (self.response, self.dark, self.sphere, self.noise, self.saturation, self.settings, *self.effects)

    @property
    def factors(self) -> tuple[StimulusFactor, ...]:
        """The factors on the effective stimulus besides the settings': the sphere's level errors, the
        factor effects."""
        return (self.sphere, *(e for e in self.effects if isinstance(e, FactorEffect)))

    def sample_offsets(self, data: ModelData):
        """Each offset term's level in the model's units (DN over full scale), sampled in turn: the dark
        level (a core term, sampled in those units), then each offset effect (sampled in DN)."""
        yield self.dark.sample(data)
        for term in self.effects:
            if isinstance(term, OffsetEffect):
                yield term.sample(data) / self.dark.dn_scale

    def sample_variances(self, data: ModelData, signal):
        """Each noise effect's variance in the model's units, sampled in turn."""
        for term in self.effects:
            if isinstance(term, NoiseEffect):
                yield term.variance(data, signal)

    @property
    def structure(self) -> Parts:
        """What the compiled program depends on: these parts with what the data carry left out
        (the nonlinearity's domain, so both domains share one compilation)."""
        return replace(self, response=self.response.structure)

    def describe(self) -> list[str]:
        """Human-readable list of what the model contains."""
        return [c.describe() for c in self.components]


def _effects(spec: ModelSpec, frame) -> tuple[Effect, ...]:
    built = (cls.build(spec.effect(cls.section), spec, frame) for cls in EFFECTS)
    return tuple(e for e in built if e is not None)


def _settings(spec: ModelSpec, layout: Layout) -> SettingFactors:
    ref = {"gain": spec.reference.gain, "exposure": spec.reference.exposure_s, "tdi": spec.reference.tdi_stages}
    sizes, refs = [], []
    for kind in KINDS:
        values = np.asarray(layout.setting_values(kind))
        match = np.flatnonzero(np.isclose(values, ref[kind], rtol=1e-9, atol=0))
        sizes.append((kind, int(values.size)))
        refs.append((kind, int(match[0]) if match.size else -1))
    return SettingFactors(spec.settings, tuple(sizes), tuple(refs))


@lru_cache(maxsize=64)
def numpyro_model(parts: Parts) -> Callable[[ModelData], None]:
    """The numpyro model for one structure (cached, so compilations are reused)::

    DN = dark + offsets + S_g(u * factors) (clipped at full scale) + noise

    ``S_g`` is the response at the row's effective gain ``g`` (its nominal ratio times the
    gain's effective factor): ``S`` itself for a nonlinearity of the output, ``g S(x / g)`` for
    one of the charge (:meth:`~bayescal.model.components.response.Response.coefficients_at`).
    """

    def model(data: ModelData) -> None:
        jnp = _jnp()
        coef = parts.response.sample(data)
        multiplier, gain_factor = parts.settings.sample_with_gain(data)
        row_coef = parts.response.coefficients_at(coef[data.channel], data.g_rel * gain_factor, jnp, charge=data.charge)

        def response(x):
            signal = parts.response.forward(row_coef, x, parts.response.sample_rolloff(), jnp)
            return numpyro.deterministic("row_signal", signal)

        factors = (multiplier, *(f.sample(data) for f in parts.factors))
        expected = reading(data.u, factors, response, parts.sample_offsets(data))
        observation.score(
            parts.noise, parts.saturation, data, expected, tuple(parts.sample_variances(data, expected.signal))
        )

    return model


def _jnp():
    import jax.numpy as jnp

    return jnp


@dataclass(frozen=True)
class CalibrationModel:
    """A spec, a prepared dataset and the assembled numpyro model.

    Examples
    --------
    >>> import bayescal as bc
    >>> spec = bc.load_spec("seed000")
    >>> model = bc.build_model(bc.simulate(spec, bc.load_design("seed000"), seed=1).table, spec)
    >>> model.spec.name == spec.name, len(model.table.frame)
    (True, 192)
    """

    spec: ModelSpec
    table: MeasurementTable
    data: ModelData
    layout: Layout
    parts: Parts

    @property
    def model(self) -> Callable[[ModelData], None]:
        """The numpyro model function (data is its argument)."""
        return numpyro_model(self.parts.structure)

    @property
    def structure_key(self) -> tuple:
        """What determines the compiled program: components and array shapes."""
        return (self.parts.structure, self.layout.shape_key)


def resolve_for_table(spec: ModelSpec, table: MeasurementTable) -> ModelSpec:
    """The spec with its table-dependent options decided: ``dark.drift = "auto"`` is on when the table
    records when each row was measured (``time_s``, two or more moments)."""
    if spec.dark.drift == "auto":
        spec = spec.replace(dark={"drift": "time_s" in table.frame and table.frame["time_s"].nunique() > 1})
    return spec


def build_model(table: MeasurementTable, spec: ModelSpec) -> CalibrationModel:
    """Validate ``table`` against ``spec`` and assemble the model.

    Examples
    --------
    >>> import bayescal as bc
    >>> spec = bc.load_spec("seed000")
    >>> sim = bc.simulate(spec, bc.load_design("seed000"), seed=1)
    >>> model = bc.build_model(sim.table, spec)
    >>> model.layout.channels
    ('R', 'G', 'B')
    """
    spec = resolve_for_table(spec, table)
    data, layout = prepare(table, spec)
    parts = Parts.from_spec(spec, layout, np.asarray(data.level_sigma), table.frame)
    extra = {k: np.asarray(v, dtype=float) for e in parts.effects for k, v in e.inputs(table.frame).items()}
    extra |= parts.response.guides() | parts.dark.guides()
    return CalibrationModel(spec=spec, table=table, data=data._replace(extra=extra), layout=layout, parts=parts)
