"""Does a designed campaign deliver what its design predicted?  Simulate it many times, fit each, and
compare the posterior widths achieved with the widths :func:`bayescal.campaign.design.design` expected,
and the intervals with the truth (docs/guides/design.md, "Checked by simulation").

Each campaign is simulated by :func:`bayescal.simulate` from the protocol's ``[truth]`` camera (fresh
sphere errors and noise per campaign), with one extra row per channel at each prediction target's group
that the fit predicts but does not see (the leave-out mechanism of the holdout check), and fitted by
the Laplace backend (its draws, with the excess scatter's scale integrated, as ``bayescal fit --backend
laplace`` reports them).  The truth of each target comes from the same campaign simulated without noise.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pandas as pd

from bayescal._config import computes
from bayescal.campaign.design import CampaignDesign
from bayescal.campaign.grid import Group
from bayescal.campaign.information import Targets
from bayescal.errors import SpecError
from bayescal.inference.laplace import laplace
from bayescal.inference.program import program_for
from bayescal.inference.samplers import laplace_z
from bayescal.inference.start import initial_point
from bayescal.model.assemble import build_model
from bayescal.model.simulate import simulate
from bayescal.model.spec import ModelSpec, load_spec

__all__ = ["DesignCheck", "check_design"]


@dataclass(frozen=True)
class DesignCheck:
    """Widths and coverage achieved by a design over simulated campaigns.

    Attributes
    ----------
    widths : DataFrame
        Per target: ``predicted_sd``, ``achieved_sd`` (the posterior sd averaged over campaigns),
        ``ratio`` (predicted over achieved) and ``coverage`` (share of 95 % intervals holding the truth).
    coverage : float
        The 95 % intervals' coverage pooled over targets and campaigns.
    campaigns : int
        Campaigns fitted (those whose mode search converged).
    failed : int
        Campaigns whose mode search did not converge (left out).
    """

    widths: pd.DataFrame
    coverage: float
    campaigns: int
    failed: int

    @property
    def worst_ratio(self) -> float:
        """The largest relative error of a predicted width, ``max |predicted / achieved - 1|``."""
        return float(np.max(np.abs(self.widths["ratio"] - 1.0)))


@computes
def check_design(
    plan: CampaignDesign,
    counts: np.ndarray | None = None,
    predicted: np.ndarray | None = None,
    *,
    spec: ModelSpec | None = None,
    campaigns: int = 50,
    seed: int = 0,
    progress: Callable[[int], None] | None = None,
) -> DesignCheck:
    """Simulate and fit ``campaigns`` campaigns of a design and compare them with its prediction.

    Parameters
    ----------
    plan : CampaignDesign
        The design (:func:`bayescal.campaign.design.design`) and its targets.
    counts, predicted : array, optional
        Another choice of the plan's grid groups to check, with its predicted sds (default: the plan's
        own; ``plan.grid.counts(protocol)`` and ``plan.widths["protocol_sd"]`` check the protocol).
    spec : ModelSpec, optional
        The model (default: the protocol's).
    campaigns : int
        How many campaigns to simulate and fit.
    seed : int
        Campaign ``i`` is simulated and fitted with seed ``seed + i``.
    progress : callable, optional
        ``progress(campaigns_done)``.
    """
    grid = plan.grid
    protocol = grid.protocol
    if protocol.truth is None:
        raise SpecError("checking a design needs the protocol's [truth] camera")
    if spec is None:
        if protocol.spec is None:
            raise SpecError("the protocol names no spec; pass spec=")
        spec = load_spec(protocol.spec)
    counts = np.asarray(plan.counts if counts is None else counts, dtype=int)
    predicted = np.asarray(plan.widths["design_sd"] if predicted is None else predicted, dtype=float)
    names = list(plan.widths["target"])
    ref = spec.reference
    reference_dark = grid.index(Group(ref.exposure_s, ref.gain, ref.tdi_stages, None, -1))
    extra = np.zeros(len(grid), dtype=int)
    for _, k in plan.predictions:
        extra[k] = 1
    extra[reference_dark] = 1
    campaign = grid.design(counts + extra)
    noiseless = dataclasses.replace(campaign, n_frames=10**6, n_pixels=10**6)
    quiet_truth = dataclasses.replace(protocol.truth, excess_dn=0.0)
    sds, hits = [], []
    failed = 0
    for i in range(campaigns):
        s = seed + i
        sim = simulate(spec, campaign, seed=s)
        frame = sim.table.frame
        truth_frame = simulate(spec, noiseless, truth=quiet_truth, seed=s).table.frame
        groups = grid.rows_of(frame)
        replicate = frame["replicate"].to_numpy(dtype=int) if "replicate" in frame else np.zeros(len(frame), int)
        held = (groups >= 0) & (extra[np.maximum(groups, 0)] > 0) & (replicate == counts[np.maximum(groups, 0)])
        model = build_model(sim.table, spec)
        program = program_for(model)
        data = model.data._replace(keep=~held)
        result = laplace(program, data, initial_point(model, program))
        if not result.converged:
            failed += 1
            continue
        channel = frame["channel"].to_numpy()
        rows = [int(np.flatnonzero(held & (groups == k) & (channel == c))[0]) for c, k in plan.predictions]
        targets = Targets(coefficients=True, rows=tuple(rows))
        fitted = dataclasses.replace(model, data=data)
        sites = program.constrain(laplace_z(fitted, program, result, s, {})[0], data)
        values = targets.values(model, {k: np.asarray(v) for k, v in sites.items()}, seed=s)
        truth = np.concatenate(
            [_true_coefficients(sim, spec, model.layout.channels, truth_frame, held & (groups == reference_dark))]
            + [truth_frame["dn_mean"].to_numpy()[rows]]
        )
        lo, hi = np.percentile(values, [2.5, 97.5], axis=0)
        sds.append(values.std(axis=0, ddof=1))
        hits.append((lo <= truth) & (truth <= hi))
        if progress is not None:
            progress(i + 1)
    if not sds:
        raise SpecError(f"none of the {campaigns} simulated campaigns could be fitted")
    achieved = np.mean(sds, axis=0)
    coverage = np.mean(hits, axis=0)
    widths = pd.DataFrame(
        {
            "target": names,
            "predicted_sd": predicted,
            "achieved_sd": achieved,
            "ratio": predicted / achieved,
            "coverage": coverage,
        }
    )
    return DesignCheck(widths, float(np.mean(hits)), len(sds), failed)


def _true_coefficients(sim, spec: ModelSpec, channels, truth_frame: pd.DataFrame, dark_rows: np.ndarray) -> np.ndarray:
    """The true ``A0..Ap`` of each channel relative to the sphere, in the order of the targets: ``A0`` the
    noiseless dark reading at the reference setting, ``A1..`` the truth's monomials at the sphere's scale."""
    out = []
    channel = truth_frame["channel"].to_numpy()
    for c in channels:
        a0 = float(truth_frame["dn_mean"].to_numpy()[dark_rows & (channel == c)][0])
        coef = np.zeros(spec.response.order)
        given = sim.true_coefficients(c, relative=True)
        coef[: given.size] = given
        out.append(np.concatenate([[a0], coef]))
    return np.concatenate(out)
