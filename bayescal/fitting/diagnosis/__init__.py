"""When a fit does not describe its data: find what in the library does, and say by how much.

A real camera departs from any fixed model in ways the library has components for: its
nonlinearity arises after the gain rather than in the charge, its response needs a higher
order near full scale, its dark level drifted over a session that recorded no times, an
amplifier glows during long exposures, the lamp's spectrum changes with its level, its
readout's offset follows the sensor temperature.  The misfit checks
(:mod:`bayescal.fitting.misfit`) see that something is wrong; they cannot say which of these
it is (a drifting dark level and a mis-placed nonlinearity both leave residuals that run along
the row order).

The package in the order the data flow through it:

- :mod:`~bayescal.fitting.diagnosis.candidates`: the switches a table can inform;
- :mod:`~bayescal.fitting.diagnosis.trials`: their Laplace fits, two at a time, and PSIS-LOO;
- :mod:`~bayescal.fitting.diagnosis.domain`: where the nonlinearity arises, whenever gains are swept;
- :mod:`~bayescal.fitting.diagnosis.search`: the :class:`Search` that adopts switches one at a time;
- :mod:`~bayescal.fitting.diagnosis.found`: what it found (:class:`Diagnosis`);
- :mod:`~bayescal.fitting.diagnosis.doubts`: the range, structure and rival doubts a fit carries;
- :mod:`~bayescal.fitting.diagnosis.diagnosed`: :func:`fit_diagnosed`, the fit ``bayescal fit`` runs:
  the user's backend fits the spec found, the diagnosis rides along in the diagnostics
  (``summary.json``), and the fit fails (exit 3) only when nothing in the library explains the data.
"""

from bayescal.fitting.diagnosis.candidates import SCREENED, candidates, other_domain, screen_candidates
from bayescal.fitting.diagnosis.diagnosed import fit_diagnosed
from bayescal.fitting.diagnosis.domain import decide_domain
from bayescal.fitting.diagnosis.doubts import DOUBT_Z, range_check, rival_doubt, structure_doubt
from bayescal.fitting.diagnosis.found import Diagnosis
from bayescal.fitting.diagnosis.search import MAX_STEPS, Search, diagnose
from bayescal.fitting.diagnosis.trials import EVIDENCE_SE, laplace_proxy

__all__ = [
    "DOUBT_Z",
    "Diagnosis",
    "EVIDENCE_SE",
    "MAX_STEPS",
    "SCREENED",
    "Search",
    "candidates",
    "decide_domain",
    "diagnose",
    "fit_diagnosed",
    "laplace_proxy",
    "other_domain",
    "range_check",
    "rival_doubt",
    "screen_candidates",
    "structure_doubt",
]
