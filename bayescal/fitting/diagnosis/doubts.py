"""Doubts a diagnosed fit carries: a response that disagrees with itself below the roll-off (the range), a
screened structure the data cannot tell from the spec's, a rival of the adopted model."""

from __future__ import annotations

import numpy as np

from bayescal.fitting.diagnosis.found import Diagnosis
from bayescal.fitting.diagnosis.trials import EVIDENCE_SE, laplace_proxy, quiet_fit
from bayescal.fitting.result import Fit
from bayescal.io.table import MeasurementTable
from bayescal.model.spec import ModelSpec

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
        sub = quiet_fit(
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
            # the structure not reported (the spec's: the candidate nests it), for `design --after`
            info |= {"other": "the spec without it", "other_spec": spec_toml(base)}
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
            info["other_spec"] = spec_toml(result)  # the rival's structure, for `design --after`
            if name == found.preferred.get("over"):  # the flexible shape reported draws this one too
                info |= {"carried": True, "reported": found.preferred["candidate"]}
            else:
                info |= {"carried": False}
            best = (max(moved.values()), info)
    return None if best is None else best[1]


def spec_toml(fit) -> str | None:
    """The spec a fit was made with, as TOML (what `design --after` refits the other structure from); None for
    a fit that carries no model."""
    spec = getattr(getattr(fit, "model", None), "spec", None)
    return None if spec is None else spec.to_toml()
