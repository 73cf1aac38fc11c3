"""Film density calibration of the 4-band film camera (seed 003): a model kind of its own.

spec (the bands' radiance chains, the wedge; eq. 3, 10, 11) -> table (wedge densities per band) ->
model (the characteristic curve, eq. 5-6, and the numpyro model of one band) -> fit (every band
through the backend seam) -> posterior (band radiance from density) -> report.  ``kind = "film"``
in a spec's TOML makes :func:`bayescal.load_spec`, :func:`bayescal.fit`,
:meth:`bayescal.Calibration.load`, :func:`bayescal.invert` and the report take this package's
path (:mod:`bayescal.model.kinds`).
"""

from bayescal.film.fit import BandFit, FilmFit, fit_film, fit_film_table
from bayescal.film.model import simulate_film, uncertainty_budget_film
from bayescal.film.posterior import FilmCalibration
from bayescal.film.spec import FilmBand, FilmSpec, convert_exposure, correction_chain, table1_check
from bayescal.film.table import FilmTable, load_film_table

__all__ = [
    "BandFit",
    "FilmBand",
    "FilmCalibration",
    "FilmFit",
    "FilmSpec",
    "FilmTable",
    "convert_exposure",
    "correction_chain",
    "fit_film",
    "fit_film_table",
    "load_film_table",
    "simulate_film",
    "table1_check",
    "uncertainty_budget_film",
]
