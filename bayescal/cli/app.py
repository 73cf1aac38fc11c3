"""Command line: ``bayescal fit | predict | invert | plan | simulate | demo | fleet | ...``.

Exit codes: 0 success, 2 bad input (the message names the row/column or
key), 3 a fit that failed its diagnostics (outputs are still written, marked
FAILED).
"""

from __future__ import annotations

import argparse
import math
import os
import signal
import sys
from pathlib import Path

from bayescal.inference import registry as backends

__all__ = ["main"]


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``bayescal`` command (exit codes in the module docstring)."""
    parser = _parser()
    args = parser.parse_args(argv)
    from bayescal._config import numerics
    from bayescal.errors import BayescalError

    previous = _catch_interrupts()
    try:
        with numerics():
            return args.func(args)
    except BayescalError as exc:
        print(f"bayescal: error: {exc}", file=sys.stderr)
        return 2
    except (OSError, UnicodeError) as exc:  # unreadable or unwritable paths, wrong encodings
        print(f"bayescal: error: {_os_message(exc)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        _interrupted()
    finally:
        if previous is not None:
            signal.signal(signal.SIGINT, previous)


def _interrupted(*_) -> None:
    """Ctrl-C: remove staged outputs and leave at once with status 130.

    Installed as the SIGINT handler rather than left to ``KeyboardInterrupt``,
    which JAX's garbage-collection callback can swallow (the run then went on
    to finish with status 0); chains still running in worker threads cannot be
    stopped from Python, so the process does not wait for them.
    """
    from bayescal.io.files import discard_staging

    discard_staging()
    print("\nbayescal: interrupted; no output was written or replaced", file=sys.stderr)
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(130)


def _catch_interrupts():
    """Install :func:`_interrupted` for SIGINT (main thread only); returns the previous handler."""
    import threading

    if threading.current_thread() is not threading.main_thread():
        return None
    return signal.signal(signal.SIGINT, _interrupted)


def _os_message(exc: BaseException) -> str:
    if isinstance(exc, UnicodeDecodeError):
        return f"cannot decode the input as {exc.encoding} text ({exc.reason} at byte {exc.start}); save it as UTF-8"
    if isinstance(exc, OSError) and exc.filename is not None:
        what = {
            IsADirectoryError: "is a directory; expected a file",
            NotADirectoryError: "is not a directory",
            FileNotFoundError: "no such file or directory",
            PermissionError: "permission denied",
        }.get(type(exc), exc.strerror or str(exc))
        return f"{exc.filename}: {what}"
    return str(exc)


def _parser() -> argparse.ArgumentParser:
    from bayescal import __version__

    p = argparse.ArgumentParser(
        prog="bayescal",
        description="Bayesian radiometric calibration of imaging sensors",
        epilog="exit codes: 0 ok, 2 bad input (names the file, row, column or key), "
        "3 the fit failed its diagnostics or does not fit its data, 130 interrupted",
    )
    p.add_argument("--version", action="version", version=f"bayescal {__version__}")
    sub = p.add_subparsers(required=True, metavar="COMMAND")
    f = sub.add_parser("fit", help="fit a calibration model to a measurement table")
    f.add_argument("data", help="CSV or Parquet measurement table")
    f.add_argument("--model", required=True, help="model spec (TOML), e.g. models/seed000_bayer.toml")
    f.add_argument(
        "--backend",
        default="nuts",
        choices=backends.names(baseline=True),
        help="inference backend (default nuts)",
    )
    f.add_argument("--out", required=True, help="output directory")
    f.add_argument("--seed", type=int, default=0, help=SEED_HELP)
    f.add_argument("--quiet", action="store_true", help="no progress bar")
    f.add_argument("--report", action="store_true", help="also write OUT/report.html (+ .json, .md)")
    f.set_defaults(func=_cmd_fit)
    pr = sub.add_parser("predict", help="posterior predictive DN at a (possibly unmeasured) setting")
    pr.add_argument("posterior", help="fit directory or its posterior.nc")
    _setting_args(pr, required=True)
    pr.add_argument("--radiance", "--stimulus", dest="stimulus", type=_floats, help="stimulus values (comma list)")
    pr.add_argument("--channel", action="append", help="channel(s) (default all)")
    pr.add_argument("--n-avg", type=_finite, default=1.0, help="pixels x frames averaged per reading (default 1)")
    pr.add_argument("--out", help="also write the table as CSV")
    pr.add_argument("--seed", type=int, default=0, help=SEED_HELP)
    pr.set_defaults(func=_cmd_predict)
    iv = sub.add_parser("invert", help="radiance posterior of DN values or an image (median and 95 %% interval)")
    iv.add_argument("posterior", help="fit directory or its posterior.nc")
    iv.add_argument("image", nargs="?", help="TIFF, PNG or NPY image")
    iv.add_argument("--dn", type=_floats, help="DN values instead of an image (comma list)")
    _setting_args(iv, required=False)
    _image_args(iv, channel_help="channel of a single-channel image or of --dn values")
    iv.add_argument("--out", help="output directory (image) or CSV (--dn)")
    iv.add_argument(
        "--maps",
        help="per-pixel maps directory (from `bayescal maps`): correct every pixel before inverting",
    )
    iv.add_argument("--seed", type=int, default=0, help=SEED_HELP)
    iv.set_defaults(func=_cmd_invert)
    mp = sub.add_parser(
        "maps", help="per-pixel relative gain, offset, dark current and defect maps from flat and dark frame stacks"
    )
    mp.add_argument("stacks", help="directory with conditions.csv and one .npy/.tif/.raw file per stack")
    mp.add_argument("--out", required=True, help="output directory (holds maps.zarr, or maps.nc with --netcdf)")
    mp.add_argument("--calibration", help="channel-level fit directory the maps are relative to (provenance)")
    mp.add_argument("--netcdf", action="store_true", help="write NetCDF (maps.nc) instead of zarr")
    mp.add_argument(
        "--cfa", help="Bayer pattern of raw mosaic frames (RGGB, BGGR, GRBG, GBRG): one population per colour"
    )
    mp.add_argument("--channel", default="M", help="channel name of a monochrome sensor (default M)")
    mp.add_argument(
        "--fit-pixels", type=int, default=262_144, help="pixels used to fit the population (default 262144)"
    )
    mp.add_argument("--rows-per-chunk", type=int, default=None, help="rows per block (default: ~48 MB per block)")
    mp.add_argument(
        "--scheduler", help="address of a dask.distributed scheduler (e.g. tcp://host:8786); default: this machine"
    )
    mp.add_argument("--report", action="store_true", help="also write OUT/maps_report.html (+ .md)")
    mp.add_argument("--quiet", action="store_true", help="no progress bar or stage messages")
    mp.set_defaults(func=_cmd_maps)
    pl = sub.add_parser("plan", help="choose gain/exposure/TDI so the next frame lands in a DN window")
    pl.add_argument("posterior", help="fit directory or its posterior.nc")
    pl.add_argument("--channel", required=True, help="channel the reading (or the scene) is of")
    pl.add_argument("--dn", type=_finite, help="reading at the current setting")
    pl.add_argument("--current", type=_setting_values, help="current setting: EXPOSURE_S[,GAIN[,TDI[,TEMPERATURE_C]]]")
    pl.add_argument("--radiance", "--stimulus", dest="stimulus", type=_finite, help="known scene stimulus instead")
    pl.add_argument("--exposures", type=_floats, required=True, help="allowed exposures, s (comma list)")
    pl.add_argument("--gains", type=_floats, default=[1.0], help="allowed gains (comma list)")
    pl.add_argument("--tdi-stages", type=_floats, default=[1.0], help="allowed TDI stages (comma list)")
    pl.add_argument("--window", type=_floats, help="target DN window LOW,HIGH (default 1080,1920 scaled to bits)")
    pl.add_argument("--n-avg", type=_finite, default=1.0, help="pixels x frames averaged per reading (default 1)")
    pl.add_argument("--top", type=int, default=5, help="rows to print")
    pl.add_argument("--seed", type=int, default=0, help=SEED_HELP)
    pl.set_defaults(func=_cmd_plan)
    rp = sub.add_parser("report", help="HTML report (figures embedded) + report.json + report.md of a fit")
    rp.add_argument("fit_dir", help="directory written by `bayescal fit`")
    rp.add_argument("--out", help="HTML path (default FIT_DIR/report.html); .json and .md go beside it")
    rp.add_argument("--seed", type=int, default=0, help=SEED_HELP)
    rp.set_defaults(func=_cmd_report)
    ch = sub.add_parser("characterize", help="EMVA 1288: standard estimates beside posteriors (K, R, QE, dark, ...)")
    ch.add_argument("input", help="EMVA 1288 descriptor (.txt) with its images, crop128.npz, or a reduced steps.csv")
    ch.add_argument("--out", required=True, help="output directory")
    ch.add_argument("--seed", type=int, default=0, help=SEED_HELP)
    ch.set_defaults(func=_cmd_characterize)
    se = sub.add_parser("select", help="compare polynomial orders / components by PSIS-LOO (F-test beside it)")
    se.add_argument("data", help="CSV or Parquet measurement table")
    se.add_argument("--model", required=True, help="base model spec (TOML)")
    se.add_argument("--orders", type=_orders, default=[1, 2, 3], help="response orders 1-4 to compare (default 1,2,3)")
    se.add_argument("--without", default="", help="components to try switching off: level_errors,excess,exposure_slope")
    se.add_argument("--backend", default="laplace", choices=backends.names(), help="backend (default laplace)")
    se.add_argument("--seed", type=int, default=0, help=SEED_HELP)
    se.add_argument(
        "--pooling",
        action="store_true",
        help="a fleet table (camera column): compare no / partial / complete pooling by PSIS-LOO over units",
    )
    se.set_defaults(func=_cmd_select)
    sc = sub.add_parser("scene", help="cheapest calibration whose inversion of an image matches the full model's")
    sc.add_argument("image", help="TIFF, PNG or NPY image (the scene)")
    sc.add_argument("posteriors", nargs="+", help="fit directories (or posterior.nc) of the candidate models")
    _setting_args(sc, required=False)
    _image_args(sc, channel_help="channel of a single-channel image")
    sc.add_argument("--full", help="the reference candidate (default: the highest response order)")
    sc.add_argument("--tol", type=_finite, default=0.1, help="allowed deviation in posterior sds (default 0.1)")
    sc.add_argument("--out", help="write the comparison as JSON here")
    sc.add_argument("--seed", type=int, default=0, help=SEED_HELP)
    sc.set_defaults(func=_cmd_scene)
    sb = sub.add_parser("sbc", help="simulation-based calibration of a model over a table's design (rank tests)")
    sb.add_argument("data", help="CSV or Parquet table: its design (settings, levels) is used, not its readings")
    sb.add_argument("--model", required=True, help="model spec (TOML); its priors generate the datasets")
    sb.add_argument("--sims", type=int, default=200, help="simulated datasets (default 200)")
    sb.add_argument("--backend", default="nuts", choices=backends.names(), help="backend of the refits (default nuts)")
    sb.add_argument("--out", required=True, help="output stem: writes STEM.csv, STEM.md, STEM.png")
    sb.add_argument("--seed", type=int, default=0, help=SEED_HELP)
    sb.set_defaults(func=_cmd_sbc)
    s = sub.add_parser("simulate", help="simulate a measurement table from a design with a [truth] table")
    s.add_argument("--design", required=True, help="design TOML (names its spec, holds [truth])")
    s.add_argument("--model", help="model spec (default: the design's)")
    s.add_argument("--out", required=True, help="CSV to write")
    s.add_argument("--seed", type=int, default=0, help=SEED_HELP)
    s.set_defaults(func=_cmd_simulate)
    fl = sub.add_parser("fleet", help="calibrate a fleet of cameras over campaigns: each alone, then the hierarchy")
    fl.add_argument(
        "data", help="CSV or Parquet measurement table with 'camera' and optional 'campaign' (date) columns"
    )
    fl.add_argument("--model", required=True, help="model spec (TOML) of one camera, with an optional [fleet] section")
    fl.add_argument("--out", required=True, help="output directory (fleet posterior, summaries, per-camera fits)")
    fl.add_argument(
        "--backend", default="laplace", choices=("laplace", "nuts"), help="stage one's backend (default laplace)"
    )
    fl.add_argument("--pooling", choices=("partial", "none", "complete"), help="override the spec's [fleet] pooling")
    fl.add_argument(
        "--compare-pooling", action="store_true", help="also compare no/partial/complete pooling by PSIS-LOO"
    )
    fl.add_argument("--report", action="store_true", help="also write OUT/fleet_report.html")
    fl.add_argument("--seed", type=int, default=0, help=SEED_HELP)
    fl.add_argument("--quiet", action="store_true", help="no progress bar")
    fl.set_defaults(func=_cmd_fleet)
    fq = sub.add_parser("fleet-query", help="a fleet camera at a date, its drift probability, its calibration")
    fq.add_argument("fleet", help="directory written by `bayescal fleet`")
    who = fq.add_mutually_exclusive_group(required=True)
    who.add_argument("--camera", help="camera name (as in the table's camera column)")
    who.add_argument("--new-camera", action="store_true", help="a camera of the type never measured")
    fq.add_argument("--date", help="ISO date (default: the camera's last campaign)")
    fq.add_argument(
        "--drift-percent", type=_finite, help="P(|gain change since the last campaign| > this %%) at --date"
    )
    fq.add_argument("--probability", type=_finite, default=0.05, help="risk for the recalibration date (default 0.05)")
    fq.add_argument("--calibration", help="write this fit directory (for predict, invert, plan)")
    fq.add_argument("--seed", type=int, default=0, help=SEED_HELP)
    fq.set_defaults(func=_cmd_fleet_query)
    fs = sub.add_parser("fleet-simulate", help="simulate a fleet's campaigns (independent simulator) from a design")
    fs.add_argument("design", help="fleet design TOML, e.g. models/fleet_seed000_design.toml")
    fs.add_argument("--out", required=True, help="measurement table CSV to write")
    fs.add_argument("--truth", help="also write the true coefficients per unit to this CSV")
    fs.add_argument("--seed", type=int, default=0, help=SEED_HELP)
    fs.set_defaults(func=_cmd_fleet_simulate)
    d = sub.add_parser("demo", help="simulate the seed 000 camera, fit it, compare with least squares")
    d.add_argument("--out", default="demo-out", help="output directory (default demo-out)")
    d.add_argument("--seed", type=int, default=0, help=SEED_HELP)
    d.add_argument("--backend", default="nuts", choices=backends.names(), help="backend (default nuts)")
    d.add_argument("--quiet", action="store_true", help="no progress bar")
    d.set_defaults(func=_cmd_demo)
    return p


SEED_HELP = "seed of every random number (default 0): the same seed gives the same result"


def _finite(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got '{text}'") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"expected a finite number, got '{text}'")
    return value


def _setting_values(text: str) -> list[float]:
    values = _floats(text)
    if not 1 <= len(values) <= 4:
        raise argparse.ArgumentTypeError(
            f"expected EXPOSURE_S[,GAIN[,TDI[,TEMPERATURE_C]]] (1 to 4 numbers), got {len(values)}: '{text}'"
        )
    return values


def _orders(text: str) -> list[int]:
    out = []
    for v in text.split(","):
        v = v.strip()
        if v not in {"1", "2", "3", "4"}:
            raise argparse.ArgumentTypeError(f"expected response orders among 1,2,3,4 (comma list), got '{v}'")
        out.append(int(v))
    return out


def _floats(text: str) -> list[float]:
    try:
        values = [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers, got '{text}'") from None
    if not values or not all(math.isfinite(v) for v in values):
        raise argparse.ArgumentTypeError(f"expected comma-separated finite numbers, got '{text}'")
    return values


def _setting_args(p: argparse.ArgumentParser, required: bool) -> None:
    p.add_argument("--exposure-s", type=_finite, required=required, help="exposure time, s")
    p.add_argument("--gain", type=_finite, default=None, help="gain factor (default the reference gain)")
    p.add_argument("--tdi-stages", type=_finite, default=None, help="TDI stages (default the reference)")
    p.add_argument("--temperature-c", type=_finite, default=None, help="sensor temperature, degC (default reference)")


def _image_args(p, channel_help: str) -> None:
    """How an image's pixels map to channels, and how many readings each value averages."""
    p.add_argument("--cfa", help="Bayer pattern of a raw mosaic: RGGB, BGGR, GRBG, GBRG")
    p.add_argument("--channel", help=channel_help)
    p.add_argument("--channels", help="comma list naming the planes of an (H, W, C) image")
    p.add_argument("--n-avg", type=_finite, default=1.0, help="pixels x frames averaged per value (default 1)")


