"""Cameras nobody described: a second independent simulator whose departures are drawn at random from
families, so that no test is passed by adding one named term.

Written from the physics apart from the model (it imports numpy and pandas only, and shares no code
with :mod:`bayescal.validation.bench` either).  Each session draws a camera (responsivities, a gentle
compression, offsets and dark currents per gain step, gain steps off their labels, a shutter offset)
and, from each family below, one member with its own parameters:

- **roll-off** towards full scale: none; a knee of any sharpness ``S / (1 + (S/K)^p)^(1/p)``; a tanh;
  an exponential saturation ``T (1 - exp(-S/T))``;
- **lamp**: stable; warming up (low at the start, recovering exponentially); a ramp; an overshoot
  (high at the start, settling): every lamp is at its calibrated radiance by the session's end;
- **offset drift** over the session, the same DN in every channel: none; linear; a warm-up that
  settles; a slow oscillation (a building's air conditioning);
- **dark law**: a dark current linear in the exposure; or with amplifier glow (``t^2``, per channel);
- **temperature history**: constant at 20 degC; or a sensor warming during the session by 3-10 degC
  (recorded in ``temperature_c``), its dark current doubling every 5-9 degC and each channel's black
  level moving by up to 1 DN per degC;
- **crosstalk** between neighbouring colour channels (0-3 % of the neighbour's signal);
- **dark frames**: interleaved with the sweeps, or all taken at the session's end;
- **stray light**: none; a light leak, a constant radiance (4-20 % of the lowest level, its own colour)
  that reaches the sensor in every illuminated frame and in no dark frame;
- **black level**: steady; or jittering from frame to frame by 0.7-2.5 DN, the same in the channels of one
  frame;
- **lamp colour**: constant; or following the lamp's colour temperature, which falls as the lamp is dimmed
  (Wien's law per band: the red band gains 1-4 % on the blue from the highest level to the lowest,
  systematically, the channels' mean as the broadband reading says);
- **thermometer**: on the die; or on the housing, leading the die, which follows it with a lag of a
  tenth to a third of the session (where the temperature changes).

Every frame is read as the mean of many pixels of many frames, each clipped to the ADC's range and
quantised; the three channels of one frame share its ``time_s``.  The truth is what a calibration
should report: each channel's ``A0`` (the dark level at gain 1, the reference exposure, 20 degC, at
the session's start) and ``A1`` (its small-signal response at gain 1 and the reference exposure,
per unit of the sphere's nominal radiance, with the lamp as calibrated).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd

__all__ = ["WildSession", "draw_session", "simulate_wild", "FAMILIES", "CLASSIC"]

CHANNELS = ("R", "G", "B")
BITS = 12
FULL_SCALE = 2.0**BITS - 1
T_REF = 0.004
REFERENCE_C = 20.0
LEVELS = (1.5, 3.0, 5.0, 7.5, 10.0, 12.5, 15.0, 17.5, 21.5, 24.0, 27.0, 30.0)
GAINS = (1.0, 2.0, 3.0, 4.0)
#: the families and their members (the first member of each is "no departure")
FAMILIES = {
    "rolloff": ("none", "knee", "tanh", "exponential"),
    "lamp": ("stable", "warm-up", "ramp", "overshoot"),
    "offset_drift": ("none", "linear", "settling", "oscillation"),
    "dark_law": ("linear", "glow"),
    "temperature": ("constant", "warming"),
    "crosstalk": ("none", "neighbour"),
    "darks": ("interleaved", "at the end"),
    "stray": ("none", "leak"),
    "black_level": ("steady", "jitter"),
    "lamp_colour": ("constant", "tilt"),
    "thermometer": ("on the die", "leading"),
}
#: the first seven families, whose sessions keep the draws they had before the last four were added
#: (a seed draws the same camera and session from them as it did)
CLASSIC = tuple(FAMILIES)[:7]


@dataclass(frozen=True)
class WildSession:
    """One camera and session: its members of each family and every parameter drawn."""

    members: dict
    responsivity: np.ndarray  # DN per unit radiance at gain 1, T_REF, per channel
    compression: np.ndarray  # DN per unit radiance squared, per channel (<= 0)
    offset: dict  # gain -> DN per channel
    dark_current: dict  # gain -> DN/s
    gain_true: dict  # gain label -> true gain
    shutter_s: float
    sphere_scale: float
    level_error: np.ndarray
    prnu: np.ndarray  # each channel's pixels' response over the channel's (1 % spread), (3, pixels)
    params: dict = field(default_factory=dict)

    def label(self) -> str:
        """The departures in words: the members that are not 'none'."""
        parts = [f"{k}: {v}" for k, v in self.members.items() if v != FAMILIES[k][0]]
        return "; ".join(parts) or "none"

    # ------------------------------------------------------------------ physics, from a datasheet
    def _rolloff(self, s: np.ndarray) -> np.ndarray:
        kind, p = self.members["rolloff"], self.params
        if kind == "knee":
            return s / (1.0 + (np.maximum(s, 0.0) / p["knee"]) ** p["sharpness"]) ** (1.0 / p["sharpness"])
        if kind == "tanh":
            return p["top"] * np.tanh(s / p["top"])
        if kind == "exponential":
            return p["top"] * -np.expm1(-s / p["top"])
        return s

    def lamp(self, tau: float) -> float:
        """The lamp's radiance over its calibration at session fraction ``tau`` (1 at the end)."""
        kind, p = self.members["lamp"], self.params
        if kind == "warm-up":
            return 1.0 - p["lamp_amp"] * (np.exp(-tau / p["lamp_tau"]) - np.exp(-1.0 / p["lamp_tau"]))
        if kind == "ramp":
            return 1.0 + p["lamp_amp"] * (tau - 1.0)
        if kind == "overshoot":
            return 1.0 + p["lamp_amp"] * (np.exp(-tau / p["lamp_tau"]) - np.exp(-1.0 / p["lamp_tau"]))
        return 1.0

    def offset_drift(self, tau: float) -> float:
        """DN added to every reading at session fraction ``tau`` (0 at the start)."""
        kind, p = self.members["offset_drift"], self.params
        if kind == "linear":
            return p["drift_dn"] * tau
        if kind == "settling":
            return p["drift_dn"] * -np.expm1(-tau / 0.25)
        if kind == "oscillation":
            return p["drift_dn"] * np.sin(2.0 * np.pi * tau / p["period"])
        return 0.0

    def temperature(self, tau: float) -> float:
        """The die's temperature at session fraction ``tau``."""
        if self.members["temperature"] == "warming":
            if self.members["thermometer"] == "leading":  # the die follows the housing with a lag
                return self._housing(tau - self.params["lag"])
            return self._housing(tau)
        return REFERENCE_C

    def recorded_temperature(self, tau: float) -> float:
        """What the thermometer reads at ``tau``: the die's, or the housing's, which leads it."""
        return self._housing(tau) if self.members["temperature"] == "warming" else REFERENCE_C

    def _housing(self, tau: float) -> float:
        tau = max(tau, 0.0)
        return REFERENCE_C + self.params["warming_c"] * -np.expm1(-tau / 0.3) / -np.expm1(-1.0 / 0.3)

    def lamp_colour(self, level: int) -> np.ndarray:
        """Each channel's radiance over the lamp's calibration at sphere level ``level``: 1, or following the
        lamp's colour temperature, which rises with its level (Wien's law per band at the channels' centre
        wavelengths, relative to the channels' mean, which the broadband reading follows): dimmed, the red
        band gains on the blue by ``tilt`` from the highest level to the lowest."""
        if self.members["lamp_colour"] != "tilt":
            return np.ones(3)
        u = np.log(LEVELS[level] / LEVELS[0]) / np.log(LEVELS[-1] / LEVELS[0])  # 0 .. 1 over the levels
        c2 = 1.4388e-2  # second radiation constant, m K
        wavelength = np.array([610e-9, 540e-9, 465e-9])
        t_mid = 2800.0
        # the colour temperatures' span that moves red against blue by ``tilt`` (1/T_low - 1/T_high)
        span = self.params["tilt"] / (c2 * (1.0 / wavelength[2] - 1.0 / wavelength[0]))
        inverse_t = 1.0 / t_mid + span * (0.5 - u)
        log_band = -c2 / wavelength * (inverse_t - 1.0 / t_mid)
        return np.exp(log_band - log_band.mean())

    def stray(self) -> np.ndarray:
        """The radiance a light leak adds to every illuminated frame, per channel (0 without)."""
        return self.params["leak"] if self.members["stray"] == "leak" else np.zeros(3)

    def dark_dn(self, c: int, t: float, g: float, temp: float) -> float:
        p = self.params
        current = self.dark_current[g] * t
        if self.members["temperature"] == "warming":
            current *= 2.0 ** ((temp - REFERENCE_C) / p["doubling_c"])
        level = self.offset[g][c] + current + p.get("bias_per_c", np.zeros(3))[c] * (temp - REFERENCE_C)
        if self.members["dark_law"] == "glow":
            level += p["glow"][c] * t * t * g
        return level

    def signal_dn(self, radiance: np.ndarray, t: float, g: float) -> np.ndarray:
        """Mean signal of each channel (DN, before the dark level), crosstalk and roll-off included."""
        k = (t + self.shutter_s) / (T_REF + self.shutter_s)
        x = radiance * k
        s = (self.responsivity * x + self.compression * x * x) * self.gain_true[g]
        if self.members["crosstalk"] == "neighbour":
            s = s + self.params["crosstalk"] * (np.roll(s, 1) + np.roll(s, -1)) / 2.0
        return self._rolloff(s)

    def truth(self) -> pd.DataFrame:
        """A0 and A1 per channel (at gain 1, T_REF, 20 degC, the session's start, per nominal radiance)."""
        a0 = np.array([self.dark_dn(c, T_REF, 1.0, REFERENCE_C) for c in range(3)])
        a1 = self.responsivity * self.gain_true[1.0] * self.sphere_scale
        if self.members["crosstalk"] == "neighbour":
            a1 = a1 + self.params["crosstalk"] * (np.roll(a1, 1) + np.roll(a1, -1)) / 2.0
        a1 = a1 * self.prnu[:, : self.params.get("n_pixels", self.prnu.shape[1])].mean(axis=1)  # the region's
        return pd.DataFrame({"channel": CHANNELS, "A0": a0, "A1": a1})


