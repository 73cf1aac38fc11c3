"""Reading inputs: text files in the encodings labs save them in, and images of every format a camera
writes, each refused with the file named when it cannot be read (writing: :mod:`bayescal.io.outputs`)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING

from bayescal.io.outputs.claims import read_from

if TYPE_CHECKING:  # numpy is imported on use: the CLI's help stays instant
    import numpy as np

__all__ = ["read_text", "read_image"]


def read_text(path: str | os.PathLike, error: type[Exception], what: str = "file") -> str:
    """Read a text input (CSV, TOML), saying clearly what is wrong when it cannot be read.

    UTF-8 (with or without a byte-order mark) and UTF-16 with a byte-order
    mark are accepted; anything else, a directory, a missing or unreadable
    path raise ``error`` naming the file (and the line of an undecodable byte).
    """
    path = Path(path)
    if not path.exists():
        from bayescal.io.resources import did_you_mean

        raise error(f"no such {what}: {path}{did_you_mean(path)}")
    if path.is_dir():
        raise error(f"{path} is a directory; expected a {what}")
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise error(f"cannot read {path}: {exc.strerror or exc}") from exc
    read_from(path)
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


def read_image(path: str | os.PathLike) -> np.ndarray:
    """Read a TIFF, PNG, NPY or FITS image as a 2-D (mosaic or mono) or 3-D (H, W, C) array.

    A missing, empty, truncated or mislabelled file raises :class:`~bayescal.errors.TableError`
    naming the file and what it holds, never the decoder's own exception.

    Examples
    --------
    >>> import os, tempfile
    >>> import numpy as np
    >>> import bayescal as bc
    >>> path = os.path.join(tempfile.mkdtemp(), "frame.npy")
    >>> np.save(path, np.arange(6, dtype=np.uint16).reshape(2, 3))
    >>> bc.read_image(path)
    array([[0, 1, 2],
           [3, 4, 5]], dtype=uint16)
    """
    import numpy as np

    from bayescal.errors import TableError

    path = Path(path)
    suffix = path.suffix.lower()
    if not path.exists():
        from bayescal.io.resources import did_you_mean

        raise FileNotFoundError(f"no such image: {path}{did_you_mean(path)}")
    if suffix not in _IMAGE_SUFFIXES:
        raise TableError(f"{path}: unsupported image type '{suffix}'; expected {', '.join(_IMAGE_SUFFIXES)}")
    if path.is_dir():
        raise TableError(f"{path} is a folder; expected an image file")
    if path.stat().st_size == 0:
        raise TableError(f"{path} is empty (0 bytes); expected a {_IMAGE_SUFFIXES[suffix]} image")
    read_from(path)
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
