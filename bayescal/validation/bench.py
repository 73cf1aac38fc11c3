"""An independent calibration bench: a camera that does not obey bayescal's model exactly.

Written apart from the model: this module imports only numpy and pandas, draws
every pixel of every frame, and describes the camera the way a datasheet
would, not the way the model parametrises it.  Its departures from the model's
assumptions (each switchable, all realistic):

- **gain steps off nominal**: each step other than 1 has a true factor drawn
  uniformly within +-``gain_step_error`` of its label;
- **shutter offset**: the sensor integrates ``t + shutter_offset_s``;
- **roll-off**: the signal compresses smoothly near full scale,
  ``S / (1 + (S / S_k)^4)^(1/4)`` (not a polynomial), or ``S_t tanh(S / S_t)``
  (``rolloff_shape = "tanh"``: compressed a little at every level);
- **spectral sphere errors**: each lamp level's error differs slightly by
  colour channel (``spectral_level_rel``) on top of the shared part;
- **dark drift**: the dark level drifts linearly by ``dark_drift_dn`` over the
  measurement run (rows in the order measured: sweeps, then darks);
- **PRNU with partial clipping**: a wider pixel response spread than the
  model's 1 % (``prnu``), with every pixel clipped separately at full scale;
- **non-proportional exposures**: a named exposure integrates ``factor`` times
  its nominal time (seed 000 Table 2: +5 % at 1/100 s);
- **nonlinearity after the gain**: the compression acts on the amplified output
  (the same curve in DN at every gain) instead of on the collected charge;
- **a lamp whose spectrum changes**: on top of the per-level errors, each
  channel sees its own scale error (``channel_scale_rel``) of the sphere's
  radiance, as a lamp's colour temperature differs from the one its
  calibration assumed;
- **amplifier glow**: a dark signal growing with the square of the exposure,
  different in each channel (``glow_dn_s2`` at gain 1, scaling with the gain).

The camera defaults follow seed 000 (12-bit Bayer CCD, Table 1 gains, dark
about 50 DN at gain 1 and 460 DN at gain 4, 20 frames of 32 x 32 pixels).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
import pandas as pd

__all__ = ["BenchCamera", "Departures", "Realisation", "simulate_bench", "with_held_out"]

#: how the amplifier glow divides between the channels (R, G, B): the amplifier sits nearer some pixels
GLOW_SHARE = (1.0, 0.4, 1.8)
#: how the readout bias's temperature drift divides between the channels (R, G, B): each has its own path
BIAS_SHARE = (1.0, -0.6, 0.4)
#: the temperature (degC) the bench's datasheet offsets refer to
BENCH_REFERENCE_C = 20.0


@dataclass(frozen=True)
class Departures:
    """How the camera departs from the model (all zero: it obeys it, up to pixel-level detail)."""

    gain_step_error: float = 0.0
    shutter_offset_s: float = 0.0
    rolloff: bool = False
    spectral_level_rel: float = 0.0
    dark_drift_dn: float = 0.0
    prnu: float = 0.01
    exposure_factor: tuple[tuple[float, float], ...] = ()  # (exposure_s, true factor) pairs: non-proportional
    output_nonlinearity: bool = False
    channel_scale_rel: float = 0.0
    glow_dn_s2: float = 0.0
    rolloff_shape: str = "knee"  # "knee": S / (1 + (S / S_k)^4)^(1/4); "tanh": S_t tanh(S / S_t)
    bias_dn_per_c: float = 0.0  # the readout bias drifts this many DN per degC (times BIAS_SHARE per channel)
    flicker_rel: float = 0.0  # the lamp's output in each frame departs from its mean by this relative sd

    @classmethod
    def everything(cls) -> Departures:
        """All departures at once, at the sizes of the misspecification benchmark."""
        return cls(
            gain_step_error=0.08,
            shutter_offset_s=0.0002,
            rolloff=True,
            spectral_level_rel=0.003,
            dark_drift_dn=3.0,
            prnu=0.03,
        )


@dataclass(frozen=True)
class BenchCamera:
    """A seed-000-like camera and bench, in datasheet terms.

    ``responsivity``: DN per (W m^-2 sr^-1) at gain 1 and ``t_ref`` for small
    signals; ``compression``: DN per (W m^-2 sr^-1)^2 (a gentle quadratic);
    dark ``offset_dn`` and ``dark_current_dn_s`` per gain step; ``channel_dark_scale``: each channel's
    dark current over that (a channel read through its own output, from its own region of the die;
    missing channels: 1).
    """

    channels: tuple[str, ...] = ("R", "G", "B")
    responsivity: dict = field(default_factory=lambda: {"R": 62.09, "G": 30.18, "B": 17.87})
    compression: dict = field(default_factory=lambda: {"R": -0.012, "G": -0.003, "B": -0.001})
    channel_offset_dn: dict = field(default_factory=lambda: {"R": 2.0, "G": -1.0, "B": 0.5})
    offset_dn: dict = field(default_factory=lambda: {1.0: 50.0, 2.0: 150.0, 3.0: 300.0, 4.0: 460.0})
    dark_current_dn_s: dict = field(default_factory=lambda: {1.0: 200.0, 2.0: 400.0, 3.0: 600.0, 4.0: 800.0})
    channel_dark_scale: dict = field(default_factory=dict)
    t_ref: float = 0.004
    bits: int = 12
    read_noise_dn: float = 3.0
    electrons_per_dn: float = 4.0
    sphere_common_rel: float = 0.03
    sphere_level_rel: float = 0.005
    levels: tuple[float, ...] = (1.5, 3.0, 5.0279, 7.5, 10.0, 12.5, 15.0, 17.5, 21.559, 24.0, 27.0, 30.0)
    sweeps: tuple = (((0.004, 0.008, 0.01), (1.0,), None), ((0.008,), (2.0, 3.0, 4.0), (0, 2, 4, 6)))
    darks: tuple = ((0.0027, 0.004, 0.008, 0.01), (1.0, 2.0, 3.0, 4.0))
    n_frames: int = 20
    n_pixels: int = 1024
    temperatures_c: tuple[float, ...] = ()  # sessions at these sensor temperatures (each repeats the plan)

    @property
    def full_scale(self) -> float:
        """Largest ADC code."""
        return float(2**self.bits - 1)


@dataclass(frozen=True)
class Realisation:
    """One simulated camera and bench: the truth behind one dataset.

    ``gain_factor[g]`` is the true gain of step ``g`` over its label,
    ``sphere_scale`` the true radiance over the sphere's nominal reading.
    """

    camera: BenchCamera
    departures: Departures
    gain_factor: dict
    sphere_scale: float
    prnu_map: dict
    channel_scale: dict = field(default_factory=dict)  # each channel's lamp scale error (1: none)

    def integration(self, exposure_s: float) -> float:
        """Effective integration time (s): a shutter offset, and any exposure that is not proportional."""
        factor = dict(self.departures.exposure_factor).get(exposure_s, 1.0)
        return exposure_s * factor + self.departures.shutter_offset_s

    def signal_dn(self, channel: str, radiance, exposure_s: float, gain: float) -> np.ndarray:
        """Mean signal (DN, before clipping) of a uniform radiance (true, W m^-2 sr^-1)."""
        cam = self.camera
        k = self.integration(exposure_s) / self.integration(cam.t_ref)  # the datasheet's t_ref is the effective one
        e = np.asarray(radiance, dtype=float) * k  # radiance-equivalent at the reference integration time
        g = gain * self.gain_factor.get(gain, 1.0)
        if self.departures.output_nonlinearity:  # the same curvature per DN of output at every gain
            out = cam.responsivity[channel] * e * g
            s = out + cam.compression[channel] / cam.responsivity[channel] ** 2 * out**2
        else:
            s = (cam.responsivity[channel] * e + cam.compression[channel] * e**2) * g
        if self.departures.rolloff and self.departures.rolloff_shape == "tanh":
            top = 1.3 * cam.full_scale  # an exponential approach: every signal compressed a little
            s = top * np.tanh(s / top)
        elif self.departures.rolloff:
            knee = 1.6 * cam.full_scale
            s = s / (1.0 + (np.maximum(s, 0.0) / knee) ** 4) ** 0.25
        return s

    def dark_dn(
        self, channel: str, exposure_s: float, gain: float, drift: float = 0.0, temperature_c: float = BENCH_REFERENCE_C
    ) -> float:
        """Mean dark level (DN) at a gain step, exposure and sensor temperature, plus any drift."""
        cam = self.camera
        share = cam.channels.index(channel) % 3
        glow = self.departures.glow_dn_s2 * GLOW_SHARE[share] * exposure_s**2 * gain
        bias = self.departures.bias_dn_per_c * BIAS_SHARE[share] * (temperature_c - BENCH_REFERENCE_C)
        current = cam.dark_current_dn_s[gain] * cam.channel_dark_scale.get(channel, 1.0)
        dark = cam.offset_dn[gain] + cam.channel_offset_dn[channel] + current * exposure_s
        return dark + glow + drift + bias

    def read(
        self,
        channel: str,
        radiance: float,
        exposure_s: float,
        gain: float,
        rng: np.random.Generator,
        *,
        n_frames: int | None = None,
        n_pixels: int | None = None,
        drift: float = 0.0,
        temperature_c: float = BENCH_REFERENCE_C,
    ) -> float:
        """One region-mean reading: every pixel of every frame drawn, clipped and quantised."""
        cam = self.camera
        nf, npx = n_frames or cam.n_frames, n_pixels or cam.n_pixels
        prnu = self.prnu_map[channel][:npx]
        signal = self.signal_dn(channel, radiance, exposure_s, gain) * prnu  # (pixels,)
        electrons = np.maximum(signal, 0.0) * cam.electrons_per_dn / gain
        shot = np.sqrt(electrons) / cam.electrons_per_dn * gain
        noise = rng.standard_normal((nf, npx)) * np.sqrt(shot**2 + (cam.read_noise_dn * gain) ** 2)
        if self.departures.flicker_rel > 0:  # the lamp frame to frame, the same for every pixel of a frame
            signal = signal * (1.0 + self.departures.flicker_rel * rng.standard_normal((nf, 1)))
        frames = self.dark_dn(channel, exposure_s, gain, drift, temperature_c) + signal + noise
        return float(np.clip(np.round(frames), 0.0, cam.full_scale).mean())

    def true_coefficients(self, channel: str, relative: bool = False) -> np.ndarray:
        """``[A0, A1, A2]`` at the reference setting (gain 1, ``t_ref``), small-signal, in true radiance;
        ``relative``: against the sphere's nominal reading (``A_k s^k``), what the bench's readings say."""
        cam = self.camera
        # the region's pixels respond by the mean of their PRNU map (1 +- prnu / sqrt(n_pixels)):
        # that mean, not the nominal responsivity, is what a calibration of region means measures
        region = float(np.mean(self.prnu_map[channel][: cam.n_pixels]))
        a = np.array(
            [
                self.dark_dn(channel, cam.t_ref, 1.0),
                cam.responsivity[channel] * self.gain_factor.get(1.0, 1.0) * region,
                cam.compression[channel] * self.gain_factor.get(1.0, 1.0) * region,
            ]
        )
        return a * (self.sphere_scale * self.channel_scale.get(channel, 1.0)) ** np.arange(3) if relative else a


def simulate_bench(
    camera: BenchCamera | None = None,
    departures: Departures | None = None,
    seed: int = 0,
    *,
    sphere_scale: float | None = None,
    level_errors=None,
) -> tuple[pd.DataFrame, Realisation]:
    """A measurement table (the file a lab would write) and the truth behind it.

    ``sphere_scale`` (true radiance over the sphere's reading) and ``level_errors``
    (each lamp level's relative error) are drawn unless given: cameras measured on one
    sphere in one campaign share them.

    Columns: ``channel, radiance, exposure_s, gain, dn_mean, level, n_frames,
    n_pixels, time_s`` (and ``temperature_c`` when the camera has ``temperatures_c``: the whole plan is
    measured once per sensor temperature); ``radiance`` is the sphere's *nominal* reading, 0 for dark
    rows; ``time_s`` when the row was measured.
    """
    cam = camera or BenchCamera()
    dep = departures or Departures()
    rng = np.random.default_rng(seed)
    gains = sorted({g for _, gs, _ in cam.sweeps for g in gs} | set(cam.darks[1]))
    factor = {g: (1.0 if g == 1.0 else 1.0 + rng.uniform(-dep.gain_step_error, dep.gain_step_error)) for g in gains}
    scale = float(np.exp(cam.sphere_common_rel * rng.standard_normal()))
    shared = cam.sphere_level_rel * rng.standard_normal(len(cam.levels))
    if sphere_scale is not None:
        scale = float(sphere_scale)
    if level_errors is not None:
        shared = np.asarray(level_errors, dtype=float)
    spectral = dep.spectral_level_rel * rng.standard_normal((len(cam.levels), len(cam.channels)))
    prnu = {c: 1.0 + dep.prnu * rng.standard_normal(cam.n_pixels) for c in cam.channels}
    channel_scale = {c: 1.0 + dep.channel_scale_rel * rng.standard_normal() for c in cam.channels}
    real = Realisation(cam, dep, factor, scale, prnu, channel_scale)
    plan = []
    for exposures, sweep_gains, level_idx in cam.sweeps:
        idx = range(len(cam.levels)) if level_idx is None else level_idx
        for t in exposures:
            for g in sweep_gains:
                for li in idx:
                    plan += [(c, li, t, g) for c in cam.channels]
    for t in cam.darks[0]:
        for g in cam.darks[1]:
            plan += [(c, None, t, g) for c in cam.channels]
    sessions = cam.temperatures_c or (BENCH_REFERENCE_C,)
    runs = [(c, li, t, g, temp) for temp in sessions for c, li, t, g in plan]
    rows = []
    for i, (c, li, t, g, temp) in enumerate(runs):
        drift = dep.dark_drift_dn * i / max(len(runs) - 1, 1)
        if li is None:
            nominal, true = 0.0, 0.0
        else:
            nominal = cam.levels[li]
            true = nominal * scale * channel_scale[c] * (1.0 + shared[li] + spectral[li, cam.channels.index(c)])
        dn = real.read(c, true, t, g, rng, drift=drift, temperature_c=temp)
        rows.append(
            {
                **({"temperature_c": temp} if cam.temperatures_c else {}),
                "channel": c,
                "radiance": nominal,
                "exposure_s": t,
                "gain": g,
                "dn_mean": dn,
                "level": f"L{li}" if li is not None else "dark",
                "n_frames": cam.n_frames,
                "n_pixels": cam.n_pixels,
                "time_s": 30.0 * i,  # rows in the order measured, 30 s apart
            }
        )
    return pd.DataFrame(rows), real


def with_held_out(camera: BenchCamera, exposures=(), gains=()) -> BenchCamera:
    """The same camera with some sweep settings left out of the calibration (they are predicted instead)."""
    sweeps = []
    for ex, gs, lv in camera.sweeps:
        ex = tuple(t for t in ex if t not in exposures)
        gs = tuple(g for g in gs if g not in gains)
        if ex and gs:
            sweeps.append((ex, gs, lv))
    return replace(camera, sweeps=tuple(sweeps))
