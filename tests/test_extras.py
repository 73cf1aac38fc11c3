"""The optional packages: the core fits, predicts and inverts without them, and a feature that needs one
names the extra that installs it (``pip install 'bayescal[...]'``), exit 2 on the command line."""

import sys

import pytest

from bayescal.errors import EXTRAS, MissingExtraError, optional
from tests.conftest import ROOT


@pytest.mark.parametrize(("module", "extra"), sorted(EXTRAS.items()))
def test_a_missing_package_names_its_extra(monkeypatch, module, extra):
    monkeypatch.setitem(sys.modules, module, None)  # as if it were not installed
    with pytest.raises(
        MissingExtraError, match=rf"the thing needs the optional package '{module}': pip install 'bayescal\[{extra}\]'"
    ):
        optional(module, "the thing")


def test_every_extra_is_declared_in_the_project():
    import tomllib

    declared = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["optional-dependencies"]
    assert set(EXTRAS.values()) <= set(declared)
    core = " ".join(tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["dependencies"])
    assert not [m for m in EXTRAS if m in core]  # none of them is a core dependency


def test_the_emcee_backend_without_emcee_says_how_to_install_it(monkeypatch, capsys, tmp_path):
    from bayescal.cli import main

    table = tmp_path / "table.csv"
    assert main(["simulate", "--design", "seed000", "--out", str(table), "--seed", "1"]) == 0
    monkeypatch.setitem(sys.modules, "emcee", None)

    argv = ["fit", str(table), "--model", "seed000", "--backend", "emcee", "--out", str(tmp_path / "fit")]
    assert main([*argv, "--no-diagnose", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "the emcee backend needs the optional package 'emcee': pip install 'bayescal[emcee]'" in err
    assert not (tmp_path / "fit").exists()
