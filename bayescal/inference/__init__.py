"""Inference: compiled programs of a model, the backends that sample them (a registry), least squares
and the solvers; every one computes in float64 (switched on where they compute, not on import)."""
