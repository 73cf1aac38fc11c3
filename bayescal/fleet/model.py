"""Stage two of the fleet model: the hierarchy over channels, cameras and campaigns.

Each unit ``u`` (camera ``m`` measured at campaign time ``t_u``, years) reports a
Gaussian likelihood of its fleet quantities ``y_u`` (:mod:`.stage1`).  Per
quantity kind ``k`` (log gain, offset, nonlinearity terms) and channel ``c``::

    theta[k, u, c] = level[k, m, c] + drift[k, u]            (+ sphere[j(u)] for the log gain)
    level[k, m, c] = mu[k, c] + a[k, m] + b[k, m, c]
    a[k, m] ~ Normal(0, sigma_camera[k])                     the camera within the type
    b[k, m, c] ~ Normal(0, sigma_channel[k])                 the channel within the camera
    drift[k, u] = (rho[k] + r[k, m]) (t_u - t_mean) + w[k, u] + e[k, u]   log gain and offset only
    r[k, m] ~ Normal(0, rate_sd[k])                          the fleet's spread of drift rates
    w[k, u] = w[k, u-1] + walk_sd[k] sqrt(t_u - t_{u-1}) z   a random walk per camera
    e[k, u] ~ Normal(0, jitter_sd[k])                        the unit's own state in that campaign
    sphere[j] ~ Normal(0, common_rel)                        the sphere's log scale error, per campaign
    state[j] ~ Normal(0, campaign_sd)                        a common effect on the gains measured in campaign j
    s[k, m] = T_k L_m e,  e ~ Normal(0, I)                   the camera's error repeating in its campaigns
    y_u ~ MultivariateNormal(theta[:, u, :] (+ sphere, state) + s[:, m], T_k Sigma_u T_k)
    T_k = sqrt(kappa[k, 1]) P_1 + sqrt(kappa[k, 2]) P_2      P_1: the channels' mean, P_2 = I - P_1

The excess dispersion ``kappa >= 1`` scales a unit's own (stage-one) covariance where
the channels move together and where they differ, separately: a unit's log gains are
0.93-0.97 correlated across channels, and the channel model's misfit inflates the two
directions by different amounts (``benchmarks/fleet_excess_directions.py``).

Given the scales ``h = (sigma_camera, sigma_channel, rate_sd, walk_sd, jitter_sd, kappa)`` everything
else is linear and Gaussian, so it is integrated out exactly: NUTS samples only the
few scales on their marginal likelihood (no funnel to parametrise around, whatever
the data's strength), and every other quantity is then drawn from its Gaussian
conditional, per draw.  The latent precision is block-arrowhead (one block per camera
plus the fleet-wide ``mu``, ``rho`` and sphere terms), so each evaluation costs one
small Cholesky factor per camera and one of the global block (Schur complement).
Quantities are standardised by the spread of the units' estimates, so one set of
hyperpriors (:class:`~bayescal.fleet.spec.FleetSpec`) serves gains and offsets
(docs/architecture.md, section 8).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import lru_cache
from typing import NamedTuple

import numpy as np

from bayescal.fleet.excess import direction_sizes, excess_of, kind_blocks, projections, weighted
from bayescal.fleet.spec import FleetSpec
from bayescal.fleet.stage1 import UnitFits
from bayescal.fleet.units import to_years

__all__ = [
    "FleetData",
    "Plan",
    "fleet_data",
    "log_marginal",
    "integrated_value",
    "conditional_draws",
    "with_units",
    "design_of",
]

#: the prior sd of a camera's level without pooling (standardised units: effectively flat)
UNPOOLED_SD = 30.0
#: prior variance of a global term that a pooling leaves out (effectively fixed at 0)
ABSENT_VAR = 1e-10


class GlobalSlots(NamedTuple):
    """Where each fleet-wide latent sits in a kind's global vector (:attr:`Plan.g`)."""

    mu: slice  # each channel's fleet mean (C)
    rho: int  # the fleet's common trend
    sphere: slice  # each sphere's log scale error (J; the log gain only)
    campaign: slice  # each campaign's fleet-wide state (the log gain only)


class CameraSlots(NamedTuple):
    """Where each of a camera's latents sits in its block (:attr:`Plan.m`)."""

    a: int  # the camera's level, common to its channels
    b: slice  # its channels' own levels (C)
    r: int  # its trend, off the fleet's
    walk: slice  # its random-walk steps (max_walk)
    jitter: slice  # its campaigns' own states (max_units)
    shared: slice  # its repeating error, in what its units report (C)


