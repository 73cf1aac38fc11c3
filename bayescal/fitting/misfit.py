"""Does the model fit its data?  Posterior predictive checks that say what is wrong and where.

A model that cannot describe its data has two ways to hide it: an inflated
excess-scatter term (every residual then looks small) and residuals that are
each unremarkable but share a sign or a trend across a group of rows.  So a
fit is checked for

- **excess scatter against the noise floor**: the fitted extra scatter of a
  region mean, compared with the noise that averaging ``n_frames x n_pixels``
  readings leaves (read, shot and quantisation noise, or the measured
  ``dn_var``).  Lamp drift or a slightly wrong noise model give a few times
  the floor; a setting whose gain is 5 % off gives 100 times;
- **residual structure by group**: rows of one gain step, exposure, TDI
  setting, channel or sphere level whose standardised residuals share a sign
  (their sum over ``sqrt(n)`` is ~Normal(0, 1) under the model), reported
  with the group's relative deviation from the model;
- **runs along the signal**: within a channel, residuals sorted by signal
  that change sign too rarely (Wald-Wolfowitz runs test): the response shape
  is not what the model can draw (e.g. a roll-off near full scale);
- **runs along the measurement order** (``time_s``, else the row order):
  a dark level or responsivity that drifted during the run;
- **the channels of one frame together**: residuals of one frame's rows that share a sign more than
  chance allows (:func:`frame_correlation`): an offset common to the frame (a jittering black level).

When a check fires, the groups one channel makes with one setting (its gain,
exposure, TDI or sphere level rows) say where the misfit sits, if one of them
stands out from the channel's and the setting's rows as a whole: a departure
at one setting in one channel, which no term draws and the marginal groups
dilute (a channel's readings 3 % high at one exposure: z = +6.4 there, +1.1
for the exposure's rows, +0.3 for the channel's).  They never fail a fit on
their own: there are many of them, and they add a place, not a finding.

Each check that fires adds a problem naming the rows and a remedy; the fit is
then reported failed (exit 3, the report's banner).  The numbers behind the
checks are kept in the diagnostics (``misfit``) and drawn in the report.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from bayescal.model.components.frame_offset import frame_index

__all__ = ["MisfitThresholds", "misfit_checks", "group_residuals", "crossed_residuals", "frame_correlation"]


@dataclass(frozen=True)
class MisfitThresholds:
    """When a check fires.

    ``excess_ratio``: fitted excess scatter / median noise floor of a row mean
    (0 turns the check off).  ``group_z``: |sum of standardised residuals| /
    sqrt(n) of a group (4: a false alarm ~6e-5 per group, < 0.3 % over the ~40
    groups of a typical table).  ``runs_z``: the runs statistic along the
    signal within a channel (one-sided, too few runs).
    """

    excess_ratio: float = 10.0
    group_z: float = 4.0
    runs_z: float = -4.0


#: table column -> how a group of it is named in messages
_GROUPS = {
    "gain": "gain {v:g} rows",
    "exposure_s": "exposure {v:g} s rows",
    "tdi_stages": "TDI {v:g} rows",
    "channel": "channel {v} rows",
    "level": "sphere level {v} rows",
}
_REMEDY = {
    "gain": "the effective gain of that step differs from its label (settings.gain_tolerance)",
    "exposure_s": "the effective exposure differs from the nominal one: a shutter offset (settings.exposure_tolerance)",
    "tdi_stages": "the effective TDI factor differs from the stage count (settings.tdi_tolerance)",
    "channel": "this channel's response or offset is not what the model can draw",
    "level": "this sphere level's radiance reading is off beyond sphere.per_level_rel",
}


def group_residuals(frame: pd.DataFrame, resid_z: np.ndarray, rel_dev: np.ndarray, lit: np.ndarray) -> pd.DataFrame:
    """Per group of rows: count, summed standardised residual / sqrt(n), and median relative deviation."""
    rows = []
    for column in _GROUPS:
        if column not in frame:
            continue
        values = frame[column].to_numpy()
        for v in pd.unique(values[lit]):
            m = lit & (values == v)
            n = int(m.sum())
            if n < 2:
                continue
            rows.append(
                {
                    "column": column,
                    "value": v,
                    "n": n,
                    "z": float(resid_z[m].sum() / np.sqrt(n)),
                    "rel_dev": float(np.median(rel_dev[m])),
                }
            )
    return pd.DataFrame(rows, columns=["column", "value", "n", "z", "rel_dev"])


#: the settings whose groups are also read within each channel (:func:`crossed_residuals`)
_CROSSED = ("gain", "exposure_s", "tdi_stages", "level")
#: a crossed group is named when its |z| exceeds the threshold and this many times its marginal groups' |z|
_CROSSED_OVER_MARGINS = 1.5


def crossed_residuals(frame: pd.DataFrame, resid_z: np.ndarray, rel_dev: np.ndarray, lit: np.ndarray) -> pd.DataFrame:
    """:func:`group_residuals` of the groups one channel makes with one setting (``channel`` x ``gain``,
    ``exposure_s``, ``tdi_stages`` or ``level``), each with its rows' name (``name``): where a departure
    sits that touches one channel at one setting, which the marginal groups dilute."""
    columns = ["name", "channel", "column", "value", "n", "z", "rel_dev"]
    if "channel" not in frame:
        return pd.DataFrame(columns=columns)
    channel = frame["channel"].astype(str).to_numpy()
    parts = []
    for ch in pd.unique(channel[lit]):
        m = channel == ch
        sub = frame.loc[m, [c for c in _CROSSED if c in frame]]
        one = group_residuals(sub, resid_z[m], rel_dev[m], lit[m])
        one.insert(0, "channel", ch)
        names = [_GROUPS[c].format(v=v) for c, v in zip(one["column"], one["value"], strict=True)]
        one.insert(0, "name", [f"channel {ch}, {name}" for name in names])
        parts.append(one)
    return pd.concat(parts, ignore_index=True)[columns] if parts else pd.DataFrame(columns=columns)


def _located(crossed: pd.DataFrame, groups: pd.DataFrame, threshold: float) -> list[str]:
    """Where a misfit sits, when a fit fails: the crossed groups (one channel at one setting) whose |z| exceeds
    ``threshold`` and :data:`_CROSSED_OVER_MARGINS` times that of the channel's and the setting's own groups."""
    margin = {(r.column, str(r.value)): abs(r.z) for r in groups.itertuples()}
    out: list[str] = []
    for r in crossed.sort_values("z", key=np.abs, ascending=False).itertuples():
        if abs(r.z) <= threshold or len(out) == 2:
            break
        marginal = max(margin.get(("channel", str(r.channel)), 0.0), margin.get((r.column, str(r.value)), 0.0))
        if abs(r.z) > _CROSSED_OVER_MARGINS * marginal:
            side = "above" if r.z > 0 else "below"
            out.append(
                f"where it sits: {r.name} read {abs(r.rel_dev):.2%} {side} the model (n = {r.n}, z = {r.z:+.1f}), "
                "more than the channel's or the setting's rows as a whole: something at that setting differs in "
                "that channel alone, which no term of the model draws"
            )
    return out


def frame_correlation(frame: pd.DataFrame, resid_z: np.ndarray, usable: np.ndarray) -> float:
    """Do the residuals of the rows of one frame (its channels, :func:`~bayescal.model.components.frame_offset.
    frame_index`) move together?  ``sum_f sum_{i<j} z_i z_j / sqrt(sum_f n_f (n_f - 1) / 2)`` over the
    frames' usable rows: under the model (independent standardised residuals) about Normal(0, 1); an offset
    shared by a frame's channels makes it large and positive."""
    idx = frame_index(frame)[usable]
    zu = resid_z[usable]
    n = np.bincount(idx)
    total = np.bincount(idx, weights=zu)
    squares = np.bincount(idx, weights=zu * zu)
    pairs = float(np.sum(n * (n - 1) / 2.0))
    if pairs < 8:
        return 0.0
    return float(np.sum((total**2 - squares) / 2.0) / np.sqrt(pairs))


