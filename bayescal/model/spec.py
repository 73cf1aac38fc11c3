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
from bayescal.io.toml import build, dumps, read_toml
from bayescal.model import kinds
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
    "FleetSpec",
    "load_spec",
]


@dataclass(frozen=True)
class Reference:
    """Setting at which the papers' monomial coefficients DN = A0 + A1 L + ... are reported.

    Seed 000 Table 1 uses gain 1, 1/250 s; seed 002 eq. 9-10 use M = 48,
    T_int = 105 us, g = 1.
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
class FleetSpec:
    """The hierarchy over a fleet of cameras of one type (docs/architecture.md, section 8).

    Per channel, a camera's log gain, offset and nonlinearity are its type's
    mean plus a camera effect shared by its channels plus a channel-within-
    camera deviation, each Normal with a fitted spread (``pooling``: ``partial``;
    ``none`` fits every camera on its own; ``complete`` makes the cameras one).
    With campaigns at two or more dates, log gain and offset drift: a trend per
    camera, its rate drawn from the fleet's (mean and spread fitted), plus a
    random walk (``walk``) whose diffusion is fitted, plus each campaign's own state of
    the camera (``jitter``: a remount, a thermal state; Normal, its spread fitted, prior
    HalfNormal(``jitter_prior``)).  ``sphere``: the sphere's
    common scale error, a factor on every gain of one campaign
    (``per_campaign``: recalibrated between campaigns) or of all
    (``shared``: one calibration for every campaign), log-normal with the
    spec's ``[sphere] common_rel``.

    Hyperpriors, in units of the spread of the units' estimates of each
    quantity (so they adapt to gains and offsets alike): spreads
    HalfNormal(``spread_prior``), the mean drift rate Normal(0,
    ``rate_prior``) per year, the rates' spread HalfNormal(``rate_prior``) per
    year and the walk's diffusion HalfNormal(``walk_prior``) per sqrt(year).

    ``excess``: each unit's stage-one covariance is scaled, per quantity kind, by a
    fitted ``kappa = 1 + HalfNormal(excess_prior)`` where the channels move together and
    by another where they differ (``T Sigma T``, :mod:`bayescal.fleet.model`): when the
    channel model does not describe a camera exactly, a unit's own intervals are too
    narrow, and the scatter of the units about the hierarchy says by how much and in which
    direction (the fleet's intervals widen; ``sqrt(kappa)`` is reported, and a widening of
    a unit's own interval of a channel by over 3x fails the fit).  One factor for both
    directions over-widened the gains: on one fleet of the independent simulator the
    channels' differences needed 1.4-3.1x, their common part 0.4-1.5x (that part carries the
    sphere's lamp-level errors, shared by a campaign's units, so one fleet sees it 3 times;
    over 12 fleets a unit's gain errors are 1.16x their claimed sd).
    ``excess_together_prior`` replaces ``excess_prior`` where the channels move together in
    a kind that has a campaign jitter (the log gain and offset with ``drift`` and
    ``jitter``): there the excess and the jitter each add one variance per unit to the same
    value, and the data cannot tell them apart (on 5-camera fleets of the independent
    simulator that factor's posterior was its prior, ``sqrt(kappa)`` 1.44 [1.03, 2.20], and
    it widened the fleet's gain and offset intervals 1.4x for nothing). The jitter is the
    physical reading (the unit's state in that campaign, carried into predictions), so the
    excess there is held near 1; where the data can tell (the channels apart, the
    nonlinearity) ``excess_prior`` stays.

    ``shared_error``: the fraction of a unit's stage-one error variance that repeats in
    every campaign of its camera (the same channel model's systematic misfit of the same
    camera): a camera-level error term carries it, so three campaigns do not shrink a
    camera's interval by sqrt(3) when their errors are not independent (0: independent).
    On the independent fleet simulator, 0 gave 95 % intervals of the offsets that covered
    0.83-0.93.

    ``campaign_sd``: a common effect on every log gain measured in one campaign (Normal,
    this sd) beside the sphere's: a fleet that does not age along the straight line (it
    settles), or a bench that differs between campaigns beyond the sphere's scale. Without
    it the line ties the sphere's per-campaign errors together and biased them (95 %
    intervals of the absolute gain covered 0.83-0.86 on the independent simulator). It is
    not extrapolated: the drift ahead is the cameras' trends, walk and jitter.

    ``chains``, ``warmup``, ``draws``, ``target_accept``: NUTS on the scales; while their
    bulk or tail ESS is below ``[inference] min_ess`` (or their R-hat above ``max_rhat``)
    every chain continues for another
    ``draws`` draws, ``extend`` times at most (the trend and walk spreads of the log gain
    trade off along a ridge that mixes slowly on some seeds).  Warmup adapts the step size only
    (the mass matrix is the Laplace approximation's, :mod:`bayescal.fleet.sampling`; the walk
    and jitter are sampled as their total and ratio): 150 iterations and 500 draws per chain
    gave a smallest bulk or tail ESS of 434-750 on a 20-camera, 12-level fleet (seeds 5-16; one
    continued to 1000 draws) and no divergent transition in 16 seeds.  Target 0.9: at 0.85 a
    fit took 7 % fewer gradients but 2 of 9 continued, 3 % more on average; at 0.8 4 of 10
    continued.  A divergence is run again at ``retry_target_accept``; one left after the retry
    fails the fit.
    """

    pooling: Literal["partial", "none", "complete"] = "partial"
    drift: bool = True
    walk: bool = True
    sphere: Literal["per_campaign", "shared"] = "per_campaign"
    spread_prior: float = 1.0
    rate_prior: float = 0.5
    walk_prior: float = 0.3
    excess: bool = True
    excess_prior: float = 2.0
    excess_together_prior: float = 0.1
    jitter: bool = True
    jitter_prior: float = 0.3
    shared_error: float = 0.5
    campaign_sd: float = 0.02
    chains: int = 4
    draws: int = 500
    warmup: int = 150
    target_accept: float = 0.9
    extend: int = 2


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
    fleet: FleetSpec = field(default_factory=FleetSpec)
    effects: tuple[tuple[str, Any], ...] = ()

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
        spec = build(cls, data, source)
        return dataclasses.replace(spec, effects=effects) if effects else spec

    def to_dict(self) -> dict[str, Any]:
        """Nested dict in the TOML layout."""
        out = {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.name != "effects"}
        out = {k: dataclasses.asdict(v) if _instance(v) else v for k, v in out.items()}
        return out | {name: dataclasses.asdict(section) for name, section in self.effects}

    def to_toml(self) -> str:
        """Serialise as TOML (round-trips through :func:`load_spec`)."""
        return dumps(self.to_dict())

    def replace(self, **sections: Any) -> ModelSpec:
        """Copy with sections replaced; a dict value updates that section's fields.

        ``spec.replace(response={"order": 2}, sphere={"per_level_rel": 0})``
        """
        changes, effects = {}, dict(self.effects)
        for key, value in sections.items():
            current = effects[key] if key in effects else getattr(self, key)
            if isinstance(value, dict) and _instance(current):
                value = dataclasses.replace(current, **value)
            if key in effects:
                effects[key] = value
            else:
                changes[key] = value
        return dataclasses.replace(self, **changes, effects=tuple(effects.items()))

    def structure_key(self) -> str:
        """Hash of everything that changes the model's structure (not sampler settings)."""
        d = self.to_dict()
        for key in ("name", "description", "inference", "fleet"):
            d.pop(key)
        return hashlib.sha1(dumps(d).encode()).hexdigest()[:16]


def _renamed(data: dict[str, Any]) -> dict[str, Any]:
    """The TOML layout with the keys that moved into an effect's own section moved there (``Effect.renamed``),
    so specs written before, such as a saved posterior's, still read; the new key wins where both are given."""
    for e in EFFECTS:
        for old, key in e.renamed.items():
            section, name = old.split(".")
            if isinstance(data.get(section), dict) and name in data[section]:
                data[section] = dict(data[section])
                value = data[section].pop(name)
                data[e.section] = {key: value} | dict(data.get(e.section, {}))
    return data


def _instance(value: Any) -> bool:
    """A dataclass instance (a spec section), not a dataclass type."""
    return dataclasses.is_dataclass(value) and not isinstance(value, type)


def load_spec(path: str | os.PathLike) -> ModelSpec:
    """Load a model spec from a TOML file (see ``models/*.toml``): a :class:`ModelSpec`, or the spec of
    the kind the file names (``kind = "film"``, :mod:`bayescal.model.kinds`).  ``path`` may also name a
    shipped spec (``"seed000"``: :func:`bayescal.io.resources.example_path`)."""
    from bayescal.io.resources import example_path

    path = example_path(path, "spec")
    data = read_toml(path, "model spec (TOML)")
    kind = data.pop("kind", kinds.CALIBRATION)
    if kind != kinds.CALIBRATION:
        return kinds.get(str(kind)).spec_from_dict(data, str(path))
    return ModelSpec.from_dict(data, source=str(path))


def _non_finite(obj, prefix: str = "") -> str | None:
    """The dotted key of the first NaN or infinite number in a spec's sections, or None."""
    import dataclasses
    import math

    for f in dataclasses.fields(obj):
        value = getattr(obj, f.name)
        key = f"{prefix}{f.name}"
        if dataclasses.is_dataclass(value):
            found = _non_finite(value, key + ".")
            if found:
                return found
        elif isinstance(value, float) and not math.isfinite(value):
            return f"{key} = {value}"
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
        (
            min(
                spec.fleet.spread_prior,
                spec.fleet.rate_prior,
                spec.fleet.walk_prior,
                spec.fleet.excess_prior,
                spec.fleet.excess_together_prior,
                spec.fleet.jitter_prior,
            )
            > 0,
            "fleet.spread_prior, rate_prior, walk_prior, excess_prior, excess_together_prior and jitter_prior"
            " must be > 0",
        ),
        (spec.fleet.chains >= 1 and spec.fleet.draws >= 10, "fleet needs chains >= 1 and draws >= 10"),
        (spec.fleet.warmup >= 10, f"fleet.warmup = {spec.fleet.warmup}; expected >= 10"),
        (0 < spec.fleet.target_accept < 1, "fleet.target_accept must be in (0, 1)"),
        (spec.fleet.extend >= 0, f"fleet.extend = {spec.fleet.extend}; expected >= 0"),
        (0 <= spec.fleet.shared_error < 1, "fleet.shared_error must be in [0, 1)"),
        (spec.fleet.campaign_sd >= 0, "fleet.campaign_sd must be >= 0"),
    ]
    for ok, message in checks:
        if not ok:
            raise SpecError(message)
