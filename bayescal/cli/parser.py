"""The ``bayescal`` command's arguments: every verb, its options and their help; the argument types."""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable
from pathlib import Path

from bayescal.cli.calibrate import cmd_demo, cmd_fit, cmd_report, cmd_sbc, cmd_select, cmd_simulate
from bayescal.cli.characterize import cmd_characterize
from bayescal.cli.completion import cmd_completion
from bayescal.cli.design import cmd_design
from bayescal.cli.examples import cmd_examples
from bayescal.cli.fleet import cmd_fleet, cmd_fleet_query, cmd_fleet_simulate
from bayescal.cli.maps import cmd_maps
from bayescal.cli.products import cmd_invert, cmd_plan, cmd_predict, cmd_scene
from bayescal.errors import SpecError
from bayescal.inference import registry as backends
from bayescal.io import checks  # light: numpy and pandas are imported on use
from bayescal.io.cluster import scheduler_address
from bayescal.io.limits import check_value

SEED_HELP = "seed of every random number (default 0): the same seed gives the same result"


def build() -> argparse.ArgumentParser:
    """The argument parser of every verb (each calls its ``cmd_*`` function with the parsed arguments)."""
    from bayescal._version import describe

    p = argparse.ArgumentParser(
        prog="bayescal",
        description="Bayesian radiometric calibration of imaging sensors",
        epilog="exit codes: 0 ok, 2 bad input (names the file, row, column or key), "
        "3 the fit failed its diagnostics or does not fit its data, 130 interrupted",
    )
    p.add_argument("--version", action="version", version=f"bayescal {describe()}")
    sub = p.add_subparsers(required=True, metavar="COMMAND")
    for verb in VERBS:
        verb(sub)
    for name, verb_parser in sub.choices.items():
        verb_parser.set_defaults(verb=name)
        verb_parser.add_argument(
            "--json",
            action="store_true",
            help="print one JSON document on stdout for a script: the results, the exit status, the output "
            "folders and the JSON files written there (the text goes to stderr)",
        )
    sub.choices["completion"].set_defaults(parser=p)  # the script completes this very command line
    return p


def _fit(sub) -> None:
    """The arguments of ``bayescal fit``."""
    f = sub.add_parser("fit", help="fit a calibration model to a measurement table")
    f.add_argument("data", help="CSV or Parquet measurement table")
    f.add_argument("--model", required=True, help="model spec (TOML), or a shipped one's name: seed000, seed002, ...")
    f.add_argument(
        "--backend",
        default="nuts",
        choices=backends.names(baseline=True),
        help="inference backend (default nuts)",
    )
    folder_output(f, "--out", required=True, help="output directory")
    f.add_argument("--seed", type=seed, default=0, help=SEED_HELP)
    f.add_argument("--quiet", action="store_true", help="no progress bar")
    f.add_argument("--report", action="store_true", help="also write OUT/report.html (+ .json, .md)")
    f.add_argument(
        "--no-diagnose",
        dest="diagnose",
        action="store_false",
        help="when the fit does not describe its data, fail (exit 3) without trying the library's components",
    )
    f.set_defaults(func=cmd_fit)


def _predict(sub) -> None:
    """The arguments of ``bayescal predict``."""
    pr = sub.add_parser("predict", help="posterior predictive DN at a (possibly unmeasured) setting")
    pr.add_argument("posterior", help="fit directory or its posterior.nc")
    setting_args(pr, required=True)
    pr.add_argument("--radiance", "--stimulus", dest="stimulus", type=stimuli, help="stimulus values (comma list)")
    pr.add_argument("--channel", action="append", help="channel(s) (default all)")
    pr.add_argument("--n-avg", type=positive, default=1.0, help="pixels x frames averaged per reading (default 1)")
    file_output(pr, "--out", help="also write the table as CSV")
    pr.add_argument("--seed", type=seed, default=0, help=SEED_HELP)
    pr.set_defaults(func=cmd_predict)