def runs_z(resid: np.ndarray) -> float:
    """Wald-Wolfowitz runs statistic of the residual signs (negative: fewer runs than chance)."""
    signs = resid > 0
    n1, n2 = int(signs.sum()), int((~signs).sum())
    n = n1 + n2
    if n1 == 0 or n2 == 0:
        return -np.inf if n >= 8 else 0.0
    runs = 1 + int(np.count_nonzero(signs[1:] != signs[:-1]))
    mean = 2.0 * n1 * n2 / n + 1.0
    var = 2.0 * n1 * n2 * (2.0 * n1 * n2 - n) / (n**2 * (n - 1))
    return float((runs - mean) / np.sqrt(var)) if var > 0 else 0.0


def misfit_checks(
    frame: pd.DataFrame,
    y_dn: np.ndarray,
    mean_dn: np.ndarray,
    sd_dn: np.ndarray,
    signal_dn: np.ndarray,
    floor_dn: np.ndarray,
    excess_dn: np.ndarray | None,
    censored: np.ndarray,
    thresholds: MisfitThresholds = MisfitThresholds(),  # noqa: B008 - frozen
    terms_on: frozenset[str] = frozenset(),
) -> tuple[list[str], dict]:
    """Run the checks on one fit's posterior predictive summaries (all in DN, one value per row).

    ``terms_on``: the drift terms the model has (``"dark.drift"``, ``"offset_drift"``,
    ``"stimulus_drift"``): a remedy never suggests one of them.  Returns the problems found (empty: the
    model fits its data) and the numbers behind them.
    """
    problems: list[str] = []
    lit = (frame["stimulus"].to_numpy() > 0) & ~censored
    usable = ~censored
    resid = y_dn - mean_dn
    z = np.where(usable, resid / sd_dn, 0.0)
    info: dict = {}
    floor = float(np.median(floor_dn[usable])) if usable.any() else float("nan")
    info["noise_floor_dn"] = floor
    if excess_dn is not None and thresholds.excess_ratio > 0:
        excess = float(np.median(excess_dn))
        ratio = excess / floor if floor > 0 else np.inf
        info.update(excess_dn=excess, excess_ratio=ratio)
        if ratio > thresholds.excess_ratio:
            problems.append(
                f"the fitted excess scatter is {excess:.3g} DN, {ratio:.0f}x the noise floor of a row mean "
                f"({floor:.3g} DN from n_frames x n_pixels): the model does not describe the data to within their "
                "noise and has inflated its scatter instead"
            )
    rel = np.where(lit & (np.abs(signal_dn) > 1e-9), resid / np.where(np.abs(signal_dn) > 1e-9, signal_dn, 1.0), 0.0)
    groups = group_residuals(frame, z, rel, lit)
    info["groups"] = groups.to_dict("records")
    flagged = groups[np.abs(groups["z"]) > thresholds.group_z].sort_values("z", key=np.abs, ascending=False)
    for r in flagged.head(4).itertuples():
        name = _GROUPS[r.column].format(v=r.value)
        side = "above" if r.z > 0 else "below"
        problems.append(
            f"{name} sit {abs(r.rel_dev):.2%} {side} the model (n = {r.n}, z = {r.z:+.1f}): {_REMEDY[r.column]}"
        )
    runs = {}
    if "channel" in frame:
        for ch in pd.unique(frame["channel"].to_numpy()[lit]):
            m = lit & (frame["channel"].to_numpy() == ch)
            order = np.argsort(signal_dn[m], kind="stable")
            runs[str(ch)] = runs_z(z[m][order])
            if runs[str(ch)] < thresholds.runs_z:
                problems.append(
                    f"channel {ch}: residuals change sign too rarely along the signal (runs z = {runs[str(ch)]:+.1f}): "
                    "the response shape is not one the model can draw (a roll-off near full scale? a higher order?)"
                )
    info["runs_z"] = runs
    info.update(_drift_check(frame, z, usable, thresholds, problems, resid, signal_dn, terms_on))
    info["frame_z"] = frame_correlation(frame, z, usable)
    if info["frame_z"] > thresholds.group_z:
        problems.append(
            f"the residuals of the channels of one frame move together (z = {info['frame_z']:+.1f} over "
            f"{int(np.sum(np.bincount(frame_index(frame)) >= 2))} frames): an offset common to the frame, not scatter "
            "of each row"
            + (
                "; fit a black level that jitters from frame to frame ([frame_offset] enabled = true)"
                if "frame_offset" not in terms_on
                else ""
            )
        )
    crossed = crossed_residuals(frame, z, rel, lit)
    info["crossed_groups"] = crossed.drop(columns="name").to_dict("records")
    if problems:  # a fit that fails anyway: say where its misfit sits (never a reason to fail on its own)
        problems += _located(crossed, groups, thresholds.group_z)
    return problems, info


