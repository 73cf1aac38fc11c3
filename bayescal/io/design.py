"""Experiment designs and simulation truths (TOML in ``models/``).

A design lists what a lab measures: sphere levels, the exposure/gain/TDI
combinations at which they are measured (seed 000 Fig. 3), dark settings, and
how many frames and pixels are averaged per row (seed 000: 20 frames).  The
``[truth]`` table describes a camera for :func:`bayescal.simulate`.
"""

from __future__ import annotations

import dataclasses
import itertools
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from bayescal.errors import SpecError
from bayescal.io.toml import build, read_toml

__all__ = ["Design", "Block", "Truth", "load_design", "design_toml"]


@dataclass(frozen=True)
class Block:
    """A set of settings measured together (full factorial within the block)."""

    exposure_s: tuple[float, ...]
    gain: tuple[float, ...] = (1.0,)
    tdi_stages: tuple[float, ...] = (1.0,)
    levels: tuple[int, ...] | Literal["all"] | None = None  # indices into Design.levels; None or "all": all
    temperature_c: tuple[float, ...] | None = None  # sensor temperatures (None: not recorded)

    def __post_init__(self) -> None:
        if self.levels == "all":
            object.__setattr__(self, "levels", None)
        if not self.exposure_s:
            raise SpecError("a block needs at least one exposure_s")
        if not self.temperature_c:
            object.__setattr__(self, "temperature_c", None)
        for key in ("exposure_s", "gain", "tdi_stages", "temperature_c"):
            _within(getattr(self, key) or (), key, key)

    def settings(self) -> list[tuple[float, float, float]]:
        """Every (exposure, gain, tdi) combination of the block."""
        return list(itertools.product(self.exposure_s, self.gain, self.tdi_stages))


@dataclass(frozen=True)
class Truth:
    """A camera with known parameters, for simulation.

    Attributes
    ----------
    response : dict
        Channel -> ``[A1, ..., Ap]``: monomial coefficients of the signal (DN)
        in the *true* stimulus at the spec's reference setting.
    dark_offset : dict
        Gain factor -> offset in DN at zero exposure (for a proportional dark
        model, the offset at the reference gain under key of that gain).
    dark_slope : dict
        Gain factor -> dark slope in DN/s (missing gains: 0).
    dark_proportional : bool
        Offsets scale with gain / reference gain (seed 002 eq. 12).
    channel_offset : dict
        Channel -> extra offset in DN (seed 000: small).
    channel_dark_slope : dict
        Channel -> extra dark slope in DN/s (a channel read through its own output).
    sphere_scale : float or None
        True/nominal radiance scale; None draws ``exp(N(0, common_rel))``.
    level_rel : float
        Standard deviation of the per-level relative errors drawn.
    effects : dict
        Optional effect (spec section name) -> its true parameters, read by the effect's
        ``truth`` (``[truth.effects.responsivity] coefficient_per_c = 0.003``).

    Examples
    --------
    >>> import bayescal as bc
    >>> truth = bc.load_design("seed000").truth
    >>> truth.response["G"]  # A1 (DN per W m^-2 sr^-1) and A2 of the simulated camera's green channel
    (30.18, -0.003)
    """

    response: dict[str, tuple[float, ...]]
    dark_offset: dict[float, float]
    dark_slope: dict[float, float] = field(default_factory=dict)
    dark_proportional: bool = False
    channel_offset: dict[str, float] = field(default_factory=dict)
    channel_dark_slope: dict[str, float] = field(default_factory=dict)
    read_noise_dn: float = 2.0
    conversion_gain: float = 0.1
    excess_dn: float = 0.0
    prnu: float = 0.01
    sphere_scale: float | None = None
    common_rel: float = 0.03
    level_rel: float = 0.0
    dark_doubling_c: float | None = None  # dark current doubles every this many degC (None: no T effect)
    temperature_ref_c: float = 20.0
    effects: dict[str, dict[str, Any]] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for key, limit in _TRUTH_LIMITS.items():
            value = getattr(self, key)
            if isinstance(value, dict):
                for k, v in value.items():
                    _within(tuple(v) if isinstance(v, tuple | list) else (v,), limit, f"truth.{key}.{k}")
            elif value is not None:
                _within((value,), limit, f"truth.{key}")