def draw_session(seed: int, departures: int | None = None, families: tuple[str, ...] = CLASSIC) -> WildSession:
    """A camera and a session (``seed``): ``departures`` of ``families`` (default: one or two, drawn; the
    families: :data:`CLASSIC`, or every one of :data:`FAMILIES`) depart, each by a member drawn at random
    among its departures; the others keep their first member."""
    rng = np.random.default_rng([seed, 0x5EED])
    n = int(rng.integers(1, 3)) if departures is None else departures
    departing = set(rng.choice(list(families), size=n, replace=False))
    members = {k: str(rng.choice(v[1:])) if k in departing else v[0] for k, v in FAMILIES.items() if k in families}
    members |= {k: v[0] for k, v in FAMILIES.items() if k not in families}
    p: dict = {}
    if members["rolloff"] == "knee":
        p |= {"knee": rng.uniform(1.1, 2.0) * FULL_SCALE, "sharpness": rng.uniform(2.0, 8.0)}
    elif members["rolloff"] in ("tanh", "exponential"):
        p["top"] = rng.uniform(1.1, 1.8) * FULL_SCALE
    if members["lamp"] != "stable":
        p |= {"lamp_amp": rng.uniform(0.01, 0.04), "lamp_tau": rng.uniform(0.05, 0.3)}
    if members["offset_drift"] != "none":
        p |= {"drift_dn": rng.uniform(2.0, 8.0) * rng.choice([-1.0, 1.0]), "period": rng.uniform(0.5, 1.5)}
    if members["dark_law"] == "glow":
        p["glow"] = rng.uniform(0.3, 2.0, 3) * 5e4
    if members["temperature"] == "warming":
        p |= {
            "warming_c": rng.uniform(3.0, 10.0),
            "doubling_c": rng.uniform(5.0, 9.0),
            "bias_per_c": rng.uniform(-1.0, 1.0, 3),
        }
    if members["crosstalk"] == "neighbour":
        p["crosstalk"] = rng.uniform(0.0, 0.03)
    if members["stray"] == "leak":
        p["leak"] = LEVELS[0] * rng.uniform(0.04, 0.2) * rng.uniform(0.5, 1.5, 3)
    if members["black_level"] == "jitter":
        p["jitter_dn"] = rng.uniform(0.7, 2.5)
    if members["lamp_colour"] == "tilt":
        p["tilt"] = rng.uniform(0.01, 0.04)
    if members["thermometer"] == "leading":
        p["lag"] = rng.uniform(0.1, 0.33)
        if members["temperature"] != "warming":  # a thermometer that leads a constant temperature reads it
            members["temperature"] = "warming"
    if members["temperature"] == "warming" and "warming_c" not in p:
        p |= {
            "warming_c": rng.uniform(3.0, 10.0),
            "doubling_c": rng.uniform(5.0, 9.0),
            "bias_per_c": rng.uniform(-1.0, 1.0, 3),
        }
    responsivity = np.array([rng.uniform(45, 80), rng.uniform(22, 40), rng.uniform(13, 25)])
    base = rng.uniform(30.0, 70.0)
    offset = {g: base * g + rng.normal(0.0, 2.0, 3) for g in GAINS}
    current = rng.uniform(100.0, 400.0)
    return WildSession(
        members=members,
        responsivity=responsivity,
        compression=-responsivity * rng.uniform(0.0, 0.004, 3),
        offset=offset,
        dark_current={g: current * g for g in GAINS},
        gain_true={g: g * (1.0 if g == 1.0 else 1.0 + rng.uniform(-0.05, 0.05)) for g in GAINS},
        shutter_s=rng.uniform(-2e-4, 2e-4),
        sphere_scale=float(np.exp(0.03 * rng.standard_normal())),
        level_error=0.005 * rng.standard_normal(len(LEVELS)),
        prnu=1.0 + 0.01 * rng.standard_normal((3, 256)),
        params=p,
    )