def _setting(args, cal):
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


def _cmd_predict(args) -> int:
    import numpy as np

    from bayescal.io.files import write_text_atomic
    from bayescal.posterior.calibration import Calibration
    from bayescal.prediction.readings import predict

    cal = Calibration.load(args.posterior)
    setting = _setting(args, cal)
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


def _cmd_invert(args) -> int:
    import numpy as np

    from bayescal.errors import SpecError
    from bayescal.io.files import check_output_dir, write_text_atomic
    from bayescal.posterior.calibration import Calibration
    from bayescal.prediction.images import invert_image, read_image, write_radiance_maps
    from bayescal.prediction.invert import invert

    cal = Calibration.load(args.posterior)
    setting = _setting(args, cal)
    if args.maps is not None:
        return _invert_with_maps(args, cal, setting)
    if (args.image is None) == (args.dn is None):
        raise SpecError("give an IMAGE or --dn values (one of them)")
    if args.dn is not None:
        if not args.channel:
            raise SpecError("--dn needs --channel")
        res = invert(cal, np.asarray(args.dn), args.channel, setting, n_avg=args.n_avg, seed=args.seed)
        table = res.to_frame()
        print(res.describe(cal.stimulus) + ":")
        print(table.to_string(index=False, float_format="%.6g"))
        if args.out:
            write_text_atomic(args.out, table.to_csv(index=False, float_format="%.10g"))
        return 0
    if not args.out:
        raise SpecError("inverting an image needs --out DIR")
    check_output_dir(args.out)
    from bayescal.cli.progress import progress_bar

    image = read_image(args.image)
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


