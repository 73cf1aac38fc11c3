"""Model specifications: which components a calibration model is assembled from.

A spec is a small tree of frozen dataclasses, loadable from TOML (``models/``)
or built in Python.  Turning a component off (``order = 1``,
``per_level_rel = 0``, ``excess_dn = 0``, ``censor = false``) removes its
parameters from the model: model only what the scene needs (docs/architecture.md
section 1).
"""

from __future__ import annotations

import dataclasses
import hashlib
import os
from dataclasses import dataclass, field
from typing import Any, Literal

from bayescal.errors import SpecError
from bayescal.io.limits import limit
from bayescal.io.toml import build, dumps, read_toml
from bayescal.model import kinds, plugins
from bayescal.model.components import EFFECTS
from bayescal.model.components.dark import DarkSpec
from bayescal.model.components.noise import NoiseSpec
from bayescal.model.components.response import ResponseSpec
from bayescal.model.components.saturation import SaturationSpec
from bayescal.model.components.settings import SettingsSpec
from bayescal.model.components.sphere import SphereSpec

__all__ = [
    "ModelSpec",
    "Reference",
    "ResponseSpec",
    "DarkSpec",
    "NoiseSpec",
    "SphereSpec",
    "SaturationSpec",
    "SettingsSpec",
    "InferenceSpec",
    "section_names",
    "section_class",
    "load_spec",
]


@dataclass(frozen=True)
class Reference:
    """Setting at which the papers' monomial coefficients DN = A0 + A1 L + ... are reported.

    Seed 000 Table 1 uses gain 1, 1/250 s; seed 002 eq. 9-10 use M = 48,
    T_int = 105 us, g = 1.

    Attributes
    ----------
    exposure_s : float
        The reference exposure (or TDI line) time, s.
    gain : float
        The reference programmable gain factor.
    tdi_stages : float
        The reference number of TDI stages M (1 for an area sensor).

    Examples
    --------
    >>> import bayescal as bc
    >>> bc.Reference(0.004)  # 4 ms at unit gain, no TDI: the setting the coefficients refer to
    Reference(exposure_s=0.004, gain=1.0, tdi_stages=1.0)
    """

    exposure_s: float
    gain: float = 1.0
    tdi_stages: float = 1.0


@dataclass(frozen=True)
class InferenceSpec:
    """Sampler settings and the thresholds a fit must pass (docs/architecture.md, section 4).

    ``laplace_integrate``: the ``laplace`` backend integrates the excess
    scatter numerically (one-dimensional nested Laplace) instead of fixing it
    at the joint mode, which under-states every coefficient's sd by ~10 %.

    NUTS runs in coordinates whitened by the Laplace covariance at the mode,
    where the posterior is close to isotropic: a diagonal metric and 500
    warmup iterations suffice there (a dense metric measured ~3x slower per
    draw with no gain in ESS on the seed 000 model).

    ``misfit_*``: when the model is judged not to fit its data
    (:mod:`bayescal.fitting.misfit`): excess scatter over this many noise floors,
    a group of rows whose residuals sum to more than ``misfit_group_z``
    sds, residual runs along the signal below ``misfit_runs_z`` (0 turns a
    check off).  ``holdout_check``: leave each setting's rows out in turn and
    compare them with what the other rows predict (:mod:`bayescal.fitting.holdout`;
    one warm Laplace refit per setting group, run by ``fit``).

    ``retry_target_accept``: a NUTS run with divergent transitions is run
    again (new chains) with this target acceptance, i.e. smaller steps, and
    the retry is recorded in the diagnostics; divergences left after it get one
    last run at 0.99 when they are at most 2 % of the draws
    (:data:`bayescal.inference.chains.LAST_RETRY_ACCEPT`); the last run's
    own diagnostics decide the verdict (0 turns retrying off).  On 200 simulated 8-bit,
    2-12 DN datasets, 0.8 left 8 fits with 1-7 divergences; 0.95 left none.  The pooled
    seed-000 channels (``pooled = true``) leave 2-6 at 0.95 and none at 0.99.

    Attributes
    ----------
    chains, draws, warmup : int
        NUTS (and BlackJAX) chains, draws kept per chain, and warmup iterations per chain.
    target_accept : float
        NUTS's target acceptance probability (higher: smaller steps, fewer divergences, slower).
    max_tree_depth : int
        NUTS's largest tree: at most 2^depth leapfrog steps per draw.
    dense_mass : bool
        Adapt a dense mass matrix (the whitened coordinates make a diagonal one enough).
    laplace_draws : int
        Draws taken from the Laplace approximation (the ``laplace`` backend's posterior sample).
    emcee_walkers, emcee_steps, emcee_burn : int
        The emcee cross-check: walkers (0: twice the parameters, at least 32), steps, and steps discarded.
    max_rhat : float
        A fit fails when some reported quantity's R-hat exceeds this.
    min_ess : float
        A fit fails when some reported quantity's bulk or tail effective sample size is below this.
    """

    chains: int = 4
    draws: int = 1000
    warmup: int = 500
    target_accept: float = 0.8
    retry_target_accept: float = 0.95
    max_tree_depth: int = 10
    dense_mass: bool = False
    laplace_draws: int = 4000
    laplace_integrate: bool = True
    emcee_walkers: int = 0
    emcee_steps: int = 6000
    emcee_burn: int = 2000
    max_rhat: float = 1.01
    min_ess: float = 400.0
    misfit_excess_ratio: float = 10.0
    misfit_group_z: float = 4.0
    misfit_runs_z: float = -4.0
    holdout_check: bool = True