@dataclass(frozen=True)
class Plan:
    """The static structure of one fleet model (one compilation per plan and data shape).

    Latent slots per kind (:attr:`g`, :attr:`m`): global ``[mu_c (C), rho, sphere_j (J), campaign
    states]``, per camera ``[a, b_c (C), r, walk steps (max_walk), unit jitters (max_units), shared
    error (C)]``; slots a kind does not use stay inactive.
    """

    n_kinds: int
    n_channels: int
    n_cameras: int
    n_units: int
    n_spheres: int
    n_walk: int
    max_walk: int
    drift: bool
    walk: bool
    pooling: str
    spread_prior: float
    rate_prior: float
    walk_prior: float
    excess: bool = True
    excess_prior: float = 2.0
    excess_together_prior: float = 0.1
    max_units: int = 0
    jitter_prior: float = 0.3
    shared: bool = False
    n_campaigns: int = 0  # fleet-wide campaign states of the log gain (0: none)

    @property
    def jitter(self) -> bool:
        return self.max_units > 0

    @property
    def n_directions(self) -> int:
        """Directions of a unit's error with their own excess: the channels together, and apart."""
        return 2 if self.n_channels > 1 else 1

    @property
    def pairs(self) -> tuple[tuple[int, int], ...]:
        """The weight products of the Gram arrays: pairs ``a <= b`` of the factors
        ``(kappa_together^-1/2, kappa_apart^-1/2, 1)`` (:func:`.excess.factors`)."""
        f = self.n_directions + 1
        return tuple((a, b) for a in range(f) for b in range(a, f))

    @property
    def n_drift(self) -> int:
        return 2 if self.drift else 0

    @property
    def g(self) -> GlobalSlots:
        """The global latents' slots, by name."""
        c, j = self.n_channels, self.n_spheres
        return GlobalSlots(slice(0, c), c, slice(c + 1, c + 1 + j), slice(c + 1 + j, self.n_global))

    @property
    def m(self) -> CameraSlots:
        """A camera's latents' slots, by name."""
        c = self.n_channels
        walk = slice(2 + c, 2 + c + max(self.max_walk, 0))
        jitter = slice(walk.stop, walk.stop + self.max_units)
        return CameraSlots(0, slice(1, 1 + c), 1 + c, walk, jitter, slice(jitter.stop, self.block))

    @property
    def n_global(self) -> int:
        return self.n_channels + 1 + self.n_spheres + self.n_campaigns

    @property
    def block(self) -> int:
        return self.shared_base + (self.n_channels if self.shared else 0)

    @property
    def shared_base(self) -> int:
        return 2 + self.n_channels + max(self.max_walk, 0) + self.max_units

    def excess_priors(self) -> np.ndarray:
        """The half-normal prior scale of each ``kappa - 1``, ``(K * D,)`` (kind-major, as sampled):
        ``excess_together_prior`` where the channels move together in a kind with a campaign jitter
        (that excess and the jitter are one value per unit each, :class:`~bayescal.fleet.spec.FleetSpec`),
        ``excess_prior`` elsewhere."""
        scales = np.full((self.n_kinds, self.n_directions), self.excess_prior)
        if self.jitter:
            scales[: self.n_drift, 0] = self.excess_together_prior
        return scales.reshape(-1)

    def sampled(self) -> dict[str, int]:
        """The scales NUTS samples and their sizes."""
        out: dict[str, int] = {}
        if self.pooling == "partial":
            out |= {"sigma_camera": self.n_kinds, "sigma_channel": self.n_kinds}
            if self.drift:
                out["rate_sd"] = 2
        if self.walk:
            out["walk_sd"] = 2
        if self.jitter:
            out["jitter_sd"] = 2
        if self.excess:
            out["excess"] = self.n_kinds * self.n_directions
        return out


@dataclass(frozen=True)
class FleetData:
    """The stage-two model's arrays (standardised) and how to undo the standardisation.

    ``value = center[k, c] + scale[k] * theta``.  Per weight product and kind (leading
    ``(P, K)``, :func:`_blocks`): ``g_*`` and ``b_*`` are the blocks of ``H' Sigma^-1 H`` and
    ``H' Sigma^-1 y`` (global ``g``, per camera ``m``), ``yy`` is ``y' Sigma^-1 y``;
    ``n_rows`` ``(K, D)`` counts the units' values in each direction of the excess.
    """

    y: np.ndarray  # (U, K*C)
    chol: np.ndarray  # (U, K*C, K*C) Cholesky factors of the units' covariances (kind-block-diagonal)
    camera: np.ndarray  # (U,) int
    sphere: np.ndarray  # (U,) int
    t: np.ndarray  # (U,) years minus t_mean
    years: np.ndarray  # (U,) years since the origin
    walk_units: np.ndarray  # (n_walk,) units that follow an earlier one of their camera
    walk_dt: np.ndarray  # (n_walk,) years since that earlier unit
    walk_interval: np.ndarray  # () the mean of walk_dt (1 without steps): NUTS's walk-jitter coordinates
    walk_slot: np.ndarray  # (n_walk,) the step's slot in its camera's block
    unit_slot: np.ndarray  # (U,) the unit's place among its camera's units
    shared_chol: np.ndarray  # (K, M, C, C) factor of each camera's repeating error covariance
    campaign: np.ndarray  # (U,) the unit's campaign
    campaign_sd: float  # the fleet-wide campaign state's sd (standardised log gain; 0: none)
    sphere_sd: float  # common_rel in standardised log-gain units
    center: np.ndarray  # (K, C)
    scale: np.ndarray  # (K,)
    t_mean: float
    g_gg: np.ndarray  # (P, K, G, G)
    g_gm: np.ndarray  # (P, K, M, G, B)
    g_mm: np.ndarray  # (P, K, M, B, B)
    b_g: np.ndarray  # (P, K, G)
    b_m: np.ndarray  # (P, K, M, B)
    prior_var_g: np.ndarray  # (K, G)
    active: np.ndarray  # (K, M, B) 1 where the slot is a real latent
    yy: np.ndarray  # (P, K)
    n_rows: np.ndarray  # (K, D) the units' values per kind and direction

    def arrays(self) -> dict[str, np.ndarray]:
        """The traced arguments of the marginal likelihood."""
        names = ("g_gg", "g_gm", "g_mm", "b_g", "b_m", "prior_var_g", "active", "yy", "n_rows", "walk_interval")
        return {k: getattr(self, k) for k in names}