def _invert_with_maps(args, cal, setting) -> int:
    """``invert --maps``: per-pixel correction, then the channel's inversion, with every uncertainty."""
    import numpy as np

    from bayescal.errors import SpecError
    from bayescal.io.files import check_output_dir, staged_directory
    from bayescal.maps.apply import apply_maps
    from bayescal.maps.store import read_maps
    from bayescal.prediction.images import read_image

    if args.image is None or not args.out:
        raise SpecError("--maps corrects an IMAGE: give the image and --out DIR")
    if args.exposure_s is None:
        raise SpecError("--maps needs the image's --exposure-s (the dark current scales with it)")
    check_output_dir(args.out)
    maps = read_maps(args.maps)
    image = read_image(args.image)
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
    print(f"wrote {args.out}/radiance.nc")
    return 0


def _cmd_maps(args) -> int:
    from bayescal.cli.progress import progress_bar, stage_reporter
    from bayescal.io.files import check_output_dir
    from bayescal.maps.build import build_maps
    from bayescal.maps.metadata import channel_attrs
    from bayescal.maps.model import DEFECT_CODES
    from bayescal.maps.stacks import load_manifest
    from bayescal.maps.store import make_maps, read_maps, write_maps

    check_output_dir(args.out)
    stage = stage_reporter(args.quiet)
    manifest = load_manifest(args.stacks)
    client = None
    if args.scheduler:
        from distributed import Client

        client = Client(args.scheduler)
        stage(f"using the dask scheduler at {args.scheduler}")
    try:
        h, w = manifest.shape
        stage(
            f"{len(manifest.stacks)} stacks of {h} x {w} pixels ({manifest.bytes / 1e9:.2f} GB); fitting the population"
        )

        def population(ds) -> None:
            for channel in ds.attrs["channels"]:
                a = channel_attrs(ds, channel)
                spread = ", ".join(f"{n} {a[f'spread_{n}']:.4g} +- {a[f'spread_{n}_se']:.2g}" for n in a["parameters"])
                stage(f"channel {channel}: spreads {spread}; defect fraction {a['population_weights'][1]:.2e}")
            stage("writing the maps")

        kw = dict(
            fit_pixels=args.fit_pixels,
            rows_per_chunk=args.rows_per_chunk,
            calibration=args.calibration,
            cfa=args.cfa,
            channel=args.channel,
        )
        with progress_bar(1, "row blocks", quiet=args.quiet) as tick:
            advance = tick if tick is None else (lambda done, total: tick(done, total))

            if args.netcdf:
                ds = build_maps(manifest, **kw)
                population(ds)
                write_maps(ds, args.out, netcdf=True, progress=advance)
                maps = read_maps(args.out)
            else:
                maps = make_maps(manifest, args.out, **kw, progress=advance, processes=True, stage=population)
    finally:
        if client is not None:
            client.close()
    if args.report:
        from bayescal.maps.report import maps_report

        stage("writing the report")
        maps_report(maps, args.out)
    defect = maps["defect"].to_numpy()
    counts = {name: int((defect == code).sum()) for code, name in DEFECT_CODES.items() if code}
    spreads = "; ".join(
        f"{c}: PRNU {channel_attrs(maps, c)['spread_relative_gain']:.3%}, "
        f"offset spread {channel_attrs(maps, c)['spread_offset_dn']:.3g} DN"
        for c in maps.attrs["channels"]
    )
    print(
        f"maps of {defect.size} pixels written to {args.out}/: {spreads}; defects: "
        + ", ".join(f"{v} {k}" for k, v in counts.items())
    )
    return 0


