"""Fitting the film: every band's characteristic curve and radiance chain through the backend seam.

Each band is one dataset of one model structure (:func:`bayescal.film.model.film_model`): one
compiled program serves all bands, the posterior mode of each is found by
:func:`~bayescal.inference.laplace.laplace`, and any registered backend samples them
(``sample_many``), as for the camera model.  The result, :class:`FilmFit`, saves a fit directory
that :meth:`bayescal.Calibration.load`, ``bayescal invert`` and ``bayescal report`` read
(``posterior.nc`` with ``kind = "film"``).
"""

from __future__ import annotations

import os
import time
import warnings
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np
import pandas as pd

from bayescal._config import computes
from bayescal._version import __version__
from bayescal.errors import TableError
from bayescal.film.model import band_model, film_model
from bayescal.film.spec import FilmSpec
from bayescal.film.table import FilmTable
from bayescal.fitting.result import fail
from bayescal.inference import registry as backends
from bayescal.inference.diagnostics import Diagnostics
from bayescal.inference.laplace import laplace
from bayescal.inference.program import LOGLIK, program_of
from bayescal.io.fit_folder import POSTERIOR, SUMMARY, TABLE
from bayescal.io.outputs import staged_directory, write_json_atomic, write_netcdf
from bayescal.io.summary import FitSummary

__all__ = ["BandFit", "FilmFit", "fit_film", "fit_film_table", "REPORTED"]

#: the quantities of each band in the summary: the curve, the reference radiance and the chain's inputs
REPORTED = ("gamma", "D0", "L_ref", "alpha", "beta", "tau_max", "meter", "D_min", "D_max")
#: what the verdict judges: the characteristic curve
JUDGED = ("gamma", "D0")


@dataclass(frozen=True)
class BandFit:
    """One band's posterior: constrained draws ``(chain, draw, ...)`` and the backend's verdict."""

    band: str
    draws: dict[str, np.ndarray]
    diagnostics: Diagnostics

    def flat(self, name: str) -> np.ndarray:
        """Draws of one quantity, chains merged: ``(n_draws, ...)``."""
        a = self.draws[name]
        return a.reshape((-1,) + a.shape[2:])


@dataclass(frozen=True)
class FilmFit:
    """Every band of a film calibration fitted: the kind ``film`` of a :class:`~bayescal.Fit`."""

    spec: FilmSpec
    table: FilmTable
    backend: str
    seed: int
    bands: dict[str, BandFit]
    timings: dict = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        """Every band passed its diagnostics."""
        return all(b.diagnostics.ok for b in self.bands.values())

    @cached_property
    def diagnostics(self) -> Diagnostics:
        """The bands' verdicts together (a problem names its band)."""
        problems = tuple(f"band {name}: {p}" for name, b in self.bands.items() for p in b.diagnostics.problems)
        per_band = [b.diagnostics for b in self.bands.values()]
        return Diagnostics(
            not problems,
            problems,
            divergences=sum(d.divergences for d in per_band),
            max_rhat=float(np.nanmax([d.max_rhat for d in per_band])),
            min_ess_bulk=float(np.nanmin([d.min_ess_bulk for d in per_band])),
            min_ess_tail=float(np.nanmin([d.min_ess_tail for d in per_band])),
            extra={"bands": {name: b.diagnostics.to_dict() for name, b in self.bands.items()}},
        )

    @cached_property
    def summary(self) -> pd.DataFrame:
        """Per band and quantity: mean, sd, 2.5/50/97.5 % quantiles."""
        rows = []
        for name, b in self.bands.items():
            for q in REPORTED:
                if q in b.draws:
                    d = b.flat(q)
                    lo, med, hi = np.quantile(d, [0.025, 0.5, 0.975])
                    rows.append(
                        {
                            "parameter": f"{q}[{name}]",
                            "mean": d.mean(),
                            "sd": d.std(),
                            "q2.5": lo,
                            "q50": med,
                            "q97.5": hi,
                        }
                    )
        return pd.DataFrame(rows).set_index("parameter")

    def to_dict(self) -> dict:
        """JSON-ready summary (``summary.json``, :class:`~bayescal.io.summary.FitSummary`): status,
        diagnostics per band, the curve and scale of each band."""
        return FitSummary(
            model_kind="film",
            status="ok" if self.ok else "FAILED",
            backend=self.backend,
            seed=self.seed,
            bayescal_version=__version__,
            model={"name": self.spec.name, "bands": list(self.bands), "toe_shoulder": self.spec.toe_shoulder},
            diagnostics=self.diagnostics.to_dict(),
            timings_s=self.timings,
            parameters=[{"parameter": k, **v} for k, v in self.summary.to_dict("index").items()],
        ).to_json()

    def summary_text(self) -> str:
        """Readable summary for the terminal: each band's curve with 95 % intervals."""
        lines = [
            f"Film {self.spec.name} ({self.backend}, seed {self.seed}): {len(self.bands)} bands, "
            f"{'toe and shoulder' if self.spec.toe_shoulder else 'straight part'} of the characteristic curve",
            f"Diagnostics: {self.diagnostics.verdict}",
        ]
        s = self.summary
        for name in self.bands:
            cells = []
            for q in ("gamma", "D0", "L_ref"):
                r = s.loc[f"{q}[{name}]"]
                cells.append(f"{q} {r['q50']:.4g} [{r['q2.5']:.4g}, {r['q97.5']:.4g}]")
            lines.append(f"  {name}: " + ", ".join(cells))
        lines.append("L_ref: the reference step's band radiance (mW sr^-1 cm^-2), eq. 3 and 10")
        return "\n".join(lines)

    @cached_property
    def posterior(self):
        """An arviz-style DataTree: ``posterior`` (dims chain, draw, band[, step]) and ``measurements``."""
        import xarray as xr

        names = sorted(set.intersection(*(set(b.draws) for b in self.bands.values())))
        band_names = list(self.bands)
        data = {}
        for k in names:
            stacked = np.stack([self.bands[b].draws[k] for b in band_names], axis=2)
            dims = ("chain", "draw", "band") + tuple(
                f"{k}_dim_{i}" if k not in ("T", "L_steps") else "step" for i in range(stacked.ndim - 3)
            )
            data[k] = (dims, stacked)
        post = xr.Dataset(data, coords={"band": band_names})
        tree = xr.DataTree.from_dict(
            {"posterior": post, "measurements": xr.Dataset.from_dataframe(self.table.frame.reset_index(drop=True))}
        )
        tree.attrs.update(kind="film", spec_toml=self.spec.to_toml(), backend=self.backend, seed=self.seed)
        tree.attrs["bayescal_version"] = __version__
        return tree

    def save(self, out_dir: str | os.PathLike, *, measurements: bool = False) -> Path:
        """Write ``posterior.nc``, ``summary.csv`` and ``summary.json`` as one new directory replacing ``out_dir``."""
        out_dir = Path(out_dir)
        with staged_directory(out_dir, kind="fit") as stage:
            if measurements:
                self.table.write_csv(stage("measurements.csv"))
            write_netcdf(self.posterior, stage(POSTERIOR))
            self.summary.to_csv(stage(TABLE), index_label="parameter", float_format="%.8g")
            write_json_atomic(stage(SUMMARY), self.to_dict())
        return out_dir