def fleet_data(fits: UnitFits, fleet_spec: FleetSpec, common_rel: float) -> tuple[FleetData, Plan]:
    """Standardise the stage-one summaries and build the blocks of the marginal likelihood."""
    fleet = fits.fleet
    units = fleet.units
    n_units, n_kinds, n_ch = fits.mean.shape
    cam_index = {c: i for i, c in enumerate(fleet.cameras)}
    camera = np.array([cam_index[u.camera] for u in units])
    n_cam = len(fleet.cameras)
    years = to_years([u.campaign for u in units], fleet.origin) if fleet.origin is not None else np.zeros(n_units)
    campaigns = sorted(set(years.tolist()))
    drift = fleet_spec.drift and len(campaigns) >= 2
    if fleet_spec.sphere == "shared" or not campaigns:
        sphere = np.zeros(n_units, dtype=int)
    else:
        sphere = np.array([campaigns.index(y) for y in years])
    # standardise each kind by the spread of the units' estimates (or their noise, if larger)
    sd = np.sqrt(np.diagonal(fits.cov, axis1=1, axis2=2)).reshape(n_units, n_kinds, n_ch)
    center = fits.mean.mean(axis=0)
    spread = np.sqrt(np.mean(fits.mean.var(axis=0), axis=1))
    scale = np.maximum(spread, np.median(sd, axis=(0, 2)))
    scale = np.where(scale > 0, scale, 1.0)
    y = (fits.mean - center) / scale[None, :, None]  # (U, K, C)
    s_vec = np.repeat(scale, n_ch)
    cov = fits.cov / np.outer(s_vec, s_vec)
    # each kind's own (marginal) likelihood: a kind the hierarchy describes less well (a gain
    # that ages along a curve) must not pull another (the offset) through their correlation
    cov = cov * np.kron(np.eye(n_kinds), np.ones((n_ch, n_ch)))
    # a fraction of each unit's error repeats in every campaign of its camera (the same method's
    # systematic errors): a camera-level error term carries it, so campaigns do not average it away
    rho = fleet_spec.shared_error
    shared_chol = np.zeros((n_kinds, n_cam, n_ch, n_ch))
    if rho > 0:
        for m in range(n_cam):
            mean_cov = cov[camera == m].mean(axis=0)
            for k in range(n_kinds):
                sl = slice(k * n_ch, (k + 1) * n_ch)
                shared_chol[k, m] = np.linalg.cholesky(rho * mean_cov[sl, sl] + 1e-15 * np.eye(n_ch))
        cov = (1.0 - rho) * cov
    chol = np.linalg.cholesky(cov + 1e-12 * np.eye(cov.shape[-1]))
    t_mean = float(years.mean())
    t = years - t_mean
    walk_units, walk_dt, walk_slot = [], [], []
    if drift and fleet_spec.walk:
        prev: dict[int, int] = {}
        count: dict[int, int] = {}
        for u in range(n_units):
            m = int(camera[u])
            if m in prev and years[u] > years[prev[m]]:
                walk_units.append(u)
                walk_dt.append(years[u] - years[prev[m]])
                walk_slot.append(count.get(m, 0))
                count[m] = count.get(m, 0) + 1
            prev[m] = u
    max_walk = max(walk_slot, default=-1) + 1
    unit_slot = np.zeros(n_units, dtype=int)
    seen: dict[int, int] = {}
    for u in range(n_units):
        unit_slot[u] = seen.get(int(camera[u]), 0)
        seen[int(camera[u])] = unit_slot[u] + 1
    max_units = int(unit_slot.max()) + 1 if drift and fleet_spec.jitter else 0
    plan = Plan(
        n_kinds=n_kinds,
        n_channels=n_ch,
        n_cameras=n_cam,
        n_units=n_units,
        n_spheres=int(sphere.max()) + 1,
        n_campaigns=len(campaigns) if drift and fleet_spec.campaign_sd > 0 else 0,
        n_walk=len(walk_units),
        max_walk=max_walk,
        drift=drift,
        walk=max_walk > 0,
        pooling=fleet_spec.pooling,
        spread_prior=fleet_spec.spread_prior,
        rate_prior=fleet_spec.rate_prior,
        walk_prior=fleet_spec.walk_prior,
        excess=fleet_spec.excess,
        excess_prior=fleet_spec.excess_prior,
        excess_together_prior=fleet_spec.excess_together_prior,
        max_units=max_units,
        jitter_prior=fleet_spec.jitter_prior,
        shared=rho > 0,
    )
    walk = (np.asarray(walk_units, int), np.asarray(walk_dt, float), np.asarray(walk_slot, int))
    campaign = np.array([campaigns.index(y) for y in years]) if campaigns else np.zeros(n_units, dtype=int)
    h_g, h_m, active = _design(plan, camera, sphere, t, *walk, unit_slot, shared_chol, campaign)
    g_gg, g_gm, g_mm, b_g, b_m, yy = _blocks(plan, h_g, h_m, cov, y, camera)
    prior_var_g = np.ones((n_kinds, plan.n_global))  # unused slots: N(0, 1), untouched by data
    prior_var_g[:, :n_ch] = 9.0 if plan.pooling != "none" else ABSENT_VAR
    if drift:
        prior_var_g[:2, n_ch] = fleet_spec.rate_prior**2 if plan.pooling != "none" else ABSENT_VAR
    # the camera's convention (bayescal.model.components.sphere): common_rel is the sd of the log scale
    sphere_var = (common_rel / scale[0]) ** 2 if common_rel > 0 else ABSENT_VAR
    prior_var_g[0, n_ch + 1 : n_ch + 1 + plan.n_spheres] = sphere_var
    if plan.n_campaigns:
        prior_var_g[0, n_ch + 1 + plan.n_spheres :] = (fleet_spec.campaign_sd / scale[0]) ** 2
    data = FleetData(
        y=y.reshape(n_units, -1),
        chol=chol,
        camera=camera,
        sphere=sphere,
        t=t,
        years=years,
        walk_units=walk[0],
        walk_dt=walk[1],
        walk_interval=np.asarray(np.mean(walk[1]) if len(walk[1]) else 1.0, dtype=float),
        walk_slot=walk[2],
        unit_slot=unit_slot,
        shared_chol=shared_chol,
        campaign=campaign,
        campaign_sd=float(fleet_spec.campaign_sd / scale[0]) if plan.n_campaigns else 0.0,
        sphere_sd=float(np.sqrt(sphere_var)),
        center=center,
        scale=scale,
        t_mean=t_mean,
        g_gg=g_gg,
        g_gm=g_gm,
        g_mm=g_mm,
        b_g=b_g,
        b_m=b_m,
        prior_var_g=prior_var_g,
        active=active,
        yy=yy,
        n_rows=np.tile(n_units * direction_sizes(plan), (n_kinds, 1)),
    )
    return data, plan


