"""What a measurement tells about a calibration: the Fisher information of each candidate row and the
sensitivity of each target quantity, at points of the posterior (docs/guides/design.md).

For a row read with mean ``m(z)`` and standard deviation ``s(z)`` (the model's ``row_mean`` and
``row_sd`` in its unconstrained parameters ``z``), a Gaussian reading carries the information::

    F_row = (grad m grad m' + 2 grad s grad s') / s^2

(the Fisher information of a normal mean and standard deviation), weighted by the chance that the row
is not clipped at full scale.  A design measuring group ``k`` ``n_k`` times then has the approximate
posterior precision ``H_prior + sum_k n_k F_k``, with ``H_prior`` the Hessian of the prior's negative
log density, and a target quantity ``q(z)`` the approximate posterior variance ``grad q' Sigma grad q``
(the Laplace approximation of docs/architecture.md, section 4, for a table not yet measured; Chaloner
and Verdinelli 1995, Bayesian experimental design, section 2).

The gradients are central differences through the model's own constrained sites and reported
quantities (:func:`bayescal.model.physical.physical_draws`), in one batch of ``2 d + 1`` points per
posterior point: nothing here restates the measurement equation.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
from scipy.special import ndtr

from bayescal.campaign.scale import NoiseScale, integrated_variances
from bayescal.inference.program import Program
from bayescal.model.assemble import CalibrationModel
from bayescal.model.physical import physical_draws

__all__ = ["Targets", "Linearisation", "linearise"]

#: the central-difference step in the unconstrained parameters (O(1) by construction, docs/architecture.md
#: section 5): truncation error ~ STEP^2, rounding ~ 1e-16 / STEP, both far below the widths compared
STEP = 1e-5


@dataclass(frozen=True)
class Targets:
    """The quantities a design must pin down.

    Attributes
    ----------
    coefficients : bool
        Every channel's response coefficients at the reference setting relative to the sphere
        (``A0`` the offset, ``A1`` the gain, ``A2..`` the nonlinearity; the reported ``A_rel``).
    rows : tuple of int
        Rows of the grid table whose expected reading is a target (a prediction at a setting and level).
    row_names : tuple of str
        Their names.
    """

    coefficients: bool = True
    rows: tuple[int, ...] = ()
    row_names: tuple[str, ...] = ()

    def names(self, model: CalibrationModel) -> tuple[str, ...]:
        """The target names, coefficients first (``A1[R]``), then the predictions."""
        out: list[str] = []
        if self.coefficients:
            order = model.spec.response.order
            out += [f"A{k}[{c}]" for c in model.layout.channels for k in range(order + 1)]
        return (*out, *self.row_names)

    def values(self, model: CalibrationModel, sites: dict, seed: int = 0) -> np.ndarray:
        """The targets at a batch of constrained sites (``(N, ...)`` each): ``(N, T)``, in DN and
        stimulus units."""
        parts = []
        if self.coefficients:
            lead = {k: np.asarray(v)[None] for k, v in sites.items()}  # (chain, draw, ...)
            coef = physical_draws(model, lead, seed)["A_rel"][0]
            parts.append(coef.reshape(coef.shape[0], -1))
        if self.rows:
            parts.append(np.asarray(sites["row_mean"])[:, list(self.rows)] * model.layout.dn_scale)
        return np.concatenate(parts, axis=1)


@dataclass(frozen=True)
class Linearisation:
    """The information of every grid group and the targets' gradients at ``S`` points of the parameters.

    Attributes
    ----------
    names : tuple of str
        Target names.
    values : array (S, T)
        The targets at each point.
    gradients : array (S, T, d)
        Their gradients in the unconstrained parameters.
    prior : array (S, d, d)
        The precision before any group is measured: the prior's (Hessian of its negative log density),
        with the information of the rows known already (``base`` of :func:`linearise`).
    factors : array (S, K, m, d)
        Group ``k``'s information is ``factors[s, k].T @ factors[s, k]`` (``m``: two per row of the group).
    clipped : array (K,)
        The chance, at the first point, that the group's reading is clipped in every channel (its smallest
        over channels: a group informs while one channel reads below full scale).
    noise : NoiseScale, optional
        The excess scatter's scale, integrated out of :meth:`sd` (:mod:`bayescal.campaign.scale`); None:
        the model has none, or the widths are taken at the points' scale.
    """

    names: tuple[str, ...]
    values: np.ndarray
    gradients: np.ndarray
    prior: np.ndarray
    factors: np.ndarray
    clipped: np.ndarray
    noise: NoiseScale | None = None

    @property
    def n_groups(self) -> int:
        return self.factors.shape[1]

    def precision(self, counts: np.ndarray) -> np.ndarray:
        """The approximate posterior precision ``(S, d, d)`` of a design measuring group ``k``
        ``counts[k]`` times (rows already measured enter as counts too)."""
        counts = np.asarray(counts, dtype=float)
        s, k, m, d = self.factors.shape
        flat = self.factors.reshape(s, k * m, d)
        return self.prior + np.swapaxes(flat, 1, 2) @ (flat * np.repeat(counts, m)[None, :, None])

    def covariance(self, counts: np.ndarray) -> np.ndarray:
        """Its inverse, ``(S, d, d)`` (symmetrised)."""
        cov = np.linalg.inv(self.precision(counts))
        return 0.5 * (cov + np.swapaxes(cov, 1, 2))

    def variances(self, cov: np.ndarray) -> np.ndarray:
        """The targets' variances ``(S, T)`` under covariances ``cov`` ``(S, d, d)``."""
        return np.sum((self.gradients @ cov) * self.gradients, axis=-1)

    def sd(self, counts: np.ndarray) -> np.ndarray:
        """The targets' expected posterior standard deviations ``(T,)``, averaged over the points, the
        noise scale integrated over its expected posterior under the design (when ``noise`` is given)."""
        if self.noise is None:
            var = self.variances(self.covariance(counts))
        else:
            var = integrated_variances(self.prior, self.factors, self.gradients, self.noise, counts)
        return np.sqrt(np.maximum(var, 0.0)).mean(axis=0)

    def at_scale(self) -> Linearisation:
        """The same information with the noise scale held at the points' (what the search optimises)."""
        return dataclasses.replace(self, noise=None)

    def reductions(self, cov: np.ndarray, groups: np.ndarray | None = None) -> np.ndarray:
        """How much measuring each group once more lowers each target's variance, ``(S, K, T)``, under the
        current covariances ``cov`` (Woodbury: ``Sigma' = Sigma - Sigma U' (I + U Sigma U')^-1 U Sigma``)."""
        factors = self.factors if groups is None else self.factors[:, groups]
        w = factors @ cov[:, None]  # (S, K, m, d)
        inner = w @ np.swapaxes(factors, 2, 3) + np.eye(factors.shape[2])
        v = w @ np.swapaxes(self.gradients, 1, 2)[:, None]  # (S, K, m, T)
        return np.sum(v * np.linalg.solve(inner, v), axis=2)


