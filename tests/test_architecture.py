"""The package's structure holds: no private helper is imported across modules, and every component and
effect declares what it samples and reports (the layers themselves are import-linter's contracts, checked
in CI: ``lint-imports``)."""

import ast
import sys
import warnings
from pathlib import Path

import pytest

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


def _layers() -> list[list[str]]:
    """import-linter's layers (top first), each a list of package names without the root."""
    import tomllib

    config = tomllib.loads((PACKAGE.parent / "pyproject.toml").read_text())["tool"]["importlinter"]
    layers = next(c for c in config["contracts"] if c["type"] == "layers")["layers"]
    return [[name.strip().removeprefix("bayescal.") for name in layer.split("|")] for layer in layers]


def _strings(tree: ast.AST) -> list[str]:
    """String constants of a module that are not docstrings."""
    docs = set()
    for node in ast.walk(tree):
        body = getattr(node, "body", None)
        if isinstance(body, list) and body and isinstance(body[0], ast.Expr):
            if isinstance(body[0].value, ast.Constant):
                docs.add(id(body[0].value))
    return [
        n.value
        for n in ast.walk(tree)
        if isinstance(n, ast.Constant) and isinstance(n.value, str) and id(n) not in docs
    ]


def test_no_layer_names_a_package_above_it_by_string():
    """import-linter sees imports; a module path in a string (``importlib.import_module("bayescal.fleet...")``)
    would cross the layers unseen.  Packages above register with the model through entry points instead
    (:mod:`bayescal.model.plugins`)."""
    import re

    layers = _layers()
    found = []
    for depth, layer in enumerate(layers):
        above = [name for upper in layers[:depth] for name in upper]
        if not above:
            continue
        names = "|".join(re.escape(a) for a in above)
        pattern = re.compile(rf"\bbayescal\.({names})\b")
        for name in layer:
            root = PACKAGE / name
            paths = list(root.rglob("*.py")) if root.is_dir() else [root.with_suffix(".py")]
            for path in paths:
                hits = [s for s in _strings(ast.parse(path.read_text())) if pattern.search(s)]
                found += [f"{path.relative_to(PACKAGE)}: {s!r}" for s in hits]
    assert not found, found


def test_the_packages_above_register_their_kinds_and_sections():
    from bayescal.model import kinds, plugins
    from bayescal.model.spec import section_class, section_names

    assert "film" in kinds.names() and kinds.get("film").__name__ == "bayescal.film.kind"
    assert "fleet" in section_names() and section_class("fleet").__module__ == "bayescal.fleet.spec"
    with pytest.raises(bayescal.SpecError, match="unknown model kind 'plate'; registered: \\['film'\\]"):
        kinds.get("plate")
    assert plugins.names("bayescal.nothing") == ()


def test_clear_caches_forgets_the_compiled_programs():
    from bayescal._caches import clear_caches
    from bayescal.inference import program

    program._CACHE[("a structure",)] = None  # noqa: SLF001 - the cache under test
    clear_caches()
    assert len(program._CACHE) == 0  # noqa: SLF001


def test_the_fit_folder_names_its_files_alone():
    """A fit folder's file names are written once (:mod:`bayescal.io.fit_folder`): no other module spells
    them in code (docstrings may name them)."""
    names = {"posterior.nc", "summary.json", "summary.csv", "lsq.csv"}
    spelled = []
    for path in PACKAGE.rglob("*.py"):
        rel = path.relative_to(PACKAGE).as_posix()
        if rel in (
            "io/fit_folder.py",
            "io/outputs/folders.py",
            "fleet/store.py",
        ):  # outputs: old folders; fleet: its own
            continue
        spelled += [f"{rel}: {s}" for s in _strings(ast.parse(path.read_text())) if s in names]
    assert not spelled, spelled


def test_every_package_is_in_the_wheel():
    """pyproject.toml lists the packages a wheel carries: every folder of bayescal/ with an __init__.py
    is among them (a package left out installs from a clone and is missing from a wheel)."""
    import tomllib

    root = PACKAGE.parent
    listed = set(tomllib.loads((root / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    found = {".".join(p.parent.relative_to(root).parts) for p in PACKAGE.rglob("__init__.py")}
    assert found <= listed, sorted(found - listed)


def test_every_benchmark_imports(monkeypatch):
    """A benchmark names the package's internals it measures; a restructuring that moves one must not
    leave the script broken until someone runs it (importing runs nothing: each runs under ``__main__``)."""
    import importlib.util

    folder = Path(__file__).resolve().parents[1] / "benchmarks"
    monkeypatch.syspath_prepend(str(folder))  # a script run as one finds its siblings there
    scripts = sorted(folder.glob("*.py"))
    assert len(scripts) > 10
    with warnings.catch_warnings():  # the libraries a benchmark imports first may add warning filters
        for path in scripts:
            spec = importlib.util.spec_from_file_location(f"_benchmark_{path.stem}", path)
            assert spec is not None and spec.loader is not None
            module = importlib.util.module_from_spec(spec)
            monkeypatch.setitem(sys.modules, spec.name, module)  # a dataclass looks its module up there
            spec.loader.exec_module(module)