@computes
def fit_film_table(
    table: FilmTable,
    spec: FilmSpec,
    backend: str = "nuts",
    *,
    seed: int = 0,
    progress=None,
    strict: bool = False,
    stage=None,
) -> FilmFit:
    """Fit every band of ``table`` with ``spec`` (any posterior backend; ``seed`` seeds every band's sampler)."""
    say = stage or (lambda message: None)
    if backend not in backends.names():
        raise TableError(
            f"the film model is fitted by a posterior backend ({', '.join(backends.names())}), not '{backend}'"
        )
    t0 = time.perf_counter()
    models = []
    for name, (current, density) in table.bands.items():
        spec.band(name)  # a band the spec does not describe: a clear error
        if density.size != len(spec.wedge):
            raise TableError(
                f"band {name}: {density.size} wedge densities, expected {len(spec.wedge)}", column="density"
            )
        models.append(band_model(spec, name, current, density))
    say(f"{len(models)} bands: finding each posterior mode (the first fit compiles the film model)")
    program = program_of(film_model(spec.toe_shoulder, spec.reference_step), models[0].data, obs="D")
    modes = [laplace(program, m.data) for m in models]
    timings = {"prepare+map": time.perf_counter() - t0}
    t1 = time.perf_counter()
    samples = backends.get(backend).sample_many(
        models, program, modes, [seed] * len(models), iterations=progress, stage=say
    )
    timings[backend] = time.perf_counter() - t1
    bands = {}
    sampler = backends.get(backend)
    for m, draws, mode in zip(models, samples, modes, strict=True):
        chains, n, dim = draws.z.shape
        sites = program.constrain(draws.z.reshape(-1, dim), m.data, loglik=backends.reads_loglik(sampler))
        known = sites.pop(LOGLIK, None)  # the verdict's log-likelihood, from the same pass
        sites = {k: np.asarray(v).reshape((chains, n) + np.shape(v)[1:]) for k, v in sites.items() if k != "D"}
        judged = {k: sites[k] for k in JUDGED}
        diag = sampler.verdict(backends.judged(sampler, draws, program, m.data, known), judged, spec, mode)
        bands[m.band] = BandFit(m.band, sites, diag)
    result = FilmFit(spec, table, backend, seed, bands, timings)
    if not result.ok:
        fail(strict, f"film fit failed its diagnostics: {result.diagnostics.verdict}")
    return result


def fit_film(spec: FilmSpec, band: str, current: float, density, seed: int = 0, backend: str = "nuts") -> BandFit:
    """Fit one band's characteristic curve and chain to its wedge densities."""
    density = np.asarray(density, dtype=float)
    if not np.all(np.isfinite(density)):
        raise TableError(f"band {band}: a wedge density is not a number", column="density")
    spec.band(band)
    frame = pd.DataFrame(
        {"band": band, "step": np.arange(1, density.size + 1), "density": density, "meter_current": float(current)}
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return fit_film_table(FilmTable.from_frame(frame), spec, backend, seed=seed).bands[band]