def _cmd_plan(args) -> int:
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


def _cmd_characterize(args) -> int:
    from bayescal.characterization.emva1288 import characterize, plot_curves
    from bayescal.cli.progress import stage_reporter
    from bayescal.io.emva import load_steps
    from bayescal.io.files import check_output_dir, staged_directory, write_json_atomic

    out = check_output_dir(args.out)
    stage = stage_reporter()
    stage(f"reading {args.input} (image pairs and stacks are reduced streaming)")
    steps = load_steps(args.input)
    stage("standard method and posteriors")
    res = characterize(steps, seed=args.seed)
    with staged_directory(out, kind="characterization") as stage:
        res.table.to_csv(stage("characterization.csv"), index=False, float_format="%.8g")
        write_json_atomic(stage("characterization.json"), res.to_dict())
        res.curves.to_csv(stage("curves.csv"), index=False, float_format="%.8g")
        plot_curves(res, stage("photon_transfer.png"))
    print(f"EMVA 1288 characterisation of {args.input} (standard point estimate | posterior median [95 %]):")
    print(res.table.to_string(index=False, float_format="%.5g"))
    verdict = {True: "compatible", False: "NOT compatible", None: "not determined (one dark exposure time)"}[
        res.dark_current_compatible
    ]
    print(f"dark current from the mean and from the variance: {verdict} (95 % interval of their difference)")
    print(f"wrote {out}/: " + ", ".join(sorted(p.name for p in out.iterdir() if not p.name.startswith("."))))
    if res.problems:
        print("CHARACTERISATION IMPLAUSIBLE:\n  " + "\n  ".join(res.problems), file=sys.stderr)
        return 3
    return 0


