"""The package's structure holds: no private helper is imported across modules, and every component and
effect declares what it samples and reports (the layers themselves are import-linter's contracts, checked
in CI: ``lint-imports``)."""

import ast
from pathlib import Path

import bayescal
from bayescal.model.components import CORE, EFFECTS

PACKAGE = Path(bayescal.__file__).parent


def test_no_private_name_is_imported_across_modules():
    crossing = []
    for path in PACKAGE.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("bayescal"):
                crossing += [
                    f"{path.relative_to(PACKAGE)}: {node.module}.{a.name}"
                    for a in node.names
                    if a.name.startswith("_") and not a.name.startswith("__")
                ]
    assert not crossing, crossing


def test_every_component_declares_its_section_sites_and_quantities():
    sections = [c.section for c in CORE + EFFECTS]
    assert len(set(sections)) == len(sections)
    for c in CORE + EFFECTS:
        assert c.__doc__ and c.sites is not None and c.reported is not None, c
    for e in EFFECTS:
        e.spec_class()  # every effect's section has defaults (the effect switched off or automatic)


def test_the_public_names_are_listed_alike():
    """``bayescal.__all__`` (the lazy table) and the eager imports static analysers read name the same
    objects from the same modules."""
    tree = ast.parse((PACKAGE / "__init__.py").read_text())
    eager = {}
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and getattr(node.test, "id", "") == "TYPE_CHECKING":
            for imp in node.body:
                if isinstance(imp, ast.ImportFrom):
                    eager |= {a.name: imp.module for a in imp.names}
    lazy = {k: v for k, v in bayescal._LAZY.items()}  # noqa: SLF001 - the table under test
    assert eager == lazy
    assert set(lazy) <= set(bayescal.__all__)


def test_noise_and_clipping_are_composed_in_one_module():
    """A reading's noise meets the ADC in :mod:`bayescal.model.observation` alone: no other module of the
    camera's equation calls the ADC (the film and the independent simulators have their own physics)."""
    callers = []
    for path in PACKAGE.rglob("*.py"):
        rel = path.relative_to(PACKAGE).as_posix()
        if rel.startswith(("film/", "validation/")):
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Call) and getattr(node.func, "attr", getattr(node.func, "id", "")) == "adc":
                callers.append(rel)
    assert set(callers) == {"model/observation.py"}, callers
