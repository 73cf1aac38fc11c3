"""Release the compiled programs bayescal keeps per model structure.

Within a process, programs (potentials, samplers, solvers) are cached per model
structure so that a second fit of the same shape does not compile again.  A
long session that fits many different structures can hand the memory back
with :func:`clear_caches`; the next fit of a structure compiles again (served
from the persistent compilation cache when it is on).
"""

from __future__ import annotations

import sys

__all__ = ["clear_caches"]


def clear_caches() -> None:
    """Forget every compiled program of bayescal and JAX's in-memory caches."""
    for name, module in list(sys.modules.items()):
        if not name.startswith("bayescal.") or module is None:
            continue
        for value in list(vars(module).values()):
            clear = getattr(value, "cache_clear", None)
            if callable(clear) and getattr(value, "__module__", None) == name:
                clear()
    program = sys.modules.get("bayescal.inference.program")
    if program is not None:
        program.clear_program_cache()
    if "jax" in sys.modules:
        import jax

        jax.clear_caches()