def _cmd_select(args) -> int:
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
        print(compare_pooling(fleet, spec, fits, seed=args.seed).to_string(float_format="%.2f"))
        return 0
    table, spec = load_table(args.data), load_spec(args.model)
    off = tuple(x for x in args.without.split(",") if x)
    specs = order_candidates(spec, tuple(int(o) for o in args.orders), off)
    from bayescal.cli.progress import stage_reporter

    stage_reporter()(f"fitting {len(specs)} candidate models ({args.backend}) for PSIS-LOO")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FitFailedWarning)
        cmp = compare_specs(table, specs, backend=args.backend, seed=args.seed)
    print("PSIS-LOO (elpd_diff: this model minus the best; dse: its standard error):")
    print(cmp.to_string(float_format="%.2f"))
    best = cmp.index[0]
    print(f"best: {best}" + ("" if cmp.iloc[0]["fit_ok"] else " (its fit FAILED its diagnostics)"))
    ft = f_test_orders(table, spec, max_order=max(int(o) for o in args.orders))
    if len(ft):
        print("\nleast-squares F-test per channel at the reference setting (baseline):")
        print(ft.to_string(index=False, float_format="%.4g"))
    return 0


def _cmd_scene(args) -> int:
    from bayescal.io.files import write_json_atomic
    from bayescal.posterior.calibration import Calibration
    from bayescal.prediction.images import read_image
    from bayescal.prediction.scene import choose_for_scene

    cals = {str(p): Calibration.load(p) for p in args.posteriors}
    full = args.full or max(cals, key=lambda n: cals[n].coef.shape[-1])
    setting = _setting(args, cals[full])
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