def _plan(darks_at_end: bool) -> list[tuple]:
    """Frames in the order measured: (level index or None, exposure, gain)."""
    lit = [(li, t, 1.0) for t in (0.004, 0.008, 0.01) for li in range(len(LEVELS))]
    lit += [(li, 0.008, g) for g in GAINS[1:] for li in (0, 2, 4, 6)]
    darks = [(None, t, g) for g in GAINS for t in (0.0027, 0.004, 0.008, 0.01)]
    if darks_at_end:
        return lit + darks
    blocks = np.array_split(np.arange(len(lit)), len(GAINS))
    out: list[tuple] = []
    for block, g in zip(blocks, GAINS, strict=True):  # each gain's darks after a block of the sweep
        out += [lit[i] for i in block] + [d for d in darks if d[2] == g]
    return out


def simulate_wild(
    seed: int,
    departures: int | None = None,
    n_frames: int = 20,
    n_pixels: int = 256,
    families: tuple[str, ...] = CLASSIC,
) -> tuple[pd.DataFrame, WildSession]:
    """The measurement table a lab would write for the session drawn by ``seed`` (see :func:`draw_session`),
    and the session."""
    session = draw_session(seed, departures, families)
    session.params["n_pixels"] = n_pixels  # the region the truth's response is the mean of
    if n_pixels > session.prnu.shape[1]:
        raise ValueError(f"n_pixels = {n_pixels}; the simulated region has {session.prnu.shape[1]} pixels")
    rng = np.random.default_rng([seed, 0xF00D])
    plan = _plan(session.members["darks"] == "at the end")
    rows = []
    for i, (li, t, g) in enumerate(plan):
        tau = i / (len(plan) - 1)
        temp = session.temperature(tau)
        nominal = 0.0 if li is None else LEVELS[li]
        true = nominal * session.sphere_scale * (1.0 + (0.0 if li is None else session.level_error[li]))
        if li is None:
            signal = np.zeros(3)
        else:
            radiance = true * session.lamp(tau) * session.lamp_colour(li) + session.stray()
            signal = session.signal_dn(radiance, t, g)
        jitter = session.params["jitter_dn"] * rng.standard_normal() if "jitter_dn" in session.params else 0.0
        for c, channel in enumerate(CHANNELS):
            dark = session.dark_dn(c, t, g, temp) + session.offset_drift(tau) + jitter
            pixels = signal[c] * session.prnu[c, :n_pixels]  # the same pixels in every frame
            electrons = np.maximum(pixels, 0.0) * 4.0 / g  # 4 electrons per DN at gain 1
            sd = np.sqrt((3.0 * g) ** 2 + electrons * (g / 4.0) ** 2)  # read noise 3 DN at gain 1, and shot noise
            frames = dark + pixels + sd * rng.standard_normal((n_frames, n_pixels))
            dn = float(np.clip(np.round(frames), 0.0, FULL_SCALE).mean())
            rows.append(
                {
                    "channel": channel,
                    "radiance": nominal,
                    "exposure_s": t,
                    "gain": g,
                    "dn_mean": dn,
                    "level": "dark" if li is None else f"L{li}",
                    "n_frames": n_frames,
                    "n_pixels": n_pixels,
                    "time_s": 25.0 * i,
                    "temperature_c": round(session.recorded_temperature(tau), 2),
                }
            )
    return pd.DataFrame(rows), session
