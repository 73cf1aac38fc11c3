"""When a fit does not describe its data: find what in the library does, and say by how much.

A real camera departs from any fixed model in ways the library has components for: its
nonlinearity arises after the gain rather than in the charge, its response needs a higher
order near full scale, its dark level drifted over a session that recorded no times, an
amplifier glows during long exposures, the lamp's spectrum changes with its level, its
readout's offset follows the sensor temperature.  The
misfit checks (:mod:`bayescal.fitting.misfit`) see that something is wrong; they cannot say
which of these it is (a drifting dark level and a mis-placed nonlinearity both leave
residuals that run along the row order).

:func:`diagnose` refits the table with each candidate switched on (Laplace: the search costs
seconds; the candidates' fits skip the leave-one-setting-out refits, which only the adopted
model's final fit runs), ranks them by PSIS-LOO against the model so far, adopts the best one when its
gain in expected log predictive density exceeds twice its standard error, and repeats
(at most :data:`MAX_STEPS` switches) while a switch adds that much: a fit that passes its
checks may still gain from one more (a roll-off near full scale that a cubic passes but a
quartic describes).  Where the nonlinearity arises is decided by the data whenever gains are
swept (:func:`decide_domain`), failing or not.  :func:`fit_diagnosed`
is a fit that does this when its own checks fail: the user's backend then fits the spec
the search found, the diagnosis rides along in the diagnostics (``summary.json``), and the
fit fails (exit 3) only when nothing in the library explains the data.
"""

from __future__ import annotations

import warnings
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import pandas as pd

from bayescal.errors import FitFailedWarning
from bayescal.fitting.fit import fit
from bayescal.fitting.modegain import mode_fits, paired_gain, screen
from bayescal.fitting.result import Fit
from bayescal.io.table import MeasurementTable
from bayescal.model.components import EFFECTS
from bayescal.model.spec import ModelSpec

__all__ = [
    "Diagnosis",
    "candidates",
    "decide_domain",
    "diagnose",
    "fit_diagnosed",
    "laplace_proxy",
    "other_domain",
    "MAX_STEPS",
]

#: at most this many switches are adopted, one at a time
MAX_STEPS = 3
#: a switch is adopted when it raises elpd_loo by more than this many standard errors of the difference
EVIDENCE_SE = 2.0
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


def decide_domain(table: MeasurementTable, spec: ModelSpec, seed: int = 0) -> tuple[ModelSpec, dict | None, Fit | None]:
    """Where the nonlinearity arises, decided by the data whenever gains are swept: Laplace fits with it in
    the charge (before the gain) and in the output (after it), compared by PSIS-LOO; the other domain is
    taken when it gains more than :data:`EVIDENCE_SE` standard errors.  A charge-domain model fitted to a
    camera whose nonlinearity is the output's passes every check yet its offsets and gains cover the
    truth 0.37 of the time on the independent bench (benchmarks/results/misspecification.md).

    The other domain is screened by its mode first (:func:`~bayescal.fitting.modegain.screen`): when its
    in-sample gain is at most :data:`~bayescal.fitting.modegain.SCREEN_SE` standard errors it cannot be
    taken, and it is not fitted further (``elpd_diff_other`` is then None and ``mode_gain`` says why).

    Returns the chosen spec, the comparison (None when the table cannot tell), and the chosen
    spec's Laplace fit."""
    change = other_domain(spec, table)
    if change is None:
        return spec, None, None
    other = spec.replace(**change)
    info: dict[str, Any] = {"spec": spec.response.nonlinearity_domain, "other": other.response.nonlinearity_domain}
    modes = mode_fits(table, {"spec": laplace_proxy(spec), "other": laplace_proxy(other)})
    kept_out = screen(modes["spec"], modes["other"])
    info |= {"mode_gain": kept_out.gain, "mode_dse": kept_out.se}
    own = _quiet_fit(table, laplace_proxy(spec), "laplace", seed)
    if kept_out.out:
        info |= {"elpd_diff_other": np.nan, "dse": np.nan, "chosen": info["spec"], "screened": True}
        return spec, info, own if laplace_proxy(spec) is spec else None
    fits = [own, _quiet_fit(table, laplace_proxy(other), "laplace", seed)]
    diff, se = _difference(*(_loo(f) for f in fits))
    take = diff > EVIDENCE_SE * se
    chosen = other if take else spec
    info |= {"elpd_diff_other": diff, "dse": se, "chosen": chosen.response.nonlinearity_domain, "screened": False}
    return chosen, info, fits[1 if take else 0] if laplace_proxy(spec) is spec else None