def _invert(sub) -> None:
    """The arguments of ``bayescal invert``."""
    iv = sub.add_parser("invert", help="radiance posterior of DN values or an image (median and 95 %% interval)")
    iv.add_argument("posterior", help="fit directory or its posterior.nc")
    iv.add_argument(
        "image",
        nargs="*",
        help="TIFF, PNG or NPY image; several (or a quoted glob) invert a survey: one folder per frame under --out",
    )
    iv.add_argument("--dn", type=floats, help="DN values instead of an image (comma list)")
    setting_args(iv, required=False)
    image_args(iv, channel_help="channel of a single-channel image or of --dn values")
    file_output(iv, "--out", help="output directory (image) or CSV (--dn)", when=lambda a: a.dn is not None)
    iv.add_argument(
        "--maps",
        help="per-pixel maps directory (from `bayescal maps`): correct every pixel before inverting",
    )
    iv.add_argument(
        "--scheduler",
        type=address,
        help="dask.distributed scheduler address (tcp://host:8786): invert the frames on its workers, "
        "which must see the same files",
    )
    iv.add_argument("--seed", type=seed, default=0, help=SEED_HELP)
    iv.set_defaults(func=cmd_invert)


def _maps(sub) -> None:
    """The arguments of ``bayescal maps``."""
    mp = sub.add_parser(
        "maps", help="per-pixel relative gain, offset, dark current and defect maps from flat and dark frame stacks"
    )
    mp.add_argument(
        "stacks",
        help="directory with conditions.csv and one .npy/.tif/.fits/.raw file per stack, or an EMVA 1288 image set: "
        "its descriptor (.txt, images beside it; exposure or illumination sweep) or cropped arrays (.npz)",
    )
    folder_output(mp, "--out", required=True, help="output directory (holds maps.zarr, or maps.nc with --netcdf)")
    mp.add_argument("--calibration", help="channel-level fit directory the maps are relative to (provenance)")
    mp.add_argument("--netcdf", action="store_true", help="write NetCDF (maps.nc) instead of zarr")
    mp.add_argument(
        "--cfa", help="Bayer pattern of raw mosaic frames (RGGB, BGGR, GRBG, GBRG): one population per colour"
    )
    mp.add_argument("--channel", default="M", help="channel name of a monochrome sensor (default M)")
    mp.add_argument(
        "--fit-pixels", type=positive_int, default=262_144, help="pixels used to fit the population (default 262144)"
    )
    mp.add_argument(
        "--rows-per-chunk",
        type=positive_int,
        default=None,
        help="rows per block and store chunk (default: ~2^20 pixels)",
    )
    mp.add_argument(
        "--scheduler",
        type=address,
        help="address of a dask.distributed scheduler (e.g. tcp://host:8786); default: this machine",
    )
    mp.add_argument("--report", action="store_true", help="also write OUT/maps_report.html (+ .md)")
    mp.add_argument("--quiet", action="store_true", help="no progress bar or stage messages")
    mp.set_defaults(func=cmd_maps)


def _plan(sub) -> None:
    """The arguments of ``bayescal plan``."""
    pl = sub.add_parser("plan", help="choose gain/exposure/TDI so the next frame lands in a DN window")
    pl.add_argument("posterior", help="fit directory or its posterior.nc")
    pl.add_argument("--channel", required=True, help="channel the reading (or the scene) is of")
    pl.add_argument("--dn", type=non_negative, help="reading at the current setting")
    pl.add_argument("--current", type=setting_values, help="current setting: EXPOSURE_S[,GAIN[,TDI[,TEMPERATURE_C]]]")
    pl.add_argument(
        "--radiance",
        "--stimulus",
        dest="stimulus",
        type=limited("stimulus", positive=True),
        help="known scene stimulus instead",
    )
    pl.add_argument(
        "--exposures", type=limited_list("exposure_s"), required=True, help="allowed exposures, s (comma list)"
    )
    pl.add_argument("--gains", type=limited_list("gain"), default=[1.0], help="allowed gains (comma list)")
    pl.add_argument(
        "--tdi-stages", type=limited_list("tdi_stages"), default=[1.0], help="allowed TDI stages (comma list)"
    )
    pl.add_argument("--window", type=window, help="target DN window LOW,HIGH (default 1080,1920 scaled to bits)")
    pl.add_argument("--n-avg", type=positive, default=1.0, help="pixels x frames averaged per reading (default 1)")
    pl.add_argument("--top", type=positive_int, default=5, help="rows to print")
    pl.add_argument("--seed", type=seed, default=0, help=SEED_HELP)
    pl.set_defaults(func=cmd_plan)


