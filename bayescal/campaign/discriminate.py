"""The rows that tell two structures apart, for a fit whose data could not (its ``MODEL DOUBT``).

A fit may end with two structures that predict its data about as well (a knee or a smooth roll-off, a
lamp's drift or the settings' factors) yet disagree on the coefficients.  Where they disagree on what
a *new* reading would be, that reading tells them apart.  Both structures are fitted (Laplace, the fit's
own rows) and each candidate group of the protocol's grid is scored by the separation of the two
predictive distributions of one more reading in each channel, summed over channels:

``d_g = sum_c (m_a - m_b)^2 / (v_a + v_b)``

with ``m`` the predictive mean and ``v`` the predictive variance (the posterior's spread of the mean plus
the reading's noise).  For two Gaussians of about equal variance ``d / 4`` is the expected log Bayes
factor that one reading adds (the Kullback-Leibler divergence ``(m_a - m_b)^2 / (2 v)`` with
``v = (v_a + v_b) / 2``); the groups with the largest ``d`` are the ones to measure next.
"""

from __future__ import annotations

import dataclasses
import tomllib
from collections.abc import Callable

import numpy as np
import pandas as pd

from bayescal.campaign.grid import Grid, with_rows
from bayescal.errors import SpecError
from bayescal.inference.laplace import laplace
from bayescal.inference.program import program_for
from bayescal.inference.samplers import laplace_z
from bayescal.inference.start import initial_point
from bayescal.io.table import MeasurementTable
from bayescal.model.assemble import build_model
from bayescal.model.spec import ModelSpec

__all__ = ["Discrimination", "telling_apart"]

#: draws of each structure's Laplace posterior the predictive spread of a group's mean comes from
DRAWS = 400
#: the expected log Bayes factor (summed over the block) the block aims at: a difference of two standard
#: errors of a paired elpd difference is what the diagnosis takes as telling structures apart
TARGET_LOG_BF = 4.0


@dataclasses.dataclass(frozen=True)
class Discrimination:
    """Where two structures of one fit disagree on a new reading.

    Attributes
    ----------
    reported, other : str
        The structure the fit reported and the one it could not tell from it.
    table : DataFrame
        One row per candidate group, most telling first: ``group`` (its label), ``separation`` (``d_g``),
        ``log_bf`` (``d_g / 4``, the expected log Bayes factor of one reading of the group), and per channel
        ``dn_<c>`` (the reported structure's predicted reading, DN), ``diff_<c>`` (``m_a - m_b``, DN) and
        ``sd_<c>`` (``sqrt((v_a + v_b) / 2)``, DN).
    block : int
        How many of the first groups reach :data:`TARGET_LOG_BF` together (each read once); the whole
        table's length when even all of them do not.
    """

    reported: str
    other: str
    table: pd.DataFrame
    block: int

    def summary(self) -> str:
        """The lines ``bayescal design --after`` prints."""
        head = self.table.head(max(self.block, 1))
        total = float(head["log_bf"].sum())
        reach = "" if total >= TARGET_LOG_BF else f" (all {len(self.table)} groups together reach {total:.1f})"
        lines = [
            f"MODEL DOUBT: the fit could not tell '{self.reported}' from '{self.other}'. The groups where their "
            f"predictions of one more reading differ most (expected log Bayes factor per reading); reading the "
            f"first {len(head)} once gives about {total:.1f}{reach}:"
        ]
        channels = [c.removeprefix("diff_") for c in self.table.columns if c.startswith("diff_")]
        for _, r in head.iterrows():
            per = ", ".join(f"{c} {r[f'diff_{c}']:+.3g} DN (sd {r[f'sd_{c}']:.3g})" for c in channels)
            lines.append(f"  {r['group']:<40s} {r['log_bf']:7.2f}   {per}")
        return "\n".join(lines)


