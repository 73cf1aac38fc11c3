"""EMVA 1288 characterisation: the standard's point estimates beside Bayesian posteriors.

Photon transfer (EMVA 1288 release 3.0, docs/architecture.md, section 2)::

    s2_y - s2_y.dark = K (mu_y - mu_y.dark)          (system gain K, DN/e-)
    mu_y - mu_y.dark = R mu_p,   QE = R / K          (responsivity R, DN/photon)
    mu_y.dark(t) = mu_0 + K I t,  s2_y.dark(t) = s2_0 + K^2 I t   (dark current I, e-/s)

**Standard method** (own implementation of the standard's formulas): the
saturation step is the one of largest temporal variance; K and R are
least-squares slopes through the origin over the steps up to 70 % of the
saturation signal, the linearity error is the relative deviation from a
straight line fitted (minimising relative deviations) between 5 % and 95 %,
``sigma_y_dark`` is the dark temporal noise at the shortest exposure, dark
currents are the slopes of the dark mean and variance.

**Bayesian**: the same relations as regressions with a flat prior on the
coefficients and an unknown noise scale (Jeffreys prior), whose posterior is
closed form (Student-t coefficients).  K and R are the small-signal slopes
(at zero signal) of quartics through the origin over the standard's range, so
a sensor whose output is not linear does not bias them (the standard's
straight lines give the average slope over the range).  The photon-transfer regression weights each
step by the sampling variance of a pair variance (``2 s^4 / N``) and the
responsivity regression by ``1 / (s^2 + rho)``: the source's stability relative to the
signal, with a floor ``rho`` for the darkest steps' own noise chosen by the data (each draw
picks ``rho`` from a grid by its marginal likelihood), so the posterior is calibrated where
the standard's unweighted fit is not and no single step decides it.  On quantisation-limited
sensors (dark variance below 1 DN^2: 8- and 10-bit sensors with a fraction of a DN of dark
noise, :mod:`bayescal.model.quantisation`) the photon transfer curve keeps the steps with
half a DN of noise or more and both curves get a free intercept, which absorbs the rounding
of the dark level; the dark variance gets the standard's floor of 0.24 DN^2; and a K the
data cannot determine (95 % interval wider than half its median) is reported.  The
dark noise gets the posterior of a variance from
``N - 1`` degrees of freedom.  Derived quantities (QE, dark currents,
saturation capacity, dynamic range, SNR, linearity error) are computed per
draw, so their intervals carry the correlations.  The two dark-current
estimates are compared through the posterior of their difference.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from bayescal._config import computes
from bayescal.errors import TableError
from bayescal.io.emva import Steps
from bayescal.model.components.noise import QUANTISATION_DN2
from bayescal.model.quantisation import DARK_FLOOR_DN2

__all__ = ["Characterization", "characterize", "standard_method"]

SENSITIVITY_FRACTION = 0.7
#: a K whose 95 % interval spans more than this fraction of its median is reported as not determined
K_UNDETERMINED_WIDTH = 0.5
#: on quantisation-limited sensors, photon-transfer steps need this measured variance (DN^2): noise of half
#: a DN, where rounding changes a variance by less than 1 % wherever the level sits in its code
ROUNDING_SAFE_DN2 = 0.25 + QUANTISATION_DN2
LINEARITY_RANGE = (0.05, 0.95)
QUANT = QUANTISATION_DN2  # the standard's quantisation variance, 1/12 DN^2


@dataclass(frozen=True)
class Characterization:
    """Standard point estimates, posteriors and the per-step curves."""

    table: pd.DataFrame
    standard: dict
    draws: dict
    curves: pd.DataFrame
    ranges: dict
    dark_current_compatible: bool | None  # None: the dark current is not determined
    source: str
    #: posterior draws of each fitted curve's coefficients, ``name -> (powers, draws (n, len(powers)))``:
    #: ``photon_transfer`` (variance against signal), ``sensitivity`` (signal against photons), ``linearity``
    #: (the standard's straight line over 5-95 % of saturation), ``dark_mean`` (dark level against exposure)
    curve_draws: dict = field(default_factory=dict)
    #: the dark frames at several exposures (``texp_s``, ``mean_dn``, ``var_dn2``); None: one exposure only
    dark: pd.DataFrame | None = None
    #: the set's stack statistics and mean images (:attr:`bayescal.io.emva.Steps.stack`; empty: pairs only)
    stack: dict = field(default_factory=dict)
    #: what the layout of the set made the characterisation assume, in words (printed and on the datasheet)
    notes: tuple[str, ...] = ()
    #: the photon transfer curve's straightness over its fit range (:func:`_ptc_linearity`): ``linear`` decides
    #: whether EMVA 1288 Release 4 Linear applies (K, QE and what needs them are reported)
    ptc: dict = field(default_factory=dict)
    #: the operating point the set records (:func:`operating_point`): bits, pixels, exposures, photons, steps
    operating: dict = field(default_factory=dict)

    @property
    def module(self) -> str:
        """The Release 4 module the camera's quantities follow: "Linear", or "General" where the photon transfer
        curve is not straight."""
        return "Linear" if self.ptc.get("linear", True) else "General"

    @property
    def problems(self) -> list[str]:
        """Results no sensor can have, each with what to check (empty: plausible)."""
        out: list[str] = []
        if self.module == "General":  # K and what needs it are not determinable, and say so in their notes
            return out
        for name, value in (("K", self.standard.get("K")), ("QE", self.standard.get("QE"))):
            if value is None or not np.isfinite(value) or value <= 0:
                out.append(f"{name} = {value}: not a positive number; check the photon counts and the dark pairs")
        qe = self.standard.get("QE")
        if qe is not None and np.isfinite(qe) and qe > 100:
            out.append(
                f"QE = {qe:.3g} % exceeds 100 %: the photon counts (photons per pixel per exposure) are too low "
                "for the signal, or the bit depth is wrong"
            )
        for name in ("sigma_y_dark", "u_e_sat", "SNR_max", "DR"):
            value = self.standard.get(name)
            if value is not None and not np.isfinite(value):
                out.append(f"{name} is not a number: the sweep does not reach saturation, or a step is empty")
        k = self.draws.get("K")
        if k is not None and np.all(np.isfinite(k)):
            lo, mid, hi = np.quantile(k, [0.025, 0.5, 0.975])
            if mid <= 0 or (hi - lo) / abs(mid) > K_UNDETERMINED_WIDTH:
                out.append(
                    f"K is not determined by these data: its 95 % interval [{lo:.4g}, {hi:.4g}] DN/e- spans "
                    f"{(hi - lo) / abs(mid):.0%} of its median; the photon transfer curve needs more steps with "
                    "half a DN of noise or more below 70 % of saturation (a finer sweep, or a higher gain)"
                )
        return out

    def to_dict(self) -> dict:
        """JSON-ready: table rows, ranges, the dark-current verdict and any implausible result."""
        return {
            "problems": self.problems,
            "source": self.source,
            "ranges": self.ranges,
            "dark_current_compatible": self.dark_current_compatible,
            "module": self.module,
            "photon_transfer_linearity": self.ptc,
            "operating_point": self.operating,
            "notes": list(self.notes),
            "quantities": self.table.to_dict("records"),
        }


def _aligned(steps: Steps) -> pd.DataFrame:
    """Each bright step beside the dark step at its exposure.

    Both layouts of the standard are accepted: an exposure sweep (a dark pair
    per bright exposure) and an illumination sweep (one exposure, the
    illumination varied, dark pairs at that exposure shared by every step).
    Dark pairs at one exposure only serve every bright step, whatever its
    exposure: the dark signal is then taken as the same at every exposure
    (the dark current is not determined, and is reported so).
    """
    b, d = steps.bright, steps.dark
    dark_t = d["texp_s"].to_numpy()
    if _dark_exposures(steps) == 1:
        dark_t = np.full_like(dark_t, np.nan)  # matched below to every bright exposure
    match = []
    for i, t in enumerate(b["texp_s"].to_numpy()):
        same = np.flatnonzero(np.isclose(dark_t, t, rtol=1e-9, atol=0) | np.isnan(dark_t))
        if same.size == 0:
            raise TableError(
                f"{steps.source}: bright step {i + 1} at exposure {t * 1e3:g} ms has no dark image pair at that "
                f"exposure (dark exposures: {sorted({round(v * 1e3, 6) for v in dark_t})} ms); EMVA 1288 subtracts "
                "the dark signal at the same exposure"
            )
        # the dark pair at this exposure; several (an exposure sweep repeated) pair up in order
        match.append(int(same[min(int(np.sum(np.isclose(b["texp_s"].to_numpy()[:i], t))), same.size - 1)]))
    d = d.iloc[match].reset_index(drop=True)
    return pd.DataFrame(
        {
            "texp_s": b["texp_s"].to_numpy(),
            "photons": b["photons"].to_numpy(),
            "mu_y": b["mean_dn"].to_numpy(),
            "mu_dark": d["mean_dn"].to_numpy(),
            "s2_y": b["var_dn2"].to_numpy(),
            "s2_dark": d["var_dn2"].to_numpy(),
            "n_pixels": b["n_pixels"].to_numpy(),
        }
    )


def _dark_exposures(steps: Steps) -> int:
    """Distinct exposure times of the dark steps: a dark current needs at least two."""
    return int(np.unique(np.round(steps.dark["texp_s"].to_numpy(), 12)).size)


def _below_full_scale(c: pd.DataFrame, steps: Steps) -> None:
    """Refuse a sweep whose bright steps read full scale (a flat field far too bright): the photon
    transfer needs steps from dark to saturation, and a saturated step has no temporal noise to read."""
    full = 2**steps.bits - 1
    saturated = c["mu_y"].to_numpy() >= full - 0.5
    if c["mu_y"].size - int(saturated.sum()) < 3:
        raise TableError(
            f"{steps.source}: {int(saturated.sum())} of {saturated.size} bright steps are saturated (their mean "
            f"reads {full} DN, the full scale of a {steps.bits}-bit ADC): the flat field is too bright for EMVA "
            "1288, which needs steps from dark to saturation; lower the illumination or the exposure times"
        )


def _ranges(c: pd.DataFrame) -> dict:
    sat = int(np.argmax(c["s2_y"].to_numpy()))
    signal = (c["mu_y"] - c["mu_dark"]).to_numpy()
    top = signal[sat]
    if np.ptp(signal) <= 1e-9 * max(float(np.max(np.abs(signal))), 1.0):
        raise TableError(
            f"every bright step reads the same signal ({signal[0]:.6g} DN above dark): the images do not follow "
            "the photon counts (the same image pair listed for every step?)"
        )
    sens = np.flatnonzero(signal[: sat + 1] <= SENSITIVITY_FRACTION * top)
    lin = np.flatnonzero(
        (signal[: sat + 1] >= LINEARITY_RANGE[0] * top) & (signal[: sat + 1] <= LINEARITY_RANGE[1] * top)
    )
    if sens.size < 3 or lin.size < 3:
        raise TableError("fewer than 3 steps below 70 % of saturation: the sweep is too coarse for EMVA 1288")
    return {
        "index_u_ysat": sat,
        "index_sensitivity_min": int(sens[0]),
        "index_sensitivity_max": int(sens[-1]),
        "index_linearity_min": int(lin[0]),
        "index_linearity_max": int(lin[-1]),
    }


def standard_method(steps: Steps) -> tuple[dict, dict]:
    """EMVA 1288 point estimates (our implementation of the standard's formulas) and the index ranges.

    Examples
    --------
    >>> import bayescal as bc
    >>> estimates, _ = bc.standard_method(bc.load_steps("emva"))  # the real CCD of reference set 001
    >>> round(estimates["K"], 3)  # the system gain, DN per electron
    0.28
    """
    c = _aligned(steps)
    _below_full_scale(c, steps)
    r = _ranges(c)
    s = slice(r["index_sensitivity_min"], r["index_sensitivity_max"] + 1)
    x_sig = (c["mu_y"] - c["mu_dark"]).to_numpy()
    k = _through_origin(x_sig[s], (c["s2_y"] - c["s2_dark"]).to_numpy()[s])
    resp = _through_origin(c["photons"].to_numpy()[s], x_sig[s])
    s2_dark0 = max(float(c["s2_dark"].iloc[0]), DARK_FLOOR_DN2)  # the standard's floor for quantisation
    if _dark_exposures(steps) >= 2:  # the dark current is the slope of the dark signal in exposure time
        t, dk = steps.dark["texp_s"].to_numpy(), steps.dark
        i_mean_dn = np.polyfit(t, dk["mean_dn"].to_numpy(), 1)[0]
        i_var_dn2 = np.polyfit(t, dk["var_dn2"].to_numpy(), 1)[0]
    else:  # one exposure time determines no slope: not determined, not a number with an interval
        i_mean_dn = i_var_dn2 = np.nan
    u_p_sat = float(c["photons"].iloc[r["index_u_ysat"]])
    # relative deviations: the line minimises sum(((y - fit) / y)^2) (np.polyfit's w multiplies residuals)
    xl, yl = c["photons"].to_numpy()[_lin(r)], x_sig[_lin(r)]
    le_min, le_max = _linearity(c, r, *np.polyfit(xl, yl, 1, w=1.0 / yl))
    point = _quantities(k, resp, s2_dark0, i_mean_dn / k, i_var_dn2 / k**2, u_p_sat, le_min, le_max)
    if steps.stack:
        point.update(_nonuniformity(steps.stack, k, *_spatial(steps.stack)))
    return point, r


def _quantities(k, resp, s2_dark, i_mean, i_var, u_p_sat, le_min, le_max) -> dict:
    """The EMVA 1288 quantities from K, R, the dark variance and the dark currents (scalars or draws alike)."""
    qe = resp / k
    sigma_y_dark = np.sqrt(s2_dark)
    u_p_min = (sigma_y_dark / k + 0.5) / qe  # the absolute sensitivity threshold
    return {
        "K": k,
        "R": resp,
        "QE": 100 * qe,
        "sigma_y_dark": sigma_y_dark,
        "sigma_d": np.sqrt(np.maximum(s2_dark - QUANT, 0.0)) / k,
        "dark_current_mean": i_mean,
        "dark_current_var": i_var,
        "dark_current_difference": i_mean - i_var,
        "u_p_sat": np.broadcast_to(u_p_sat, np.shape(k)) * 1.0,
        "u_e_sat": qe * u_p_sat,
        "u_p_min": u_p_min,
        "DR": u_p_sat / u_p_min,
        "SNR_max": np.sqrt(np.maximum(qe * u_p_sat, 0.0)),
        "LE_min": le_min,
        "LE_max": le_max,
    }


def _spatial(stack: dict) -> tuple[float, float]:
    """Spatial variances of the averaged bright and dark images, less the residual temporal noise / L."""
    n = stack["n_images"]
    bright = stack["spatial_var_bright"] - stack["temporal_var_bright"] / n
    dark = stack["spatial_var_dark"] - stack["temporal_var_dark"] / n
    return bright, dark


def _spatial_draws(stack: dict, n_pix: float, n_draws: int, rng: np.random.Generator) -> tuple:
    """Posterior draws of the bright and dark spatial variances (eq. 32): the mean image's variance and the
    temporal variance each drawn from its own scaled inverse chi-square (``N - 1`` and ``N (L - 1)`` degrees
    of freedom, Jeffreys), then the residual temporal noise subtracted draw by draw.

    Scaling the corrected variance alone ignored the temporal term's own error: where the pattern is small
    beside ``s2_temporal / L`` (the reference CCD's dark stack: 6e-5 of 0.19 DN^2), that interval was
    several times too narrow."""
    n = float(stack["n_images"])

    def variance(value: float, dof: float) -> np.ndarray:
        return dof * value / rng.chisquare(dof, n_draws)

    out = []
    for kind in ("bright", "dark"):
        mean_image = variance(stack[f"spatial_var_{kind}"], n_pix - 1)
        temporal = variance(stack[f"temporal_var_{kind}"], n_pix * (n - 1))
        out.append(mean_image - temporal / n)
    return tuple(out)


def _nonuniformity(st: dict, k, s2_bright, s2_dark) -> dict:
    """DSNU1288 (e-) and PRNU1288 (%) from the stacks' spatial variances (EMVA 1288 release 3.0 section 8)."""
    return {
        "DSNU1288": np.sqrt(np.maximum(s2_dark, 0.0)) / k,
        "PRNU1288": 100 * np.sqrt(np.maximum(s2_bright - s2_dark, 0.0)) / (st["mean_bright"] - st["mean_dark"]),
    }


def _through_origin(x: np.ndarray, y: np.ndarray) -> float:
    """Least-squares slope of a line through the origin (the standard's K and R)."""
    return float(np.sum(x * y) / np.sum(x * x))


def _lin(r: dict) -> slice:
    return slice(r["index_linearity_min"], r["index_linearity_max"] + 1)


def _linearity(c: pd.DataFrame, r: dict, slope, intercept) -> tuple:
    """Minimum and maximum relative deviation (%) from the straight line over the linearity range."""
    x = c["photons"].to_numpy()[_lin(r)]
    y = (c["mu_y"] - c["mu_dark"]).to_numpy()[_lin(r)]
    fit = np.multiply.outer(np.atleast_1d(slope), x) + np.atleast_1d(intercept)[:, None]
    dev = 100 * (y - fit) / fit
    lo, hi = dev.min(axis=1), dev.max(axis=1)
    return (float(lo[0]), float(hi[0])) if np.ndim(slope) == 0 else (lo, hi)


def _linearity_at_extremes(c, r, point, slope, intercept) -> tuple[np.ndarray, np.ndarray]:
    """Posterior deviation (%) at the steps where the standard's line deviates most.

    The minimum over steps of each draw's deviations is biased outward by the
    parameter noise; the deviation at the standard's extreme steps is the
    quantity the standard reports.
    """
    xl = c["photons"].to_numpy()[_lin(r)]
    yl = (c["mu_y"] - c["mu_dark"]).to_numpy()[_lin(r)]
    a1, a0 = np.polyfit(xl, yl, 1, w=1.0 / yl)
    dev = 100 * (yl - (a1 * xl + a0)) / (a1 * xl + a0)
    out = []
    for i in (int(np.argmin(dev)), int(np.argmax(dev))):
        fit = slope * xl[i] + intercept
        out.append(100 * (yl[i] - fit) / fit)
    return out[0], out[1]


#: powers of the curves whose slope at zero gives K (photon transfer) and R (sensitivity)
SLOPE_POWERS = (1, 2, 3, 4)


def _line_posterior(
    x,
    y,
    weights,
    n: int,
    rng: np.random.Generator,
    origin: bool = False,
    powers: tuple[int, ...] | None = None,
    what: str = "a regression",
) -> np.ndarray:
    """Posterior draws ``(n, len(powers))`` of the coefficients of ``sum_k b_k x^k`` over ``powers``
    (in that order; default ``(1,)`` with ``origin``, else ``(1, 0)``).

    Flat prior on the coefficients, noise variance ``scale^2 / w``, Jeffreys prior on the scale:
    the closed-form posterior (Student-t coefficients).  ``weights`` may be a grid ``(G, n)`` of
    candidate weightings (a variance model with one unknown shape, e.g. ``1 / (s^2 + rho)`` over
    ``rho``): each draw then picks a row by its marginal likelihood (a uniform prior over the
    grid), so the data decide how the steps are weighted and no single step dominates unless
    the data say it should.
    """
    x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    grid = np.atleast_2d(np.asarray(weights, dtype=float))
    if powers is None:
        powers = (1,) if origin else (1, 0)
    p = len(powers)
    dof = x.size - p
    if dof < 1:
        raise TableError(
            f"{what} has {x.size} step(s) and needs at least {p + 1}: the sweep is too coarse "
            "(EMVA 1288 asks for at least 50 steps from dark to saturation)"
        )
    h = float(np.max(np.abs(x))) or 1.0  # columns on the unit scale, coefficients scaled back below
    cols = np.column_stack([(x / h) ** k for k in powers])
    fits, log_ml = [], []
    for w in grid:
        design = cols * np.sqrt(w)[:, None]
        yw = y * np.sqrt(w)
        q, rr = np.linalg.qr(design)
        beta = np.linalg.solve(rr, q.T @ yw)
        sse = float(np.sum((yw - design @ beta) ** 2))
        fits.append((beta, sse, rr))
        # log p(y | w) up to a constant: 1/2 log|W| - 1/2 log|X'WX| - (n - p)/2 log SSE (invariant to w's scale)
        log_ml.append(0.5 * np.sum(np.log(w)) - np.sum(np.log(np.abs(np.diag(rr)))) - 0.5 * dof * np.log(sse))
    log_evidence = np.asarray(log_ml)
    prob = np.exp(log_evidence - log_evidence.max())
    rows = rng.choice(len(fits), size=n, p=prob / prob.sum())
    out = np.empty((n, p))
    for g in np.unique(rows):
        pick = np.flatnonzero(rows == g)
        beta, sse, rr = fits[g]
        scale2 = sse / rng.chisquare(dof, pick.size)
        z = rng.standard_normal((pick.size, p)) @ np.linalg.inv(rr).T
        out[pick] = beta + np.sqrt(scale2)[:, None] * z
    return out / h ** np.asarray(powers, dtype=float)


def _rising_line_posterior(t, y, n: int, rng: np.random.Generator, what: str) -> tuple[np.ndarray, str | None]:
    """Posterior draws ``(n, 2)`` of the slope and intercept of ``y`` against the exposure ``t`` under a prior
    flat on a slope that cannot be negative: a dark current, and the variance it adds, grow with the
    exposure (EMVA 1288 takes the dark currents as the slopes of the dark mean and variance in the exposure).
    The flat-prior posterior (:func:`_line_posterior`) restricted to a non-negative slope, drawn by
    rejection: an interval then holds only possible values (a normal clipped at zero would pile mass on
    zero).  Where the data put the slope firmly below zero (fewer than 1 in 1,000 draws above; seen where
    the dark variance sits at the quantisation floor), the draws are NaN and the second value says why."""
    kept: list[np.ndarray] = []
    have = tried = 0
    while have < n and not (tried >= 20 * n and have < tried / 1000):
        batch = _line_posterior(t, y, np.ones_like(t), n, rng, what=f"the {what} against exposure")
        tried += n
        kept.append(batch[batch[:, 0] >= 0.0])
        have += len(kept[-1])
    if have >= n:
        return np.concatenate(kept)[:n], None
    why = (
        f"not determinable: the {what} falls with the exposure time (its slope is below zero in "
        f"{1 - have / tried:.1%} of {tried} posterior draws), which no dark current does"
    )
    return np.full((n, 2), np.nan), why


def _saturation_draws(c: pd.DataFrame, r: dict, n: int, rng: np.random.Generator) -> np.ndarray:
    """Draws of the saturation irradiation ``u_p_sat`` (photons).  The standard takes the step where the
    temporal variance peaks (EMVA 1288, the saturation point); a sweep of discrete steps places the true peak
    only to within the step spacing, so the draws are uniform between the midpoints to the neighbouring
    steps (a last step has no neighbour above: its own spacing below is mirrored)."""
    photons = c["photons"].to_numpy()
    i = int(r["index_u_ysat"])
    at = photons[i]
    below = photons[i - 1] if i > 0 else at
    above = photons[i + 1] if i + 1 < len(photons) else at + (at - below)
    return rng.uniform(0.5 * (below + at), 0.5 * (at + above), n)


def _relative_or_floor(signal: np.ndarray, grid: int = 21) -> np.ndarray:
    """Candidate weightings ``1 / (s^2 + rho)`` of a regression on the signal ``s``: errors relative to the
    signal (source stability) up to a floor ``rho`` (the means' own noise and rounding), ``sqrt(rho)`` from
    1e-5 to 1 of the largest signal (``(G, n)``)."""
    top = float(np.max(np.abs(signal))) or 1.0
    rho = (np.logspace(-5, 0, grid) * top)[:, None] ** 2
    return 1.0 / (signal[None, :] ** 2 + rho)


@computes
def characterize(steps: Steps, n_draws: int = 4000, seed: int = 0) -> Characterization:
    """Standard EMVA 1288 estimates and Bayesian posteriors of the same quantities.

    Examples
    --------
    >>> import bayescal as bc
    >>> res = bc.characterize(bc.load_steps("emva"), seed=0)  # the real CCD of EMVA 1288 reference set 001
    >>> res.module, round(res.standard["K"], 4)  # Release 4 Linear; K in DN/e-, the standard's estimate
    ('Linear', 0.2801)
    """
    point, r = standard_method(steps)
    c = _aligned(steps)
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0xE4A]))
    s = slice(r["index_sensitivity_min"], r["index_sensitivity_max"] + 1)
    sig = (c["mu_y"] - c["mu_dark"]).to_numpy()
    dvar = (c["s2_y"] - c["s2_dark"]).to_numpy()
    # weighted by the sampling variance of a pair variance (2 s^4 / N): the noise of the photon transfer
    # points grows with the signal, and an unweighted posterior under-covers (85 % for nominal 95 % on
    # simulated sensors).
    w_var = 1.0 / (c["s2_y"].to_numpy() ** 2 + c["s2_dark"].to_numpy() ** 2)
    # K and R are the small-signal slopes (at zero signal) of curves that need not be straight: a sense node
    # or ADC with a 2 % cubic nonlinearity moved the standard's straight-line K by -1.7 % and QE by +1.5 %,
    # and straight-line intervals covered neither (0 of 30 simulated sensors); a cubic through the origin
    # missed a late (quintic) roll-off (0.35); a quartic covers linear, cubic and quintic sensors at
    # 0.93-0.97 (tests/characterization/test_emva1288.py)
    #
    # Quantisation-limited sensors (dark noise below 1 DN, :mod:`bayescal.model.quantisation`):
    # the rounding distorts the variance of any step whose noise is under half a DN, and the dark
    # variance that every step subtracts by an amount that depends on where the dark level sits within
    # its code. Such a constant error, forced through the origin, bends the quartic's small-signal slope
    # (K 0.0149 against a true 0.0206 on the simulated 8-bit sensor of benchmarks/emva_lowbit.py; with the
    # intercept 0.0214 [0.0185, 0.0242], and K and QE cover 0.96 over 300 simulated 8- and 10-bit sensors). So on
    # those sensors the photon transfer curve keeps only steps with at least half a DN of noise and gets
    # a free intercept, and the sensitivity curve a free intercept too (the dark level's rounding shifts
    # every step's mean alike).
    rounding = bool(np.median(c["s2_dark"]) < 1.0)
    powers = (0, *SLOPE_POWERS) if rounding else SLOPE_POWERS
    where = "below 70 % of saturation"
    kept = np.arange(len(sig))[s]
    if rounding:
        kept = kept[c["s2_y"].to_numpy()[kept] >= ROUNDING_SAFE_DN2]
    what = f"the photon transfer curve (K) {where}" + (" with half a DN of noise or more" if rounding else "")
    k_curve = _line_posterior(sig[kept], dvar[kept], w_var[kept], n_draws, rng, powers=powers, what=what)
    k = k_curve[:, powers.index(1)]
    ptc = _ptc_linearity(sig[kept], dvar[kept], w_var[kept], n_draws, rng)
    # the means' step-to-step error: the source's stability (relative to the signal) and, at the darkest
    # steps, the means' own noise and rounding (a floor): weighted 1 / (s^2 + rho), rho from the data, so
    # a step reading a fraction of a DN cannot decide R alone (1 / s^2 gave QE 1.6 % for 55 % on a real
    # 8-bit sensor whose darkest step read 0.0002 DN)
    resp_curve = _line_posterior(
        c["photons"].to_numpy()[s],
        sig[s],
        _relative_or_floor(sig[s]),
        n_draws,
        rng,
        powers=powers,
        what=f"the sensitivity curve (R) {where}",
    )
    resp = resp_curve[:, powers.index(1)]
    curve_draws: dict[str, tuple[tuple[int, ...], np.ndarray]] = {
        "photon_transfer": (powers, k_curve),
        "sensitivity": (powers, resp_curve),
    }
    n_pix = c["n_pixels"].iloc[0]
    if not np.isfinite(n_pix):
        n_pix = 640 * 480  # reduced tables carry no pixel count: assume the full VGA frame of the data set
    s2_d0 = float(c["s2_dark"].iloc[0])
    s2_dark = np.maximum((n_pix - 1) * s2_d0 / rng.chisquare(n_pix - 1, n_draws), DARK_FLOOR_DN2)
    if _dark_exposures(steps) >= 2:
        dk = steps.dark
        t = dk["texp_s"].to_numpy()
        dark_line, fell_mean = _rising_line_posterior(t, dk["mean_dn"].to_numpy(), n_draws, rng, "mean dark signal")
        var_line, fell_var = _rising_line_posterior(t, dk["var_dn2"].to_numpy(), n_draws, rng, "dark variance")
        if fell_mean is None:
            curve_draws["dark_mean"] = ((1, 0), dark_line)
        i_mean, i_var = dark_line[:, 0] / k, var_line[:, 0] / k**2
        fell = {"dark_current_mean": fell_mean, "dark_current_var": fell_var}
        fell["dark_current_difference"] = fell_mean or fell_var
    else:
        i_mean = i_var = np.full(n_draws, np.nan)
        fell = {}
    lin = _line_posterior(c["photons"].to_numpy()[_lin(r)], sig[_lin(r)], 1.0 / sig[_lin(r)] ** 2, n_draws, rng)
    curve_draws["linearity"] = ((1, 0), lin)
    le_min, le_max = _linearity_at_extremes(c, r, point, lin[:, 0], lin[:, 1])
    draws = _quantities(k, resp, s2_dark, i_mean, i_var, _saturation_draws(c, r, n_draws, rng), le_min, le_max)
    if steps.stack:
        draws.update(_nonuniformity(steps.stack, k, *_spatial_draws(steps.stack, n_pix, n_draws, rng)))
    notes = {name: why for name, why in fell.items() if why is not None}
    if not ptc["linear"]:  # Release 4 Linear does not apply: no K, nor what needs one (Release 4 General)
        why = (
            f"not determinable: the photon transfer curve is not straight over its fit range (its slope changes by "
            f"{ptc['change']:+.0%} [{ptc['interval'][0]:+.0%}, {ptc['interval'][1]:+.0%}] from the lower to the "
            "upper half): EMVA 1288 Release 4 Linear does not apply (the General module's quantities are reported)"
        )
        for name in NEEDS_K:
            if name in draws:
                draws[name] = np.full(n_draws, np.nan)
                notes[name] = why
        point = point | {name: np.nan for name in NEEDS_K if name in point} | _general(c, r, point)
        general = _general_draws(c, r, draws["u_p_sat"], n_pix, n_draws, rng)  # no K needed: with posteriors
        for name, values in general.items():
            draws[name] = values
            notes.pop(name, None)
    determined = _dark_exposures(steps) >= 2 and ptc["linear"]
    if determined:
        lo, hi = np.quantile(draws["dark_current_difference"], [0.025, 0.975])
        compatible = bool(lo <= 0.0 <= hi)
    else:
        compatible = None
    units = {
        "K": "DN/e-",
        "R": "DN/photon",
        "QE": "%",
        "sigma_y_dark": "DN",
        "sigma_d": "e-",
        "dark_current_mean": "e-/s",
        "dark_current_var": "e-/s",
        "dark_current_difference": "e-/s",
        "u_p_sat": "photons",
        "u_e_sat": "e-",
        "u_p_min": "photons",
        "DR": "1",
        "SNR_max": "1",
        "LE_min": "%",
        "LE_max": "%",
        "DSNU1288": "e-",
        "PRNU1288": "%",
    }
    rows = []
    for name, d in draws.items():
        q = np.quantile(d, [0.025, 0.5, 0.975]) if np.all(np.isfinite(d)) else np.full(3, np.nan)
        rows.append(
            {
                "quantity": name,
                "unit": units[name],
                "standard": float(point.get(name, np.nan)),
                "median": q[1],
                "q2.5": q[0],
                "q97.5": q[2],
                "note": "" if np.all(np.isfinite(d)) else notes.get(name, _undetermined(name)),
            }
        )
    curves = c.assign(signal=sig, var_signal=dvar)
    dark = steps.dark.reset_index(drop=True) if determined else None
    return Characterization(
        pd.DataFrame(rows),
        point,
        draws,
        curves,
        r,
        compatible,
        steps.source,
        curve_draws,
        dark,
        steps.stack,
        _layout_notes(steps),
        ptc,
        operating_point(steps),
    )


