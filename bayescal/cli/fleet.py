"""The fleet verbs: fleet, fleet-query, fleet-simulate."""

from __future__ import annotations

import sys
from pathlib import Path


def cmd_fleet(args) -> int:
    from bayescal.cli.progress import progress_bar, stage_reporter
    from bayescal.fleet import compare_pooling, fit_fleet, load_fleet_table
    from bayescal.io.outputs import check_output_dir, write_text_atomic
    from bayescal.model.spec import load_spec

    check_output_dir(args.out, "fleet")
    spec = load_spec(args.model)
    if args.pooling:
        spec = spec.replace(fleet={"pooling": args.pooling})
    fleet = load_fleet_table(args.data)
    stage = stage_reporter(args.quiet)
    with progress_bar(len(fleet.units), "units", quiet=args.quiet) as tick:
        result = fit_fleet(fleet, spec, args.backend, seed=args.seed, progress=tick, stage=stage)
    d = result.draws.diagnostics
    stage(
        f"hierarchy: {d['divergences']} divergences, R-hat {d['max_rhat']:.4f}, "
        f"ESS {min(d['min_ess_bulk'], d['min_ess_tail']):.0f}"
    )
    result.save(args.out)
    if args.compare_pooling:
        stage("comparing no / partial / complete pooling (PSIS-LOO over units)")
        table = compare_pooling(fleet, spec, result.fits, seed=args.seed)
        write_text_atomic(Path(args.out) / "pooling_loo.csv", table.to_csv(float_format="%.6g"))
        print(table.to_string(float_format=lambda v: f"{v:.2f}"))
    if args.report:
        from bayescal.fleet.report import write_fleet_report

        write_fleet_report(result, Path(args.out) / "fleet_report.html")
    print(result.hyperparameters().to_string(index=False, float_format=lambda v: f"{v:.4g}"))
    for warning in result.warnings:
        print(f"bayescal: warning: {warning}", file=sys.stderr)
    print(f"wrote {Path(args.out)}/: fleet.nc, summary.csv, hyperparameters.csv, units.csv, summary.json, cameras/")
    if not result.ok:
        print("bayescal: FLEET FIT FAILED: " + "; ".join(result.problems), file=sys.stderr)
        return 3
    return 0


def cmd_fleet_query(args) -> int:
    import numpy as np

    from bayescal.errors import SpecError
    from bayescal.fleet import FleetFit
    from bayescal.fleet.export import write_calibration

    camera = None if args.new_camera else args.camera
    if args.drift_percent is not None and (camera is None or args.date is None):
        raise SpecError(
            "--drift-percent needs --camera and --date (the drift of a measured camera since its last campaign)"
        )
    fleet = FleetFit.load(args.fleet)
    if camera is not None:
        fleet.camera_index(camera)
    if args.date is not None:
        warning = fleet.check_date(args.date, camera, after_last=args.drift_percent is not None)
        if warning:
            print(f"bayescal: warning: {warning}", file=sys.stderr)
    values = fleet.at(camera, args.date, seed=args.seed)
    from bayescal.cli.results import emit

    label = camera or "a new camera of the type"
    print(f"{label} at {args.date or 'its last campaign'}:")
    rows = []
    for k, kind in enumerate(fleet.kinds):
        for c, ch in enumerate(fleet.channels):
            v = np.exp(values[:, k, c]) if kind == "log_gain" else values[:, k, c]
            lo, med, hi = np.quantile(v, [0.025, 0.5, 0.975])
            name = "gain A1" if kind == "log_gain" else ("offset A0" if kind == "offset" else kind)
            print(f"  {ch} {name}: {med:.6g} [{lo:.6g}, {hi:.6g}]")
            rows.append({"channel": ch, "quantity": name, "median": med, "q2.5": lo, "q97.5": hi})
    emit(camera=camera, date=args.date, values=rows)
    if args.drift_percent is not None and camera is not None:  # a camera is required above
        p = fleet.drift_probability(camera, args.date, args.drift_percent, seed=args.seed)
        print(f"P(gain drifted by more than {args.drift_percent:g} % by {args.date}) = {p:.3f}")
        rel = fleet.drift_probability(camera, args.date, args.drift_percent, seed=args.seed, relative=True)
        print(f"P(... by more than {args.drift_percent:g} % against the fleet's common trend) = {rel:.3f}")
        caveat = fleet.drift_caveat(camera)
        if caveat:
            print(f"bayescal: note: {caveat}", file=sys.stderr)
        when = fleet.recalibration_date(camera, args.drift_percent, args.probability)
        emit(
            drift_probability=p,
            relative_drift_probability=rel,
            recalibrate_by=None if when is None else when.date().isoformat(),
        )
        print(
            f"recalibrate by {when.date().isoformat()} (risk {args.probability:g} of a {args.drift_percent:g} % drift)"
            if when is not None
            else f"the risk stays below {args.probability:g} for 10 years"
        )
    if args.calibration:
        write_calibration(args.fleet, args.calibration, camera, args.date, seed=args.seed)
        print(f"wrote {args.calibration}/ (predict, invert and plan read it)")
    return 0


def cmd_fleet_simulate(args) -> int:
    import tomllib

    from bayescal.errors import SpecError
    from bayescal.io.files import read_text
    from bayescal.io.outputs import write_text_atomic
    from bayescal.io.resources import example_path
    from bayescal.validation.fleet import design_from_dict, simulate_fleet

    path = example_path(args.design, "design")
    text = read_text(path, SpecError, "fleet design (TOML)")
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise SpecError(f"{path} is not valid TOML: {exc}") from None
    design = design_from_dict(raw, str(path))
    table, truth = simulate_fleet(design, seed=args.seed)
    write_text_atomic(args.out, table.to_csv(index=False, float_format="%.10g"))
    if args.truth:
        write_text_atomic(args.truth, truth.to_csv(index=False, float_format="%.10g"))
    print(f"wrote {len(table)} rows ({design.n_cameras} cameras, {len(design.campaigns)} campaigns) to {args.out}")
    return 0
