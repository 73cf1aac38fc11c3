"""What a maps store says about itself: variable attributes, provenance, each channel's population.

Follows the Earth-observation uncertainty conventions: each mapped quantity
names its uncertainty variables in ``unc_comps``; each uncertainty variable
states its error correlation across pixels in ``err_corr`` (``random``:
independent from pixel to pixel; ``systematic``: common to all pixels).
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import json
from pathlib import Path
from typing import Any

import numpy as np

from bayescal._version import __version__
from bayescal.errors import SpecError
from bayescal.maps.model import DEFECT_CODES, MapModel, SensorModel
from bayescal.maps.population import combination_spread
from bayescal.maps.stacks import Manifest

__all__ = ["variable_attrs", "provenance", "channel_attrs"]

_UNITS = {"offset_dn": "DN", "dark_current_dn_s": "DN s-1", "relative_gain": "1"}
_LONG = {
    "offset_dn": "pixel offset (dark level at zero exposure)",
    "dark_current_dn_s": "pixel dark current",
    "relative_gain": "pixel gain relative to the channel (1 + PRNU deviation)",
}


def variable_attrs(name: str) -> dict:
    base = name.removeprefix("u_random_").removeprefix("lsq_")
    if name in _UNITS:
        attrs: dict[str, Any] = {"units": _UNITS[name], "long_name": _LONG[name] + ", posterior mean"}
        comps = [f"u_random_{name}"]
        if name == "relative_gain":
            comps.append("u_systematic_relative_gain")
        attrs["unc_comps"] = comps
        return attrs
    if name.startswith("u_random_"):
        return {
            "units": _UNITS[base],
            "long_name": f"per-pixel posterior standard deviation of {base}",
            "err_corr": json.dumps([{"dim": ["y", "x"], "form": "random", "params": [], "units": []}]),
            "pdf_shape": "gaussian",
        }
    if name.startswith("lsq_"):
        return {"units": _UNITS[base], "long_name": f"{base}, per-pixel weighted least squares (baseline)"}
    derived: dict[str, dict[str, Any]] = {
        "corr_offset_dark": {"units": "1", "long_name": "posterior correlation of offset and dark current"},
        "defect_probability": {"units": "1", "long_name": "posterior probability that the pixel is defective"},
        "noisy_probability": {"units": "1", "long_name": "posterior probability of excess temporal noise"},
        "noise_scale": {"units": "1", "long_name": "expected temporal-variance scale of the pixel"},
        "defect": {
            "long_name": "defect class",
            "flag_values": list(DEFECT_CODES),
            "flag_meanings": " ".join(DEFECT_CODES.values()),
        },
    }
    return derived[name]


def provenance(manifest: Manifest, sensor: SensorModel, calibration: str | None) -> dict:
    """The store's attributes: where the maps came from, and each channel's population.

    A monochrome sensor's population attributes sit at the top level; a
    mosaic's are in ``channel_attrs`` (JSON, one entry per channel); read
    either with :func:`channel_attrs`.
    """
    digest = hashlib.sha256((manifest.directory / "conditions.csv").read_bytes()).hexdigest()
    attrs = {
        "title": "bayescal per-pixel calibration maps",
        "bayescal_version": __version__,
        "created": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
        "stacks": manifest.source or str(manifest.directory),
        "manifest_sha256": digest,
        "source_sha256": hashlib.sha256(Path(manifest.source).read_bytes()).hexdigest() if manifest.source else "",
        "calibration": calibration or "",
        "channels": list(sensor.models),
        "cfa": sensor.cfa or "",
        "u_systematic_relative_gain_err_corr": json.dumps(
            [{"dim": ["y", "x"], "form": "systematic", "params": [], "units": []}]
        ),
    }
    per_channel = {name: _channel_provenance(model) for name, model in sensor.models.items()}
    if sensor.cfa is None:
        attrs.update(next(iter(per_channel.values())))
    else:
        attrs["channel_attrs"] = json.dumps(per_channel)
    return attrs


def channel_attrs(ds, channel: str | None = None) -> dict:
    """One channel's population attributes of a maps dataset (the first channel by default)."""
    if "channel_attrs" not in ds.attrs:
        return dict(ds.attrs)
    per = json.loads(ds.attrs["channel_attrs"])
    if channel is None:
        return per[next(iter(per))]
    if channel not in per:
        raise SpecError(f"the maps hold channels {', '.join(per)}; not '{channel}'")
    return per[channel]


def _channel_provenance(model: MapModel) -> dict:
    pop = model.population
    names = model.names
    spread = pop.spread
    flats = model.stacks["kind"] == "flat"
    systematic = float(np.sqrt(np.mean(model.signal_se[flats.to_numpy()] ** 2)))
    attrs = {
        "parameters": list(names),
        "population_weights": pop.weights.tolist(),
        "population_mean": pop.means[0].tolist(),
        "population_cov": pop.covs[0].ravel().tolist(),
        "defect_mean": pop.means[1].tolist(),
        "defect_cov": pop.covs[1].ravel().tolist(),
        "em_iterations": pop.iterations,
        "em_converged": int(pop.converged),
        "noisy_fraction": model.noise.fraction,
        "noisy_scale": model.noise.scale,
        "fit_pixels": model.info["fit_pixels"],
        "stacks_table": model.stacks.to_json(orient="records"),
        "design_X": model.design.X.ravel().tolist(),
        "design_var": model.design.var.tolist(),
        "u_systematic_relative_gain": systematic,
    }
    thermal = model.info.get("thermal")
    if thermal is not None:  # the dark current is at temperature_ref_c; it doubles every doubling_c degrees
        attrs.update({k: thermal[k] for k in ("temperature_ref_c", "doubling_c", "doubling_c_se")})
    for j, name in enumerate(names):
        attrs[f"spread_{name}"] = float(spread[j])
        attrs[f"spread_{name}_se"] = float(model.spread_se[j])
        attrs[f"spread_{name}_95"] = list(model.spread_95[j])
    # the dark signal non-uniformity at each dark exposure (EMVA 1288 section 8.2, pixel part): sd of o + D t
    exposures = np.unique(model.stacks.loc[model.stacks["kind"] == "dark", "exposure_s"].to_numpy(float))
    dsnu = [
        combination_spread(
            pop, model.design.covariance, np.r_[1.0, [t] * ("dark_current_dn_s" in names), 0.0], model.n_normal
        )
        for t in exposures
    ]
    attrs["dsnu_exposure_s"] = exposures.tolist()
    attrs["dsnu_dn"] = [d[0] for d in dsnu]
    attrs["dsnu_dn_se"] = [d[1] for d in dsnu]
    attrs["dsnu_dn_95"] = [list(d[2]) for d in dsnu]
    return attrs
