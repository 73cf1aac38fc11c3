"""The EMVA 1288 datasheet of the shipped reference CCD (EMVA refset001): the standard's plots with the
posterior's bands, and an SNR model that describes the real sensor's measured SNR."""

import re

import numpy as np
import pytest

import bayescal as bc
from bayescal.characterization.datasheet import snr_band, write_datasheet
from bayescal.io.resources import example_path


@pytest.fixture(scope="module")
def ccd():
    return bc.characterize(bc.load_steps(example_path("emva_refset001_steps", "data")), seed=0)


def test_the_posterior_snr_describes_the_measured_snr_of_the_real_ccd(ccd):
    """Between 10 and 70 % of saturation the SNR of the fitted K, QE and dark noise (the standard's
    eq. 15) is within 3 % of each step's measured (mu_y - mu_dark) / s_y (1.5 % at worst measured)."""
    c = ccd.curves
    photons = c["photons"].to_numpy()
    saturation = ccd.standard["u_p_sat"]
    inside = (photons > 0.1 * saturation) & (photons < 0.7 * saturation)
    assert inside.sum() >= 20
    measured = c["signal"].to_numpy()[inside] / np.sqrt(c["s2_y"].to_numpy()[inside])
    median = np.median(snr_band(ccd, photons[inside]), axis=0)
    np.testing.assert_allclose(median, measured, rtol=0.03)


def test_the_datasheet_draws_every_plot_with_its_band(ccd, tmp_path):
    out = write_datasheet(ccd, tmp_path / "datasheet.html")
    html = out.read_text()
    alts = re.findall(r'<img alt="([^"]*)" src="data:image/png;base64,', html)
    assert alts == ["Photon transfer", "Sensitivity", "Signal-to-noise ratio", "Linearity", "Dark signal"]
    for quantity in ("K", "QE", "sigma_d", "PRNU1288"):
        assert f"<td>{quantity}</td>" in html
    # the curves the bands are drawn from: the photon transfer quartic's slope at zero is K's posterior
    powers, coef = ccd.curve_draws["photon_transfer"]
    np.testing.assert_allclose(np.median(coef[:, powers.index(1)]), np.median(ccd.draws["K"]), rtol=1e-12)


def test_the_datasheet_opens_with_the_operating_point_the_set_records(ccd, tmp_path):
    """The standard's first table, as far as the set's files record it (the reference CCD: 12 bits, 50 bright
    steps); what no file records is said so, not invented (the shipped reduced table has no pixel count)."""
    op = ccd.operating
    assert op["bits"] == 12 and op["pixels_per_image"] is None and op["bright_steps"] == 50
    assert op["exposure_s"][0] < op["exposure_s"][1] and op["photons_per_pixel"][1] > 30000
    html = write_datasheet(ccd, tmp_path / "datasheet.html").read_text()
    assert html.index("Operating point") < html.index("Quantities")
    assert "<td>bit depth</td><td>12</td>" in html and "not recorded in the set&#x27;s files" in html
    assert "not recorded (a reduced table" in html


def test_a_column_pattern_stands_out_of_the_white_profile():
    """The horizontal profile (the mean of each column) of a white pattern scatters by its sd / sqrt(rows); a
    column pattern of 0.5 sd stands 11 of those out (closed form on a 500 x 64 white image)."""
    from bayescal.characterization.pattern import profile

    rng = np.random.default_rng(3)
    white = rng.standard_normal((500, 64))
    flat = profile(white, 0)
    assert flat.shape == (64,) and abs(np.std(flat) * np.sqrt(500) - 1.0) < 0.25  # sd of 64 means: MC error ~0.09
    striped = white + 0.5 * (np.arange(64) % 8 == 0)
    assert profile(striped, 0)[::8].min() > 3.0 / np.sqrt(500)  # every striped column out of the band
    assert profile(striped, 1).shape == (500,)
