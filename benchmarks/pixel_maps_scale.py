"""Per-pixel maps at sensor scale: a 24 Mpix sensor x 20 conditions x 16 frames, out of core.

Run: ``python benchmarks/pixel_maps_scale.py [--megapixels 24] [--conditions 20] [--frames 16] [--dir PATH]``.

The frames (about 15 GB of uint16 at the defaults) are generated streaming to
disk, one frame at a time (Normal approximation of the shot noise, for
speed).  Then, in one run:

1. ``read``: every stack file read, sequentially, in 64 MB pieces (what
   merely touching the frames costs), twice: the first read may come partly
   from disk; the second, from the page cache when the frames fit in memory,
   is the state the maps then run in;
2. ``maps``: ``bayescal maps`` in a fresh process (population from a
   subsample, then every pixel's posterior streamed to a zarr store), with
   its CPU time (user and system) over both cores.

Peak memory is the maps process tree's maximum RSS.  The ratio that compares
like with like is maps against the second read (same page cache).  Writes
``benchmarks/results/pixel_maps_scale.md``.
"""

from __future__ import annotations

import argparse
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from bayescal.validation.sensor import PixelSensor, write_stacks

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"


def tree_rss_mb(pid: int) -> float:
    """Resident memory of a process and all its descendants (Linux /proc), in MB."""
    total, stack = 0, [pid]
    while stack:
        p = stack.pop()
        try:
            status = Path(f"/proc/{p}/status").read_text()
            total += int(next(line.split()[1] for line in status.splitlines() if line.startswith("VmRSS")))
            for task in Path(f"/proc/{p}/task").iterdir():
                stack += [int(c) for c in (task / "children").read_text().split()]
        except (OSError, StopIteration):
            continue
    return total / 1024


def read_all(directory: Path) -> tuple[float, int]:
    t = time.perf_counter()
    total = 0
    buf = bytearray(64 << 20)
    for path in sorted(directory.glob("*.npy")):
        with open(path, "rb", buffering=0) as fh:
            while n := fh.readinto(buf):
                total += n
    return time.perf_counter() - t, total


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--megapixels", type=float, default=24.0)
    parser.add_argument("--conditions", type=int, default=20)
    parser.add_argument("--frames", type=int, default=16)
    parser.add_argument("--dir", help="where to write the frames (default: a temporary directory)")
    parser.add_argument("--keep", action="store_true", help="keep the frames afterwards")
    args = parser.parse_args()
    h = int(np.sqrt(args.megapixels * 1e6 * 2 / 3))
    w = int(args.megapixels * 1e6 / h)
    work = Path(args.dir or tempfile.mkdtemp(prefix="pixel_maps_scale."))
    stacks, out = work / "stacks", work / "maps"
    n_flat = args.conditions // 2  # each flat condition has its dark stack: `conditions` stacks in all
    photons = list(np.geomspace(2000, 30000, n_flat))
    exposures = list(np.linspace(0.05, 0.4, n_flat))
    try:
        t = time.perf_counter()
        generated = not (stacks / "conditions.csv").exists()
        if generated:
            write_stacks(
                PixelSensor(height=h, width=w),
                stacks,
                photons=photons,
                exposure_s=exposures,
                frames=args.frames,
                seed=0,
                shot_noise="normal",
            )
        t_gen = time.perf_counter() - t
        t_first, nbytes = read_all(stacks)
        t_read, _ = read_all(stacks)
        print(f"read {nbytes / 1e9:.1f} GB in {t_first:.1f} s, again in {t_read:.1f} s", flush=True)
        shutil.rmtree(out, ignore_errors=True)
        cpu0 = resource.getrusage(resource.RUSAGE_CHILDREN)
        t = time.perf_counter()
        proc = subprocess.Popen(
            [sys.executable, "-m", "bayescal.cli", "maps", str(stacks), "--out", str(out), "--quiet"],
            env={**os.environ, "PYTHONUNBUFFERED": "1"},
        )
        peak = 0.0
        while proc.poll() is None:  # the whole process tree: the command and its worker processes
            peak = max(peak, tree_rss_mb(proc.pid))
            time.sleep(0.25)
        if proc.returncode:
            raise SystemExit(f"bayescal maps failed with status {proc.returncode}")
        t_maps = time.perf_counter() - t
        cpu1 = resource.getrusage(resource.RUSAGE_CHILDREN)
        user, system = cpu1.ru_utime - cpu0.ru_utime, cpu1.ru_stime - cpu0.ru_stime
        t_read_after, _ = read_all(stacks)  # again, with whatever the maps run left in the page cache
        print(f"maps in {t_maps:.1f} s, peak RSS of the process tree {peak:.0f} MB; read after {t_read_after:.1f} s")
        RESULTS.mkdir(parents=True, exist_ok=True)
        memory = os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE") / 2**30
        lines = [
            "# Per-pixel maps at sensor scale",
            "",
            f"`python benchmarks/pixel_maps_scale.py --megapixels {args.megapixels:g} --conditions {args.conditions} "
            f"--frames {args.frames}`: {h} x {w} pixels, {args.conditions} stacks (flat and dark) of "
            f"{args.frames} uint16 frames "
            f"({nbytes / 1e9:.1f} GB), 2-core machine with {memory:.0f} GiB of memory.",
            "",
            "| step | seconds | ratio to reading |",
            "|---|---|---|",
            f"| generate the frames (streaming) | {f'{t_gen:.0f}' if generated else 'kept from an earlier run'} | |",
            f"| first read of every frame (partly from disk if not cached) | {t_first:.1f} | {t_first / t_read:.2f} |",
            f"| second read, just before the maps (the page cache the maps see) | {t_read:.1f} | 1.00 |",
            f"| `bayescal maps` (population + every pixel's posterior, zarr) | {t_maps:.1f} | {t_maps / t_read:.2f} |",
            f"| read after the maps | {t_read_after:.1f} | {t_read_after / t_read:.2f} |",
            "",
            f"`bayescal maps` used {user:.1f} s of user and {system:.1f} s of system CPU time "
            f"({(user + system) / t_maps:.2f} cores on average); against the first read it took "
            f"{t_maps / t_first:.2f}x. Peak resident memory of the maps process tree (sampled every 0.25 s): "
            f"{peak:.0f} MB. Reading speed: {nbytes / 1e9 / t_first:.1f} GB/s first, "
            f"{nbytes / 1e9 / t_read:.1f} GB/s second, {nbytes / 1e9 / t_read_after:.1f} GB/s after.",
        ]
        (RESULTS / "pixel_maps_scale.md").write_text("\n".join(lines) + "\n")
    finally:
        if not args.keep:
            shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
