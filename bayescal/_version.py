"""The package version: the one place it is written (pyproject.toml reads it), and the commit it was run from."""

from __future__ import annotations

from pathlib import Path

__version__ = "0.1.0"


def commit(root: Path | None = None) -> str | None:
    """The commit of the checkout the package runs from (12 hex digits), read from its ``.git`` without running
    git; None for an installed wheel, which carries no repository."""
    git = (root or Path(__file__).resolve().parent.parent) / ".git"
    try:
        head = (git / "HEAD").read_text().strip()
        if not head.startswith("ref: "):
            return head[:12]
        ref = head[5:]
        loose = git / ref
        if loose.is_file():
            return loose.read_text().strip()[:12]
        for line in (git / "packed-refs").read_text().splitlines():
            if line.endswith(" " + ref):
                return line.split()[0][:12]
    except OSError:
        return None
    return None


def describe() -> str:
    """``0.1.0``, or ``0.1.0 (commit 0123456789ab)`` when run from a checkout: which code made a result."""
    found = commit()
    return __version__ if found is None else f"{__version__} (commit {found})"
