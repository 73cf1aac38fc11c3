"""A fitted fleet: per-camera calibrations shrunk toward the fleet, predictions, recalibration.

:func:`fit_fleet` runs both stages (docs/architecture.md, section 8); a
:class:`FleetFit` holds the stage-two draws and the verdict, and answers the fleet's questions
from the draws (:mod:`.queries`):

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
from bayescal.fleet.data import fleet_data
from bayescal.fleet.excess import channel_inflation, excess_of
from bayescal.fleet.plan import FleetData, Plan
from bayescal.fleet.queries import FleetQueries
from bayescal.fleet.sampling import FleetDraws, loo_of, sample_fleet
from bayescal.fleet.stage1 import UnitFits, fit_units
from bayescal.fleet.store import load_fleet, save_fleet
from bayescal.fleet.units import FleetTable
from bayescal.model.spec import ModelSpec

__all__ = ["FleetFit", "fit_fleet", "compare_pooling"]

#: the widening of a unit's own interval of a channel by the excess (:func:`~.excess.channel_inflation`)
#: above which the units' scatter fails the fit (their own intervals 3x too narrow)
EXCESS_LIMIT = 3.0
#: the directions of a unit's error with their own excess (:func:`~.excess.excess_of`), as reported
DIRECTIONS = ("channels together", "channels apart")


@dataclass(frozen=True, eq=False)
class FleetFit(FleetQueries):
    """Both stages of a fleet fit: its draws and verdict, its tables, its storage; the questions it
    answers are :class:`~bayescal.fleet.queries.FleetQueries`.

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
    def _excess(self) -> np.ndarray:
        """Draws of the excess dispersion, ``(S, K, D)``."""
        return excess_of(self.plan, {"excess": self._flat("excess")})

    def unit_values(self, relative: bool = False) -> np.ndarray:
        """Each unit's quantities at its campaign, ``(S, U, K, C)``: absolute (the sphere's scale
        error folded in), or with ``relative`` the gain against that campaign's sphere reading
        (what the unit's own data measure; the units' stage-one values are on this scale)."""
        theta = self._flat("theta_observed" if relative else "theta")  # (S, K, U, C)
        return self._physical(np.transpose(theta, (0, 2, 1, 3)))

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
