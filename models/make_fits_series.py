"""Write the shipped FITS flat/dark series: an EMVA 1288 set of a small simulated 12-bit CCD.

A 24 x 24 pixel region of a CCD like the EMVA reference set's (K = 0.28 DN/e-, QE 45 %, read noise
10 e-, dark current 30 e-/s, 1 % PRNU, 2 DN DSNU, offset 100 DN): a pair of flats at each of 24
illumination steps from dark to saturation at 20 ms, pairs of darks at 20, 100 and 200 ms (the dark
current is a slope in time), and a stack of 16 flats at half saturation with 16 darks beside it (the
spatial non-uniformity: DSNU, PRNU and their histograms and spectrograms on the datasheet).  Each frame
is a FITS file (``EXPTIME`` in its header), listed in
``EMVA1288_Data.txt`` as the standard's descriptor lists images; ``bayescal characterize`` reads the
descriptor::

    python models/make_fits_series.py      # rewrites models/ccd_fits/
    bayescal characterize ccd_fits --out ccd/

The simulation is written here from the sensor's datasheet values, apart from bayescal's model.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent / "ccd_fits"
SIDE = 24
BITS = 12
K = 0.28  # DN per electron
QE = 0.45
READ_E = 10.0
DARK_E_S = 30.0
PRNU = 0.01
DSNU_DN = 2.0
OFFSET_DN = 100.0
EXPOSURE_S = 0.02
DARK_EXPOSURES_S = (0.02, 0.1, 0.2)
STEPS = 24
STACK = 16  # frames of each stack (the standard asks for more; enough for the datasheet's plots)
FULL_WELL_PHOTONS = 36000.0  # past saturation of the 12-bit ADC at this K and QE


def _frame(rng: np.random.Generator, photons: float, exposure_s: float, gain_map, offset_map) -> np.ndarray:
    electrons = rng.poisson(QE * photons * gain_map + DARK_E_S * exposure_s) + rng.normal(0.0, READ_E, gain_map.shape)
    dn = np.floor(offset_map + K * electrons + rng.uniform(0, 1, gain_map.shape))  # ADC rounding
    return np.clip(dn, 0, 2**BITS - 1).astype(np.uint16)


def main(seed: int = 1288) -> None:
    from astropy.io import fits

    rng = np.random.default_rng(seed)
    gain_map = 1.0 + PRNU * rng.standard_normal((SIDE, SIDE))
    offset_map = OFFSET_DN + DSNU_DN * rng.standard_normal((SIDE, SIDE))
    HERE.mkdir(exist_ok=True)
    for old in HERE.glob("*.fits"):
        old.unlink()
    lines = [
        "# A FITS flat/dark series of a simulated 12-bit CCD (models/make_fits_series.py)",
        f"n {BITS} {SIDE} {SIDE}",
    ]

    def group(tag: str, name: str, photons: float, exposure_s: float, suffixes) -> None:
        ns = int(round(exposure_s * 1e9))
        lines.append(f"b {ns} {photons:.1f}" if tag == "b" else f"d {ns}")
        for k in suffixes:
            header = fits.Header({"EXPTIME": exposure_s, "CCD-TEMP": 20.0})
            data = _frame(rng, photons, exposure_s, gain_map, offset_map)
            fits.PrimaryHDU(data=data, header=header).writeto(HERE / f"{name}{k}.fits", overwrite=True)
            lines.append(f"i {name}{k}.fits")

    for i, photons in enumerate(np.linspace(FULL_WELL_PHOTONS / STEPS, FULL_WELL_PHOTONS, STEPS)):
        group("b", f"flat{i:02d}", float(photons), EXPOSURE_S, "ab")
    for exposure_s in DARK_EXPOSURES_S:
        group("d", f"dark{int(exposure_s * 1000):03d}ms", 0.0, exposure_s, "ab")
    frames = [f"_{k:02d}" for k in range(STACK)]
    group("b", "stackflat", FULL_WELL_PHOTONS / 2, EXPOSURE_S, frames)
    group("d", "stackdark", 0.0, EXPOSURE_S, frames)
    (HERE / "EMVA1288_Data.txt").write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
