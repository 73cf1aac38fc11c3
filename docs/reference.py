"""Write the API reference (``docs/api.md``) from ``bayescal.__all__`` and the spec reference
(``docs/spec.md``) from the spec's dataclasses, so neither can go stale.

Run ``python docs/reference.py`` after changing a public name or a spec key;
``tests/test_docs_reference.py`` fails while the committed pages differ from what this writes.
"""

from __future__ import annotations

import dataclasses
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: the API page's sections: heading -> the packages whose public names it lists (first match wins)
GROUPS = {
    "Specs, designs and tables": ("bayescal.model.spec", "bayescal.io", "bayescal.model.simulate"),
    "Fitting": ("bayescal.fitting", "bayescal.model.assemble", "bayescal.inference"),
    "A calibrated camera": ("bayescal.posterior", "bayescal.model.setting", "bayescal.report"),
    "Predictions, inversion and planning": ("bayescal.prediction",),
    "Designing a campaign": ("bayescal.campaign", "bayescal.validation.design"),
    "EMVA 1288 and sensor characterisation": ("bayescal.characterization",),
    "Per-pixel maps": ("bayescal.maps",),
    "Fleets over campaigns": ("bayescal.fleet",),
    "Validation": ("bayescal.validation",),
    "Errors and numerics": ("bayescal.errors", "bayescal._config", "bayescal._version"),
}

API_HEAD = """# API reference

The public API is flat: everything below is `bayescal.NAME`, generated from `bayescal.__all__`
(`docs/reference.py`). Importing bayescal imports neither JAX nor arviz and changes no global
setting; functions that compute run in float64 inside `bayescal.numerics()`. The keys of a spec
file are in the [spec reference](spec.md).
"""


def _home(name: str) -> str:
    import bayescal

    module = bayescal._LAZY.get(name)  # noqa: SLF001 - the public table itself
    if module is not None:
        return module
    return getattr(getattr(bayescal, name), "__module__", "bayescal._version") or "bayescal._version"


def api_page() -> str:
    """The API reference: every public name under its section, in ``__all__``'s order."""
    import bayescal

    names = [n for n in bayescal.__all__ if n != "__version__"]
    sections: dict[str, list[str]] = {heading: [] for heading in GROUPS}
    for name in names:
        home = _home(name)
        heading = next((h for h, packages in GROUPS.items() if home.startswith(packages)), None)
        if heading is None:
            raise SystemExit(f"bayescal.{name} ({home}) belongs to no section of docs/reference.py's GROUPS")
        sections[heading].append(name)
    out = [API_HEAD]
    for heading, members in sections.items():
        if members:
            out.append(f"## {heading}\n")
            out += [f"::: bayescal.{name}\n" + _inherited(getattr(bayescal, name)) for name in members]
    return "\n".join(out)


def _inherited(obj) -> str:
    """The options that show a class's members from a base of the package's own (a ``FleetFit``'s
    questions are its base's, :class:`bayescal.fleet.queries.FleetQueries`); none for anything else."""
    import inspect

    own = inspect.isclass(obj) and any(
        b.__module__.startswith("bayescal.") and not issubclass(b, BaseException) for b in obj.__mro__[1:]
    )
    return "    options:\n      inherited_members: true\n" if own else ""


SPEC_HEAD = """# Spec reference

Every key of a model spec (TOML), generated from the spec's dataclasses (`docs/reference.py`):
its type, its default, and what the section's documentation says of it. A section left out takes
its defaults; an unknown key is an error that names it. Units are those the meaning gives; the
model's priors are in the model's scaled units unless it says otherwise.
"""


ROLE = re.compile(r":(?:class|func|meth|mod|data|attr|exc):`~?([\w.]+)`")


def markdown(text: str) -> str:
    """reStructuredText inline markup as Markdown: a role's target by its last name, literals in single
    backticks, table bars escaped."""
    text = ROLE.sub(lambda m: f"``{m.group(1).split('.')[-1]}``", text)
    return text.replace("``", "`").replace("|", "\\|")


def _attributes(doc: str) -> dict[str, str]:
    """A numpydoc ``Attributes`` section: each name -> its description."""
    out: dict[str, str] = {}
    for m in re.finditer(r"^    ([\w, ]+) : [^\n]*\n((?:        [^\n]*\n?)+)", doc, re.M):
        for name in (n.strip() for n in m.group(1).split(",")):
            out[name] = re.sub(r"\s+", " ", m.group(2)).strip()
    return out


def _meaning(doc: str, key: str) -> str:
    """What a section's docstring says of ``key``: its numpydoc entry, or the sentences that name it (as
    ``key`` or ``prefix_*``)."""
    listed = _attributes(doc or "")
    if key in listed:
        return markdown(listed[key])
    text = re.sub(r"\s+", " ", doc or "")
    sentences = re.split(r"(?<=[.;])\s+(?=[A-Z`(])", text)
    named = re.compile(rf"``{re.escape(key)}(?:``| = | : )|``{re.escape(key.split('_')[0])}_\*``")
    said = [s for s in sentences if named.search(s)]
    return markdown(" ".join(said)) if said else ""


def _default(f: dataclasses.Field) -> str:
    if f.default is not dataclasses.MISSING:
        value = f.default
    elif f.default_factory is not dataclasses.MISSING:
        value = f.default_factory()
    else:
        return "(required)"
    if isinstance(value, str):
        return f'`"{value}"`'
    if isinstance(value, bool):
        return f"`{str(value).lower()}`"
    return f"`{value!r}`".replace("|", "\\|")


def _table(cls: type, title: str, skip: tuple[str, ...] = ()) -> list[str]:
    doc = cls.__doc__ or ""
    summary = markdown(re.sub(r"\s+", " ", doc.strip().split("\n\n")[0]))
    rows = [f"## {title}\n", f"{summary}\n", "| key | type | default | meaning |", "|---|---|---|---|"]
    for f in dataclasses.fields(cls):
        if f.name in skip or not f.init:
            continue
        kind = str(f.type).replace("|", "or")
        # the class's own documentation, else that of the class it refines (a drift's section documents its keys once)
        meaning = next((m for c in cls.__mro__ if (m := _meaning(c.__doc__ or "", f.name))), "")
        rows.append(f"| `{f.name}` | `{kind}` | {_default(f)} | {meaning} |")
    return rows + [""]


def spec_page() -> str:
    """The spec reference: the top-level keys, each core section, each effect's and each registered one."""
    from bayescal.model.components import EFFECTS
    from bayescal.model.spec import ModelSpec, Reference, section_class, section_names

    out = [SPEC_HEAD]
    nested = {f.name: f for f in dataclasses.fields(ModelSpec) if dataclasses.is_dataclass(f.default_factory)}
    out += _table(ModelSpec, "Top level", skip=("effects", "sections", "reference", *nested))
    out += _table(Reference, "[reference]")
    for name, f in nested.items():
        out += _table(f.default_factory, f"[{name}]")  # type: ignore[arg-type]
    for effect in EFFECTS:
        out += _table(effect.spec_class, f"[{effect.section}] (an optional effect)")
    for name in section_names():
        out += _table(section_class(name), f"[{name}] (a section of the {name} package)")
    return "\n".join(out).rstrip() + "\n"


def main() -> None:
    sys.path.insert(0, str(ROOT))
    (ROOT / "docs" / "api.md").write_text(api_page())
    (ROOT / "docs" / "spec.md").write_text(spec_page())
    print("wrote docs/api.md and docs/spec.md")


if __name__ == "__main__":
    main()