@dataclass(frozen=True)
class ModelSpec:
    """A full calibration model: sensor facts plus the components to assemble.

    Attributes
    ----------
    name, description : str
        Identification for reports.
    bits : int
        ADC bit depth; full scale is ``2**bits - 1`` DN.
    stimulus : {"radiance", "irradiance"}
        What the table's stimulus column holds.
    reference : Reference
        Setting for the papers' coefficient table.
    effects : tuple of (str, section)
        The sections of the optional effects (:data:`bayescal.model.components.EFFECTS`), one per
        registered effect, by section name (``[responsivity]`` in TOML); :meth:`effect` reads one.
    sections : tuple of (str, section)
        The sections that packages above the model own (:func:`section_names`: ``[fleet]``), as given;
        :meth:`section` reads one (its defaults where not given), ``spec.fleet`` the fleet's.

    Examples
    --------
    >>> import bayescal as bc
    >>> spec = bc.load_spec("seed000")
    >>> spec.bits, spec.response.order
    (12, 2)
    >>> spec.replace(response={"order": 1}).response.order  # a changed copy; the spec itself is unchanged
    1
    """

    name: str
    bits: int
    reference: Reference
    description: str = ""
    stimulus: Literal["radiance", "irradiance"] = "radiance"
    response: ResponseSpec = field(default_factory=ResponseSpec)
    dark: DarkSpec = field(default_factory=DarkSpec)
    noise: NoiseSpec = field(default_factory=NoiseSpec)
    sphere: SphereSpec = field(default_factory=SphereSpec)
    saturation: SaturationSpec = field(default_factory=SaturationSpec)
    settings: SettingsSpec = field(default_factory=SettingsSpec)
    inference: InferenceSpec = field(default_factory=InferenceSpec)
    effects: tuple[tuple[str, Any], ...] = ()
    sections: tuple[tuple[str, Any], ...] = ()

    def __post_init__(self) -> None:
        given = dict(self.effects)
        unknown = set(given) - {e.section for e in EFFECTS}
        if unknown:
            raise SpecError(f"unknown effect section(s) {sorted(unknown)}; registered: {[e.section for e in EFFECTS]}")
        # every registered effect has its section (its defaults where not given), in registry order
        object.__setattr__(self, "effects", tuple((e.section, given.get(e.section, e.spec_class())) for e in EFFECTS))
        _check_spec(self)

    def effect(self, section: str) -> Any:
        """The spec section of the optional effect named ``section``."""
        return dict(self.effects)[section]

    def section(self, name: str) -> Any:
        """The registered section ``name`` (:func:`section_names`) (its defaults where the spec does not give it)."""
        given = dict(self.sections)
        return given[name] if name in given else section_class(name)()

    @property
    def fleet(self) -> Any:
        """The ``[fleet]`` section (:class:`bayescal.fleet.spec.FleetSpec`)."""
        return self.section("fleet")

    @property
    def full_scale(self) -> float:
        """Largest DN the ADC can output."""
        return float(2**self.bits - 1)

    @classmethod
    def from_dict(cls, data: dict[str, Any], *, source: str = "<dict>") -> ModelSpec:
        """Build a spec from nested dicts (the TOML layout); unknown keys are errors."""
        data = _renamed(dict(data))
        if "effects" in data:
            raise SpecError(f"{source}: unknown key 'effects'; an effect is its own table, e.g. [responsivity]")
        effects = tuple(
            (e.section, build(e.spec_class, data.pop(e.section), source, e.section + "."))
            for e in EFFECTS
            if e.section in data
        )
        sections = tuple(
            (name, build(section_class(name), data.pop(name), source, name + "."))
            for name in section_names()
            if name in data
        )
        spec = build(cls, data, source)
        return dataclasses.replace(spec, effects=effects, sections=sections) if effects or sections else spec

    def to_dict(self) -> dict[str, Any]:
        """Nested dict in the TOML layout."""
        out = {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.name not in ("effects", "sections")}
        out = {k: dataclasses.asdict(v) if _instance(v) else v for k, v in out.items()}
        return out | {name: dataclasses.asdict(section) for name, section in self.effects + self.sections}

    def to_toml(self) -> str:
        """Serialise as TOML (round-trips through :func:`load_spec`)."""
        return dumps(self.to_dict())

    def replace(self, **sections: Any) -> ModelSpec:
        """Copy with sections replaced; a dict value updates that section's fields.

        ``spec.replace(response={"order": 2}, sphere={"per_level_rel": 0})``
        """
        changes, effects, owned = {}, dict(self.effects), dict(self.sections)
        for key, value in sections.items():
            if key in effects:
                current = effects[key]
            elif key in section_names():
                current = self.section(key)
            else:
                current = getattr(self, key)
            if isinstance(value, dict) and _instance(current):
                value = dataclasses.replace(current, **value)
            if key in effects:
                effects[key] = value
            elif key in section_names():
                owned[key] = value
            else:
                changes[key] = value
        return dataclasses.replace(self, **changes, effects=tuple(effects.items()), sections=tuple(owned.items()))

    def structure_key(self) -> str:
        """Hash of everything that changes the model's structure (not sampler settings)."""
        d = self.to_dict()
        for key in ("name", "description", "inference", *section_names()):
            d.pop(key, None)
        return hashlib.sha1(dumps(d).encode()).hexdigest()[:16]


