"""Film density calibration of the 4-band (B, G, R, IR) film camera (seed 003).

Every frame carries a 10-step optical wedge exposed by a xenon flash; a step
``j`` of transmittance ``T_j`` reproduces the radiance (eq. 10)::

    L*_j = (T_j / T_M) L*_rho

where ``L*_rho`` is the ground target's band radiance measured by a
multispectral radiance meter whose reading passes a correction chain (eq. 3)::

    L* = L / (alpha beta tau_max),   L = R_meter I

(spectral-mismatch factors ``alpha``, ``beta``, filter peak transmittance
``tau_max``, meter responsivity ``R_meter`` and current ``I``).  The film's
characteristic curve on its straight part is ``D = gamma lg H + D0`` (eq.
5-6); at a fixed exposure ``lg H = lg L* + const``, absorbed into ``D0``.
With ``toe_shoulder`` the curve is a logistic in ``lg L*`` whose midpoint
slope is ``gamma``, between fog ``D_min`` and ``D_max``.  Other exposure times
and apertures scale the radiance by ``(t*/t) ((D*/f*) / (D/f))`` (eq. 11).

Every input (``alpha``, ``beta``, ``tau_max``, ``R_meter``, each ``T_j``) is a
log-normal random variable with its stated relative uncertainty; the curve
parameters and the density noise are fitted by NUTS (numpyro).  Inversion
maps densities to band radiance per posterior draw; the uncertainty budget
switches the inputs' uncertainties on one at a time.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import numpyro
import numpyro.distributions as dist
import pandas as pd

from bayescal._config import computes
from bayescal.errors import SpecError, TableError

__all__ = [
    "FilmBand",
    "FilmSpec",
    "FilmFit",
    "TABLE1",
    "correction_chain",
    "table1_check",
    "load_film_spec",
    "simulate_film",
    "fit_film",
    "uncertainty_budget_film",
    "convert_exposure",
    "load_film_table",
    "save_film_fits",
    "load_film_fits",
]

#: seed 003 Table 1 as printed: alpha, beta, tau_max, L (meter), L* (printed), mW sr^-1 cm^-2
TABLE1 = pd.DataFrame(
    {
        "band": ["B", "G", "R", "IR"],
        "alpha": [1.17, 1.10, 1.11, 1.43],
        "beta": [1.04, 1.02, 0.98, 1.70],
        "tau_max": [0.730, 0.655, 0.625, 0.860],
        "L": [4.13, 3.39, 3.02, 5.17],
        "L_star_printed": [4.44, 5.22, 4.31, 2.49],
    }
)


def correction_chain(L, alpha, beta, tau_max):
    """Eq. 3: the meter reading corrected for spectral mismatch and filter peak, ``L / (alpha beta tau_max)``."""
    return L / (alpha * beta * tau_max)


def table1_check(tolerance: float = 0.01) -> pd.DataFrame:
    """What eq. 3 gives for each column of Table 1 beside what is printed, flagged where they disagree.

    The IR column follows eq. 3 (2.47 against the printed 2.49, 0.7 %); the
    visible columns do not (the formula gives 4.65, 4.61, 4.44 for B, G, R
    against the printed 4.44, 5.22, 4.31: the scan may have shuffled them --
    the printed B value is the formula's R value).
    """
    t = TABLE1.copy()
    t["L_star_eq3"] = correction_chain(t["L"], t["alpha"], t["beta"], t["tau_max"])
    t["rel_diff"] = t["L_star_eq3"] / t["L_star_printed"] - 1
    t["follows_eq3"] = t["rel_diff"].abs() <= tolerance
    return t


@dataclass(frozen=True)
class FilmBand:
    """One band's chain inputs: nominal values and relative standard uncertainties."""

    name: str
    alpha: float
    beta: float
    tau_max: float
    meter_responsivity: float  # mW sr^-1 cm^-2 per unit meter current
    u_alpha: float = 0.05
    u_beta: float = 0.05
    u_tau: float = 0.02
    u_meter: float = 0.05


@dataclass(frozen=True)
class FilmSpec:
    """Film camera: bands, the wedge, and the density model.

    ``wedge`` holds the nominal transmittances of the 10 steps (step M is the
    reference the ground target is matched to, ``reference_step``);
    ``u_wedge`` their relative standard uncertainty; ``density_sd`` the
    densitometer's reading precision (known; a free noise scale would trade
    off against the ten per-step wedge errors); ``toe_shoulder`` switches to the
    logistic curve.
    """

    bands: tuple[FilmBand, ...]
    wedge: tuple[float, ...]
    reference_step: int = 5
    u_wedge: float = 0.02
    density_sd: float = 0.05
    toe_shoulder: bool = False
    draws: int = 1000
    warmup: int = 500
    chains: int = 4
    stated_uncertainty: dict = field(default_factory=lambda: {"B": 0.15, "G": 0.15, "R": 0.15, "IR": 0.20})

    def band(self, name: str) -> FilmBand:
        """The named band; a clear error otherwise."""
        for b in self.bands:
            if b.name == name:
                return b
        raise TableError(f"band '{name}' is not in the film spec (bands {[b.name for b in self.bands]})", column="band")


def load_film_spec(path) -> FilmSpec:
    """Load a film spec (TOML with ``kind = "film"``, see ``models/seed003_film.toml``)."""
    path = Path(path)
    try:
        d = tomllib.loads(path.read_text())
    except FileNotFoundError as exc:
        raise SpecError(f"no such film spec: {path}") from exc
    if d.pop("kind", None) != "film":
        raise SpecError(f'{path}: not a film spec (expected kind = "film")')
    try:
        bands = tuple(FilmBand(name=k, **v) for k, v in d.pop("bands").items())
        stated = d.pop("stated_uncertainty", None)
        spec = FilmSpec(bands=bands, wedge=tuple(float(x) for x in d.pop("wedge")), **d)
    except (KeyError, TypeError) as exc:
        raise SpecError(f"{path}: malformed film spec: {exc}") from exc
    if stated is not None:
        spec = FilmSpec(**{**spec.__dict__, "stated_uncertainty": stated})
    if not 0 <= spec.reference_step < len(spec.wedge):
        raise SpecError(f"{path}: reference_step {spec.reference_step} outside the {len(spec.wedge)}-step wedge")
    return spec


# --------------------------------------------------------------------- model
def _curve(lg_l, gamma, d0, d_min=None, d_max=None, toe_shoulder=False):
    if not toe_shoulder:
        return d0 + gamma * lg_l
    # logistic between fog and D_max whose midpoint lies on the straight line D0 + gamma lg L with slope gamma
    span = d_max - d_min
    mid = (d_min + span / 2 - d0) / gamma
    return d_min + span * jax.nn.sigmoid(4 * gamma / span * (lg_l - mid))


def _inputs(spec: FilmSpec, band: FilmBand) -> jnp.ndarray:
    return jnp.asarray(
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
def _film_model(toe_shoulder: bool, reference_step: int):
    """The numpyro model of one structure; data ``(inputs, wedge, current, density)`` are its argument,
    so one compiled program (:func:`bayescal.inference.program.program_of`) serves every band."""

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
            mean = _curve(jnp.log10(l_steps), gamma, d0, d_min, d_max, True)
        else:
            mean = _curve(jnp.log10(l_steps), gamma, d0)
        numpyro.sample("D", dist.Normal(mean, sd), obs=density)

    return model


@dataclass(frozen=True)
class FilmFit:
    """Posterior draws of one band: ``gamma``, ``D0``, chain inputs, step radiances."""

    band: str
    draws: dict
    spec: FilmSpec
    diagnostics: dict

    def invert(self, density, level: float = 0.95, include_noise: bool = True, seed: int = 0) -> pd.DataFrame:
        """Band radiance (mW sr^-1 cm^-2) of target densities: median and ``level`` interval per value.

        Vectorised over any array of densities (a scanned density image is
        flattened and reshaped by the caller).  Only the straight part is
        inverted; densities outside the wedge's range are flagged.
        """
        d = np.atleast_1d(np.asarray(density, dtype=float))
        gamma, d0 = self.draws["gamma"][:, None], self.draws["D0"][:, None]
        rng = np.random.default_rng(np.random.SeedSequence([seed, 0xF11]))  # the density noise draws
        sd = np.broadcast_to(np.asarray(self.draws["density_sd"], dtype=float).reshape(-1, 1), gamma.shape)
        noise = sd * rng.standard_normal(gamma.shape) if include_noise else 0.0
        lg = (d[None, :] - noise - d0) / gamma
        radiance = 10.0**lg
        tail = (1 - level) / 2
        q = np.quantile(radiance, [tail, 0.5, 1 - tail], axis=0)
        lo_l, hi_l = np.quantile(self.draws["L_steps"], 0.5, axis=0)[[0, -1]]
        med = q[1]
        return pd.DataFrame(
            {
                "density": d,
                "median": med,
                "lower": q[0],
                "upper": q[2],
                "outside_wedge": (med < min(lo_l, hi_l)) | (med > max(lo_l, hi_l)),
            }
        )


@computes
def fit_film(spec: FilmSpec, band: str, current: float, density: np.ndarray, seed: int = 0) -> FilmFit:
    """Fit one band's characteristic curve and chain to its wedge densities (NUTS)."""
    b = spec.band(band)
    density = np.asarray(density, dtype=float)
    if density.shape != (len(spec.wedge),):
        raise TableError(f"band {band}: {density.size} wedge densities, expected {len(spec.wedge)}", column="density")
    if not np.all(np.isfinite(density)):
        raise TableError(f"band {band}: a wedge density is not a number", column="density")
    from bayescal.inference.laplace import laplace
    from bayescal.inference.nuts import run_nuts
    from bayescal.inference.program import program_of
    from bayescal.model.spec import InferenceSpec

    data = (_inputs(spec, b), jnp.asarray(spec.wedge), jnp.asarray(float(current)), jnp.asarray(density))
    program = program_of(_film_model(spec.toe_shoulder, spec.reference_step), data, obs="D")
    start = laplace(program, data)
    settings = InferenceSpec(chains=spec.chains, draws=spec.draws, warmup=spec.warmup, target_accept=0.9)
    out = run_nuts(program, data, start.mode, start.cov, settings, seed)
    chains, draws, dim = out.z.shape
    sites = program.constrain(out.z.reshape(-1, dim), data)
    samples = {k: np.asarray(v) for k, v in sites.items() if k != "D"}
    import arviz as az

    div = int(np.asarray(out.diverging).sum())
    rhat = float(
        max(
            np.nanmax(np.asarray(az.rhat(samples[k].reshape((chains, draws) + samples[k].shape[1:]))))
            for k in ("gamma", "D0")
        )
    )
    diagnostics = {"divergences": div, "max_rhat_curve": rhat, "ok": div == 0 and rhat <= 1.01}
    return FilmFit(band, samples, spec, diagnostics)


@computes
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
    density = d0 + gamma * np.log10(l_steps) + density_sd * rng.standard_normal(l_steps.size)
    return density, truth


@computes
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
    rows = []
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


def load_film_table(path) -> dict[str, tuple[float, np.ndarray]]:
    """Read wedge densities: CSV with ``band, step, density, meter_current`` (one row per band and wedge step).

    ``step`` runs 1..10 (the wedge's steps), ``meter_current`` is the
    radiance meter's reading on the reference target for that band (the same
    on every row of the band).  Returns ``{band: (current, densities by step)}``.
    """
    df = pd.read_csv(path)
    need = ["band", "step", "density", "meter_current"]
    for col in need:
        if col not in df:
            raise TableError(f"{path}: missing column '{col}'; expected {need}", column=col)
    out = {}
    for band, g in df.groupby("band", sort=False):
        g = g.sort_values("step")
        bad = g[~np.isfinite(pd.to_numeric(g["density"], errors="coerce"))]
        if len(bad):
            raise TableError(f"{path}: density is not a number", row=int(bad.index[0]) + 1, column="density")
        currents = g["meter_current"].unique()
        if currents.size != 1:
            raise TableError(
                f"{path}: band {band} has several meter_current values {list(currents)}", column="meter_current"
            )
        out[str(band)] = (float(currents[0]), g["density"].to_numpy(dtype=float))
    return out


def save_film_fits(fits: dict[str, FilmFit], out_dir) -> Path:
    """Write ``film_draws.npz`` (per band draws) and ``film_summary.json`` atomically."""
    from bayescal.io.files import staged_directory, write_json_atomic

    out_dir = Path(out_dir)
    arrays = {f"{b}/{k}": np.asarray(v) for b, f in fits.items() for k, v in f.draws.items()}
    summary = {}
    for b, f in fits.items():
        summary[b] = {"diagnostics": f.diagnostics}
        for k in ("gamma", "D0", "L_ref"):
            q = np.quantile(f.draws[k], [0.025, 0.5, 0.975])
            summary[b][k] = {"median": q[1], "q2.5": q[0], "q97.5": q[2]}
    with staged_directory(out_dir) as stage:
        with open(stage("film_draws.npz"), "wb") as fh:
            np.savez(fh, **arrays)
        write_json_atomic(stage("film_summary.json"), {"kind": "film", "bands": summary})
    return out_dir


def load_film_fits(fit_dir, spec: FilmSpec | None = None) -> dict[str, FilmFit]:
    """Read what :func:`save_film_fits` wrote."""
    path = Path(fit_dir) / "film_draws.npz"
    data = np.load(path)
    bands: dict[str, dict] = {}
    for key in data.files:
        b, k = key.split("/", 1)
        bands.setdefault(b, {})[k] = data[key]
    return {b: FilmFit(b, d, spec, {}) for b, d in bands.items()}


def convert_exposure(radiance, t_star: float, t: float, aperture_star: float, aperture: float, aperture_power=2):
    """Eq. 11: step radiances calibrated at ``t*``, ``D*/f*`` re-expressed for exposure ``t`` and aperture ``D/f``.

    ``L_j(t, D/f) = (t* / t) ((D*/f*) / (D/f))^k L_j(t*, D*/f*)``: the same film
    density needs the same exposure ``H ~ L t (D/f)^2``.  The scan of the paper
    prints the aperture ratio to the first power; image irradiance goes with
    the square of the relative aperture, so ``k = 2`` by default
    (``aperture_power=1`` reproduces the printed form).
    """
    if min(t_star, t, aperture_star, aperture) <= 0:
        raise SpecError("exposure times and relative apertures must be positive")
    return np.asarray(radiance, dtype=float) * (t_star / t) * (aperture_star / aperture) ** aperture_power
