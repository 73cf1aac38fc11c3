"""A diagnosed fit: the posterior of one dataset, its checks, its summaries and its files.

:func:`finish` turns a backend's unconstrained draws into a :class:`Fit`: the backend's own
verdict (:mod:`bayescal.inference.registry`), the per-row outlier check, the misfit checks
(:mod:`bayescal.fitting.misfit`) and the leave-one-setting-out check (:mod:`bayescal.fitting.holdout`),
the reported quantities in physical units (:mod:`bayescal.model.physical`) and the arviz
DataTree that ``posterior.nc`` holds.  Every path to a fit (:func:`~bayescal.fitting.fit.fit`,
:meth:`~bayescal.fitting.batch.FitBatch.fit`) ends here.
"""

from __future__ import annotations

import os
import time
import warnings
from dataclasses import dataclass, field, replace
from functools import cached_property
from pathlib import Path

import numpy as np
import pandas as pd
import xarray as xr

from bayescal._version import __version__
from bayescal.errors import FitFailedError, FitFailedWarning, PosteriorError
from bayescal.fitting.holdout import holdout_checks
from bayescal.fitting.misfit import MisfitThresholds, misfit_checks
from bayescal.fitting.nuisance import nuisance_checks
from bayescal.fitting.variance import variance_checks
from bayescal.inference import registry as backends
from bayescal.inference.diagnostics import Diagnostics
from bayescal.inference.program import LOGLIK
from bayescal.io.fit_folder import LSQ, POSTERIOR, SUMMARY, TABLE
from bayescal.io.outputs import staged_directory, write_json_atomic, write_netcdf
from bayescal.io.summary import CALIBRATION, FitSummary
from bayescal.io.table import MeasurementTable
from bayescal.model.assemble import CalibrationModel
from bayescal.model.components import reported_dims, site_dims
from bayescal.model.physical import dims, physical_draws

__all__ = [
    "Fit",
    "coefficients_at_reference",
    "finish",
    "parameter_records",
    "parameter_table",
    "records",
    "row_summaries",
    "misfit_of",
    "fail",
    "REPORTED",
    "SAMPLED",
    "OUTLIER_Z",
]

#: quantities in the summary, in order: every component's reported quantities
REPORTED = tuple(reported_dims())
#: the sampled sites stored beside them in ``posterior.nc``
SAMPLED = tuple(site_dims())
#: what a fit whose mode has no positive-definite Hessian reports
NOT_IDENTIFIED = "the posterior mode's Hessian is not positive definite: the model is not identified by these data"


