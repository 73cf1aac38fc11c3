"""Reading inputs and writing single files atomically: a failed run never leaves a
half-written file (output folders: :mod:`bayescal.io.outputs`)."""

from __future__ import annotations

import errno
import json
import os
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # numpy is imported on use: the CLI's help stays instant
    import numpy as np

__all__ = [
    "read_text",
    "atomic_path",
    "write_errors",
    "write_netcdf",
    "write_text_atomic",
    "write_json_atomic",
    "read_image",
]


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
    """Yield a temporary path beside ``target``; rename it onto ``target`` on success.

    A ``target`` bayescal may not replace (a file of the user's: :func:`bayescal.io.ledger.refusal`)
    is refused before the block runs and again at the rename.  In a bayescal output folder the file
    joins the run's list of files in the same step (:func:`bayescal.io.outputs.record_file`);
    elsewhere it joins the folder's record of bayescal's files (:func:`bayescal.io.ledger.commit_file`).
    A write that fails for want of space or a file-size limit raises
    :class:`~bayescal.errors.OutputError` naming ``target``, and leaves nothing behind.
    """
    from bayescal.io.ledger import check_output_file, commit_file
    from bayescal.io.outputs import record_file

    target = Path(target)
    check_output_file(target)
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        with write_errors(target):
            yield tmp_path
            os.chmod(tmp_path, 0o666 & ~_umask())  # mkstemp makes 0600; outputs get the usual permissions
            if not record_file(tmp_path, target):
                commit_file(tmp_path, target)
    finally:
        if tmp_path.exists():
            tmp_path.unlink()


#: errors of a write that the disk or the system refused: reported as the output's, not as a traceback
_WRITE_ERRNOS = frozenset({errno.ENOSPC, errno.EFBIG, errno.EDQUOT, errno.EROFS})


@contextmanager
def write_errors(target: str | os.PathLike) -> Iterator[None]:
    """Turn a write refused by the disk (full, a quota, a file-size limit, read-only) into
    :class:`~bayescal.errors.OutputError` naming ``target``."""
    from bayescal.errors import OutputError

    try:
        yield
    except OSError as exc:
        if exc.errno not in _WRITE_ERRNOS:
            raise
        raise OutputError(f"cannot write {target}: {os.strerror(exc.errno)}; nothing was written there") from None


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def write_netcdf(data: Any, path: str | os.PathLike) -> None:
    """Write an xarray Dataset or DataTree to ``path`` as NetCDF-4 (h5netcdf).

    The file is serialised in memory and written with a plain write: a disk that fills up or a
    file-size limit then fails in that write, with an ``OSError`` the caller reports, instead of
    inside the HDF5 library, which leaves its handles broken and can crash the process at exit.
    """
    view = data.to_netcdf(None, engine="h5netcdf")
    try:
        payload = bytes(view)
    finally:
        view.release()  # a view left exported when its buffer is collected crashes the process at exit
    with open(path, "wb") as f:
        f.write(payload)


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


def read_image(path: str | os.PathLike) -> np.ndarray:
    """Read a TIFF, PNG, NPY or FITS image as a 2-D (mosaic or mono) or 3-D (H, W, C) array.

    A missing, empty, truncated or mislabelled file raises :class:`~bayescal.errors.TableError`
    naming the file and what it holds, never the decoder's own exception.
    """
    import numpy as np

    from bayescal.errors import TableError

    path = Path(path)
    suffix = path.suffix.lower()
    if not path.exists():
        raise FileNotFoundError(f"no such image: {path}")
    if suffix not in _IMAGE_SUFFIXES:
        raise TableError(f"{path}: unsupported image type '{suffix}'; expected {', '.join(_IMAGE_SUFFIXES)}")
    if path.is_dir():
        raise TableError(f"{path} is a folder; expected an image file")
    if path.stat().st_size == 0:
        raise TableError(f"{path} is empty (0 bytes); expected a {_IMAGE_SUFFIXES[suffix]} image")
    try:
        img = _decode(path, suffix)
    except TableError:
        raise
    except Exception as exc:  # each decoder raises its own types for a truncated or mislabelled file
        raise TableError(
            f"{path} is not a readable {_IMAGE_SUFFIXES[suffix]} image ({type(exc).__name__}: {exc}); "
            "is it truncated, or another format under this name?"
        ) from None
    from bayescal.io import checks

    return checks.image(np.asarray(img), str(path))


#: image files by suffix, and what each holds (for messages)
_IMAGE_SUFFIXES = {
    ".tif": "TIFF",
    ".tiff": "TIFF",
    ".png": "PNG",
    ".npy": "NumPy (.npy)",
    ".fits": "FITS",
    ".fit": "FITS",
    ".fts": "FITS",
}


def _decode(path: Path, suffix: str) -> np.ndarray:
    import numpy as np

    from bayescal.errors import TableError

    if suffix in (".tif", ".tiff"):
        import tifffile

        return np.asarray(tifffile.imread(path))
    if _IMAGE_SUFFIXES[suffix] == "FITS":
        from bayescal.io.fits import read_fits_image

        image = read_fits_image(path)[0]
        return np.moveaxis(image, 0, -1) if image.ndim == 3 else image  # FITS planes first: (H, W, C)
    if suffix == ".png":
        from PIL import Image

        with Image.open(path) as im:
            im.load()
            return np.asarray(im)
    try:
        return np.load(path, allow_pickle=False)
    except ValueError as exc:
        if "pickle" in str(exc):  # object arrays need pickle, which is never loaded from a user's file
            raise TableError(f"{path}: not an array of numbers ({exc}); expected DN as integers or floats") from None
        raise