def _cmd_sbc(args) -> int:
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


def _cmd_report(args) -> int:
    from bayescal.report.html import write_report

    fit_dir = Path(args.fit_dir)
    if not (fit_dir / "summary.json").exists():
        from bayescal.errors import SpecError

        raise SpecError(f"{fit_dir} has no summary.json; expected a directory written by `bayescal fit`")
    if not (fit_dir / "posterior.nc").exists():
        from bayescal.errors import SpecError

        raise SpecError(f"{fit_dir} holds a least-squares fit (no posterior.nc); a report needs a Bayesian backend")
    from bayescal.cli.progress import stage_reporter

    stage_reporter()("drawing the report's figures and tables")
    path = write_report(fit_dir, args.out, seed=args.seed)
    print(f"wrote {path} (+ {path.with_suffix('.json').name}, {path.with_suffix('.md').name})")
    return 0


def _cmd_fit(args) -> int:
    from bayescal import load_spec
    from bayescal.io.files import check_output_dir
    from bayescal.model import kinds

    check_output_dir(args.out)
    spec = load_spec(args.model)
    table = kinds.load_table(spec, args.data)  # the table of the spec's kind (a camera's, a film's)
    return _run_fit(table, spec, args.backend, args.seed, Path(args.out), args.quiet, report=args.report)


