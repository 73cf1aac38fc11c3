"""Which code made a result: the version, the commit of a checkout, the citation file that agrees with both."""

import re

from bayescal._version import __version__, commit, describe
from bayescal.cli import main
from tests.conftest import ROOT


def test_the_commit_is_read_from_a_checkout_without_git(tmp_path):
    sha = "0123456789abcdef0123456789abcdef01234567"
    git = tmp_path / ".git"
    (git / "refs" / "heads").mkdir(parents=True)
    (git / "HEAD").write_text("ref: refs/heads/main\n")
    assert commit(tmp_path) is None  # a branch with no commit yet
    (git / "packed-refs").write_text(f"# pack-refs with: peeled\n{sha} refs/heads/main\n")
    assert commit(tmp_path) == sha[:12]
    (git / "refs" / "heads" / "main").write_text("f" * 40 + "\n")  # a loose ref wins over the packed one
    assert commit(tmp_path) == "f" * 12
    (git / "HEAD").write_text(sha + "\n")  # detached
    assert commit(tmp_path) == sha[:12]
    assert commit(tmp_path / "elsewhere") is None  # an installed wheel: no repository


def test_version_names_the_commit_and_the_citation_agrees(capsys):
    try:
        main(["--version"])
    except SystemExit as done:
        assert done.code == 0
    printed = capsys.readouterr().out.strip()
    assert printed == f"bayescal {describe()}" and printed.startswith(f"bayescal {__version__}")
    if commit() is not None:
        assert re.fullmatch(rf"bayescal {re.escape(__version__)} \(commit [0-9a-f]{{12}}\)", printed)
    cff = (ROOT / "CITATION.cff").read_text()
    assert re.search(r'^version: "([^"]+)"$', cff, re.M).group(1) == __version__
    assert "cff-version: 1.2.0" in cff and "license: MIT" in cff