#: what each place of a drift is called, the term that models it, and the spec change that switches it on
_DRIFT_PLACES = {
    "offset": ("added to every reading (a black level or dark signal that moved)", "offset_drift"),
    "stimulus": (
        "on the stimulus, the same fraction in every channel (a lamp or sphere that drifted)",
        "stimulus_drift",
    ),
}


def _drift_check(
    frame: pd.DataFrame,
    z: np.ndarray,
    usable: np.ndarray,
    thresholds: MisfitThresholds,
    problems,
    resid: np.ndarray | None = None,
    signal: np.ndarray | None = None,
    terms_on: frozenset[str] = frozenset(),
):
    """Runs of the residual signs along the measurement order: a camera or bench that drifted during the run.

    The order is ``time_s`` where the table has it, else the row order (the order most labs write rows
    in).  Under the model the residuals are independent of either order, so the check's false-alarm rate
    is that of the runs test whatever the order.  When it fires, the residuals are split by place: the dark
    rows' in DN (an offset that moved) and the lit rows' relative to their signal (a stimulus that moved),
    each against a smooth curve over the session; the message names the covariate, the place that explains
    more and the size of the drift there, the terms that would model it that are not on yet, and the
    measurement that tells the places apart.
    """
    by_time = "time_s" in frame
    key = frame["time_s"].to_numpy(dtype=float) if by_time else np.arange(len(frame), dtype=float)
    dark = frame["stimulus"].to_numpy() == 0
    zr_by = {}
    for name, rows in (("all", usable), ("dark", usable & dark), ("lit", usable & ~dark)):
        idx = np.flatnonzero(rows)
        order = idx[np.argsort(key[idx], kind="stable")]
        zr_by[name] = runs_z(z[order]) if order.size >= 8 else 0.0
    zr = min(zr_by.values())  # a drift in one place only is diluted among the other place's rows
    info: dict = {"order_runs_z": zr, "order_runs_z_by": zr_by, "order_by": "time_s" if by_time else "row"}
    if zr >= thresholds.runs_z:
        return info
    where = "time_s" if by_time else "the row order (no time_s column)"
    places = _drift_places(frame, key, z, usable, resid, signal) if resid is not None and signal is not None else {}
    info["drift_places"] = places
    problem = (
        f"residuals change sign too rarely along the measurement order, {where} (runs z = {zr:+.1f}): the camera "
        "or the bench drifted during the run"
    )
    if places:
        best = max(places, key=lambda k: places[k]["chi2_drop"])
        text, term = _DRIFT_PLACES[best]
        size = places[best]["size"]
        size_text = f"{size:.2g} DN" if best == "offset" else f"{size:.2%}"
        problem += f"; it is mostly {text}, a drift of about {size_text} over the session"
        remedies = []
        if term not in terms_on:
            over = "time_s" if by_time else "order"
            remedies.append(f'[{term}] enabled = true, over = "{over}"')
        if best == "offset" and "dark.drift" not in terms_on:
            remedies.append("dark.drift = true" if by_time else 'dark.drift = "order"')
        if remedies:
            problem += "; fit it with " + " or ".join(remedies)
        else:
            problem += "; the terms the library has for it are on and do not describe it"
    elif "dark.drift" not in terms_on:
        problem += "; fit a dark-level drift (dark.drift)"
    if not by_time:
        problem += "; record when each frame was taken (a time_s column)"
    problem += (
        "; to tell a moving offset from a moving lamp, repeat one sphere level and one dark frame at the start, "
        "the middle and the end of the session"
    )
    problems.append(problem)
    return info


