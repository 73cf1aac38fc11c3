"""Design a calibration campaign: which groups to measure, and how often, to reach the intervals wanted
(docs/guides/design.md).

:func:`design` linearises the model over the candidate grid of a protocol
(:mod:`bayescal.campaign.information`), predicts the widths the protocol would give, and chooses groups
greedily (:mod:`bayescal.campaign.search`) until every target is as narrow as asked, keeping the rows
the model's checks need (:mod:`bayescal.campaign.checks`).  Without an earlier fit the camera is the
protocol's ``[truth]`` (a nominal camera): the point the information is computed at is the mode of a
simulated measurement of the whole grid.  With ``after`` (a fit of a campaign under way) it is that
fit's posterior, and the design is the next block to measure.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from bayescal._config import computes
from bayescal.campaign import checks as model_checks
from bayescal.campaign.discriminate import Discrimination, telling_apart
from bayescal.campaign.grid import Grid, with_rows
from bayescal.campaign.information import Linearisation, Targets, linearise
from bayescal.campaign.search import Costs, cost_of, greedy, pruned, relaxed, trimmed
from bayescal.errors import SpecError
from bayescal.inference.laplace import LaplaceResult, laplace
from bayescal.inference.program import Program, program_for
from bayescal.inference.samplers import laplace_z
from bayescal.inference.start import initial_point
from bayescal.io.design import Design, load_design
from bayescal.io.table import MeasurementTable
from bayescal.model.assemble import CalibrationModel, build_model
from bayescal.model.spec import ModelSpec, load_spec

__all__ = ["CampaignDesign", "design"]


@dataclass(frozen=True)
class CampaignDesign:
    """A designed campaign (or its next block) and the widths it is expected to give.

    Attributes
    ----------
    design : Design
        What to measure (for ``after``: the next block only); ``bayescal simulate`` and a lab's scripts
        read it as written by :meth:`save`.
    grid : Grid
        The candidates it was chosen from.
    counts : array (K,)
        How often each grid group is measured (for ``after``: in the next block).
    widths : DataFrame
        One row per target: ``target``, ``goal_sd``, ``design_sd`` (expected posterior sd after the
        design), ``protocol_sd`` (after the protocol), ``now_sd`` (``after``: before the block).
    rows, protocol_rows : int
        Rows the design and the protocol measure (for ``after``: the block's rows, and the protocol's
        rows not yet measured).
    checks : list of Check
        The model checks the design supports (or gives up).
    met : bool
        Every target reaches its goal (with ``after``: once the next block is measured).
    done : bool
        ``after`` only: the campaign already meets its goals (stop measuring).
    """

    design: Design
    grid: Grid
    counts: np.ndarray
    widths: pd.DataFrame
    rows: int
    protocol_rows: int
    checks: list[model_checks.Check]
    met: bool
    done: bool = False
    #: the prediction targets after the coefficients: ``(channel, grid group)`` of each, in ``widths``' order
    predictions: tuple[tuple[str, int], ...] = ()
    #: without a budget: the rows of the best continuous design (fractional repeats) at the nominal noise
    #: scale, a lower bound on the rows of any design of this grid that meets the goals at that scale
    bound_rows: float | None = None
    #: ``after`` only: how often each grid group was measured already, and the protocol's next block
    measured: np.ndarray | None = None
    protocol_next: np.ndarray | None = None
    #: targets whose goal lies below what any campaign of the grid reaches -> that floor (expected sd)
    unreachable: dict[str, float] = field(default_factory=dict)
    #: without a budget: the most rows the search considers, when the goals need that many or more
    max_rows: int | None = None
    #: what the design costs in rows (setting changes included), and the budget it was made for
    cost_rows: float = 0.0
    budget_rows: float | None = None
    #: ``after`` a fit with a MODEL DOUBT: the groups that tell its two structures apart
    #: (:mod:`bayescal.campaign.discriminate`)
    telling_apart: Discrimination | None = None

    @property
    def over_budget(self) -> bool:
        """The design costs more than its budget (the rows the model's checks need, kept)."""
        return self.budget_rows is not None and self.cost_rows > self.budget_rows + 1e-9

    def groups(self) -> pd.DataFrame:
        """The chosen groups, one row each: the setting, the level and how many times."""
        levels = self.grid.protocol.levels
        recs = []
        for g, n in zip(self.grid.groups, self.counts, strict=True):
            if n > 0:
                recs.append(
                    {
                        "exposure_s": g.exposure_s,
                        "gain": g.gain,
                        "tdi_stages": g.tdi_stages,
                        "temperature_c": g.temperature_c,
                        "level": "dark" if g.dark else f"L{g.level + 1:02d}",
                        "stimulus": 0.0 if g.dark else levels[g.level],
                        "times": int(n),
                    }
                )
        return pd.DataFrame(recs)

    def summary(self) -> str:
        """What a lab manager reads: rows, goals met, the widest targets, the checks given up."""
        w = self.widths
        after = "now_sd" in w
        ratio = (w["design_sd"] / w["goal_sd"]).to_numpy()
        groups = int((self.counts > 0).sum())
        lines = []
        if self.done:
            lines.append("The campaign already meets every goal: stop measuring.")
        elif after and self.protocol_next is not None:
            lines.append(
                f"Next block: {self.rows} rows ({groups} groups); the protocol has {self.protocol_rows} rows left, "
                f"its own next block {int(self.protocol_next.sum()) * len(self.grid.channels)}."
            )
        else:
            lines.append(
                f"The design measures {self.rows} rows ({groups} groups); the protocol has {self.protocol_rows}."
            )
        if self.bound_rows is not None and self.met and not after:
            lines.append(
                f"With fractional repeats and the noise scale known, {self.bound_rows:.0f} rows would do; whole "
                "repeats and the noise scale the campaign must estimate cost the rest."
            )
        unmet = int((ratio > 1 + 1e-9).sum())
        for name, floor in self.unreachable.items():
            goal = float(w.loc[w["target"] == name, "goal_sd"].iloc[0])
            lines.append(
                f"UNREACHABLE: {name} cannot be narrowed to {goal:.4g}: no campaign of this grid takes it below "
                f"{floor:.4g} (what the prior and the sphere's common scale leave); the design aims at "
                f"{UNREACHABLE_AIM * floor:.4g}."
            )
        if self.over_budget:
            lines.append(
                f"OVER BUDGET: the design costs {self.cost_rows:g} rows, more than the budget of {self.budget_rows:g}: "
                "the model's checks need these rows (--no-checks gives them up and stays within the budget)."
            )
        if self.max_rows is not None:
            lines.append(
                f"The goals need more than {self.max_rows} rows ({MAX_ROWS_PER_PROTOCOL} times the protocol's); the "
                "search stopped there: widen the goals (--goal-scale) or give --budget-rows."
            )
        if self.met:
            lines.append("Every target reaches its goal" + (" once the block is measured." if after else "."))
        elif after:
            lines.append(f"{unmet} target(s) stay wider than their goal after this block: more blocks are needed.")
        else:
            lines.append(f"{unmet} target(s) stay wider than their goal: raise the budget or widen the goals.")
        worst = w.assign(ratio=ratio).sort_values("ratio", ascending=False).head(5)
        lines.append("Widest against goal (expected posterior sd):")
        for _, r in worst.iterrows():
            now = f", now {r['now_sd']:.4g}" if after else ""
            lines.append(
                f"  {r['target']:<40s} {r['design_sd']:.4g} (goal {r['goal_sd']:.4g}, protocol "
                f"{r['protocol_sd']:.4g}{now})"
            )
        for c in self.checks:
            if not c.supported:
                lines.append(f"GIVES UP the {c.name} check: it needs {c.needs}.")
        if self.telling_apart is not None:
            lines.append(self.telling_apart.summary())
        return "\n".join(lines)

    def save(self, out_dir: str | os.PathLike) -> Path:
        """Write ``design.toml`` (read by ``bayescal simulate``), ``groups.csv`` and ``widths.csv`` to a
        new folder (an earlier design's folder is replaced whole; any other folder is refused)."""
        from bayescal.io.design import design_toml
        from bayescal.io.outputs import staged_directory

        out = Path(out_dir)
        with staged_directory(out, "design") as stage:
            spec = self.design.spec
            relative = None if spec is None else os.path.relpath(Path(spec).resolve(), out.resolve())
            stage("design.toml").write_text(design_toml(self.design, spec=relative))
            stage("groups.csv").write_text(self.groups().to_csv(index=False, float_format="%.8g"))
            stage("widths.csv").write_text(self.widths.to_csv(index=False, float_format="%.6g"))
            if self.telling_apart is not None:
                table = self.telling_apart.table
                stage("telling_apart.csv").write_text(table.to_csv(index=False, float_format="%.6g"))
        return out


def _targets(grid: Grid, frame: pd.DataFrame, groups: np.ndarray, protocol: Design, clipped: np.ndarray) -> Targets:
    """The coefficients, and the reading at each illuminated setting of the protocol in each channel, at the
    middle of the levels the protocol measures there that stay clear of clipping (``clipped``: per row),
    a prediction at the settings the lab uses."""
    per_setting: dict[tuple, list[int]] = {}
    for g, n in zip(grid.groups, grid.counts(protocol), strict=True):
        if n > 0 and not g.dark:
            per_setting.setdefault(g.setting, []).append(g.level)
    position = {(g.setting, g.level): k for k, g in enumerate(grid.groups)}
    channel = frame["channel"].to_numpy()
    rows, names = [], []
    for setting, levels in per_setting.items():
        for c in grid.channels:
            clear = []
            for level in sorted(levels):
                r = np.flatnonzero((groups == position[setting, level]) & (channel == c))
                if r.size and not clipped[r[0]]:
                    clear.append(int(r[0]))
            if clear:
                row = clear[len(clear) // 2]
                rows.append(row)
                names.append(f"DN[{c}] at {grid.groups[groups[row]].label(grid.protocol.levels)}")
    return Targets(coefficients=True, rows=tuple(rows), row_names=tuple(names))


def _goals(names: tuple[str, ...], protocol_sd: np.ndarray, scale: float, given: Mapping[str, float] | None):
    goals = protocol_sd * scale
    for name, value in (given or {}).items():
        if name not in names:
            raise SpecError(f"goal for '{name}': no such target; targets are {', '.join(names)}")
        goals[names.index(name)] = float(value)
    if np.any(~(goals > 0)):
        raise SpecError("every goal must be a positive standard deviation")
    return goals


@computes
def design(
    protocol: Design | str | os.PathLike,
    spec: ModelSpec | str | os.PathLike | None = None,
    *,
    goals: Mapping[str, float] | None = None,
    goal_scale: float = 1.0,
    budget_rows: float | None = None,
    setting_cost: float = 0.0,
    draws: int = 1,
    keep_checks: bool = True,
    after: str | os.PathLike | None = None,
    block_rows: float | None = None,
    seed: int = 0,
    progress: Callable[[str], None] | None = None,
) -> CampaignDesign:
    """The cheapest campaign that reaches the protocol's interval widths (times ``goal_scale``), or the
    narrowest one within ``budget_rows``.

    Parameters
    ----------
    protocol : Design or path
        The protocol the lab would follow (``models/seed000_design.toml``, or a shipped name such as
        ``"seed000"``), with a ``[truth]`` table: the nominal camera the design is made for.  Its
        illuminated settings at every one of its levels, and its dark settings, are the candidates.
    spec : ModelSpec or path, optional
        The model; defaults to the protocol's ``spec``.
    goals : mapping, optional
        Target name -> the posterior standard deviation wanted (``"A2[R]"``, ``"DN[G] at 0.008 s, gain 2,
        L05 (10)"``); the others get the protocol's, times ``goal_scale``.
    goal_scale : float
        The protocol's expected widths times this are the goals (0.5: twice as narrow).
    budget_rows : float, optional
        The most rows to measure (setting changes included, see ``setting_cost``); with a budget the
        design narrows the targets until it is spent.
    setting_cost : float
        What changing the setting costs, in rows (time at the sphere).
    draws : int
        Points of the nominal camera's posterior the widths are averaged over (1: its mode).
    keep_checks : bool
        Keep the rows the model's checks need (:mod:`bayescal.campaign.checks`).
    after : path, optional
        A fit of the campaign so far (``bayescal fit --out``): the design is the next block to measure,
        computed at that fit's posterior; the fit's model replaces ``spec``.  ``widths`` then also holds
        ``now_sd`` and ``protocol_next_sd`` (after the protocol's own next block), and ``done`` says
        whether the goals are met already.
    block_rows : float, optional
        With ``after``: the next block's size in rows (default: the protocol's next block's).
    seed : int
        Seed of the simulated measurement the nominal camera's mode comes from, and of its draws.
    progress : callable, optional
        ``progress(message)`` as each stage starts.

    Returns
    -------
    CampaignDesign

    Examples
    --------
    >>> import bayescal as bc
    >>> plan = bc.design("seed000")  # doctest: +SKIP
    >>> print(plan.summary())  # doctest: +SKIP
    """
    say = progress or (lambda message: None)
    protocol = protocol if isinstance(protocol, Design) else load_design(protocol)
    grid = Grid.of(protocol)
    if after is None:
        state = _nominal(grid, _spec(spec, protocol), seed, say)
    else:
        if block_rows is None and budget_rows is not None:
            block_rows = budget_rows
        state = _measured(grid, after, say)
    telling = _telling_apart(grid, after, seed, say) if after is not None else None
    points = _points(state, draws, seed)
    say(f"linearising at {len(points)} point(s)")
    model, program, groups = state.model, state.program, state.groups
    targets = _targets(grid, model.table.frame, groups, protocol, _clipped(program, model, points[0]))
    lin = linearise(program, model, points, targets, groups, len(grid), base=state.base)
    protocol_counts = grid.counts(protocol)
    protocol_sd = lin.sd(protocol_counts)
    goal = _goals(lin.names, protocol_sd, goal_scale, goals)
    measured = state.measured
    now_sd = lin.sd(measured)
    done = after is not None and bool(np.all(now_sd <= goal * (1 + 1e-9)))
    # the widths no campaign of this grid goes below (every group that reads below full scale measured a
    # million times): a goal under its floor is unreachable, whatever is measured (the prior, the sphere)
    floor = lin.sd(measured + (lin.clipped < 0.5) * 1e6)
    unreachable = {n: float(f) for n, f, g in zip(lin.names, floor, goal, strict=True) if not g > f * (1 + 1e-6)}
    say(
        "choosing measurements"
        + (f" ({len(unreachable)} goal(s) below what any campaign reaches)" if unreachable else "")
    )
    budget = budget_rows
    if after is not None:
        nxt = _protocol_next(grid, protocol, measured)
        budget = float(block_rows) if block_rows is not None else float(nxt.sum() * len(grid.channels))
    bound = 0.0
    counts = np.zeros(len(grid), dtype=int)
    # the search works at the noise scale of the points; the goals are widths with the scale integrated
    # (Linearisation.sd), so each round tightens the search's goals by what integrating added
    aim = np.where(goal > floor * (1 + 1e-6), goal, UNREACHABLE_AIM * floor)  # an unreachable goal: near its floor
    search_goal = aim * lin.at_scale().sd(protocol_counts) / protocol_sd
    n_ch = len(grid.channels)
    max_rows = max(MAX_ROWS_PER_PROTOCOL * int(protocol_counts.sum()) * n_ch, MIN_MAX_ROWS)
    for _ in range(0 if done else 4):
        counts, bound = _choose(
            lin,
            grid,
            search_goal,
            protocol_counts,
            state.spec,
            budget,
            setting_cost,
            keep_checks,
            base=measured,
            max_rows=max_rows,
        )
        sd = lin.sd(measured + counts)
        if budget is not None or np.all(sd <= goal * (1 + 1e-9)):
            break
        search_goal = search_goal * np.minimum(1.0, goal / sd)
    sd = lin.sd(measured + counts)
    columns = {"target": lin.names, "goal_sd": goal, "design_sd": sd, "protocol_sd": protocol_sd, "floor_sd": floor}
    if after is not None:
        columns |= {"now_sd": now_sd, "protocol_next_sd": lin.sd(measured + nxt)}
    left = np.maximum(protocol_counts - measured, 0)
    return CampaignDesign(
        design=grid.design(counts),
        grid=grid,
        counts=counts,
        widths=pd.DataFrame(columns),
        rows=int(counts.sum()) * n_ch,
        protocol_rows=int(left.sum()) * n_ch,
        checks=model_checks.checks_of(grid.groups, measured + counts, state.spec.response.order, protocol_counts),
        met=bool(np.all(sd <= goal * (1 + 1e-9))),
        done=done,
        predictions=tuple((str(model.table.frame["channel"].iloc[r]), int(groups[r])) for r in targets.rows),
        bound_rows=bound if budget is None else None,
        measured=None if after is None else measured,
        protocol_next=None if after is None else nxt,
        unreachable=unreachable,
        max_rows=max_rows if budget is None and int(counts.sum()) * n_ch >= max_rows else None,
        cost_rows=cost_of(counts, Costs(n_ch, setting_cost), [g.setting for g in grid.groups]),
        budget_rows=budget,
        telling_apart=telling,
    )


@dataclass(frozen=True)
class _State:
    """What the design is computed from: the model of the grid table, its mode, each row's group, the rows
    whose information enters as already known (``base``) and the groups measured so far."""

    spec: ModelSpec
    model: CalibrationModel
    program: Program
    mode: LaplaceResult
    groups: np.ndarray
    base: np.ndarray | None
    measured: np.ndarray
    centre: np.ndarray


def _nominal(grid: Grid, spec: ModelSpec, seed: int, say: Callable[[str], None]) -> _State:
    """The nominal camera (the protocol's truth): the mode of a simulated measurement of the whole grid."""
    if grid.protocol.truth is None:
        raise SpecError("design needs the nominal camera: give the protocol a [truth] table, or use --after FIT")
    from bayescal.model.simulate import simulate

    say(f"simulating the whole grid ({len(grid)} groups) of the nominal camera")
    table = simulate(spec, grid.design(np.ones(len(grid), dtype=int)), seed=seed).table
    say("finding the nominal camera's mode")
    model = build_model(table, spec)
    program = program_for(model)
    mode = laplace(program, model.data, initial_point(model, program))
    if not mode.converged:
        raise SpecError("the nominal camera's simulated grid could not be fitted (its mode search did not converge)")
    groups = grid.rows_of(model.table.frame)
    centre = _with_noise_scale(program, model, np.asarray(mode.mode), grid.protocol.truth.excess_dn)
    return _State(spec, model, program, mode, groups, None, np.zeros(len(grid), dtype=int), centre)


def _with_noise_scale(program, model, z: np.ndarray, excess_dn: float) -> np.ndarray:
    """``z`` with the excess scatter at the nominal camera's (the mode of one simulated grid states it a
    fifth low on the seed-002 grid: fitted beside every level's and setting's factor, as maximum
    likelihood states a variance against REML)."""
    if program.site_index("excess") is None or excess_dn <= 0:
        return z
    latent = program.unravel(program.z0)
    values = {k: np.asarray(v)[0] for k, v in program.constrain(z[None], model.data).items() if k in latent}
    values["excess"] = np.asarray(excess_dn / model.layout.dn_scale)
    return np.asarray(program.unconstrain(values, model.data))


def _measured(grid: Grid, after, say: Callable[[str], None]) -> _State:
    """A campaign under way: its fit's table, and every grid group not yet measured as a row the model
    predicts but does not fit (its reading a placeholder: the fit's posterior mean)."""
    from bayescal.io.fit_folder import FitFolder
    from bayescal.posterior.calibration import Calibration

    say("reading the campaign's fit")
    folder = after if isinstance(after, FitFolder) else FitFolder.at(after, "`bayescal design --after`")
    cal = Calibration.load(folder)
    import tomllib

    spec = ModelSpec.from_dict(tomllib.loads(folder.posterior.attrs["spec_toml"]), source=str(folder.posterior_path))
    frame = folder.measurements.rename(columns={spec.stimulus: "stimulus"})
    missing = [c for c in grid.channels if c not in set(frame["channel"])]
    if missing:
        raise SpecError(f"the fit at {folder.posterior_path} has no channel(s) {missing} of the protocol")
    at = grid.rows_of(frame)
    first = frame["channel"].to_numpy() == grid.channels[0]
    measured = np.bincount(at[(at >= 0) & first], minlength=len(grid))
    todo = [g for g, n in zip(grid.groups, measured, strict=True) if n == 0]
    candidates = _placeholder_rows(todo, grid, cal, frame)
    union = with_rows(frame, candidates)
    union = union.rename(columns={"stimulus": spec.stimulus})
    table = MeasurementTable.from_frame(union, source=f"{folder.posterior_path} and the grid's groups not measured")
    say("finding the campaign's mode")
    model = build_model(table, spec)
    program = program_for(model)
    done = np.arange(len(union)) < len(frame)
    data = model.data._replace(keep=done)
    mode = laplace(program, data, initial_point(model, program))
    if not mode.converged:
        raise SpecError(f"the campaign's fit at {folder.posterior_path} could not be refitted with the grid's rows")
    groups = np.concatenate([at, grid.rows_of(candidates)])
    # measured rows off the grid, or repeating a group, enter with what they were measured as
    base = done & ((groups < 0) | ~_first_of_group(groups, union["channel"].to_numpy()))
    model = dataclasses.replace(model, data=data)
    # the posterior mean of the Laplace backend's draws: the excess scatter's scale integrated (the joint
    # mode under-states it as maximum likelihood does against REML)
    centre = laplace_z(model, program, mode, 0, {})[0].mean(axis=0)
    return _State(spec, model, program, mode, groups, base, measured, centre)


def _telling_apart(grid: Grid, after, seed: int, say: Callable[[str], None]) -> Discrimination | None:
    """For a fit that ended with a MODEL DOUBT: the grid's groups that tell its two structures apart."""
    from bayescal.io.fit_folder import FitFolder
    from bayescal.posterior.calibration import Calibration

    folder = after if isinstance(after, FitFolder) else FitFolder.at(after, "`bayescal design --after`")
    doubt = folder.summary.diagnostics.get("structure")
    if not doubt:
        return None
    import tomllib

    spec = ModelSpec.from_dict(tomllib.loads(folder.posterior.attrs["spec_toml"]), source=str(folder.posterior_path))
    frame = folder.measurements.rename(columns={spec.stimulus: "stimulus"})
    every = _placeholder_rows(list(grid.groups), grid, Calibration.load(folder), frame)
    return telling_apart(grid, spec, frame, doubt, every, seed, say)


def _first_of_group(groups: np.ndarray, channels: np.ndarray) -> np.ndarray:
    """Rows that are the first of their group in their channel (the one whose information stands for the
    group's); a repeat of a group is counted, not linearised."""
    seen: set[tuple[int, str]] = set()
    out = np.zeros(len(groups), dtype=bool)
    for r, (k, c) in enumerate(zip(groups, channels, strict=True)):
        if k >= 0 and (k, c) not in seen:
            seen.add((k, c))
            out[r] = True
    return out


def _placeholder_rows(todo: list, grid: Grid, cal, frame: pd.DataFrame) -> pd.DataFrame:
    """A row per channel of every group not yet measured, its reading the calibration's posterior mean
    (clipped) and its per-pixel variance the calibration's, its level named as the table names it."""
    from bayescal.model.setting import Setting

    labels = {float(s): str(lv) for s, lv in zip(frame["stimulus"], frame["level"], strict=True) if s > 0}
    levels = grid.protocol.levels
    recs = []
    for g in todo:
        setting = Setting(g.exposure_s, g.gain, g.tdi_stages, g.temperature_c)
        stim = 0.0 if g.dark else float(levels[g.level])
        for c in grid.channels:
            dn, var = _placeholder(cal, c, stim, setting)
            recs.append(
                {
                    "channel": c,
                    "stimulus": stim,
                    "exposure_s": g.exposure_s,
                    "gain": g.gain,
                    "tdi_stages": g.tdi_stages,
                    **({} if g.temperature_c is None else {"temperature_c": g.temperature_c}),
                    "level": "dark" if g.dark else labels.get(stim, f"design-L{g.level + 1:02d}"),
                    "n_frames": grid.protocol.n_frames,
                    "n_pixels": grid.protocol.n_pixels,
                    "dn_mean": dn,
                    "dn_var": var,
                }
            )
    return pd.DataFrame(recs)


def _placeholder(cal, channel: str, stimulus: float, setting) -> tuple[float, float]:
    """The calibration's mean reading (clipped) and per-pixel variance at a setting; at a gain it cannot
    predict (offsets per gain setting, that gain never dark-measured) the nearest calibrated gain's,
    scaled by the gain ratio: only a starting value for a row that is predicted, not fitted."""
    try:
        reading = cal.reading(channel, np.array([stimulus]), setting, relative=True)
        scale = 1.0
    except SpecError:
        gains = np.asarray(cal.dark.gains, dtype=float)
        near = float(gains[np.argmin(np.abs(np.log(gains / setting.gain)))])
        reading = cal.reading(channel, np.array([stimulus]), dataclasses.replace(setting, gain=near), relative=True)
        scale = setting.gain / near
    dn = float(np.clip(np.mean(reading.mean) * scale, 0.0, cal.full_scale))
    var = float(np.mean(cal.pixel_var(np.maximum(reading.signal * scale, 0.0), setting)))
    return dn, var


def _protocol_next(grid: Grid, protocol: Design, measured: np.ndarray) -> np.ndarray:
    """The protocol's next block: the groups of its first block (in the file's order) not yet measured."""
    left = np.array(measured, dtype=int)
    for block in (*protocol.illuminated, *protocol.dark):
        one = dataclasses.replace(protocol, illuminated=(block,) if block in protocol.illuminated else (), dark=())
        if block in protocol.dark and block not in protocol.illuminated:
            one = dataclasses.replace(protocol, illuminated=(), dark=(block,))
        want = grid.counts(one)
        todo = np.maximum(want - left, 0)
        left = np.maximum(left - want, 0)
        if todo.any():
            return todo
    return np.zeros(len(grid), dtype=int)


def _clipped(program, model, z: np.ndarray) -> np.ndarray:
    """Rows whose expected reading at ``z`` comes near clipping: within two noise sds of the threshold, or
    where a pixel spread of ``saturation.prnu_bound`` (three sds of it) would clip some pixels of a region
    (its mean then depends on a spread the table does not measure; seed 000 section 5.3)."""
    sites = program.constrain(np.asarray(z)[None], model.data)
    mean, sd = np.asarray(sites["row_mean"])[0], np.asarray(sites["row_sd"])[0]
    signal = np.maximum(np.asarray(sites["row_signal"])[0], 0.0)
    spread = 3 * model.spec.saturation.prnu_bound * signal
    return mean + np.maximum(2 * sd, spread) >= float(np.asarray(model.data.threshold))


def _spec(spec, protocol: Design) -> ModelSpec:
    if isinstance(spec, ModelSpec):
        return spec
    path = spec if spec is not None else protocol.spec
    if path is None:
        raise SpecError('no model: give a spec, or a protocol whose file names one (spec = "...")')
    return load_spec(path)


def _points(state: _State, draws: int, seed: int) -> np.ndarray:
    """Where the information is computed: the state's centre, then ``draws - 1`` of the Laplace backend's
    draws (the excess scatter's scale integrated, as ``bayescal fit --backend laplace`` reports them)."""
    if draws <= 1:
        return state.centre[None]
    z = laplace_z(state.model, state.program, state.mode, seed, {})[0]
    return np.concatenate([state.centre[None], z[: draws - 1]])


#: a goal below its floor is aimed at this multiple of the floor
UNREACHABLE_AIM = 1.05
#: without a budget, the search considers designs of at most this many times the protocol's rows ...
MAX_ROWS_PER_PROTOCOL = 20
#: ... and at least this many rows
MIN_MAX_ROWS = 2000


def _choose(
    lin: Linearisation,
    grid: Grid,
    goal: np.ndarray,
    protocol_counts: np.ndarray,
    spec: ModelSpec,
    budget_rows: float | None,
    setting_cost: float,
    keep_checks: bool,
    base: np.ndarray | None = None,
    max_rows: float = np.inf,
) -> tuple[np.ndarray, float]:
    """The groups to measure beyond ``base`` (those measured already): the continuous optimum
    (:func:`~bayescal.campaign.search.relaxed`) rounded up (to meet goals) or down (within a budget), groups
    added greedily until the goals or the budget are met, the checks' groups kept
    (:mod:`bayescal.campaign.checks`), then what is not needed taken back
    (:func:`~bayescal.campaign.search.pruned`) or what the budget cannot pay removed
    (:func:`~bayescal.campaign.search.trimmed`).  Returns the new counts (``base`` excluded) and the
    continuous optimum's rows (a lower bound on any design's rows that meets the goals)."""
    costs = Costs(len(grid.channels), setting_cost)
    settings = [g.setting for g in grid.groups]
    eligible = lin.clipped < 0.5
    meet = budget_rows is None
    budget = np.inf if budget_rows is None else float(budget_rows)
    order = spec.response.order
    base = np.zeros(len(grid), dtype=int) if base is None else np.asarray(base, dtype=int)
    paid = cost_of(base, costs, settings)

    def spent(counts: np.ndarray) -> float:
        return cost_of(counts, costs, settings) - paid

    w = relaxed(lin, base, goal, costs.of(settings, set()), eligible, None if meet else budget)
    bound = float(w.sum() * costs.rows_per_group)
    if meet and bound > max_rows:  # goals out of reach: the continuous design cut down to the most rows considered
        counts = base + np.floor(w * max_rows / bound).astype(int)
        for mask in model_checks.missing(grid.groups, counts, order, protocol_counts) if keep_checks else []:
            counts, _ = greedy(lin, counts, goal, costs, settings, eligible=eligible & mask, meet=False, steps=1)
        return counts - base, bound
    counts = base + (np.ceil(w - 0.02) if meet else np.floor(w)).astype(int)
    cap = min(budget, max_rows)
    for _ in range(8):
        counts, _ = greedy(
            lin, counts, goal, costs, settings, eligible=eligible, budget=cap, meet=meet, spent=spent(counts)
        )
        repairs = model_checks.missing(grid.groups, counts, order, protocol_counts) if keep_checks else []
        if not repairs:
            break
        for mask in repairs:
            counts, _ = greedy(
                lin, counts, goal, costs, settings, eligible=eligible & mask, meet=False, steps=1, spent=spent(counts)
            )
    kept = {c.name for c in model_checks.checks_of(grid.groups, counts, order, protocol_counts) if c.supported}

    def allowed(trial: np.ndarray) -> bool:
        now = model_checks.checks_of(grid.groups, trial, order, protocol_counts)
        return not keep_checks or kept <= {c.name for c in now if c.supported}

    if meet:
        counts = pruned(lin, counts, goal, costs, settings, base, allowed)
    else:
        counts = trimmed(lin, counts, goal, costs, settings, budget + paid, base, allowed)
    return counts - base, bound
