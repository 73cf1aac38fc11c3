"""Numerical configuration: float64 and JAX's compilation cache.

Calibration residuals are ~1e-4 of the signal, so every inference path runs in
float64 (docs/architecture.md, "Numerics").  JAX compiles each model structure
once; the persistent cache makes the *first* call in a new process cheap too.
Nothing here runs at ``import bayescal``: :func:`enable_numerics` is called by
the first use of a computing attribute of the package, by the computing
subpackages and by the command line.
"""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["enable_float64", "enable_compilation_cache", "enable_numerics", "cache_dir"]

_DONE = False


def enable_float64() -> None:
    """Switch JAX to float64 (idempotent)."""
    import jax

    jax.config.update("jax_enable_x64", True)


def cache_dir() -> Path:
    """Directory of the persistent JAX compilation cache.

    ``$BAYESCAL_CACHE_DIR`` overrides the default ``~/.cache/bayescal/jax``.
    """
    env = os.environ.get("BAYESCAL_CACHE_DIR")
    return Path(env) if env else Path.home() / ".cache" / "bayescal" / "jax"


def enable_compilation_cache() -> Path | None:
    """Turn on JAX's persistent compilation cache unless ``BAYESCAL_NO_CACHE`` is set.

    Returns the cache directory, or ``None`` when disabled or not writable.
    """
    if os.environ.get("BAYESCAL_NO_CACHE"):
        return None
    path = cache_dir()
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError:
        return None
    import jax

    jax.config.update("jax_compilation_cache_dir", str(path))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.2)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    return path


def enable_numerics() -> None:
    """float64 and the compilation cache, once per process (idempotent, cheap after the first call)."""
    global _DONE
    if not _DONE:
        enable_float64()
        enable_compilation_cache()
        _DONE = True