def _drift_places(frame, key, z, usable, resid, signal) -> dict:
    """For each place of a drift (the dark rows' residuals in DN, the lit rows' relative to their signal):
    the drop in chi-square when a smooth curve over the session (three cosine terms) is fitted to the
    standardised residuals there, and the size of that curve (its range: DN, or a fraction)."""
    span = max(float(np.ptp(key[usable])), 1e-300) if usable.any() else 1.0
    tau = (key - key[usable].min()) / span if usable.any() else key
    dark = frame["stimulus"].to_numpy() == 0
    places = {}
    for place, rows, values in (
        ("offset", usable & dark, resid),
        ("stimulus", usable & ~dark & (np.abs(signal) > 1e-9), resid / np.where(np.abs(signal) > 1e-9, signal, 1.0)),
    ):
        if rows.sum() < 6:
            continue
        basis = np.cos(np.pi * np.arange(1, 4)[None, :] * tau[rows, None])
        design = np.column_stack([np.ones(rows.sum()), basis])
        weights = z[rows] / np.where(values[rows] != 0, values[rows], 1.0)  # 1 / sd in the place's units
        coef, *_ = np.linalg.lstsq(design * weights[:, None], z[rows], rcond=None)
        fitted = design @ coef
        chi2_drop = float(np.sum(z[rows] ** 2) - np.sum((z[rows] - weights * fitted) ** 2))
        curve = basis @ coef[1:]
        places[place] = {"chi2_drop": chi2_drop, "size": float(np.ptp(curve)), "rows": int(rows.sum())}
    return places
