"""Process-wide numerical configuration: float64 and JAX's compilation cache.

Calibration residuals are ~1e-4 of the signal, so every inference path runs in
float64 (DESIGN.md section 5).  JAX compiles each model structure once; the
persistent cache makes the *first* call in a new process cheap too
(DESIGN.md section 4).
"""

from __future__ import annotations

import os
from pathlib import Path

import jax

__all__ = ["enable_float64", "enable_compilation_cache", "cache_dir"]


def enable_float64() -> None:
    """Switch JAX to float64 (idempotent)."""
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
    jax.config.update("jax_compilation_cache_dir", str(path))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.2)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    return path
