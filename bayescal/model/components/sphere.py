"""Integrating-sphere radiance errors: common scale (folded in) and per-level errors.

Physics: seed 002 section 4.3 (sphere uncertainty below 3 %), docs/architecture.md
section 2.  Every channel and setting at one sphere level sees the same
level error, so the errors are shared across channels and sampled
non-centred.  The common scale multiplies every stimulus and is exactly
degenerate with the gains: it is not sampled but folded in afterwards
(:func:`fold_common_scale`), exact for a response whose prior is flat on the
data's scale (docs/architecture.md, section 4).
"""

from __future__ import annotations

from dataclasses import dataclass

import jax.numpy as jnp
import numpy as np
import numpyro
import numpyro.distributions as dist

from bayescal.model.spec import SphereSpec

__all__ = ["Sphere", "fold_common_scale"]


@dataclass(frozen=True)
class Sphere:
    """Per-level multiplicative stimulus errors ``1 + sigma_l z_l`` (none when disabled)."""

    spec: SphereSpec
    n_levels: int
    per_level: bool

    def sample(self, data) -> jnp.ndarray | float:
        """Per-row stimulus multiplier (dark rows and disabled component: 1)."""
        if not self.per_level or self.n_levels == 0:
            return 1.0
        z = numpyro.sample("level_z", dist.Normal(0.0, 1.0).expand([self.n_levels]).to_event(1))
        err = jnp.concatenate([data.level_sigma * z, jnp.zeros(1)])
        return 1.0 + err[data.level]

    def physical(self, draws: dict[str, np.ndarray], level_sigma: np.ndarray) -> dict[str, np.ndarray]:
        """Relative error of each level's stimulus reading."""
        if "level_z" not in draws:
            return {}
        return {"level_error": draws["level_z"] * level_sigma}


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
