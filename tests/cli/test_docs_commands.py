"""Every command of the README and of the guides' runnable blocks, run as a user would: from a
folder outside the repository, against the installed package, one block after another."""

import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

from tests.conftest import ROOT

MARKER = "<!-- the commands below run in tests/cli/test_docs_commands.py -->"


def _blocks(path: Path, marked: bool) -> list[list[str]]:
    """The bash blocks of a page (with ``marked``, only those after the marker), as command lines."""
    text = path.read_text()
    out = []
    for m in re.finditer(r"```bash\n(.*?)```", text, re.S):
        if marked and not text[: m.start()].rstrip().endswith(MARKER):
            continue
        lines = [line.split(" #")[0].strip() for line in m.group(1).splitlines()]
        out.append([line for line in lines if line and not line.startswith("#")])
    return out


def _run(cwd: Path, line: str) -> None:
    args = shlex.split(line)
    assert args[0] == "bayescal", line
    proc = subprocess.run(
        [sys.executable, "-m", "bayescal.cli", *args[1:]], cwd=cwd, capture_output=True, text=True, timeout=900
    )
    assert proc.returncode == 0, f"{line}\n{proc.stdout[-2000:]}\n{proc.stderr[-2000:]}"


def test_readme_commands_run_from_any_folder(tmp_path, monkeypatch, capsys):
    """The README's commands, in this process from a folder outside the repository (the wheel's slow test
    runs them as a newcomer would, by the installed ``bayescal`` of a clean environment)."""
    from bayescal.cli import main

    blocks = _blocks(ROOT / "README.md", marked=False)
    setup = [b for b in blocks if any(line.startswith("bash .ci/setup") for line in b)]
    assert len(setup) == 2  # the two commands a newcomer needs (run by CI itself)
    commands = [line for b in blocks if b not in setup for line in b]
    assert len(commands) >= 5
    monkeypatch.chdir(tmp_path)
    for line in commands:
        args = shlex.split(line)
        assert args[0] == "bayescal", line
        rc = main(args[1:])
        said = capsys.readouterr()
        assert rc == 0 and "Traceback" not in said.err, f"{line}\n{said.out[-2000:]}\n{said.err[-2000:]}"
    assert (tmp_path / "fit" / "report.html").is_file() and (tmp_path / "ccd" / "characterization.json").is_file()


GUIDES = [
    "getting-started.md",
    "guides/emva1288.md",
    "guides/calibrate.md",
    "guides/design.md",
    "guides/film.md",
    "guides/fleet.md",
]


@pytest.mark.slow
@pytest.mark.parametrize("page", GUIDES)
def test_guide_commands_run_from_any_folder(tmp_path, page):
    blocks = _blocks(ROOT / "docs" / page, marked=True)
    assert blocks, f"{page} has no runnable block"
    for line in (line for block in blocks for line in block):  # every runnable block, in the page's order
        _run(tmp_path, line)


def test_every_guide_has_a_runnable_block():
    for page in GUIDES:
        assert _blocks(ROOT / "docs" / page, marked=True), page


def _python_blocks(path: Path) -> list[str]:
    """The Python blocks of a page (a block that starts with ``>>>`` is a doctest, not a script)."""
    return [m.group(1) for m in re.finditer(r"```python\n(.*?)```", path.read_text(), re.S)]


#: every page with a Python block (test_every_python_block_is_run keeps the list whole)
PYTHON_PAGES = ["README.md", "docs/getting-started.md", "docs/guides/calibrate.md", "docs/guides/design.md"]


def test_every_python_block_is_run():
    pages = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
    with_blocks = {str(p.relative_to(ROOT)) for p in pages if _python_blocks(p)}
    assert with_blocks <= set(PYTHON_PAGES), sorted(with_blocks - set(PYTHON_PAGES))


@pytest.mark.slow
@pytest.mark.parametrize("page", PYTHON_PAGES)
def test_guide_python_blocks_run_from_any_folder(tmp_path, page):
    """Each Python block of a guide runs as written, in a fresh interpreter, from a folder outside the
    repository (the calibrate guide's once named tables it never made)."""
    blocks = _python_blocks(ROOT / page)
    assert blocks, f"{page} has no Python block"
    for code in blocks:
        proc = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=900)
        assert proc.returncode == 0, f"{page}:\n{code}\n{proc.stderr[-3000:]}"