def _report(sub) -> None:
    """The arguments of ``bayescal report``."""
    rp = sub.add_parser("report", help="HTML report (figures embedded) + report.json + report.md of a fit")
    rp.add_argument("fit_dir", help="directory written by `bayescal fit`")
    file_output(
        rp,
        "--out",
        help="HTML path (default FIT_DIR/report.html); .json and .md go beside it",
        paths=lambda v: [v, str(Path(v).with_suffix(".json")), str(Path(v).with_suffix(".md"))],
    )
    rp.add_argument("--seed", type=seed, default=0, help=SEED_HELP)
    rp.add_argument(
        "--figures",
        action="store_true",
        help="also write each figure as a PNG beside the HTML (report-response.png, report-residuals.png, ...)",
    )
    rp.set_defaults(func=cmd_report)


def _characterize(sub) -> None:
    """The arguments of ``bayescal characterize``."""
    ch = sub.add_parser("characterize", help="EMVA 1288: standard estimates beside posteriors (K, R, QE, dark, ...)")
    ch.add_argument("input", help="EMVA 1288 descriptor (.txt) with its images, crop128.npz, or a reduced steps.csv")
    folder_output(ch, "--out", required=True, help="output directory")
    ch.add_argument("--seed", type=seed, default=0, help=SEED_HELP)
    ch.set_defaults(func=cmd_characterize)


def _select(sub) -> None:
    """The arguments of ``bayescal select``."""
    se = sub.add_parser(
        "select",
        help="compare polynomial orders, components and where the nonlinearity arises (a table with a gain "
        "sweep) by PSIS-LOO (F-test beside it)",
    )
    se.add_argument("data", help="CSV or Parquet measurement table")
    se.add_argument("--model", required=True, help="base model spec (TOML)")
    se.add_argument("--orders", type=orders, default=[1, 2, 3], help="response orders 1-4 to compare (default 1,2,3)")
    se.add_argument("--without", default="", help="components to try switching off: level_errors,excess,exposure_slope")
    se.add_argument("--backend", default="laplace", choices=backends.names(), help="backend (default laplace)")
    se.add_argument("--seed", type=seed, default=0, help=SEED_HELP)
    se.add_argument(
        "--pooling",
        action="store_true",
        help="a fleet table (camera column): compare no / partial / complete pooling by PSIS-LOO over units",
    )
    se.set_defaults(func=cmd_select)


def _scene(sub) -> None:
    """The arguments of ``bayescal scene``."""
    sc = sub.add_parser("scene", help="cheapest calibration whose inversion of an image matches the full model's")
    sc.add_argument("image", help="TIFF, PNG or NPY image (the scene)")
    sc.add_argument("posteriors", nargs="+", help="fit directories (or posterior.nc) of the candidate models")
    setting_args(sc, required=False)
    image_args(sc, channel_help="channel of a single-channel image")
    sc.add_argument("--full", help="the reference candidate (default: the highest response order)")
    sc.add_argument("--tol", type=positive, default=0.1, help="allowed deviation in posterior sds (default 0.1)")
    file_output(sc, "--out", help="write the comparison as JSON here")
    sc.add_argument("--seed", type=seed, default=0, help=SEED_HELP)
    sc.set_defaults(func=cmd_scene)


