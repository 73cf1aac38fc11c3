"""Verbs that answer from a calibration: predict, invert (values, images, per-pixel maps), plan, scene."""

from __future__ import annotations

import sys
from pathlib import Path


def setting_of(args, cal):
    """The camera setting the arguments give (None for a posterior without camera settings: a film)."""
    from bayescal.model.setting import Setting

    ref = cal.reference
    if ref is None:
        return None
    return Setting(
        args.exposure_s if args.exposure_s is not None else ref.exposure_s,
        args.gain if args.gain is not None else ref.gain,
        args.tdi_stages if args.tdi_stages is not None else ref.tdi_stages,
        args.temperature_c,
    )


def cmd_predict(args) -> int:
    import numpy as np

    from bayescal.cli.results import emit
    from bayescal.io.outputs import write_text_atomic
    from bayescal.posterior.calibration import Calibration
    from bayescal.prediction.readings import predict

    cal = Calibration.load(args.posterior)
    setting = setting_of(args, cal)
    stim = args.stimulus
    if stim is None:
        stim = list(np.linspace(0, cal.calibrated.max_effective / setting.ratio(cal.reference), 7)[1:])
    table = predict(cal, stim, setting, args.channel, n_avg=args.n_avg, seed=args.seed)
    print(
        f"Posterior predictive DN at exposure {setting.exposure_s:g} s, gain {setting.gain:g}, "
        f"TDI {setting.tdi_stages:g} ({cal.stimulus} in {cal.unit}; 95 % intervals):"
    )
    shown = table.drop(columns=["exposure_s", "gain", "tdi_stages", "why"])
    # the requested stimulus as asked (15.9973, not 16); the predictions to four digits
    print(shown.to_string(index=False, float_format="%.4g", formatters={"stimulus": "{:.10g}".format}))
    for why in sorted(set(table.loc[table.extrapolated, "why"])):
        print(f"EXTRAPOLATION: {why}", file=sys.stderr)
    if args.out:
        write_text_atomic(args.out, table.to_csv(index=False, float_format="%.8g"))
    emit(stimulus=cal.stimulus, unit=cal.unit, setting=vars(setting), predictions=table)
    return 0


def cmd_invert(args) -> int:
    from bayescal.io.outputs import reading
    from bayescal.prediction.frames import expand_frames

    images = expand_frames(args.image or [])
    with reading(images):  # the frames a glob names are inputs too: no output replaces them
        return _invert(args, images)


def _invert(args, images) -> int:
    import numpy as np

    from bayescal.cli.results import emit
    from bayescal.errors import SpecError
    from bayescal.io.outputs import write_text_atomic
    from bayescal.posterior.calibration import Calibration
    from bayescal.prediction.invert import invert

    if args.maps is None and bool(images) == (args.dn is not None):
        raise SpecError("give an IMAGE or --dn values (one of them; several images invert a survey)")
    if args.dn is not None and not args.channel:
        raise SpecError("--dn needs --channel")
    if images and not args.out:
        raise SpecError("inverting an image needs --out DIR")
    if args.maps is not None and len(images) > 1:
        raise SpecError("--maps corrects one IMAGE at a time")
    if args.scheduler is not None and (args.maps is not None or args.dn is not None):
        raise SpecError("--scheduler inverts image frames; it does not apply to --maps or --dn")
    survey = len(images) > 1 or args.scheduler is not None
    image = None
    if images and not survey:  # one image: checked before the posterior is read
        from bayescal.io.files import read_image

        image = read_image(images[0])
    cal = Calibration.load(args.posterior)
    if image is not None and getattr(cal, "full_scale", None):
        from bayescal.io import checks

        checks.within_bits(image, cal.full_scale, str(images[0]))
    setting = setting_of(args, cal)
    if args.maps is not None:
        return _invert_with_maps(args, cal, setting, images[0] if images else None, image)
    if args.dn is not None:
        res = invert(cal, np.asarray(args.dn), args.channel, setting, n_avg=args.n_avg, seed=args.seed)
        table = res.to_frame()
        print(res.describe(cal.stimulus) + ":")
        print(table.to_string(index=False, float_format="%.6g"))
        if args.out:
            write_text_atomic(args.out, table.to_csv(index=False, float_format="%.10g"))
        emit(stimulus=cal.stimulus, unit=cal.unit, description=res.describe(cal.stimulus), inversions=table)
        return 0
    return _invert_images(args, cal, setting, images, image)


