"""FITS frames and stacks: written by astropy, read by bayescal's own readers, compared number for number."""

import numpy as np
import pandas as pd
import pytest

from bayescal.errors import TableError
from bayescal.io.files import read_image
from bayescal.io.fits import fits_layout, read_fits_image
from bayescal.maps.stacks import LazyStack, load_manifest
from bayescal.validation.sensor import PixelSensor, write_stacks

fits = pytest.importorskip("astropy.io.fits")


@pytest.mark.parametrize("dtype", ["uint16", "int16", "uint8", "float32", "float64", "uint32"])
def test_a_frame_reads_as_written_with_its_settings(tmp_path, dtype):
    """Unsigned 16- and 32-bit pixels go to disk signed with BZERO (astropy's own convention); they read back
    unsigned and equal (the full range, the sign bit set included), as does every other type; the exposure and
    temperature keywords are the setting."""
    rng = np.random.default_rng(1)
    info = np.iinfo(dtype) if np.dtype(dtype).kind in "ui" else None
    image = (
        rng.integers(max(info.min, 0), info.max, (7, 5), endpoint=True) if info else rng.normal(100, 5, (7, 5))
    ).astype(dtype)
    header = fits.Header({"EXPTIME": 0.008, "CCD-TEMP": -10.5, "GAIN": 1.7})
    fits.PrimaryHDU(image, header=header).writeto(tmp_path / "f.fits")
    read, settings = read_fits_image(tmp_path / "f.fits")
    assert read.dtype == np.dtype(dtype) and read.dtype.isnative
    np.testing.assert_array_equal(read, image)
    assert settings == {"exposure_s": 0.008, "temperature_c": -10.5, "conversion_gain_e_per_dn": 1.7}
    np.testing.assert_array_equal(read_image(tmp_path / "f.fits"), image)


def test_an_image_in_an_extension_and_colour_planes(tmp_path):
    """An empty primary with the image in an extension; a (planes, H, W) cube reads as (H, W, C)."""
    planes = np.arange(3 * 4 * 6, dtype=np.uint16).reshape(3, 4, 6)
    fits.HDUList([fits.PrimaryHDU(), fits.ImageHDU(planes)]).writeto(tmp_path / "rgb.fit")
    np.testing.assert_array_equal(read_image(tmp_path / "rgb.fit"), np.moveaxis(planes, 0, -1))


def test_scaled_or_imageless_files_are_refused_by_name(tmp_path):
    hdu = fits.PrimaryHDU(np.ones((4, 4), np.int16))
    hdu.header["BSCALE"], hdu.header["BZERO"] = 2.0, 10.0
    hdu.writeto(tmp_path / "scaled.fits")
    with pytest.raises(TableError, match=r"scaled\.fits: BSCALE = 2.0, BZERO = 10.0 .* expected raw DN"):
        read_image(tmp_path / "scaled.fits")
    fits.HDUList([fits.PrimaryHDU(), fits.BinTableHDU.from_columns([fits.Column("a", "E", array=[1.0])])]).writeto(
        tmp_path / "table.fits"
    )
    with pytest.raises(TableError, match=r"table\.fits: no image in any of its 2 HDUs"):
        read_image(tmp_path / "table.fits")


def test_a_stack_reads_lazily_row_block_by_row_block(tmp_path):
    """A (frames, H, W) uint16 cube: the layout found in the header; rows read from the file equal astropy's."""
    cube = np.random.default_rng(2).integers(0, 65535, (3, 9, 5), endpoint=True).astype(np.uint16)
    fits.PrimaryHDU(cube).writeto(tmp_path / "s.fits")
    layout = fits_layout(tmp_path / "s.fits")
    assert layout.shape == (3, 9, 5) and layout.flip == 2**15 and layout.offset % 2880 == 0
    stack = LazyStack(str(tmp_path / "s.fits"), layout.shape, layout.dtype, "fits", layout.offset, layout.flip)
    np.testing.assert_array_equal(stack.read_rows(2, 7), cube[:, 2:7])
    np.testing.assert_array_equal(stack[1], cube[1])


def test_maps_from_fits_stacks_equal_those_from_npy(tmp_path):
    """The same simulated sensor's stacks as .npy and as FITS (converted by astropy): identical pixel statistics."""
    npy = tmp_path / "npy"
    write_stacks(PixelSensor(height=24, width=16), npy, photons=[0.0, 5000.0], exposure_s=0.05, frames=3, seed=4)
    conditions = pd.read_csv(npy / "conditions.csv")
    as_fits = tmp_path / "fits"
    as_fits.mkdir()
    for name in conditions.file:
        header = fits.Header({"EXPTIME": 0.05})
        fits.PrimaryHDU(np.load(npy / name), header=header).writeto(as_fits / name.replace(".npy", ".fits"))
    # the exposures left to the headers (EXPTIME)
    manifest = conditions.assign(file=conditions.file.str.replace(".npy", ".fits"), exposure_s="")
    manifest.to_csv(as_fits / "conditions.csv", index=False)
    a, b = load_manifest(npy), load_manifest(as_fits)
    np.testing.assert_array_equal(b.table.exposure_s, a.table.exposure_s)
    for x, y in zip(a.stacks, b.stacks, strict=True):
        assert y.format == "fits" and x.shape == y.shape
        np.testing.assert_array_equal(x.read_rows(0, x.shape[1]), y.read_rows(0, y.shape[1]))
        np.testing.assert_array_equal(x[1], y[1])
