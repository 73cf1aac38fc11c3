"""Stage one of the fleet model: each unit fitted alone, its likelihood summarised as a Gaussian.

Every (camera, campaign) unit is fitted with the channel-level model
(:func:`bayescal.fit_many`, one compilation per table structure).  The fleet
quantities of a unit are, per channel: the log gain relative to the sphere's
reading (``log A1``), the offset at the reference setting (``A0``, DN) and the
nonlinearity coefficients ``eta``.  Their posterior is summarised by its mean
and covariance; the Gaussian prior of ``eta`` is divided out (exact for a
Gaussian), so what stage two sees is each unit's *likelihood* of its fleet
quantities (the gain's and offset's priors are nearly flat: log-sd 2, a quarter
of full scale).  This is the two-stage route to a hierarchical posterior
(docs/architecture.md, section 8): exact when each unit's likelihood is
Gaussian in these quantities, which the coverage runs check.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from bayescal.errors import SpecError
from bayescal.fitting.batch import FitBatch, fit_many
from bayescal.fitting.result import Fit
from bayescal.fleet.units import FleetTable
from bayescal.model.physical import POOLED, pooled_quantities
from bayescal.model.spec import ModelSpec

if TYPE_CHECKING:
    import pandas as pd

__all__ = ["UnitFits", "fit_units", "QUANTITIES"]

#: fleet quantity kinds before the nonlinearity's, in the order of the per-unit vector (one entry per channel)
QUANTITIES = POOLED
#: eigenvalue floor of a unit's likelihood precision, relative to its largest (prior division noise)
PRECISION_FLOOR = 1e-9


@dataclass(frozen=True, eq=False)
class UnitFits:
    """Each unit's fit and the Gaussian summary of its likelihood of the fleet quantities.

    Attributes
    ----------
    fleet : FleetTable
    kinds : tuple of str
        Quantity kinds: ``log_gain``, ``offset``, ``eta1``, ``eta2``, ...
    channels : tuple of str
    mean : array (U, K, C)
        Per unit, kind and channel: the likelihood's centre.
    cov : array (U, K*C, K*C)
        Its covariance (kind-major order).
    diagnostics : pandas.DataFrame
        Per unit: ``camera``, ``campaign``, ``rows``, ``ok`` (the unit's own fit passed every
        check), ``converged`` (its posterior was computed correctly: MAP, R-hat, ESS,
        divergences), ``max_abs_residual_z`` and ``misfit``.
    """

    fleet: FleetTable
    kinds: tuple[str, ...]
    channels: tuple[str, ...]
    mean: np.ndarray
    cov: np.ndarray
    diagnostics: pd.DataFrame
    backend: str
    _batches: tuple[tuple[FitBatch, int], ...]

    def fit(self, u: int) -> Fit:
        """Unit ``u``'s full stage-one :class:`~bayescal.fitting.fit.Fit`."""
        batch, i = self._batches[u]
        return batch.fit(i)

    def physical(self, u: int) -> dict[str, np.ndarray]:
        """Unit ``u``'s reported quantities (``(chain, draw, ...)``)."""
        batch, i = self._batches[u]
        return batch.physical(i)