def _invert_images(args, cal, setting, images, image) -> int:
    """One image into ``--out``, or a survey's frames into ``--out/<frame>/`` (here, or on a Dask cluster)."""
    from bayescal.cli.progress import progress_bar
    from bayescal.cli.results import emit
    from bayescal.prediction.frames import FrameJob, frame_outputs, invert_frames

    survey = image is None
    outs = frame_outputs(images, args.out) if survey else [args.out]
    jobs = [
        FrameJob(
            posterior=str(args.posterior),
            image=str(path),
            out=str(out),
            exposure_s=setting.exposure_s,
            gain=setting.gain,
            tdi_stages=setting.tdi_stages,
            temperature_c=setting.temperature_c,
            cfa=args.cfa,
            channel=args.channel,
            channels=tuple(args.channels.split(",")) if args.channels else None,
            n_avg=args.n_avg,
            seed=args.seed,
        )
        for path, out in zip(images, outs, strict=True)
    ]
    if not survey:
        with progress_bar(1, "inverting", quiet=False):
            (r,) = invert_frames(cal, jobs, first=image)
        print(
            f"inverted {r['pixels']} pixels of {r['image']}: {r['clipped']} clipped (lower bound only), "
            f"{r['below_dark']} at/below dark (upper bound only), {r['extrapolated']} beyond the calibrated range"
        )
        written = sorted(p.name for p in Path(args.out).iterdir() if not p.name.startswith("."))
        print(f"wrote {args.out}/: " + ", ".join(written))
        emit(frames=[r])
        return 0
    where = f"the workers of {args.scheduler}" if args.scheduler else "this machine"
    print(f"inverting {len(jobs)} frames on {where} into {args.out}/<frame>/", file=sys.stderr)
    with progress_bar(len(jobs), "frames", quiet=False) as tick:
        results = invert_frames(cal, jobs, survey=args.out, scheduler=args.scheduler, tick=tick)
    total = {k: sum(r[k] for r in results) for k in ("pixels", "clipped", "below_dark", "extrapolated")}
    print(
        f"inverted {len(results)} frames ({total['pixels']} pixels): {total['clipped']} clipped (lower bound only), "
        f"{total['below_dark']} at/below dark (upper bound only), {total['extrapolated']} beyond the calibrated range"
    )
    print(f"wrote {len(results)} folders under {args.out}/ (one per frame: radiance.nc, median/lower/upper/bound.tif)")
    emit(frames=results, totals=total)
    return 0