def operating_point(steps: Steps) -> dict:
    """The operating point of the datasheet (EMVA 1288's first table) as far as the set records it: the bit
    depth, the pixels per image, the exposure times and photons per pixel swept, the steps, the dark
    exposures and the stacks' images.  The wavelength, pixel size and gain are not in a set's files: the
    datasheet says so rather than inventing them."""
    b = steps.bright
    n_pix = b["n_pixels"].iloc[0] if "n_pixels" in b else np.nan
    out = {
        "bits": int(steps.bits),
        "pixels_per_image": int(n_pix) if np.isfinite(n_pix) else None,
        "exposure_s": [float(b["texp_s"].min()), float(b["texp_s"].max())],
        "photons_per_pixel": [float(b["photons"].min()), float(b["photons"].max())],
        "bright_steps": int(len(b)),
        "dark_exposures_s": sorted({round(float(t), 12) for t in steps.dark["texp_s"]}),
        "stack_images": int(steps.stack["n_images"]) if steps.stack else 0,
    }
    image = steps.stack.get("image_bright") if steps.stack else None
    if image is not None:
        out["image_shape"] = list(np.shape(image))
    return out


def _general(c: pd.DataFrame, r: dict, point: dict) -> dict:
    """EMVA 1288 Release 4 General's point values, which need no photon transfer: the signal-to-noise ratio
    measured at every step, ``(mu_y - mu_dark) / s_y``; its largest value below saturation; the photons at
    which it reaches 1 (the absolute sensitivity threshold, interpolated in log-log); the dynamic range."""
    sat = r["index_u_ysat"]
    signal = (c["mu_y"] - c["mu_dark"]).to_numpy()[: sat + 1]
    out = _snr_quantities(signal, c["s2_y"].to_numpy()[: sat + 1], c["photons"].to_numpy()[: sat + 1], point["u_p_sat"])
    return {k: float(v) for k, v in out.items() if np.isfinite(v)}