@dataclass(frozen=True)
class Fit:
    """A fitted calibration model.

    Attributes
    ----------
    model : CalibrationModel
        Spec, table and assembled model.
    backend : str
        ``nuts``, ``laplace``, ``emcee`` or ``lsq``.
    seed : int
        Seed of every random number in the fit.
    posterior : xarray.DataTree or None
        arviz DataTree (``posterior``, ``sample_stats``, ``measurements``);
        None for ``lsq``.
    diagnostics : Diagnostics
        Convergence verdict.
    lsq : pandas.DataFrame
        The papers' least-squares fits per channel and setting.
    timings : dict
        Wall seconds of the stages: ``prepare`` (data to arrays), ``map`` (the mode), the backend's
        sampler (``laplace``, ``nuts``, ...), ``lsq`` (the least-squares baseline), ``posterior`` (draws
        to physical quantities and the pointwise log-likelihood), ``checks`` (verdict, outliers,
        misfit), ``holdout`` (the leave-one-setting-out refits) and ``tree`` (the arviz DataTree);
        a batch's shared stages carry the prefix ``batch_``.
    """

    model: CalibrationModel
    backend: str
    seed: int
    posterior: xr.DataTree | None
    diagnostics: Diagnostics
    lsq: pd.DataFrame
    timings: dict = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        """Whether the diagnostics passed."""
        return self.diagnostics.ok

    @cached_property
    def summary(self) -> pd.DataFrame:
        """Per reported quantity: mean, sd, 2.5/50/97.5 % quantiles, R-hat, bulk/tail ESS."""
        if self.posterior is None:
            return pd.DataFrame()
        return parameter_table(self.posterior["posterior"].to_dataset())

    @cached_property
    def comparison(self) -> pd.DataFrame:
        """The papers' coefficients at the reference setting: least squares beside the posterior."""
        post = None if self.posterior is None else self.posterior["posterior"].to_dataset()
        return coefficients_at_reference(post, self.lsq, self.model.spec, self.model.layout.channels)

    def draws(self, name: str) -> np.ndarray:
        """Draws of one posterior variable, flattened over chains: shape ``(n_draws, ...)``."""
        if self.posterior is None:
            raise PosteriorError(f"a {self.backend} fit has no posterior draws (of '{name}' or any other quantity)")
        arr = np.asarray(self.posterior["posterior"][name])
        return arr.reshape((-1,) + arr.shape[2:])

    def to_dict(self) -> dict:
        """JSON-ready summary (``summary.json``, :class:`~bayescal.io.summary.FitSummary`): status,
        diagnostics, model, parameters and the LSQ baseline."""
        return self.fit_summary().to_json()

    def fit_summary(self) -> FitSummary:
        """The fit's summary, typed (:class:`~bayescal.io.summary.FitSummary`)."""
        spec, layout = self.model.spec, self.model.layout
        return FitSummary(
            model_kind=CALIBRATION,
            status="ok" if self.ok else "FAILED",
            backend=self.backend,
            seed=self.seed,
            bayescal_version=__version__,
            model={
                "name": spec.name,
                "components": self.model.parts.describe(),
                "reference": spec.to_dict()["reference"],
            },
            stimulus_unit=layout.unit,
            diagnostics=self.diagnostics.to_dict(),
            timings_s=self.timings,
            parameters=parameter_records(self.summary),
            comparison_at_reference=records(self.comparison),
            lsq=records(self.lsq),
        )

    def summary_text(self) -> str:
        """Readable summary: model, verdict, coefficients with 95 % intervals beside least squares."""
        spec, layout = self.model.spec, self.model.layout
        ref = spec.reference
        lines = [
            f"Model {spec.name} ({self.backend}, seed {self.seed}): " + "; ".join(self.model.parts.describe()),
            f"Diagnostics: {self.diagnostics.verdict}"
            + (
                f" (max R-hat {self.diagnostics.max_rhat:.4f}, min bulk ESS {self.diagnostics.min_ess_bulk:.0f}, "
                f"{self.diagnostics.divergences} divergences)"
                if np.isfinite(self.diagnostics.max_rhat)
                else ""
            ),
            *([f"Note: {self.diagnostics.extra['retried']}"] if "retried" in self.diagnostics.extra else []),
            "",
            f"DN = A0 + A1 L + ... at exposure {ref.exposure_s:g} s, gain {ref.gain:g}, TDI {ref.tdi_stages:g}; "
            f"L in {layout.unit}",
        ]
        cmp = self.comparison
        if len(cmp) == 0:
            return "\n".join(lines)
        titles = ("least squares [95% CI]", "Bayes vs sphere [95%]", "Bayes absolute [95%]")
        header = f"{'ch':>4} {'coef':>4} " + " ".join(f"{t:>34}" for t in titles)
        lines += [header, "-" * len(header)]
        for _, r in cmp.iterrows():
            cells = [f"{r['channel']:>4}", f"{r['coefficient']:>4}"]
            for key in ("lsq", "bayes_rel", "bayes_abs"):
                if key in r and np.isfinite(r.get(key, np.nan)):
                    cells.append(f"{f5(r[key]):>12} [{f5(r[key + '_lo'])}, {f5(r[key + '_hi'])}]".rjust(34))
                else:
                    cells.append(f"{'-':>34}")
            lines.append(" ".join(cells))
        lines.append(
            "'vs sphere': relative to the sphere's radiance scale (what least squares sees); "
            f"'absolute': with its {spec.sphere.common_rel:.1%} scale uncertainty folded in"
            + (
                f" and each channel's own {spec.sphere.channel_scale_rel:.1%}."
                if spec.sphere.channel_scale_rel > 0
                else "."
            )
        )
        if "lsq_r2" in cmp:
            r2 = cmp.groupby("channel", sort=False)["lsq_r2"].first()
            lines.append("Least-squares R^2: " + ", ".join(f"{c} {v:.5f}" for c, v in r2.items()))
        return "\n".join(lines)

    def save(self, out_dir: str | os.PathLike, *, measurements: bool = False) -> Path:
        """Write ``posterior.nc``, ``summary.csv``, ``summary.json`` and ``lsq.csv`` (and, with
        ``measurements``, the table as ``measurements.csv``) as one new directory that replaces
        ``out_dir`` whole (see :func:`bayescal.io.files.staged_directory`)."""
        out_dir = Path(out_dir)
        with staged_directory(out_dir, kind="fit") as stage:
            if measurements:
                self.model.table.write_csv(stage("measurements.csv"))
            if self.posterior is not None:
                write_netcdf(self.posterior, stage(POSTERIOR))
                self.summary.to_csv(stage(TABLE), index_label="parameter", float_format="%.8g")
            else:
                self.lsq.to_csv(stage(TABLE), index=False, float_format="%.8g")
            self.lsq.to_csv(stage(LSQ), index=False, float_format="%.8g")
            write_json_atomic(stage(SUMMARY), self.to_dict())
        return out_dir


