"""Verbs that fit and check calibrations: fit, demo, simulate, select, sbc, report."""

from __future__ import annotations

import sys
from pathlib import Path


def cmd_fit(args) -> int:
    from bayescal import load_spec
    from bayescal.io.outputs import check_output_dir
    from bayescal.model import kinds

    if args.report and args.backend == "lsq":
        from bayescal.errors import SpecError

        raise SpecError(
            "--report draws the posterior's credible bands, and the lsq backend makes no posterior: fit with "
            "--backend laplace or nuts (the report shows least squares beside it)"
        )
    check_output_dir(args.out, "fit")
    spec = load_spec(args.model)
    table = kinds.load_table(spec, args.data)  # the table of the spec's kind (a camera's, a film's)
    return run_fit(
        table, spec, args.backend, args.seed, Path(args.out), args.quiet, report=args.report, diagnose=args.diagnose
    )


def run_fit(
    table,
    spec,
    backend,
    seed,
    out: Path,
    quiet: bool,
    report: bool = False,
    measurements: bool = False,
    diagnose: bool = True,
) -> int:
    import warnings

    from bayescal import FitFailedWarning, fit
    from bayescal.cli.progress import progress_bar, stage_reporter
    from bayescal.cli.results import emit
    from bayescal.fitting.diagnosis import fit_diagnosed
    from bayescal.inference import registry as backends

    inf = spec.inference
    if backend == "emcee":
        total, desc = inf.emcee_burn + inf.emcee_steps, "emcee (ensemble steps)"
    else:
        total, desc = inf.warmup + inf.draws, f"{backend} ({inf.chains} chains)"
    sampling = backends.chained(backend)
    found = None
    with progress_bar(total, desc, quiet or not sampling) as tick:  # draws on a terminal only
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", FitFailedWarning)  # reported below, loudly
            stage = stage_reporter(quiet)
            if diagnose:
                result, found = fit_diagnosed(table, spec, backend, seed=seed, progress=tick, stage=stage)
            else:
                result = fit(table, spec, backend, seed=seed, progress=tick, stage=stage)
    result.save(out, measurements=measurements)
    if found is not None:
        print("DIAGNOSIS: the spec's model did not describe the data; what the library has, by PSIS-LOO:")
        print(found.describe() + "\n")
    doubt = result.diagnostics.extra.get("structure")
    if doubt:
        moved = ", ".join(f"{k} by {v:g} sd" for k, v in doubt["moved_sd"].items())
        if doubt.get("reported"):
            print(
                f"MODEL DOUBT: '{doubt['candidate']}' predicts the data about as well as '{doubt['reported']}' "
                f"(elpd_loo {doubt['elpd_diff']:+g} +- {doubt['dse']:g}) and moves {moved}; the posterior below is "
                "the flexible shape's, which draws the other too: more levels between half and full scale tell "
                "the shapes apart and narrow it\n"
            )
        elif doubt.get("carried", True):
            print(
                f"MODEL DOUBT: the data cannot tell the spec from '{doubt['candidate']}', which moves {moved}; "
                "the posterior below carries both (the candidate nests the spec): measure what tells them apart "
                "to narrow it\n"
            )
        else:
            print(
                f"MODEL DOUBT: '{doubt['candidate']}' predicts the data about as well as the model adopted "
                f"(elpd_loo {doubt['elpd_diff']:+g} +- {doubt['dse']:g}) and moves {moved}; the intervals below "
                "are those of the adopted structure alone and do not cover the other: these quantities are "
                "limited by the structure, not the noise; "
                + (
                    "more levels between half and full scale tell roll-off shapes apart\n"
                    if "roll-off" in doubt["candidate"]
                    else "measure what tells the two apart\n"
                )
            )
    print(result.summary_text())
    emit(ok=bool(result.ok), verdict=result.diagnostics.verdict, diagnosis=None if found is None else found.to_dict())
    if report and result.posterior is not None:
        from bayescal.report.html import write_report

        write_report(out, seed=seed)
    print(f"\nwrote {out}/: " + ", ".join(sorted(p.name for p in out.iterdir() if not p.name.startswith("."))))
    if not result.ok:
        bar = "!" * 72
        print(f"\n{bar}\nFIT FAILED: {result.diagnostics.verdict}\nDo not use these numbers.\n{bar}", file=sys.stderr)
        return 3
    return 0


