"""Atomic file output: a failed run never leaves a half-written file, and an output
directory is replaced as a whole, so files of two runs are never mixed."""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # numpy is imported on use: the CLI's help stays instant
    import numpy as np

__all__ = [
    "read_text",
    "atomic_path",
    "write_text_atomic",
    "write_json_atomic",
    "staged_directory",
    "scratch_directory",
    "check_output_dir",
    "read_image",
    "MARKER",
]

#: staging directories of outputs being written in this process (removed on an interrupt)
_STAGING: set[Path] = set()
#: written into every output directory bayescal makes; a directory with it may be replaced by a later run
MARKER = ".bayescal-output"
#: files that identify a directory written by an earlier bayescal version (before the marker)
_KNOWN = ("summary.json", "characterization.json", "radiance.nc", "film_summary.json")


def read_text(path: str | os.PathLike, error: type[Exception], what: str = "file") -> str:
    """Read a text input (CSV, TOML), saying clearly what is wrong when it cannot be read.

    UTF-8 (with or without a byte-order mark) and UTF-16 with a byte-order
    mark are accepted; anything else, a directory, a missing or unreadable
    path raise ``error`` naming the file (and the line of an undecodable byte).
    """
    path = Path(path)
    if not path.exists():
        raise error(f"no such {what}: {path}")
    if path.is_dir():
        raise error(f"{path} is a directory; expected a {what}")
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise error(f"cannot read {path}: {exc.strerror or exc}") from exc
    if raw.startswith((b"\xff\xfe", b"\xfe\xff")):
        try:
            return raw.decode("utf-16")
        except UnicodeDecodeError:
            pass
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = raw[: exc.start].count(b"\n") + 1
        raise error(
            f"{path}: line {line} is not UTF-8 text (byte 0x{raw[exc.start]:02x} at offset {exc.start}); "
            f"expected a UTF-8 {what} (re-save it as UTF-8)"
        ) from None


@contextmanager
def atomic_path(target: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path beside ``target``; rename it onto ``target`` on success."""
    target = Path(target)
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        os.chmod(tmp_path, 0o666 & ~_umask())  # mkstemp makes 0600; outputs get the usual permissions
        os.replace(tmp_path, target)
    finally:
        if tmp_path.exists():
            tmp_path.unlink()


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


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


def check_output_dir(out_dir: str | os.PathLike) -> Path:
    """Refuse an output directory before any work is done, unless bayescal may replace it.

    ``out_dir`` may be missing, an empty directory, or a directory that an
    earlier bayescal run wrote (it holds the :data:`MARKER` file).  Anything
    else (a file, a directory of someone else's files) raises
    :class:`~bayescal.errors.OutputError`.
    """
    from bayescal.errors import OutputError

    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise OutputError(f"{out_dir} is a file; expected a directory for the outputs (give another --out)")
    if out_dir.is_dir():
        names = {p.name for p in out_dir.iterdir()}
        if names and MARKER not in names and not names.intersection(_KNOWN):
            raise OutputError(
                f"{out_dir} is a non-empty directory that bayescal did not write; refusing to replace it "
                "(give a new or empty --out directory)"
            )
    parent = out_dir.absolute().parent
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir() or not os.access(parent, os.W_OK):
        raise OutputError(f"cannot create {out_dir}: {parent} is not a writable directory")
    return out_dir


@contextmanager
def staged_directory(out_dir: str | os.PathLike, kind: str = "output") -> Iterator[Callable[[str], Path]]:
    """Stage a directory of outputs, then put it in place of ``out_dir`` as a whole, only on success.

    Yields ``stage(name) -> Path``: a path to write ``name`` to (``stage.root``
    is the staged directory itself, for stores such as zarr).  If the block
    raises, ``out_dir`` is left exactly as it was; on success it holds only
    this run's files (an earlier bayescal output there is replaced, never
    mixed with the new one; see :func:`check_output_dir`).
    """
    out_dir = check_output_dir(out_dir)
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.staging.", dir=out_dir.parent))
    _STAGING.add(staging)

    def stage(name: str) -> Path:
        path = staging / name
        path.parent.mkdir(parents=True, exist_ok=True)
        return path

    stage.root = staging
    try:
        yield stage
        from bayescal._version import __version__

        (staging / MARKER).write_text(json.dumps({"kind": kind, "bayescal_version": __version__}) + "\n")
        os.chmod(staging, 0o777 & ~_umask())
        old = None
        if out_dir.exists():
            old = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.old.", dir=out_dir.parent))
            os.replace(out_dir, old / "d")
        os.replace(staging, out_dir)
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
    finally:
        _STAGING.discard(staging)
        if staging.exists():
            shutil.rmtree(staging, ignore_errors=True)


@contextmanager
def scratch_directory(beside: str | os.PathLike, name: str) -> Iterator[Path]:
    """A hidden working directory beside ``beside``, removed afterwards, also when the run is interrupted.

    For intermediate files a run needs but does not keep (an image set
    rewritten as stacks); being beside the output, it is on the same disk,
    visible to a cluster's workers when that disk is shared.
    """
    beside = Path(beside).resolve()
    beside.parent.mkdir(parents=True, exist_ok=True)
    scratch = Path(tempfile.mkdtemp(prefix=f".{beside.name}.{name}-", dir=beside.parent))
    _STAGING.add(scratch)
    try:
        yield scratch
    finally:
        _STAGING.discard(scratch)
        shutil.rmtree(scratch, ignore_errors=True)


def discard_staging() -> None:
    """Remove the staging directories of outputs still being written (an interrupted run leaves none)."""
    for path in list(_STAGING):
        shutil.rmtree(path, ignore_errors=True)
        _STAGING.discard(path)


def read_image(path: str | os.PathLike) -> np.ndarray:
    """Read a TIFF, PNG or NPY image as a 2-D (mosaic or mono) or 3-D (H, W, C) array."""
    import numpy as np

    from bayescal.errors import TableError

    path = Path(path)
    suffix = path.suffix.lower()
    if not path.exists():
        raise FileNotFoundError(f"no such image: {path}")
    if suffix in (".tif", ".tiff"):
        import tifffile

        img = tifffile.imread(path)
    elif suffix == ".png":
        from PIL import Image

        with Image.open(path) as im:
            img = np.asarray(im)
    elif suffix == ".npy":
        img = np.load(path, allow_pickle=False)
    else:
        raise TableError(f"{path}: unsupported image type '{suffix}'; expected .tif, .tiff, .png or .npy")
    if img.ndim not in (2, 3):
        raise TableError(f"{path}: expected a 2-D image or an (H, W, C) stack, got shape {img.shape}")
    return img
