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

import numpy as np

from bayescal.model.components.base import StimulusFactor

__all__ = ["Sphere", "SphereSpec", "fold_common_scale"]


@dataclass(frozen=True)
class SphereSpec:
    """Integrating-sphere radiance uncertainty (seed 002 section 4.3: below 3 %).

    ``common_rel``: relative standard uncertainty of the sphere's scale,
    common to every level; it is exactly degenerate with the gains and is
    folded in after fitting (docs/architecture.md, section 4).  ``per_level_rel``:
    relative standard uncertainty of each level's reading, shared by all
    channels and settings at that level, sampled non-centred (0 turns it off;
    a ``radiance_u_rel`` column overrides it per level).
    """

    common_rel: float = 0.03
    per_level_rel: float = 0.0


@dataclass(frozen=True)
class Sphere(StimulusFactor):
    """Per-level multiplicative stimulus errors ``1 + sigma_l z_l`` (none when disabled)."""

    section = "sphere"
    sites = {"level_z": ("level",)}
    reported = {"level_error": ("level",), "sphere_scale": ()}

    spec: SphereSpec
    n_levels: int
    per_level: bool

    @staticmethod
    def factor(level_error):
        """The stimulus a level delivers, relative to its reading: ``1 + e_level``."""
        return 1.0 + level_error

    def sample(self, data):
        """Per-row stimulus multiplier (dark rows and disabled component: 1)."""
        if not self.per_level or self.n_levels == 0:
            return 1.0
        import jax.numpy as jnp
        import numpyro
        import numpyro.distributions as dist

        z = numpyro.sample("level_z", dist.Normal(0.0, 1.0).expand([self.n_levels]).to_event(1))
        err = jnp.concatenate([data.level_sigma * z, jnp.zeros(1)])
        return self.factor(err[data.level])

    def describe(self) -> str:
        return f"sphere: common {self.spec.common_rel:.1%} folded in" + (
            f", {self.n_levels} level errors" if self.per_level else ""
        )

    def physical(self, draws, ctx) -> dict[str, np.ndarray]:
        """Relative error of each level's stimulus reading (the common scale: :func:`fold_common_scale`)."""
        if "level_z" not in draws:
            return {}
        return {"level_error": draws["level_z"] * ctx.level_sigma}


def fold_common_scale(
    coef_rel: np.ndarray, common_rel: float, rng: np.random.Generator
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
    return coef_rel / s**powers, scale
