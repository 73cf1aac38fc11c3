"""Sensor characterisation: EMVA 1288 (the standard's estimates beside posteriors) and the
diagnosis of a nonlinearity's source (V/Q or DN/V, seed 004)."""