#: the physical limit (:data:`bayescal.io.limits.LIMITS`) of each number of a simulation's truth
_TRUTH_LIMITS = {
    "response": "finite",
    "dark_offset": "signal_dn",
    "dark_slope": "finite",
    "channel_offset": "signal_dn",
    "channel_dark_slope": "finite",
    "read_noise_dn": "noise_dn",
    "conversion_gain": "positive",
    "excess_dn": "noise_dn",
    "prnu": "relative_sd",
    "sphere_scale": "positive",
    "common_rel": "relative_sd",
    "level_rel": "relative_sd",
    "dark_doubling_c": "doubling_c",
    "temperature_ref_c": "temperature_c",
}


def _within(values, limit: str, key: str) -> None:
    """Each of ``values`` within the physical limit ``limit``; else :class:`SpecError` naming ``key``."""
    from bayescal.io.limits import check_value

    for i, v in enumerate(values):
        check_value(v, limit, key if len(values) == 1 else f"{key}[{i}]")


@dataclass(frozen=True)
class Design:
    """What is measured: channels, sphere levels, settings blocks and dark settings.

    Examples
    --------
    >>> import bayescal as bc
    >>> design = bc.load_design("seed000")  # the seed 000 Bayer CCD's campaign
    >>> design.channels, len(design.levels)
    (('R', 'G', 'B'), 12)
    """

    channels: tuple[str, ...]
    levels: tuple[float, ...]
    illuminated: tuple[Block, ...]
    dark: tuple[Block, ...] = ()
    n_frames: int = 1
    n_pixels: int = 1
    spec: str | None = None
    truth: Truth | None = None

    def __post_init__(self) -> None:
        if not self.channels or not self.levels:
            raise SpecError("a design needs channels and levels")
        if self.n_frames < 1 or self.n_pixels < 1:
            raise SpecError("n_frames and n_pixels must be >= 1")
        _within(self.levels, "stimulus", "levels")
        if not all(level > 0 for level in self.levels):
            raise SpecError(f"levels = {list(self.levels)}; expected sphere levels above 0 (darks are [[dark]] blocks)")
        for block in self.illuminated:
            for i in block.levels if isinstance(block.levels, tuple) else ():
                if not 0 <= i < len(self.levels):
                    raise SpecError(f"level index {i} outside 0..{len(self.levels) - 1}")

    @classmethod
    def from_dict(cls, d: dict[str, Any], source: str = "<design>") -> Design:
        """Parse the TOML layout (see ``models/seed000_design.toml``); every key is checked."""
        return build(cls, d, source)


def load_design(path: str | os.PathLike) -> Design:
    """Load a :class:`Design` (with optional truth) from TOML; ``path`` may also name a shipped design
    (``"seed000"``: :func:`bayescal.io.resources.example_path`).

    Examples
    --------
    >>> import bayescal as bc
    >>> design = bc.load_design("seed000")  # the seed-000 campaign: 12 sphere levels
    >>> len(design.levels), design.levels[:3]
    (12, (1.5, 3.0, 5.0279))
    """
    from bayescal.io.resources import example_path

    path = example_path(path, "design")
    design = Design.from_dict(read_toml(path, "design (TOML)"), source=str(path))
    if design.spec is not None and not Path(design.spec).is_absolute():
        design = dataclasses.replace(design, spec=str(path.parent / design.spec))
    return design


def design_toml(design: Design, spec: str | None = None) -> str:
    """``design`` as the TOML :func:`load_design` reads, one line per key, one table per block (the
    truth's dict keys as strings); ``spec`` replaces the path of its model (written relative to the
    file's folder)."""
    import json

    def value(v: Any) -> str:
        if isinstance(v, dict):
            return "{ " + ", ".join(f"{json.dumps(str(k))} = {value(x)}" for k, x in v.items()) + " }"
        if isinstance(v, (list, tuple)):
            return "[" + ", ".join(value(x) for x in v) + "]"
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, str):
            return json.dumps(v)
        return repr(float(v)) if isinstance(v, float) else str(v)

    def table(items: dict[str, Any]) -> list[str]:
        return [f"{k} = {value(v)}" for k, v in items.items() if v is not None and v != {}]

    lines = table(
        {
            "spec": spec if spec is not None else design.spec,
            "channels": design.channels,
            "levels": design.levels,
            "n_frames": design.n_frames,
            "n_pixels": design.n_pixels,
        }
    )
    for kind, blocks in (("illuminated", design.illuminated), ("dark", design.dark)):
        for b in blocks:
            lines += ["", f"[[{kind}]]", *table(dataclasses.asdict(b))]
    if design.truth is not None:
        lines += ["", "[truth]", *table(dataclasses.asdict(design.truth))]
    return "\n".join(lines) + "\n"
