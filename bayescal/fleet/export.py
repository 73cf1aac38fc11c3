"""A camera's calibration from the fleet, as a fit directory that every verb reads.

The fleet posterior gives a camera's gain, offset and nonlinearity at a date (shrunk
toward the fleet, drift extrapolated, or drawn from the population for a camera that
was never measured).  Everything else a calibration needs (dark slopes per gain, the
settings' effective factors, noise) comes from the camera's latest stage-one fit (for
a camera never measured: from a measured camera of the type, named in the output).
The result is a ``posterior.nc`` in the layout of ``bayescal fit``, so ``predict``,
``invert``, ``plan`` and ``report`` use it unchanged (docs/architecture.md, section 8).
"""

from __future__ import annotations

import os
import tomllib
from pathlib import Path

import numpy as np
import pandas as pd

from bayescal._version import __version__
from bayescal.errors import PosteriorError
from bayescal.fitting.result import coefficients_at_reference, parameter_records, parameter_table, records
from bayescal.fleet.posterior import FleetFit
from bayescal.fleet.store import safe_name
from bayescal.inference.diagnostics import Diagnostics
from bayescal.io.fit_folder import POSTERIOR, SUMMARY, FitFolder
from bayescal.io.summary import FitSummary
from bayescal.model.physical import reported_from_pooled
from bayescal.model.spec import ModelSpec

__all__ = ["fleet_calibration", "write_calibration"]


def write_calibration(
    fleet_dir: str | os.PathLike,
    out_dir: str | os.PathLike,
    camera: str | None,
    date=None,
    *,
    template: str | None = None,
    seed: int = 0,
) -> Path:
    """Write ``out_dir``: camera ``camera`` (None: one never measured) calibrated at ``date``.

    Parameters
    ----------
    fleet_dir : path
        A directory written by ``bayescal fleet``.
    date : str or Timestamp, optional
        Default: the camera's last campaign (required for a camera never measured).
    template : str, optional
        The measured camera whose stage-one fit supplies the quantities the fleet does
        not model (default: the camera itself; for a new camera, the fleet's first).
    """
    import xarray as xr

    from bayescal.io.outputs import check_output_dir, staged_directory, write_json_atomic, write_netcdf

    fleet_dir = Path(fleet_dir)
    fleet = FleetFit.load(fleet_dir)
    check_output_dir(out_dir, "fit")
    source = template or camera or fleet.cameras[0]
    fleet.camera_index(source)
    path = fleet_dir / "cameras" / safe_name(source) / POSTERIOR
    if not path.is_file():
        raise PosteriorError(f"{path} is missing; the fleet directory is incomplete (re-run `bayescal fleet`)")
    tree = xr.open_datatree(path)
    post = tree["posterior"].to_dataset()
    chains, draws = post.sizes["chain"], post.sizes["draw"]
    values = fleet.at(camera, date, seed=seed)  # (S, K, C)
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0xCA11B]))
    values = values[rng.integers(0, values.shape[0], chains * draws)]
    reported = reported_from_pooled({k: values[:, i] for i, k in enumerate(fleet.kinds)}, fleet.spec)
    coef, gain, eta = reported["A_rel"], reported["gain_rel"], reported.get("nonlinearity")
    offset = coef[..., 0]
    shape = (chains, draws)
    old_a0 = np.asarray(post["A_abs"])[..., 0].reshape(chains * draws, -1)
    shift = (offset - old_a0).reshape(shape + (-1,))
    post["A_abs"] = (post["A_abs"].dims, coef.reshape(shape + coef.shape[1:]))
    post["A_rel"] = (post["A_rel"].dims, coef.reshape(shape + coef.shape[1:]))
    post["gain"] = (post["gain"].dims, gain.reshape(shape + gain.shape[1:]))
    post["gain_rel"] = (post["gain_rel"].dims, gain.reshape(shape + gain.shape[1:]))
    if eta is not None and "nonlinearity" in post:
        post["nonlinearity"] = (post["nonlinearity"].dims, eta.reshape(shape + eta.shape[1:]))
    for name in ("dark_offset", "dark_offset_ref"):
        if name in post:
            extra = post[name].ndim - shift.ndim
            post[name] = post[name] + shift.reshape(shift.shape + (1,) * extra)
    if "sphere_scale" in post:
        post["sphere_scale"] = post["sphere_scale"] * 0 + 1.0
    tree["posterior"] = post
    label = camera or "a camera of the type never measured"
    when = "its last campaign" if date is None else str(date)
    tree.attrs["fleet_source"] = f"{fleet_dir} camera={label} date={when} template={source} seed={seed}"
    spec = ModelSpec.from_dict(tomllib.loads(tree.attrs["spec_toml"]), source=str(path))
    source_of = {
        "fleet": str(fleet_dir),
        "camera": camera,
        "date": None if date is None else str(date),
        "template": source,
        "note": "gain, offset and nonlinearity from the fleet hierarchy (absolute: the sphere's scale "
        "folded in by the fleet); dark slopes, setting factors and noise from the template camera's fit; "
        "the least-squares baseline is the template camera's, at its last campaign",
    }
    summary = _summary(fleet, FitFolder.at(path.parent, "a fleet's export").summary, post, spec, seed, source_of)
    with staged_directory(out_dir, kind="fit") as stage:
        write_netcdf(tree, stage(POSTERIOR))
        write_json_atomic(stage(SUMMARY), summary.to_json())
    return Path(out_dir)


def _summary(fleet: FleetFit, template: FitSummary, post, spec: ModelSpec, seed: int, source: dict) -> FitSummary:
    """The exported calibration's summary, of the one schema every fit folder has: the fleet's verdict and
    diagnostics, the parameters of the exported posterior, and the template camera's model and
    least-squares baseline (at the reference setting, beside the exported coefficients)."""
    lsq = pd.DataFrame(template.lsq)
    channels = [str(c) for c in post["A_abs"].coords["channel"].values]
    judged = fleet.draws.diagnostics  # divergences, R-hat and ESS of the fleet's scales
    verdict = Diagnostics(
        fleet.ok,
        tuple(fleet.problems),
        int(judged["divergences"]),
        judged["max_rhat"],
        judged["min_ess_bulk"],
        judged["min_ess_tail"],
        {k: v for k, v in judged.items() if k not in ("divergences", "max_rhat", "min_ess_bulk", "min_ess_tail")},
    )
    return FitSummary(
        model_kind=template.model_kind,
        status="ok" if verdict.ok else "FAILED",
        backend="fleet",
        seed=seed,
        bayescal_version=__version__,
        model=template.model,
        stimulus_unit=template.stimulus_unit,
        diagnostics=verdict.to_dict(),
        parameters=parameter_records(parameter_table(post)),
        comparison_at_reference=records(coefficients_at_reference(post, lsq, spec, channels)),
        lsq=template.lsq,
        source=source,
    )


#: the public name (``bayescal.fleet_calibration``)
fleet_calibration = write_calibration
