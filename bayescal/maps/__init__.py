"""Per-pixel calibration maps: frame stacks in, relative gain, offset, dark current and defects out.

Data flow: :mod:`~bayescal.maps.stacks` (manifest, lazy readers, per-pixel
statistics) -> :mod:`~bayescal.maps.population` (the hierarchical per-pixel
model, closed form) -> :mod:`~bayescal.maps.build` (two streaming passes, the
store) -> :mod:`~bayescal.maps.apply` (correcting and inverting new images).
"""
