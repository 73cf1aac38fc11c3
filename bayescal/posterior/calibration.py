"""A fitted camera as posterior draws in physical units: the input of predictions.

The measurement equation (docs/architecture.md, section 2; seeds 000 eq. 3-5, 002 eq.
11-12) evaluated per posterior draw ``s``::

    DN = sum_j offset_sj(channel, setting) + sum_k A_sk x^k,   x = L t M g / (t_ref M_ref g_ref) prod_i f_si

with ``A_sk`` the monomial coefficients of the response at the reference setting (seed 000 Table 1
form), the offset terms (the dark level, then the offset effects) and the factor terms (the
settings' effective factors, then the factor effects) composed by the one skeleton
:func:`bayescal.model.equation.reading`, and the variance of one reading::

    var = ((r g_rel)^2 + K g_rel S + 1/12) / n_avg + excess_s^2 + (prnu S)^2

(read noise ``r`` and conversion gain ``K`` at the reference gain, signal
``S`` in DN, quantisation 1/12 DN^2, ``n_avg`` pixels x frames averaged, the
fitted excess scatter of a region mean, and for single pixels the PRNU).

A :class:`Calibration` comes from a :class:`~bayescal.fitting.fit.Fit`, from a saved
``posterior.nc`` (:meth:`Calibration.load`) or from fixed published
coefficients (:meth:`Calibration.from_coefficients`, one "draw"), so the
papers' own numbers run through the same code as the posteriors.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field

import numpy as np

from bayescal.errors import PosteriorError, SpecError, TableError
from bayescal.io.fit_folder import FitFolder
from bayescal.model import kinds, observation
from bayescal.model.components import (
    FactorEffect,
    FactorTerm,
    Noise,
    NoiseEffect,
    NoiseTerm,
    OffsetTerm,
    Response,
    Sphere,
    effect_terms,
    offset_terms,
)
from bayescal.model.components import rolloff as roll
from bayescal.model.components.dark import DarkTerm
from bayescal.model.components.noise import QUANTISATION_DN2
from bayescal.model.components.settings import SettingFactorDraws, SettingFactors
from bayescal.model.equation import Reading, reading
from bayescal.model.setting import Setting
from bayescal.model.spec import ModelSpec, Reference

__all__ = ["Calibration", "CalibratedRange"]


@dataclass(frozen=True)
class CalibratedRange:
    """What the calibration measured; settings outside it are extrapolations.

    Examples
    --------
    >>> import bayescal as bc
    >>> measured = bc.CalibratedRange(exposure_s=(0.002, 0.01), gains=(1.0, 2.0))
    >>> measured.flags(bc.Setting(0.02))
    ['exposure 0.02 s outside the 0.002-0.01 s measured with light']
    >>> measured.flags(bc.Setting(0.005, 2.0))
    []
    """

    exposure_s: tuple[float, float] = (0.0, np.inf)
    gains: tuple[float, ...] = ()
    tdi_stages: tuple[float, float] = (0.0, np.inf)
    max_effective: float = np.inf  # largest unsaturated effective stimulus x
    temperature_c: tuple[float, float] | None = None  # calibrated sensor temperatures, when recorded

    def flags(self, setting: Setting) -> list[str]:
        """Reasons this setting is outside the calibrated range (empty: inside)."""
        out = []
        lo, hi = self.exposure_s
        if not lo * (1 - 1e-9) <= setting.exposure_s <= hi * (1 + 1e-9):
            out.append(f"exposure {setting.exposure_s:g} s outside the {lo:g}-{hi:g} s measured with light")
        if self.gains and not np.any(np.isclose(setting.gain, self.gains)):
            out.append(f"gain {setting.gain:g} never measured with light (illuminated gains {list(self.gains)})")
        lo, hi = self.tdi_stages
        if not lo <= setting.tdi_stages <= hi:
            out.append(f"TDI stages {setting.tdi_stages:g} outside the {lo:g}-{hi:g} measured with light")
        if self.temperature_c is not None and setting.temperature_c is not None:
            lo, hi = self.temperature_c
            if not lo <= setting.temperature_c <= hi:
                out.append(f"temperature {setting.temperature_c:g} degC outside calibrated {lo:g}-{hi:g} degC")
        return out


@dataclass(frozen=True, eq=False)
class Calibration:
    """Posterior draws of a camera's calibration in physical units.

    Attributes
    ----------
    channels : tuple of str
    coef : array (S, C, P)
        Absolute response coefficients ``A1..AP`` (DN per stimulus unit^k at
        the reference setting), the sphere's common scale folded in.
    coef_rel : array (S, C, P)
        The same relative to the sphere's scale (what its readings say).
    dark : DarkTerm
        The dark level's draws (:class:`~bayescal.model.components.dark.DarkTerm`): the first of the
        offset terms.
    excess_dn : array (S,)
        Extra scatter of a region mean (DN); zeros when not modelled.
    factors, offsets : tuple
        The factor terms on the effective stimulus (the settings', then the factor effects') and the
        offset effects (DN added beside the dark level); empty: none.
    """

    channels: tuple[str, ...]
    coef: np.ndarray
    coef_rel: np.ndarray
    dark: DarkTerm
    excess_dn: np.ndarray
    reference: Reference
    bits: int
    stimulus: str = "radiance"
    unit: str = ""
    read_noise_dn: float = 0.0
    conversion_gain: float = 0.0
    prnu: float = 0.0
    margin_dn: float = 0.5
    calibrated: CalibratedRange = field(default_factory=CalibratedRange)
    source: str = ""
    factors: tuple[FactorTerm, ...] = ()
    offsets: tuple[OffsetTerm, ...] = ()
    charge_nonlinearity: bool = False  # the nonlinearity is the charge's (before the gain), not the output's
    rolloff: np.ndarray | None = None  # (S, P) roll-off parameters in DN (model.components.rolloff); None: none
    rolloff_shape: str = "knee"  # the roll-off's shape (model.components.rolloff.SHAPES)
    #: the noise effects: variance each adds to a reading (:class:`~bayescal.model.components.base.NoiseTerm`)
    noises: tuple[NoiseTerm, ...] = ()
    #: the spread of pixel responses up to which the fit bracketed a partly clipped mean (saturation.prnu_bound)
    prnu_bound: float = 0.03
    #: the sphere's fitted level errors, level name -> per-draw error ``(S,)``: what each measured level delivered
    level_errors: dict[str, np.ndarray] = field(default_factory=dict, compare=False)
    #: the fit folder it was read from (None: made in memory); where its inversion tables are kept
    folder: FitFolder | None = field(default=None, repr=False)

    # ------------------------------------------------------------------ build
    @classmethod
    def from_fit(cls, fit) -> Calibration:
        """From a Bayesian :class:`~bayescal.fitting.fit.Fit` (any backend but ``lsq``)."""
        if fit.posterior is None:
            raise SpecError("a least-squares fit has no posterior; fit with nuts, laplace or emcee")
        post = fit.posterior["posterior"]
        table = fit.model.table
        return cls._from_draws(
            fit.model.spec,
            {k: np.asarray(post[k]) for k in post.data_vars},
            tuple(fit.model.layout.channels),
            tuple(fit.model.layout.gain_values),
            table.frame,
            source=f"fit backend={fit.backend} seed={fit.seed}",
            levels=_levels(post),
        )

    @classmethod
    def load(cls, path: str | os.PathLike | FitFolder) -> Calibration:
        """From a fit directory or its ``posterior.nc`` (spec and measurements are stored in it), or a
        :class:`~bayescal.io.fit_folder.FitFolder` a reader already holds (its posterior is opened once)."""
        folder = path if isinstance(path, FitFolder) else FitFolder.at(path, "a calibration's reader")
        dt = folder.posterior
        attrs = dt.attrs
        if attrs.get("kind", kinds.CALIBRATION) != kinds.CALIBRATION:  # a posterior of another model kind
            return kinds.get(str(attrs["kind"])).load_posterior(folder.posterior_path, dt)
        if "spec_toml" not in attrs or "posterior" not in dt.children or "measurements" not in dt.children:
            raise PosteriorError(
                f"{folder.posterior_path} was not written by `bayescal fit` (no spec, posterior or measurements)"
            )
        import tomllib

        spec = ModelSpec.from_dict(tomllib.loads(attrs["spec_toml"]), source=str(folder.posterior_path))
        post = dt["posterior"]
        frame = folder.measurements.rename(columns={spec.stimulus: "stimulus"})
        channels = tuple(str(c) for c in np.asarray(post["channel"]))
        gains = tuple(float(g) for g in np.asarray(post["gain_setting"])) if "gain_setting" in post.coords else ()
        draws = {str(k): np.asarray(post[str(k)]) for k in post.data_vars}
        source = str(folder.posterior_path)
        # the folder's address only: the opened posterior stays with the reader that opened it, not held open
        address = FitFolder(folder.root, folder.posterior_path)
        return cls._from_draws(spec, draws, channels, gains, frame, source, _levels(post), address)

    @classmethod
    def _from_draws(
        cls,
        spec: ModelSpec,
        draws,
        channels,
        gains,
        frame,
        source: str,
        levels: tuple[str, ...] = (),
        folder: FitFolder | None = None,
    ) -> Calibration:
        def flat(a):
            a = np.asarray(a, dtype=float)
            return a.reshape((-1,) + a.shape[2:])

        coef = flat(draws["A_abs"])[..., 1:]
        coef_rel = flat(draws["A_rel"])[..., 1:]
        dark, offsets = offset_terms(spec, draws, channels, tuple(gains), frame)
        excess = flat(draws["excess_dn"]) if "excess_dn" in draws else np.zeros(coef.shape[0])
        read, kconv = spec.noise.read_noise_dn, spec.noise.conversion_gain
        if spec.noise.kind == "measured" and "dn_var" in frame:
            read, kconv = _photon_transfer(frame, spec, dark)
        return cls(
            channels=channels,
            coef=coef,
            coef_rel=coef_rel,
            dark=dark,
            excess_dn=excess,
            reference=spec.reference,
            bits=spec.bits,
            stimulus=spec.stimulus,
            unit=_unit(spec.stimulus),
            read_noise_dn=read,
            conversion_gain=kconv,
            prnu=float(np.median(draws["prnu"])) if "prnu" in draws else spec.saturation.prnu,
            margin_dn=spec.saturation.margin_dn,
            calibrated=_calibrated_range(frame, spec),
            source=source,
            factors=_factor_terms(spec, draws, frame, flat),
            offsets=offsets,
            charge_nonlinearity=spec.response.nonlinearity_domain == "charge",
            rolloff=Response.rolloff_params({k: flat(v) for k, v in draws.items() if k.startswith("rolloff_")}, spec),
            rolloff_shape=spec.response.rolloff_shape or "knee",
            noises=effect_terms(spec, draws, frame, NoiseEffect),
            prnu_bound=spec.saturation.prnu_bound,
            level_errors=_level_errors(draws, levels, flat),
            folder=folder,
        )

    @classmethod
    def from_coefficients(
        cls,
        coefficients: dict[str, list[float]],
        *,
        reference: Reference,
        bits: int,
        dark_proportional: bool = False,
        stimulus: str = "radiance",
        read_noise_dn: float = 0.0,
        conversion_gain: float = 0.0,
        dark_slope: float = 0.0,
    ) -> Calibration:
        """A fixed-parameter calibration from published coefficients (one draw, no uncertainty).

        Parameters
        ----------
        coefficients : dict
            Channel -> ``[A0, A1, ..., AP]`` at the reference setting
            (seed 000 Table 1: ``{"G": [51.2, 30.18]}``).  ``A0`` is the
            dark offset at the reference gain.
        dark_proportional : bool
            Offset scales with the gain factor (seed 002 eq. 12); otherwise
            it is kept at every setting (seed 000 section 5.3).

        Examples
        --------
        >>> import bayescal as bc
        >>> cal = bc.Calibration.from_coefficients({"G": [45.0, 30.0]}, reference=bc.Reference(0.004), bits=12)
        >>> cal.channels
        ('G',)
        """
        channels = tuple(coefficients)
        arr = [np.asarray(coefficients[c], dtype=float) for c in channels]
        order = max(a.size for a in arr) - 1
        if order < 1:
            raise SpecError("coefficients need at least [A0, A1] per channel")
        full = np.zeros((1, len(channels), order + 1))
        for i, a in enumerate(arr):
            full[0, i, : a.size] = a
        return cls(
            channels=channels,
            coef=full[..., 1:],
            coef_rel=full[..., 1:],
            dark=DarkTerm(
                channels=channels,
                offset_dn=full[..., :1],
                slope_dn_s=np.full((1, 1), dark_slope),
                gains=(reference.gain,),
                proportional=dark_proportional,
                reference_gain=reference.gain,
            ),
            excess_dn=np.zeros(1),
            reference=reference,
            bits=bits,
            stimulus=stimulus,
            unit=_unit(stimulus),
            read_noise_dn=read_noise_dn,
            conversion_gain=conversion_gain,
            prnu=0.0,
            source="published coefficients",
        )

    # ------------------------------------------------------------ evaluation
    @property
    def n_draws(self) -> int:
        """Number of posterior draws."""
        return int(self.coef.shape[0])

    @property
    def full_scale(self) -> float:
        """Largest ADC code, ``2**bits - 1``."""
        return float(2**self.bits - 1)

    @property
    def saturation_dn(self) -> float:
        """Readings at or above this are treated as clipped."""
        return self.full_scale - self.margin_dn

    def channel_index(self, channel: str) -> int:
        """Index of ``channel``; a clear error for an unknown one."""
        try:
            return self.channels.index(str(channel))
        except ValueError:
            raise TableError(
                f"channel '{channel}' was not calibrated; calibrated channels: {list(self.channels)}", column="channel"
            ) from None

    @property
    def setting_factors(self) -> tuple[SettingFactorDraws, ...]:
        """The settings' effective factors (one term per kind measured off its reference)."""
        return tuple(f for f in self.factors if isinstance(f, SettingFactorDraws))

    def offset_terms(self) -> tuple[OffsetTerm, ...]:
        """Every term added to a reading: the dark level, then the offset effects."""
        return (self.dark, *self.offsets)

    def dark_dn(self, channel: str, setting: Setting) -> np.ndarray:
        """Level (DN) per draw at ``setting`` with no light: the offset terms' sum (the dark level, offset
        plus dark current times exposure, :class:`~bayescal.model.components.dark.DarkTerm`, and the
        offset effects)."""
        self.channel_index(channel)
        level = np.zeros(self.n_draws)
        for term in self.offset_terms():
            level = level + term.offset(channel, setting, self.n_draws)
        return level

    def gain_ratio(self, setting: Setting, channel: str | None = None) -> np.ndarray:
        """Effective programmable gain per draw relative to the reference: ``g / g_ref`` times the
        gain's effective factor (posterior where measured, a population draw where not)."""
        ratio = np.full(self.n_draws, setting.gain / self.reference.gain)
        for term in self.setting_factors:
            if term.kind == "gain":
                ratio = ratio * term.factor(channel, setting, self.n_draws)
        return ratio

    def coefficients(self, channel: str, setting: Setting | None = None, relative: bool = False) -> np.ndarray:
        """Response coefficients ``A1..AP`` per draw, ``(S, P)``, at ``setting`` (None: the reference).

        They are the reference's unless the nonlinearity is the charge's, whose coefficients at
        effective gain ``g`` are ``A_k g^(1-k)`` (:meth:`~bayescal.model.components.response.Response.at_gain`).
        """
        coef = (self.coef_rel if relative else self.coef)[:, self.channel_index(channel), :]  # (S, P)
        if self.charge_nonlinearity and setting is not None and coef.shape[-1] > 1:
            coef = Response.at_gain(coef, self.gain_ratio(setting, channel))
        return coef

    def signal_dn(
        self, channel: str, x: np.ndarray, relative: bool = False, setting: Setting | None = None
    ) -> np.ndarray:
        """Signal (DN) per draw for effective stimulus ``x`` with the draws on its first axis
        (shape ``(S, ...)``, or ``(1, ...)`` for the same ``x`` in every draw), at ``setting``'s gain
        (None: the reference's; it matters only for a nonlinearity of the charge).  Past the polynomial's
        turning point (:meth:`~bayescal.model.components.response.Response.turning_point`, far beyond any
        calibrated range) the signal holds its largest value: a response never falls as the light grows."""
        coef = self.coefficients(channel, setting, relative)
        x = np.asarray(x, dtype=float)
        shape = (-1,) + (1,) * (x.ndim - 1)
        x = np.minimum(x, Response.turning_point(coef).reshape(shape))
        rolloff = None
        if self.rolloff is not None:  # (S, 1, ..., P): the draws first, the parameters last
            rolloff = (self.rolloff_shape, self.rolloff.reshape((len(self.rolloff),) + shape[1:] + (-1,)))
        return Response.forward(coef.reshape(shape + coef.shape[1:]), x, rolloff)

    def response_signal(self, signal: np.ndarray) -> np.ndarray:
        """The polynomial response's signal behind an output ``signal`` (DN, draws on the last axis):
        the roll-off undone (:func:`~bayescal.model.components.rolloff.expand`; ``inf`` past a knee's
        asymptote), or ``signal`` itself without one."""
        if self.rolloff is None:
            return signal
        return roll.expand(signal, self.rolloff_shape, self.rolloff)

    def pixel_var(self, signal: np.ndarray, setting: Setting) -> np.ndarray:
        """Temporal variance (DN^2) of one pixel reading at ``signal`` and ``setting``'s gain: read noise,
        quantisation and shot noise (:meth:`~bayescal.model.components.noise.Noise.pixel_variance`)."""
        return Noise.pixel_variance(
            self.read_noise_dn, self.conversion_gain, setting.gain / self.reference.gain, signal
        )

    def excess(self, ndim: int) -> np.ndarray:
        """The fitted excess scatter of a reading (DN) per draw, shaped to broadcast against an array of
        ``ndim`` dimensions with the draws first."""
        return self.excess_dn.reshape((-1,) + (1,) * (ndim - 1))

    def extra_var(self, channel: str | None, setting: Setting, signal: np.ndarray) -> np.ndarray | float:
        """Variance (DN^2) the noise effects add to a reading of ``signal`` (the draws first) at ``setting``."""
        total: np.ndarray | float = 0.0
        for term in self.noises:
            total = total + term.variance(channel, setting, signal)
        return total

    def noise_var(
        self, signal: np.ndarray, setting: Setting, n_avg: float = 1.0, prnu: float = 0.0, channel: str | None = None
    ) -> np.ndarray:
        """Variance (DN^2) of one reading with ``n_avg`` pixels x frames averaged
        (:class:`~bayescal.model.components.noise.Noise`), the noise effects' included (of ``channel``).

        ``signal`` has the draws on its first axis.
        """
        return observation.variance(
            self.pixel_var(signal, setting),
            signal,
            n_avg=n_avg,
            excess=self.excess(np.ndim(signal)),
            prnu=prnu,
            extra=self.extra_var(channel, setting, signal),
        )

    def ratio(self, setting: Setting, channel: str | None = None) -> np.ndarray:
        """Stimulus -> effective stimulus per draw: the nominal ``t M g / (t_ref M_ref g_ref)`` times the
        factors on the effective stimulus (the settings' effective factors, posterior where measured and
        population draws where not; the effects at the setting, e.g. its temperature)."""
        ratio = np.full(self.n_draws, setting.ratio(self.reference))
        for term in self.factors:
            ratio = ratio * term.factor(channel, setting, self.n_draws)
        return ratio

    def reading(
        self, channel: str, stimulus, setting: Setting, relative: bool = False, per_draw: bool = False
    ) -> Reading:
        """The measurement equation per draw at ``setting`` (:func:`~bayescal.model.equation.reading`):
        the signal and the expected DN before clipping, each ``(S,) + shape(stimulus)``;
        with ``per_draw`` the stimulus already has the draws on its first axis (e.g. a sphere level's
        reading times that draw's level error)."""
        stimulus = np.asarray(stimulus, dtype=float)
        if not per_draw:
            stimulus = stimulus[None, ...]
        shape = (-1,) + (1,) * (stimulus.ndim - 1)
        return reading(
            stimulus,
            (self.ratio(setting, channel).reshape(shape),),
            lambda x: self.signal_dn(channel, x, relative, setting),
            (self.dark_dn(channel, setting).reshape(shape),),
        )

    def expected_dn(
        self, channel: str, stimulus, setting: Setting, relative: bool = False, per_draw: bool = False
    ) -> np.ndarray:
        """Expected DN (before clipping) per draw: ``(S,) + shape(stimulus)`` (``per_draw``: see
        :meth:`reading`)."""
        return self.reading(channel, stimulus, setting, relative, per_draw).mean

    def sample_dn(
        self,
        channel: str,
        stimulus,
        setting: Setting,
        rng: np.random.Generator,
        n_avg: float = 1.0,
        prnu: float = 0.0,
        relative: bool = False,
        per_draw: bool = False,
    ) -> np.ndarray:
        """Posterior predictive readings (one per draw), clipped to ``[0, full scale]`` (``per_draw``: see
        :meth:`expected_dn`; the noise and the clipping: :func:`bayescal.model.observation.draw`)."""
        expected = self.reading(channel, stimulus, setting, relative, per_draw)
        pixel = self.pixel_var(expected.signal, setting)
        normals = rng.standard_normal(expected.mean.shape)
        excess = self.excess(np.ndim(expected.signal))
        extra = self.extra_var(channel, setting, expected.signal)
        return observation.draw(
            expected, pixel, normals, self.full_scale, n_avg=n_avg, excess=excess, prnu=prnu, extra=extra
        )

    def clipped_dn(
        self, channel: str, stimulus, setting: Setting, relative: bool = False, per_draw: bool = False
    ) -> np.ndarray:
        """Expected DN per draw as the ADC outputs it, clipped to ``[0, full scale]`` (:meth:`expected_dn`,
        :func:`bayescal.model.observation.expected`)."""
        return observation.expected(self.expected_dn(channel, stimulus, setting, relative, per_draw), self.full_scale)

    def delivered(self, stimulus, levels) -> np.ndarray:
        """What the measured rows delivered per draw, ``(S, n)``: each row's reading of the stimulus times
        its sphere level's fitted error factor (:meth:`~bayescal.model.components.sphere.Sphere.factor`;
        1 for a level the fit did not estimate, or a row without one)."""
        stimulus = np.asarray(stimulus, dtype=float)[None, :] * np.ones((self.n_draws, 1))
        for j, level in enumerate(levels):
            error = self.level_errors.get(str(level))
            if error is not None:
                stimulus[:, j] = stimulus[:, j] * Sphere.factor(error)
        return stimulus

    def flags(self, setting: Setting, stimulus=None) -> list[str]:
        """Why a prediction at ``setting`` (and ``stimulus``) is an extrapolation."""
        terms = self.factors + self.offset_terms()
        out = self.calibrated.flags(setting) + [why for term in terms for why in term.flags(setting)]
        if stimulus is not None and np.isfinite(self.calibrated.max_effective):
            x = float(np.max(stimulus)) * setting.ratio(self.reference)
            if x > self.calibrated.max_effective * (1 + 1e-9):
                out.append(
                    f"signal beyond the calibrated range (effective {self.stimulus} {x:.4g} > "
                    f"{self.calibrated.max_effective:.4g} at the reference setting)"
                )
        return out


