"""An independent pixel-level sensor: flat and dark frame stacks with known per-pixel truth.

Written apart from the per-pixel model (this module imports only numpy and
pandas).  Every frame is drawn electron by electron the way EMVA 1288
(release 4.0, section 2) describes a linear camera:

- photo-electrons are Poisson with mean ``qe * photons * (1 + prnu_i)``,
  dark electrons Poisson with mean ``dark_current_i * t`` (e-/s, a log-normal
  spread across pixels: real dark-current histograms are skewed, not Normal);
- read noise is Normal in electrons; the offset carries a per-pixel DSNU;
- the sum is converted with the system gain ``K`` (DN/e-), rounded to an
  integer and clipped to ``[0, 2**bits - 1]`` (quantisation noise 1/12 DN^2);
- defects, a fraction ``defect_fraction`` of the pixels in equal parts:
  *hot* (dark current x ``hot_factor``), *dead* (response x ``dead_factor``)
  and *noisy* (read noise x ``noisy_factor``, the random-telegraph pixels that
  a mean image cannot see).

Stacks are written to ``.npy`` files one frame at a time through a memory
map, so a sensor of any size is generated with memory bounded by a few
frames, and a ``conditions.csv`` manifest names each stack.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

__all__ = ["PixelSensor", "SensorTruth", "write_stacks", "DEFECT_KINDS"]

#: defect codes of :attr:`SensorTruth.defect`
DEFECT_KINDS = {0: "none", 1: "hot", 2: "dead", 3: "noisy"}


@dataclass(frozen=True)
class PixelSensor:
    """A monochrome area sensor in datasheet terms (defaults: a 12-bit CCD like EMVA refset001)."""

    height: int = 256
    width: int = 256
    bits: int = 12
    system_gain: float = 0.28  # K, DN per electron
    qe: float = 0.45
    read_noise_e: float = 10.0
    offset_dn: float = 100.0
    dsnu_dn: float = 2.0
    prnu: float = 0.01
    dark_current_e_s: float = 30.0
    dark_current_spread: float = 0.3  # sd of log dark current across pixels
    defect_fraction: float = 0.001
    hot_factor: float = 60.0
    dead_factor: float = 0.3
    noisy_factor: float = 8.0
    nonlinearity: float = 0.0  # relative compression at full scale: y -> y (1 - a y / full scale)
    doubling_c: float = 0.0  # the dark current doubles every this many degC (0: no temperature dependence)
    temperature_ref_c: float = 20.0  # dark_current_e_s is at this temperature
    bayer: str = ""  # e.g. "RGGB": a colour mosaic whose 2 x 2 cell has these filters, row by row
    filter_qe: tuple[tuple[str, float], ...] = (("R", 0.30), ("G", 0.50), ("B", 0.22))  # QE behind each filter

    def qe_map(self) -> np.ndarray | float:
        """Quantum efficiency of every pixel (a mosaic's filters tiled over the sensor)."""
        if not self.bayer:
            return self.qe
        qe = dict(self.filter_qe)
        cell = np.array([[qe[self.bayer[0]], qe[self.bayer[1]]], [qe[self.bayer[2]], qe[self.bayer[3]]]])
        return np.tile(cell, ((self.height + 1) // 2, (self.width + 1) // 2))[: self.height, : self.width]


@dataclass
class SensorTruth:
    """Per-pixel truth of one simulated sensor (what the maps should recover)."""

    relative_gain: np.ndarray  # (H, W), 1 + PRNU deviation (mean over normal pixels ~ 1)
    offset_dn: np.ndarray  # (H, W)
    dark_current_dn_s: np.ndarray  # (H, W), in DN/s
    defect: np.ndarray  # (H, W) int8 codes of DEFECT_KINDS
    sensor: PixelSensor = field(repr=False, default_factory=PixelSensor)


def _truth(sensor: PixelSensor, rng: np.random.Generator) -> tuple[SensorTruth, tuple[np.ndarray, np.ndarray]]:
    shape = (sensor.height, sensor.width)
    gain = 1.0 + sensor.prnu * rng.standard_normal(shape)
    offset = sensor.offset_dn + sensor.dsnu_dn * rng.standard_normal(shape)
    s = sensor.dark_current_spread
    dark_e = sensor.dark_current_e_s * np.exp(s * rng.standard_normal(shape) - s * s / 2)
    read = np.full(shape, sensor.read_noise_e)
    defect = np.zeros(shape, np.int8)
    n = int(round(sensor.defect_fraction * gain.size))
    if n:
        where = rng.choice(gain.size, size=n, replace=False)
        kinds = np.arange(n) % 3 + 1
        defect.flat[where] = kinds
        dark_e.flat[where[kinds == 1]] *= sensor.hot_factor
        gain.flat[where[kinds == 2]] *= sensor.dead_factor
        read.flat[where[kinds == 3]] *= sensor.noisy_factor
    truth = SensorTruth(gain, offset, dark_e * sensor.system_gain, defect, sensor)
    return truth, (dark_e, read)


def write_stacks(
    sensor: PixelSensor,
    out_dir: str | Path,
    *,
    photons: Sequence[float] = (0.0, 2000.0, 8000.0, 20000.0),
    exposure_s: float | list[float] = 0.01,
    frames: int = 4,
    seed: int = 0,
    shot_noise: str = "poisson",
    temperatures_c: list[float] | None = None,
) -> SensorTruth:
    """Write a flat stack (and a dark stack) per illumination level; return the truth.

    Parameters
    ----------
    photons : list of float
        Mean photons per pixel of each flat condition (the sphere level times
        the exposure); a zero gives a dark-only condition.
    exposure_s : float or list of float
        Exposure of each condition (one value for all, or one per level).
    frames : int
        Frames per stack (flat and dark alike).
    seed : int
        Seed of the truth and of every frame.
    temperatures_c : list of float, optional
        Sensor temperature of each condition (a ``temperature_c`` manifest
        column); the dark current scales by ``2^((T - T_ref) / doubling_c)``.
    shot_noise : {"poisson", "normal"}
        ``normal`` draws the electrons from the Normal approximation of the
        Poisson law in float32 (five times faster; for throughput
        benchmarks of very large sensors, where the counts are large).
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    truth, (dark_e, read) = _truth(sensor, rng)
    photons = list(photons)
    exposures = [exposure_s] * len(photons) if np.isscalar(exposure_s) else list(exposure_s)
    full = 2**sensor.bits - 1
    rows = []
    temps = list(temperatures_c) if temperatures_c is not None else [sensor.temperature_ref_c] * len(photons)
    for c, (p, t) in enumerate(zip(photons, exposures, strict=True)):
        heat = 2.0 ** ((temps[c] - sensor.temperature_ref_c) / sensor.doubling_c) if sensor.doubling_c else 1.0
        for kind, level in (("dark", 0.0), ("flat", p)):
            if kind == "flat" and p <= 0:
                continue
            name = f"c{c:02d}_{kind}.npy"
            stack = np.lib.format.open_memmap(
                out / name, mode="w+", dtype=np.uint16, shape=(frames, *truth.offset_dn.shape)
            )
            mean_e = sensor.qe_map() * level * truth.relative_gain + dark_e * t * heat
            if shot_noise == "normal":
                mean_e, sd_e = mean_e.astype(np.float32), np.sqrt(mean_e).astype(np.float32)
            for f in range(frames):
                if shot_noise == "normal":
                    electrons = mean_e + sd_e * rng.standard_normal(mean_e.shape, dtype=np.float32)
                else:
                    electrons = rng.poisson(mean_e)
                dtype = np.float32 if shot_noise == "normal" else np.float64
                signal = sensor.system_gain * (electrons + read * rng.standard_normal(electrons.shape, dtype=dtype))
                if sensor.nonlinearity:
                    signal = signal * (1.0 - sensor.nonlinearity * np.clip(signal, 0, None) / full)
                stack[f] = np.clip(np.rint(truth.offset_dn + signal), 0, full)
            stack.flush()
            del stack
            row = {"file": name, "kind": kind, "exposure_s": t, "gain": 1.0, "photons": level, "condition": c}
            if temperatures_c is not None:
                row["temperature_c"] = temps[c]
            rows.append(row)
    pd.DataFrame(rows).to_csv(out / "conditions.csv", index=False)
    np.savez_compressed(
        out / "truth.npz",
        relative_gain=truth.relative_gain,
        offset_dn=truth.offset_dn,
        dark_current_dn_s=truth.dark_current_dn_s,
        defect=truth.defect,
    )
    return truth