def _run_fit(
    table, spec, backend, seed, out: Path, quiet: bool, report: bool = False, measurements: bool = False
) -> int:
    import warnings

    from bayescal import FitFailedWarning, fit
    from bayescal.cli.progress import progress_bar, stage_reporter

    inf = spec.inference
    if backend == "emcee":
        total, desc = inf.emcee_burn + inf.emcee_steps, "emcee (ensemble steps)"
    else:
        total, desc = inf.warmup + inf.draws, f"{backend} ({inf.chains} chains)"
    sampling = backend in ("nuts", "blackjax", "emcee")
    with progress_bar(total, desc, quiet or not sampling) as tick:  # draws on a terminal only
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", FitFailedWarning)  # reported below, loudly
            result = fit(table, spec, backend, seed=seed, progress=tick, stage=stage_reporter(quiet))
    result.save(out, measurements=measurements)
    print(result.summary_text())
    if report and result.posterior is not None:
        from bayescal.report.html import write_report

        write_report(out, seed=seed)
    print(f"\nwrote {out}/: " + ", ".join(sorted(p.name for p in out.iterdir() if not p.name.startswith("."))))
    if not result.ok:
        bar = "!" * 72
        print(f"\n{bar}\nFIT FAILED: {result.diagnostics.verdict}\nDo not use these numbers.\n{bar}", file=sys.stderr)
        return 3
    return 0


def _cmd_simulate(args) -> int:
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


def _cmd_fleet(args) -> int:
    from bayescal.cli.progress import progress_bar, stage_reporter
    from bayescal.fleet import compare_pooling, fit_fleet, load_fleet_table
    from bayescal.io.files import check_output_dir, write_text_atomic
    from bayescal.model.spec import load_spec

    check_output_dir(args.out)
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
    print(f"wrote {args.out}/: fleet.nc, summary.csv, hyperparameters.csv, units.csv, summary.json, cameras/")
    if not result.ok:
        print("bayescal: FLEET FIT FAILED: " + "; ".join(result.problems), file=sys.stderr)
        return 3
    return 0


