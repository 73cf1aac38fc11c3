"""Many frames: invert a survey's images, one output folder per frame, here or on a Dask cluster.

Each frame is read, checked against the camera's bit depth, inverted with
:func:`bayescal.prediction.images.invert_image` and written to its own
radiance folder (``OUT/<frame name>/``, with its record).  The survey owns
``OUT`` as every verb owns its output folder: ``OUT`` is checked before the
first frame (missing, empty, or an earlier survey nobody changed), the frames
are staged beside it and put in place together with the survey's record, so
an interrupted or failed survey leaves the earlier one (or nothing) whole,
and a rerun replaces only bayescal's own survey.

The per-DN tables (:mod:`bayescal.prediction.tables`) are computed once,
before the first frame, for every value the camera can read, and kept beside
the calibration's posterior; each worker of a ``dask.distributed`` cluster
reads them from there, so a frame costs a read, a gather and a write.
"""

from __future__ import annotations

import dataclasses
import glob
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bayescal.errors import SpecError, TableError, optional
from bayescal.io.fit_folder import POSTERIOR

__all__ = ["FrameJob", "expand_frames", "frame_outputs", "invert_frames"]


@dataclass(frozen=True)
class FrameJob:
    """Everything one frame's inversion needs, picklable for a cluster's workers."""

    posterior: str
    image: str
    out: str
    exposure_s: float
    gain: float
    tdi_stages: float
    temperature_c: float | None
    cfa: str | None = None
    channel: str | None = None
    channels: tuple[str, ...] | None = None
    n_avg: float = 1.0
    seed: int = 0


def expand_frames(patterns: Sequence[str]) -> list[Path]:
    """The frames named by ``patterns`` (paths, or globs the shell did not expand), in order, once each."""
    frames: list[Path] = []
    for pattern in patterns:
        if glob.has_magic(pattern):
            matches = sorted(glob.glob(pattern))
            if not matches:
                raise FileNotFoundError(f"no image matches {pattern!r}")
            frames.extend(Path(m) for m in matches)
        else:
            frames.append(Path(pattern))
    return list(dict.fromkeys(frames))


def frame_outputs(frames: Sequence[Path], out: str | os.PathLike) -> list[Path]:
    """``OUT/<frame stem>`` per frame; two frames with one stem are refused (their outputs would collide)."""
    seen: dict[str, Path] = {}
    for frame in frames:
        if frame.stem in seen:
            raise SpecError(
                f"frames {seen[frame.stem]} and {frame} would both write {Path(out) / frame.stem}/: "
                "give frames with distinct names"
            )
        seen[frame.stem] = frame
    return [Path(out) / f.stem for f in frames]


_CALIBRATIONS: dict[tuple[str, int], object] = {}  # per process: a worker reads each calibration once


def _calibration(posterior: str):
    """The calibration at ``posterior``, read once per process (again if the folder was rewritten since)."""
    from bayescal.posterior.calibration import Calibration
    from bayescal.prediction.tables import restore_tables

    path = Path(posterior)
    key = (str(path.resolve()), (path / POSTERIOR if path.is_dir() else path).stat().st_mtime_ns)
    cal = _CALIBRATIONS.get(key)
    if cal is None:
        cal = _CALIBRATIONS[key] = Calibration.load(posterior)
        restore_tables(cal)
    return cal


def invert_frame(job: FrameJob, cal=None, image=None) -> dict:
    """Invert one frame and write its folder; returns its counts (pixels, clipped, below dark, extrapolated).

    ``cal`` and ``image`` save reading them again where the caller has them.
    """
    from bayescal.io import checks
    from bayescal.io.files import read_image
    from bayescal.model.setting import Setting
    from bayescal.prediction.images import invert_image, write_radiance_maps

    cal = cal if cal is not None else _calibration(job.posterior)
    image = read_image(job.image) if image is None else image
    checks.within_bits(image, cal.full_scale, job.image)
    setting = Setting(job.exposure_s, job.gain, job.tdi_stages, job.temperature_c)
    ds = invert_image(
        cal,
        image,
        setting,
        cfa=job.cfa,
        channel=job.channel,
        channels=list(job.channels) if job.channels else None,
        n_avg=job.n_avg,
        seed=job.seed,
    )
    ds.attrs["image"] = job.image
    write_radiance_maps(ds, job.out)
    a = ds.attrs
    return {
        "image": job.image,
        "out": job.out,
        "pixels": int(image.size),
        "clipped": int(a["n_saturated"]),
        "below_dark": int(a["n_below_dark"]),
        "extrapolated": int(a["n_extrapolated"]),
    }