def _unit(stimulus: str) -> str:
    return "W m^-2 sr^-1" if stimulus == "radiance" else "W m^-2"


def _calibrated_range(frame, spec: ModelSpec) -> CalibratedRange:
    from bayescal.model.data import effective_stimulus

    f = frame
    lit = f["stimulus"].to_numpy() > 0 if "stimulus" in f else np.ones(len(f), bool)
    tdi = f["tdi_stages"].to_numpy() if "tdi_stages" in f else np.ones(len(f))
    x = effective_stimulus(f["stimulus"].to_numpy(), f["exposure_s"].to_numpy(), f["gain"].to_numpy(), tdi, spec)
    unsat = f["dn_mean"].to_numpy() < spec.full_scale - spec.saturation.margin_dn
    max_x = float(np.max(x[lit & unsat])) if np.any(lit & unsat) else np.inf
    temps = None
    if "temperature_c" in f and np.isfinite(f["temperature_c"]).any():
        temps = (float(np.nanmin(f["temperature_c"])), float(np.nanmax(f["temperature_c"])))
    seen = lit if lit.any() else np.ones(len(f), bool)  # a setting seen only in the dark has no measured response
    exposures = f["exposure_s"].to_numpy()[seen]
    return CalibratedRange(
        exposure_s=(float(exposures.min()), float(exposures.max())),
        gains=tuple(sorted({float(g) for g in f["gain"].to_numpy()[seen]})),
        tdi_stages=(float(np.min(tdi[seen])), float(np.max(tdi[seen]))),
        max_effective=max_x,
        temperature_c=temps,
    )