def section_names() -> tuple[str, ...]:
    """The spec sections that packages above the model own (``[fleet]``), registered through the package
    metadata (:mod:`bayescal.model.plugins`)."""
    return plugins.names(plugins.SECTION_GROUP)


def section_class(name: str) -> type:
    """The dataclass of the registered section ``name`` (:func:`section_names`)."""
    return plugins.load(plugins.SECTION_GROUP, name, "spec section")


def _renamed(data: dict[str, Any]) -> dict[str, Any]:
    """The TOML layout with the keys that moved into an effect's own section moved there (``Effect.renamed``),
    so specs written before, such as a saved posterior's, still read; the new key wins where both are given."""
    for e in EFFECTS:
        for old, key in e.renamed.items():
            section, name = old.split(".")
            if isinstance(data.get(section), dict) and name in data[section]:
                data[section] = dict(data[section])
                value = data[section].pop(name)
                given = dict(data.get(e.section, {})) if isinstance(data.get(e.section), dict) else {}
                if key in given and given[key] != value:
                    raise SpecError(
                        f"{old} = {value!r} and {e.section}.{key} = {given[key]!r} contradict each other; "
                        f"{old} is the older name of {e.section}.{key}: keep one of them"
                    )
                data[e.section] = {key: value} | given
    return data


def _instance(value: Any) -> bool:
    """A dataclass instance (a spec section), not a dataclass type."""
    return dataclasses.is_dataclass(value) and not isinstance(value, type)


def load_spec(path: str | os.PathLike) -> ModelSpec:
    """Load a model spec from a TOML file (see ``models/*.toml``): a :class:`ModelSpec`, or the spec of
    the kind the file names (``kind = "film"``, :mod:`bayescal.model.kinds`).  ``path`` may also name a
    shipped spec (``"seed000"``: :func:`bayescal.io.resources.example_path`).

    Examples
    --------
    >>> import bayescal as bc
    >>> spec = bc.load_spec("seed000")  # a shipped spec by name, or the path of your own TOML
    >>> spec.response.order, spec.full_scale
    (2, 4095.0)
    """
    from bayescal.io.resources import example_path

    path = example_path(path, "spec")
    data = read_toml(path, "model spec (TOML)")
    kind = data.pop("kind", kinds.CALIBRATION)
    if kind != kinds.CALIBRATION:
        return kinds.get(str(kind)).spec_from_dict(data, str(path))
    return ModelSpec.from_dict(data, source=str(path))


def _non_finite(obj, prefix: str = "") -> str | None:
    """The dotted key of the first NaN or infinite number in a spec's sections (its effects' and the
    sections owned above the model included), or None."""
    import math

    for f in dataclasses.fields(obj):
        value = getattr(obj, f.name)
        key = f"{prefix}{f.name}"
        if f.name in ("effects", "sections") and isinstance(value, tuple):
            found = next(
                (x for x in (_non_finite(sec, f"{name}.") for name, sec in value if _instance(sec)) if x), None
            )
        elif _instance(value):
            found = _non_finite(value, key + ".")
        elif isinstance(value, float) and not math.isfinite(value):
            found = f"{key} = {value}"
        else:
            found = None
        if found:
            return found
    return None


