"""Least squares: the papers' baseline (seed 000 Table 1, seed 002 eq. 9-10).

Polynomials ``DN = A0 + A1 L + ... + Ap L^p`` per channel and setting, with
the goodness-of-fit numbers the papers quote (R^2, SSE, RMSE) and classical
t confidence intervals.  Solved by Householder QR on a column-equilibrated
Vandermonde matrix of the scaled abscissa ``u = x / h`` (``h`` the power of
two at or above ``max|x|``); coefficients are unscaled exactly (``A_k = c_k /
h^k``), refined iteratively with residuals formed in twice the precision
(:mod:`bayescal.inference.compensated`), which reproduces NIST StRD certified
values and keeps the standard errors' digits when residuals are tiny
(docs/architecture.md, section 5).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy import stats

from bayescal.inference.compensated import residual_dot2, residual_horner
from bayescal.io.table import MeasurementTable

__all__ = ["LinearFit", "lstsq", "polyfit", "lsq_baseline"]


@dataclass(frozen=True)
class LinearFit:
    """Ordinary least-squares result.

    ``rmse`` is ``sqrt(SSE / dof)`` (the residual standard deviation that
    MATLAB's curve fitter labels RMSE, as quoted by seed 002 Table 1);
    ``r2`` is centred with an intercept and uncentred without (NIST).

    Examples
    --------
    >>> import numpy as np
    >>> import bayescal as bc
    >>> x = np.arange(6.0)
    >>> line = bc.lstsq(np.column_stack([np.ones(6), x]), 1.0 + 2.0 * x + np.array([0.1, -0.1] * 3))
    >>> line.n, line.dof, round(line.rmse, 4)  # RMSE = sqrt(SSE / dof), as curve fitters quote it
    (6, 4, 0.1171)
    """

    coef: np.ndarray
    cov: np.ndarray
    sse: float
    dof: int
    r2: float
    n: int

    @property
    def se(self) -> np.ndarray:
        """Standard errors of the coefficients."""
        return np.sqrt(np.diag(self.cov))

    @property
    def rmse(self) -> float:
        """Residual standard deviation ``sqrt(SSE / dof)``."""
        return float(np.sqrt(self.sse / self.dof)) if self.dof > 0 else float("nan")

    def ci(self, level: float = 0.95) -> tuple[np.ndarray, np.ndarray]:
        """Classical two-sided t confidence interval of each coefficient."""
        t = stats.t.ppf(0.5 + level / 2, self.dof) if self.dof > 0 else np.inf
        return self.coef - t * self.se, self.coef + t * self.se


def lstsq(design: np.ndarray, y: np.ndarray, *, intercept_included: bool = True) -> LinearFit:
    """Least squares for a design matrix, by QR on equilibrated columns.

    Parameters
    ----------
    design : array (n, p)
        Predictor columns (include a column of ones for an intercept).
    y : array (n,)
        Responses.
    intercept_included : bool
        Whether R^2 is centred (a constant column is in the model).

    Examples
    --------
    >>> import numpy as np
    >>> import bayescal as bc
    >>> x = np.arange(5.0)
    >>> line = bc.lstsq(np.column_stack([np.ones(5), x]), 2.0 + 3.0 * x)
    >>> line.coef, line.r2, line.dof
    (array([2., 3.]), 1.0, 3)
    """
    design = np.asarray(design, dtype=float)
    return _solve(design, np.asarray(y, dtype=float), lambda c: residual_dot2(design, c, y), intercept_included)


def _solve(design: np.ndarray, y: np.ndarray, residual, intercept_included: bool) -> LinearFit:
    """QR least squares on power-of-two equilibrated columns (exact scaling), with iterative refinement
    (Bjorck) driven by ``residual(coef)``, residuals formed in twice the precision
    (:mod:`bayescal.inference.compensated`): the residual sd and the standard errors keep their digits
    when the residuals are tiny against the readings."""
    n, p = design.shape
    if n < p:
        raise ValueError(f"{n} points cannot determine {p} coefficients")
    norms = np.linalg.norm(design, axis=0)
    norms = np.where(norms > 0, np.exp2(np.round(np.log2(np.where(norms > 0, norms, 1.0)))), 1.0)
    q, r = np.linalg.qr(design / norms)
    coef_s = np.linalg.solve(r, q.T @ y)
    for _ in range(2):
        coef_s = coef_s + np.linalg.solve(r, q.T @ residual(coef_s / norms))
    resid = residual(coef_s / norms)
    sse = float(resid @ resid)
    dof = n - p
    r_inv = np.linalg.solve(r, np.eye(p))
    sigma2 = sse / dof if dof > 0 else np.nan
    cov_s = sigma2 * (r_inv @ r_inv.T)
    coef = coef_s / norms
    cov = cov_s / np.outer(norms, norms)
    sst = float(np.sum((y - y.mean()) ** 2)) if intercept_included else float(y @ y)
    r2 = 1.0 - sse / sst if sst > 0 else float("nan")  # constant readings: R^2 is undefined
    return LinearFit(coef=coef, cov=cov, sse=sse, dof=dof, r2=r2, n=n)


def polyfit(x: np.ndarray, y: np.ndarray, order: int, *, intercept: bool = True) -> LinearFit:
    """Monomial polynomial fit ``y = A0 + A1 x + ... + Ap x^p``; coefficients lowest power first.

    Without ``intercept`` the model is ``A1 x + ... + Ap x^p`` (NIST NoInt)
    and ``coef`` still starts with ``A1``.  The abscissa is scaled by a power
    of two (exact); residuals are evaluated on the original ``x`` by
    compensated Horner, so the rounding of the scaled powers does not enter
    the residual sd.

    Examples
    --------
    >>> import numpy as np
    >>> import bayescal as bc
    >>> x = np.array([0.0, 1.0, 2.0, 3.0, 4.0])
    >>> bc.polyfit(x, 2.0 + 3.0 * x, 1).coef
    array([2., 3.])
    """
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    top = float(np.max(np.abs(x))) or 1.0
    h = float(np.exp2(np.ceil(np.log2(top))))
    powers = np.arange(0 if intercept else 1, order + 1)
    scale = h**powers

    def residual(coef_scaled: np.ndarray) -> np.ndarray:
        full = np.zeros(order + 1)
        full[powers] = coef_scaled / scale
        return residual_horner(x, full, y)

    fit = _solve((x[:, None] / h) ** powers, y, residual, intercept)
    return LinearFit(
        coef=fit.coef / scale, cov=fit.cov / np.outer(scale, scale), sse=fit.sse, dof=fit.dof, r2=fit.r2, n=fit.n
    )


def lsq_baseline(table: MeasurementTable, orders=(1,), full_scale: float | None = None) -> pd.DataFrame:
    """The papers' per-setting polynomial fits of DN against the stimulus.

    For every channel and (exposure, gain, TDI) setting with enough distinct
    illuminated levels, fit each order.  Saturated points (at or above
    ``full_scale - 0.5``) are left out, as the papers drop them by hand.

    Returns
    -------
    pandas.DataFrame
        One row per channel, setting and order: ``A0..Ap`` with their
        ``_lo``/``_hi`` 95 % confidence limits and ``_se``, ``r2``, ``sse``,
        ``rmse``, ``n``.

    Examples
    --------
    >>> import bayescal as bc
    >>> sim = bc.simulate(bc.load_spec("seed000"), bc.load_design("seed000"), seed=1)
    >>> lsq = bc.lsq_baseline(sim.table)  # a line per channel and setting, as the papers fit
    >>> green = lsq[(lsq["channel"] == "G") & (lsq["exposure_s"] == 0.004)].iloc[0]
    >>> round(float(green["A1"]), 1), bool(green["r2"] > 0.9999)
    (30.4, True)
    """
    df = table.frame
    lit = df["stimulus"] > 0
    if full_scale is not None:
        lit &= df["dn_mean"] < full_scale - 0.5
    rows = []
    keys = ["channel", "exposure_s", "gain", "tdi_stages"]
    for key, grp in df[lit].groupby(keys, sort=False):
        for order in orders:
            if grp["stimulus"].nunique() < order + 2:
                continue
            fit = polyfit(grp["stimulus"].to_numpy(), grp["dn_mean"].to_numpy(), order)
            lo, hi = fit.ci()
            row = dict(zip(keys, key, strict=True), order=order, n=fit.n, r2=fit.r2, sse=fit.sse, rmse=fit.rmse)
            for k in range(order + 1):
                row.update({f"A{k}": fit.coef[k], f"A{k}_se": fit.se[k], f"A{k}_lo": lo[k], f"A{k}_hi": hi[k]})
            rows.append(row)
    return pd.DataFrame(rows)
