"""A dark slope per channel (a sensor read through several outputs, each amplifier its own DN per
electron): each channel's slope recovered, and predictions carry it."""

import dataclasses
import warnings

import numpy as np
import pytest

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


def test_the_dark_term_reads_every_shape_of_the_slope():
    """The prediction term from reported draws ``(chain, draw, ...)``: a slope per gain or per channel,
    with offsets per gain setting or proportional to the gain (one column at the reference gain),
    against ``(offset + slope t) g / g_ref`` written out."""
    from bayescal.model.components.dark import Dark

    spec = bc.load_spec("seed002")
    channels, ref = ("A", "B"), spec.reference.gain
    offset = np.array([[[10.0, 20.0]]])  # (chain, draw, channel)
    at = bc.Setting(0.5, 2.0 * ref)
    for draws, slope in (
        ({"dark_slope_ref": np.array([[4.0]])}, [4.0, 4.0]),
        ({"dark_slope_channel_ref": np.array([[[4.0, 6.0]]])}, [4.0, 6.0]),
    ):
        term = Dark.term(
            spec.replace(dark={"gain_dependence": "proportional"}), {"dark_offset_ref": offset} | draws, channels, ()
        )
        for c, channel in enumerate(channels):
            expected = (offset[0, 0, c] + slope[c] * 0.5) * 2.0
            assert term.offset(channel, at, 1) == pytest.approx([expected])
    per_setting = spec.replace(dark={"gain_dependence": "per_setting"})
    offsets = np.array([[[[10.0, 11.0], [20.0, 21.0]]]])  # (chain, draw, channel, gain setting)
    for draws, slope in (
        ({"dark_slope": np.array([[[4.0, 5.0]]])}, [[4.0, 5.0], [4.0, 5.0]]),
        ({"dark_slope_channel": np.array([[[[4.0, 5.0], [6.0, 7.0]]]])}, [[4.0, 5.0], [6.0, 7.0]]),
    ):
        term = Dark.term(per_setting, {"dark_offset": offsets} | draws, channels, (1.0, 2.0))
        for c, channel in enumerate(channels):
            for k, gain in enumerate((1.0, 2.0)):
                expected = offsets[0, 0, c, k] + slope[c][k] * 0.5
                assert term.offset(channel, bc.Setting(0.5, gain), 1) == pytest.approx([expected])
