"""The model checks a campaign must leave possible (docs/guides/design.md, "What a cheaper design gives up").

A design chosen only for narrow intervals measures where the model is most informative and trusts the
model everywhere else.  bayescal's checks of the model need rows of their own: the misfit checks a
shape (several levels at one setting), leave-one-setting-out needs a second setting, the dark current
needs darks at two exposures at every gain measured with light, the nonlinearity's domain (output or
charge) is decided by gains swept, a temperature law by two temperatures.  Each :class:`Check` says
whether a design supports it and which group, added, would repair it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from bayescal.campaign.grid import Group

__all__ = ["Check", "checks_of", "missing"]


@dataclass(frozen=True)
class Check:
    """One of the model's checks and what it needs of a design."""

    name: str
    needs: str
    supported: bool


def _lit(groups: Sequence[Group], counts: np.ndarray) -> list[Group]:
    return [g for g, n in zip(groups, counts, strict=True) if n > 0 and not g.dark]


def _dark(groups: Sequence[Group], counts: np.ndarray) -> list[Group]:
    return [g for g, n in zip(groups, counts, strict=True) if n > 0 and g.dark]


def checks_of(groups: Sequence[Group], counts: np.ndarray, order: int, protocol: np.ndarray) -> list[Check]:
    """The checks a design (``counts`` of ``groups``) supports, for a response of ``order``; a check the
    ``protocol`` itself cannot make is not asked of the design."""
    out = []
    for name, needs, test in _RULES:
        if test(groups, protocol, order):
            out.append(Check(name, needs, bool(test(groups, counts, order))))
    return out


def missing(groups: Sequence[Group], counts: np.ndarray, order: int, protocol: np.ndarray) -> list[np.ndarray]:
    """For each check the protocol supports and the design does not, the groups any one of which,
    added, brings the design closer to it (boolean masks over the groups)."""
    out = []
    for _, _, test in _RULES:
        if test(groups, protocol, order) and not test(groups, counts, order):
            out.append(_repairs[test](groups, counts, order))
    return out


def _misfit(groups, counts, order) -> bool:
    per_setting: dict[tuple, set[int]] = {}
    for g in _lit(groups, counts):
        per_setting.setdefault(g.setting, set()).add(g.level)
    return any(len(v) >= order + 3 for v in per_setting.values())


def _fix_misfit(groups, counts, order) -> np.ndarray:
    per_setting: dict[tuple, set[int]] = {}
    for g in _lit(groups, counts):
        per_setting.setdefault(g.setting, set()).add(g.level)
    best = max(per_setting, key=lambda s: len(per_setting[s])) if per_setting else None
    pairs = zip(groups, counts, strict=True)
    return np.array([not g.dark and (best is None or g.setting == best) and n == 0 for g, n in pairs])


def _holdout(groups, counts, order) -> bool:
    return len({g.setting for g in _lit(groups, counts)}) >= 2


def _fix_holdout(groups, counts, order) -> np.ndarray:
    have = {g.setting for g in _lit(groups, counts)}
    return np.array([not g.dark and g.setting not in have for g in groups])


def _dark_current(groups, counts, order) -> bool:
    lit_gains = {g.gain for g in _lit(groups, counts)}
    dark = _dark(groups, counts)
    return all(len({d.exposure_s for d in dark if d.gain == gain}) >= 2 for gain in lit_gains)


def _fix_dark_current(groups, counts, order) -> np.ndarray:
    lit_gains = {g.gain for g in _lit(groups, counts)}
    dark = _dark(groups, counts)
    short = {gain for gain in lit_gains if len({d.exposure_s for d in dark if d.gain == gain}) < 2}
    have = {(d.gain, d.exposure_s) for d in dark}
    return np.array([g.dark and g.gain in short and (g.gain, g.exposure_s) not in have for g in groups])


def _domain(groups, counts, order) -> bool:
    return order >= 2 and len({g.gain for g in _lit(groups, counts)}) >= 2


def _fix_domain(groups, counts, order) -> np.ndarray:
    have = {g.gain for g in _lit(groups, counts)}
    return np.array([not g.dark and g.gain not in have for g in groups])


def _temperature(groups, counts, order) -> bool:
    return len({g.temperature_c for g in _lit(groups, counts) if g.temperature_c is not None}) >= 2


def _fix_temperature(groups, counts, order) -> np.ndarray:
    have = {g.temperature_c for g in _lit(groups, counts)}
    return np.array([not g.dark and g.temperature_c is not None and g.temperature_c not in have for g in groups])


_RULES = (
    ("misfit of the response's shape", "one setting at order + 3 or more levels", _misfit),
    ("leave-one-setting-out", "two or more illuminated settings", _holdout),
    ("dark current", "darks at two or more exposures at every gain measured with light", _dark_current),
    ("nonlinearity domain (output or charge)", "light at two or more gains", _domain),
    ("temperature law", "light at two or more sensor temperatures", _temperature),
)
_repairs = {
    _misfit: _fix_misfit,
    _holdout: _fix_holdout,
    _dark_current: _fix_dark_current,
    _domain: _fix_domain,
    _temperature: _fix_temperature,
}
