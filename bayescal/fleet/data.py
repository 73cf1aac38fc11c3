"""The fleet's data for stage two: the stage-one summaries standardised, the design ``H`` of every
unit, and the Gram arrays of the marginal likelihood (:mod:`.plan` says the model).

:func:`fleet_data` builds them once per fleet; :func:`with_units` swaps the values for others of the
same structure (what simulation-based calibration refits).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from bayescal.fleet.excess import direction_sizes, kind_blocks, projections
from bayescal.fleet.plan import ABSENT_VAR, FleetData, Plan
from bayescal.fleet.spec import FleetSpec
from bayescal.fleet.stage1 import UnitFits
from bayescal.fleet.units import to_years

__all__ = ["design_of", "fleet_data", "pieces", "with_units"]


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
