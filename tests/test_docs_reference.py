"""The API and spec references are generated (``docs/reference.py``): the committed pages are what it writes
now, so a public name or a spec key added without them fails here."""

import importlib.util

import pytest

import bayescal
from tests.conftest import ROOT


@pytest.fixture(scope="module")
def reference():
    spec = importlib.util.spec_from_file_location("docs_reference", ROOT / "docs" / "reference.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_api_reference_is_current_and_lists_every_public_name(reference):
    page = (ROOT / "docs" / "api.md").read_text()
    assert page == reference.api_page(), "docs/api.md is stale: run `python docs/reference.py`"
    listed = {line.removeprefix("::: bayescal.").strip() for line in page.splitlines() if line.startswith(":::")}
    assert listed == set(bayescal.__all__) - {"__version__"}


def test_the_spec_reference_is_current_and_lists_every_key(reference):
    page = (ROOT / "docs" / "spec.md").read_text()
    assert page == reference.spec_page(), "docs/spec.md is stale: run `python docs/reference.py`"
    spec = bayescal.load_spec("seed000").to_dict()
    for section, value in spec.items():
        if isinstance(value, dict):
            assert f"## [{section}]" in page, section
            for key in value:
                assert f"| `{key}` |" in page, (section, key)
        elif section not in ("name", "description"):
            assert f"| `{section}` |" in page, section


def test_every_spec_key_has_a_meaning():
    """Each key's row says what the key means (from its section's documentation), none left blank."""
    page = (ROOT / "docs" / "spec.md").read_text()
    rows = [line for line in page.splitlines() if line.startswith("| `")]
    blank = [row.split("|")[1].strip() for row in rows if not row.rstrip(" |").split("|")[-1].strip()]
    assert len(rows) > 100 and blank == []


def test_every_guide_reads_in_minutes():
    """A guide teaches one task: at most 1,500 words (the why is in the concepts pages, the numbers in
    validation)."""
    words = {p.name: len(p.read_text().split()) for p in (ROOT / "docs" / "guides").glob("*.md")}
    assert len(words) >= 8 and max(words.values()) <= 1500, words
