"""Scatter in proportion to the signal: a source or shutter that does not repeat exactly from one
measurement to the next.

Physics: a lamp that flickers, an integrating sphere whose output wanders between rows, or a shutter
whose exposure jitters, changes each row's signal by a small fraction of itself, the same fraction for
every pixel averaged into the row (so averaging pixels does not shrink it).  Its lowest-order form adds
to a reading's variance::

    var_scatter = (f S)^2

with ``S`` the row's signal and ``f`` the relative scatter, one for the camera (the source is shared by
every channel).  The excess scatter of :class:`~bayescal.model.components.noise.Noise` is constant in
DN: against a scatter that grows with the signal it is too wide for the dark and faint rows and too
narrow near full scale, where it under-weights the rows that pin the nonlinearity.

Off by default (``[scatter] enabled = true``).  Prior: ``f ~ HalfNormal(prior_rel)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bayescal.errors import SpecError
from bayescal.model.components.base import NoiseEffect

__all__ = ["RelativeScatter", "RelativeScatterSpec", "ScatterTerm"]


@dataclass(frozen=True)
class RelativeScatterSpec:
    """``[scatter]``: a reading's scatter ``f S`` in proportion to its signal.

    ``enabled``: fit it.  ``prior_rel``: the half-normal prior scale of ``f`` (a fraction of the signal).
    """

    enabled: bool = False
    prior_rel: float = 0.01

    def __post_init__(self) -> None:
        if not self.prior_rel > 0:
            raise SpecError("scatter.prior_rel must be > 0 (a fraction of the signal, e.g. 0.01)")


@dataclass(frozen=True)
class RelativeScatter(NoiseEffect):
    """``(f S)^2`` added to the variance of every reading."""

    section = "scatter"
    spec_class = RelativeScatterSpec
    sites = {"scatter_rel": ()}
    reported = {"scatter_rel": ()}

    spec: RelativeScatterSpec

    @staticmethod
    def forward(relative, signal, xp=np):
        """The variance ``(f max(S, 0))^2`` at signal ``S`` (any units: the variance is in their square)."""
        return (relative * xp.maximum(signal, 0.0)) ** 2

    @classmethod
    def build(cls, section: RelativeScatterSpec, spec, frame) -> RelativeScatter | None:
        return cls(section) if section.enabled else None

    def variance(self, data, signal):
        import jax.numpy as jnp
        import numpyro
        import numpyro.distributions as dist

        relative = numpyro.sample("scatter_rel", dist.HalfNormal(self.spec.prior_rel))
        return self.forward(relative, signal, jnp)

    def describe(self) -> str:
        return f"noise: scatter in proportion to the signal (prior scale {self.spec.prior_rel:g})"

    def physical(self, draws, ctx) -> dict[str, np.ndarray]:
        return {"scatter_rel": draws["scatter_rel"]}

    @classmethod
    def term(cls, section: RelativeScatterSpec, spec, draws, frame) -> ScatterTerm | None:
        if "scatter_rel" not in draws:
            return None
        return ScatterTerm(np.asarray(draws["scatter_rel"], dtype=float).reshape(-1))

    @classmethod
    def truth(cls, params, rows, spec) -> np.ndarray:
        """``params``: ``relative``, the fraction ``f`` of the signal."""
        if set(params) - {"relative"}:
            raise SpecError(f"[truth.effects.scatter] keys {sorted(set(params) - {'relative'})}; expected ['relative']")
        return cls.forward(float(params.get("relative", 0.0)), rows["signal_dn"].to_numpy(dtype=float))


@dataclass(frozen=True)
class ScatterTerm:
    """The relative scatter's posterior ``(S,)`` as predictions use it."""

    relative: np.ndarray

    def variance(self, channel, setting, signal: np.ndarray) -> np.ndarray:
        """``(f S)^2`` per draw (``signal`` with the draws on its first axis)."""
        signal = np.asarray(signal, dtype=float)
        return RelativeScatter.forward(self.relative.reshape((-1,) + (1,) * (signal.ndim - 1)), signal)

    def flags(self, setting) -> list[str]:
        return []
