"""The search: refit the table with each candidate switched on, adopt the best while the data tell it.

Each step refits the table with every offered candidate (Laplace; the candidates' fits skip the
leave-one-setting-out refits, which only the adopted model's final fit runs), ranks them by PSIS-LOO
against the model so far, and adopts the best when its gain in expected log predictive density exceeds
:data:`~bayescal.fitting.diagnosis.trials.EVIDENCE_SE` standard errors of the paired difference; at most
:data:`MAX_STEPS` switches.  A :class:`Search` owns the state of one search (the model so far, what was
adopted, each step's ranking, the rivals of the last adopted switch); :func:`diagnose` runs one.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pandas as pd

from bayescal.fitting.diagnosis.candidates import candidates
from bayescal.fitting.diagnosis.found import Diagnosis
from bayescal.fitting.diagnosis.trials import EVIDENCE_SE, difference, fit_all, laplace_proxy, psis_loo, quiet_fit
from bayescal.fitting.modegain import mode_fits, screen
from bayescal.fitting.result import Fit
from bayescal.io.table import MeasurementTable
from bayescal.model.spec import ModelSpec

#: at most this many switches are adopted, one at a time
MAX_STEPS = 3
#: per-channel lamp level errors whose posterior means rank-correlate this strongly with the level's stimulus
#: in some channel are a response shape (a roll-off) absorbed level by level, not a lamp's scatter: with 12
#: levels an |rho| this large arises by chance with probability ~0.002
LAMP_TREND = 0.8

#: the candidates a search may try on a spec: name -> spec changes
Offered = Callable[[ModelSpec, MeasurementTable], dict[str, dict]]


class Search:
    """One search over the library's switches for a model that describes ``table``.

    Parameters
    ----------
    table, spec, seed
        The data, the spec to start from, the fits' seed.
    base : Fit, optional
        A Laplace fit of ``spec`` already made (refitted otherwise).
    offered : callable, optional
        The candidates to try (default :func:`~bayescal.fitting.diagnosis.candidates.candidates`).
    by_mode : bool
        Screen out, unfitted, a candidate whose in-sample gain at its mode cannot reach the evidence
        (:func:`~bayescal.fitting.modegain.screen`).
    """

    def __init__(
        self,
        table: MeasurementTable,
        spec: ModelSpec,
        seed: int = 0,
        base: Fit | None = None,
        offered: Offered | None = None,
        by_mode: bool = True,
    ) -> None:
        self.table, self.spec, self.seed, self.by_mode = table, spec, seed, by_mode
        self.offered: Offered = offered or candidates
        self.current_spec = spec
        if base is not None and base.backend == "laplace" and laplace_proxy(spec) is spec:
            self.current: Fit = base
        else:
            self.current = quiet_fit(table, laplace_proxy(spec), "laplace", seed)
        self.current_loo = psis_loo(self.current)
        self.adopted: dict[str, dict] = {}  # name -> spec changes, in the order adopted
        self.steps: list[pd.DataFrame] = []
        self.trials: dict = {}  # the first step's candidates: name -> (spec, fit, loo)
        self.specs: dict[str, ModelSpec] = {}  # every candidate fitted: its spec
        self.won: tuple[str, dict] = ("", {})  # the last adopting step: its winner and every fit of it
        self.rivals: dict = {}
        self.replaces: dict[str, tuple[str, dict]] = {}  # a rival -> the adopted switch it would replace, its changes

    def step(self, offers: dict[str, tuple[ModelSpec, dict]]) -> tuple[str | None, dict]:
        """Fit every offered (spec, changes) and rank it against the model so far; returns the best when the
        data tell it (else None) and the fits, name -> (spec, fit, loo).  A candidate whose in-sample gain at
        its mode cannot reach the evidence is screened out unfitted."""
        searched = {
            name: laplace_proxy(trial).replace(inference={"holdout_check": False})
            for name, (trial, _) in offers.items()
        }
        modes = mode_fits(self.table, {"": laplace_proxy(self.current_spec)} | searched) if self.by_mode else {}
        at_mode = modes.get("")
        screens = {name: screen(at_mode, modes[name]) if at_mode is not None else None for name in offers}
        kept = [name for name, by in screens.items() if by is None or not by.out]
        starts = [modes[name].mode if name in modes else None for name in kept]  # each screened mode: polished
        fitted = dict(zip(kept, fit_all(self.table, [searched[name] for name in kept], self.seed, starts), strict=True))
        rows, fits = [], {}
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
                )
                rows[-1] |= screened
                continue
            result = fitted[name]
            if level_trend(result) >= LAMP_TREND:  # the "lamp errors" follow the signal: a shape, not a lamp
                continue
            loo = psis_loo(result)
            diff, se = difference(self.current_loo, loo)
            fits[name] = (trial, result, loo)
            self.specs[name] = trial
            rows.append({"candidate": name, "elpd_diff": diff, "dse": se, "fit_ok": result.ok, "changes": changes})
            rows[-1] |= screened
        if not rows:
            return None, fits
        ranked = pd.DataFrame(rows).sort_values(["elpd_diff", "mode_gain"], ascending=False).reset_index(drop=True)
        self.steps.append(ranked)
        best = ranked.iloc[0]
        return (str(best.candidate) if best.elpd_diff > EVIDENCE_SE * best.dse else None), fits

    def forward(self) -> None:
        """Adopt one switch at a time, at most :data:`MAX_STEPS`, while one adds what the data can tell.  A
        candidate that lost at an earlier step (:func:`lost`) is not offered again."""
        for _ in range(MAX_STEPS):
            offers = self.offered(self.current_spec, self.table)
            gone = set().union(*(lost(step) for step in self.steps))
            offers = {name: changes for name, changes in offers.items() if name not in gone}
            trials = {name: (self.current_spec.replace(**changes), changes) for name, changes in offers.items()}
            best, fits = self.step(trials)
            self.trials = self.trials or fits
            if best is None:
                return
            self.current_spec, self.current, self.current_loo = fits[best]
            self.adopted[best] = offers[best]
            self.won = (best, fits)
            self.replaces = {name: (best, offers[name]) for name in fits if name != best}

    def reconsider(self) -> None:
        """Each switch was judged without those adopted after it: try its alternatives with them on; an
        alternative that wins replaces it, those kept out become its rivals."""
        if len(self.adopted) < 2:
            return
        swaps = alternatives(self.spec, self.table, self.adopted, self.offered)
        best, fits = self.step({name: (trial, changes) for name, (_, trial, changes) in swaps.items()})
        if best is None:
            self.rivals = rivals_of(self.current_loo, fits)
            self.replaces |= {name: (swaps[name][0], swaps[name][2]) for name in fits}
            return
        self.current_spec, self.current, self.current_loo = fits[best]
        replaced, _, changes = swaps[best]
        self.adopted = swapped(self.adopted, replaced, best, changes)
        self.won = (best, {n: f for n, f in fits.items() if swaps[n][0] == replaced})  # those in the same place
        self.replaces = {name: (best, swaps[name][2]) for name in self.won[1] if name != best}

    def prefer_flexible(self) -> dict:
        """Where a rival draws the adopted structure and more (:func:`more_flexible`) and the data cannot tell
        them apart, adopt the rival; the rigid one becomes its rival.  Returns what was preferred (or {})."""
        flexible = next((n for n in self.rivals if more_flexible(self.specs[n], self.current_spec)), None)
        if flexible is None:
            return {}
        diff, se, _ = self.rivals.pop(flexible)
        replaced, changes = self.replaces[flexible]
        self.rivals[replaced] = (-diff, se, self.current)
        self.adopted = swapped(self.adopted, replaced, flexible, changes)
        self.current_spec = self.specs[flexible]
        return {"candidate": flexible, "over": replaced, "elpd_diff": round(diff, 1), "dse": round(se, 1)}

    def run(self) -> Diagnosis:
        """The whole search: forward steps, the adopted switches reconsidered, the flexible preferred."""
        self.forward()
        self.reconsider()
        if not self.adopted:
            first = {name: (trial, result) for name, (trial, result, _) in self.trials.items()}
            return Diagnosis((), self.current_spec, bool(self.current.ok), self.steps, trials=first)
        best, fits = self.won
        if best in fits:
            self.rivals |= rivals_of(fits[best][2], fits, best)
        preferred = self.prefer_flexible()
        final = quiet_fit(self.table, laplace_proxy(self.current_spec), "laplace", self.seed)  # every check
        return Diagnosis(
            tuple(self.adopted),
            self.current_spec,
            bool(final.ok),
            self.steps,
            final,
            rivals=self.rivals,
            preferred=preferred,
        )


def diagnose(
    table: MeasurementTable,
    spec: ModelSpec,
    seed: int = 0,
    base: Fit | None = None,
    offered: Offered | None = None,
    by_mode: bool = True,
) -> Diagnosis:
    """Search the library's switches for a model that describes ``table`` (:class:`Search`).

    ``offered``: :func:`~bayescal.fitting.diagnosis.candidates.candidates` by default,
    :func:`~bayescal.fitting.diagnosis.candidates.screen_candidates` for a fit that passed; ``by_mode`` off
    where every candidate the data cannot tell from the spec is wanted
    (:func:`~bayescal.fitting.diagnosis.doubts.structure_doubt`).
    """
    return Search(table, spec, seed, base, offered, by_mode).run()


def swapped(adopted: dict[str, dict], old: str, new: str, changes: dict) -> dict[str, dict]:
    """The adopted switches with ``old`` replaced by ``new`` (whose spec changes are ``changes``), in place."""
    return {(new if n == old else n): (changes if n == old else c) for n, c in adopted.items()}


def lost(ranked: pd.DataFrame) -> set[str]:
    """The candidates of a step that lost: at their mode they fit the rows worse than the model without
    them (an in-sample gain below zero: a structure the data pull away from, such as the other
    nonlinearity domain), or their elpd_loo fell below the model's by more than
    :data:`~bayescal.fitting.diagnosis.trials.EVIDENCE_SE` standard errors, or their fit gave none.  A
    later step, with one more switch on, does not offer them again: on the independent simulator's
    departures the candidates a later step adopted had not lost before (a glow adopted second had gained
    +0.6 +- 2.9 at the first step, not lost), and re-offering the losers was most of the later steps'
    fits (seed 22: 17 and 16 candidates against 10 and 9 after the first step's losers alone)."""
    screened = ranked["screened"].fillna(False).astype(bool).to_numpy()
    gain = ranked["mode_gain"].to_numpy(dtype=float)
    diff, se = ranked["elpd_diff"].to_numpy(dtype=float), ranked["dse"].to_numpy(dtype=float)
    worse = screened & (gain < 0)
    worse |= ~screened & ~(diff >= -EVIDENCE_SE * se)  # NaN: no elpd at all
    return set(ranked["candidate"][worse])


def more_flexible(rival: ModelSpec, adopted: ModelSpec) -> bool:
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


def rivals_of(reference, fits: dict, best: str = "") -> dict:
    """The fits of one step (but ``best``) that pass their checks and predict the data about as well as the
    model whose PSIS-LOO is ``reference``: their elpd_loo minus its is above ``-EVIDENCE_SE`` standard errors
    of that paired difference; name -> (difference, se, fit)."""
    out = {}
    for name, (_, result, loo) in fits.items():
        if name == best or not result.ok or result.posterior is None:
            continue
        diff, se = difference(reference, loo)
        if diff >= -EVIDENCE_SE * se:
            out[name] = (diff, se, result)
    return out


def alternatives(spec: ModelSpec, table: MeasurementTable, adopted: dict[str, dict], offered: Offered) -> dict:
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


def level_trend(result: Fit) -> float:
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
