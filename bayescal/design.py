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
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .errors import SpecError
from .spec import check_keys

__all__ = ["Design", "Block", "Truth", "load_design"]


@dataclass(frozen=True)
class Block:
    """A set of settings measured together (full factorial within the block)."""

    exposure_s: tuple[float, ...]
    gain: tuple[float, ...] = (1.0,)
    tdi_stages: tuple[float, ...] = (1.0,)
    levels: tuple[int, ...] | None = None  # indices into Design.levels; None: all
    temperature_c: tuple[float, ...] | None = None  # sensor temperatures (None: not recorded)

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
    sphere_scale : float or None
        True/nominal radiance scale; None draws ``exp(N(0, common_rel))``.
    level_rel : float
        Standard deviation of the per-level relative errors drawn.
    """

    response: dict[str, tuple[float, ...]]
    dark_offset: dict[float, float]
    dark_slope: dict[float, float] = field(default_factory=dict)
    dark_proportional: bool = False
    channel_offset: dict[str, float] = field(default_factory=dict)
    read_noise_dn: float = 2.0
    conversion_gain: float = 0.1
    excess_dn: float = 0.0
    prnu: float = 0.01
    sphere_scale: float | None = None
    common_rel: float = 0.03
    level_rel: float = 0.0
    dark_doubling_c: float | None = None  # dark current doubles every this many degC (None: no T effect)
    temperature_ref_c: float = 20.0

    @classmethod
    def from_dict(cls, d: dict[str, Any], source: str = "<truth>") -> Truth:
        """Parse the ``[truth]`` table (gain keys may be strings)."""
        d = dict(d)
        known = set(cls.__dataclass_fields__)
        unknown = set(d) - known
        if unknown:
            raise SpecError(f"{source}: unknown [truth] key(s) {sorted(unknown)}; expected {sorted(known)}")
        try:
            d["response"] = {str(k): tuple(float(x) for x in v) for k, v in d["response"].items()}
            d["dark_offset"] = {float(k): float(v) for k, v in d["dark_offset"].items()}
            d["dark_slope"] = {float(k): float(v) for k, v in d.get("dark_slope", {}).items()}
            d["channel_offset"] = {str(k): float(v) for k, v in d.get("channel_offset", {}).items()}
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            raise SpecError(f"{source}: malformed [truth] table: {exc}") from exc
        return cls(**d)


@dataclass(frozen=True)
class Design:
    """What is measured: channels, sphere levels, settings blocks and dark settings."""

    channels: tuple[str, ...]
    levels: tuple[float, ...]
    illuminated: tuple[Block, ...]
    dark: tuple[Block, ...] = ()
    n_frames: int = 1
    n_pixels: int = 1
    spec: str | None = None
    truth: Truth | None = None

    @classmethod
    def from_dict(cls, d: dict[str, Any], source: str = "<design>") -> Design:
        """Parse the TOML layout (see ``models/seed000_design.toml``)."""
        check_keys(d, {f.name for f in dataclasses.fields(cls)}, source)
        try:
            blocks = tuple(_block(b, source, f"illuminated[{i}].") for i, b in enumerate(d["illuminated"]))
            dark = tuple(_block(b, source, f"dark[{i}].") for i, b in enumerate(d.get("dark", [])))
            truth = Truth.from_dict(d["truth"], source) if "truth" in d else None
            design = cls(
                channels=tuple(d["channels"]),
                levels=tuple(float(v) for v in d["levels"]),
                illuminated=blocks,
                dark=dark,
                n_frames=int(d.get("n_frames", 1)),
                n_pixels=int(d.get("n_pixels", 1)),
                spec=d.get("spec"),
                truth=truth,
            )
        except KeyError as exc:
            raise SpecError(f"{source}: missing design key {exc}") from exc
        except (TypeError, ValueError, AttributeError) as exc:
            raise SpecError(f"{source}: malformed design: {exc}") from None
        if design.n_frames < 1 or design.n_pixels < 1:
            raise SpecError(f"{source}: n_frames and n_pixels must be >= 1")
        for block in design.illuminated:
            for i in block.levels or ():
                if not 0 <= i < len(design.levels):
                    raise SpecError(f"{source}: level index {i} outside 0..{len(design.levels) - 1}")
        return design


def _block(b: dict[str, Any], source: str, prefix: str) -> Block:
    if not isinstance(b, dict):
        raise SpecError(f"{source}: [{prefix.rstrip('.')}] must be a table")
    check_keys(b, {"exposure_s", "gain", "tdi_stages", "levels", "temperature_c"}, source, prefix)

    def floats(key: str, default: tuple[float, ...]) -> tuple[float, ...]:
        v = b.get(key, default)
        return tuple(float(x) for x in (v if isinstance(v, (list, tuple)) else [v]))

    levels = b.get("levels", "all")
    return Block(
        exposure_s=floats("exposure_s", ()),
        gain=floats("gain", (1.0,)),
        tdi_stages=floats("tdi_stages", (1.0,)),
        levels=None if levels == "all" else tuple(int(i) for i in levels),
        temperature_c=floats("temperature_c", ()) or None,
    )


def load_design(path: str | os.PathLike) -> Design:
    """Load a :class:`Design` (with optional truth) from TOML."""
    from .io import read_text

    path = Path(path)
    try:
        data = tomllib.loads(read_text(path, SpecError, "design (TOML)"))
    except tomllib.TOMLDecodeError as exc:
        raise SpecError(f"{path}: invalid TOML: {exc}") from exc
    design = Design.from_dict(data, source=str(path))
    if design.spec is not None and not Path(design.spec).is_absolute():
        design = Design(**{**design.__dict__, "spec": str(path.parent / design.spec)})
    return design