def _invert_with_maps(args, cal, setting, path, image) -> int:
    """``invert --maps``: per-pixel correction, then the channel's inversion, with every uncertainty."""
    import numpy as np

    from bayescal.errors import SpecError
    from bayescal.io.outputs import check_output_dir, staged_directory, write_netcdf
    from bayescal.maps.apply import apply_maps
    from bayescal.maps.store import read_maps

    if path is None or not args.out:
        raise SpecError("--maps corrects an IMAGE: give the image and --out DIR")
    if args.exposure_s is None:
        raise SpecError("--maps needs the image's --exposure-s (the dark current scales with it)")
    check_output_dir(args.out, "radiance")
    maps = read_maps(args.maps)
    if image.ndim != 2:
        raise SpecError(f"{path}: --maps corrects a 2-D single-channel image; got shape {image.shape}")
    ds = apply_maps(
        maps,
        image,
        args.exposure_s,
        n_frames=args.n_avg,
        calibration=cal,
        channel=args.channel,
        setting=setting,
        temperature_c=args.temperature_c,
    )
    ds.attrs.update(image=str(path), calibration=cal.source, seed=args.seed)
    with staged_directory(args.out, kind="radiance") as stage:
        write_netcdf(ds, stage("radiance.nc"))
    finite = np.isfinite(ds["median"].to_numpy())
    print(
        f"corrected and inverted {image.size} pixels of {path} with the maps of {args.maps}: "
        f"{ds.attrs['n_defective']} defective pixels masked; median relative interval half-width "
        f"{np.nanmedian((ds['upper'] - ds['lower']).to_numpy()[finite] / 2 / ds['median'].to_numpy()[finite]):.2%}"
    )
    print(f"wrote {Path(args.out) / 'radiance.nc'}")
    return 0


def cmd_plan(args) -> int:
    import numpy as np

    from bayescal.cli.results import emit
    from bayescal.model.setting import Setting
    from bayescal.posterior.calibration import Calibration
    from bayescal.prediction.plan import plan_exposure

    cal = Calibration.load(args.posterior)
    current = Setting(*args.current) if args.current else None  # 1-4 values, checked by the parser
    plan = plan_exposure(
        cal,
        args.channel,
        dn=args.dn,
        current=current,
        stimulus=args.stimulus,
        exposures=args.exposures,
        gains=args.gains,
        tdi_stages=args.tdi_stages,
        window=args.window,
        n_avg=args.n_avg,
        seed=args.seed,
    )
    lo, hi = plan.window
    b = plan.best
    print(f"scene {cal.stimulus}: median {float(np.median(plan.stimulus)):.5g} {cal.unit}")
    print(
        f"best: exposure {b.exposure_s:g} s, gain {b.gain:g}, TDI {b.tdi_stages:g} -> "
        f"P({lo:g} <= DN <= {hi:g}) = {plan.probability:.3f}"
    )
    shown = plan.table.head(args.top)
    print(shown.drop(columns=["why"]).to_string(index=False, float_format="%.4g"))
    for why in sorted(set("; ".join(shown.loc[shown.extrapolated, "why"]).split("; ")) - {""}):
        print(f"EXTRAPOLATION: {why}", file=sys.stderr)
    for r in plan.dropped.itertuples():
        print(f"DROPPED: exposure {r.exposure_s:g} s, gain {r.gain:g}, TDI {r.tdi_stages:g}: {r.why}", file=sys.stderr)
    if len(plan.table) > args.top:
        print(f"(showing the best {args.top} of {len(plan.table)} settings ranked; --top shows more)", file=sys.stderr)
    emit(
        dropped=plan.dropped,
        stimulus_median=float(np.median(plan.stimulus)),
        window=[lo, hi],
        best={"exposure_s": b.exposure_s, "gain": b.gain, "tdi_stages": b.tdi_stages},
        probability=plan.probability,
        settings=plan.table,
    )
    return 0


def cmd_scene(args) -> int:
    from bayescal.io.outputs import write_json_atomic
    from bayescal.posterior.calibration import Calibration
    from bayescal.prediction.images import read_image
    from bayescal.prediction.scene import choose_for_scene

    cals = {str(p): Calibration.load(p) for p in args.posteriors}
    full = args.full or max(cals, key=lambda n: cals[n].coef.shape[-1])
    setting = setting_of(args, cals[full])
    choice = choose_for_scene(
        cals,
        read_image(args.image),
        setting,
        full=full,
        tol=args.tol,
        cfa=args.cfa,
        channel=args.channel,
        channels=args.channels.split(",") if args.channels else None,
        n_avg=args.n_avg,
        seed=args.seed,
    )
    print(choice)
    if args.out:
        write_json_atomic(args.out, choice.to_dict())
    return 0
