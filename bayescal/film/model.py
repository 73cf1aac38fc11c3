"""The film's characteristic curve and the numpyro model of one band (seed 003, eq. 3, 5-6, 10).

The film's characteristic curve on its straight part is ``D = gamma lg H + D0`` (eq. 5-6); at a
fixed exposure ``lg H = lg L* + const``, absorbed into ``D0``.  With ``toe_shoulder`` the curve
is a logistic in ``lg L*`` whose midpoint slope is ``gamma``, between fog ``D_min`` and
``D_max``.  Every input of the radiance chain (``alpha``, ``beta``, ``tau_max``, ``R_meter``,
each wedge step ``T_j``; :mod:`bayescal.film.spec`) is a log-normal random variable with its
stated relative uncertainty; the curve parameters are fitted with the chain by any posterior
backend (:mod:`bayescal.inference.registry`).  The uncertainty budget switches the inputs'
uncertainties on one at a time.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import numpy as np
import pandas as pd

from bayescal.film.spec import FilmSpec, correction_chain

__all__ = ["BandModel", "band_model", "curve", "film_model", "simulate_film", "uncertainty_budget_film"]


@dataclass(frozen=True)
class BandModel:
    """One band's data and spec as a backend sees a model (``spec.inference``, ``data``)."""

    band: str
    spec: FilmSpec
    data: tuple  # (chain inputs, wedge, meter current, densities): the program's data argument


def band_model(spec: FilmSpec, band: str, current: float, density: np.ndarray) -> BandModel:
    """The data of one band's fit: its chain inputs, the wedge, its meter current and its densities."""
    data = (_inputs(spec, spec.band(band)), np.asarray(spec.wedge, float), np.asarray(float(current)), density)
    return BandModel(band, spec, data)


def curve(lg_l, gamma, d0, d_min=None, d_max=None, toe_shoulder=False, xp=np):
    """Density at ``lg L*``: the straight line ``D0 + gamma lg L*``, or its logistic with toe and shoulder."""
    if not toe_shoulder:
        return d0 + gamma * lg_l
    # logistic between fog and D_max whose midpoint lies on the straight line D0 + gamma lg L with slope gamma
    span = d_max - d_min
    mid = (d_min + span / 2 - d0) / gamma
    return d_min + span * 1.0 / (1.0 + xp.exp(-4 * gamma / span * (lg_l - mid)))


def _inputs(spec: FilmSpec, band) -> np.ndarray:
    return np.asarray(
        [
            band.alpha,
            band.beta,
            band.tau_max,
            band.meter_responsivity,
            band.u_alpha,
            band.u_beta,
            band.u_tau,
            band.u_meter,
            spec.u_wedge,
            spec.density_sd,
        ]
    )


@lru_cache(maxsize=16)
def film_model(toe_shoulder: bool, reference_step: int):
    """The numpyro model of one structure; data ``(inputs, wedge, current, density)`` are its argument,
    so one compiled program (:func:`bayescal.inference.program.program_of`) serves every band."""

    import jax.numpy as jnp
    import numpyro
    import numpyro.distributions as dist

    def model(data):
        inputs, wedge, current, density = data
        a0, b0, t0, r0, ua, ub, ut, ur, uw, dsd = (inputs[i] for i in range(10))
        alpha = numpyro.sample("alpha", dist.LogNormal(jnp.log(a0), ua))
        beta = numpyro.sample("beta", dist.LogNormal(jnp.log(b0), ub))
        tau = numpyro.sample("tau_max", dist.LogNormal(jnp.log(t0), ut))
        resp = numpyro.sample("meter", dist.LogNormal(jnp.log(r0), ur))
        z = numpyro.sample("T_z", dist.Normal(0.0, 1.0).expand([wedge.shape[0]]).to_event(1))  # non-centred
        t = numpyro.deterministic("T", wedge * jnp.exp(uw * z))
        l_ref = numpyro.deterministic("L_ref", correction_chain(resp * current, alpha, beta, tau))  # eq. 3
        l_steps = numpyro.deterministic("L_steps", t / t[reference_step] * l_ref)  # eq. 10
        gamma = numpyro.sample("gamma", dist.Normal(1.0, 1.0))
        # parametrised by the density of the reference step: the chain's scale L_ref only shifts D0, so the
        # curve's (D_ref, gamma) and the chain inputs are a posteriori independent and mix well
        d_ref = numpyro.sample("D_ref", dist.Normal(1.5, 2.0))
        d0 = numpyro.deterministic("D0", d_ref - gamma * jnp.log10(l_ref))
        sd = numpyro.deterministic("density_sd", dsd)  # the densitometer's known reading precision
        if toe_shoulder:
            d_min = numpyro.sample("D_min", dist.Normal(0.2, 0.5))
            d_max = numpyro.sample("D_max", dist.Normal(3.0, 1.0))
            mean = curve(jnp.log10(l_steps), gamma, d0, d_min, d_max, True, jnp)
        else:
            mean = curve(jnp.log10(l_steps), gamma, d0, xp=jnp)
        numpyro.sample("D", dist.Normal(mean, sd), obs=density)

    return model


