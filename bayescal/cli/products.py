"""Verbs that answer from a calibration: predict, invert (values, images, per-pixel maps), plan, scene."""

from __future__ import annotations

import sys
from pathlib import Path


def setting_of(args, cal):
    """The camera setting the arguments give (None for a posterior without camera settings: a film)."""
    from bayescal.posterior.calibration import Setting

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

    from bayescal.io.files import write_text_atomic
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
    print(table.drop(columns=["exposure_s", "gain", "tdi_stages", "why"]).to_string(index=False, float_format="%.4g"))
    for why in sorted(set(table.loc[table.extrapolated, "why"])):
        print(f"EXTRAPOLATION: {why}", file=sys.stderr)
    if args.out:
        write_text_atomic(args.out, table.to_csv(index=False, float_format="%.8g"))
    return 0


def cmd_invert(args) -> int:
    import numpy as np

    from bayescal.errors import SpecError
    from bayescal.io.files import write_text_atomic
    from bayescal.io.outputs import check_output_dir
    from bayescal.posterior.calibration import Calibration
    from bayescal.prediction.images import invert_image, read_image, write_radiance_maps
    from bayescal.prediction.invert import invert

    if args.maps is None and (args.image is None) == (args.dn is None):
        raise SpecError("give an IMAGE or --dn values (one of them)")
    if args.dn is not None and not args.channel:
        raise SpecError("--dn needs --channel")
    if args.image is not None and not args.out:
        raise SpecError("inverting an image needs --out DIR")
    image = read_image(args.image) if args.image is not None else None  # checked before the posterior is read
    cal = Calibration.load(args.posterior)
    if image is not None:
        from bayescal.io import checks

        if getattr(cal, "full_scale", None):
            checks.within_bits(image, cal.full_scale, str(args.image))
    setting = setting_of(args, cal)
    if args.maps is not None:
        return _invert_with_maps(args, cal, setting, image)
    if args.dn is not None:
        res = invert(cal, np.asarray(args.dn), args.channel, setting, n_avg=args.n_avg, seed=args.seed)
        table = res.to_frame()
        print(res.describe(cal.stimulus) + ":")
        print(table.to_string(index=False, float_format="%.6g"))
        if args.out:
            write_text_atomic(args.out, table.to_csv(index=False, float_format="%.10g"))
        return 0
    check_output_dir(args.out, "radiance")
    from bayescal.cli.progress import progress_bar

    channels = args.channels.split(",") if args.channels else None
    with progress_bar(1, "inverting", quiet=False):
        ds = invert_image(
            cal,
            image,
            setting,
            cfa=args.cfa,
            channel=args.channel,
            channels=channels,
            n_avg=args.n_avg,
            seed=args.seed,
        )
    ds.attrs["image"] = str(args.image)
    out = write_radiance_maps(ds, args.out)
    a = ds.attrs
    print(
        f"inverted {image.size} pixels of {args.image}: {a['n_saturated']} clipped (lower bound only), "
        f"{a['n_below_dark']} at/below dark (upper bound only), {a['n_extrapolated']} beyond the calibrated range"
    )
    print(f"wrote {out}/: " + ", ".join(sorted(p.name for p in out.iterdir() if not p.name.startswith("."))))
    return 0


def _invert_with_maps(args, cal, setting, image) -> int:
    """``invert --maps``: per-pixel correction, then the channel's inversion, with every uncertainty."""
    import numpy as np

    from bayescal.errors import SpecError
    from bayescal.io.outputs import check_output_dir, staged_directory
    from bayescal.maps.apply import apply_maps
    from bayescal.maps.store import read_maps

    if args.image is None or not args.out:
        raise SpecError("--maps corrects an IMAGE: give the image and --out DIR")
    if args.exposure_s is None:
        raise SpecError("--maps needs the image's --exposure-s (the dark current scales with it)")
    check_output_dir(args.out, "radiance")
    maps = read_maps(args.maps)
    if image.ndim != 2:
        raise SpecError(f"{args.image}: --maps corrects a 2-D single-channel image; got shape {image.shape}")
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
    ds.attrs.update(image=str(args.image), calibration=cal.source, seed=args.seed)
    with staged_directory(args.out, kind="radiance") as stage:
        ds.to_netcdf(stage("radiance.nc"), engine="h5netcdf")
    finite = np.isfinite(ds["median"].to_numpy())
    print(
        f"corrected and inverted {image.size} pixels of {args.image} with the maps of {args.maps}: "
        f"{ds.attrs['n_defective']} defective pixels masked; median relative interval half-width "
        f"{np.nanmedian((ds['upper'] - ds['lower']).to_numpy()[finite] / 2 / ds['median'].to_numpy()[finite]):.2%}"
    )
    print(f"wrote {Path(args.out) / 'radiance.nc'}")
    return 0


def cmd_plan(args) -> int:
    import numpy as np

    from bayescal.posterior.calibration import Calibration, Setting
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
    print(plan.table.head(args.top).drop(columns=["why"]).to_string(index=False, float_format="%.4g"))
    return 0


def cmd_scene(args) -> int:
    from bayescal.io.files import write_json_atomic
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
