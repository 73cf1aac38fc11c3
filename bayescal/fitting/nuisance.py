"""Nuisances checked against their priors: a sphere level's error, a setting's departure from its label, a
drift, that the posterior puts far out in its prior's tail has absorbed a misfit, not measured the bench.

A model's nuisance sites (:meth:`~bayescal.model.components.base.Component.nuisances`) carry the lab's
own statement of how large the imperfection is: the sphere's per-level uncertainty, the settings'
tolerance, a drift's scale.  Given data the model describes, the posterior mean of a site in units of its
prior sd is at most about as wide as the prior itself (it shrinks towards 0 where the data say little), so
``|mean| / sd`` above :data:`CONFLICT_SD` arises by chance with probability below 6e-5 per element (below
0.3 % over the ~50 elements of a typical model).  Far out there, the nuisance is doing something else: a
stray light that the darks do not see lifts the lowest sphere levels' errors by 10 % and more where their
prior says 0.5 % (a prior-posterior conflict; Evans and Moshonov 2006, Bayesian Analysis 1(4)).  The fit
is then refused, naming the nuisance, its size and its prior, so that the diagnosis looks for the term
that belongs in the model.
"""

from __future__ import annotations

import numpy as np

__all__ = ["CONFLICT_SD", "nuisance_checks"]

#: a nuisance whose posterior mean lies more than this many prior sds from 0 is in conflict with its prior
CONFLICT_SD = 4.0
#: conflicts named one by one (the rest are counted)
NAMED = 4


def nuisance_checks(model, sampled: dict, coords: dict) -> tuple[list[str], dict]:
    """Each nuisance site's posterior mean in prior sds (``sampled``: the sampled sites' draws, leading
    dims chain and draw; ``coords``: the labels of their dims).  Returns the problems (the
    :data:`NAMED` largest conflicts) and, per site, its largest ``|mean| / sd`` and where."""
    level_sigma = np.asarray(model.data.level_sigma, dtype=float)
    found: list[tuple[float, str]] = []
    info: dict = {"threshold_sd": CONFLICT_SD, "sites": {}}
    for component in model.parts.components:
        for site, n in component.nuisances(level_sigma).items():
            if site not in sampled:
                continue
            draws = np.asarray(sampled[site], dtype=float)
            mean = draws.reshape((-1,) + draws.shape[2:]).mean(axis=0)
            sd = np.broadcast_to(np.asarray(n.sd, dtype=float), mean.shape)
            size = np.broadcast_to(np.asarray(n.size, dtype=float), mean.shape)
            z = mean / sd
            if not z.size:
                continue
            worst = np.unravel_index(int(np.argmax(np.abs(z))), z.shape)
            info["sites"][site] = {"max_abs_sd": round(float(np.abs(z[worst])), 2), "at": _label(n.dims, worst, coords)}
            for idx in np.argwhere(np.abs(z) > CONFLICT_SD):
                i = tuple(int(k) for k in idx)
                what = n.what.format(_label(n.dims, i, coords))
                text = (
                    f"{what} comes out {_size(mean[i] * size[i], n.unit)} where its prior sd is "
                    f"{_size(sd[i] * size[i], n.unit).lstrip('+')}: {abs(z[i]):.0f} prior sds from 0"
                )
                found.append((abs(float(z[i])), text))
    if not found:
        return [], info
    found.sort(key=lambda item: -item[0])
    named = "; ".join(text for _, text in found[:NAMED])
    more = f" (and {len(found) - NAMED} more)" if len(found) > NAMED else ""
    problem = (
        f"nuisances far from their priors: {named}{more}; they absorb a misfit the model cannot draw (a stimulus "
        "the darks do not see, such as stray light, lifts the lowest levels' errors; a lamp or a setting far off "
        "its stated tolerance), so the fit is not reported with them"
    )
    return [problem], info


def _label(dims: tuple[str, ...], idx: tuple, coords: dict) -> str:
    return ", ".join(str(coords[d][int(i)]) if d in coords else str(int(i)) for d, i in zip(dims, idx, strict=False))


def _size(value: float, unit: str) -> str:
    return f"{value:+.2%}" if unit == "%" else f"{value:+.3g} {unit}"
