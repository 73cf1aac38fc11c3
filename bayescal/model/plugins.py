"""What the packages above the model register: model kinds and spec sections, found through the
installed package's entry points (``pyproject.toml``, ``[project.entry-points."bayescal.kinds"]`` and
``[project.entry-points."bayescal.spec_sections"]``).

The model layer names nothing above it, neither by import nor by module string: a package above
(the film kind, the fleet's ``[fleet]`` section) declares itself in the package metadata, and the
model looks the declarations up on first use.  A lab's own package can register a kind or a section
the same way, in its own ``pyproject.toml``.
"""

from __future__ import annotations

from functools import cache
from importlib.metadata import EntryPoint, entry_points
from typing import Any

from bayescal.errors import SpecError

__all__ = ["KIND_GROUP", "SECTION_GROUP", "load", "names"]

#: entry-point group of the model kinds other than the camera's: name -> module with the kind's entry points
KIND_GROUP = "bayescal.kinds"
#: entry-point group of the spec sections owned above the model: name -> the section's dataclass
SECTION_GROUP = "bayescal.spec_sections"


@cache
def _registered(group: str) -> dict[str, EntryPoint]:
    return {ep.name: ep for ep in entry_points(group=group)}


def names(group: str) -> tuple[str, ...]:
    """The names registered in ``group``, sorted."""
    return tuple(sorted(_registered(group)))


def load(group: str, name: str, what: str) -> Any:
    """The object registered as ``name`` in ``group`` (imported now); a clear error naming the registered
    ones (``what`` says what is being looked up, for the message)."""
    try:
        return _registered(group)[name].load()
    except KeyError:
        hint = "" if names(group) else " (none is registered: is bayescal installed, e.g. pip install -e .?)"
        raise SpecError(f"unknown {what} '{name}'; registered: {list(names(group))}{hint}") from None
