"""The ``maps`` verb: per-pixel maps from frame stacks."""

from __future__ import annotations

import contextlib
from pathlib import Path


def cmd_maps(args) -> int:
    from bayescal.cli.progress import stage_reporter
    from bayescal.io.outputs import check_output_dir
    from bayescal.maps.stacks import load_manifest

    check_output_dir(args.out, "maps")
    stage = stage_reporter(args.quiet)
    with _stack_directory(args, stage) as (directory, source):
        return _maps(args, stage, load_manifest(directory, source=source))


@contextlib.contextmanager
def _stack_directory(args, stage):
    """The stack directory to map: the argument itself, or an EMVA 1288 set written out as stacks.

    A descriptor (``.txt``) or cropped arrays (``.npz``) are converted into a
    hidden folder beside ``--out``, removed afterwards, also on an interrupt.
    """
    from bayescal.cli.progress import progress_bar
    from bayescal.errors import TableError
    from bayescal.io.outputs import scratch_directory
    from bayescal.maps.stacks import write_emva_stacks

    path = Path(args.stacks)
    if path.is_dir() or not path.exists():
        yield path, ""
        return
    if path.suffix.lower() not in (".txt", ".npz"):
        raise TableError(
            f"{path}: expected a stack directory (with conditions.csv), an EMVA 1288 descriptor (.txt) "
            "or the cropped arrays (.npz)"
        )
    with scratch_directory(args.out, "emva-stacks") as scratch:
        stage(f"writing the EMVA 1288 image set {path} as stacks")
        with progress_bar(1, "bright groups", quiet=args.quiet) as tick:
            write_emva_stacks(path, scratch, progress=tick)
        try:
            yield scratch, str(path.resolve())
        except TableError as exc:  # name the user's image set, not the stacks written from it
            raise TableError(_of_source(str(exc), scratch, path)) from None


def _of_source(message: str, scratch: Path, source: Path) -> str:
    """A message about the stacks written from ``source``, told in terms of ``source``."""
    import re

    where = re.escape(str(scratch))
    message = re.sub(where + r"/conditions\.csv row \d+", f"{source} (as stacks)", message)
    return re.sub(where + r"/?", f"{source} (as stacks): ", message)


def _maps(args, stage, manifest) -> int:
    from bayescal.cli.progress import progress_bar
    from bayescal.io.cluster import connect
    from bayescal.maps.build import build_maps
    from bayescal.maps.metadata import channel_attrs
    from bayescal.maps.model import DEFECT_CODES
    from bayescal.maps.store import make_maps, read_maps, write_maps

    with connect(args.scheduler) if args.scheduler else contextlib.nullcontext() as client:
        if client is not None:
            stage(f"using the dask scheduler at {args.scheduler}")
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
            advance = tick

            if args.netcdf:
                ds = build_maps(manifest, **kw)
                population(ds)
                write_maps(ds, args.out, netcdf=True, progress=advance)
                maps = read_maps(args.out)
            else:
                maps = make_maps(manifest, args.out, **kw, progress=advance, stage=population)
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