@dataclass(frozen=True)
class Diagnosis:
    """What the search found.

    Attributes
    ----------
    adopted : tuple of str
        The switches adopted, in order (empty: none explained more than the spec).
    spec : ModelSpec
        The spec with them switched on.
    explained : bool
        Whether a fit of ``spec`` passes every check.
    steps : list of pandas.DataFrame
        Per step, every candidate beside the model so far: elpd_diff against it (positive:
        better), its standard error, and whether its fit passed its checks (every check but the
        leave-one-setting-out refits, which only the adopted model's fit runs).
    fit : Fit or None
        The Laplace fit of ``spec`` with every check (None when nothing was adopted).
    trials : dict
        When nothing was adopted: the first step's candidates, name -> (spec, Laplace fit).
    rivals : dict
        The candidates of the step that adopted the last switch which pass their checks and predict the
        data about as well as it (elpd_loo within :data:`EVIDENCE_SE` standard errors of their paired
        difference): name -> (elpd difference, its se, Laplace fit).
    preferred : dict
        When a rival draws the adopted structure and more (:func:`_more_flexible`) it is adopted in its
        place: ``{"candidate": its name, "over": the switch it replaced, "elpd_diff", "dse"}``; the rigid
        one is then among the rivals.
    """

    adopted: tuple[str, ...]
    spec: ModelSpec
    explained: bool
    steps: list
    fit: Fit | None = field(default=None, repr=False, compare=False)
    trials: dict = field(default_factory=dict, repr=False, compare=False)
    rivals: dict = field(default_factory=dict, repr=False, compare=False)
    preferred: dict = field(default_factory=dict, repr=False, compare=False)
    #: the spec changes of a flexible model (:mod:`bayescal.fitting.flexible`), which has no search steps
    merged: dict = field(default_factory=dict, repr=False, compare=False)

    def describe(self) -> str:
        """The diagnosis in words, for the command line."""
        lines = []
        for i, step in enumerate(self.steps):
            lines.append(f"step {i + 1}: each candidate against the model so far (elpd_loo difference +- se):")
            for r in step.itertuples():
                if getattr(r, "screened", False):
                    lines.append(
                        f"  {'-':>9} {'':>9}  {r.candidate}  (screened out: at its mode it gains "
                        f"{r.mode_gain:+.1f} +- {r.mode_dse:.1f} in-sample)"
                    )
                    continue
                ok = "passes its checks" if r.fit_ok else "still fails"
                lines.append(f"  {r.elpd_diff:+9.1f} +- {r.dse:6.1f}  {r.candidate}  ({ok})")
        if self.adopted:
            what = " and ".join(self.adopted)
            verdict = "explains the data" if self.explained else "explains part of the data; the fit still fails"
            lines.append(f"adopted: {what}: {verdict}")
            lines.append("to fit it directly, change the spec: " + _changes_text(self.changes()))
        else:
            lines.append("nothing in the library explains the data better than the spec")
        return "\n".join(lines)

    def changes(self) -> dict:
        """The spec changes adopted, merged by section."""
        if self.merged:
            return self.merged
        merged: dict = {}
        for step in self.steps:
            for r in step.itertuples():
                if r.candidate in self.adopted:
                    for section, keys in r.changes.items():
                        merged.setdefault(section, {}).update(keys)
        return merged

    def to_dict(self) -> dict:
        """JSON-ready form (``summary.json``'s ``diagnostics.diagnosis``)."""
        return {
            "adopted": list(self.adopted),
            "explained": self.explained,
            "changes": self.changes(),
            "steps": [s.drop(columns="changes").to_dict("records") for s in self.steps],
        }


def _changes_text(changes: dict) -> str:
    return "; ".join(f"[{sec}] " + ", ".join(f"{k} = {v!r}" for k, v in keys.items()) for sec, keys in changes.items())


