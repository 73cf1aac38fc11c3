"""The film model kind: what :mod:`bayescal.model.kinds` calls for a spec with ``kind = "film"``."""

from __future__ import annotations

from bayescal.film.fit import fit_film_table
from bayescal.film.posterior import FilmCalibration
from bayescal.film.report import write_film_report
from bayescal.film.spec import FilmSpec
from bayescal.film.table import load_film_table

__all__ = ["spec_from_dict", "load_table", "fit", "load_posterior", "write_report"]


def spec_from_dict(data: dict, source: str) -> FilmSpec:
    """The film spec of a parsed TOML file."""
    return FilmSpec.from_dict(data, source=source)


load_table = load_film_table
fit = fit_film_table
load_posterior = FilmCalibration.load
write_report = write_film_report
