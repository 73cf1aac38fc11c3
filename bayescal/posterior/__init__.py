"""A calibrated camera: posterior draws in physical units, the input of every prediction."""
