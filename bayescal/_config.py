"""Numerical configuration: float64 and JAX's compilation cache, switched on where bayescal computes.

Calibration residuals are ~1e-4 of the signal, so every inference path runs in float64
(docs/architecture.md, section 5).  JAX compiles each model structure once; the persistent
cache makes the *first* call in a new process cheap too.

Neither is switched on at ``import bayescal``.  Every function of bayescal that computes with
JAX runs inside :func:`numerics` (the decorator :func:`computes`): on entry float64 is switched
on and, unless the user has set a cache directory of their own, bayescal's persistent cache;
when the outermost such call returns, JAX's settings are put back as they were, so a user's
own JAX code before and after a fit runs as if bayescal had never been imported.  Threads that
bayescal starts inside the scope (the chains of a sampler) see the same settings.  A user who
wants float64 for the whole process calls :func:`enable_numerics`.
"""

from __future__ import annotations

import functools
import os
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

__all__ = [
    "numerics",
    "computes",
    "enable_float64",
    "enable_compilation_cache",
    "enable_numerics",
    "cache_dir",
    "usable_cache_dir",
]

#: JAX settings bayescal changes inside :func:`numerics`: name -> value (None: the cache's, decided on entry)
_SETTINGS = ("jax_enable_x64", "jax_compilation_cache_dir", "jax_persistent_cache_min_compile_time_secs")
#: compilations shorter than this are not written to the persistent cache (seconds)
_MIN_COMPILE_S = 0.2

_LOCK = threading.RLock()
_DEPTH = 0
_SAVED: dict[str, Any] = {}
_OWN_CACHE = False


def cache_dir() -> Path:
    """Directory of the persistent JAX compilation cache.

    ``$BAYESCAL_CACHE_DIR`` overrides the default ``~/.cache/bayescal/jax``.
    """
    env = os.environ.get("BAYESCAL_CACHE_DIR")
    return Path(env) if env else Path.home() / ".cache" / "bayescal" / "jax"


def usable_cache_dir() -> str | None:
    """bayescal's cache directory, or None when disabled (``BAYESCAL_NO_CACHE``) or not writable."""
    if os.environ.get("BAYESCAL_NO_CACHE"):
        return None
    path = cache_dir()
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError:
        return None
    return str(path) if os.access(path, os.W_OK) else None


@contextmanager
def numerics() -> Iterator[None]:
    """Run the block with float64 and bayescal's compilation cache; restore JAX's settings after.

    Re-entrant and shared by threads: nested and concurrent scopes switch the settings on once,
    and the last one to leave puts them back.

    Examples
    --------
    >>> import jax
    >>> import bayescal as bc
    >>> before = jax.config.jax_enable_x64
    >>> with bc.numerics():  # float64 inside the block, for your own JAX code beside bayescal's
    ...     jax.numpy.zeros(1).dtype
    dtype('float64')
    >>> jax.config.jax_enable_x64 == before  # restored after it
    True
    """
    global _DEPTH, _OWN_CACHE
    with _LOCK:
        if _DEPTH == 0:
            import jax

            _SAVED.update({name: getattr(jax.config, name) for name in _SETTINGS})
            jax.config.update("jax_enable_x64", True)
            _OWN_CACHE = False
            if _SAVED["jax_compilation_cache_dir"] is None and (path := usable_cache_dir()) is not None:
                jax.config.update("jax_compilation_cache_dir", path)
                jax.config.update("jax_persistent_cache_min_compile_time_secs", _MIN_COMPILE_S)
                _OWN_CACHE = True
        _DEPTH += 1
    try:
        yield
    finally:
        with _LOCK:
            _DEPTH -= 1
            if _DEPTH == 0:
                _restore()


def _restore() -> None:
    import jax

    for name, value in _SAVED.items():
        jax.config.update(name, value)
    if _OWN_CACHE:  # the cache was opened on bayescal's directory: forget it, so a user's own setting counts
        from jax.experimental.compilation_cache import compilation_cache

        compilation_cache.reset_cache()


def computes[F: Callable[..., Any]](fn: F) -> F:
    """Decorator: run ``fn`` inside :func:`numerics`."""

    @functools.wraps(fn)
    def inside(*args: Any, **kwargs: Any) -> Any:
        with numerics():
            return fn(*args, **kwargs)

    return inside  # type: ignore[return-value]


def enable_float64() -> None:
    """Switch JAX to float64 for the whole process (idempotent; bayescal itself does not need it)."""
    import jax

    jax.config.update("jax_enable_x64", True)
    if _DEPTH:
        _SAVED["jax_enable_x64"] = True


def enable_compilation_cache() -> Path | None:
    """Turn on bayescal's persistent compilation cache for the whole process (unless ``BAYESCAL_NO_CACHE``).

    Returns the cache directory, or ``None`` when disabled or not writable.
    """
    path = usable_cache_dir()
    if path is None:
        return None
    import jax

    jax.config.update("jax_compilation_cache_dir", path)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", _MIN_COMPILE_S)
    if _DEPTH:
        _SAVED.update(jax_compilation_cache_dir=path, jax_persistent_cache_min_compile_time_secs=_MIN_COMPILE_S)
    return Path(path)


def enable_numerics() -> None:
    """float64 and the compilation cache for the whole process (what bayescal does inside its own calls)."""
    enable_float64()
    enable_compilation_cache()