def telling_apart(
    grid: Grid,
    spec: ModelSpec,
    frame: pd.DataFrame,
    doubt: dict,
    placeholders: pd.DataFrame,
    seed: int = 0,
    say: Callable[[str], None] | None = None,
) -> Discrimination | None:
    """The groups of ``grid`` that tell the fit's structure from the one its doubt names.

    ``frame``: the fit's measurements (``stimulus`` column); ``doubt``: the fit's ``structure`` diagnostic
    with the other structure's spec (``other_spec``, TOML); ``placeholders``: a row per channel of every
    grid group (:func:`bayescal.campaign.design._placeholder_rows`), the readings to predict.  None when
    the doubt carries no other structure (a fit written before it did).
    """
    text = doubt.get("other_spec")
    if not text:
        return None
    say = say or (lambda message: None)
    other = ModelSpec.from_dict(tomllib.loads(text), source="the fit's structure diagnostic")
    # a group measured already is a candidate too (a repeat): its placeholder is another replicate of it
    first_free = float(frame["replicate"].max()) + 1 if "replicate" in frame else 1.0
    union = with_rows(frame, placeholders.assign(replicate=first_free))
    done = np.arange(len(union)) < len(frame)
    predicted = {}
    for name, s in (("reported", spec), ("other", other)):
        say(f"fitting the {name} structure to predict the grid")
        table = MeasurementTable.from_frame(union.rename(columns={"stimulus": s.stimulus}), source="the grid")
        predicted[name] = _predictive(table, s, done, seed)
    (m_a, v_a), (m_b, v_b) = predicted["reported"], predicted["other"]
    rows = np.flatnonzero(~done)
    ours = union.iloc[rows].reset_index(drop=True)
    at = grid.rows_of(ours)
    diff, var = (m_a - m_b)[rows], (v_a + v_b)[rows]
    channels = list(dict.fromkeys(ours["channel"]))
    recs = []
    for g in np.unique(at[at >= 0]):
        rec: dict = {"group": grid.groups[g].label(grid.protocol.levels), "separation": 0.0}
        for c in channels:
            pick = np.flatnonzero((at == g) & (ours["channel"].to_numpy() == c))
            if pick.size == 0:
                continue
            i = pick[0]
            rec[f"dn_{c}"] = float(m_a[rows][i])
            rec[f"diff_{c}"] = float(diff[i])
            rec[f"sd_{c}"] = float(np.sqrt(var[i] / 2))
            rec["separation"] += float(diff[i] ** 2 / var[i])
        recs.append(rec)
    table = pd.DataFrame(recs)
    table["log_bf"] = table["separation"] / 4.0
    table = table.sort_values("log_bf", ascending=False, kind="stable").reset_index(drop=True)
    reach = np.cumsum(table["log_bf"].to_numpy())
    block = int(np.searchsorted(reach, TARGET_LOG_BF) + 1) if reach[-1] >= TARGET_LOG_BF else len(table)
    candidate = str(doubt.get("candidate", "the other structure"))
    if doubt.get("other"):  # a screened candidate, reported: the other is the spec it nests
        return Discrimination(candidate, str(doubt["other"]), table, block)
    return Discrimination(str(doubt.get("reported") or "the model adopted"), candidate, table, block)


def _predictive(table: MeasurementTable, spec: ModelSpec, done: np.ndarray, seed: int):
    """Each row's predictive mean and variance of one more reading (DN) under ``spec`` fitted to the rows
    ``done`` (Laplace): the mean and variance of the rows' expected reading over the posterior's draws,
    plus the reading's own noise."""
    model = build_model(table, spec.replace(inference={"laplace_draws": DRAWS}))
    program = program_for(model)
    data = model.data._replace(keep=done)
    mode = laplace(program, data, initial_point(model, program))
    if not mode.converged:
        raise SpecError(f"a structure of the fit ({spec.name or 'its spec'}) could not be refitted to its rows")
    model = dataclasses.replace(model, data=data)
    z = laplace_z(model, program, mode, seed, {})[0]
    sites = program.constrain(np.asarray(z), data)
    scale = model.layout.dn_scale
    means = np.asarray(sites["row_mean"]) * scale  # (draw, row)
    noise = np.asarray(sites["row_sd"]) * scale
    return means.mean(axis=0), means.var(axis=0) + (noise**2).mean(axis=0)
