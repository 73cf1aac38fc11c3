"""Write the shipped example frames: one raw RGGB frame of the seed-000 camera, as TIFF and as FITS.

The scene is a radiance ramp (2-40 W m^-2 sr^-1 across the frame, a darker disc in its middle) read
at 1/250 s and gain 1 by the camera of ``seed000_design.toml`` (its simulation truth: read, shot and
quantisation noise, PRNU, clipping), one pixel per reading.  ``bayescal invert`` takes either file
with a fit of that camera::

    python models/make_frames.py      # rewrites models/seed000_frame.tif and models/seed000_frame.fits
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
HEIGHT, WIDTH = 48, 64
EXPOSURE_S, GAIN = 0.004, 1.0


def frame(seed: int = 2026) -> np.ndarray:
    """The raw mosaic, ``(HEIGHT, WIDTH)`` unsigned 16-bit, R at (0, 0), B at (1, 1)."""
    import bayescal as bc

    spec, design = bc.load_spec(HERE / "seed000_bayer.toml"), bc.load_design(HERE / "seed000_design.toml")
    sim = bc.simulate(spec, design, seed=seed)
    y, x = np.mgrid[0:HEIGHT, 0:WIDTH]
    scene = 2.0 + 38.0 * x / (WIDTH - 1)
    scene = np.where((y - HEIGHT / 2) ** 2 + (x - WIDTH / 2) ** 2 < 10**2, 0.5 * scene, scene)
    plane = np.array([["R", "G"], ["G", "B"]])[y % 2, x % 2]
    rng = np.random.default_rng(seed)
    out = np.zeros((HEIGHT, WIDTH))
    for channel in ("R", "G", "B"):
        at = plane == channel
        out[at] = sim.reading(spec, channel, scene[at], EXPOSURE_S, GAIN, n_avg=1, rng=rng)
    return out.astype(np.uint16)


def main() -> None:
    import tifffile
    from astropy.io import fits

    raw = frame()
    tifffile.imwrite(HERE / "seed000_frame.tif", raw)
    header = fits.Header({"EXPTIME": EXPOSURE_S, "GAIN": GAIN, "BAYERPAT": "RGGB"})
    fits.PrimaryHDU(raw, header=header).writeto(HERE / "seed000_frame.fits", overwrite=True)
    print(f"wrote seed000_frame.tif and seed000_frame.fits ({HEIGHT} x {WIDTH}, {raw.min()}-{raw.max()} DN)")


if __name__ == "__main__":
    main()