def laplace_proxy(spec: ModelSpec) -> ModelSpec:
    """The spec whose Laplace fits stand for ``spec`` in the domain decision and the diagnosis: ``spec``
    itself, or with its channel pooling off where it pools (the Laplace backend cannot integrate the
    pooling scales; pooling changes the priors of the coefficients, not the equation the candidates
    differ in).  The user's backend then fits the pooled spec the search chose."""
    r, d = spec.response, spec.dark
    if not (r.pooled or d.pooled or r.gain_prior == "pooled"):
        return spec
    gain_prior = "lognormal" if r.gain_prior == "pooled" else r.gain_prior
    return spec.replace(response={"pooled": False, "gain_prior": gain_prior}, dark={"pooled": False})


def _quiet_fit(table, spec, backend, seed) -> Fit:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FitFailedWarning)
        warnings.simplefilter("ignore", UserWarning)
        return fit(table, spec, backend, seed=seed)


def _fit_all(table, specs: list[ModelSpec], seed: int) -> list[Fit]:
    """Laplace fits of ``specs``, two at a time in threads (each a compiled program that runs outside the
    interpreter's lock: on two cores the candidates of one step take about half the time), in order."""
    if len(specs) < 2:
        return [_quiet_fit(table, spec, "laplace", seed) for spec in specs]
    with warnings.catch_warnings():  # here, once: the warning filters are the process's, not a thread's
        warnings.simplefilter("ignore", FitFailedWarning)
        warnings.simplefilter("ignore", UserWarning)
        with ThreadPoolExecutor(CANDIDATE_THREADS) as pool:
            return list(pool.map(lambda spec: fit(table, spec, "laplace", seed=seed), specs))


#: candidate fits run at once (the machine's two cores; a fit's own blocks then run one after the other)
CANDIDATE_THREADS = 2


def _loo(result: Fit):
    import arviz_stats

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        return arviz_stats.loo(result.posterior, pointwise=True)


def _difference(current, candidate) -> tuple[float, float]:
    """elpd_loo of ``candidate`` minus that of ``current`` and the standard error of the difference."""
    return paired_gain(current.elpd_i, candidate.elpd_i)


