"""One flexible model in place of a search: every term the table can inform, on at once.

When a fit does not describe its data, the search (:func:`bayescal.fitting.diagnosis.diagnose`) fits
candidate after candidate and adopts one at a time by PSIS-LOO: a dataset with a departure costs every
candidate's fit, and a departure no candidate names alone ends in a refusal.  The flexible model instead
switches on, together, every term of the library that the table can inform (:func:`flexible_changes`):
the drifts over what the table records, the temperature laws, the amplifier glow, stray light, a
frame-common black level, per-channel lamp errors, and the monotone roll-off of any smooth shape where
the readings reach towards full scale.  Each term is centred on "absent" under a prior that shrinks it
there, so where the data cannot tell a term from its absence the posterior carries both: the intervals
widen by what the data cannot decide instead of resting on one structure chosen by a margin.

Two forms of one effect are never on together: the roll-off is the monotone shape (which draws the knee
family too), the response's order and the nonlinearity's domain stay as the spec (and the domain
decision, :func:`~bayescal.fitting.diagnosis.decide_domain`) set them, and the lamp's per-channel level
errors take :data:`LAMP_LEVEL_REL`, the middle of the sizes the search tries.
"""

from __future__ import annotations

from bayescal.io.table import MeasurementTable
from bayescal.model.spec import ModelSpec

__all__ = ["LAMP_LEVEL_REL", "flexible_changes"]

#: the per-channel lamp level errors' prior sd in the flexible model (the search tries 0.3 %, 1 % and 3 %)
LAMP_LEVEL_REL = 0.01


def flexible_changes(spec: ModelSpec, table: MeasurementTable) -> dict[str, dict]:
    """The spec changes that switch on every term the table can inform (the search's candidates,
    :func:`~bayescal.fitting.diagnosis.candidates`, merged as the module docstring says); empty when there
    is none."""
    from bayescal.fitting.diagnosis import candidates

    merged: dict[str, dict] = {}
    for changes in candidates(spec, table).values():
        for section, keys in changes.items():
            keys = dict(keys)
            if section == "response":
                keys.pop("nonlinearity_domain", None)
                keys.pop("order", None)
                if "rolloff" in keys:
                    keys["rolloff"] = "monotone"
            if section == "sphere" and "channel_level_rel" in keys:
                keys["channel_level_rel"] = LAMP_LEVEL_REL
            if keys:
                merged.setdefault(section, {}).update(keys)
    return merged
