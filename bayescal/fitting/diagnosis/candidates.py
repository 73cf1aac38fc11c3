"""What the diagnosis may try: the switches of the library a table can inform.

Only switches the table can inform are offered: the nonlinearity's domain needs several illuminated
gains; a drift over the row order a table without ``time_s``; each optional effect says itself what
it needs (:meth:`~bayescal.model.components.base.Effect.candidates`).  A fit that passes its checks is
still screened with the candidates over a covariate the table records (:func:`screen_candidates`).
"""

from __future__ import annotations

from bayescal.io.table import MeasurementTable
from bayescal.model.components import EFFECTS
from bayescal.model.spec import ModelSpec

#: the lamp's level errors per channel tried (relative sd per level: its spectrum changing with its level);
#: PSIS-LOO picks the size the data support
CHANNEL_LEVEL_REL = (0.003, 0.01, 0.03)
#: the scale error of each channel folded in with them: a lamp whose spectrum is not its calibration's shifts
#: each channel's scale too (about 1.5 %), which no table can measure (it is degenerate with that channel's
#: gain); folded in at its prior size, so absolute gains stay covered (0.867 when it followed the level errors)
CHANNEL_SCALE_REL = 0.015
#: a roll-off is tried only when some reading's signal exceeds this fraction of full scale
ROLLOFF_REACH = 0.5


def candidates(spec: ModelSpec, table: MeasurementTable) -> dict[str, dict]:
    """The switches the library can try on ``spec`` for ``table``: name -> spec changes.

    Only switches the table can inform: the nonlinearity's domain needs several illuminated
    gains; a drift over the row order a table without ``time_s``; each optional effect says itself
    what it needs (:meth:`~bayescal.model.components.base.Effect.candidates`: the glow dark rows at
    three or more exposures, an offset against temperature dark rows at two or more temperatures).
    """
    frame = table.frame
    out: dict[str, dict] = {}
    r, d, s = spec.response, spec.dark, spec.sphere
    domain = other_domain(spec, table)
    if domain is not None:
        other = domain["response"]["nonlinearity_domain"]
        where = "after the gain" if other == "output" else "in the charge, before the gain"
        out[f"nonlinearity of the {other} ({where})"] = domain
    if not r.rolloff and _reaches(frame, spec, ROLLOFF_REACH):
        shapes = {
            "a soft roll-off towards full scale": True,
            "a monotone roll-off towards full scale of any smooth shape": "monotone",
        }
        for shape, rolloff in shapes.items():
            out[shape + (" (not a polynomial)" if rolloff is True else "")] = {"response": {"rolloff": rolloff}}
        if domain is not None:  # the domain was decided without a roll-off; with one it may be the other
            other = domain["response"]["nonlinearity_domain"]
            for shape, rolloff in shapes.items():
                out[f"{shape}, with the nonlinearity of the {other}"] = {
                    "response": {"rolloff": rolloff, "nonlinearity_domain": other}
                }
    if r.order < 4:
        out[f"response order {r.order + 1} (a roll-off near full scale)"] = {"response": {"order": r.order + 1}}
    timed = "time_s" in frame and frame["time_s"].nunique() > 1
    drifting = d.drift is True or d.drift == "order" or (d.drift == "auto" and timed)
    if not drifting:
        if timed:
            out["a dark level that drifted over time_s"] = {"dark": {"drift": True}}
        else:
            out["a dark level that drifted over the run (the rows' order)"] = {"dark": {"drift": "order"}}
    out |= _temperature_laws(spec, frame)
    for effect in EFFECTS:  # each effect says when the table can measure it
        out |= effect.candidates(spec.effect(effect.section), spec, frame)
    if s.channel_level_rel == 0:
        for rel in CHANNEL_LEVEL_REL:
            name = f"lamp errors that differ by channel, {rel:.1%} per level (its spectrum changes with its level)"
            out[name] = {"sphere": {"channel_level_rel": rel, "channel_scale_rel": CHANNEL_SCALE_REL}}
    return out


def _temperature_laws(spec: ModelSpec, frame) -> dict[str, dict]:
    """When the table records the sensor temperature at two or more values: the dark current's doubling
    (dark rows at two or more exposures and temperatures tell it from an offset), and every temperature
    law the library has that is not on yet, together (a sensor that warms moves its dark current, its black
    level and its responsivity at once; tried one at a time, each is judged with the others missing)."""
    if "temperature_c" not in frame or frame["temperature_c"].nunique() < 2:
        return {}
    dark = frame["stimulus"].to_numpy() == 0
    darks = frame.loc[dark]
    laws: dict[str, dict] = {}
    if (
        not spec.dark.temperature
        and spec.dark.exposure_slope
        and darks["temperature_c"].nunique() >= 2
        and darks["exposure_s"].nunique() >= 2
    ):
        laws["dark"] = {"temperature": True}
    if spec.effect("offset_temperature").enabled is not True and darks["temperature_c"].nunique() >= 2:
        laws["offset_temperature"] = {"enabled": True}
    lit = frame.loc[~dark, "temperature_c"].nunique() >= 2
    if spec.effect("responsivity").temperature is not True and lit:
        laws["responsivity"] = {"temperature": True}
    out: dict[str, dict] = {}
    if "dark" in laws:
        out["a dark current that doubles with the sensor temperature (temperature_c)"] = {"dark": laws["dark"]}
    if len(laws) > 1:
        out["every temperature law together: dark current, black level and responsivity (temperature_c)"] = laws
    return out


#: the sections whose candidates follow a covariate the table records (time, temperature) or the dark rows'
#: exposures: screened even when a fit passes its checks, since their departures can pass every check
SCREENED = ("dark", "glow", "offset_temperature", "responsivity", "stimulus_drift", "offset_drift", "lamp_colour")


def screen_candidates(spec: ModelSpec, table: MeasurementTable) -> dict[str, dict]:
    """The candidates a fit that passes its checks is still screened with: those over a covariate the table
    records (``time_s``, ``temperature_c``) and the amplifier glow; not those over the rows' order."""
    frame = table.frame
    recorded = {c for c in ("time_s", "temperature_c") if c in frame and frame[c].nunique() > 1}
    out = {}
    for name, changes in candidates(spec, table).items():
        if not set(changes) <= set(SCREENED):
            continue
        over = [v.get("over") for v in changes.values() if isinstance(v, dict) and "over" in v]
        if any(o not in recorded for o in over):
            continue
        if "dark" in changes and "drift" in changes["dark"]:
            continue
        out[name] = changes
    return out


def _reaches(frame, spec: ModelSpec, fraction: float) -> bool:
    """Some illuminated reading lies above ``fraction`` of full scale (its dark level subtracted roughly)."""
    lit = frame["stimulus"] > 0
    dark = frame.loc[~lit, "dn_mean"].min() if (~lit).any() else 0.0
    return bool(((frame.loc[lit, "dn_mean"] - dark) > fraction * spec.full_scale).any())


def other_domain(spec: ModelSpec, table: MeasurementTable) -> dict | None:
    """The spec change that moves the nonlinearity to its other domain, when the table can tell them apart
    (a nonlinear response measured at several illuminated gains); None otherwise."""
    frame = table.frame
    if spec.response.order < 2 or frame.loc[frame["stimulus"] > 0, "gain"].nunique() < 2:
        return None
    return {
        "response": {"nonlinearity_domain": "output" if spec.response.nonlinearity_domain == "charge" else "charge"}
    }
