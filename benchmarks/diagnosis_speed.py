"""What the diagnosis costs, against an earlier commit in one run: datasets of the independent simulator's
departures (:mod:`bayescal.validation.wild`) fitted as a user would (the shipped seed-000 spec, Laplace,
the diagnosis on), by the current tree and by a baseline commit checked out as a git worktree.

Each tree runs in its own process over the same seeds, one after the other; ``--cold`` turns the kept
programs and the compilation cache off (``BAYESCAL_NO_CACHE=1``: every structure traced and compiled in
the process, as on the first dataset of a new protocol). Per dataset: seconds, verdict, what was adopted,
the doubt named, and how many of the six A0/A1 intervals cover the truth: the two trees must agree.

    python benchmarks/diagnosis_speed.py --baseline COMMIT [--seeds 0 2 12 24 28 29] [--cold] [--passes 2]

``--passes 2`` runs each tree's process twice and keeps the second: the programs of every structure the
diagnosis meets are then kept on disk (a later dataset of the same protocol).

Writes ``benchmarks/results/diagnosis_speed.{csv,md}`` (``diagnosis_speed_cold`` for the cold run).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import pandas as pd
from baseline_tree import baseline_tree  # run as a script: its folder is on the path

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "benchmarks" / "results"

#: run inside each tree's own process: its bayescal and its departures benchmark
WORKER = """
import json, sys, time
tree = sys.argv[1]
sys.path[:0] = [tree, tree + "/benchmarks"]
import bayescal
assert bayescal.__file__.startswith(tree), bayescal.__file__
import departures
for seed in map(int, sys.argv[2:]):
    start = time.perf_counter()
    row = departures.one(seed, "laplace")
    seconds = round(time.perf_counter() - start, 1)
    keep = ("seed", "departures", "verdict", "adopted", "doubt", "covered")
    print(json.dumps({**{k: row.get(k) for k in keep}, "seconds": seconds}), flush=True)
"""


def run_tree(tree: Path, seeds: list[int], cold: bool) -> list[dict]:
    env = dict(os.environ, **({"BAYESCAL_NO_CACHE": "1"} if cold else {}))
    done = subprocess.run(
        [sys.executable, "-c", WORKER, str(tree), *map(str, seeds)],
        capture_output=True,
        text=True,
        env=env,
        cwd=tempfile.gettempdir(),
        check=True,
    )
    return [json.loads(line) for line in done.stdout.splitlines() if line.startswith("{")]


def summary(df: pd.DataFrame, baseline: str, cold: bool) -> str:
    wide = df.pivot(index="seed", columns="tree", values="seconds")
    agree = df.pivot(index="seed", columns="tree", values="verdict_key").nunique(axis=1).eq(1)
    lines = [
        "# What the diagnosis costs (independent simulator's departures, seed-000 spec, Laplace)",
        "",
        f"Baseline `{baseline}` against the current tree, each in its own process over the same seeds, "
        + ("cold: no kept programs, no compilation cache." if cold else "the second of two passes (programs kept)."),
        "",
        "| seed | departures | baseline (s) | now (s) | ratio | same verdict, adoption, doubt, coverage |",
        "|---|---|---|---|---|---|",
    ]
    labels = df.drop_duplicates("seed").set_index("seed")["departures"]
    for seed, row in wide.iterrows():
        ratio = row["now"] / row["baseline"]
        lines.append(
            f"| {seed} | {labels[seed]} | {row['baseline']:.1f} | {row['now']:.1f} | {ratio:.2f} | "
            f"{'yes' if agree[seed] else 'NO'} |"
        )
    total = wide.sum()
    lines += [
        "",
        f"Total: {total['baseline']:.0f} s against {total['now']:.0f} s "
        f"(ratio {total['now'] / total['baseline']:.2f}).",
    ]
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--baseline", required=True, help="the commit to compare with")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 2, 12, 24, 28, 29])
    ap.add_argument("--cold", action="store_true", help="no kept programs, no compilation cache")
    ap.add_argument("--passes", type=int, default=1, help="passes per tree, the last one kept (2: warm caches)")
    ap.add_argument("--out", default=None, help="results stem (default diagnosis_speed, _cold with --cold)")
    args = ap.parse_args()
    args.out = args.out or str(RESULTS / ("diagnosis_speed_cold" if args.cold else "diagnosis_speed"))
    with baseline_tree(args.baseline) as base:
        rows = []
        for name, tree in (("baseline", base), ("now", ROOT)):
            for _ in range(args.passes):
                kept = run_tree(tree, args.seeds, args.cold)
            rows += [dict(r, tree=name) for r in kept]
    df = pd.DataFrame(rows)
    df["verdict_key"] = df[["verdict", "adopted", "doubt", "covered"]].astype(str).agg("|".join, axis=1)
    df.drop(columns="verdict_key").to_csv(f"{args.out}.csv", index=False)
    text = summary(df, args.baseline, args.cold)
    Path(f"{args.out}.md").write_text(text)
    print(text)


if __name__ == "__main__":
    main()