def _general_draws(c: pd.DataFrame, r: dict, u_p_sat: np.ndarray, n_pix: float, n: int, rng) -> dict:
    """Posterior draws of Release 4 General's quantities (:func:`_general`): each step's mean signal and
    temporal variance drawn from their sampling distributions over the ``n_pix`` pixels of a pair (the mean
    Normal with the variance over the pixels, the variance scaled chi-square with ``n_pix - 1`` degrees of
    freedom: the standard's estimators' own noise, flat priors), and the saturation point's draws."""
    sat = r["index_u_ysat"]
    mean = (c["mu_y"] - c["mu_dark"]).to_numpy()[: sat + 1]
    s2 = np.maximum(c["s2_y"].to_numpy()[: sat + 1], 1e-300)
    s2_dark = c["s2_dark"].to_numpy()[: sat + 1]
    dof = max(float(n_pix) - 1.0, 1.0)
    signal = mean + np.sqrt((s2 + s2_dark) / (2.0 * float(n_pix))) * rng.standard_normal((n, mean.size))
    var = s2 * rng.chisquare(dof, (n, mean.size)) / dof
    return _snr_quantities(signal, var, c["photons"].to_numpy()[: sat + 1], u_p_sat)


def _snr_quantities(signal, var, photons: np.ndarray, u_p_sat) -> dict:
    """``SNR_max``, ``u_p_min`` and ``DR`` from the measured SNR curve ``signal / sqrt(var)`` over the steps up
    to saturation (the last axis; leading axes are draws): the threshold is where the SNR first reaches 1,
    interpolated in log-log between the steps around it (NaN where no step brackets it)."""
    snr = np.asarray(signal) / np.sqrt(np.maximum(var, 1e-300))
    photons = np.asarray(photons, dtype=float)
    reached = (snr >= 1.0) & (photons > 0)
    first = np.argmax(reached, axis=-1)
    below = np.take_along_axis(snr, np.maximum(first - 1, 0)[..., None], -1)[..., 0]
    at = np.take_along_axis(snr, first[..., None], -1)[..., 0]
    p0, p1 = photons[np.maximum(first - 1, 0)], photons[first]
    valid = reached.any(axis=-1) & (first > 0) & (below > 0) & (p0 > 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        x0, x1 = np.log(np.where(valid, p0, 1.0)), np.log(np.where(valid, p1, 2.0))
        y0, y1 = np.log(np.where(valid, below, 0.5)), np.log(np.where(valid, at, 1.0))
        u_p_min = np.where(valid, np.exp(x0 - y0 * (x1 - x0) / (y1 - y0)), np.nan)
    return {"SNR_max": np.max(snr, axis=-1), "u_p_min": u_p_min, "DR": np.asarray(u_p_sat) / u_p_min}


def _layout_notes(steps: Steps) -> tuple[str, ...]:
    """What the set's layout made the characterisation assume (:func:`_aligned`)."""
    dark_t = np.unique(np.round(steps.dark["texp_s"].to_numpy(), 12))
    bright_t = np.unique(np.round(steps.bright["texp_s"].to_numpy(), 12))
    if dark_t.size == 1 and not np.allclose(bright_t, dark_t[0], rtol=1e-9, atol=0):
        return (
            f"one dark exposure ({dark_t[0] * 1e3:g} ms) serves every bright step ({bright_t.min() * 1e3:g}-"
            f"{bright_t.max() * 1e3:g} ms): the dark signal is taken as the same at every exposure, so a dark "
            "current adds to the signal; measure dark pairs at each exposure to subtract it",
        )
    return ()


#: the Linear module's photon transfer must be straight over its fit range: a slope that changes by more than
#: this fraction between the range's lower and upper half (and significantly) makes K not determinable
PTC_LINEARITY_TOL = 0.10
#: the quantities that need a system gain K (EMVA 1288 Release 4 Linear); the General module reports the rest
NEEDS_K = (
    "K",
    "QE",
    "sigma_d",
    "dark_current_mean",
    "dark_current_var",
    "dark_current_difference",
    "u_e_sat",
    "u_p_min",
    "DR",
    "SNR_max",
    "DSNU1288",
)


def _ptc_linearity(signal: np.ndarray, var: np.ndarray, weights: np.ndarray, n: int, rng) -> dict:
    """Is the photon transfer curve straight over its fit range (EMVA 1288 Release 4 Linear, its validity)?
    Straight lines through the lower and the upper half of the steps: the posterior of the upper half's slope
    over the lower half's, less 1 (``change``), and whether it departs from 0 by more than
    :data:`PTC_LINEARITY_TOL` with its 95 % interval clear of 0 (``linear``)."""
    order = np.argsort(signal)
    half = order.size // 2
    if half < 3:
        return {"linear": True, "change": np.nan, "interval": [np.nan, np.nan], "steps": int(order.size)}
    lower, upper = order[:half], order[half:]
    slopes = [
        _line_posterior(signal[i], var[i], weights[i], n, rng, what="half of the photon transfer curve")[:, 0]
        for i in (lower, upper)
    ]
    change = slopes[1] / slopes[0] - 1.0
    lo, mid, hi = np.quantile(change, [0.025, 0.5, 0.975])
    bent = abs(mid) > PTC_LINEARITY_TOL and (lo > 0 or hi < 0)
    return {"linear": not bent, "change": float(mid), "interval": [float(lo), float(hi)], "steps": int(order.size)}


def _undetermined(name: str) -> str:
    if name.startswith("dark_current"):
        return "not determined: dark frames at one exposure time only (a dark current is a slope in time)"
    return "not determined by these data"
