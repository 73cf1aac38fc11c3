"""A black level that jitters from frame to frame, the same in every channel of one frame.

Physics: a camera's black-level clamp (or its bias supply) settles a little differently at every readout,
so each frame carries an offset ``o_f`` in DN that every channel of that frame shares, dark or lit::

    DN_row = ... + o_f(row),   o_f ~ Normal(0, sd)

A fixed model takes it for scatter of each row on its own, yet the residuals of one frame's channels move
together (:func:`bayescal.fitting.misfit.frame_correlation`), and a drift over the measurement order does
not draw it (the frames' offsets are independent).  Each frame's offset is sampled with the prior
``Normal(0, prior_dn)``; their spread ``sd`` is learned afterwards, per posterior draw, by the conjugate
update of ``o_f ~ Normal(0, sd)`` with an inverse-gamma prior of mean ``prior_dn^2`` (as the settings'
spreads, :mod:`.settings`): sampling ``sd`` jointly makes a funnel that the Laplace approximation cannot
describe (79 % of its draws fell where the likelihood is far lower than its Gaussian allowed, and the spread
came out 4-5 DN where it was 1-2).  The offsets' mean is not told from the dark level's by any table; their
prior carries that doubt into ``A0`` (``prior_dn / sqrt(frames)``).  In predictions a new frame draws its
own offset from the spread, so the predictive intervals of a single reading carry it.

A frame is a set of rows taken at once: those with one ``time_s`` where the table records times, else
those that share every setting, the sphere level and the repeat (``rep``).  Off by default
(``[frame_offset] enabled = true``); the diagnosis offers it where frames hold two or more channels.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass

import numpy as np
import pandas as pd

from bayescal.errors import SpecError
from bayescal.model.components.base import OffsetEffect
from bayescal.model.components.settings import SPREAD_PRIOR_SHAPE

__all__ = ["FrameOffset", "FrameOffsetSpec", "FrameOffsetTerm", "frame_index"]

#: its per-row input in ``ModelData.extra``: the index of the row's frame
INPUT = "frame_offset.frame"
#: what identifies the frame of a row without ``time_s``: the columns of its setting, level and repeat
_FRAME_KEYS = ("stimulus", "level", "exposure_s", "gain", "tdi_stages", "temperature_c", "rep")


def frame_index(frame: pd.DataFrame) -> np.ndarray:
    """The frame each row of a table belongs to (0, 1, ... in order of appearance)."""
    keys = ["time_s"] if "time_s" in frame and frame["time_s"].nunique() > 1 else [k for k in _FRAME_KEYS if k in frame]
    return frame.groupby(keys, sort=False, dropna=False).ngroup().to_numpy()


@dataclass(frozen=True)
class FrameOffsetSpec:
    """``[frame_offset]``: an offset per frame, shared by its channels.

    ``enabled``: fit it.  ``prior_dn``: the prior sd of each frame's offset (and the prior mean of their
    spread), DN.
    """

    enabled: bool = False
    prior_dn: float = 2.0

    def __post_init__(self) -> None:
        if not self.prior_dn > 0:
            raise SpecError("frame_offset.prior_dn must be > 0")


@dataclass(frozen=True)
class FrameOffset(OffsetEffect):
    """``o_f`` DN added to every row of frame ``f``."""

    section = "frame_offset"
    spec_class = FrameOffsetSpec
    sites = {"frame_z": ("frame",)}
    reported = {"frame_offset_sd_dn": ()}

    spec: FrameOffsetSpec
    n_frames: int

    @classmethod
    def build(cls, section: FrameOffsetSpec, spec, frame) -> FrameOffset | None:
        if not section.enabled:
            return None
        return cls(section, int(frame_index(frame).max()) + 1)

    @classmethod
    def candidates(cls, section: FrameOffsetSpec, spec, frame) -> dict[str, dict]:
        """Offered where eight or more frames hold two or more channels each."""
        if section.enabled:
            return {}
        sizes = np.bincount(frame_index(frame))
        if (sizes >= 2).sum() < 8:
            return {}
        name = "a black level that jitters from frame to frame, the same in the channels of one frame"
        return {name: {"frame_offset": {"enabled": True}}}

    def inputs(self, frame) -> dict[str, np.ndarray]:
        return {INPUT: frame_index(frame).astype(float)}

    def coords(self) -> dict[str, list]:
        return {"frame": list(range(self.n_frames))}

    def sample(self, data):
        import jax.numpy as jnp
        import numpyro
        import numpyro.distributions as dist

        z = numpyro.sample("frame_z", dist.Normal(0.0, 1.0).expand([self.n_frames]).to_event(1))
        return self.spec.prior_dn * z[data.extra[INPUT].astype(jnp.int32)]

    def describe(self) -> str:
        return f"offset: a black level per frame ({self.n_frames} frames), shared by its channels"

    def physical(self, draws, ctx) -> dict[str, np.ndarray]:
        """The offsets' spread per draw: ``sd^2 ~ InvGamma(2 + n / 2, prior_dn^2 + sum(o_f^2) / 2)``."""
        offsets = self.spec.prior_dn * np.asarray(draws["frame_z"], dtype=float)
        shape = SPREAD_PRIOR_SHAPE + 0.5 * offsets.shape[-1]
        rate = self.spec.prior_dn**2 * (SPREAD_PRIOR_SHAPE - 1) + 0.5 * np.sum(offsets**2, axis=-1)
        return {"frame_offset_sd_dn": np.sqrt(rate / ctx.rng(0xF4A3E).gamma(shape, 1.0, size=rate.shape))}

    @classmethod
    def term(cls, section: FrameOffsetSpec, spec, draws, frame) -> FrameOffsetTerm | None:
        if "frame_offset_sd_dn" not in draws:
            return None
        return FrameOffsetTerm(np.asarray(draws["frame_offset_sd_dn"], dtype=float).ravel())


@dataclass(frozen=True)
class FrameOffsetTerm:
    """The spread's posterior ``(S,)``: a new frame draws its own offset."""

    sd: np.ndarray

    def offset(self, channel, setting, n_draws: int) -> np.ndarray:
        """A new frame's offset per draw, ``sd z`` (the same normals on every call: seeded)."""
        rng = np.random.default_rng(zlib.crc32(b"frame_offset"))
        sd = self.sd if self.sd.size == n_draws else np.resize(self.sd, n_draws)
        return sd * rng.standard_normal(n_draws)

    def flags(self, setting) -> list[str]:
        return []