def fit_units(
    fleet: FleetTable,
    spec: ModelSpec,
    backend: str = "laplace",
    *,
    seed: int = 0,
    progress: Callable[[int], None] | None = None,
) -> UnitFits:
    """Fit every unit of ``fleet`` alone and summarise its likelihood (see module docstring).

    Units of one table structure share one compiled program (:func:`bayescal.fit_many`);
    unit ``u`` is fitted with seed ``seed + u``.
    """
    import pandas as pd

    from bayescal.model.assemble import build_model

    units = fleet.units
    groups: dict[tuple, list[int]] = {}
    for u, unit in enumerate(units):
        groups.setdefault(build_model(unit.table, spec).structure_key, []).append(u)
    batches: list[tuple[FitBatch, int] | None] = [None] * len(units)
    done = 0
    for members in groups.values():

        def tick(n: int, base: int = done) -> None:
            if progress is not None:
                progress(base + n)

        batch = fit_many(
            [units[u].table for u in members], spec, backend, seeds=[seed + u for u in members], progress=tick
        )
        for i, u in enumerate(members):
            batches[u] = (batch, i)
        done += len(members)
        if progress is not None:
            progress(done)
    channels = tuple(units[0].table.channels)
    for unit in units:
        if tuple(unit.table.channels) != channels:
            raise SpecError(
                f"{unit.label} has channels {', '.join(unit.table.channels)} but {units[0].label} has "
                f"{', '.join(channels)}; every unit of a fleet needs the same channels"
            )
    n_eta = spec.response.order - 1
    kinds = QUANTITIES + tuple(f"eta{k + 1}" for k in range(n_eta))
    fitted = [b for b in batches if b is not None]  # every unit is in one group
    means, covs, rows = [], [], []
    for unit, (batch, i) in zip(units, fitted, strict=True):
        phys = batch.physical(i)
        vec = _quantities(phys, kinds, unit.label)  # (S, K, C)
        mean, cov = _likelihood(vec, spec.response.nonlinearity_prior_sd, n_eta)
        means.append(mean)
        covs.append(cov)
        diag = batch.diagnostics.iloc[i]
        rows.append(
            {
                "camera": unit.camera,
                "campaign": None if unit.campaign is None else unit.campaign.date().isoformat(),
                "rows": len(unit.table),
                "ok": bool(diag["ok"]),
                "converged": bool(diag["sampled"]),
                "max_abs_residual_z": float(diag["max_abs_residual_z"]),
                "misfit": diag.get("misfit", ""),
            }
        )
    return UnitFits(
        fleet=fleet,
        kinds=kinds,
        channels=channels,
        mean=np.stack(means),
        cov=np.stack(covs),
        diagnostics=pd.DataFrame(rows),
        backend=backend,
        _batches=tuple(fitted),
    )


def _quantities(phys: dict[str, np.ndarray], kinds: tuple[str, ...], label: str) -> np.ndarray:
    """Draws of the fleet quantities (:func:`bayescal.model.physical.pooled_quantities`), ``(S, K, C)``."""
    pooled = {k: v.reshape((-1,) + v.shape[2:]) for k, v in pooled_quantities(phys).items()}
    if not np.all(np.isfinite(pooled["offset"])):
        raise SpecError(
            f"{label}: no dark rows at the reference gain, so the offset at the reference setting is not "
            "measured; a fleet needs every unit's dark frames at the spec's [reference] gain"
        )
    if not np.all(np.isfinite(pooled["log_gain"])):
        raise SpecError(f"{label}: a non-positive gain draw; the unit's fit does not describe a camera")
    return np.stack([pooled[k] for k in kinds], axis=1)


def _likelihood(vec: np.ndarray, eta_prior_sd: float, n_eta: int) -> tuple[np.ndarray, np.ndarray]:
    """Mean and covariance of the unit's likelihood: the posterior's Gaussian with the eta prior divided out."""
    s, k, c = vec.shape
    flat = vec.reshape(s, k * c)
    mean = flat.mean(axis=0)
    cov = np.cov(flat, rowvar=False)
    prior_prec = np.zeros(k * c)
    if n_eta:
        prior_prec[len(QUANTITIES) * c :] = 1.0 / eta_prior_sd**2  # eta prior: Normal(0, sd), mean 0
    scale = np.sqrt(np.diag(cov))
    corr = cov / np.outer(scale, scale)
    prec = np.linalg.inv(corr) / np.outer(scale, scale) - np.diag(prior_prec)
    prec = 0.5 * (prec + prec.T)
    w, v = np.linalg.eigh(prec * np.outer(scale, scale))
    w = np.maximum(w, PRECISION_FLOOR * w.max())
    cov_lik = (v / w) @ v.T * np.outer(scale, scale)
    info = np.linalg.solve(cov, mean)  # the prior's mean is 0: no prior term in the information vector
    mean_lik = cov_lik @ info
    return mean_lik.reshape(k, c), cov_lik