def _sbc(sub) -> None:
    """The arguments of ``bayescal sbc``."""
    sb = sub.add_parser("sbc", help="simulation-based calibration of a model over a table's design (rank tests)")
    sb.add_argument("data", help="CSV or Parquet table: its design (settings, levels) is used, not its readings")
    sb.add_argument("--model", required=True, help="model spec (TOML); its priors generate the datasets")
    sb.add_argument("--sims", type=positive_int, default=200, help="simulated datasets (default 200)")
    sb.add_argument("--backend", default="nuts", choices=backends.names(), help="backend of the refits (default nuts)")
    file_output(
        sb,
        "--out",
        required=True,
        help="output stem: writes STEM.csv, STEM.md, STEM.png",
        paths=lambda v: [v + ".csv", v + ".md", v + ".png"],
    )
    sb.add_argument("--seed", type=seed, default=0, help=SEED_HELP)
    sb.set_defaults(func=cmd_sbc)


def _simulate(sub) -> None:
    """The arguments of ``bayescal simulate``."""
    s = sub.add_parser("simulate", help="simulate a measurement table from a design with a [truth] table")
    s.add_argument("--design", required=True, help="design TOML (names its spec, holds [truth])")
    s.add_argument("--model", help="model spec (default: the design's)")
    file_output(s, "--out", required=True, help="CSV to write")
    s.add_argument("--seed", type=seed, default=0, help=SEED_HELP)
    s.set_defaults(func=cmd_simulate)


def _design(sub) -> None:
    """The arguments of ``bayescal design``."""
    d = sub.add_parser(
        "design",
        help="which levels, settings and darks to measure (and how often) to reach the intervals wanted",
        description="Choose a campaign from a protocol's candidate grid (its illuminated settings at every "
        "level, its dark settings): the fewest rows whose expected posterior widths (Laplace/Fisher) reach the "
        "protocol's (times --goal-scale, or --goal), or the narrowest within --budget-rows; with --after FIT, "
        "the next block to measure.  Exit 3 when goals asked for (none, --goal or --goal-scale) cannot be met.",
    )
    d.add_argument("protocol", help="the protocol's design TOML (with a [truth] nominal camera), or a shipped name")
    d.add_argument("--model", help="model spec (default: the protocol's)")
    d.add_argument("--after", metavar="FIT", help="a fit of the campaign so far: propose the next block")
    d.add_argument("--block-rows", type=positive, help="with --after: the next block's rows (default: the protocol's)")
    d.add_argument("--goal-scale", type=positive, help="goals are the protocol's widths times this (default 1)")
    d.add_argument(
        "--goal",
        type=goal,
        action="append",
        metavar="TARGET=SD",
        help="the posterior sd wanted for one target (e.g. 'A2[R]=0.0004'); repeatable",
    )
    d.add_argument("--budget-rows", type=positive, help="the most rows to measure: the narrowest design within it")
    d.add_argument("--setting-cost", type=non_negative, default=0.0, help="rows a change of setting costs (default 0)")
    d.add_argument(
        "--draws", type=positive_int, default=1, help="posterior points the widths are averaged over (default 1)"
    )
    d.add_argument(
        "--no-checks",
        dest="keep_checks",
        action="store_false",
        help="drop the rows the model's checks need (the summary says what is given up)",
    )
    folder_output(d, "--out", help="output directory: design.toml, groups.csv, widths.csv")
    d.add_argument("--seed", type=seed, default=0, help=SEED_HELP)
    d.add_argument("--quiet", action="store_true", help="no stage messages")
    d.set_defaults(func=cmd_design)


def goal(value: str) -> tuple[str, float]:
    """``TARGET=SD``: a target's name and the posterior standard deviation wanted."""
    name, sep, number = value.rpartition("=")
    if not sep or not name:
        raise argparse.ArgumentTypeError(f"expected TARGET=SD (e.g. 'A2[R]=0.0004'), got {value!r}")
    return name.strip(), positive(number)