def finish(model, program, draws, backend: str, seed: int, result, lsq, timings: dict, strict: bool = False) -> Fit:
    """From a backend's unconstrained draws ``(chain, draw, dim)`` of one dataset to a diagnosed :class:`Fit`:
    the backend's verdict, the outlier, misfit and leave-one-setting-out checks, the posterior in
    physical units and the arviz DataTree."""
    spec, table = model.spec, model.table
    z, stats = draws.z, draws.stats
    timings = dict(timings)
    t = time.perf_counter()
    post, rows, loglik = _posterior(model, program, z, seed)
    # the DataTree's log_likelihood group, and the verdict's
    draws = backends.with_loglik(draws, program, model.data, loglik)
    loglik = draws.loglik
    timings["posterior"] = time.perf_counter() - t
    t = time.perf_counter()
    # the sampler is judged on what is reported: most sampled sites are reported through an elementwise
    # monotone map (G as gain, b0 as dark_offset, eta as nonlinearity), under which the rank-normalised R-hat
    # and ESS do not change, so judging the sites too mostly repeated the work (0.42 s against 0.24 s per
    # NUTS fit of seed 000, the same max R-hat and min ESS)
    reported = {k: v for k, v in post.items() if k in REPORTED}
    diag = backends.get(backend).verdict(draws, reported, spec, result)
    if not result.positive_definite:
        diag = diag.with_check("identified", [NOT_IDENTIFIED], {"hessian_positive_definite": False})
    diag = _check_outliers(model, rows, diag)
    diag = _check_misfit(model, rows, post, diag)
    diag = diag.with_check("nuisances", *nuisance_checks(model, post, _coords(model)))
    diag = diag.with_check("variance", *variance_checks(model, rows["signal"] * model.layout.dn_scale))
    timings["checks"] = time.perf_counter() - t
    if spec.inference.holdout_check and result.positive_definite:
        t = time.perf_counter()
        diag = _check_holdout(model, program, result.mode, seed, diag)
        timings["holdout"] = time.perf_counter() - t
    t = time.perf_counter()
    if not diag.ok:
        fail(strict, f"fit failed its diagnostics: {diag.verdict}")
    with warnings.catch_warnings():  # emcee has more walkers than thinned draws, by design
        warnings.filterwarnings("ignore", "Found chain dimension", UserWarning)
        import arviz_base

        dt = arviz_base.from_dict(
            {
                "posterior": post,
                "log_likelihood": {"obs": loglik},
                **({"sample_stats": stats} if stats else {}),
            },
            dims={**{k: v for k, v in dims().items() if k in post}, "obs": ["row"]},
            coords=_coords(model),
        )
    dt.attrs.update(spec_toml=spec.to_toml(), backend=backend, seed=seed, bayescal_version=__version__)
    dt["measurements"] = xr.DataTree(_table_dataset(table))
    timings["tree"] = time.perf_counter() - t
    return Fit(model, backend, seed, dt, diag, lsq, timings)


