"""The calibration model: a spec names its components, the data are scaled for them, and the
assembly wires them into one numpyro model (docs/architecture.md, sections 2-3).

spec (which components, their priors) -> data (scaled arrays, the layout) -> components (one
physical effect each) -> assemble (the numpyro model) -> physical (scaled draws to reported
quantities); simulate runs the same measurement equation forward with known truth.
"""
