"""A fitted fleet: per-camera calibrations shrunk toward the fleet, predictions, recalibration.

:func:`fit_fleet` runs both stages (docs/architecture.md, section 8);
:class:`FleetFit` answers the fleet's questions from the stage-two draws:

- a camera's log gain, offset and nonlinearity at any date (measured campaigns,
  between them, or ahead: the trend extrapolated and the random walk's spread
  growing as the square root of the time since the last campaign);
- the same for a camera of the type that was never measured (the population's
  predictive distribution);
- ``P(|gain(D) / gain(last campaign) - 1| > p)``: has the camera drifted by more
  than ``p`` by date ``D``; and the first date at which that probability passes a
  threshold (when to recalibrate);
- a full :class:`~bayescal.posterior.calibration.Calibration` (a fit directory that
  ``predict``, ``invert`` and ``plan`` read) for a camera at a date.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from bayescal._config import computes
from bayescal.errors import SpecError
from bayescal.fleet.excess import channel_inflation, excess_of
from bayescal.fleet.model import FleetData, Plan, fleet_data
from bayescal.fleet.sampling import FleetDraws, loo_of, sample_fleet
from bayescal.fleet.stage1 import UnitFits, fit_units
from bayescal.fleet.store import load_fleet, save_fleet
from bayescal.fleet.units import DAYS_PER_YEAR, FleetTable
from bayescal.model.spec import ModelSpec

__all__ = ["FleetFit", "fit_fleet", "compare_pooling"]

#: the widening of a unit's own interval of a channel by the excess (:func:`~.excess.channel_inflation`)
#: above which the units' scatter fails the fit (their own intervals 3x too narrow)
EXCESS_LIMIT = 3.0
#: the directions of a unit's error with their own excess (:func:`~.excess.excess_of`), as reported
DIRECTIONS = ("channels together", "channels apart")


@dataclass(frozen=True, eq=False)
class FleetFit:
    """Both stages of a fleet fit.

    Attributes
    ----------
    spec : ModelSpec
    kinds, channels, cameras : tuple of str
    units : pandas.DataFrame
        Per unit: ``camera``, ``campaign`` (ISO date or None), ``years`` (since the
        first campaign), stage-one ``ok`` and ``converged``, and its likelihood's
        centre and sd per quantity (``log_gain_R``, ``sd_log_gain_R``, ...).
    data : FleetData
    plan : Plan
    draws : FleetDraws
    origin : pandas.Timestamp or None
    fits : UnitFits or None
        The stage-one fits (in memory only; None for a loaded fleet).
    seed : int
    """

    spec: ModelSpec
    kinds: tuple[str, ...]
    channels: tuple[str, ...]
    cameras: tuple[str, ...]
    units: pd.DataFrame
    data: FleetData
    plan: Plan
    draws: FleetDraws
    origin: pd.Timestamp | None
    fits: UnitFits | None
    seed: int
    unit_mean: np.ndarray  # (U, K, C) stage-one likelihood centres
    unit_cov: np.ndarray  # (U, K*C, K*C)

    # ------------------------------------------------------------ verdict
    @property
    def problems(self) -> list[str]:
        """What stops the fleet fit from being trusted (empty: it passed)."""
        d = self.draws.diagnostics
        inf = self.spec.inference
        out = []
        if d["divergences"]:
            out.append(f"{d['divergences']} divergent transitions in the fleet hierarchy")
        if np.isfinite(d["max_rhat"]) and d["max_rhat"] > inf.max_rhat:
            out.append(f"R-hat {d['max_rhat']:.3f} > {inf.max_rhat}")
        if d["min_ess_bulk"] < inf.min_ess or d["min_ess_tail"] < inf.min_ess:
            out.append(f"ESS {min(d['min_ess_bulk'], d['min_ess_tail']):.0f} < {inf.min_ess:.0f}")
        bad = self.units[~self.units["converged"]]
        for _, r in bad.iterrows():
            out.append(f"unit {r['camera']} {r['campaign'] or ''} did not converge in stage one")
        if "excess" in self.draws.draws:
            kappa = np.median(self._excess(), axis=0)  # (K, D)
            wider = channel_inflation(self.plan, self.unit_cov, kappa)
            for kind, r, k in zip(self.kinds, wider, kappa, strict=True):
                if r > EXCESS_LIMIT:
                    parts = ", ".join(f"{w} {np.sqrt(v):.1f}x" for w, v in zip(DIRECTIONS, k, strict=False))
                    out.append(
                        f"the units' {kind} estimates scatter {r:.1f}x more than their own intervals of a channel "
                        f"allow ({parts}; the channel model or the hierarchy does not describe these cameras)"
                    )
        return out

    @property
    def ok(self) -> bool:
        """Whether both stages passed their checks."""
        return not self.problems

    @property
    def warnings(self) -> list[str]:
        """Units whose own fit flags rows the channel model does not describe (outliers, misfit).

        They do not fail the fleet: what the hierarchy uses is each unit's summary, and the
        units' scatter about the hierarchy widens every interval by ``sqrt(kappa)``, which
        fails the fit past :data:`EXCESS_LIMIT`."""
        out = []
        for _, r in self.units[self.units["converged"] & ~self.units["ok"]].iterrows():
            why = r["misfit"] or f"a row {r['max_abs_residual_z']:.1f} sd from the model"
            out.append(f"unit {r['camera']} {r['campaign'] or ''}: the channel model misfits its data ({why})")
        return out

    # ------------------------------------------------------------- values
    def _physical(self, theta: np.ndarray) -> np.ndarray:
        """Standardised ``(..., K, C)`` to physical units."""
        return self.data.center + self.data.scale[:, None] * theta

    def _excess(self) -> np.ndarray:
        """Draws of the excess dispersion, ``(S, K, D)``."""
        return excess_of(self.plan, {"excess": self._flat("excess")})

    def _flat(self, name: str) -> np.ndarray:
        a = self.draws.draws[name]
        return a.reshape((-1,) + a.shape[2:])

    def unit_values(self, relative: bool = False) -> np.ndarray:
        """Each unit's quantities at its campaign, ``(S, U, K, C)``: absolute (the sphere's scale
        error folded in), or with ``relative`` the gain against that campaign's sphere reading
        (what the unit's own data measure; the units' stage-one values are on this scale)."""
        theta = self._flat("theta_observed" if relative else "theta")  # (S, K, U, C)
        return self._physical(np.transpose(theta, (0, 2, 1, 3)))

    def years(self, date) -> float:
        """A date as years since the fleet's first campaign."""
        if self.origin is None:
            return 0.0
        return float((pd.Timestamp(date) - self.origin).total_seconds() / 86400.0 / DAYS_PER_YEAR)

    #: how far outside its campaigns the fleet answers, in years, at least (see :meth:`check_date`)
    MIN_REACH_YEARS = 5.0

    def check_date(self, date, camera: str | None = None, after_last: bool = False) -> str | None:
        """Check a date a question is asked at; returns an extrapolation warning, or None inside the campaigns.

        Dates further outside the campaigns than :attr:`MIN_REACH_YEARS` or twice their span,
        whichever is longer, are refused (:class:`~bayescal.errors.SpecError`): the drift there is
        the trend alone, extrapolated beyond anything the campaigns show.  With ``after_last``
        (a drift since ``camera``'s last campaign) the date must come after that campaign.
        """
        from bayescal.io import checks

        when = checks.date(date, "date")
        if self.origin is None:
            return None
        t = self.years(when)
        first, last = float(np.min(self.data.years)), float(np.max(self.data.years))
        reach = max(self.MIN_REACH_YEARS, 2.0 * (last - first))

        def day(years: float) -> str:
            return (self.origin + pd.Timedelta(days=years * DAYS_PER_YEAR)).date().isoformat()

        if after_last and camera is not None:
            own = float(np.max(self.data.years[self.data.camera == self.camera_index(camera)]))
            if t <= own + 1e-9:
                raise SpecError(
                    f"date {when.date()} is not after camera '{camera}''s last campaign ({day(own)}); the drift "
                    "probability is of the change since that campaign: give a later date"
                )
        if t < first - reach or t > last + reach:
            raise SpecError(
                f"date {when.date()} is {max(first - t, t - last):.1f} years outside the campaigns "
                f"({day(first)} to {day(last)}); the fleet answers up to {reach:g} years beyond them"
            )
        if t < first or t > last:
            return (
                f"EXTRAPOLATION: {when.date()} is {max(first - t, t - last):.2f} years outside the campaigns "
                f"({day(first)} to {day(last)}): the drift there is extrapolated from them"
            )
        return None

    def camera_index(self, camera: str) -> int:
        if camera not in self.cameras:
            raise SpecError(f"camera '{camera}' is not in this fleet; its cameras are {', '.join(self.cameras)}")
        return self.cameras.index(camera)

    def at(self, camera: str | None, date=None, seed: int = 0) -> np.ndarray:
        """Draws ``(S, K, C)`` of a camera's quantities at ``date`` (default: its last campaign).

        ``camera=None``: a camera of the type that was never measured (population predictive).
        Between and after campaigns the random walk adds ``walk_sd^2 |t - t_nearest|``.
        """
        if date is not None:
            self.check_date(date, camera)
        rng = np.random.default_rng(np.random.SeedSequence([seed, 0xF1EE7]))
        level = self._level(camera, rng)  # (S, K, C)
        if not self.plan.drift:
            return self._physical(level)
        units = np.flatnonzero(self.data.camera == self.camera_index(camera)) if camera is not None else None
        if date is None:
            if units is None:
                raise SpecError("give a date for a camera that was never measured")
            t = float(self.data.years[units[-1]])
        else:
            t = self.years(date)
        if units is not None:
            same = units[np.isclose(self.data.years[units], t)]
            if len(same):  # a measured campaign: that unit's own values
                return self._physical(self._flat("theta")[:, :, same[-1], :])
        rate = self._rate(camera, rng)  # (S, 2)
        drift = rate * (t - self.data.t_mean)
        if units is not None and self.plan.walk:
            nearest = units[np.argmin(np.abs(self.data.years[units] - t))]
            drift = drift + self._flat("walk")[:, :, nearest]
            gap = abs(t - self.data.years[nearest])
        else:
            gap = None  # no walk from a campaign: the population's trend alone
        drift = drift + self._ahead(slice(0, 2), gap, rng)

        level = level.copy()
        level[:, :2, :] += drift[:, :, None]
        return self._physical(level)

    def _level(self, camera: str | None, rng: np.random.Generator) -> np.ndarray:
        if camera is not None:
            return self._flat("camera_level")[:, :, self.camera_index(camera), :].copy()
        if self.plan.pooling == "none":
            raise SpecError("a fleet fitted without pooling has no population to predict an unmeasured camera from")
        mu = self._flat("mu")  # (S, K, C)
        if self.plan.pooling == "complete":
            return mu.copy()
        s, k, c = mu.shape
        a = self._flat("sigma_camera")[:, :, None] * rng.standard_normal((s, k, 1))
        b = self._flat("sigma_channel")[:, :, None] * rng.standard_normal((s, k, c))
        return mu + a + b

    def _rate(self, camera: str | None, rng: np.random.Generator) -> np.ndarray:
        if camera is not None and "rate" in self.draws.draws:
            return self._flat("rate")[:, :, self.camera_index(camera)]
        rho = self._flat("rate_mean")
        if self.plan.pooling == "partial":
            return rho + self._flat("rate_sd") * rng.standard_normal(rho.shape)
        return rho

    def _ahead(self, kinds, gap, rng: np.random.Generator) -> np.ndarray:
        """What a camera's state gains in ``gap`` years from a known one (None: no walk step):
        the random walk's step ``walk_sd sqrt(gap) z`` and the new date's own state
        ``jitter_sd z'``, for the drifting ``kinds``; ``(S, n_kinds)`` (``gap`` may be ``(D,)``:
        then ``(S, n_kinds, D)``, one draw of ``z``, ``z'`` shared by every date)."""
        n = self._flat("theta").shape[0]
        size = len(range(*kinds.indices(2)))
        out = np.zeros((n, size))
        gap = None if gap is None else np.asarray(gap, dtype=float)
        extra = () if gap is None or gap.ndim == 0 else (None,)
        out = out[(...,) + extra]
        if self.plan.walk and gap is not None:
            z = rng.standard_normal((n, size))[(...,) + extra]
            out = out + self._flat("walk_sd")[:, kinds][(...,) + extra] * np.sqrt(np.abs(gap)) * z
        if self.plan.jitter:
            z = rng.standard_normal((n, size))[(...,) + extra]
            out = out + self._flat("jitter_sd")[:, kinds][(...,) + extra] * z
        return out

    def _gain_change(self, camera: str, t1, since=None, seed: int = 0, relative: bool = False) -> np.ndarray:
        """Log-gain change (standardised) from ``since`` (default: the last campaign) to the
        dates ``t1`` (years; scalar or ``(D,)``): draws ``(S,)`` or ``(S, D)``; ``relative``: less the
        fleet's common trend over the same time (what the campaigns measure of this camera)."""
        if not self.plan.drift:
            raise SpecError("the fleet has one campaign date: drift is not modelled (add campaigns)")
        m = self.camera_index(camera)
        units = np.flatnonzero(self.data.camera == m)
        t1 = np.asarray(t1, dtype=float)
        t0 = float(self.data.years[units[-1]]) if since is None else self.years(since)
        rng = np.random.default_rng(np.random.SeedSequence([seed, 0xD41F7]))
        rate = self._gain_rate(m)
        extra = (None,) * t1.ndim
        if relative:
            rate = rate - self._flat("rate_mean")[:, 0]
        change = rate[(...,) + extra] * (t1 - t0)
        change = change + self._ahead(slice(0, 1), t1 - t0, rng)[:, 0]
        if self.plan.jitter and since is None:  # against the last campaign's own state (known from its data)
            change = change - self._flat("jitter")[:, 0, units[-1]][(...,) + extra]
        return change

    def gain_drift(self, camera: str, date, since=None, seed: int = 0, relative: bool = False) -> np.ndarray:
        """Draws ``(S,)`` of the relative gain change ``gain(date) / gain(since) - 1``
        (``since``: the camera's last campaign); ``relative``: against the fleet's common trend."""
        change = self._gain_change(camera, self.years(date), since, seed, relative)
        return np.expm1(change * self.data.scale[0])

    def drift_probability(
        self, camera: str, date, percent: float, since=None, seed: int = 0, relative: bool = False
    ) -> float:
        """``P(|gain(date) / gain(since) - 1| > percent / 100)`` (``since``: the last campaign).

        ``relative``: the camera's change against the fleet's common trend, which the campaigns
        measure even where the common trend itself is not (:meth:`drift_caveat`)."""
        if percent <= 0:
            raise SpecError(f"drift threshold {percent} %: expected a positive percentage")
        if since is None:
            self.check_date(date, camera, after_last=True)
        drift = self.gain_drift(camera, date, since, seed, relative)
        return float(np.mean(np.abs(drift) > percent / 100.0))

    def trend_sd(self, camera: str) -> tuple[float, float]:
        """Posterior sd of the camera's gain trend (relative change per year): absolute, and against
        the fleet's common trend."""
        if not self.plan.drift:
            raise SpecError("the fleet has one campaign date: drift is not modelled (add campaigns)")
        rate = self._gain_rate(self.camera_index(camera))
        scale = self.data.scale[0]
        return float(np.std(rate) * scale), float(np.std(rate - self._flat("rate_mean")[:, 0]) * scale)

    def _gain_rate(self, m: int) -> np.ndarray:
        """Draws of camera ``m``'s log-gain trend (standardised per year): its own, or the fleet's
        where cameras have none of their own."""
        return self._flat("rate")[:, 0, m] if "rate" in self.draws.draws else self._flat("rate_mean")[:, 0]

    def drift_caveat(self, camera: str) -> str | None:
        """What the campaigns cannot tell apart, when it dominates the camera's drift forecast: the
        fleet's common trend against the campaigns' sphere scale errors (every camera of a campaign
        shares its sphere, so a change common to the fleet reads the same as a change of the spheres).
        None when the camera's own trend is the larger uncertainty."""
        absolute, relative = self.trend_sd(camera)
        if absolute <= 2.0 * relative:
            return None
        return (
            f"the fleet's common gain trend cannot be told apart from the campaigns' sphere scale errors: "
            f"the camera's trend is known to +-{absolute:.2%}/year, of which all but +-{relative:.2%}/year "
            "is that common part; the drift probability carries it (on independent fleets it overstates the "
            "risk), the probability relative to the fleet does not"
        )

    def recalibration_date(self, camera: str, percent: float, probability: float = 0.05, horizon_years: float = 10.0):
        """The first date (monthly steps) at which ``drift_probability`` exceeds ``probability``;
        None if not within ``horizon_years`` of the last campaign.  Every month is evaluated in
        one pass, with the same draws :meth:`drift_probability` uses for each date."""
        if percent <= 0:
            raise SpecError(f"drift threshold {percent} %: expected a positive percentage")
        m = self.camera_index(camera)
        units = np.flatnonzero(self.data.camera == m)
        last = self.origin + pd.Timedelta(days=float(self.data.years[units[-1]]) * DAYS_PER_YEAR)
        dates = [last + pd.DateOffset(months=k) for k in range(1, int(12 * horizon_years) + 1)]
        change = np.expm1(self._gain_change(camera, np.array([self.years(d) for d in dates])) * self.data.scale[0])
        over = np.flatnonzero(np.mean(np.abs(change) > percent / 100.0, axis=0) > probability)
        return dates[over[0]].normalize() if len(over) else None

    # ------------------------------------------------------------ tables
    def summary(self) -> pd.DataFrame:
        """Per unit and channel: the pooled gain and offset (absolute: ``gain``, the sphere's scale
        folded in) beside the unit fitted alone (``gain_alone``: relative to its campaign's sphere
        reading; its absolute interval adds the sphere's ~3 %), and the pooled gain on that same
        footing (``gain_vs_sphere``), so the two compare."""
        vals = self.unit_values()  # (S, U, K, C)
        rel = self.unit_values(relative=True)
        rows = []
        for u, unit in self.units.iterrows():
            for c, ch in enumerate(self.channels):
                row = {"camera": unit["camera"], "campaign": unit["campaign"], "channel": ch}
                for k, kind in enumerate(self.kinds):
                    v = vals[:, u, k, c]
                    if kind == "log_gain":
                        v = np.exp(v)
                        name = "gain"
                        alone = np.exp(self.unit_mean[u, k, c])
                        alone_sd = alone * np.sqrt(
                            self.unit_cov[u, k * len(self.channels) + c, k * len(self.channels) + c]
                        )
                    else:
                        name = kind
                        alone = self.unit_mean[u, k, c]
                        alone_sd = np.sqrt(self.unit_cov[u, k * len(self.channels) + c, k * len(self.channels) + c])
                    lo, med, hi = np.quantile(v, [0.025, 0.5, 0.975])
                    row |= {
                        f"{name}": float(med),
                        f"{name}_lo": float(lo),
                        f"{name}_hi": float(hi),
                        f"{name}_alone": float(alone),
                        f"{name}_alone_sd": float(alone_sd),
                    }
                    if kind == "log_gain":  # the pooled gain against the campaign's sphere, as the unit alone
                        rlo, rmed, rhi = np.quantile(np.exp(rel[:, u, k, c]), [0.025, 0.5, 0.975])
                        row |= {
                            "gain_vs_sphere": float(rmed),
                            "gain_vs_sphere_lo": float(rlo),
                            "gain_vs_sphere_hi": float(rhi),
                        }
                rows.append(row)
        return pd.DataFrame(rows)

    def hyperparameters(self) -> pd.DataFrame:
        """The fleet's population: per quantity kind, mean, spreads, drift rate, walk (physical units)."""
        rows = []
        scale = self.data.scale
        d = self.draws.draws
        if "excess" in d:  # what the verdict judges: a unit's own interval of a channel widened
            excess = self._excess()
            widening = channel_inflation(self.plan, self.unit_cov, excess)  # (S, K)
        for k, kind in enumerate(self.kinds):
            entries = {}
            if "sigma_camera" in d:
                entries["camera spread"] = self._flat("sigma_camera")[:, k] * scale[k]
                entries["channel spread"] = self._flat("sigma_channel")[:, k] * scale[k]
            if k < 2 and "rate_mean" in d:
                entries["drift rate mean (per year)"] = self._flat("rate_mean")[:, k] * scale[k]
                if "rate_sd" in d:
                    entries["drift rate spread (per year)"] = self._flat("rate_sd")[:, k] * scale[k]
                if "walk_sd" in d:
                    entries["random walk (per sqrt year)"] = self._flat("walk_sd")[:, k] * scale[k]
                if "jitter_sd" in d:
                    entries["campaign jitter"] = self._flat("jitter_sd")[:, k] * scale[k]
            if "excess" in d:
                for where, kappa in zip(DIRECTIONS, np.moveaxis(excess[:, k], -1, 0), strict=False):
                    entries[f"interval inflation sqrt(kappa), {where}"] = np.sqrt(kappa)
                entries["interval inflation of one channel"] = widening[:, k]
            unit = {"log_gain": "log gain (relative)", "offset": "DN"}.get(kind, "relative to full scale")
            for name, v in entries.items():
                lo, med, hi = np.quantile(v, [0.025, 0.5, 0.975])
                what = (
                    "1" if name.startswith("interval inflation") else unit + (" per year" if "per year" in name else "")
                )
                what = unit + " per sqrt(year)" if "sqrt year" in name else what
                rows.append({"quantity": kind, "parameter": name, "unit": what, "median": med, "q2.5": lo, "q97.5": hi})
        if "sphere_log_scale" in d:
            s = self._flat("sphere_log_scale") * scale[0]
            for j in range(s.shape[1]):
                lo, med, hi = np.quantile(s[:, j], [0.025, 0.5, 0.975])
                rows.append(
                    {"quantity": "log_gain", "parameter": f"sphere scale {j}", "median": med, "q2.5": lo, "q97.5": hi}
                )
        return pd.DataFrame(rows)

    def to_dict(self) -> dict:
        """JSON-ready summary: verdict, diagnostics, structure, population."""
        return {
            "status": "ok" if self.ok else "FAILED",
            "problems": self.problems,
            "warnings": self.warnings,
            "seed": self.seed,
            "model": self.spec.name,
            "stage_one_backend": "" if self.fits is None else self.fits.backend,
            "pooling": self.plan.pooling,
            "drift": self.plan.drift,
            "walk": self.plan.walk,
            "cameras": list(self.cameras),
            "channels": list(self.channels),
            "quantities": list(self.kinds),
            "origin": None if self.origin is None else self.origin.date().isoformat(),
            "diagnostics": self.draws.diagnostics,
            "sampled_scales": self.plan.sampled(),
            "hyperparameters": self.hyperparameters().to_dict(orient="records"),
        }

    # ----------------------------------------------------------- storage
    def save(self, out_dir: str | os.PathLike) -> Path:
        """Write the fleet directory, replacing ``out_dir`` whole (:func:`bayescal.fleet.store.save_fleet`)."""
        return save_fleet(self, out_dir)

    @classmethod
    def load(cls, path: str | os.PathLike) -> FleetFit:
        """From a fleet directory written by :meth:`save`, or its ``fleet.nc``
        (:func:`bayescal.fleet.store.load_fleet`)."""
        return cls(**load_fleet(path))


