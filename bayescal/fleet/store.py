"""A fitted fleet on disk: the directory :meth:`FleetFit.save` writes and :meth:`FleetFit.load` reads.

``fleet.nc`` holds the stage-two draws, each unit's stage-one Gaussian and the structure the
predictions need (the plan, the units' dates and slots); beside it the summaries as CSV and JSON
and each camera's latest stage-one fit under ``cameras/``.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd

from bayescal.errors import PosteriorError
from bayescal.fleet.plan import FleetData, Plan
from bayescal.fleet.sampling import FleetDraws
from bayescal.model.spec import ModelSpec

if TYPE_CHECKING:
    from bayescal.fleet.posterior import FleetFit

__all__ = ["FLEET_FILE", "save_fleet", "load_fleet", "fleet_dataset", "safe_name"]

#: the fleet posterior file inside a fleet directory
FLEET_FILE = "fleet.nc"


def safe_name(name: str) -> str:
    """A camera's name as a directory name (letters, digits, ``-_.``; anything else ``_``)."""
    return "".join(ch if ch.isalnum() or ch in "-_." else "_" for ch in name)


def save_fleet(fit: FleetFit, out_dir: str | os.PathLike) -> Path:
    """Write the fleet directory (replacing ``out_dir`` whole): ``fleet.nc`` (draws and the
    stage-one summaries), ``summary.csv``, ``hyperparameters.csv``, ``units.csv``,
    ``summary.json``, and each camera's latest stage-one fit under ``cameras/``."""
    from bayescal.io.outputs import staged_directory, write_json_atomic, write_netcdf

    with staged_directory(out_dir, kind="fleet") as stage:
        write_netcdf(fleet_dataset(fit), stage(FLEET_FILE))
        fit.summary().to_csv(stage("summary.csv"), index=False, float_format="%.8g")
        fit.hyperparameters().to_csv(stage("hyperparameters.csv"), index=False, float_format="%.8g")
        fit.units.to_csv(stage("units.csv"), index=False, float_format="%.8g")
        write_json_atomic(stage("summary.json"), fit.to_dict())
        if fit.fits is not None:
            import warnings

            from bayescal.errors import FitFailedWarning

            for camera in fit.cameras:
                u = int(np.flatnonzero(fit.units["camera"].to_numpy() == camera)[-1])
                with warnings.catch_warnings():  # the unit's verdict is in units.csv and the fleet's warnings
                    warnings.simplefilter("ignore", FitFailedWarning)
                    fit.fits.fit(u).save(stage(f"cameras/{safe_name(camera)}"))
    return Path(out_dir)


def fleet_dataset(fit: FleetFit):
    """The draws, stage-one summaries and structure of a fleet as one dataset (its fleet.nc)."""
    import xarray as xr

    ds = xr.Dataset()
    for name, v in fit.draws.draws.items():
        ds[name] = (("chain", "draw") + tuple(f"{name}_dim{i}" for i in range(v.ndim - 2)), v)
    ds["log_likelihood"] = (("chain", "draw", "unit"), fit.draws.log_likelihood)
    ds["unit_mean"] = (("unit", "kind", "channel"), fit.unit_mean)
    ds["unit_cov"] = (("unit", "q1", "q2"), fit.unit_cov)
    for name in ("camera", "sphere", "years", "walk_units", "walk_dt", "walk_slot", "unit_slot", "campaign"):
        ds[f"data_{name}"] = ((f"data_{name}_dim",), np.asarray(getattr(fit.data, name)))
    ds["data_center"] = (("kind", "channel"), fit.data.center)
    ds["data_scale"] = (("kind",), fit.data.scale)
    ds.attrs = {
        "spec_toml": fit.spec.to_toml(),
        "plan": json.dumps(fit.plan.__dict__),
        "diagnostics": json.dumps(fit.draws.diagnostics),
        "kinds": json.dumps(list(fit.kinds)),
        "channels": json.dumps(list(fit.channels)),
        "cameras": json.dumps(list(fit.cameras)),
        "origin": "" if fit.origin is None else fit.origin.isoformat(),
        "units": fit.units.to_json(orient="records"),
        "seed": fit.seed,
        "t_mean": fit.data.t_mean,
        "sphere_sd": fit.data.sphere_sd,
        "campaign_sd": fit.data.campaign_sd,
    }
    return ds