def diagnose(
    table: MeasurementTable,
    spec: ModelSpec,
    seed: int = 0,
    base: Fit | None = None,
    offered=None,
    by_mode: bool = True,
) -> Diagnosis:
    """Search the library's switches for a model that describes ``table`` (see the module docstring).

    ``base``: a Laplace fit of ``spec`` already made (refitted otherwise).  ``offered(spec, table)``:
    the candidates to try (default :func:`candidates`; :func:`screen_candidates` for a fit that passed).
    ``by_mode``: a candidate whose log-likelihood at its mode gains at most
    :data:`~bayescal.fitting.modegain.SCREEN_SE` standard errors over the model so far's in-sample is not
    fitted further (:func:`~bayescal.fitting.modegain.screen`); off where every candidate the data cannot
    tell from the spec is wanted (:func:`structure_doubt`).
    """
    offered = offered or candidates
    current_spec = spec
    proxy = laplace_proxy(spec)
    if base is not None and base.backend == "laplace" and proxy is spec:
        current: Fit = base
    else:
        current = _quiet_fit(table, proxy, "laplace", seed)
    current_loo = _loo(current)
    adopted: dict[str, dict] = {}  # name -> spec changes, in the order adopted
    steps = []
    trials: dict = {}  # the first step's candidates and their fits
    specs: dict[str, ModelSpec] = {}  # every candidate fitted: its spec

    def step(offers: dict[str, tuple[ModelSpec, dict]]):
        """Fit every offered (spec, changes), rank it against the model so far; the best when the data tell it.
        A candidate whose in-sample gain at its mode cannot reach the evidence is screened out unfitted."""
        rows, fits = [], {}
        searched = {
            name: laplace_proxy(trial).replace(inference={"holdout_check": False})
            for name, (trial, _) in offers.items()
        }
        modes = mode_fits(table, {"": laplace_proxy(current_spec)} | searched) if by_mode else {}
        at_mode = modes.get("")
        screens = {name: screen(at_mode, modes[name]) if at_mode is not None else None for name in offers}
        kept = [name for name, by in screens.items() if by is None or not by.out]
        fitted = dict(zip(kept, _fit_all(table, [searched[name] for name in kept], seed), strict=True))
        for name, (trial, changes) in offers.items():
            by = screens[name]
            screened = {
                "mode_gain": np.nan if by is None else by.gain,
                "mode_dse": np.nan if by is None else by.se,
                "screened": by is not None and by.out,
            }
            if screened["screened"]:
                rows.append(
                    {"candidate": name, "elpd_diff": np.nan, "dse": np.nan, "fit_ok": False, "changes": changes}
                    | screened
                )
                continue
            result = fitted[name]
            if _level_trend(result) >= LAMP_TREND:  # the "lamp errors" follow the signal: a shape, not a lamp
                continue
            loo = _loo(result)
            diff, se = _difference(current_loo, loo)
            fits[name] = (trial, result, loo)
            specs[name] = trial
            rows.append(
                {"candidate": name, "elpd_diff": diff, "dse": se, "fit_ok": result.ok, "changes": changes} | screened
            )
        if not rows:
            return None, fits
        ranked = pd.DataFrame(rows).sort_values(["elpd_diff", "mode_gain"], ascending=False).reset_index(drop=True)
        steps.append(ranked)
        best = ranked.iloc[0]
        return (str(best.candidate) if best.elpd_diff > EVIDENCE_SE * best.dse else None), fits

    won: tuple[str, dict] = ("", {})  # the last adopting step: its winner and every fit of it
    rivals: dict = {}
    replaces: dict[str, tuple[str, dict]] = {}  # a rival -> the adopted switch it would replace, its changes
    for _ in range(MAX_STEPS):
        offers = offered(current_spec, table)
        best, fits = step({name: (current_spec.replace(**changes), changes) for name, changes in offers.items()})
        trials = trials or fits
        if best is None:  # nothing adds what the data can tell
            break
        current_spec, current, current_loo = fits[best]
        adopted[best] = offers[best]
        won = (best, fits)
        replaces = {name: (best, offers[name]) for name in fits if name != best}
    if len(adopted) > 1:  # each switch was judged without those adopted after it: its alternatives, with them
        swaps = _swaps(spec, table, adopted, offered)
        best, fits = step({name: (trial, changes) for name, (_, trial, changes) in swaps.items()})
        if best is not None:
            current_spec, current, current_loo = fits[best]
            replaced, _, changes = swaps[best]
            adopted = dict((best, changes) if n == replaced else (n, c) for n, c in adopted.items())
            won = (best, {n: f for n, f in fits.items() if swaps[n][0] == replaced})  # those in the same place
            replaces = {name: (best, swaps[name][2]) for name in won[1] if name != best}
        else:  # the alternatives kept out are rivals of the switch they would replace
            rivals = _rivals(current_loo, fits)
            replaces |= {name: (swaps[name][0], swaps[name][2]) for name in fits}
    if not adopted:
        first = {name: (trial, result) for name, (trial, result, _) in trials.items()}
        return Diagnosis((), current_spec, bool(current.ok), steps, trials=first)
    if won[0] in won[1]:
        rivals |= _rivals(won[1][won[0]][2], won[1], won[0])
    preferred: dict = {}
    flexible = next((n for n in rivals if _more_flexible(specs[n], current_spec)), None)
    if flexible is not None:  # the data cannot tell a rigid shape from a flexible one: report the flexible one
        diff, se, result = rivals.pop(flexible)
        replaced, changes = replaces[flexible]
        preferred = {"candidate": flexible, "over": replaced, "elpd_diff": round(diff, 1), "dse": round(se, 1)}
        rivals[replaced] = (-diff, se, current)  # the rigid shape is now the flexible one's rival
        adopted = dict((flexible, changes) if n == replaced else (n, c) for n, c in adopted.items())
        current_spec = specs[flexible]
    final = _quiet_fit(table, laplace_proxy(current_spec), "laplace", seed)  # the adopted model, every check
    return Diagnosis(tuple(adopted), current_spec, bool(final.ok), steps, final, rivals=rivals, preferred=preferred)