def invert_frames(
    cal,
    jobs: Sequence[FrameJob],
    *,
    survey: str | os.PathLike | None = None,
    scheduler: str | None = None,
    tick: Callable[[int], None] | None = None,
    first: np.ndarray | None = None,
) -> list[dict]:
    """Invert every frame of ``jobs`` (one output folder each); returns each frame's counts, in order.

    ``cal`` is the calibration the jobs' ``posterior`` names, already read; ``first``, the first
    frame's image where the caller has read it (checked before the calibration was loaded).
    ``survey``: the folder the jobs' folders lie in (:func:`frame_outputs`), written as one output of
    kind ``"survey"`` (see the module docstring); without it each job's folder is its own output.
    ``scheduler`` is a ``dask.distributed`` scheduler address: the frames
    run on its workers (which must see the same files); None runs them here,
    one after another, each gather on every core.  ``tick(done)`` reports
    progress.
    """
    from bayescal.io.outputs import check_output_dir, staged_directory

    for job in jobs:  # every input and target checked before any work
        if not Path(job.image).is_file():
            raise FileNotFoundError(f"no such image: {job.image}")
        if survey is None:
            check_output_dir(job.out, "radiance")
    if survey is None:
        return _invert_all(cal, jobs, scheduler, tick, first)
    with staged_directory(survey, "survey") as stage:
        staged = [dataclasses.replace(j, out=str(stage.root / Path(j.out).name)) for j in jobs]
        results = _invert_all(cal, staged, scheduler, tick, first)
    return [r | {"out": j.out} for r, j in zip(results, jobs, strict=True)]


def _invert_all(cal, jobs: Sequence[FrameJob], scheduler, tick, first) -> list[dict]:
    from bayescal.prediction.tables import fill, persist_tables, restore_tables

    restore_tables(cal)
    if scheduler is not None:  # the workers read the tables from disk: every DN value, computed once here
        for job in {(j.cfa, j.channel, j.channels, j.n_avg, j.seed, _setting(j)): j for j in jobs}.values():
            fill(cal, _channel_names(job), _setting(job), n_avg=job.n_avg, seed=job.seed)
        persist_tables(cal)
        return _on_cluster(jobs, scheduler, tick)
    results = []
    try:
        for done, job in enumerate(jobs, 1):
            results.append(invert_frame(job, cal, first if done == 1 else None))
            if tick is not None:
                tick(done)
    except (TableError, SpecError) as exc:  # a bad frame: say which, and that nothing of the survey was kept
        raise type(exc)(f"{exc} (frame {len(results) + 1} of {len(jobs)}; no frame was written)") from None
    finally:
        persist_tables(cal)  # the tables the frames needed, kept for the next run
    return results


def _setting(job: FrameJob):
    from bayescal.model.setting import Setting

    return Setting(job.exposure_s, job.gain, job.tdi_stages, job.temperature_c)


def _channel_names(job: FrameJob) -> list[str]:
    from bayescal.io.cfa import cfa_cells

    if job.channels:
        return list(job.channels)
    if job.channel:
        return [job.channel]
    return list(dict.fromkeys(cfa_cells(job.cfa or "").values()))


def _on_cluster(jobs: Sequence[FrameJob], scheduler: str, tick: Callable[[int], None] | None) -> list[dict]:
    as_completed = optional("distributed", "a survey on a dask scheduler (--scheduler)").as_completed

    from bayescal.io.cluster import connect

    with connect(scheduler) as client:
        futures = client.map(invert_frame, list(jobs), pure=False)
        order = {f.key: i for i, f in enumerate(futures)}
        results: list[dict | None] = [None] * len(jobs)
        for done, future in enumerate(as_completed(futures), 1):
            results[order[future.key]] = future.result()  # a worker's error is raised here, naming its frame
            if tick is not None:
                tick(done)
    return [r for r in results if r is not None]
