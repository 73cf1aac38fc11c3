"""A fit's folder: the one place that knows its files' names, checks it before a read, and opens each
of its files at most once.

``bayescal fit --out DIR`` (and a fleet's per-camera export) writes::

    DIR/posterior.nc     the posterior draws, the spec (``spec_toml``) and the measurements (a DataTree)
    DIR/summary.json     the verdict, the diagnostics and the summaries (:class:`~bayescal.io.summary.FitSummary`)
    DIR/summary.csv      the parameters' summaries as a table
    DIR/lsq.csv          the least-squares baseline
    DIR/.bayescal-output the run's record of its files (:mod:`bayescal.io.outputs`)

A least-squares fit writes no ``posterior.nc``.  Readers get a :class:`FitFolder` from
:meth:`FitFolder.at` (a folder, or a ``posterior.nc`` named directly) and read through it: the run's
record is verified once there, the summary parsed once and the posterior opened once, however many
readers (a calibration, the report's figures) use them.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Any

from bayescal.errors import PosteriorError
from bayescal.io.summary import FitSummary

__all__ = ["FitFolder", "LSQ", "POSTERIOR", "SUMMARY", "TABLE"]

#: the posterior draws, spec and measurements
POSTERIOR = "posterior.nc"
#: the verdict, diagnostics and summaries
SUMMARY = "summary.json"
#: the parameters' summaries as a table
TABLE = "summary.csv"
#: the least-squares baseline
LSQ = "lsq.csv"


@dataclass(frozen=True)
class FitFolder:
    """A fit's folder (or a bare ``posterior.nc``), checked, with its files read on first use (each once:
    ``summary`` and ``posterior`` are computed when first asked for and kept).

    Attributes
    ----------
    root : Path or None
        The folder; None for a posterior file that lies outside any fit folder.
    posterior_path : Path
        Where the posterior is (it may not exist: a least-squares fit).
    """

    root: Path | None
    posterior_path: Path

    @classmethod
    def at(
        cls, path: str | os.PathLike, verb: str = "a fit's reader", needs: tuple[str, ...] = (POSTERIOR,)
    ) -> FitFolder:
        """The fit at ``path`` (a folder or its ``posterior.nc``), its run's record verified once.

        ``needs``: the files the reader needs, checked as the run's own (a reader that needs the posterior
        is told when the folder holds a least-squares fit); ``verb`` names the reader in messages.
        """
        from bayescal.io.outputs import verify_output

        path = Path(path)
        if path.is_dir():
            if POSTERIOR in needs and not (path / POSTERIOR).exists() and (path / SUMMARY).exists():
                raise PosteriorError(
                    f"no posterior at {path / POSTERIOR}: {path} holds a least-squares fit; "
                    f"{verb} needs a Bayesian backend (--backend nuts or laplace)"
                )
            verify_output(path, ("fit",), needs=needs, verb=verb)
            return cls(path, path / POSTERIOR)
        if path.is_file():  # a posterior.nc named directly: its folder, if any, is checked once here
            verify_output(path, ("fit",), verb=verb)
            return cls(path.parent if path.name == POSTERIOR else None, path)
        raise PosteriorError(f"no posterior at {path}; run `bayescal fit ... --out DIR` first")

    def file(self, name: str) -> Path:
        """The path of the fit's file ``name`` (one of this module's names)."""
        if self.root is None:
            raise PosteriorError(f"{self.posterior_path} is not in a fit folder: it has no {name}")
        return self.root / name

    @cached_property
    def summary(self) -> FitSummary:
        """``summary.json``, parsed and checked on first use (:meth:`FitSummary.from_json`); a clear error
        when it is missing or not a bayescal summary."""
        path = self.file(SUMMARY)
        try:
            data = json.loads(path.read_text())
        except (OSError, UnicodeError, ValueError) as exc:
            raise PosteriorError(
                f"{path} is missing or not a bayescal summary ({type(exc).__name__}: {exc}); re-run `bayescal fit`"
            ) from None
        return FitSummary.from_json(data, path)

    @cached_property
    def measurements(self) -> Any:
        """The measured table the fit was made on (a ``pandas.DataFrame``, its stimulus column under its own
        name), from the posterior's ``measurements`` group."""
        tree = self.posterior
        if "measurements" not in tree.children:
            raise PosteriorError(f"{self.posterior_path} holds no measurements; was it written by `bayescal fit`?")
        return tree["measurements"].to_dataset().to_dataframe().reset_index(drop=True)

    @cached_property
    def posterior(self) -> Any:
        """``posterior.nc`` as an ``xarray.DataTree``, opened on first use; a clear error for a truncated or
        foreign file."""
        import xarray as xr

        if not self.posterior_path.is_file():
            raise PosteriorError(f"no posterior at {self.posterior_path}; run `bayescal fit ... --out DIR` first")
        try:
            return xr.open_datatree(self.posterior_path)
        except Exception as exc:  # h5py/xarray raise many types for truncated or foreign files
            raise PosteriorError(
                f"{self.posterior_path} is not a readable posterior file ({type(exc).__name__}: "
                f"{str(exc)[:200]}); was it truncated? Re-run `bayescal fit`"
            ) from None
