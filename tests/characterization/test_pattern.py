"""The spatial non-uniformity from image stacks: DSNU and PRNU intervals that cover simulated sensors (the
stacks' temporal noise corrected once, EMVA 1288 eq. 32), the spectrogram's arithmetic, and the datasheet's
histograms and spectrograms of the real CCD's stacks.

The sensors are written here with numpy (Poisson electrons, a Gaussian gain and offset map, read noise,
ADC rounding and clipping), not with the characterisation's code.
"""

import re

import numpy as np
import pytest

import bayescal as bc
from bayescal.characterization.datasheet import write_datasheet
from bayescal.characterization.pattern import pattern_images, pattern_sd_draws, spectrogram
from tests.conftest import ROOT, least_hits

CROP = ROOT / "tests" / "data" / "emva1288" / "refset001_ccd_12bit" / "crop128.npz"


def _sensor(seed: int, dsnu_dn: float, side: int = 32, frames: int = 16, k: float = 0.25) -> tuple[dict, dict]:
    """A 12-bit sensor's sweep of 40 bright and dark pairs and a 16-frame bright and dark stack (npz keys)."""
    rng = np.random.default_rng(seed)
    qe, read_e, prnu, offset, full = 0.6, 6.0, 0.01, 64.0, 4095
    gain = 1.0 + prnu * rng.standard_normal((side, side))
    off = offset + dsnu_dn * rng.standard_normal((side, side))

    def frame(photons: float) -> np.ndarray:
        electrons = rng.poisson(qe * photons * gain) + read_e * rng.standard_normal((side, side))
        dn = np.floor(off + k * electrons + rng.uniform(0.0, 1.0, (side, side)))
        return np.clip(dn, 0, full).astype(np.uint16)

    saturation = (full - offset) / k / qe
    photons = np.linspace(0.01, 1.15, 40) * saturation
    exposure = np.full(photons.size, 1e6)
    arrays = {
        "bits": 12,
        "bright_texp": exposure,
        "bright_photons": photons,
        "dark_texp": exposure,
        "bright_pairs": np.stack([[frame(p), frame(p)] for p in photons]),
        "dark_pairs": np.stack([[frame(0.0), frame(0.0)] for _ in photons]),
        "bright_stack": np.stack([frame(0.5 * saturation) for _ in range(frames)]),
        "bright_stack_texp": 1e6,
        "bright_stack_photons": 0.5 * saturation,
        "dark_stack": np.stack([frame(0.0) for _ in range(frames)]),
        "dark_stack_texp": 1e6,
    }
    # the realised maps' spread: DSNU in electrons, PRNU in %
    return arrays, {"DSNU1288": off.std() / k, "PRNU1288": 100.0 * gain.std()}


@pytest.mark.parametrize("dsnu_dn", [2.0, 0.15])
def test_dsnu_and_prnu_intervals_cover_simulated_sensors(tmp_path, dsnu_dn):
    """40 sensors: each interval covers the realised map's spread at least as often as a 95 % interval must
    (binomial bound). Measured over 100 sensors: DSNU 98 and PRNU 100 with a 2 DN offset pattern, 97 and
    100 with 0.15 DN (below the 16-frame means' residual temporal noise, 0.38 DN). Before, with the
    stacks' temporal noise subtracted twice and its own error ignored: 37 and 28 of 40 at 2 DN, 0 and
    69 of 100 at 0.15 DN."""
    hits = {"DSNU1288": 0, "PRNU1288": 0}
    n = 40
    for seed in range(n):
        arrays, truth = _sensor(seed, dsnu_dn)
        path = tmp_path / f"sensor{seed}.npz"
        np.savez(path, **arrays)
        q = bc.characterize(bc.load_steps(path), seed=seed).table.set_index("quantity")
        for name, value in truth.items():
            hits[name] += int(q.loc[name, "q2.5"] <= value <= q.loc[name, "q97.5"])
    assert min(hits.values()) >= least_hits(n), hits


def test_the_real_ccds_prnu_is_its_stacks_corrected_once():
    """The standard's PRNU of the real CCD's 128 x 128 crop, from its 50-frame stacks by eq. 32 written out."""
    res = bc.characterize(bc.load_steps(CROP), seed=0)
    d = np.load(CROP)
    bright, dark = (d[k].astype(np.float64) for k in ("bright_stack", "dark_stack"))
    frames = bright.shape[0]
    s2 = {}
    for name, stack in (("bright", bright), ("dark", dark)):
        temporal = np.mean(np.var(stack, axis=0, ddof=1))
        s2[name] = np.var(stack.mean(axis=0), ddof=1) - temporal / frames
    signal = bright.mean() - dark.mean()
    assert res.standard["PRNU1288"] == pytest.approx(100 * np.sqrt(s2["bright"] - s2["dark"]) / signal, rel=1e-9)


def test_a_white_pattern_reads_its_standard_deviation_at_every_frequency():
    rng = np.random.default_rng(3)
    image = 3.0 * rng.standard_normal((256, 256))
    for axis in (0, 1):
        freq, amplitude = spectrogram(image, axis)
        assert freq[0] > 0 and freq[-1] == 0.5
        # each frequency averages 256 rows' |FFT|^2 (exponential): the amplitude's relative sd is about 3 %
        assert np.median(amplitude) == pytest.approx(3.0, rel=0.03)
        assert amplitude.max() < 3.0 * 1.25


def test_a_column_pattern_is_a_peak_in_the_horizontal_spectrogram_only():
    rng = np.random.default_rng(4)
    columns = np.tile([1.0, 0.0, -1.0, 0.0], 32)  # period 4 pixels along each row: 0.25 cycles/pixel
    image = rng.standard_normal((128, 128)) + columns[None, :]
    freq, horizontal = spectrogram(image, axis=1)
    assert freq[np.argmax(horizontal)] == pytest.approx(0.25)
    # the peak holds the pattern's power: |FFT|^2 / N at that bin is N / 4 (amplitude 1, two bins)
    assert horizontal.max() == pytest.approx(np.sqrt(128 / 4), rel=0.1)
    _, vertical = spectrogram(image, axis=0)
    assert vertical.max() < 1.5  # columns are constant down each column: nothing periodic vertically


def test_the_pattern_images_match_the_posteriors_spread_on_the_real_ccd():
    """Each pattern image's sample sd is inside the 95 % band of the posterior's (DSNU1288 K and PRNU1288 with
    the residual temporal noise of the 50-frame means)."""
    res = bc.characterize(bc.load_steps(CROP), seed=0)
    images, sds = pattern_images(res.stack), pattern_sd_draws(res.stack, res.draws)
    assert images is not None and sds is not None
    for name in ("DSNU", "PRNU"):
        lo, hi = np.quantile(sds[name], [0.025, 0.975])
        assert lo <= images[name].std(ddof=1) <= hi, (name, lo, images[name].std(ddof=1), hi)


def test_the_datasheet_shows_the_histograms_and_spectrograms_where_images_exist(tmp_path):
    html = write_datasheet(bc.characterize(bc.load_steps(CROP), seed=0), tmp_path / "d.html").read_text()
    alts = re.findall(r'<img alt="([^"]*)" src="data:image/png;base64,', html)
    assert alts[-3:] == ["Non-uniformity histograms", "Non-uniformity spectrograms", "Non-uniformity profiles"]
    # a reduced table has no images: no pattern pictures, no error
    steps = bc.load_steps(ROOT / "tests" / "data" / "emva1288" / "refset001_ccd_12bit" / "steps.csv")
    assert pattern_images(steps.stack) is None
