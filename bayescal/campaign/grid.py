"""The candidate measurements of a campaign (docs/guides/design.md).

A lab measures in *groups*: one setting (exposure, gain, TDI stages, sensor temperature) at one sphere
level, or dark, read in every channel at once (one frame series gives a row per channel).  The grid
of a protocol (:class:`~bayescal.io.design.Design`) is every setting of its illuminated blocks at every
one of its levels, and every setting of its dark blocks: the protocol is a choice of groups from it,
and so is any design bayescal proposes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
import pandas as pd

from bayescal.errors import SpecError
from bayescal.io.design import Block, Design

__all__ = ["Group", "Grid", "with_rows"]


@dataclass(frozen=True)
class Group:
    """One candidate measurement: a setting at a sphere level (``level`` indexes the design's levels; -1
    dark), read in every channel."""

    exposure_s: float
    gain: float
    tdi_stages: float
    temperature_c: float | None  # None: not recorded
    level: int

    @property
    def key(self) -> tuple:
        """Sort key: setting, then level."""
        temp = -math.inf if self.temperature_c is None else self.temperature_c
        return (self.dark, self.exposure_s, self.gain, self.tdi_stages, temp, self.level)

    @property
    def dark(self) -> bool:
        return self.level < 0

    @property
    def setting(self) -> tuple[float, float, float, float | None, bool]:
        """What the lab changes between groups (a change of setting costs time at the sphere)."""
        return (self.exposure_s, self.gain, self.tdi_stages, self.temperature_c, self.dark)

    def label(self, levels: tuple[float, ...]) -> str:
        """``0.008 s, gain 2, L05 (10)`` or ``dark 0.004 s, gain 1``."""
        temp = "" if self.temperature_c is None else f", {self.temperature_c:g} degC"
        tdi = "" if self.tdi_stages == 1 else f", {self.tdi_stages:g} stages"
        where = "dark " if self.dark else ""
        lv = "" if self.dark else f", L{self.level + 1:02d} ({levels[self.level]:g})"
        return f"{where}{self.exposure_s:g} s, gain {self.gain:g}{tdi}{temp}{lv}"


def _temps(block: Block) -> tuple[float | None, ...]:
    return tuple(block.temperature_c) if block.temperature_c else (None,)


def _groups(design: Design) -> list[Group]:
    """The design's groups in the simulator's row order, repeated where the design repeats them."""
    out: list[Group] = []
    for block in design.illuminated:
        levels = block.levels if isinstance(block.levels, tuple) else range(len(design.levels))
        for temp in _temps(block):
            for t, g, m in block.settings():
                out.extend(Group(t, g, m, temp, int(i)) for i in levels)
    for block in design.dark:
        for temp in _temps(block):
            out.extend(Group(t, g, m, temp, -1) for t, g, m in block.settings())
    return out


@dataclass(frozen=True)
class Grid:
    """Every group a campaign may measure: the protocol's illuminated settings at every level, its dark
    settings.

    Attributes
    ----------
    protocol : Design
        The design the grid was drawn from (channels, levels, frames and pixels per row, truth).
    groups : tuple of Group
        The candidates, sorted.
    """

    protocol: Design
    groups: tuple[Group, ...]

    @classmethod
    def of(cls, protocol: Design) -> Grid:
        """The grid of ``protocol``: each illuminated setting at every level, each dark setting."""
        lit = {replace(g, level=0) for g in _groups(protocol) if not g.dark}
        every = {replace(g, level=i) for g in lit for i in range(len(protocol.levels))}
        every |= {g for g in _groups(protocol) if g.dark}
        return cls(protocol, tuple(sorted(every, key=lambda g: g.key)))

    def __len__(self) -> int:
        return len(self.groups)

    @property
    def channels(self) -> tuple[str, ...]:
        return self.protocol.channels

    def index(self, group: Group) -> int:
        """Position of ``group`` in the grid."""
        try:
            return self._positions[group]
        except KeyError:
            raise SpecError(f"{group.label(self.protocol.levels)} is not in the candidate grid") from None

    @property
    def _positions(self) -> dict[Group, int]:
        return {g: i for i, g in enumerate(self.groups)}

    def counts(self, design: Design) -> np.ndarray:
        """How many times ``design`` measures each group (its levels must be the grid's)."""
        if tuple(design.levels) != tuple(self.protocol.levels):
            raise SpecError("the design's levels differ from the grid's; designs are compared on one set of levels")
        counts = np.zeros(len(self), dtype=int)
        positions = self._positions
        for g in _groups(design):
            if g not in positions:
                raise SpecError(f"the design measures {g.label(design.levels)}, which is not in the candidate grid")
            counts[positions[g]] += 1
        return counts

    def design(self, counts: np.ndarray) -> Design:
        """The :class:`~bayescal.io.design.Design` that measures group ``i`` ``counts[i]`` times (one block
        per setting, repeats listed as repeated levels), with the protocol's channels, levels, frames,
        pixels, spec and truth."""
        lit: dict[tuple, list[int]] = {}
        dark: list[Group] = []
        for g, n in zip(self.groups, np.asarray(counts, dtype=int), strict=True):
            if n <= 0:
                continue
            if g.dark:
                dark.extend([g] * int(n))
            else:
                lit.setdefault(g.setting, []).extend([g.level] * int(n))

        def temps(temp: float | None) -> tuple[float, ...] | None:
            return None if temp is None else (temp,)

        illuminated = tuple(
            Block((t,), (g,), (m,), tuple(sorted(levels)), temps(temp)) for (t, g, m, temp, _), levels in lit.items()
        )
        per_gain: dict[tuple, list[float]] = {}
        for g in dark:  # one block per gain (and stages, temperature): its exposures, repeats listed again
            per_gain.setdefault((g.gain, g.tdi_stages, g.temperature_c), []).append(g.exposure_s)
        darks = tuple(
            Block(tuple(sorted(ts)), (gain,), (m,), None, temps(temp)) for (gain, m, temp), ts in per_gain.items()
        )
        return replace(self.protocol, illuminated=illuminated, dark=darks)

    def rows_of(self, frame: pd.DataFrame) -> np.ndarray:
        """The group of every row of a table ``frame`` (simulated from this grid's design or measured at
        its settings): its position in the grid, -1 where the row is at no grid group."""
        levels = np.asarray(self.protocol.levels, dtype=float)
        stim = frame["stimulus"].to_numpy(dtype=float)
        temp = frame["temperature_c"].to_numpy(dtype=float) if "temperature_c" in frame else np.full(len(frame), np.nan)
        positions = self._positions
        out = np.full(len(frame), -1)
        cols = zip(frame["exposure_s"], frame["gain"], frame["tdi_stages"], temp, stim, strict=True)
        for r, (t, g, m, tc, s) in enumerate(cols):
            if s == 0:
                level = -1
            else:
                near = np.flatnonzero(np.isclose(levels, s, rtol=1e-9, atol=0))
                if not near.size:
                    continue
                level = int(near[0])
            group = Group(float(t), float(g), float(m), None if np.isnan(tc) else float(tc), level)
            out[r] = positions.get(group, -1)
        return out


def with_rows(frame: pd.DataFrame, rows: pd.DataFrame) -> pd.DataFrame:
    """A fit's measured table with rows to predict appended (a grid's placeholders), the columns the
    placeholders lack filled as the measured rows imply: replicate 0, the session's last ``time_s``, the
    levels' median ``radiance_u_rel``.  The measured rows come first."""
    union = pd.concat([frame, rows], ignore_index=True)
    fills = {"replicate": 0.0, "time_s": frame.get("time_s", pd.Series([0.0])).max()}
    if "radiance_u_rel" in frame:
        fills["radiance_u_rel"] = frame["radiance_u_rel"].median()
    return union.fillna({k: v for k, v in fills.items() if k in union})