@computes
def fit_fleet(
    fleet: FleetTable,
    spec: ModelSpec,
    backend: str = "laplace",
    *,
    seed: int = 0,
    progress: Callable[[int], None] | None = None,
    stage: Callable[[str], None] | None = None,
    fits: UnitFits | None = None,
) -> FleetFit:
    """Fit a fleet: every unit alone (``backend``), then the hierarchy by NUTS.

    Parameters
    ----------
    fleet : FleetTable
        From :func:`~bayescal.fleet.units.load_fleet_table`.
    spec : ModelSpec
        The channel-level model of one unit and the ``[fleet]`` section.
    backend : {"laplace", "nuts"}
        Stage one's inference.
    seed : int
        Unit ``u`` is fitted with ``seed + u``; the hierarchy with ``seed``.
    fits : UnitFits, optional
        Reuse stage one (e.g. to compare poolings).
    """
    stage = stage or (lambda message: None)
    if fits is None:
        stage(f"stage one: fitting {len(fleet.units)} units ({len(fleet.cameras)} cameras) alone")
        fits = fit_units(fleet, spec, backend, seed=seed, progress=progress)
    stage(f"stage two: the fleet hierarchy ({spec.fleet.pooling} pooling) by NUTS")
    data, plan = fleet_data(fits, spec.fleet, spec.sphere.common_rel)
    draws = sample_fleet(data, plan, spec.fleet, seed=seed, inference=spec.inference)
    units = fits.diagnostics.copy()
    units.insert(2, "years", data.years)
    for k, kind in enumerate(fits.kinds):
        for c, ch in enumerate(fits.channels):
            units[f"{kind}_{ch}"] = fits.mean[:, k, c]
            i = k * len(fits.channels) + c
            units[f"sd_{kind}_{ch}"] = np.sqrt(fits.cov[:, i, i])
    return FleetFit(
        spec=spec,
        kinds=fits.kinds,
        channels=fits.channels,
        cameras=fleet.cameras,
        units=units,
        data=data,
        plan=plan,
        draws=draws,
        origin=fleet.origin,
        fits=fits,
        seed=seed,
        unit_mean=fits.mean,
        unit_cov=fits.cov,
    )