def load_fleet(path: str | os.PathLike) -> dict[str, Any]:
    """The fields of a :class:`~bayescal.fleet.posterior.FleetFit` read from a fleet directory written by
    :func:`save_fleet` (or its ``fleet.nc``); :meth:`FleetFit.load` builds the fit from them."""
    import io
    import tomllib

    import xarray as xr

    from bayescal.io.outputs import verify_output

    path = Path(path)
    file = path / FLEET_FILE if path.is_dir() else path
    if not file.is_file():
        raise PosteriorError(f"no fleet posterior at {file}; run `bayescal fleet TABLE --out DIR` first")
    verify_output(file, ("fleet",), verb="reading a fleet")
    try:
        ds = xr.load_dataset(file, engine="h5netcdf")
        a = ds.attrs
        spec = ModelSpec.from_dict(tomllib.loads(a["spec_toml"]), source=str(file))
        plan = Plan(**json.loads(a["plan"]))
        units = pd.read_json(io.StringIO(a["units"]), orient="records", dtype={"campaign": str})
    except PosteriorError:
        raise
    except Exception as exc:  # netCDF/HDF5 and JSON raise many types for foreign or truncated files
        raise PosteriorError(
            f"{file} is not a fleet posterior written by bayescal ({type(exc).__name__}: {exc})"
        ) from None
    units["campaign"] = units["campaign"].where(units["campaign"].notna() & (units["campaign"] != "None"), None)
    draws = {str(k): np.asarray(ds[k]) for k in ds.data_vars if "chain" in ds[k].dims and k != "log_likelihood"}
    years = np.asarray(ds["data_years"], dtype=float)
    empty = np.zeros((0,))
    data = FleetData(
        y=np.zeros((plan.n_units, 0)),
        chol=np.zeros((plan.n_units, 0, 0)),
        camera=np.asarray(ds["data_camera"], dtype=int),
        sphere=np.asarray(ds["data_sphere"], dtype=int),
        t=years - float(a["t_mean"]),
        years=years,
        walk_units=np.asarray(ds["data_walk_units"], dtype=int),
        walk_dt=np.asarray(ds["data_walk_dt"], dtype=float),
        walk_interval=np.asarray(np.mean(ds["data_walk_dt"]) if ds["data_walk_dt"].size else 1.0, dtype=float),
        walk_slot=np.asarray(ds["data_walk_slot"], dtype=int),
        unit_slot=np.asarray(ds["data_unit_slot"], dtype=int),
        shared_chol=empty,
        campaign=np.asarray(ds["data_campaign"], dtype=int),
        campaign_sd=float(a["campaign_sd"]),
        sphere_sd=float(a["sphere_sd"]),
        center=np.asarray(ds["data_center"]),
        scale=np.asarray(ds["data_scale"]),
        t_mean=float(a["t_mean"]),
        g_gg=empty,
        g_gm=empty,
        g_mm=empty,
        b_g=empty,
        b_m=empty,
        prior_var_g=empty,
        active=empty,
        yy=empty,
        n_rows=empty,
    )
    return dict(
        spec=spec,
        kinds=tuple(json.loads(a["kinds"])),
        channels=tuple(json.loads(a["channels"])),
        cameras=tuple(json.loads(a["cameras"])),
        units=units,
        data=data,
        plan=plan,
        draws=FleetDraws(draws, np.asarray(ds["log_likelihood"]), json.loads(a["diagnostics"])),
        origin=pd.Timestamp(a["origin"]) if a["origin"] else None,
        fits=None,
        seed=int(a["seed"]),
        unit_mean=np.asarray(ds["unit_mean"]),
        unit_cov=np.asarray(ds["unit_cov"]),
    )
