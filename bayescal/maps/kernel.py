"""The streaming pass's unit of work, compiled: a row block's frames to every pixel's maps in one XLA program.

For every stack the block's frames are read into 64-byte aligned buffers
(which JAX takes without a copy), then one jitted program reduces them to
per-pixel means and temporal variances (exact integer sums for 16-bit
frames, :func:`bayescal.maps.stacks.block_statistics`) and maps every pixel
(:func:`bayescal.maps.model.map_pixels`, the same function numpy runs on the
population's subsample).  The program takes the fitted models as arguments,
so it is compiled once per sensor structure (stacks, frames, block shape,
colour planes), not per model; the block is cut into sub-blocks of one shape
(the last one padded) that stay in the processor's caches.  XLA releases the
GIL, so the row blocks run on threads.
"""

from __future__ import annotations

import functools
import threading

import numpy as np

from bayescal._config import numerics
from bayescal.maps.model import SensorModel, map_pixels
from bayescal.maps.stacks import block_statistics

__all__ = ["block_maps", "SUB_BLOCK_BYTES"]

#: frame bytes (all stacks) per compiled sub-block: large enough to amortise a call, small enough for the caches
SUB_BLOCK_BYTES = 24e6
_ALIGN = 64


_BUFFERS = threading.local()


def _buffer(k: int, shape: tuple[int, ...], dtype: np.dtype) -> np.ndarray:
    """This thread's ``k``-th read buffer of ``shape``: allocated (and its pages faulted in) once per
    thread, not once per block."""
    cache = _BUFFERS.__dict__.setdefault("arrays", {})
    key = (k, shape, np.dtype(dtype).newbyteorder("=").str)
    if key not in cache:
        if len(cache) > 256:  # another sensor's shapes: let the old buffers go
            cache.clear()
        cache[key] = _aligned(shape, dtype)
    return cache[key]


def _aligned(shape: tuple[int, ...], dtype: np.dtype) -> np.ndarray:
    """An uninitialised array whose data start on a 64-byte boundary (JAX on CPU then aliases it)."""
    dtype = np.dtype(dtype).newbyteorder("=")
    nbytes = int(np.prod(shape)) * dtype.itemsize
    raw = np.empty(nbytes + _ALIGN, np.uint8)
    start = (-raw.ctypes.data) % _ALIGN
    return raw[start : start + nbytes].view(dtype).reshape(shape)


def sub_block_rows(rows: int, step: int, stacks) -> int:
    """Rows per compiled sub-block of a ``rows``-row block: at most about :data:`SUB_BLOCK_BYTES` of frames,
    whole colour cells, and as even a split of the block as that allows."""
    width = stacks[0].shape[2]
    row_bytes = sum(s.shape[0] * s.dtype.itemsize for s in stacks) * width
    most = max(1, int(SUB_BLOCK_BYTES // row_bytes))
    sub = -(-rows // -(-rows // most))  # ceil(rows / number of sub-blocks)
    return sub + (-sub) % step


@functools.cache
def _program(names: tuple[str, ...], outputs: int, planes: tuple[tuple[str, int, int], ...], step: int):
    """The jitted block program for one sensor structure (shapes: jit's own cache, one entry per shape)."""
    import jax
    import jax.numpy as jnp

    def program(mappers: dict, frames: tuple):
        stats = [block_statistics(f, jnp) for f in frames]
        means = jnp.stack([m for m, _ in stats])
        variances = jnp.stack([v for _, v in stats])
        n_stacks, rows, width = means.shape
        out = jnp.zeros((outputs, rows, width), jnp.float32)
        for name, dy, dx in planes:
            sub = means[:, dy::step, dx::step]
            maps = map_pixels(
                mappers[name],
                sub.reshape(n_stacks, -1),
                variances[:, dy::step, dx::step].reshape(n_stacks, -1),
                names,
                jnp,
            )
            out = out.at[:, dy::step, dx::step].set(maps.reshape(-1, *sub.shape[1:]))
        return out

    return jax.jit(program)


def block_maps(model: SensorModel, stacks, r0: int, r1: int) -> np.ndarray:
    """Rows ``r0:r1``: read every stack's frames, reduce and map each pixel -> (outputs, rows, W) float32."""
    import jax

    first = next(iter(model.models.values()))
    program = _program(first.names, len(first.outputs()), tuple(model.planes), model.step)
    mappers = model.mappers
    width = stacks[0].shape[2]
    sub = sub_block_rows(first.info["rows_per_chunk"], model.step, stacks)  # every block: one compiled shape
    out = np.empty((len(model.outputs()), r1 - r0, width), np.float32)
    with numerics():
        mappers = jax.device_put(mappers)
        for s0 in range(r0, r1, sub):
            s1 = min(s0 + sub, r1)
            frames = []
            for k, stack in enumerate(stacks):
                buf = _buffer(k, (stack.shape[0], sub, width), stack.dtype)
                stack.read_rows(s0, s1, buf[:, : s1 - s0])
                buf[:, s1 - s0 :] = buf[:, :1]  # pad a short last sub-block: one compiled shape
                frames.append(buf)
            out[:, s0 - r0 : s1 - r0] = np.asarray(program(mappers, tuple(frames)))[:, : s1 - s0]
    return out
