"""Simulation-based calibration of the fleet hierarchy's stage two (Talts et al. 2018).

The units' reported values are drawn from the stage-two model's own prior, given a
fleet's structure and its units' covariances (as stage one measured them): the scales
from their half-normal priors, the fleet-wide and per-camera latents from theirs, and
each unit's values around its truth with its covariance scaled by ``kappa`` per
direction (``T Sigma T``, :mod:`.model`).  Refitting
each simulated fleet, the rank of every true value among its posterior draws is
uniform when the sampler, the integration of the latents and the conditional draws
are right.  This checks stage two as written; the Gaussian summary of stage one is
checked against the independent fleet simulator (``benchmarks/fleet_pooling.py``).  The ranks
and their tests are the single-camera SBC's (:mod:`bayescal.validation.sbc`).
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np
import pandas as pd

from bayescal.fleet.data import design_of, with_units
from bayescal.fleet.excess import excess_of, scale_directions
from bayescal.fleet.marginal import block_scales
from bayescal.fleet.plan import FleetData, Plan
from bayescal.fleet.sampling import sample_fleet, scale_priors
from bayescal.fleet.spec import FleetSpec
from bayescal.model.spec import InferenceSpec
from bayescal.validation.sbc import RankStatistics, rank_statistics

__all__ = ["FleetSBC", "prior_fleet", "run_fleet_sbc"]


def prior_fleet(plan: Plan, data: FleetData, rng: np.random.Generator, design=None) -> tuple[dict, np.ndarray]:
    """One fleet from the stage-two prior: the true values by name and the units' reports
    ``(U, K, C)`` (standardised, as :class:`~.model.FleetData` holds them).  ``design``:
    :func:`~.model.design_of` of ``data``, when the caller already has it."""
    priors = scale_priors(plan)
    hyper = {}
    for name, size in plan.sampled().items():
        v = np.abs(rng.normal(0.0, priors[name], size))
        hyper[name] = 1.0 + v if name == "excess" else v
    k_n = plan.n_kinds
    kappa = excess_of(plan, hyper)  # (K, D)
    sc = block_scales(plan, hyper)[:, None, :] * data.active  # (K, M, B)
    g = rng.standard_normal(data.prior_var_g.shape) * np.sqrt(data.prior_var_g)  # (K, G)
    x_m = sc * rng.standard_normal(sc.shape)
    h_g, h_m, _ = design_of(plan, data) if design is None else design
    own = np.ones(plan.block, bool)
    own[plan.m.shared] = False  # the camera's shared error is part of the units' error
    per_unit = x_m[:, data.camera, :]
    theta = np.einsum("kucg,kg->kuc", h_g, g) + np.einsum("kucb,kub->kuc", h_m * own, per_unit)
    shared = np.einsum("kucb,kub->ukc", h_m * ~own, per_unit)
    z = rng.standard_normal((plan.n_units, k_n * plan.n_channels))
    noise = np.einsum("uqr,ur->uq", data.chol, z).reshape(plan.n_units, k_n, plan.n_channels)
    y = np.transpose(theta, (1, 0, 2)) + scale_directions(plan, noise + shared, kappa)  # T (L e + Sigma^1/2 z)
    truth = {name: np.atleast_1d(v) for name, v in hyper.items()}
    gs, ms = plan.g, plan.m
    truth["mu"] = g[:, gs.mu]
    truth["camera_level"] = g[:, gs.mu] + x_m[:, 0, ms.a, None] + x_m[:, 0, ms.b]  # the first camera's, (K, C)
    return truth, y


@dataclass(frozen=True, kw_only=True)
class FleetSBC(RankStatistics):
    """Ranks of the true values among the posterior draws and the 95 % interval coverage
    (:class:`~bayescal.validation.sbc.RankStatistics`), with each refit's sampler ``diagnostics``."""

    diagnostics: pd.DataFrame

    def plot(self, path: str | os.PathLike | None = None, title: str = ""):
        title = (
            title or f"Fleet stage two: SBC rank histograms ({self.n_sims} fleets; grey: 99 % band of uniform ranks)"
        )
        return super().plot(path, title)


def run_fleet_sbc(
    plan: Plan,
    data: FleetData,
    spec: FleetSpec,
    n_sims: int,
    seed: int = 0,
    thin: int = 4,
    progress=None,
    inference: InferenceSpec | None = None,
    bins: int = 10,
) -> FleetSBC:
    """Simulate ``n_sims`` fleets from the prior (:func:`prior_fleet`), refit each with
    :func:`~bayescal.fleet.sampling.sample_fleet`, and rank the truths among as many evenly spaced
    draws as every ``thin``-th one makes (:func:`~bayescal.validation.sbc.rank_statistics`; a camera's
    level: the first camera's); ``bins``: of the uniformity test.

    ``inference``: the fit's policy as a user's fit runs it (chains continued while the scales'
    ESS or R-hat miss its bounds, new chains at its ``retry_target_accept`` after a divergent
    transition); without it every fleet gets one run of ``spec.chains x spec.draws``.  Each
    fleet's ranks are taken among its first ``spec.draws`` draws per chain, so that continued
    chains do not change the rank scale.
    """
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0x5BC]))
    n_draws = spec.chains * len(range(0, spec.draws, thin))
    ranks, covered, diags = [], [], []
    design = design_of(plan, data)  # the structure is the same for every simulated fleet
    for i in range(n_sims):
        truth, y = prior_fleet(plan, data, rng, design)
        draws = sample_fleet(with_units(plan, data, y, design), plan, spec, seed=seed + i, inference=inference)
        posterior = {}
        for name in truth:
            post = draws.draws[name][:, : spec.draws]  # (chain, draw, ...): continued chains keep the rank scale
            posterior[name] = (post[:, :, :, 0] if name == "camera_level" else post)[None]
        r, c = rank_statistics(posterior, {k: np.asarray(v)[None] for k, v in truth.items()}, n_draws)
        ranks.append(r)
        covered.append(c)
        diags.append(draws.diagnostics)
        if progress is not None:
            progress(i + 1)
    return FleetSBC(
        ranks=pd.concat(ranks, ignore_index=True),
        covered=pd.concat(covered, ignore_index=True),
        n_draws=n_draws,
        bins=bins,
        diagnostics=pd.DataFrame(diags),
    )
