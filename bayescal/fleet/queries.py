"""The fleet's questions, answered from the stage-two draws of a :class:`~bayescal.fleet.posterior.FleetFit`.

A camera's quantities at any date (:meth:`FleetQueries.at`: at a campaign its own values; between
and after campaigns the trend, the random walk's step ``walk_sd sqrt(gap)`` and the campaign
jitter; a camera never measured from the population), its gain drift since its last campaign and
the probability that it passes a threshold, and the first month at which it does
(:meth:`FleetQueries.recalibration_date`).  Dates are refused beyond the campaigns' reach
(:meth:`FleetQueries.check_date`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

from bayescal.errors import SpecError
from bayescal.fleet.plan import FleetData, Plan
from bayescal.fleet.units import DAYS_PER_YEAR

if TYPE_CHECKING:
    from bayescal.fleet.sampling import FleetDraws

__all__ = ["FleetQueries"]


class FleetQueries:
    """The questions of a fitted fleet (a base of :class:`~bayescal.fleet.posterior.FleetFit`, which
    holds the attributes below)."""

    cameras: tuple[str, ...]
    data: FleetData
    plan: Plan
    draws: FleetDraws
    origin: pd.Timestamp | None

    def _physical(self, theta: np.ndarray) -> np.ndarray:
        """Standardised ``(..., K, C)`` to physical units."""
        return self.data.center + self.data.scale[:, None] * theta

    def _flat(self, name: str) -> np.ndarray:
        a = self.draws.draws[name]
        return a.reshape((-1,) + a.shape[2:])

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
