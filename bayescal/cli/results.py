"""``--json``: what a verb printed, as one JSON document on stdout for a script (the text goes to stderr).

A verb names its results with :func:`emit` (a table as a list of records); the document adds the verb, its
exit status, an error's message where there was one, and each output folder it put in place with the JSON
files it wrote there (a fit's ``summary.json``, a characterisation's ``characterization.json``), so a
script reads the same numbers the files hold.
"""

from __future__ import annotations

import contextlib
import json
import math
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

__all__ = ["emit", "json_document"]

_COLLECTED: list[dict] = []  # the innermost document being collected (empty: not collecting)
#: an output folder's JSON files larger than this are named, not included
MAX_INCLUDED_BYTES = 2_000_000


def emit(**items: Any) -> None:
    """Record results for ``--json`` (nothing happens without it): tables become lists of records."""
    if _COLLECTED:
        _COLLECTED[-1].update({key: _ready(value) for key, value in items.items()})


@contextlib.contextmanager
def json_document(verb: str) -> Iterator[dict]:
    """Collect a verb's results while its text goes to stderr; the caller fills ``exit`` (and ``error``) and
    prints the document with :func:`dump`."""
    doc: dict = {"verb": verb}
    _COLLECTED.append(doc)
    try:
        with contextlib.redirect_stdout(sys.stderr):
            yield doc
    finally:
        _COLLECTED.pop()


def dump(doc: dict, folders: list[Path]) -> None:
    """Print ``doc`` with the output folders (and their JSON files) on stdout, as one line of JSON."""
    doc["outputs"] = [_folder(Path(f)) for f in folders]
    print(json.dumps(_ready(doc), allow_nan=False, sort_keys=False))


def _folder(path: Path) -> dict:
    files: dict = {}
    skipped = []
    for p in sorted(path.glob("*.json")):
        if p.stat().st_size > MAX_INCLUDED_BYTES:
            skipped.append(p.name)
            continue
        files[p.name] = json.loads(p.read_text())
    out: dict = {"path": str(path), "json": files}
    if skipped:
        out["not_included"] = skipped
    return out


def _ready(value: Any) -> Any:
    """JSON-ready: NaN and infinities as null (JSON has none), numpy scalars and arrays as numbers and
    lists, DataFrames as lists of records, paths as strings."""
    import numpy as np
    import pandas as pd

    if isinstance(value, pd.DataFrame):
        return [_ready(r) for r in value.to_dict("records")]
    if isinstance(value, pd.Series):
        return _ready(value.to_dict())
    if isinstance(value, dict):
        return {str(k): _ready(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_ready(v) for v in value]
    if isinstance(value, np.ndarray):
        return _ready(value.tolist())
    if isinstance(value, np.generic):
        return _ready(value.item())
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, Path):
        return str(value)
    if value is None or isinstance(value, bool | int | str):
        return value
    return str(value)