def cmd_demo(args) -> int:
    from bayescal import load_design, load_spec, simulate
    from bayescal.io.outputs import check_output_dir
    from bayescal.io.resources import models_dir

    design = load_design(models_dir() / "seed000_design.toml")
    spec = load_spec(design.spec or models_dir() / "seed000_bayer.toml")
    out = check_output_dir(args.out, "fit")
    sim = simulate(spec, design, seed=args.seed)
    print(f"Simulated the seed 000 Bayer CCD: {len(sim.table)} rows, sphere scale error {sim.sphere_scale - 1:+.2%}")
    print(
        "True gains, A1 (DN per W m^-2 sr^-1 at gain 1, 1/250 s; compare with the A1 rows' 'Bayes absolute' "
        "column below): " + ", ".join(f"{c} {v[0]:g}" for c, v in sim.truth.response.items())
    )
    return run_fit(sim.table, spec, args.backend, args.seed, out, args.quiet, report=True, measurements=True)


def cmd_simulate(args) -> int:
    from bayescal import load_design, load_spec, simulate
    from bayescal.errors import SpecError

    design = load_design(args.design)
    spec_path = args.model or design.spec
    if spec_path is None:
        raise SpecError("the design names no spec; pass --model")
    sim = simulate(load_spec(spec_path), design, seed=args.seed)
    sim.table.write_csv(args.out)
    print(f"wrote {len(sim.table)} rows to {args.out} (sphere scale drawn: {sim.sphere_scale:.4f})")
    return 0


def cmd_select(args) -> int:
    import warnings

    from bayescal import FitFailedWarning, load_spec, load_table
    from bayescal.fitting.select import compare_specs, f_test_orders, order_candidates

    if args.pooling:
        from bayescal.fleet import compare_pooling, load_fleet_table
        from bayescal.fleet.stage1 import fit_units

        spec, fleet = load_spec(args.model), load_fleet_table(args.data)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", FitFailedWarning)
            fits = fit_units(
                fleet, spec, "laplace" if args.backend not in ("laplace", "nuts") else args.backend, seed=args.seed
            )
        print("PSIS-LOO over units (elpd_diff: this pooling minus the best; dse: its standard error):")
        pooling = compare_pooling(fleet, spec, fits, seed=args.seed)
        print(pooling.to_string(float_format="%.2f"))
        from bayescal.cli.results import emit

        emit(comparison=pooling.reset_index(names="pooling"))
        return 0
    table, spec = load_table(args.data), load_spec(args.model)
    off = tuple(x for x in args.without.split(",") if x)
    frame = table.frame
    lit_gains = frame.loc[frame["stimulus"] > 0, "gain"].nunique()
    specs = order_candidates(spec, tuple(int(o) for o in args.orders), off, domains=lit_gains > 1)
    from bayescal.cli.progress import stage_reporter

    stage_reporter()(f"fitting {len(specs)} candidate models ({args.backend}) for PSIS-LOO")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FitFailedWarning)
        cmp = compare_specs(table, specs, backend=args.backend, seed=args.seed)
    print("PSIS-LOO (elpd_diff: this model minus the best; dse: its standard error):")
    print(cmp.to_string(float_format="%.2f"))
    from bayescal.cli.results import emit

    emit(comparison=cmp.reset_index(names="model"))
    best = cmp.index[0]
    print(f"best: {best}" + ("" if cmp.iloc[0]["fit_ok"] else " (its fit FAILED its diagnostics)"))
    ft = f_test_orders(table, spec, max_order=max(int(o) for o in args.orders))
    if len(ft):
        print("\nleast-squares F-test per channel at the reference setting (baseline):")
        print(ft.to_string(index=False, float_format="%.4g"))
    return 0


def cmd_sbc(args) -> int:
    from bayescal import build_model, load_spec, load_table
    from bayescal.cli.progress import progress_bar
    from bayescal.validation.sbc import run_sbc

    model = build_model(load_table(args.data), load_spec(args.model))
    with progress_bar(args.sims, f"SBC ({args.backend})") as bar:
        result = run_sbc(model, args.sims, args.backend, seed=args.seed, progress=bar)
    result.save(args.out)
    print(result.to_markdown().split("\n\n|")[0])
    print(f"wrote {args.out}.csv, {args.out}.md, {args.out}.png")
    return 0 if result.batch.converged.mean() >= 0.99 else 1


def cmd_report(args) -> int:
    from bayescal.report.html import write_report

    fit_dir = Path(args.fit_dir)
    if not fit_dir.is_dir():
        from bayescal.errors import PosteriorError

        raise PosteriorError(f"{fit_dir} is not a folder; expected a folder written by `bayescal fit`")
    from bayescal.cli.progress import stage_reporter

    stage_reporter()("drawing the report's figures and tables")
    path = write_report(fit_dir, args.out, seed=args.seed, figures=args.figures)
    extra = ", the figures as PNGs" if args.figures else ""
    print(f"wrote {path} (+ {path.with_suffix('.json').name}, {path.with_suffix('.md').name}{extra})")
    return 0
