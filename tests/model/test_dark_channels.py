"""A dark slope per channel (a sensor read through several outputs, each amplifier its own DN per
electron): each channel's slope recovered, and predictions carry it."""

import dataclasses
import warnings

import numpy as np

import bayescal as bc

#: the simulated camera's extra dark slope per channel (DN/s), beside its slope per gain
EXTRA = {"R": 1500.0, "G": 0.0, "B": -1000.0}


def test_each_channel_its_own_dark_slope(seed000):
    spec, design = seed000
    spec = spec.replace(dark={"slope_per_channel": True})  # the camera's other terms as the shipped spec's
    slopes = {1.0: 2000.0, 2.0: 4000.0, 3.0: 6000.0, 4.0: 8000.0}
    truth = dataclasses.replace(design.truth, dark_slope=slopes, channel_dark_slope=EXTRA)
    sim = bc.simulate(spec, dataclasses.replace(design, truth=truth), seed=71)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", bc.FitFailedWarning)
        fit = bc.fit(sim.table, spec, "laplace", seed=71)
    assert fit.ok, fit.diagnostics.verdict
    draws = fit.draws("dark_slope_channel")  # (S, channel, gain setting)
    for c, channel in enumerate(("R", "G", "B")):
        for k, gain in enumerate((1.0, 2.0, 3.0, 4.0)):
            lo, hi = np.quantile(draws[:, c, k], [0.0005, 0.9995])
            assert lo <= slopes[gain] + EXTRA[channel] <= hi, (channel, gain, lo, hi)
    cal = bc.Calibration.from_fit(fit)
    at = bc.Setting(0.01, 4.0)
    gap = np.median(cal.dark_dn("R", at) - cal.dark_dn("B", at))  # the slopes' difference over 10 ms
    offsets = truth.channel_offset.get("R", 0.0) - truth.channel_offset.get("B", 0.0)
    assert abs(gap - (offsets + 2500.0 * 0.01)) < 3.0
