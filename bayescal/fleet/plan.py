"""Stage two of the fleet model, its plan: the hierarchy over channels, cameras and campaigns.

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

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

__all__ = ["ABSENT_VAR", "UNPOOLED_SD", "CameraSlots", "FleetData", "GlobalSlots", "Plan"]

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