def _blocks(plan: Plan, h_g, h_m, cov, y, camera):
    """The Gram arrays of stage two, one per weight product (:attr:`Plan.pairs`), per kind.

    A unit's error covariance is ``T Sigma T`` with ``T = sqrt(kappa_1) P_1 + sqrt(kappa_2) P_2``
    (``P_1`` the channels' mean, ``P_2 = I - P_1``: the excess where the channels move together and
    where they differ), and the camera's shared error is ``T L e``.  Multiplying a unit's values by
    ``T^-1 = sum_a f_a P_a`` (``f_a = kappa_a^-1/2``) leaves ``Sigma`` and ``L e`` unscaled, so
    ``H' T^-1 Sigma^-1 T^-1 H = sum_{a<=b} f_a f_b G_ab``: each ``G_ab`` (and each ``b_ab``,
    ``yy_ab``) is computed once here, from the pieces ``X_a`` of the design (``P_a H`` for the
    directional columns; the shared error's columns under the factor 1) and of the values.
    Returns ``g_gg (P, K, G, G)``, ``g_gm (P, K, M, G, B)``, ``g_mm (P, K, M, B, B)``,
    ``b_g (P, K, G)``, ``b_m (P, K, M, B)`` and ``yy (P, K)``; ``y`` is ``(U, K, C)``.
    """
    onehot = np.eye(plan.n_cameras)[camera]  # (U, M)
    x_g, x_m, v = pieces(plan, h_g, h_m, y)
    prec = np.linalg.inv(kind_blocks(plan, cov))

    def both(a, b, form):  # the ordered pairs (a, b) and (b, a) share the weight f_a f_b
        return form(a, b) + (form(b, a) if a != b else 0.0)

    out: dict[str, list] = {name: [] for name in ("g_gg", "g_gm", "g_mm", "b_g", "b_m", "yy")}
    for a, b in plan.pairs:
        out["g_gg"].append(both(a, b, lambda i, j: np.einsum("kuci,kucd,kudj->kij", x_g[i], prec, x_g[j])))
        out["g_gm"].append(both(a, b, lambda i, j: np.einsum("kuci,kucd,kudj,um->kmij", x_g[i], prec, x_m[j], onehot)))
        out["g_mm"].append(both(a, b, lambda i, j: np.einsum("kuci,kucd,kudj,um->kmij", x_m[i], prec, x_m[j], onehot)))
        out["b_g"].append(both(a, b, lambda i, j: np.einsum("kuci,kucd,kud->ki", x_g[i], prec, v[j])))
        out["b_m"].append(both(a, b, lambda i, j: np.einsum("kuci,kucd,kud,um->kmi", x_m[i], prec, v[j], onehot)))
        out["yy"].append(both(a, b, lambda i, j: np.einsum("kuc,kucd,kud->k", v[i], prec, v[j])))
    return tuple(np.stack(out[name]) for name in ("g_gg", "g_gm", "g_mm", "b_g", "b_m", "yy"))