def _more_flexible(rival: ModelSpec, adopted: ModelSpec) -> bool:
    """``rival`` draws ``adopted``'s structure and more: the monotone roll-off of any smooth shape where
    ``adopted`` has the knee family (the monotone slope's hinges draw a knee; on an exponential or tanh
    saturation the knee, preferred by elpd within its se, left ``A0`` 3-14 sd off where the monotone
    shape covered); or the same model with wider per-channel lamp level errors (a wider prior draws the
    narrower one's errors too: where PSIS-LOO cannot tell 0.3 % from 1 % per level, the narrower size taken
    by the coin of the elpd left ``A0, A1`` covering 0.80 of the time on lamps whose errors were 1 %, the wider
    0.93, on the independent bench)."""
    if rival.response.rolloff == "monotone" and adopted.response.rolloff is True:
        return True
    wider, narrower = rival.sphere.channel_level_rel, adopted.sphere.channel_level_rel
    return 0 < narrower < wider and rival == adopted.replace(sphere={"channel_level_rel": wider})


def _rivals(reference, fits: dict, best: str = "") -> dict:
    """The fits of one step (but ``best``) that pass their checks and predict the data about as well as the
    model whose PSIS-LOO is ``reference``: their elpd_loo minus its is above ``-EVIDENCE_SE`` standard errors
    of that paired difference."""
    out = {}
    for name, (_, result, loo) in fits.items():
        if name == best or not result.ok or result.posterior is None:
            continue
        diff, se = _difference(reference, loo)
        if diff >= -EVIDENCE_SE * se:
            out[name] = (diff, se, result)
    return out


def _swaps(spec: ModelSpec, table: MeasurementTable, adopted: dict[str, dict], offered) -> dict:
    """For each adopted switch, its alternatives (the candidates on ``spec`` that set one of the same keys:
    another roll-off shape, the other domain, another lamp-error size) with every other adopted switch on:
    name -> (the switch it replaces, the trial spec, its changes)."""
    keys = {name: {(sec, k) for sec, ks in changes.items() for k in ks} for name, changes in adopted.items()}
    out: dict = {}
    for alt, changes in offered(spec, table).items():
        if alt in adopted:
            continue
        own = {(sec, k) for sec, ks in changes.items() for k in ks}
        for name in adopted:
            if own & keys[name]:
                trial = spec
                for other, c in adopted.items():
                    trial = trial.replace(**(changes if other == name else c))
                out[f"{alt} (in place of {name})"] = (name, trial, changes)
    return out


#: the rows a range check refits: illuminated readings below this fraction of full scale (and every dark row)
RANGE_FRACTION = 0.6
#: a small-signal gain that moves by more than this many sd of the difference between the two fits fails
RANGE_Z = 4.0


def range_check(table: MeasurementTable, spec: ModelSpec, result: Fit, seed: int = 0) -> tuple[list[str], dict]:
    """Does the response over the whole range agree with the response below :data:`RANGE_FRACTION` of full
    scale?  A higher order adopted for a roll-off near full scale passes every check of the residuals, yet
    the polynomial then bends its small-signal gain to follow the roll-off (on the independent bench
    ``A0, A1`` covered 0.70).  So the low rows are refitted alone (Laplace) and each channel's
    sphere-relative ``A1`` compared: nested fits of the same rows differ by ``sqrt(sd_low^2 - sd_all^2)``.
    """
    frame = table.frame
    low = (frame["stimulus"].to_numpy() == 0) | (frame["dn_mean"].to_numpy() < RANGE_FRACTION * spec.full_scale)
    info: dict = {"fraction": RANGE_FRACTION, "rows": int(low.sum())}
    if low.all() or result.posterior is None:
        return [], info
    try:
        sub = _quiet_fit(
            MeasurementTable.from_frame(table.to_frame()[low].reset_index(drop=True)),
            laplace_proxy(spec),
            "laplace",
            seed,
        )
    except Exception as exc:  # too few levels below the cut for the response's order: nothing to compare
        info["skipped"] = str(exc)
        return [], info
    if sub.posterior is None or result.posterior is None:
        return [], info
    a_all, a_low = (np.asarray(tree["posterior"]["A_rel"])[..., 1] for tree in (result.posterior, sub.posterior))
    mean_all, mean_low = a_all.mean(axis=(0, 1)), a_low.mean(axis=(0, 1))
    sd = np.sqrt(np.maximum(a_low.var(axis=(0, 1)) - a_all.var(axis=(0, 1)), 0.05 * a_low.var(axis=(0, 1))))
    z = (mean_all - mean_low) / sd
    info["z"] = dict(zip(result.model.layout.channels, np.round(z, 2).tolist(), strict=True))
    worst = int(np.argmax(np.abs(z)))
    if abs(z[worst]) <= RANGE_Z:
        return [], info
    channel = result.model.layout.channels[worst]
    return [
        f"channel {channel}: the small-signal gain A1 over the whole range differs from the one below "
        f"{RANGE_FRACTION:.0%} of full scale by {z[worst]:+.1f} sd ({mean_all[worst]:.5g} against "
        f"{mean_low[worst]:.5g}): the response rolls off near full scale in a shape no polynomial of the library "
        f"draws; calibrate below the roll-off (saturation.margin_dn = {spec.full_scale * (1 - RANGE_FRACTION):.0f} "
        "treats the top as clipped)"
    ], info


