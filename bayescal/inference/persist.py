"""Traced programs kept on disk, so that a new process loads a model structure's functions instead of tracing them.

JAX's persistent compilation cache (:mod:`bayescal._config`) spares a new process the XLA
compilation of a structure it has met before, but not the tracing that comes first: running the
model's Python through ``jax.value_and_grad`` and ``jax.jacfwd`` costs about two seconds for a
camera's model, every process, every structure (a diagnosis fits several).  Here a function's
traced and lowered program is written once with :mod:`jax.export` and read back by later processes;
its compilation then comes from the persistent cache.

A program is found by a key that holds everything its trace depends on: the model structure's full
description (:class:`~bayescal.model.assemble.Parts`), the data's tree and array shapes, the argument's
shape, the function's name, float64, the JAX backend, and a digest of the bayescal source that the trace
runs (the model, its data and spec, the programs) with the versions of jax, jaxlib and numpyro (any
change to them is a new key).  What cannot be keyed exactly is
not kept: the function is then jitted as usual.  ``BAYESCAL_NO_CACHE`` turns this off with the
compilation cache.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
import threading
from collections.abc import Callable
from functools import lru_cache
from pathlib import Path
from typing import Any

import jax
import numpy as np

__all__ = ["persisted", "programs_dir", "structure_key", "load_json", "save_json", "dtype_of"]

#: programs and records kept on disk (~35 kB each); the least recently written beyond this are removed
#: when one is written
MAX_FILES = 1000
_SUFFIX = ".jaxexport"


def programs_dir() -> Path | None:
    """Where traced programs are kept (beside the compilation cache); None when caching is off or the
    folder cannot be written."""
    from bayescal._config import usable_cache_dir

    base = usable_cache_dir()
    if base is None:
        return None
    path = Path(base) / "programs"
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError:
        return None
    return path if os.access(path, os.W_OK) else None


#: the parts of bayescal a traced program depends on (the model, its data and spec, the programs
#: themselves); a change elsewhere (the command line, the reports, the checks after a fit) keeps them
TRACED_SOURCES = ("model", "inference", "io", "_config.py", "errors.py")


def traced_files(root: Path) -> list[Path]:
    """The Python files of :data:`TRACED_SOURCES` under the package folder ``root``, sorted."""
    files: list[Path] = []
    for part in TRACED_SOURCES:
        files += [root / part] if part.endswith(".py") else list((root / part).rglob("*.py"))
    return sorted(files)


@lru_cache(maxsize=1)
def _source_digest() -> str:
    """The source a program's trace runs (:data:`TRACED_SOURCES`) and the versions of what traces it: a
    program traced by other code is not reused."""
    import jaxlib
    import numpyro

    root = Path(__file__).resolve().parents[1]
    digest = hashlib.sha256()
    for path in traced_files(root):
        digest.update(str(path.relative_to(root)).encode())
        digest.update(path.read_bytes())
    digest.update(f"{jax.__version__} {jaxlib.__version__} {numpyro.__version__}".encode())
    return digest.hexdigest()


def structure_key(structure: str, example: Any, obs: str) -> str | None:
    """The key of one structure's programs, or None when ``structure`` is not an exact description (a
    truncated array in it)."""
    if "..." in structure:
        return None
    leaves, tree = jax.tree.flatten(example)
    shapes = [(np.shape(x), str(dtype_of(x))) for x in leaves]
    text = f"{_source_digest()}|{structure}|{obs}|{tree}|{shapes}|{jax.default_backend()}"
    return hashlib.sha256(text.encode()).hexdigest()


def dtype_of(x: Any) -> np.dtype:
    """The dtype of an array (numpy or JAX, read without converting it) or of a Python scalar."""
    dtype = getattr(x, "dtype", None)
    return np.dtype(dtype) if dtype is not None else np.result_type(x)


def _write_atomic(path: Path, blob: bytes) -> None:
    """A cache file written whole or not at all (not :func:`bayescal.io.outputs.atomic_path`, which keeps
    the ledger of a user's output folder)."""
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".tmp-")
    try:
        with os.fdopen(fd, "wb") as handle:
            handle.write(blob)
        os.replace(tmp, path)
    except OSError:
        Path(tmp).unlink(missing_ok=True)


def _prune(folder: Path) -> None:
    """Remove the oldest programs and records beyond :data:`MAX_FILES` (a source change keys new ones).
    Another process may be pruning too: a file gone meanwhile is skipped."""

    def written(path: Path) -> float:
        try:
            return path.stat().st_mtime
        except OSError:
            return 0.0

    files = sorted((p for p in folder.iterdir() if p.suffix in (_SUFFIX, ".json")), key=written)
    for old in files[: max(len(files) - MAX_FILES, 0)]:
        try:
            old.unlink(missing_ok=True)
        except OSError:
            pass