def simulate_film(
    spec: FilmSpec, band: str, *, gamma: float, d0: float, current: float, density_sd: float = 0.02, seed: int = 0
) -> tuple[np.ndarray, dict]:
    """Wedge densities of one band with known truth: chain factors and wedge drawn from their uncertainties."""
    b = spec.band(band)
    rng = np.random.default_rng(seed)
    truth = {
        "alpha": b.alpha * np.exp(b.u_alpha * rng.standard_normal()),
        "beta": b.beta * np.exp(b.u_beta * rng.standard_normal()),
        "tau_max": b.tau_max * np.exp(b.u_tau * rng.standard_normal()),
        "meter": b.meter_responsivity * np.exp(b.u_meter * rng.standard_normal()),
        "T": np.asarray(spec.wedge) * np.exp(spec.u_wedge * rng.standard_normal(len(spec.wedge))),
        "gamma": gamma,
        "D0": d0,
    }
    l_ref = correction_chain(truth["meter"] * current, truth["alpha"], truth["beta"], truth["tau_max"])
    l_steps = truth["T"] / truth["T"][spec.reference_step] * l_ref
    truth["L_ref"], truth["L_steps"] = l_ref, l_steps
    density = curve(np.log10(l_steps), gamma, d0) + density_sd * rng.standard_normal(l_steps.size)
    return density, truth


def uncertainty_budget_film(spec: FilmSpec, band: str, n: int = 20000, seed: int = 0) -> pd.DataFrame:
    """Relative standard uncertainty of a band's radiance scale from each input alone, and in total.

    Propagates the log-normal inputs of eq. 3 and eq. 10 (the step radiance
    of the reference step, which sets the calibration's scale) by Monte
    Carlo.  The total's expanded (k = 2) value is compared with the paper's
    stated +-15 % (visible) / +-20 % (IR).
    """
    b = spec.band(band)
    rng = np.random.default_rng(seed)
    parts = {"alpha": b.u_alpha, "beta": b.u_beta, "tau_max": b.u_tau, "meter": b.u_meter, "wedge": spec.u_wedge}
    rows: list[dict[str, Any]] = []
    total_var = 0.0
    for name, u in parts.items():
        if name == "wedge":  # a step relative to the reference step: two independent transmittances
            x = np.exp(u * rng.standard_normal(n) - u * rng.standard_normal(n))
        else:
            x = np.exp(u * rng.standard_normal(n))
        rel_sd = float(np.std(x) / np.mean(x))
        total_var += rel_sd**2
        rows.append({"band": band, "input": name, "rel_sd": rel_sd})
    total = float(np.sqrt(total_var))
    for r in rows:
        r["share"] = r["rel_sd"] ** 2 / total_var
    stated = spec.stated_uncertainty.get(band, np.nan)
    rows.append(
        {
            "band": band,
            "input": "total",
            "rel_sd": total,
            "share": 1.0,
            "expanded_k2": 2 * total,
            "paper_stated": stated,
            "within_paper": bool(2 * total <= stated),
        }
    )
    return pd.DataFrame(rows)
