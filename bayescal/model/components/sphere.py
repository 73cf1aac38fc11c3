"""Integrating-sphere radiance errors: common scale (folded in) and per-level errors.

Physics: seed 002 section 4.3 (sphere uncertainty below 3 %), docs/architecture.md section 2.
Every channel and setting at one sphere level sees the same level error, so the errors are
shared across channels and sampled non-centred: the stimulus a level delivers is its reading
times ``1 + e_level`` (:meth:`Sphere.factor`).  The common scale multiplies every stimulus and
is exactly degenerate with the gains: it is not sampled but folded in afterwards
(:func:`fold_common_scale`), exact for a response whose prior is flat on the data's scale
(docs/architecture.md, section 4).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from bayescal.model.components.base import Nuisance, StimulusFactor

__all__ = ["Sphere", "SphereSpec", "fold_common_scale"]


@dataclass(frozen=True)
class SphereSpec:
    """Integrating-sphere radiance uncertainty (seed 002 section 4.3: below 3 %).

    ``common_rel``: relative standard uncertainty of the sphere's scale,
    common to every level; it is exactly degenerate with the gains and is
    folded in after fitting (docs/architecture.md, section 4).  ``per_level_rel``:
    relative standard uncertainty of each level's reading, shared by all
    channels and settings at that level, sampled non-centred (0 turns it off;
    a ``radiance_u_rel`` column overrides it per level).  ``channel_level_rel``:
    relative sd of each level's error in each channel on top of the shared one
    (a lamp whose spectrum changes with its level: the channels see different
    errors), sampled non-centred; 0 turns it off.  ``channel_scale_rel``:
    relative sd of each channel's own scale error (the lamp's spectrum differs
    from the one its calibration assumed), degenerate with that channel's gain
    like the common scale, and folded in the same way.
    """

    common_rel: float = 0.03
    per_level_rel: float = 0.0
    channel_level_rel: float = 0.0
    channel_scale_rel: float = 0.0


@dataclass(frozen=True)
class Sphere(StimulusFactor):
    """Per-level multiplicative stimulus errors ``1 + sigma_l z_l`` (none when disabled)."""

    section = "sphere"
    role = "factor"
    sites = {"level_z": ("level",), "level_w": ("level", "channel")}
    reported = {"level_error": ("level",), "level_channel_error": ("level", "channel"), "sphere_scale": ()}

    spec: SphereSpec
    n_levels: int
    per_level: bool
    n_channels: int = 1

    @staticmethod
    def factor(level_error):
        """The stimulus a level delivers, relative to its reading: ``1 + e_level``."""
        return 1.0 + level_error

    @property
    def per_channel(self) -> bool:
        """Level errors that differ by channel are sampled."""
        return self.spec.channel_level_rel > 0 and self.n_levels > 0

    def sample(self, data):
        """Per-row stimulus multiplier (dark rows and disabled component: 1)."""
        if (not self.per_level and not self.per_channel) or self.n_levels == 0:
            return 1.0
        import jax.numpy as jnp
        import numpyro
        import numpyro.distributions as dist

        err: Any = 0.0
        if self.per_level:
            z = numpyro.sample("level_z", dist.Normal(0.0, 1.0).expand([self.n_levels]).to_event(1))
            err = jnp.concatenate([data.level_sigma * z, jnp.zeros(1)])[data.level]
        if self.per_channel:
            shape = [self.n_levels, self.n_channels]
            w = numpyro.sample("level_w", dist.Normal(0.0, 1.0).expand(shape).to_event(2))
            w = jnp.concatenate([self.spec.channel_level_rel * w, jnp.zeros((1, self.n_channels))])
            err = err + w[data.level, data.channel]
        return self.factor(err)

    def nuisances(self, level_sigma) -> dict[str, Nuisance]:
        """The level errors (standard normal, non-centred), each as a fraction of its level's stimulus."""
        out = {}
        if self.per_level and self.n_levels:
            sigma = np.asarray(level_sigma, dtype=float)[: self.n_levels]
            out["level_z"] = Nuisance(1.0, "the radiance error of sphere level {}", ("level",), sigma)
        if self.per_channel:
            out["level_w"] = Nuisance(
                1.0, "the lamp's error at level {} (per channel)", ("level", "channel"), self.spec.channel_level_rel
            )
        return out

    def describe(self) -> str:
        return (
            f"sphere: common {self.spec.common_rel:.1%} folded in"
            + (f", {self.n_levels} level errors" if self.per_level else "")
            + (f", per-channel level errors {self.spec.channel_level_rel:.1%}" if self.per_channel else "")
        )

    def physical(self, draws, ctx) -> dict[str, np.ndarray]:
        """Relative error of each level's stimulus reading (the common scale: :func:`fold_common_scale`)."""
        out = {}
        if "level_z" in draws:
            out["level_error"] = draws["level_z"] * ctx.level_sigma
        if "level_w" in draws:
            out["level_channel_error"] = draws["level_w"] * self.spec.channel_level_rel
        return out


def fold_common_scale(
    coef_rel: np.ndarray, common_rel: float, rng: np.random.Generator, channel_rel: float = 0.0
) -> tuple[np.ndarray, np.ndarray]:
    """Fold the sphere's common scale into monomial coefficients.

    The fit sees ``f_rel(L_nominal) = f_abs(s L_nominal)``, so
    ``A_abs[k] = A_rel[k] / s^k`` with ``log s ~ Normal(0, common_rel)``
    drawn independently for every posterior draw (the data carry no
    information about ``s``).

    Parameters
    ----------
    coef_rel : array (..., p + 1)
        Coefficients relative to the sphere's scale, leading dims are draws.
    common_rel : float
        Relative standard uncertainty of the sphere scale (0: none).
    rng : numpy.random.Generator
        Source of the scale draws (seeded by the caller).
    channel_rel : float
        Relative standard uncertainty of each channel's own scale (the third axis of
        ``coef_rel``), drawn independently per channel and draw (0: none).

    Returns
    -------
    coef_abs, scale : arrays
        Absolute coefficients and the scale draws (shape ``coef_rel.shape[:-1]``
        without trailing non-draw dims).
    """
    draw_shape = coef_rel.shape[:2]
    scale = np.exp(common_rel * rng.standard_normal(draw_shape)) if common_rel > 0 else np.ones(draw_shape)
    powers = np.arange(coef_rel.shape[-1])
    extra = coef_rel.ndim - 3
    s = scale.reshape(draw_shape + (1,) * extra + (1,))
    if channel_rel > 0 and extra >= 1:
        own = np.exp(channel_rel * rng.standard_normal(draw_shape + coef_rel.shape[2:3]))
        s = s * own.reshape(own.shape + (1,) * extra)
    return coef_rel / s**powers, scale
