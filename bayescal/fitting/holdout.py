"""Leave-one-setting-out predictive check: do the other rows predict each setting's rows?

The per-row checks of :mod:`bayescal.fitting.misfit` look at residuals from a fit to
*all* rows, where a flexible model can share a discrepancy out among its
parameters (a dark level that drifted between the bright and the dark
measurements is split between the offsets and the excess scatter, and no
residual stands out).  Here each group of rows measured at one setting is
left out of the likelihood in turn, the model is refitted to the rest
(posterior mode and Laplace covariance, warm-started from the full fit's mode
on the already compiled program: the held-out rows are masked, the array
shapes do not change), and the group's mean reading is compared with its
posterior predictive distribution:

``z = (mean(y_group) - E[mean(mu_group)]) / sqrt(Var[mean(mu_group)] + mean(sd_group^2) / n)``

with ``mu`` the predicted row means and ``sd`` their noise (excess scatter
included) per draw.  Groups: the illuminated rows of each gain step, exposure
and TDI setting (where a kind has more than one), and the dark rows of each
gain step with illuminated rows (their level is then also predicted by the
illuminated rows' intercept), unless a dark drift is modelled: the darks of
one gain, left out, are then predicted through the drift, which the other
gains' bright-against-dark intercepts pin down, so any response misfit at
those gains turns into a confident false alarm (measured on the bench: z ~ -8
on clean data with a drift modelled, |z| < 2 without).  A group whose ``|z|`` exceeds the spec's
``misfit_group_z`` is reported as a problem naming it.

A left-out setting's factor (:mod:`bayescal.model.components.settings`) falls back
to its prior, so a gain step is flagged here only when it sits further from
its label than its tolerance allows; that is the check's intent.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from bayescal._parallel import parallel_map
from bayescal.inference.laplace import laplace, laplace_draws

__all__ = ["holdout_groups", "holdout_checks"]

#: draws of the refitted posterior per group (the z statistic's sd is then estimated to ~5 %; moving
#: 4000 draws of every row's prediction off the device cost 0.9 s per fit of the seed-000 model)
N_DRAWS = 200

_REMEDY = {
    "dark": (
        "the dark rows disagree with the offset the illuminated rows extrapolate to: a dark level that drifted "
        "between the dark and the bright measurements (add a time_s column, dark.drift), stray light, or a "
        "response that is not polynomial near zero"
    ),
    "gain": "this gain step is further from its label than settings.gain_tolerance allows",
    "exposure_s": "this exposure is further from its nominal value than settings.exposure_tolerance allows",
    "tdi_stages": "this TDI setting is further from its stage count than settings.tdi_tolerance allows",
}


def holdout_groups(frame, lit: np.ndarray, darks: bool = True) -> list[tuple[str, str, np.ndarray]]:
    """``(kind, description, row mask)`` of each group the check leaves out in turn (``darks``: include
    the dark rows of each gain)."""
    groups = []
    for column, label in (("gain", "gain {v:g}"), ("exposure_s", "exposure {v:g} s"), ("tdi_stages", "TDI {v:g}")):
        values = frame[column].to_numpy()
        distinct = pd.unique(values[lit])
        if len(distinct) < 2:
            continue
        for v in distinct:
            groups.append((column, f"the illuminated {label.format(v=v)} rows", lit & (values == v)))
    gains = frame["gain"].to_numpy()
    for g in pd.unique(gains[~lit]) if darks else []:
        mask = ~lit & (gains == g)
        if np.any(lit & (gains == g)):
            groups.append(("dark", f"the dark rows at gain {g:g}", mask))
    return groups


def holdout_checks(
    model, program, mode: np.ndarray, z_threshold: float, seed: int = 0, n_draws: int = N_DRAWS
) -> tuple[list[str], dict]:
    """Run the check on a fitted model; returns the problems and, per group, the numbers behind them.

    Parameters
    ----------
    model : CalibrationModel
        The fitted model (its ``data.keep`` all true).
    program : Program
        Its compiled program.
    mode : ndarray
        Unconstrained posterior mode of the full fit (the refits start there).
    z_threshold : float
        ``|z|`` above which a group is reported.
    seed : int
        Seed of the refits' Laplace draws.
    n_draws : int
        Draws per refit.
    """
    data, frame, scale = model.data, model.table.frame, model.layout.dn_scale
    censored = np.asarray(data.censored)
    lit = frame["stimulus"].to_numpy() > 0
    y = np.asarray(data.y)
    problems: list[str] = []
    groups = [
        (position, kind, name, mask, np.flatnonzero(mask & ~censored))
        for position, (kind, name, mask) in enumerate(holdout_groups(frame, lit, darks=not model.spec.dark.drift))
    ]
    groups = [(position, kind, name, mask, idx) for position, kind, name, mask, idx in groups if idx.size]

    def refit(group):
        _, _, _, mask, _ = group
        return laplace(program, data._replace(keep=np.asarray(data.keep) & ~mask), mode, polish=False)

    results = parallel_map(refit, groups)  # independent refits, one per core
    refits, failed = [], {}  # each group refitted: (kind, name, rows, draws); failed groups by position
    for (position, kind, name, _, idx), result in zip(groups, results, strict=True):
        if not (result.positive_definite and result.converged):
            failed[position] = {"kind": kind, "group": name, "n": int(idx.size), "z": float("nan"), "refit": "failed"}
        else:
            refits.append((position, kind, name, idx, laplace_draws(result, n_draws, seed)))
    # the predictions do not depend on which rows were kept: every group's draws in one call
    every = program.constrain(np.concatenate([r[-1] for r in refits]), data) if refits else {}
    found = dict(failed)
    for k, (position, kind, name, idx, _) in enumerate(refits):
        draws = slice(k * n_draws, (k + 1) * n_draws)
        mu = np.asarray(every["row_mean"])[draws, idx]
        sd = np.asarray(every["row_sd"])[draws, idx]
        avg = mu.mean(axis=1)
        var = float(np.var(avg) + np.mean(sd**2) / idx.size)
        dev = float(y[idx].mean() - avg.mean())
        z = dev / np.sqrt(var)
        signal = float(np.asarray(every["row_signal"])[draws, idx].mean())
        rec = {"kind": kind, "group": name, "n": int(idx.size), "z": float(z), "dev_dn": dev * scale}
        if kind != "dark" and signal > 0:
            rec["rel_dev"] = dev / signal
        found[position] = rec
        if abs(z) > z_threshold:
            side = "above" if dev > 0 else "below"
            size = f"{abs(rec['rel_dev']):.2%}" if "rel_dev" in rec else f"{abs(rec['dev_dn']):.3g} DN"
            problems.append(
                f"left out of the fit, {name} read {size} {side} what the other rows predict "
                f"(n = {idx.size}, z = {z:+.1f}): {_REMEDY[kind]}"
            )
    rows = [found[p] for p in sorted(found)]  # in the groups' order
    return problems, {"groups": rows}