def kinds_calibration(spec: ModelSpec) -> bool:
    """A camera calibration (not another model kind, such as a film's)."""
    from bayescal.model import kinds

    return kinds.kind_of(spec) == kinds.CALIBRATION


#: per-channel lamp level errors whose posterior means rank-correlate this strongly with the level's stimulus
#: in some channel are a response shape (a roll-off) absorbed level by level, not a lamp's scatter: with 12
#: levels an |rho| this large arises by chance with probability ~0.002
LAMP_TREND = 0.8


def _level_trend(result: Fit) -> float:
    """Largest |Spearman rho| over channels between the fitted per-channel level errors and the levels'
    stimulus (0 without per-channel level errors)."""
    from scipy.stats import spearmanr

    post = None if result.posterior is None else result.posterior["posterior"]
    if post is None or "level_channel_error" not in post:
        return 0.0
    errors = np.asarray(post["level_channel_error"]).mean(axis=(0, 1))  # (level, channel), levels by stimulus
    if errors.shape[0] < 5:
        return 0.0
    order = np.arange(errors.shape[0])
    return float(max(abs(spearmanr(order, errors[:, c]).statistic) for c in range(errors.shape[1])))


def _misfit_only(result: Fit) -> bool:
    """The fit failed its checks of the data (misfit, held-out settings, outlying rows), not its sampler."""
    d = result.diagnostics
    sampler = d.divergences > 0 or (np.isfinite(d.max_rhat) and d.max_rhat > 1.01)
    return not d.ok and not sampler and result.posterior is not None


