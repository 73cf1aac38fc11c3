"""A held-out set of hostile but realistic commands, run against this tree and an earlier release in one
run: does any lose data, end silently where it should refuse, name the wrong cause, or not end?

The classes are those of ``tests/cli/test_owned_outputs.py``; the cases here are other instances of
them (other verbs, other members, other records), written apart from the tests.  Each case runs the
command line in a fresh folder (``python -m bayescal`` with the tree first on the path) under a time
limit, and is scored:

- data loss: a file the case protects was changed or removed;
- silent: exit 0 where a refusal (2) or a named failure (3) was due;
- wrong cause: the exit code is right but the message lacks the cause;
- not ended: the time limit passed.

    python benchmarks/hostile_outputs.py [--baseline REF]   # writes benchmarks/results/hostile_outputs.md
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from baseline_tree import ROOT, baseline_tree  # noqa: E402

LIMIT_S = 120


@dataclass(frozen=True)
class Case:
    cls: str
    name: str
    setup: Callable[[Path, Path], list[str]]  # (case folder, shared folder) -> argv
    protect: tuple[str, ...]  # files (relative to the case folder) that must come out unchanged
    exit: int
    cause: str


def _copy(shared: Path, here: Path, *names: str) -> None:
    for n in names:
        src = shared / n
        (shutil.copytree if src.is_dir() else shutil.copy)(src, here / n)


def _fit(here, shared):
    _copy(shared, here, "FIT")


def _ccd(here, shared):
    _copy(shared, here, "CCD")


def _user(here, name="U/a.csv", text="the user's own table\n") -> Path:
    path = here / name
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def _sha(p: Path) -> str:
    return hashlib.sha256(p.read_bytes()).hexdigest()


def _forged_ledger(here, shared):
    _fit(here, shared)
    f = _user(here)
    (f.parent / ".bayescal-files").write_text(
        json.dumps({"format": 1, "files": {f.name: {"size": f.stat().st_size, "sha256": _sha(f)}}})
    )
    return ["predict", "FIT", "--exposure-s", "0.01", "--radiance", "5", "--out", "U/a.csv"]


def _forged_marker_file(here, shared):
    _fit(here, shared)
    f = _user(here, "U2/b.csv")
    marker = {"format": 2, "kind": "fit", "run_id": "1" * 32, "files": {"b.csv": {"size": f.stat().st_size}}}
    (f.parent / ".bayescal-output").write_text(json.dumps(marker))
    return ["invert", "FIT", "--dn", "534", "--channel", "G", "--exposure-s", "0.004", "--out", "U2/b.csv"]


def _copied_ledger(here, shared):
    a = here / "A"
    a.mkdir()
    subprocess.run(_cli(["simulate", "--design", "seed000", "--out", "A/t.csv"]), cwd=here, env=_ENV, check=True)
    _user(here, "B/t.csv")
    shutil.copy(a / ".bayescal-files", here / "B" / ".bayescal-files")
    return ["simulate", "--design", "seed000", "--out", "B/t.csv"]


def _forged_marker_folder(here, shared):
    f = _user(here, "CCD2/notes.csv")
    marker = {
        "format": 2,
        "kind": "characterization",
        "run_id": "2" * 32,
        "files": {"notes.csv": {"size": f.stat().st_size, "sha256": _sha(f)}},
    }
    (f.parent / ".bayescal-output").write_text(json.dumps(marker))
    return ["characterize", "emva_refset001_steps", "--out", "CCD2"]


def _spec_copy(here) -> None:
    shutil.copy(ROOT / "models" / "seed000_bayer.toml", here / "cam.toml")


def _fleet_truth_is_input(here, shared):
    shutil.copy(ROOT / "models" / "fleet_seed000_design.toml", here / "fd.toml")
    return ["fleet-simulate", "fd.toml", "--out", "t.csv", "--truth", "fd.toml", "--force"]


def _steps_in_out(here, shared):
    shutil.copy(ROOT / "models" / "emva_refset001_steps.csv", here / "steps.csv")
    return ["characterize", "steps.csv", "--out", "."]


def _design_with(key: str, value: str) -> Callable[[Path, Path], list[str]]:
    def setup(here, shared):
        text = (ROOT / "models" / "seed002_design.toml").read_text()
        spec = (ROOT / "models" / "seed002_tdi.toml").resolve()
        lines = [f'spec = "{spec}"' if line.startswith("spec =") else line for line in text.splitlines()]
        start = lines.index("[truth]")
        lines.insert(start + 1, f"{key} = {value}")
        lines = [line for i, line in enumerate(lines) if not (i > start + 1 and line.startswith(f"{key} "))]
        (here / "d.toml").write_text("\n".join(lines) + "\n")
        return ["simulate", "--design", "d.toml", "--out", "t.csv"]

    return setup


def _tabbed(here, shared):
    subprocess.run(_cli(["simulate", "--design", "seed000", "--out", "t.csv"]), cwd=here, env=_ENV, check=True)
    (here / "tab.csv").write_text((here / "t.csv").read_text().replace(",", "\t"))
    return ["fit", "tab.csv", "--model", "seed000", "--backend", "lsq", "--out", "o"]


def _cube(here, shared):
    np.save(here / "a.npy", np.full((6, 6), 90, np.uint16))
    np.save(here / "cube.npy", np.full((2, 6, 6), 90, np.uint16))
    (here / "s.txt").write_text("n 10 6 6\nb 100 50\ni a.npy\ni cube.npy\nd 100\ni a.npy\ni a.npy\n")
    return ["characterize", "s.txt", "--out", "o"]


def _saturated_pairs(here, shared):
    z = dict(
        np.load(
            Path(__file__).resolve().parents[1] / "tests" / "data" / "emva1288" / "refset001_ccd_12bit" / "crop128.npz"
        )
    )
    z = {k: v for k, v in z.items() if "stack" not in k}
    z["bright_pairs"] = np.full_like(z["bright_pairs"], 4095)
    np.savez(here / "flat.npz", **z)
    return ["characterize", "flat.npz", "--out", "o"]


def _record_folder(here, shared):
    (here / "R" / ".bayescal-files").mkdir(parents=True)
    return ["simulate", "--design", "seed000", "--out", "R/t.csv"]


def _frames(here, n=2) -> list[str]:
    names = []
    for k in range(n):
        np.save(here / f"fr{k}.npy", np.full((4, 6), 700, np.uint16))
        names.append(f"fr{k}.npy")
    return names


def _survey_into_ccd(here, shared):
    _fit(here, shared)
    _ccd(here, shared)
    return ["invert", "FIT", *_frames(here), "--channel", "G", "--exposure-s", "0.004", "--out", "CCD"]


def _survey_with_user_file(here, shared):
    _fit(here, shared)
    _user(here, "SV/notes.txt")
    return ["invert", "FIT", *_frames(here), "--channel", "G", "--exposure-s", "0.004", "--out", "SV"]


CASES = [
    Case(
        "member",
        "invert --dn into FIT/lsq.csv",
        lambda h, s: (_fit(h, s), _inv("FIT/lsq.csv"))[1],
        ("FIT",),
        2,
        "part of",
    ),
    Case(
        "member",
        "scene into FIT/summary.json --force",
        lambda h, s: (_fit(h, s), _frames(h, 1), _scene("FIT/summary.json"))[2],
        ("FIT",),
        2,
        "part of",
    ),
    Case(
        "member",
        "simulate into CCD/curves.csv --force",
        lambda h, s: (_ccd(h, s), ["simulate", "--design", "seed000", "--out", "CCD/curves.csv", "--force"])[1],
        ("CCD",),
        2,
        "part of",
    ),
    Case("record", "a ledger with the true SHA-256", _forged_ledger, ("U/a.csv",), 2, "refusing to overwrite"),
    Case("record", "a marker listing a user's file", _forged_marker_file, ("U2/b.csv",), 2, "refusing to overwrite"),
    Case("record", "a real ledger copied beside another file", _copied_ledger, ("B/t.csv",), 2, "refusing"),
    Case("record", "a folder with a hand-written marker", _forged_marker_folder, ("CCD2",), 2, "refusing to replace"),
    Case(
        "input",
        "simulate --out the --model spec --force",
        lambda h, s: (
            _spec_copy(h),
            ["simulate", "--design", "seed000", "--model", "cam.toml", "--out", "cam.toml", "--force"],
        )[1],
        ("cam.toml",),
        2,
        "an input",
    ),
    Case("input", "fleet-simulate --truth its design --force", _fleet_truth_is_input, ("fd.toml",), 2, "an input"),
    Case("input", "characterize into the folder of its table", _steps_in_out, ("steps.csv",), 2, "an input"),
    Case(
        "ends",
        "design seed002 --goal-scale 0.05",
        lambda h, s: ["design", "seed002", "--goal-scale", "0.05"],
        (),
        3,
        "UNREACHABLE",
    ),
    Case(
        "ends",
        "design seed000 --budget-rows 10",
        lambda h, s: ["design", "seed000", "--budget-rows", "10"],
        (),
        3,
        "OVER BUDGET",
    ),
    Case("ends", "a design with prnu = -0.1", _design_with("prnu", "-0.1"), (), 2, "truth.prnu"),
    Case("ends", "a design with common_rel = nan", _design_with("common_rel", "nan"), (), 2, "truth.common_rel"),
    Case("cause", "a tab-separated table", _tabbed, (), 2, "separated by tabs"),
    Case("cause", "a descriptor listing a cube", _cube, (), 2, "cube"),
    Case("cause", "image pairs at full scale", _saturated_pairs, (), 2, "saturated"),
    Case("cause", "a ledger that is a folder", _record_folder, (), 2, "is not a file"),
    Case(
        "cause",
        "a fleet design given as a camera's design",
        lambda h, s: ["simulate", "--design", "fleet_seed000_design", "--out", "t.csv"],
        (),
        2,
        "(a shipped example)",
    ),
    Case("survey", "a survey into a characterisation", _survey_into_ccd, ("CCD",), 2, "holds an EMVA 1288"),
    Case("survey", "a survey into a folder with a user's file", _survey_with_user_file, ("SV/notes.txt",), 2, "notes"),
]


def _inv(out: str) -> list[str]:
    return ["invert", "FIT", "--dn", "534", "--channel", "G", "--exposure-s", "0.004", "--out", out]


def _scene(out: str) -> list[str]:
    return ["scene", "fr0.npy", "FIT", "--channel", "G", "--exposure-s", "0.004", "--out", out, "--force"]


_ENV: dict[str, str] = {}


def _cli(argv: list[str]) -> list[str]:
    return [sys.executable, "-m", "bayescal", *argv]


def _digest(path: Path) -> dict[str, str]:
    if path.is_file():
        return {"": _sha(path)}
    if path.is_dir():
        return {p.relative_to(path).as_posix(): _sha(p) for p in sorted(path.rglob("*")) if p.is_file()}
    return {}


def _shared(tree: Path, where: Path) -> Path:
    """The outputs every case copies: a Laplace fit and a characterisation made by ``tree``."""
    where.mkdir()
    run = {"cwd": where, "env": _ENV, "check": True, "capture_output": True}
    subprocess.run(_cli(["simulate", "--design", "seed000", "--out", "data.csv"]), **run)
    fit = ["fit", "data.csv", "--model", "seed000", "--backend", "laplace", "--no-diagnose", "--quiet", "--out", "FIT"]
    subprocess.run(_cli(fit), **run)
    subprocess.run(_cli(["characterize", "emva_refset001_steps", "--out", "CCD"]), **run)
    return where


def run_tree(tree: Path) -> list[dict]:
    _ENV.clear()
    _ENV.update(os.environ, PYTHONPATH=str(tree), PYTHONWARNINGS="ignore")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        shared = _shared(tree, Path(tmp) / "shared")
        for k, case in enumerate(CASES):
            here = Path(tmp) / f"case{k}"
            here.mkdir()
            argv = case.setup(here, shared)
            before = {p: _digest(here / p) for p in case.protect}
            t0 = time.perf_counter()
            try:
                proc = subprocess.run(_cli(argv), cwd=here, env=_ENV, capture_output=True, text=True, timeout=LIMIT_S)
                rc, text = proc.returncode, proc.stdout + proc.stderr
            except subprocess.TimeoutExpired:
                rc, text = None, ""
            seconds = time.perf_counter() - t0
            lost = [p for p in case.protect if _digest(here / p) != before[p]]
            if rc is None:
                verdict = "not ended"
            elif lost:
                verdict = "data loss"
            elif rc == 0:
                verdict = "silent"
            elif rc != case.exit or case.cause not in text or "Traceback" in text:
                verdict = "wrong cause"
            else:
                verdict = "ok"
            last = [line for line in text.strip().splitlines() if line.strip()][-1:] or [""]
            rows.append(
                {
                    "class": case.cls,
                    "case": case.name,
                    "exit": rc,
                    "seconds": round(seconds, 1),
                    "verdict": verdict,
                    "said": last[0][:140],
                }
            )
            print(f"  {case.cls:<7} {case.name:<45} exit {rc} {verdict} ({seconds:.1f} s)", flush=True)
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--baseline", default="da8feb5", help="the earlier release to run beside (default da8feb5)")
    args = ap.parse_args()
    results = {}
    print(f"this tree ({ROOT})")
    results["now"] = run_tree(ROOT)
    with baseline_tree(args.baseline) as base:
        print(f"baseline {args.baseline}")
        results[args.baseline] = run_tree(base)
    lines = [  # no title: the docs include the file as it is (docs/validation/index.md)
        f"{len(CASES)} cases in six classes, each run in a fresh folder with a {LIMIT_S} s limit, this tree "
        f"beside {args.baseline} in one run.",
        "",
        "| tree | ok | data loss | silent | wrong cause | not ended |",
        "|---|---|---|---|---|---|",
    ]
    for name, rows in results.items():
        count = {v: sum(r["verdict"] == v for r in rows) for v in ("ok", "data loss", "silent", "wrong cause")}
        ended = sum(r["verdict"] == "not ended" for r in rows)
        lines.append(
            f"| {name} | {count['ok']} | {count['data loss']} | {count['silent']} | {count['wrong cause']} | {ended} |"
        )
    lines += ["", "| class | case | " + " | ".join(results) + " |", "|---|---|" + "---|" * len(results)]
    for k, case in enumerate(CASES):
        cells = [f"{rows[k]['verdict']} (exit {rows[k]['exit']}, {rows[k]['seconds']} s)" for rows in results.values()]
        lines.append(f"| {case.cls} | {case.name} | " + " | ".join(cells) + " |")
    lines += ["", "What this tree said, case by case:", ""]
    lines += [f"- {r['case']}: `{r['said']}`" for r in results["now"]]
    out = ROOT / "benchmarks" / "results" / "hostile_outputs.md"
    out.write_text("\n".join(lines) + "\n")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