def _cmd_fleet_query(args) -> int:
    import numpy as np

    from bayescal.fleet import FleetFit
    from bayescal.fleet.export import write_calibration

    fleet = FleetFit.load(args.fleet)
    camera = None if args.new_camera else args.camera
    values = fleet.at(camera, args.date, seed=args.seed)
    label = camera or "a new camera of the type"
    print(f"{label} at {args.date or 'its last campaign'}:")
    for k, kind in enumerate(fleet.kinds):
        for c, ch in enumerate(fleet.channels):
            v = np.exp(values[:, k, c]) if kind == "log_gain" else values[:, k, c]
            lo, med, hi = np.quantile(v, [0.025, 0.5, 0.975])
            name = "gain A1" if kind == "log_gain" else ("offset A0" if kind == "offset" else kind)
            print(f"  {ch} {name}: {med:.6g} [{lo:.6g}, {hi:.6g}]")
    if args.drift_percent is not None:
        if camera is None or args.date is None:
            from bayescal.errors import SpecError

            raise SpecError("--drift-percent needs --camera and --date")
        p = fleet.drift_probability(camera, args.date, args.drift_percent, seed=args.seed)
        print(f"P(gain drifted by more than {args.drift_percent:g} % by {args.date}) = {p:.3f}")
        when = fleet.recalibration_date(camera, args.drift_percent, args.probability)
        print(
            f"recalibrate by {when.date().isoformat()} (risk {args.probability:g} of a {args.drift_percent:g} % drift)"
            if when is not None
            else f"the risk stays below {args.probability:g} for 10 years"
        )
    if args.calibration:
        write_calibration(args.fleet, args.calibration, camera, args.date, seed=args.seed)
        print(f"wrote {args.calibration}/ (predict, invert and plan read it)")
    return 0


def _cmd_fleet_simulate(args) -> int:
    import dataclasses
    import tomllib

    from bayescal.errors import SpecError
    from bayescal.io.files import read_text, write_text_atomic
    from bayescal.validation.fleet import FleetDesign, simulate_fleet

    text = read_text(args.design, SpecError, "fleet design (TOML)")
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise SpecError(f"{args.design} is not valid TOML: {exc}") from None
    fields = {f.name: f for f in dataclasses.fields(FleetDesign) if f.name != "camera"}
    for key, value in raw.items():
        if key not in fields:
            raise SpecError(f"{args.design}: unknown key '{key}'; expected one of {', '.join(fields)}")
        if key == "absent":
            raw[key] = tuple(tuple(v) for v in value)
        elif isinstance(value, list):
            raw[key] = tuple(value)
    try:
        design = FleetDesign(**raw)
    except TypeError as exc:
        raise SpecError(f"{args.design}: {exc}") from None
    if design.n_cameras < 2:
        raise SpecError(f"{args.design}: n_cameras = {design.n_cameras}; a fleet needs at least 2")
    table, truth = simulate_fleet(design, seed=args.seed)
    write_text_atomic(args.out, table.to_csv(index=False, float_format="%.10g"))
    if args.truth:
        write_text_atomic(args.truth, truth.to_csv(index=False, float_format="%.10g"))
    print(f"wrote {len(table)} rows ({design.n_cameras} cameras, {len(design.campaigns)} campaigns) to {args.out}")
    return 0


def _cmd_demo(args) -> int:
    from bayescal import load_design, load_spec, simulate
    from bayescal.io.files import check_output_dir
    from bayescal.io.resources import models_dir

    design = load_design(models_dir() / "seed000_design.toml")
    spec = load_spec(design.spec)
    out = check_output_dir(args.out)
    sim = simulate(spec, design, seed=args.seed)
    print(f"Simulated the seed 000 Bayer CCD: {len(sim.table)} rows, sphere scale error {sim.sphere_scale - 1:+.2%}")
    print(
        "True gains (DN per W m^-2 sr^-1 at gain 1, 1/250 s): "
        + ", ".join(f"{c} {v[0]:g}" for c, v in sim.truth.response.items())
    )
    return _run_fit(sim.table, spec, args.backend, args.seed, out, args.quiet, report=True, measurements=True)


if __name__ == "__main__":
    raise SystemExit(main())