@computes
def compare_pooling(fleet: FleetTable, spec: ModelSpec, fits: UnitFits | None = None, seed: int = 0) -> pd.DataFrame:
    """No, partial and complete pooling compared by PSIS leave-one-unit-out (stage one shared).

    Columns: ``elpd_loo``, ``se``, ``elpd_diff`` and ``dse`` (against the best, as
    :func:`arviz_stats.compare` ranks them, the same as :func:`~bayescal.fitting.select.compare_specs`),
    ``weight`` (stacking), ``p_loo``, ``n_high_k``, ``divergences``; one row per pooling, best first.
    ``fits``: stage one, fitted here when not given.
    """
    import arviz_stats

    if fits is None:
        fits = fit_units(fleet, spec, seed=seed)
    rows, elpd = {}, {}
    for pooling in ("none", "partial", "complete"):
        s = spec.replace(fleet={"pooling": pooling})
        fit = fit_fleet(fleet, s, seed=seed, fits=fits)
        loo = loo_of(fit.plan, fit.data, fit.draws)
        elpd[pooling] = loo["elpd_data"]
        rows[pooling] = {
            "p_loo": loo["p_loo"],
            "n_high_k": loo["n_high_k"],
            "divergences": fit.draws.diagnostics["divergences"],
        }
    ranked = arviz_stats.compare(elpd, round_to="none")
    table = ranked.rename(columns={"elpd": "elpd_loo"})[["elpd_loo", "se", "elpd_diff", "dse", "weight"]]
    table = table.join(pd.DataFrame(rows).T)
    return table[["elpd_loo", "se", "elpd_diff", "dse", "weight", "p_loo", "n_high_k", "divergences"]]