def fit_diagnosed(
    table: MeasurementTable,
    spec: ModelSpec,
    backend: str = "nuts",
    *,
    seed: int = 0,
    stage=None,
    screen: bool = True,
    strategy: str = "search",
    **kw,
) -> tuple[Fit, Diagnosis | None]:
    """:func:`~bayescal.fitting.fit.fit`, and when the fit does not describe its data, :func:`diagnose`
    (``strategy="search"``) or one flexible model (``"flexible"``, :mod:`bayescal.fitting.flexible`): the
    backend then fits the spec found.  A fit that passes is screened with the candidates over what the table
    records (``screen``; :func:`screen_candidates`).  Returns the final fit (its diagnostics carry the
    diagnosis) and the diagnosis (None when nothing was adopted, or the first fit failed in its sampler)."""
    if backend == "lsq" or not kinds_calibration(spec):  # nothing to diagnose: the baseline, another kind
        return fit(table, spec, backend, seed=seed, stage=stage, **kw), None
    if stage is not None and other_domain(spec, table) is not None:
        stage("where the nonlinearity arises: charge or output, by PSIS-LOO (Laplace)")
    spec, domain, laplace = decide_domain(table, spec, seed)
    if laplace is None and backend == "laplace":
        laplace = fit(table, spec, backend, seed=seed, stage=stage, **kw)
    first = (
        laplace
        if backend == "laplace" and laplace is not None
        else fit(table, spec, backend, seed=seed, stage=stage, **kw)
    )
    if domain is not None:
        first = replace(first, diagnostics=first.diagnostics.with_check("domain", [], domain))
    if first.ok and screen:
        return _screened(table, spec, backend, first, laplace, seed, stage, kw)
    if first.ok or not _misfit_only(first):
        return first, None
    if strategy == "flexible":
        return _flexible(table, spec, backend, first, seed, stage, kw)
    if stage is not None:
        stage("the fit does not describe its data: trying what the library has (Laplace, PSIS-LOO)")
    found = diagnose(table, spec, seed, base=laplace)  # the Laplace fit of this spec, when one was made
    final = first
    if found.adopted:
        if stage is not None:
            stage(f"refitting with {' and '.join(found.adopted)}")
        reused = found.fit if backend == "laplace" and not kw else None  # the diagnosis's own fit of that spec
        final = reused if reused is not None else fit(table, found.spec, backend, seed=seed, **kw)
    diag = final.diagnostics.with_check("diagnosis", [], found.to_dict())
    if found.adopted and final.ok and "order" in found.changes().get("response", {}):
        diag = diag.with_check("range", *range_check(table, found.spec, final, seed))
    doubt = rival_doubt(final, found) if found.adopted and final.ok else None
    if doubt is not None:
        diag = diag.with_check("structure", [], doubt)
    if not found.adopted or not final.ok:
        problem = (
            "nothing in the library explains the data (see diagnosis)"
            if not found.adopted
            else f"with {' and '.join(found.adopted)} the fit still fails (see diagnosis)"
        )
        diag = replace(diag, ok=False, problems=tuple(dict.fromkeys(diag.problems + (problem,))))
    return replace(final, diagnostics=diag), found


def _flexible(table, spec, backend, first: Fit, seed: int, stage, kw) -> tuple[Fit, Diagnosis | None]:
    """The spec with every term the table can inform on (:func:`~bayescal.fitting.flexible.flexible_changes`),
    fitted once by the user's backend; it fails (exit 3) when even that does not describe the data."""
    from bayescal.fitting.flexible import flexible_changes

    changes = flexible_changes(spec, table)
    if not changes:
        return first, None
    if stage is not None:
        stage("the fit does not describe its data: one model with every term the table can inform")
    trial = spec.replace(**changes)
    final = fit(table, trial, backend, seed=seed, **kw)
    terms = tuple(
        f"[{section}] " + ", ".join(f"{k} = {v!r}" for k, v in keys.items()) for section, keys in changes.items()
    )
    found = Diagnosis(terms, trial, bool(final.ok), [], final, merged=changes)
    diag = final.diagnostics.with_check("diagnosis", [], found.to_dict() | {"strategy": "flexible"})
    if not final.ok:
        problem = "with every term the library has for this table on, the fit still fails (see diagnosis)"
        diag = replace(diag, ok=False, problems=tuple(dict.fromkeys(diag.problems + (problem,))))
    return replace(final, diagnostics=diag), found


def _screened(
    table, spec, backend, first: Fit, laplace: Fit | None, seed: int, stage, kw
) -> tuple[Fit, Diagnosis | None]:
    """A fit that passes its checks, screened with the candidates over what the table records
    (:func:`screen_candidates`): a departure that follows the time or the temperature, or a dark signal
    that grows faster than the exposure, can pass every check of the residuals while its offsets are off.
    A candidate adopted by PSIS-LOO replaces the fit only when its own fit passes too."""
    if not screen_candidates(spec, table):
        return first, None
    if stage is not None:
        stage("screening what the table records (time, temperature, dark exposures) by PSIS-LOO (Laplace)")
    found = diagnose(
        table, spec, seed, base=laplace if laplace is not None else None, offered=screen_candidates, by_mode=False
    )
    diag = first.diagnostics.with_check("screen", [], found.to_dict())
    if found.adopted and found.explained:
        reused = found.fit if backend == "laplace" and not kw else None
        final = reused if reused is not None else fit(table, found.spec, backend, seed=seed, **kw)
        if not final.ok:  # the adopted model fails where the spec's passed: keep the spec's
            return replace(first, diagnostics=diag), None
        return replace(final, diagnostics=final.diagnostics.with_check("diagnosis", [], found.to_dict())), found
    doubt = structure_doubt(first, found)
    if doubt is None:
        return replace(first, diagnostics=diag), None
    name, info = doubt
    trial_spec = found.trials[name][0]
    final = fit(table, trial_spec, backend, seed=seed, **kw)
    if not final.ok:
        return replace(first, diagnostics=diag.with_check("structure", [], info)), None
    return replace(
        final, diagnostics=final.diagnostics.with_check("screen", [], found.to_dict()).with_check("structure", [], info)
    ), None


