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

import os
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from bayescal._config import computes
from bayescal.campaign import checks as model_checks
from bayescal.campaign.grid import Grid
from bayescal.campaign.information import Linearisation, Targets, linearise
from bayescal.campaign.search import Costs, greedy
from bayescal.errors import SpecError
from bayescal.inference.laplace import laplace, laplace_draws
from bayescal.inference.program import program_for
from bayescal.inference.start import initial_point
from bayescal.io.design import Design, load_design
from bayescal.model.assemble import build_model
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
        Every target reaches its goal.
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

    def groups(self) -> pd.DataFrame:
        """The chosen groups, one row each: the setting, the level and how many times."""
        levels = self.grid.protocol.levels
        recs = []
        for g, n in zip(self.grid.groups, self.counts):
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
        ratio = (w["design_sd"] / w["goal_sd"]).to_numpy()
        lines = []
        if self.done:
            lines.append("The campaign already meets every goal: stop measuring.")
        what = "next block" if "now_sd" in w else "design"
        lines.append(
            f"The {what} measures {self.rows} rows ({int((self.counts > 0).sum())} groups); "
            f"the protocol {'has' if 'now_sd' not in w else 'has left'} {self.protocol_rows}."
        )
        lines.append(
            "Every target reaches its goal." if self.met else f"{int((ratio > 1 + 1e-9).sum())} target(s) stay wider "
            "than their goal: raise the budget or widen the goals."
        )
        worst = w.assign(ratio=ratio).sort_values("ratio", ascending=False).head(5)
        lines.append("Widest against goal (expected posterior sd):")
        for _, r in worst.iterrows():
            lines.append(
                f"  {r['target']:<40s} {r['design_sd']:.4g} (goal {r['goal_sd']:.4g}, protocol {r['protocol_sd']:.4g})"
            )
        given_up = [c for c in self.checks if not c.supported]
        for c in given_up:
            lines.append(f"GIVES UP the {c.name} check: it needs {c.needs}.")
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
        return out


def _targets(grid: Grid, frame: pd.DataFrame, groups: np.ndarray, protocol: Design, clipped: np.ndarray) -> Targets:
    """The coefficients, and the reading at each illuminated setting of the protocol at the middle of the
    levels it measures there (a prediction at the settings the lab uses), in every channel that does not
    clip there (``clipped``: per row)."""
    per_setting: dict[tuple, list[int]] = {}
    counts = grid.counts(protocol)
    for g, n in zip(grid.groups, counts):
        if n > 0 and not g.dark:
            per_setting.setdefault(g.setting, []).append(g.level)
    rows, names = [], []
    for setting, levels in per_setting.items():
        mid = sorted(levels)[len(levels) // 2]
        k = next(i for i, g in enumerate(grid.groups) if g.setting == setting and g.level == mid)
        for r in np.flatnonzero((groups == k) & ~clipped):
            rows.append(int(r))
            names.append(f"DN[{frame['channel'].iloc[r]}] at {grid.groups[k].label(grid.protocol.levels)}")
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
    spec = _spec(spec, protocol)
    if protocol.truth is None:
        raise SpecError("design needs the nominal camera: give the protocol a [truth] table, or use --after FIT")
    grid = Grid.of(protocol)
    say(f"simulating the whole grid ({len(grid)} groups) of the nominal camera")
    from bayescal.model.simulate import simulate

    table = simulate(spec, grid.design(np.ones(len(grid), dtype=int)), seed=seed).table
    say("finding the nominal camera's mode")
    model = build_model(table, spec)
    program = program_for(model)
    mode = laplace(program, model.data, initial_point(model, program))
    if not mode.converged:
        raise SpecError("the nominal camera's simulated grid could not be fitted (its mode search did not converge)")
    points = _points(mode, draws, seed)
    groups = grid.rows_of(model.table.frame)
    say(f"linearising at {len(points)} point(s)")
    targets = _targets(grid, model.table.frame, groups, protocol, _clipped(program, model, points[0]))
    lin = linearise(program, model, points, targets, groups, len(grid))
    protocol_counts = grid.counts(protocol)
    protocol_sd = lin.sd(protocol_counts)
    goal = _goals(lin.names, protocol_sd, goal_scale, goals)
    say("choosing measurements")
    counts = _choose(
        lin, grid, np.zeros(len(grid), dtype=int), goal, protocol_counts, spec, budget_rows, setting_cost, keep_checks
    )
    sd = lin.sd(counts)
    widths = pd.DataFrame({"target": lin.names, "goal_sd": goal, "design_sd": sd, "protocol_sd": protocol_sd})
    n_ch = len(grid.channels)
    return CampaignDesign(
        design=grid.design(counts),
        grid=grid,
        counts=counts,
        widths=widths,
        rows=int(counts.sum()) * n_ch,
        protocol_rows=int(protocol_counts.sum()) * n_ch,
        checks=model_checks.checks_of(grid.groups, counts, spec.response.order, protocol_counts),
        met=bool(np.all(sd <= goal * (1 + 1e-9))),
    )


def _clipped(program, model, z: np.ndarray) -> np.ndarray:
    """Rows whose expected reading at ``z`` lies within two noise sds of the clipping threshold."""
    sites = program.constrain(np.asarray(z)[None], model.data)
    mean, sd = np.asarray(sites["row_mean"])[0], np.asarray(sites["row_sd"])[0]
    return mean + 2 * sd >= float(np.asarray(model.data.threshold))


def _spec(spec, protocol: Design) -> ModelSpec:
    if isinstance(spec, ModelSpec):
        return spec
    path = spec if spec is not None else protocol.spec
    if path is None:
        raise SpecError("no model: give a spec, or a protocol whose file names one (spec = \"...\")")
    return load_spec(path)


def _points(mode, draws: int, seed: int) -> np.ndarray:
    if draws <= 1:
        return np.asarray(mode.mode)[None]
    return np.concatenate([np.asarray(mode.mode)[None], laplace_draws(mode, draws - 1, seed)])


def _choose(
    lin: Linearisation,
    grid: Grid,
    counts: np.ndarray,
    goal: np.ndarray,
    protocol_counts: np.ndarray,
    spec: ModelSpec,
    budget_rows: float | None,
    setting_cost: float,
    keep_checks: bool,
    spent: float = 0.0,
) -> np.ndarray:
    """Greedy choice with the checks' rows kept: the cheapest repair of each check the design lacks, then
    more groups until the goals (or the budget) are met, repeated while a repair was needed."""
    costs = Costs(len(grid.channels), setting_cost)
    settings = [g.setting for g in grid.groups]
    eligible = lin.clipped < 0.5
    budget = np.inf if budget_rows is None else float(budget_rows)
    meet = budget_rows is None
    order = spec.response.order
    for _ in range(8):
        counts, spent = greedy(
            lin, counts, goal, costs, settings, eligible=eligible, budget=budget, meet=meet, spent=spent
        )
        if not keep_checks:
            break
        repairs = model_checks.missing(grid.groups, counts, order, protocol_counts)
        if not repairs:
            break
        for mask in repairs:
            counts, spent = greedy(
                lin, counts, goal, costs, settings, eligible=eligible & mask, meet=False, spent=spent, steps=1
            )
    return counts


