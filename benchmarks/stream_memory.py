"""Peak memory of the streaming stack reduction against stack size (it must stay flat).

Run: ``python benchmarks/stream_memory.py``.  Frames (640 x 480, uint16, like
the EMVA 1288 reference camera) are generated one at a time, as they would be
read from disk, and reduced by :func:`bayescal.io.emva.reduce_stack`; tracemalloc
records the peak of Python/numpy allocations.  Writes
``benchmarks/results/stream_memory.md``.
"""

from __future__ import annotations

import time
import tracemalloc
from pathlib import Path

import numpy as np

from bayescal.io.emva import reduce_stack

RESULTS = Path(__file__).resolve().parents[1] / "benchmarks" / "results"


def frames(n: int, shape=(480, 640), seed: int = 0):
    rng = np.random.default_rng(seed)
    base = rng.normal(1000, 10, shape)
    for _ in range(n):
        yield (base + rng.normal(0, 20, shape)).astype(np.uint16)


def main() -> None:
    lines = ["| frames | stack size (MB as uint16) | peak traced memory (MB) | seconds |", "|---|---|---|---|"]
    for n in (10, 50, 200, 800):
        tracemalloc.start()
        t = time.perf_counter()
        out = reduce_stack(frames(n))
        dt = time.perf_counter() - t
        _, peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
        size = n * 480 * 640 * 2 / 1e6
        lines.append(f"| {n} | {size:.0f} | {peak / 1e6:.1f} | {dt:.2f} |")
        print(lines[-1], out["temporal_var"], flush=True)
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "stream_memory.md").write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
