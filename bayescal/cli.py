"""Command line: ``bayescal fit | simulate | demo``.

Exit codes: 0 success, 2 bad input (the message names the row/column or
key), 3 a fit that failed its diagnostics (outputs are still written, marked
FAILED).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

__all__ = ["main"]

MODELS = Path(__file__).resolve().parent.parent / "models"


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``bayescal`` command."""
    parser = _parser()
    args = parser.parse_args(argv)
    from . import BayescalError, enable_compilation_cache

    enable_compilation_cache()
    try:
        return args.func(args)
    except BayescalError as exc:
        print(f"bayescal: error: {exc}", file=sys.stderr)
        return 2


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="bayescal", description="Bayesian radiometric calibration of imaging sensors")
    sub = p.add_subparsers(required=True, metavar="COMMAND")
    f = sub.add_parser("fit", help="fit a calibration model to a measurement table")
    f.add_argument("data", help="CSV or Parquet measurement table")
    f.add_argument("--model", required=True, help="model spec (TOML), e.g. models/seed000_bayer.toml")
    f.add_argument("--backend", default="nuts", choices=["nuts", "emcee", "laplace", "lsq"])
    f.add_argument("--out", required=True, help="output directory")
    f.add_argument("--seed", type=int, default=0)
    f.add_argument("--quiet", action="store_true", help="no progress bar")
    f.set_defaults(func=_cmd_fit)
    s = sub.add_parser("simulate", help="simulate a measurement table from a design with a [truth] table")
    s.add_argument("--design", required=True, help="design TOML (names its spec, holds [truth])")
    s.add_argument("--model", help="model spec (default: the design's)")
    s.add_argument("--out", required=True, help="CSV to write")
    s.add_argument("--seed", type=int, default=0)
    s.set_defaults(func=_cmd_simulate)
    d = sub.add_parser("demo", help="simulate the seed 000 camera, fit it, compare with least squares")
    d.add_argument("--out", default="demo-out", help="output directory (default demo-out)")
    d.add_argument("--seed", type=int, default=0)
    d.add_argument("--backend", default="nuts", choices=["nuts", "emcee", "laplace"])
    d.add_argument("--quiet", action="store_true")
    d.set_defaults(func=_cmd_demo)
    return p


def _cmd_fit(args) -> int:
    from . import load_spec, load_table

    table = load_table(args.data)
    spec = load_spec(args.model)
    return _run_fit(table, spec, args.backend, args.seed, Path(args.out), args.quiet)


def _run_fit(table, spec, backend, seed, out: Path, quiet: bool) -> int:
    import warnings

    from . import FitFailedWarning, fit
    from .progress import progress_bar
    from .report_text import render_summary

    inf = spec.inference
    if backend == "emcee":
        total, desc = inf.emcee_burn + inf.emcee_steps, "emcee (ensemble steps)"
    else:
        total, desc = inf.warmup + inf.draws, f"nuts ({inf.chains} chains)"
    with progress_bar(total, desc, quiet or backend not in ("nuts", "emcee")) as tick:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", FitFailedWarning)  # reported below, loudly
            result = fit(table, spec, backend, seed=seed, progress=tick)
    result.save(out)
    print(render_summary(result))
    print(f"\nwrote {out}/: " + ", ".join(sorted(p.name for p in out.iterdir())))
    if not result.ok:
        bar = "!" * 72
        print(f"\n{bar}\nFIT FAILED: {result.diagnostics.verdict}\nDo not use these numbers.\n{bar}", file=sys.stderr)
        return 3
    return 0


def _cmd_simulate(args) -> int:
    from . import load_design, load_spec, simulate
    from .errors import SpecError

    design = load_design(args.design)
    spec_path = args.model or design.spec
    if spec_path is None:
        raise SpecError("the design names no spec; pass --model")
    sim = simulate(load_spec(spec_path), design, seed=args.seed)
    sim.table.write_csv(args.out)
    print(f"wrote {len(sim.table)} rows to {args.out} (sphere scale drawn: {sim.sphere_scale:.4f})")
    return 0


def _cmd_demo(args) -> int:
    from . import load_design, load_spec, simulate

    design = load_design(MODELS / "seed000_design.toml")
    spec = load_spec(design.spec)
    sim = simulate(spec, design, seed=args.seed)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    sim.table.write_csv(out / "measurements.csv")
    print(f"Simulated the seed 000 Bayer CCD: {len(sim.table)} rows, sphere scale error {sim.sphere_scale - 1:+.2%}")
    print(
        "True gains (DN per W m^-2 sr^-1 at gain 1, 1/250 s): "
        + ", ".join(f"{c} {v[0]:g}" for c, v in sim.truth.response.items())
    )
    return _run_fit(sim.table, spec, args.backend, args.seed, out, args.quiet)


if __name__ == "__main__":
    raise SystemExit(main())
