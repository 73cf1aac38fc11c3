"""Shared prior shapes."""

from __future__ import annotations

__all__ = ["scale_prior"]


def scale_prior(scale: float):
    """Boundary-avoiding prior for a pooling scale: Gamma(2, 2/scale), mean ``scale``.

    A half-normal puts its mode at zero, where the joint density of a
    hierarchical model is unbounded (the funnel): MAP collapses there and
    NUTS diverges.  A Gamma(2) density vanishes at zero, keeping the mode
    interior (Chung et al. 2013, Psychometrika 78:685).
    """
    import numpyro.distributions as dist

    return dist.Gamma(2.0, 2.0 / scale)