def _sites(program: Program, model: CalibrationModel, z: np.ndarray) -> dict:
    return {k: np.asarray(v) for k, v in program.constrain(z, model.data).items()}


def linearise(
    program: Program,
    model: CalibrationModel,
    z: np.ndarray,
    targets: Targets,
    groups: np.ndarray,
    n_groups: int,
    base: np.ndarray | None = None,
) -> Linearisation:
    """The information of each grid group and the targets' gradients at the points ``z`` ``(S, d)``.

    Parameters
    ----------
    program, model : Program, CalibrationModel
        The model of the grid table: every candidate row (whether or not it has been measured).
    z : array (S, d)
        Points of the unconstrained parameters (a mode, or draws of a posterior).
    targets : Targets
        What the design must pin down.
    groups : array (R,)
        The grid group of each row of the table (-1: a row that is no candidate, e.g. measured elsewhere).
    n_groups : int
        How many groups the grid has.
    base : array (R,) of bool, optional
        Rows whose information is known already and enters as the starting precision (the Hessian of the
        potential with only these rows' readings; none: the prior's); they stand for no group.

    The first row of each group in each channel stands for the group (a repeat is counted, not
    linearised again).
    """
    z = np.atleast_2d(np.asarray(z, dtype=float))
    d = z.shape[1]
    keep = np.zeros(len(groups), dtype=bool) if base is None else np.asarray(base, dtype=bool)
    groups = np.where(keep, -1, np.asarray(groups))
    channel = np.asarray(model.data.channel)
    stands = np.zeros(len(groups), dtype=bool)
    seen: set[tuple[int, int]] = set()
    for r in np.flatnonzero(groups >= 0):
        if (groups[r], channel[r]) not in seen:
            seen.add((groups[r], channel[r]))
            stands[r] = True
    per_group = np.bincount(groups[stands], minlength=n_groups)
    width = int(per_group.max()) if per_group.size else 0
    known = model.data._replace(keep=keep)
    threshold = float(np.asarray(model.data.threshold))
    names = targets.names(model)
    values, gradients, priors, factors, row_sds = [], [], [], [], []
    clipped = np.ones(n_groups)
    steps = np.concatenate([np.zeros((1, d)), STEP * np.eye(d), -STEP * np.eye(d)])
    for s, point in enumerate(z):
        sites = _sites(program, model, point[None] + steps)
        q = targets.values(model, sites)
        values.append(q[0])
        gradients.append(((q[1 : d + 1] - q[d + 1 :]) / (2 * STEP)).T)
        mean, sd = sites["row_mean"], sites["row_sd"]
        grad_m = (mean[1 : d + 1] - mean[d + 1 :]).T / (2 * STEP)  # (R, d)
        grad_s = (sd[1 : d + 1] - sd[d + 1 :]).T / (2 * STEP)
        kept = ndtr((threshold - mean[0]) / sd[0])  # the chance a row is not clipped
        scale = np.sqrt(kept) / sd[0]
        rows = np.concatenate([grad_m * scale[:, None], np.sqrt(2) * grad_s * scale[:, None]], axis=1)
        u = np.zeros((n_groups, 2 * width, d))
        row_sd = np.zeros((n_groups, width))
        filled = np.zeros(n_groups, dtype=int)
        for r in np.flatnonzero(stands):
            k = groups[r]
            u[k, 2 * filled[k]] = rows[r, :d]
            u[k, 2 * filled[k] + 1] = rows[r, d:]
            row_sd[k, filled[k]] = sd[0, r]
            filled[k] += 1
            if s == 0:
                clipped[k] = min(clipped[k], 1.0 - kept[r])
        factors.append(u)
        row_sds.append(row_sd)
        hess = np.asarray(program.hessian(point, known))
        priors.append(_positive(0.5 * (hess + hess.T)))
    return Linearisation(
        names=names,
        values=np.asarray(values),
        gradients=np.asarray(gradients),
        prior=np.asarray(priors),
        factors=np.asarray(factors),
        clipped=clipped,
        noise=_noise_scale(program, model, z, np.asarray(row_sds)),
    )


def _noise_scale(program: Program, model: CalibrationModel, z: np.ndarray, row_sd: np.ndarray) -> NoiseScale | None:
    """The excess scatter's coordinate, when the model samples one (``noise.excess_dn > 0``)."""
    index = program.site_index("excess")
    if index is None or model.spec.noise.excess_dn <= 0:
        return None
    excess = np.asarray(program.constrain(z, model.data)["excess"], dtype=float).reshape(-1)
    return NoiseScale(index, excess, model.spec.noise.excess_dn / model.layout.dn_scale, row_sd)


def _positive(hess: np.ndarray) -> np.ndarray:
    """The prior's precision made positive definite: its eigenvalues floored at 1e-8 of the largest (a
    hierarchical prior's Hessian can be indefinite away from its mode; a flat direction stays nearly flat)."""
    vals, vecs = np.linalg.eigh(hess)
    vals = np.maximum(vals, 1e-8 * max(float(vals.max()), 1.0))
    return (vecs * vals) @ vecs.T
