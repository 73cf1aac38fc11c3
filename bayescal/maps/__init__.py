"""Per-pixel calibration maps: frame stacks in, relative gain, offset, dark current and defects out.

Data flow: :mod:`~bayescal.maps.stacks` (manifest, lazy readers, per-pixel
statistics) -> :mod:`~bayescal.maps.population` (the hierarchical per-pixel
model, closed form) -> :mod:`~bayescal.maps.model` (pass 1: each channel's
signal, noise and population; the per-block mapping) ->
:mod:`~bayescal.maps.build` (the lazy maps) -> :mod:`~bayescal.maps.store`
(streamed, staged writes; reading back), with :mod:`~bayescal.maps.metadata`
(attributes, provenance); then :mod:`~bayescal.maps.apply` (correcting and
inverting new images) and :mod:`~bayescal.maps.report` (the HTML page).
"""
