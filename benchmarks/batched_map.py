"""The vmapped MAP search against the one-by-one search, and against an earlier commit, in one run.

Run: ``python benchmarks/batched_map.py [--baseline REF] [--datasets 32] [--repeats 5]``.

Each tree (this checkout, and ``REF`` checked out into a temporary git worktree) runs in its own
process with the compilation cache off (``BAYESCAL_NO_CACHE=1``): it simulates ``--datasets``
seed-000 tables, times the first batched search (compiling the batched program), then ``--repeats``
batched and one-by-one searches of all of them (medians), and the largest distance between the two
searches' modes in posterior standard deviations.  Results go to
``benchmarks/results/batched_map.{json,md}``.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

from baseline_tree import baseline_tree, short_commit  # run as a script: its folder is on the path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"

CHILD = """
import json, sys, time
import numpy as np
import bayescal as bc
from bayescal.inference.laplace import laplace, laplace_many
from bayescal.inference.program import program_for
from bayescal.inference.start import initial_point
n, repeats = int(sys.argv[1]), int(sys.argv[2])
spec, design = bc.load_spec("seed000"), bc.load_design("seed000")
models = [bc.build_model(bc.simulate(spec, design, seed=s).table, spec) for s in range(n)]
with bc.numerics():
    program = program_for(models[0])
    starts = [initial_point(m, program) for m in models]
    datas = [m.data for m in models]
    one = [laplace(program, d, s) for d, s in zip(datas, starts)]  # compiles the one-by-one programs
    t = time.perf_counter()
    batched = laplace_many(program, datas, starts)
    first = time.perf_counter() - t
    times = {"batched": [], "one_by_one": []}
    for _ in range(repeats):
        t = time.perf_counter()
        laplace_many(program, datas, starts)
        times["batched"].append(time.perf_counter() - t)
        t = time.perf_counter()
        [laplace(program, d, s) for d, s in zip(datas, starts)]
        times["one_by_one"].append(time.perf_counter() - t)
gap = max(float(np.max(np.abs(a.mode - b.mode) / np.sqrt(np.diag(a.cov)))) for a, b in zip(one, batched))
print(json.dumps({
    "first_batched_s": first,
    **{k: float(np.median(v)) for k, v in times.items()},
    "max_mode_gap_sd": gap,
    "converged": sum(b.converged for b in batched),
}))
"""


def run(tree: Path, datasets: int, repeats: int) -> dict:
    env = dict(os.environ, PYTHONPATH=str(tree), BAYESCAL_NO_CACHE="1")
    done = subprocess.run(
        [sys.executable, "-c", CHILD, str(datasets), str(repeats)],
        cwd=tree,
        env=env,
        capture_output=True,
        text=True,
        check=True,
    )
    return json.loads(done.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline", default="HEAD", help="git ref of the baseline (default HEAD)")
    parser.add_argument("--datasets", type=int, default=32)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--out", default="batched_map", help="results stem under benchmarks/results")
    args = parser.parse_args()
    commit = short_commit(args.baseline)
    with baseline_tree(commit) as base:
        rows = {name: run(tree, args.datasets, args.repeats) for name, tree in (("this", ROOT), ("baseline", base))}
    (RESULTS / f"{args.out}.json").write_text(json.dumps({"baseline": commit, **rows}, indent=2) + "\n")
    lines = [
        f"MAP searches of {args.datasets} seed-000 datasets (one structure), medians of {args.repeats}, compilation "
        f"cache off; baseline commit {commit}; 2 CPU cores.",
        "",
        "| tree | first batched search (compiles) s | batched s | one by one s | batched / one by one "
        "| largest mode gap (posterior sds) | converged |",
        "|---|---|---|---|---|---|---|",
    ]
    for name, r in rows.items():
        lines.append(
            f"| {name} | {r['first_batched_s']:.2f} | {r['batched']:.3f} | {r['one_by_one']:.3f} | "
            f"{r['batched'] / r['one_by_one']:.2f} | {r['max_mode_gap_sd']:.1e} | {r['converged']} of {args.datasets} |"
        )
    (RESULTS / f"{args.out}.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