def _fleet(sub) -> None:
    """The arguments of ``bayescal fleet``."""
    fl = sub.add_parser("fleet", help="calibrate a fleet of cameras over campaigns: each alone, then the hierarchy")
    fl.add_argument(
        "data", help="CSV or Parquet measurement table with 'camera' and optional 'campaign' (date) columns"
    )
    fl.add_argument("--model", required=True, help="model spec (TOML) of one camera, with an optional [fleet] section")
    folder_output(fl, "--out", required=True, help="output directory (fleet posterior, summaries, per-camera fits)")
    fl.add_argument(
        "--backend", default="laplace", choices=("laplace", "nuts"), help="stage one's backend (default laplace)"
    )
    fl.add_argument("--pooling", choices=("partial", "none", "complete"), help="override the spec's [fleet] pooling")
    fl.add_argument(
        "--compare-pooling", action="store_true", help="also compare no/partial/complete pooling by PSIS-LOO"
    )
    fl.add_argument("--report", action="store_true", help="also write OUT/fleet_report.html")
    fl.add_argument("--seed", type=seed, default=0, help=SEED_HELP)
    fl.add_argument("--quiet", action="store_true", help="no progress bar")
    fl.set_defaults(func=cmd_fleet)


def _fleet_query(sub) -> None:
    """The arguments of ``bayescal fleet-query``."""
    fq = sub.add_parser("fleet-query", help="a fleet camera at a date, its drift probability, its calibration")
    fq.add_argument("fleet", help="directory written by `bayescal fleet`")
    who = fq.add_mutually_exclusive_group(required=True)
    who.add_argument("--camera", help="camera name (as in the table's camera column)")
    who.add_argument("--new-camera", action="store_true", help="a camera of the type never measured")
    fq.add_argument("--date", type=iso_date, help="ISO date (default: the camera's last campaign)")
    fq.add_argument(
        "--drift-percent", type=positive, help="P(|gain change since the last campaign| > this %%) at --date"
    )
    fq.add_argument(
        "--probability", type=probability, default=0.05, help="risk for the recalibration date (default 0.05)"
    )
    folder_output(fq, "--calibration", help="write this fit directory (for predict, invert, plan)")
    fq.add_argument("--seed", type=seed, default=0, help=SEED_HELP)
    fq.set_defaults(func=cmd_fleet_query)


def _fleet_simulate(sub) -> None:
    """The arguments of ``bayescal fleet-simulate``."""
    fs = sub.add_parser("fleet-simulate", help="simulate a fleet's campaigns (independent simulator) from a design")
    fs.add_argument("design", help="fleet design TOML, e.g. models/fleet_seed000_design.toml")
    file_output(fs, "--out", required=True, help="measurement table CSV to write")
    file_output(fs, "--truth", help="also write the true coefficients per unit to this CSV")
    fs.add_argument("--seed", type=seed, default=0, help=SEED_HELP)
    fs.set_defaults(func=cmd_fleet_simulate)


def _examples(sub) -> None:
    """The arguments of ``bayescal examples``."""
    ex = sub.add_parser("examples", help="list the shipped specs, designs and data; copy one out to edit it")
    ex.add_argument("--copy", metavar="NAME", help="copy this example (a design with its spec) to --to")
    folder_output(ex, "--to", default=".", help="folder to copy into (default: this one)")
    ex.set_defaults(func=cmd_examples)


def _completion(sub) -> None:
    """The arguments of ``bayescal completion``."""
    c = sub.add_parser("completion", help='a shell completion script: eval "$(bayescal completion bash)"')
    c.add_argument("shell", choices=("bash",), help="the shell (zsh: bashcompinit reads the bash script)")
    c.set_defaults(func=cmd_completion)


