"""The bottom of every write: a file's digest, the permissions an output gets, a write the disk refused
named as the output's, and NetCDF written with a plain write."""

from __future__ import annotations

import errno
import hashlib
import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

__all__ = ["sha256", "public", "as_given", "write_errors", "write_netcdf"]


def sha256(path: str | os.PathLike) -> str:
    """The SHA-256 of a file's content, read in blocks of 1 MiB."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def public(path: str | os.PathLike, folder: bool = False) -> None:
    """Give ``path`` the permissions a new file (or folder) gets under the process's umask: ``mkstemp``
    makes files private (0600) and ``mkdtemp`` folders 0700."""
    os.chmod(path, (0o777 if folder else 0o666) & ~_umask())


def as_given(found: Path, given: Path) -> str:
    """``found`` (an absolute folder found above the path ``given``) as the user wrote it, where it is
    part of what was given; messages then show the user's own paths, not the machine's."""
    for p in (given, *given.parents):
        if p.absolute() == found:
            return str(p) if str(p) != "." else "the current folder"
    return str(found)


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
    with open(Path(path), "wb") as f:
        f.write(payload)
