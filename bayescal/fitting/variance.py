"""The noise checked like the mean: the table's temporal variances against the noise the spec implies.

A fit of region means takes the spec's read noise and conversion gain as given (``noise.kind =
"physical"``): region means over many pixels and frames carry almost no information about them, yet the
predictive interval of a single reading, an inversion's per-pixel interval and the noise floor of the
misfit checks all rest on them.  Where the table records each row's temporal variance (``dn_var``), the
photon transfer is checked, per channel and gain: the measured variances against
``(r g)^2 + 1/12 + K g S`` at the rows' fitted signal ``S`` (:meth:`~bayescal.model.components.noise.Noise.
pixel_variance`).  A sample variance over ``n_pixels (n_frames - 1)`` degrees of freedom has a relative sd
of ``sqrt(2 / dof)``, so at a few thousand degrees of freedom even a small error of the spec shows; the
check therefore fails a fit only where the spec's variance is off by more than :data:`VARIANCE_TOL` and
the group's evidence exceeds :data:`VARIANCE_Z` (a spec whose conversion gain is 46 % off is named; one
that is 5 % off is not), and it names the curve's shape when its slope falls with the signal (a concave
photon transfer, as a V/Q nonlinearity makes).
"""

from __future__ import annotations

import numpy as np

from bayescal.model.components.noise import Noise

__all__ = ["VARIANCE_TOL", "VARIANCE_Z", "variance_checks"]

#: the spec's variance may be off by this fraction before the check fails a fit
VARIANCE_TOL = 0.25
#: and the group's evidence must exceed this many standard errors
VARIANCE_Z = 4.0


def variance_checks(model, signal_dn: np.ndarray) -> tuple[list[str], dict]:
    """The photon transfer check of one fit (``signal_dn``: each row's posterior mean signal, DN): per channel
    and gain, the ratio of the measured variances to the spec's, its z, and the slope's change from the lower
    to the upper half of the signal.  Empty without ``dn_var`` or with ``noise.kind = "measured"``."""
    frame, spec = model.table.frame, model.spec
    if "dn_var" not in frame or spec.noise.kind == "measured":
        return [], {}
    var = frame["dn_var"].to_numpy(dtype=float)
    clipped = np.asarray(model.data.censored, dtype=bool)
    g_rel = frame["gain"].to_numpy(dtype=float) / spec.reference.gain
    expected = Noise.pixel_variance(spec.noise.read_noise_dn, spec.noise.conversion_gain, g_rel, signal_dn)
    dof = (frame["n_pixels"].to_numpy(dtype=float) if "n_pixels" in frame else np.full(len(frame), 1e4)) * (
        frame["n_frames"].to_numpy(dtype=float) - 1.0 if "n_frames" in frame else 1.0
    )
    usable = (var > 0) & ~clipped & np.isfinite(var) & np.isfinite(signal_dn) & np.isfinite(expected) & (dof > 1)
    problems, groups = [], []
    for (channel, gain), rows in frame[usable].groupby(["channel", "gain"], sort=False).groups.items():
        idx = np.asarray(rows)
        if idx.size < 3:
            continue
        ratio = float(var[idx].sum() / expected[idx].sum())
        # the relative sd of a sum of sample variances: sqrt(sum(2 v^2 / dof)) / sum(v)
        rel_sd = float(np.sqrt(np.sum(2.0 * expected[idx] ** 2 / dof[idx])) / expected[idx].sum())
        z = float(np.log(ratio) / max(rel_sd, 1e-12))
        order = idx[np.argsort(signal_dn[idx])]
        half = order.size // 2
        change = np.nan
        halves = (order[:half], order[half:])
        if half >= 2 and all(np.ptp(signal_dn[h]) > 0 for h in halves):
            slopes = [_slope(signal_dn[h], var[h]) for h in halves]
            change = float(slopes[1] / slopes[0] - 1.0) if slopes[0] > 0 else np.nan
        groups.append({"channel": str(channel), "gain": float(gain), "ratio": ratio, "z": z, "slope_change": change})
        if abs(ratio - 1.0) > VARIANCE_TOL and abs(z) > VARIANCE_Z:
            side = "above" if ratio > 1 else "below"
            shape = (
                f"; the photon transfer's slope changes by {change:+.0%} from the lower half of the signal to the "
                "upper (a conversion gain that varies with the signal)"
                if np.isfinite(change) and abs(change) > VARIANCE_TOL
                else ""
            )
            noise = f"read noise {spec.noise.read_noise_dn:g} DN, conversion gain {spec.noise.conversion_gain:g} DN/e-"
            problems.append(
                f"channel {channel} at gain {gain:g}: the measured temporal variances (dn_var) sit "
                f"{abs(ratio - 1):.0%} {side} what the spec's noise implies ({noise} at the reference gain; "
                f"z = {z:+.0f}){shape}: a single "
                "reading's interval would be wrong by that much; set noise.read_noise_dn and conversion_gain from "
                'a photon transfer measurement (bayescal characterize), or noise.kind = "measured"'
            )
    return problems[:3], {"tolerance": VARIANCE_TOL, "groups": groups}


def _slope(x: np.ndarray, y: np.ndarray) -> float:
    """The least-squares slope of ``y`` on ``x``."""
    xc = x - x.mean()
    return float(np.sum(xc * (y - y.mean())) / np.sum(xc * xc))
