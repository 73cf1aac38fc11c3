"""What each stage of a warm fit costs, and the whole fit against an earlier commit, measured in one run.

Run: ``python benchmarks/fit_stages.py [--baseline REF] [--repeats 7] [--backends laplace,nuts]``.

Each tree (this checkout, and ``REF`` checked out into a temporary git worktree) runs in its own
process: it simulates the seed-000 dataset, fits it twice to compile, then fits it ``--repeats``
times.  The processes alternate, one repeat each, so a machine that slows down mid-run slows both.
Reported per backend: the median whole ``bayescal.fit`` call, its ratio to the baseline's, and the
median of each stage in ``Fit.timings`` (a stage the baseline does not time is blank there).
Then the fresh command, ``bayescal fit DATA --model seed000 --backend laplace`` in a new process (with the
diagnosis, and with ``--no-diagnose``), ``--fresh`` times per tree, alternating; the first run of each tree
is left out (it fills the caches).  Results go to ``benchmarks/results/fit_stages.{json,md}``.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from baseline_tree import baseline_tree, short_commit  # run as a script: its folder is on the path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"

CHILD = """
import json, sys, time, warnings
import bayescal as bc
warnings.simplefilter("ignore")
spec = bc.load_spec("seed000"); design = bc.load_design("seed000")
table = bc.simulate(spec, design, seed=0).table
backend = sys.argv[1]
for _ in range(2):
    bc.fit(table, spec, backend, seed=0)
print("ready", flush=True)
for line in sys.stdin:
    t = time.perf_counter()
    fit = bc.fit(table, spec, backend, seed=0)
    whole = time.perf_counter() - t
    print(json.dumps({"whole": whole, **fit.timings}), flush=True)
"""


def _worker(tree: Path, backend: str) -> subprocess.Popen:
    env = dict(os.environ, PYTHONPATH=str(tree))
    proc = subprocess.Popen(
        [sys.executable, "-c", CHILD, backend],
        cwd=tree,
        env=env,
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    assert proc.stdout is not None and proc.stdout.readline().strip() == "ready", f"{tree}: the worker did not start"
    return proc


def _one(proc: subprocess.Popen) -> dict:
    assert proc.stdin is not None and proc.stdout is not None
    proc.stdin.write("go\n")
    proc.stdin.flush()
    return json.loads(proc.stdout.readline())


def measure(trees: dict[str, Path], backend: str, repeats: int) -> dict[str, dict[str, float]]:
    """Median seconds per stage, per tree, the trees' fits alternating."""
    procs = {name: _worker(tree, backend) for name, tree in trees.items()}
    runs: dict[str, list[dict]] = {name: [] for name in trees}
    try:
        for _ in range(repeats):
            for name, proc in procs.items():
                runs[name].append(_one(proc))
    finally:
        for proc in procs.values():
            proc.communicate("")
    return {name: {k: float(np.median([r[k] for r in rs])) for k in rs[0]} for name, rs in runs.items()}


def fresh_command(trees: dict[str, Path], repeats: int, work: Path) -> dict[str, dict[str, float]]:
    """Median wall seconds of a fresh ``bayescal fit --backend laplace`` per tree (with and without the
    diagnosis), the trees alternating; each tree's first run fills the caches and is left out."""
    data = work / "seed000.csv"
    cli = [sys.executable, "-m", "bayescal.cli"]
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    subprocess.run(
        [*cli, "simulate", "--design", "seed000", "--out", str(data)], env=env, check=True, capture_output=True
    )
    times: dict[str, dict[str, list[float]]] = {name: {"diagnosed": [], "no_diagnose": []} for name in trees}
    for r in range(repeats + 1):
        for name, tree in trees.items():
            for kind, extra in (("diagnosed", []), ("no_diagnose", ["--no-diagnose"])):
                out = work / f"{name}-{kind}-{r}"
                argv = [
                    *cli,
                    "fit",
                    str(data),
                    "--model",
                    "seed000",
                    "--backend",
                    "laplace",
                    "--quiet",
                    "--out",
                    str(out),
                ]
                t = time.perf_counter()
                subprocess.run(
                    argv + extra, env=dict(os.environ, PYTHONPATH=str(tree)), check=True, capture_output=True, cwd=work
                )
                if r:
                    times[name][kind].append(time.perf_counter() - t)
    return {name: {k: float(np.median(v)) for k, v in kinds.items()} for name, kinds in times.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline", default="HEAD", help="git ref of the baseline (default HEAD)")
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--backends", default="laplace,nuts")
    parser.add_argument("--fresh", type=int, default=3, help="fresh-command runs per tree (0: none)")
    parser.add_argument("--out", default="fit_stages", help="results stem under benchmarks/results")
    args = parser.parse_args()
    commit = short_commit(args.baseline)
    with baseline_tree(commit) as base, tempfile.TemporaryDirectory() as tmp:
        trees = {"this": ROOT, "baseline": base}
        rows = {b: measure(trees, b, args.repeats) for b in args.backends.split(",") if b}
        fresh = fresh_command(trees, args.fresh, Path(tmp)) if args.fresh else {}
    write(rows, fresh, commit, args.repeats, args.out)


def write(rows: dict, fresh: dict, commit: str, repeats: int, stem: str) -> None:
    RESULTS.mkdir(parents=True, exist_ok=True)
    record = {"baseline": commit, "seconds": rows, "fresh_command_s": fresh}
    (RESULTS / f"{stem}.json").write_text(json.dumps(record, indent=1) + "\n")
    lines = [
        f"Warm `bayescal.fit` of the seed-000 dataset (192 rows, 3 channels), median of {repeats} fits per tree, "
        f"the two trees alternating; baseline commit {commit}; {os.cpu_count()} CPU cores.",
        "",
        "| backend | whole fit s | baseline s | ratio | stages (s) |",
        "|---|---|---|---|---|",
    ]
    for backend, trees in rows.items():
        this, base = trees["this"], trees["baseline"]
        stages = ", ".join(f"{k} {v:.3f}" for k, v in this.items() if k != "whole")
        ratio = this["whole"] / base["whole"]
        lines.append(f"| {backend} | {this['whole']:.3f} | {base['whole']:.3f} | {ratio:.2f} | {stages} |")
    if fresh:
        lines += [
            "",
            "Fresh process, `bayescal fit seed000.csv --model seed000 --backend laplace` (caches filled by a first "
            "run), median wall seconds:",
            "",
            "| | this | baseline | ratio |",
            "|---|---|---|---|",
        ]
        for kind in ("diagnosed", "no_diagnose"):
            this, base = fresh["this"][kind], fresh["baseline"][kind]
            lines.append(f"| {kind.replace('_', ' ')} | {this:.2f} | {base:.2f} | {this / base:.2f} |")
    (RESULTS / f"{stem}.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