def _factor_terms(spec: ModelSpec, draws: dict, frame, flat) -> tuple[FactorTerm, ...]:
    """The factors on the effective stimulus that predictions apply: the settings', then each factor effect's."""
    return SettingFactors.terms(draws, frame, spec.reference, flat) + effect_terms(spec, draws, frame, FactorEffect)


def _photon_transfer(frame, spec, dark: DarkTerm) -> tuple[float, float]:
    """Read noise and conversion gain at the reference gain from ``dn_var`` (least squares).

    ``dn_var - 1/12 = r^2 g_rel^2 + K g_rel S`` over unsaturated rows (EMVA
    1288 photon transfer), ``S`` the mean DN above the posterior-median dark.
    """
    from bayescal.inference.lsq import lstsq

    f = frame
    g_rel = f["gain"].to_numpy() / spec.reference.gain
    unsat = f["dn_mean"].to_numpy() < spec.full_scale - spec.saturation.margin_dn
    unlit = f["stimulus"].to_numpy() == 0
    base = np.zeros(len(f))
    for i, row in enumerate(f.itertuples()):
        gi = 0 if dark.proportional else int(np.argmin(np.abs(np.asarray(dark.gains) - row.gain)))
        level = np.median(dark.offset_dn[:, :, gi])
        base[i] = level * (g_rel[i] if dark.proportional else 1.0)
    signal = np.where(unlit, 0.0, np.maximum(f["dn_mean"].to_numpy() - base, 0.0))
    design = np.column_stack([g_rel**2, g_rel * signal])[unsat]
    coef = lstsq(design, (f["dn_var"].to_numpy() - QUANTISATION_DN2)[unsat]).coef
    return float(np.sqrt(max(coef[0], 0.0))), float(max(coef[1], 0.0))


def _levels(post) -> tuple[str, ...]:
    """The sphere levels of a posterior's ``level`` coordinate (none without one)."""
    return tuple(str(v) for v in np.asarray(post["level"])) if "level" in post.coords else ()


def _level_errors(draws, levels: tuple[str, ...], flat) -> dict[str, np.ndarray]:
    """Each fitted sphere level's error per draw, from the reported ``level_error`` ``(chain, draw, level)``."""
    if "level_error" not in draws or not levels:
        return {}
    errors = flat(draws["level_error"])
    return {name: errors[:, i] for i, name in enumerate(levels)}