#: a candidate the data cannot tell from the spec (elpd within this many se) that moves a reported coefficient
#: by more than this many of the spec's posterior sds is a doubt about the model the intervals must carry
DOUBT_Z = 2.0


def structure_doubt(base: Fit, found: Diagnosis) -> tuple[str, dict] | None:
    """The screened candidate whose structure the data cannot tell from the spec's but which disagrees on
    the reported coefficients: its elpd_loo is within :data:`EVIDENCE_SE` standard errors of the spec's (or
    above), its fit passes, and it moves some channel's ``A0`` or ``A1`` by more than :data:`DOUBT_Z` of the
    spec's posterior sds.  Every screened candidate nests the spec (its term at zero is the spec), so its
    posterior carries both structures: it is the one reported, and the quantities it moved are named as
    limited by the structure.  Returns (name, what moved) or None."""
    if not found.steps or not found.trials or base.posterior is None:
        return None
    best: tuple[float, str, dict] | None = None
    for r in found.steps[0].itertuples():
        trial = found.trials.get(r.candidate)
        if trial is None or not r.fit_ok or r.elpd_diff < -EVIDENCE_SE * r.dse or trial[1].posterior is None:
            continue
        moved = _moved(base, trial[1])
        if moved and (best is None or max(moved.values()) > best[0]):
            info = {"candidate": str(r.candidate), "moved_sd": moved, "carried": True}
            best = (max(moved.values()), str(r.candidate), info)
    return None if best is None else (best[1], best[2])


def _moved(base: Fit, other: Fit) -> dict[str, float]:
    """The channels' ``A0``/``A1`` (relative to the sphere) whose posterior mean under ``other`` lies more than
    :data:`DOUBT_Z` of ``base``'s posterior sds from ``base``'s: ``"R A0" -> that distance in sds``."""
    ref = base.draws("A_rel")[..., :2]
    mean, sd = ref.mean(axis=0), ref.std(axis=0)
    z = np.abs(other.draws("A_rel")[..., :2].mean(axis=0) - mean) / np.maximum(sd, 1e-300)
    return {
        f"{c} {name}": round(float(z[i, k]), 2)
        for i, c in enumerate(base.model.layout.channels)
        for k, name in enumerate(("A0", "A1"))
        if z[i, k] > DOUBT_Z
    }


def rival_doubt(final: Fit, found: Diagnosis) -> dict | None:
    """The rival of the adopted model (:attr:`Diagnosis.rivals`) that moves the reported coefficients most,
    when one moves some by more than :data:`DOUBT_Z` of ``final``'s sds: the quantities the choice of
    structure limits.  Unlike a screened candidate (:func:`structure_doubt`) a rival does not nest the
    adopted model, so the posterior reported carries one structure and the doubt is named, not integrated;
    except where the adopted model is the flexible one preferred to a rigid rival (:attr:`Diagnosis.preferred`):
    its posterior draws the rival's shape too, and the doubt is carried."""
    if final.posterior is None:
        return None
    best: tuple[float, dict] | None = None
    for name, (diff, se, result) in found.rivals.items():
        moved = _moved(final, result)
        if moved and (best is None or max(moved.values()) > best[0]):
            info = {"candidate": name, "moved_sd": moved, "elpd_diff": round(diff, 1), "dse": round(se, 1)}
            if name == found.preferred.get("over"):  # the flexible shape reported draws this one too
                info |= {"carried": True, "reported": found.preferred["candidate"]}
            else:
                info |= {"carried": False}
            best = (max(moved.values()), info)
    return None if best is None else best[1]
