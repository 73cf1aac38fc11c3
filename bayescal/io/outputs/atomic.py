"""Single files written atomically: a failed run never leaves a half-written file, and the file joins
the record of its folder in the same step (the folder's run list, :mod:`.folders`, or the ledger of a
folder of the user's, :mod:`.ledger`)."""

from __future__ import annotations

import json
import os
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from bayescal.io.outputs import interrupts
from bayescal.io.outputs.disk import public, write_errors
from bayescal.io.outputs.folders import record_file
from bayescal.io.outputs.ledger import check_output_file, commit_file

__all__ = ["atomic_path", "write_text_atomic", "write_json_atomic"]


@contextmanager
def atomic_path(target: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path beside ``target``; rename it onto ``target`` on success.

    A ``target`` bayescal may not replace (:func:`~.ledger.refusal`) is refused before the block runs
    and again at the rename.  In a folder being staged the file is simply renamed (the folder's record
    lists it when the folder is put in place); in a bayescal output folder the file joins the run's list of files in
    the same step (:func:`~.folders.record_file`); elsewhere it joins the folder's record of
    bayescal's files (:func:`~.ledger.commit_file`).  A write that fails for want of space or a
    file-size limit raises :class:`~bayescal.errors.OutputError` naming ``target``, and leaves
    nothing behind.
    """
    target = Path(target)
    check_output_file(target)
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        with write_errors(target):
            yield tmp_path
            public(tmp_path)
            if interrupts.in_staging(target):  # a staged folder's files are listed when it is put in place
                os.replace(tmp_path, target)
            elif not record_file(tmp_path, target):
                commit_file(tmp_path, target)
    finally:
        if tmp_path.exists():
            tmp_path.unlink()


def write_text_atomic(target: str | os.PathLike, text: str) -> None:
    """Write ``text`` to ``target`` atomically."""
    with atomic_path(target) as tmp:
        tmp.write_text(text)


def write_json_atomic(target: str | os.PathLike, obj: Any) -> None:
    """Write ``obj`` as indented JSON atomically (NaN written as null)."""
    write_text_atomic(target, json.dumps(_jsonable(obj), indent=2, allow_nan=False) + "\n")


def _jsonable(obj: Any) -> Any:
    import math

    import numpy as np

    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _jsonable(obj.tolist())
    if isinstance(obj, (np.floating, float)):
        value = float(obj)
        return value if math.isfinite(value) else None
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, np.bool_):
        return bool(obj)
    return obj