def _demo(sub) -> None:
    """The arguments of ``bayescal demo``."""
    d = sub.add_parser("demo", help="simulate the seed 000 camera, fit it, compare with least squares")
    folder_output(d, "--out", default="demo-out", help="output directory (default demo-out)")
    d.add_argument("--seed", type=seed, default=0, help=SEED_HELP)
    d.add_argument("--backend", default="nuts", choices=backends.names(), help="backend (default nuts)")
    d.add_argument("--quiet", action="store_true", help="no progress bar")
    d.set_defaults(func=cmd_demo)


VERBS = (
    _fit,
    _predict,
    _invert,
    _maps,
    _plan,
    _report,
    _characterize,
    _select,
    _scene,
    _sbc,
    _design,
    _simulate,
    _fleet,
    _fleet_query,
    _fleet_simulate,
    _examples,
    _completion,
    _demo,
)  # in the order of the command's help


def finite(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got '{text}'") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"expected a finite number, got '{text}'")
    return value


def _checked(check):
    """An argument type from a check of :mod:`bayescal.io.checks` (its message becomes argparse's)."""

    def convert(text: str):
        try:
            return check(text)
        except SpecError as exc:  # "value = '0'; expected ..." reads "argument --n-avg: '0'; expected ..."
            message = str(exc).removeprefix("value = ").removeprefix("value ")
            raise argparse.ArgumentTypeError(message) from None

    return convert


positive = _checked(lambda t: checks.number(t, "value", positive=True))
non_negative = _checked(lambda t: checks.number(t, "value", minimum=0.0))
positive_int = _checked(lambda t: checks.count(t, "value"))
seed = _checked(lambda t: checks.count(t, "value", minimum=0))
probability = _checked(lambda t: checks.probability(t, "value"))
iso_date = _checked(lambda t: checks.date(t, "value").date().isoformat())
address = _checked(lambda t: scheduler_address(t, "value"))


def window(text: str) -> list[float]:
    values = floats(text)
    if len(values) != 2 or not 0 <= values[0] < values[1]:
        raise argparse.ArgumentTypeError(f"expected LOW,HIGH with 0 <= LOW < HIGH (DN), got '{text}'")
    return values


def setting_values(text: str) -> list[float]:
    values = floats(text)
    if not 1 <= len(values) <= 4:
        raise argparse.ArgumentTypeError(
            f"expected EXPOSURE_S[,GAIN[,TDI[,TEMPERATURE_C]]] (1 to 4 numbers), got {len(values)}: '{text}'"
        )
    for value, name in zip(values, ("exposure_s", "gain", "tdi_stages", "temperature_c"), strict=False):
        limited(name)(str(value))
    return values


def limited(name: str, positive: bool = False) -> Callable[[str], float]:
    """An argument type: a number within the physical limit ``name`` (:data:`bayescal.io.limits.LIMITS`),
    above 0 as well with ``positive``."""

    def convert(text: str) -> float:
        value = _checked(lambda t: check_value(t, name, "value"))(text)
        if positive and not value > 0:
            raise argparse.ArgumentTypeError(f"'{text}'; expected a number above 0")
        return value

    return convert


def limited_list(name: str) -> Callable[[str], list[float]]:
    """An argument type: a comma list of numbers, each within the physical limit ``name``."""

    def convert(text: str) -> list[float]:
        return [limited(name)(v.strip()) for v in text.split(",") if v.strip()] or floats(text)

    return convert


def stimuli(text: str) -> list[float]:
    """Stimulus values (radiance or irradiance, comma list): each within its physical limit (>= 0)."""
    return limited_list("stimulus")(text)


def orders(text: str) -> list[int]:
    out = []
    for v in text.split(","):
        v = v.strip()
        if v not in {"1", "2", "3", "4"}:
            raise argparse.ArgumentTypeError(f"expected response orders among 1,2,3,4 (comma list), got '{v}'")
        out.append(int(v))
    return out


def floats(text: str) -> list[float]:
    try:
        values = [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers, got '{text}'") from None
    if not values or not all(math.isfinite(v) for v in values):
        raise argparse.ArgumentTypeError(f"expected comma-separated finite numbers, got '{text}'")
    return values


def setting_args(p: argparse.ArgumentParser, required: bool) -> None:
    p.add_argument("--exposure-s", type=limited("exposure_s"), required=required, help="exposure time, s")
    p.add_argument("--gain", type=limited("gain"), default=None, help="gain factor (default the reference gain)")
    p.add_argument("--tdi-stages", type=limited("tdi_stages"), default=None, help="TDI stages (default the reference)")
    p.add_argument(
        "--temperature-c",
        type=limited("temperature_c"),
        default=None,
        help="sensor temperature, degC (default reference)",
    )


def image_args(p, channel_help: str) -> None:
    """How an image's pixels map to channels, and how many readings each value averages."""
    p.add_argument("--cfa", help="Bayer pattern of a raw mosaic: RGGB, BGGR, GRBG, GBRG")
    p.add_argument("--channel", help=channel_help)
    p.add_argument("--channels", help="comma list naming the planes of an (H, W, C) image")
    p.add_argument("--n-avg", type=positive, default=1.0, help="pixels x frames averaged per value (default 1)")


#: what ``--force`` allows, in the help of every verb that writes single files
FORCE_HELP = "replace output files that bayescal did not write (by default it refuses and names them)"


def file_output(
    p: argparse.ArgumentParser,
    flag: str,
    *,
    help: str,
    required: bool = False,
    paths: Callable[[str], list[str]] = lambda value: [value],
    when: Callable[[argparse.Namespace], bool] = lambda args: True,
) -> None:
    """A file-valued output option: every file it names (``paths`` of its value, e.g. a report's ``.json``
    and ``.md`` beside its HTML) is checked before any work when ``when(args)`` holds (see
    :func:`output_files`); the verb gets ``--force`` to replace files bayescal did not write."""
    p.add_argument(flag, required=required, help=help)
    dest = flag.lstrip("-").replace("-", "_")
    p.set_defaults(file_outputs=(*(p.get_default("file_outputs") or ()), (dest, paths, when)))
    if p.get_default("force") is None:
        p.add_argument("--force", action="store_true", default=False, help=FORCE_HELP)


def folder_output(p: argparse.ArgumentParser, flag: str, *, help: str, **kwargs) -> None:
    """A folder-valued output option (``--out DIR``): its value is never taken for an input of the command."""
    p.add_argument(flag, help=help, **kwargs)
    dest = flag.lstrip("-").replace("-", "_")
    p.set_defaults(folder_outputs=(*(p.get_default("folder_outputs") or ()), dest))


def input_paths(args: argparse.Namespace) -> list[str]:
    """Every path the parsed command names that exists and is not one of its outputs: its inputs (a table,
    a spec, a design, a fit folder, images), which no output of the command may replace."""
    import os

    outputs = {dest for dest, _, _ in getattr(args, "file_outputs", ())} | set(getattr(args, "folder_outputs", ()))
    found = []
    for dest, value in vars(args).items():
        if dest in outputs or dest in ("func", "verb", "file_outputs", "folder_outputs"):
            continue
        for item in value if isinstance(value, list) else [value]:
            if isinstance(item, str) and item and os.path.lexists(item):
                found.append(item)
    return found


def output_files(args: argparse.Namespace) -> list[str]:
    """Every single file the parsed command will write (its file-valued outputs, expanded); two options
    naming one file are refused."""
    files: list[str] = []
    for dest, paths, when in getattr(args, "file_outputs", ()):
        value = getattr(args, dest)
        if value is not None and when(args):
            files += paths(value)
    seen: dict[str, str] = {}
    for f in files:
        key = str(Path(f).absolute())
        if key in seen:
            raise SpecError(f"two outputs of this command name the same file, {f}; give each its own name")
        seen[key] = f
    return files