def load_json(key: str | None, name: str) -> Any:
    """A small record kept beside the programs (None when absent or unreadable)."""
    import json

    folder = programs_dir() if key else None
    if folder is None:
        return None
    try:
        return json.loads((folder / f"{key}-{name}.json").read_text())
    except (OSError, ValueError):
        return None


def save_json(key: str | None, name: str, value: Any) -> None:
    """Keep ``value`` beside the programs of ``key`` (nothing when caching is off)."""
    import json

    folder = programs_dir() if key else None
    if folder is not None:
        _write_atomic(folder / f"{key}-{name}.json", json.dumps(value).encode())


def persisted(fn: Callable, key: str | None, name: str) -> Callable:
    """``jax.jit(fn)``, its program traced once per machine: the first call with an argument of a new shape
    loads the program kept under ``key`` and ``name`` (or traces, exports and keeps it), and later calls
    with that shape run it.  Without a key, or for a function :mod:`jax.export` cannot hold, the plain jit.

    ``fn(arg, data)``: the data's structure and shapes are part of ``key``; the arguments' shapes and
    dtypes are part of the program's name.  Called inside a transformation (``vmap``, ``grad``, an
    enclosing ``jit``), it is the plain jit, traced as usual.
    """
    jitted = jax.jit(fn)
    if key is None:
        return jitted
    calls: dict[tuple, Callable] = {}

    def call(*args):
        leaves, tree = jax.tree.flatten(args)
        if any(isinstance(x, jax.core.Tracer) for x in leaves):
            return jitted(*args)  # inside a transformation (a vmapped MAP search): traced as usual
        signature = (tree, tuple((np.shape(x), dtype_of(x)) for x in leaves))
        run = calls.get(signature)
        if run is None:
            run = calls[signature] = _resolve(jitted, args, key, name, signature)
        if any(isinstance(x, jax.Array) for x in leaves):
            # one kind of argument: jit keys an array placed on a device apart from a host array of the same
            # shape, so a mode search started from a device array (the start) and continued on host arrays
            # (Newton's steps) loaded each program twice, 0.15-0.5 s each on a camera's model
            args = jax.tree.unflatten(tree, [np.asarray(x) if isinstance(x, jax.Array) else x for x in leaves])
        return run(*args)

    call.__name__ = call.__qualname__ = name
    return call


_REGISTERED: set[type] = set()
#: held while a model's Python runs under a trace (numpyro's effect handlers are one stack per process, so
#: two threads may not trace models at once; :mod:`bayescal.inference.program`) and while a named tuple is
#: registered; loading and running a kept program does not need it (the diagnosis loads its candidates'
#: programs from several threads)
TRACING = threading.RLock()


def _register_namedtuples(tree: Any) -> None:
    """Let :mod:`jax.export` write the named tuples among ``tree``'s nodes (a model's data)."""
    from jax import export

    def visit(node: Any) -> None:
        if isinstance(node, tuple):
            kind = type(node)
            if hasattr(kind, "_fields") and kind not in _REGISTERED:
                with TRACING:
                    if kind not in _REGISTERED:
                        name = f"{kind.__module__}.{kind.__qualname__}"
                        export.register_namedtuple_serialization(kind, serialized_name=name)
                        _REGISTERED.add(kind)
            for child in node:
                visit(child)
        elif isinstance(node, dict):
            for child in node.values():
                visit(child)

    visit(tree)


def _resolve(jitted: Any, args: tuple, key: str, name: str, signature: tuple) -> Callable:
    from jax import export

    folder = programs_dir()
    if folder is None:
        return jitted
    tag = hashlib.sha256(f"{key}|{name}|{signature}|{jax.config.jax_enable_x64}".encode()).hexdigest()
    path = folder / f"{tag}{_SUFFIX}"
    exported = None
    _register_namedtuples(args)
    try:
        exported = export.deserialize(bytearray(path.read_bytes()))
    except FileNotFoundError:
        pass
    except Exception:  # a file from another JAX, cut short: traced again and replaced
        exported = None
    if exported is None:
        specs = jax.tree.map(lambda x: jax.ShapeDtypeStruct(np.shape(x), dtype_of(x)), args)
        try:
            exported = export.export(jitted)(*specs)
            blob = exported.serialize()
        except Exception:  # something export cannot hold: the plain jit, as without a cache
            return jitted
        _write_atomic(path, bytes(blob))
        _prune(folder)
    return jax.jit(exported.call)
