"""FITS frames and stacks: the first image of a file, its layout on disk, and the settings its header records.

FITS (Wells, Greisen & Harten 1981; the FITS Standard 4.0, 2018) stores an image as big-endian numbers,
``NAXIS1`` (the width) fastest, so a ``NAXIS = 3`` cube is ``(frames, height, width)`` in C order.  Unsigned
16- and 32-bit pixels are stored signed with ``BZERO = 2^15`` or ``2^31``: the value is the stored bits
with their top bit flipped.  Any other ``BSCALE``/``BZERO`` would turn DN into scaled floats and is refused.

Exposure and temperature are read from the header where a common keyword holds them (:data:`EXPOSURE_KEYS`,
:data:`TEMPERATURE_KEYS`).  ``GAIN`` in astronomical headers is the conversion gain in e-/DN, not the
camera's gain setting; it is reported as ``conversion_gain_e_per_dn`` and never taken for the setting.
Reading FITS needs astropy (``pip install 'bayescal[fits]'``).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from bayescal.errors import TableError

__all__ = ["FITS_SUFFIXES", "FitsLayout", "read_fits_image", "fits_layout", "header_settings"]

#: file name endings read as FITS
FITS_SUFFIXES = (".fits", ".fit", ".fts")
#: header keywords holding the exposure time in seconds, in the order tried
EXPOSURE_KEYS = ("EXPTIME", "EXPOSURE", "EXP_TIME")
#: header keywords holding the sensor temperature in degrees C, in the order tried (the measured one first)
TEMPERATURE_KEYS = ("CCD-TEMP", "CCDTEMP", "DET-TEMP", "DETTEMP", "SENSTEMP")


def _fits():
    try:
        from astropy.io import fits
    except ImportError:
        raise TableError("reading FITS needs astropy: pip install 'bayescal[fits]' (or astropy)") from None
    return fits


def _image_hdu(hdul, path: Path):
    """The first HDU holding an image (the primary, or an image extension of a file whose primary is empty)."""
    for index, hdu in enumerate(hdul):
        if hdu.is_image and hdu.header.get("NAXIS", 0) >= 2:
            return index, hdu
    raise TableError(f"{path}: no image in any of its {len(hdul)} HDUs; expected a 2-D frame or a 3-D stack")


def _unsigned_flip(header, path: Path) -> int:
    """The bit to flip for unsigned pixels stored signed (``BZERO = 2^(BITPIX-1)``), 0 for none."""
    bitpix, bzero, bscale = int(header["BITPIX"]), header.get("BZERO", 0), header.get("BSCALE", 1)
    if bscale != 1 or (bzero != 0 and not (bitpix in (16, 32) and bzero == 2 ** (bitpix - 1))):
        raise TableError(
            f"{path}: BSCALE = {bscale}, BZERO = {bzero} scale the stored numbers; expected raw DN "
            "(BSCALE 1, BZERO 0, or BZERO 2^15 / 2^31 for unsigned pixels)"
        )
    return 2 ** (bitpix - 1) if bzero else 0


def read_fits_image(path: str | Path) -> tuple[np.ndarray, dict[str, Any]]:
    """The first image of a FITS file as a native-order array (unsigned where ``BZERO`` says so), and
    :func:`header_settings` of its header."""
    path = Path(path)
    fits = _fits()
    with fits.open(path, memmap=False, uint=True) as hdul:  # astropy turns BZERO-shifted pixels unsigned
        _, hdu = _image_hdu(hdul, path)
        _unsigned_flip(hdu.header, path)  # refuse scaled pixels before astropy scales them to floats
        data = np.asarray(hdu.data)
        settings = header_settings(hdu.header)
    return data.astype(data.dtype.newbyteorder("=")), settings


@dataclass(frozen=True)
class FitsLayout:
    """Where a FITS image lies in its file: byte offset, ``(frames, height, width)``, the stored dtype (big-endian,
    unsigned where the sign bit is flipped) and the bit to flip (0: none)."""

    offset: int
    shape: tuple[int, int, int]
    dtype: np.dtype
    flip: int
    settings: dict[str, Any]


def fits_layout(path: str | Path) -> FitsLayout:
    """The layout of the first image of a FITS file, for reading it lazily (a 2-D image is one frame)."""
    path = Path(path)
    fits = _fits()
    with fits.open(path, memmap=False, do_not_scale_image_data=True, lazy_load_hdus=False) as hdul:
        index, hdu = _image_hdu(hdul, path)
        header = hdu.header
        flip = _unsigned_flip(header, path)
        offset = int(hdul.fileinfo(index)["datLoc"])
        settings = header_settings(header)
    bitpix = int(header["BITPIX"])
    kinds = {8: "u1", 16: "i2", 32: "i4", 64: "i8", -32: "f4", -64: "f8"}
    code = kinds[bitpix].replace("i", "u") if flip else kinds[bitpix]
    axes = [int(header[f"NAXIS{k}"]) for k in range(int(header["NAXIS"]), 0, -1)]
    if len(axes) > 3:
        raise TableError(f"{path}: a {len(axes)}-D image; expected a 2-D frame or a 3-D (frames, height, width) stack")
    frames, height, width = axes if len(axes) == 3 else [1, *axes]
    return FitsLayout(offset, (frames, height, width), np.dtype(">" + code), flip, settings)


def header_settings(header) -> dict[str, Any]:
    """What a FITS header records of the reading's setting: ``exposure_s``, ``temperature_c`` and the
    conversion gain ``conversion_gain_e_per_dn`` (``GAIN``), each where a keyword holds a number."""
    out: dict[str, Any] = {}
    for name, keys in (("exposure_s", EXPOSURE_KEYS), ("temperature_c", TEMPERATURE_KEYS)):
        for key in keys:
            value = header.get(key)
            if isinstance(value, (int, float)) and not isinstance(value, bool) and np.isfinite(value):
                out[name] = float(value)
                break
    gain = header.get("GAIN")
    if isinstance(gain, (int, float)) and not isinstance(gain, bool) and np.isfinite(gain):
        out["conversion_gain_e_per_dn"] = float(gain)
    return out