def pieces(plan: Plan, h_g, h_m, y) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The design and the values split by the factor that scales them (:func:`_blocks`):
    ``x_g (F, K, U, C, G)``, ``x_m (F, K, U, C, B)`` and ``v (F, K, U, C)``; ``T^-1 H = sum_a f_a x_a``."""
    n_dir = plan.n_directions
    shared = np.zeros(plan.block, bool)
    shared[plan.m.shared] = True  # empty without a shared error
    proj = projections(plan.n_channels)
    x_g = np.zeros((n_dir + 1,) + h_g.shape)
    x_m = np.zeros((n_dir + 1,) + h_m.shape)
    v = np.zeros((n_dir + 1, plan.n_kinds, plan.n_units, plan.n_channels))
    for a in range(n_dir):
        x_g[a] = np.einsum("cd,kudg->kucg", proj[a], h_g)
        x_m[a] = np.einsum("cd,kudb->kucb", proj[a], h_m * ~shared)
        v[a] = np.einsum("cd,ukd->kuc", proj[a], y)
    x_m[n_dir] = h_m * shared
    return x_g, x_m, v


def design_of(plan: Plan, data: FleetData):
    """``H`` of built fleet data: global columns ``(K, U, C, G)``, own-camera columns
    ``(K, U, C, B)`` and the active camera slots ``(K, M, B)``."""
    fields = ("camera", "sphere", "t", "walk_units", "walk_dt", "walk_slot", "unit_slot", "shared_chol", "campaign")
    return _design(plan, *(getattr(data, f) for f in fields))


def with_units(plan: Plan, data: FleetData, y: np.ndarray, design=None) -> FleetData:
    """The same fleet (structure, units' covariances, standardisation) reporting other
    standardised values ``y`` ``(U, K, C)``: what simulation-based calibration refits
    (``design``: :func:`design_of` of ``data``, when the caller already has it)."""
    h_g, h_m, _ = design_of(plan, data) if design is None else design
    cov = data.chol @ np.swapaxes(data.chol, -1, -2)
    g_gg, g_gm, g_mm, b_g, b_m, yy = _blocks(plan, h_g, h_m, cov, y, data.camera)
    return replace(data, y=y.reshape(plan.n_units, -1), g_gg=g_gg, g_gm=g_gm, g_mm=g_mm, b_g=b_g, b_m=b_m, yy=yy)


def _design(plan: Plan, camera, sphere, t, walk_units, walk_dt, walk_slot, unit_slot, shared_chol=None, campaign=None):
    """``H`` per kind: global columns ``(K, U, C, G)`` and own-camera columns ``(K, U, C, B)``."""
    k_n, c_n = plan.n_kinds, plan.n_channels
    h_g = np.zeros((k_n, plan.n_units, c_n, plan.n_global))
    h_m = np.zeros((k_n, plan.n_units, c_n, plan.block))
    active = np.zeros((k_n, plan.n_cameras, plan.block))
    gs, ms = plan.g, plan.m
    for k in range(k_n):
        drifting = k < plan.n_drift
        for u in range(plan.n_units):
            m = camera[u]
            for c in range(c_n):
                h_g[k, u, c, gs.mu.start + c] = 1.0
                h_m[k, u, c, ms.a] = 1.0
                h_m[k, u, c, ms.b.start + c] = 1.0
                if drifting:
                    h_g[k, u, c, gs.rho] = t[u]
                    h_m[k, u, c, ms.r] = t[u]
                    for w in np.flatnonzero(camera[walk_units] == m):
                        if t[walk_units[w]] <= t[u]:
                            h_m[k, u, c, ms.walk.start + walk_slot[w]] = np.sqrt(walk_dt[w])
                    if plan.jitter:
                        h_m[k, u, c, ms.jitter.start + unit_slot[u]] = 1.0  # this campaign's own state
                if k == 0:
                    h_g[k, u, c, gs.sphere.start + sphere[u]] = 1.0
                    if plan.n_campaigns:  # common to that campaign's measurements (a fleet not on a straight line)
                        h_g[k, u, c, gs.campaign.start + campaign[u]] = 1.0
            if plan.shared:  # the camera's repeating error, correlated across channels as the units' are
                h_m[k, u, :, ms.shared] = shared_chol[k, m]
        active[k, :, ms.a] = 1.0
        active[k, :, ms.b] = 1.0
        if drifting:
            active[k, :, ms.r] = 1.0
            for j, walker in enumerate(walk_units):
                active[k, camera[walker], ms.walk.start + walk_slot[j]] = 1.0
            if plan.jitter:
                for u in range(plan.n_units):
                    active[k, camera[u], ms.jitter.start + unit_slot[u]] = 1.0
        if plan.shared:
            active[k, :, ms.shared] = 1.0
    return h_g, h_m, active


def block_scales(plan: Plan, hyper: dict, xp=np):
    """The scale of each camera slot per kind, ``(K, B)``, from the scales' values (columns in the
    order of :class:`CameraSlots`: ``a``, ``b``, ``r``, ``walk``, ``jitter``, ``shared``)."""
    k_n, c_n = plan.n_kinds, plan.n_channels
    pad = xp.zeros(k_n - 2) if plan.drift else None
    if plan.pooling == "partial":
        s_cam, s_ch = hyper["sigma_camera"], hyper["sigma_channel"]
        tau = xp.concatenate([hyper["rate_sd"], pad]) if plan.drift else xp.zeros(k_n)
    elif plan.pooling == "none":
        s_cam, s_ch = xp.zeros(k_n), xp.full(k_n, UNPOOLED_SD)
        tau = xp.full(k_n, 4.0 * plan.rate_prior)
    else:
        s_cam = s_ch = tau = xp.zeros(k_n)
    walk = xp.concatenate([hyper["walk_sd"], pad]) if plan.walk else xp.zeros(k_n)
    cols = [s_cam[:, None], xp.repeat(s_ch[:, None], c_n, axis=1), tau[:, None]]
    cols.append(xp.repeat(walk[:, None], max(plan.max_walk, 0), axis=1))
    if plan.jitter:
        jitter = xp.concatenate([hyper["jitter_sd"], pad])
        cols.append(xp.repeat(jitter[:, None], plan.max_units, axis=1))
    if plan.shared:  # unit sd: the excess dispersion scales it with the units' own errors (``_blocks``)
        cols.append(xp.ones((k_n, c_n)))
    return xp.concatenate(cols, axis=1)


def log_marginal(plan: Plan, hyper: dict, arrays: dict):
    """log p(y | scales) up to a constant: every linear latent integrated out, summed over kinds.

    The value and its gradient come from one factorisation (:func:`_integrated`); JAX
    carries the gradient from the slots' scales and the weighted Gram arrays back to the
    sampled scales.  ``log |T Sigma T| = log |Sigma| + sum_a n_a log kappa_a`` per kind
    (``n_a``: the units' values in direction ``a``).
    """
    import jax.numpy as jnp

    kappa = excess_of(plan, hyper, jnp)
    sc = block_scales(plan, hyper, jnp)[:, None, :] * arrays["active"]  # (K, M, B)
    value = _integrated()(sc, weighted(plan, arrays, kappa, jnp))
    return value - 0.5 * jnp.sum(arrays["n_rows"] * jnp.log(kappa))


@lru_cache(maxsize=1)
def _integrated():
    """``F(sc, a) = 1/2 b' P^-1 b - 1/2 log|P| - 1/2 y' Sigma^-1 y`` per kind, summed, with its
    gradient in closed form (``a``: the Gram arrays as :func:`.excess.weighted` combines them).

    Latents in the camera blocks are standardised (``x_m = S_m z_m``, ``z_m ~ N(0, I)``), so
    the posterior precision and the data vector are, per kind::

        P_mm = I + S G_mm S,   P_mg = S G_mg,   P_gg = G_gg + D,
        b_m = S b_m,   b_g = b_g.

    With ``mu = P^-1 b`` and ``V = P^-1`` (the posterior mean and covariance),
    ``dF = db' mu - 1/2 mu' dP mu - 1/2 tr(V dP)``.  For one slot ``j`` of camera ``m`` that is
    ``mu_mj (b_mj - (G_mm S mu_m)_j - (G_mg mu_g)_j) - (G_mm S V_mm)_jj - (G_mg V_gm)_jj``; for
    the arrays (``x_m = S mu_m``)::

        dF/db_m = x_m,  dF/db_g = mu_g,  dF/dyy = -1/2,
        dF/dG_mm = -1/2 (x_m x_m' + S V_mm S),  dF/dG_gm = -(mu_g x_m' + V_gm S),
        dF/dG_gg = -1/2 (mu_g mu_g' + V_gg),  dF/dv_g = 1/2 (mu_g^2 + diag V_gg) / v_g^2

    (``v_g`` the global prior variances, ``D = diag(1 / v_g)``).  ``V``'s blocks come from the
    same Cholesky factors (``V_mg = -P_mm^-1 P_mg V_gg``, ``V_mm = P_mm^-1 + P_mm^-1 P_mg V_gg
    P_gm P_mm^-1``, ``V_gg`` the inverse Schur complement), so a gradient costs matrix products
    instead of reverse-mode passes through the factorisations: about half the time on the CPU.
    """
    import jax
    import jax.numpy as jnp

    @jax.custom_vjp
    def integrated(sc, a):
        return integrated_value(sc, a)[0]

    def forward(sc, a):
        value, res = integrated_value(sc, a)
        return value, (sc, a, res)

    def backward(saved, ct):
        sc, a, (inv_l, y_g, inv_s, mu_g, mu_m) = saved
        g_mm = a["g_mm"]
        g_mg = jnp.swapaxes(a["g_gm"], -1, -2)
        inv_lt = jnp.swapaxes(inv_l, -1, -2)
        v_gg = jnp.swapaxes(inv_s, -1, -2) @ inv_s
        x_mg = inv_lt @ y_g  # P_mm^-1 P_mg
        v_mg = -x_mg @ v_gg[:, None]
        v_mm = inv_lt @ inv_l - v_mg @ jnp.swapaxes(x_mg, -1, -2)
        x_m = sc * mu_m
        d_mm = jnp.einsum("kmij,kmj,kmji->kmi", g_mm, sc, v_mm)  # (G_mm S V_mm)_jj
        d_mg = jnp.einsum("kmjg,kmjg->kmj", g_mg, v_mg)  # (G_mg V_gm)_jj
        resid = a["b_m"] - jnp.einsum("kmij,kmj->kmi", g_mm, x_m) - jnp.einsum("kmbg,kg->kmb", g_mg, mu_g)
        grad_sc = mu_m * resid - d_mm - d_mg
        s_v_mg = sc[..., :, None] * v_mg  # S V_mg
        grads = {
            "b_m": x_m,
            "b_g": mu_g,
            "yy": jnp.full_like(a["yy"], -0.5),
            "g_mm": -0.5 * (x_m[..., :, None] * x_m[..., None, :] + sc[..., :, None] * v_mm * sc[..., None, :]),
            "g_gm": -(mu_g[:, None, :, None] * x_m[:, :, None, :] + jnp.swapaxes(s_v_mg, -1, -2)),
            "g_gg": -0.5 * (mu_g[:, :, None] * mu_g[:, None, :] + v_gg),
            "prior_var_g": 0.5 * (mu_g**2 + jnp.diagonal(v_gg, axis1=-2, axis2=-1)) / a["prior_var_g"] ** 2,
        }
        return ct * grad_sc, {k: ct * grads[k] for k in a}

    integrated.defvjp(forward, backward)
    return integrated


def factor_blocks(sc, a, xp):
    """The one factorisation of the posterior precision that every path shares (the marginal
    likelihood and its gradient, the conditional draws, the leave-one-out densities).

    ``sc``: slot scales ``(..., K, M, B)``; ``a``: the weighted Gram arrays (:func:`.excess.weighted`),
    leading dims broadcast (draws).  With ``P_mm = I + S G_mm S = L_m L_m'``, returns ``L_m``,
    ``L_m^-1``, ``Y_g = L_m^-1 S G_mg``, ``y_b = L_m^-1 S b_m`` and the factor ``L_s`` of the Schur
    complement ``G_gg + D - Y_g' Y_g`` (summed over cameras).
    """
    g_mg = xp.swapaxes(a["g_gm"], -1, -2)  # (..., K, M, B, G)
    p_mm = sc[..., :, None] * a["g_mm"] * sc[..., None, :] + xp.eye(sc.shape[-1])
    l_m = xp.linalg.cholesky(p_mm)
    inv_l = inverse_lower(l_m, xp)
    y_g = inv_l @ (sc[..., :, None] * g_mg)  # L_m^-1 P_mg
    y_b = xp.einsum("...ij,...j->...i", inv_l, sc * a["b_m"])
    schur = a["g_gg"] + _diag(1.0 / a["prior_var_g"], xp) - xp.einsum("...mbg,...mbh->...gh", y_g, y_g)
    return l_m, inv_l, y_g, y_b, xp.linalg.cholesky(schur)


def inverse_lower(low, xp):
    """``L^-1`` of batched lower-triangular factors."""
    return solve_lower(low, xp.broadcast_to(xp.eye(low.shape[-1]), low.shape), xp)


def integrated_value(sc, a):
    """The value of :func:`_integrated` and the pieces its gradient reuses (JAX; reverse-mode
    differentiable too, which is the slower path the closed form replaces)."""
    import jax.numpy as jnp

    l_m, inv_l, y_g, y_b, l_s = factor_blocks(sc, a, jnp)
    inv_s = inverse_lower(l_s, jnp)
    v = jnp.einsum("kgh,kh->kg", inv_s, a["b_g"] - jnp.einsum("kmbg,kmb->kg", y_g, y_b))
    mu_g = jnp.einsum("khg,kh->kg", inv_s, v)
    mu_m = jnp.einsum("kmji,kmj->kmi", inv_l, y_b - jnp.einsum("kmbg,kg->kmb", y_g, mu_g))
    logdet = 2.0 * jnp.sum(jnp.log(jnp.diagonal(l_m, axis1=-2, axis2=-1))) + 2.0 * jnp.sum(
        jnp.log(jnp.diagonal(l_s, axis1=-2, axis2=-1))
    )
    value = 0.5 * (jnp.sum(y_b * y_b) + jnp.sum(v * v)) - 0.5 * logdet - 0.5 * jnp.sum(a["yy"])
    return value, (inv_l, y_g, inv_s, mu_g, mu_m)


def factorise(plan, sc, a, xp):
    """What the conditional draws and the leave-one-out densities read, from :func:`factor_blocks`.

    ``sc``: ``(..., K, M, B)``; ``a``: the weighted Gram arrays (:func:`.excess.weighted`), leading
    dims broadcast (draws).  Returns ``S b_m``, the factors of ``P_mm`` and of the Schur
    complement, the reduced global vector, ``P_gm`` and ``P_mm^-1 P_mg``.
    """
    l_m, inv_l, y_g, y_b, l_s = factor_blocks(sc, a, xp)
    x_mg = xp.swapaxes(inv_l, -1, -2) @ y_g  # P_mm^-1 P_mg, (..., K, M, B, G)
    b_g2 = a["b_g"] - xp.einsum("...mbg,...mb->...g", y_g, y_b)  # b_g - P_gm P_mm^-1 S b_m
    return sc * a["b_m"], l_m, l_s, b_g2, a["g_gm"] * sc[..., None, :], x_mg


def _diag(v, xp):
    return v[..., :, None] * xp.eye(v.shape[-1])


def solve_lower(low, b, xp, transpose: bool = False):
    """``L^-1 b`` (``L'^-1 b`` with ``transpose``) for batched lower factors and matrix ``b``."""
    if xp is np:
        return np.linalg.solve(np.swapaxes(low, -1, -2) if transpose else low, b)
    import jax.scipy.linalg as jsl

    return jsl.solve_triangular(low, b, lower=True, trans=1 if transpose else 0)


def solve_chol(low, b, xp=np):
    """``(L L')^-1 b`` for batched lower factors; ``b`` a vector or a matrix per factor."""
    vector = b.ndim == low.ndim - 1
    rhs = b[..., None] if vector else b
    out = solve_lower(low, solve_lower(low, rhs, xp), xp, transpose=True)
    return out[..., 0] if vector else out


def conditional_draws(plan: Plan, hyper: dict, arrays: dict, rng: np.random.Generator):
    """Draws of the linear latents given each draw of the scales (NumPy, batched over draws).

    ``hyper``: scale name -> ``(S, size)``.  Returns the global coefficients ``(S, K, G)``
    and the per-camera ones ``(S, K, M, B)`` (already multiplied by their scales).
    """
    sc, kappa = draw_scales(plan, hyper, arrays)
    z_g, z_m = standard_normals(plan, sc.shape[0], rng)
    return latent_draws(plan, sc, kappa, arrays, z_g, z_m)


def draw_scales(plan: Plan, hyper: dict, arrays: dict) -> tuple[np.ndarray, np.ndarray]:
    """Each draw's slot scales ``(S, K, M, B)`` and excess dispersion ``(S, K, D)``."""
    s = next(iter(hyper.values())).shape[0] if hyper else 1
    sc = np.stack([block_scales(plan, {k: v[i] for k, v in hyper.items()}) for i in range(s)])  # (S, K, B)
    sc = sc[:, :, None, :] * arrays["active"][None]  # (S, K, M, B)
    kappa = excess_of(plan, hyper, draws=s)
    return sc, kappa


def standard_normals(plan: Plan, s: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """The standard normal variates of ``s`` conditional draws: global ``(S, K, G)``, per camera ``(S, K, M, B)``."""
    z_g = rng.standard_normal((s, plan.n_kinds, plan.n_global))
    z_m = rng.standard_normal((s, plan.n_kinds, plan.n_cameras, plan.block))
    return z_g, z_m


def latent_draws(plan: Plan, sc, kappa, arrays: dict, z_g, z_m, xp=np):
    """The conditional draws of :func:`conditional_draws` from given standard normals, in the array
    module ``xp`` (numpy, or ``jax.numpy`` compiled: :func:`bayescal.fleet.sampling.sample_fleet`)."""
    a = weighted(plan, arrays, kappa, xp)
    bm_s, l_m, l_s, b_g2, p_gm, _ = factorise(plan, sc, a, xp)
    g = solve_chol(l_s, b_g2, xp) + solve_lower(l_s, z_g[..., None], xp, transpose=True)[..., 0]
    rhs = bm_s - xp.einsum("skmgb,skg->skmb", p_gm, g)
    cam = solve_chol(l_m, rhs, xp) + solve_lower(l_m, z_m[..., None], xp, transpose=True)[..., 0]
    return g, sc * cam
