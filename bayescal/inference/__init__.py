"""Inference backends and solvers; every one computes in float64."""

from .._config import enable_numerics

enable_numerics()