def row_summaries(sites: dict) -> dict[str, np.ndarray]:
    """Each row's posterior predictive mean and variance and its mean signal (scaled units), from the
    constrained sites of a batch of draws: what the outlier and misfit checks read."""
    mean = np.asarray(sites["row_mean"])
    return {
        "mean": mean.mean(axis=0),
        "var": np.mean(np.asarray(sites["row_sd"]) ** 2, axis=0) + np.var(mean, axis=0),
        "signal": np.asarray(sites["row_signal"]).mean(axis=0),
    }


def _posterior(model: CalibrationModel, program, z: np.ndarray, seed: int) -> tuple[dict, dict, np.ndarray]:
    """Reported draws, each row's posterior predictive mean and variance (scaled units), and each draw's
    pointwise log-likelihood ``(chain, draw, row)`` (one pass of the program over the draws)."""
    chains, draws, dim = z.shape
    sites = program.constrain(np.asarray(z).reshape(-1, dim), model.data, loglik=True)
    rows = row_summaries(sites)
    sites = {k: np.asarray(v).reshape((chains, draws) + np.shape(v)[1:]) for k, v in sites.items()}
    post = {k: v for k, v in sites.items() if k in SAMPLED}
    post.update(physical_draws(model, sites, seed))
    return post, rows, sites[LOGLIK]


#: a row whose reading lies this many predictive sds from the posterior mean is reported (p ~ 6e-7 each)
OUTLIER_Z = 5.0


def _check_outliers(model: CalibrationModel, rows: dict, diag: Diagnostics) -> Diagnostics:
    """Posterior predictive check per row: name rows the model cannot explain, loudly."""
    data = model.data
    z = (np.asarray(data.y) - rows["mean"]) / np.sqrt(rows["var"])
    z = np.where(np.asarray(data.censored), 0.0, z)
    worst = np.argsort(-np.abs(z))
    bad = [int(i) for i in worst if abs(z[i]) > OUTLIER_Z]
    extra = dict(diag.extra, max_abs_residual_z=float(np.max(np.abs(z))) if z.size else 0.0)
    if not bad:
        return replace(diag, extra=extra)
    frame = model.table.frame
    scale = model.layout.dn_scale
    described = []
    for i in bad[:5]:
        r = frame.iloc[i]
        described.append(
            f"row {i + 1} (channel {r['channel']}, {model.table.stimulus} {r['stimulus']:g}, exposure "
            f"{r['exposure_s']:g} s, gain {r['gain']:g}): dn_mean {r['dn_mean']:g} is "
            f"{(float(data.y[i]) - rows['mean'][i]) * scale:+.3g} DN ({z[i]:+.1f} sd) from the model"
        )
    more = f" and {len(bad) - 5} more" if len(bad) > 5 else ""
    problem = f"{len(bad)} outlying row(s), e.g. " + "; ".join(described) + more + ": check those frames"
    return replace(diag, ok=False, problems=diag.problems + (problem,), extra=extra)


