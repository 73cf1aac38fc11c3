"""A dark slope per channel (a sensor read through several outputs, each amplifier its own DN per
electron): each channel's slope recovered, and predictions carry it."""

import warnings

import numpy as np
import pytest

import bayescal as bc

#: each channel's dark current over the bench camera's (a channel read through its own output)
SCALE = {"R": 1.5, "G": 1.0, "B": 0.5}


def test_each_channel_its_own_dark_slope_on_the_independent_bench():
    """On the independent bench (:mod:`bayescal.validation.bench`, which shares no code with the model),
    a camera whose channels' dark currents are 1.5, 1 and 0.5 times its datasheet's at every gain: the
    per-channel slopes are recovered (each of the 12 inside its 99.9 % interval), the fit passes its
    checks, and the dark level the calibration predicts at the longest dark exposure is within 0.3 DN
    of the bench's own."""
    from bayescal.validation.bench import BenchCamera, simulate_bench

    camera = BenchCamera(channel_dark_scale=SCALE)
    frame, real = simulate_bench(camera, seed=71)
    spec = bc.load_spec("seed000").replace(dark={"slope_per_channel": True})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", bc.FitFailedWarning)
        fit = bc.fit(bc.MeasurementTable.from_frame(frame), spec, "laplace", seed=71)
    assert fit.ok, fit.diagnostics.verdict
    draws = fit.draws("dark_slope_channel")  # (S, channel, gain setting), DN/s
    for c, channel in enumerate(camera.channels):
        for k, gain in enumerate(sorted(camera.dark_current_dn_s)):
            truth = camera.dark_current_dn_s[gain] * SCALE[channel]
            lo, hi = np.quantile(draws[:, c, k], [0.0005, 0.9995])
            assert lo <= truth <= hi, (channel, gain, truth, lo, hi)
    cal = bc.Calibration.from_fit(fit)
    for channel in camera.channels:
        predicted = np.median(cal.dark_dn(channel, bc.Setting(0.01, 4.0)))
        assert abs(predicted - real.dark_dn(channel, 0.01, 4.0)) < 0.3, channel


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
