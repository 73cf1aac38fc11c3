"""What the command being run has said about its outputs: whether it may replace files bayescal did not
write (``--force``), which paths are its inputs (never written, with ``--force`` or without), and which
product its single files are (a report, a prediction table), so that one product added to an output
folder is not replaced by another."""

from __future__ import annotations

import contextlib
import contextvars
import os
from collections.abc import Iterable, Iterator
from pathlib import Path

__all__ = ["overwrite_allowed", "forced", "reading", "read_from", "input_at", "input_inside", "writing_as", "product"]

_FORCE: contextvars.ContextVar[bool] = contextvars.ContextVar("bayescal_overwrite", default=False)
_INPUTS: contextvars.ContextVar[tuple[tuple[Path, str], ...]] = contextvars.ContextVar("bayescal_inputs", default=())
_READING: contextvars.ContextVar[bool] = contextvars.ContextVar("bayescal_reading", default=False)
_PRODUCT: contextvars.ContextVar[str] = contextvars.ContextVar("bayescal_product", default="python")


@contextlib.contextmanager
def _set(var: contextvars.ContextVar, value) -> Iterator[None]:
    token = var.set(value)
    try:
        yield
    finally:
        var.reset(token)


def overwrite_allowed(allowed: bool = True) -> contextlib.AbstractContextManager[None]:
    """Within the block, single files may replace files bayescal did not write (``--force``).

    Output folders, the members of an output folder and the command's inputs are not affected.
    """
    return _set(_FORCE, bool(allowed))


def forced() -> bool:
    """``--force`` is in effect."""
    return _FORCE.get()


def reading(paths: Iterable[str | os.PathLike]) -> contextlib.AbstractContextManager[None]:
    """Within the block, ``paths`` (files or folders, as the user gave them) are inputs of the command too:
    no output replaces one, or a folder that holds one."""
    known = tuple((Path(p).absolute(), str(p)) for p in paths if os.path.lexists(p))
    return _both(_INPUTS.get() + known)


@contextlib.contextmanager
def _both(known: tuple[tuple[Path, str], ...]) -> Iterator[None]:
    with _set(_READING, True), _set(_INPUTS, known):
        yield


def read_from(path: str | os.PathLike) -> None:
    """Note that the running command read ``path`` (a spec a design names, a frame a glob matched): it is
    an input too, checked again when an output is put in place (inside :func:`reading` only)."""
    if _READING.get():
        _INPUTS.set(_INPUTS.get() + ((Path(path).absolute(), str(path)),))


def _same(a: Path, b: Path) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:
        return os.path.normpath(a) == os.path.normpath(b)


def input_at(target: str | os.PathLike) -> str | None:
    """The input (as the user named it) that ``target`` is, if any."""
    target = Path(target).absolute()
    if not os.path.lexists(target):
        return None
    return next((given for path, given in _INPUTS.get() if _same(path, target)), None)


def input_inside(folder: str | os.PathLike) -> str | None:
    """An input (as the user named it) that lies in ``folder`` or is it, if any."""
    folder = Path(folder).absolute()
    if not folder.is_dir():
        return None
    real = Path(os.path.realpath(folder))
    for path, given in _INPUTS.get():
        if _same(path, folder) or Path(os.path.realpath(path)).is_relative_to(real):
            return given
    return None


def writing_as(name: str) -> contextlib.AbstractContextManager[None]:
    """Within the block, single files written are the product ``name`` (a verb's, or ``"report"``)."""
    return _set(_PRODUCT, name)


def product() -> str:
    """The product single files written now are (``"python"`` outside any command)."""
    return _PRODUCT.get()