def misfit_of(model: CalibrationModel, rows: dict, excess_dn: np.ndarray | None) -> tuple[list[str], dict]:
    """The misfit checks (:mod:`bayescal.fitting.misfit`) of one fit: ``rows`` from :func:`row_summaries`,
    ``excess_dn`` the draws of the excess scatter in DN (None when not modelled)."""
    data, scale, settings = model.data, model.layout.dn_scale, model.spec.inference
    floor_var = np.asarray(model.parts.noise.nominal_pixel_variance(data, rows["signal"])) / np.asarray(data.n_avg)
    thresholds = MisfitThresholds(settings.misfit_excess_ratio, settings.misfit_group_z, settings.misfit_runs_z)
    problems, info = misfit_checks(
        model.table.frame,
        np.asarray(data.y) * scale,
        rows["mean"] * scale,
        np.sqrt(rows["var"]) * scale,
        rows["signal"] * scale,
        np.sqrt(floor_var) * scale,
        None if excess_dn is None else np.asarray(excess_dn).ravel(),
        np.asarray(data.censored),
        thresholds,
        drift_terms(model),
    )
    info["thresholds"] = {"excess_ratio": thresholds.excess_ratio, "group_z": thresholds.group_z}
    return problems, info


def drift_terms(model: CalibrationModel) -> frozenset[str]:
    """The drift terms ``model`` has, and a frame's offset (their remedies are not suggested again)."""
    on = {e.section for e in model.parts.effects if e.section in ("offset_drift", "stimulus_drift", "frame_offset")}
    return frozenset(on | ({"dark.drift"} if model.spec.dark.drift else set()))


def _check_misfit(model: CalibrationModel, rows: dict, post: dict, diag: Diagnostics) -> Diagnostics:
    """Does the model describe its data to within their noise? Fails the fit, naming where, if not."""
    return diag.with_check("misfit", *misfit_of(model, rows, post.get("excess_dn")))


def _check_holdout(model: CalibrationModel, program, mode, seed: int, diag: Diagnostics) -> Diagnostics:
    """Leave each setting's rows out in turn: do the other rows predict them? (:mod:`bayescal.fitting.holdout`)"""
    return diag.with_check("holdout", *holdout_checks(model, program, mode, model.spec.inference.misfit_group_z, seed))


def fail(strict: bool, message: str) -> None:
    """A failed fit: raise :class:`~bayescal.errors.FitFailedError` (``strict``) or warn."""
    if strict:
        raise FitFailedError(message)
    warnings.warn(message, FitFailedWarning, stacklevel=3)


def _coords(model: CalibrationModel) -> dict:
    layout, spec = model.layout, model.spec
    coords = {
        "channel": list(layout.channels),
        "power": list(range(spec.response.order + 1)),
        "nl_term": list(range(1, spec.response.order)),
        "level": list(layout.levels),
        "exposure_setting": list(layout.exposure_values),
        "lit_gain_setting": list(layout.lit_gain_values),
        "tdi_setting": list(layout.tdi_values),
    }
    refs = dict(model.parts.settings.ref_index)
    for kind in ("gain", "exposure", "tdi"):
        values = list(layout.setting_values(kind))
        coords[f"{kind}_free"] = [v for i, v in enumerate(values) if i != refs[kind]]
    if not model.parts.dark.proportional:
        coords["gain_setting"] = list(layout.gain_values)
    else:
        coords["gain_setting"] = [spec.reference.gain]
    for effect in model.parts.effects:
        coords |= effect.coords()
    return coords


def _table_dataset(table: MeasurementTable) -> xr.Dataset:
    df = table.to_frame().reset_index(drop=True)
    ds = xr.Dataset(
        {c: ("row", df[c].to_numpy().astype(str) if df[c].dtype == object else df[c].to_numpy()) for c in df}
    )
    ds.attrs.update(stimulus=table.stimulus, unit=table.unit, source=table.source)
    return ds