def _check_spec(spec: ModelSpec) -> None:
    bad = _non_finite(spec)
    if bad:
        raise SpecError(f"{bad}; expected a finite number")
    checks = [
        (1 <= spec.bits <= 24, f"bits = {spec.bits}; expected 1..24"),
        (1 <= spec.response.order <= 4, f"response.order = {spec.response.order}; expected 1..4 (the papers' range)"),
        (spec.reference.exposure_s > 0, "reference.exposure_s must be > 0"),
        (spec.reference.gain > 0, "reference.gain must be > 0"),
        (spec.reference.tdi_stages >= 1, "reference.tdi_stages must be >= 1"),
        (0 <= spec.sphere.common_rel < 0.5, "sphere.common_rel must be in [0, 0.5)"),
        (0 <= spec.sphere.per_level_rel < 0.5, "sphere.per_level_rel must be in [0, 0.5)"),
        (0 <= spec.sphere.channel_level_rel < 0.5, "sphere.channel_level_rel must be in [0, 0.5)"),
        (0 <= spec.sphere.channel_scale_rel < 0.5, "sphere.channel_scale_rel must be in [0, 0.5)"),
        (spec.noise.read_noise_dn > 0, "noise.read_noise_dn must be > 0"),
        (spec.noise.conversion_gain > 0, "noise.conversion_gain must be > 0"),
        (spec.noise.excess_dn >= 0, "noise.excess_dn must be >= 0"),
        (
            0 <= spec.saturation.margin_dn < spec.full_scale / 2,
            f"saturation.margin_dn = {spec.saturation.margin_dn}; expected >= 0 and below half the full scale",
        ),
        (not spec.dark.temperature or spec.dark.exposure_slope, "dark.temperature needs dark.exposure_slope = true"),
        (spec.dark.doubling_c > 0 and spec.dark.doubling_rel_sd > 0, "dark.doubling_c and doubling_rel_sd must be > 0"),
        (
            limit("doubling_c").holds(spec.dark.doubling_c),
            f"dark.doubling_c; expected {limit('doubling_c').describe()}",
        ),
        (
            limit("temperature_c").holds(spec.dark.temperature_ref_c),
            f"dark.temperature_ref_c = {spec.dark.temperature_ref_c}; expected {limit('temperature_c').describe()}",
        ),
        (
            limit("exposure_s").holds(spec.reference.exposure_s),
            f"reference.exposure_s; expected {limit('exposure_s').describe()}",
        ),
        (spec.saturation.prnu >= 0, "saturation.prnu must be >= 0"),
        (spec.saturation.prnu_log_sd > 0, "saturation.prnu_log_sd must be > 0"),
        (spec.saturation.prnu_bound >= 0, "saturation.prnu_bound must be >= 0"),
        (spec.dark.drift_prior_dn > 0, "dark.drift_prior_dn must be > 0"),
        (
            all(
                0 <= getattr(spec.settings, k) < 0.5 for k in ("gain_tolerance", "exposure_tolerance", "tdi_tolerance")
            ),
            "settings tolerances must be in [0, 0.5) (relative standard deviations; 0: exact)",
        ),
        (spec.response.gain_prior_median > 0, "response.gain_prior_median must be > 0"),
        (spec.response.gain_prior_log_sd > 0, "response.gain_prior_log_sd must be > 0"),
        (spec.response.nonlinearity_prior_sd > 0, "response.nonlinearity_prior_sd must be > 0"),
        (spec.dark.offset_prior_sd > 0, "dark.offset_prior_sd must be > 0"),
        (spec.dark.slope_prior_sd > 0, "dark.slope_prior_sd must be > 0"),
        (spec.inference.chains >= 1 and spec.inference.draws >= 10, "inference needs chains >= 1 and draws >= 10"),
        (spec.inference.warmup >= 10, f"inference.warmup = {spec.inference.warmup}; expected >= 10"),
        (1 <= spec.inference.max_tree_depth <= 15, "inference.max_tree_depth must be in 1..15"),
        (spec.inference.laplace_draws >= 10, "inference.laplace_draws must be >= 10"),
        (spec.inference.emcee_walkers >= 0, "inference.emcee_walkers must be >= 0 (0: automatic)"),
        (spec.inference.emcee_steps >= 10 and spec.inference.emcee_burn >= 0, "inference.emcee_steps >= 10, burn >= 0"),
        (spec.inference.max_rhat > 1.0, "inference.max_rhat must be > 1"),
        (spec.inference.min_ess > 0, "inference.min_ess must be > 0"),
        (0 < spec.inference.target_accept < 1, "inference.target_accept must be in (0, 1)"),
        (0 <= spec.inference.retry_target_accept < 1, "inference.retry_target_accept must be in [0, 1)"),
    ]
    for ok, message in checks:
        if not ok:
            raise SpecError(message)