def parameter_table(post: xr.Dataset) -> pd.DataFrame:
    """Per reported quantity of a posterior: mean, sd, 2.5/50/97.5 % quantiles, R-hat, bulk/tail ESS."""
    names = [v for v in REPORTED if v in post]
    with warnings.catch_warnings():  # R-hat of the reference setting's factor (a constant 1) is NaN, by design
        warnings.simplefilter("ignore", RuntimeWarning)
        import arviz_stats

        table = arviz_stats.summary(post[names], ci_prob=0.95, ci_kind="eti", round_to="none")
    median = _flat_stat(post[names], lambda a: np.median(a, axis=(0, 1)))
    table.insert(2, "q2.5", table.pop("eti95_lb"))
    table.insert(3, "q50", median.reindex(table.index))
    table.insert(4, "q97.5", table.pop("eti95_ub"))
    return table[["mean", "sd", "q2.5", "q50", "q97.5", "r_hat", "ess_bulk", "ess_tail"]]


def coefficients_at_reference(post: xr.Dataset | None, lsq: pd.DataFrame, spec, channels) -> pd.DataFrame:
    """The papers' coefficients at ``spec``'s reference setting per channel: the least-squares fit there
    (``lsq``) beside the posterior's ``A_rel`` and ``A_abs`` (mean and 95 % interval; none without one)."""
    ref = spec.reference
    order = spec.response.order
    rows = []
    at_ref = (
        lsq[
            np.isclose(lsq.get("exposure_s", np.nan), ref.exposure_s)
            & np.isclose(lsq.get("gain", np.nan), ref.gain)
            & np.isclose(lsq.get("tdi_stages", np.nan), ref.tdi_stages)
            & (lsq.get("order", -1) == order)
        ]
        if len(lsq)
        else lsq
    )
    for ci, channel in enumerate(channels):
        lrow = at_ref[at_ref["channel"] == channel] if len(at_ref) else at_ref
        for k in range(order + 1):
            row: dict[str, object] = {"channel": channel, "coefficient": f"A{k}"}
            if len(lrow):
                r = lrow.iloc[0]
                row.update(lsq=r[f"A{k}"], lsq_lo=r[f"A{k}_lo"], lsq_hi=r[f"A{k}_hi"], lsq_r2=r["r2"])
            if post is not None:
                for kind in ("rel", "abs"):
                    a = np.asarray(post[f"A_{kind}"])[..., ci, k].ravel()
                    row.update(
                        {
                            f"bayes_{kind}": float(a.mean()),
                            f"bayes_{kind}_lo": float(np.quantile(a, 0.025)),
                            f"bayes_{kind}_hi": float(np.quantile(a, 0.975)),
                        }
                    )
            rows.append(row)
    return pd.DataFrame(rows)


def _flat_stat(ds: xr.Dataset, fn) -> pd.Series:
    out = {}
    for name, da in ds.data_vars.items():
        values = fn(np.asarray(da))
        dims = da.dims[2:]
        if not dims:
            out[name] = float(values)
            continue
        coords = [da[d].values for d in dims]
        for idx in np.ndindex(values.shape):
            label = ", ".join(str(coords[i][j]) for i, j in enumerate(idx))
            out[f"{name}[{label}]"] = float(values[idx])
    return pd.Series(out)


def records(df: pd.DataFrame) -> list[dict]:
    """A table as JSON-ready rows (numpy scalars as Python numbers)."""
    return [{k: (v.item() if hasattr(v, "item") else v) for k, v in row.items()} for row in df.to_dict("records")]


def parameter_records(table: pd.DataFrame) -> list[dict]:
    """:func:`parameter_table`'s rows for ``summary.json``, each with its ``parameter`` name."""
    return records(table.reset_index(names="parameter")) if len(table) else []


def f5(x: float) -> str:
    """A number to 5 significant digits."""
    return f"{x:.5g}"
