"""Exceptions raised by bayescal.

Every input error names where it is (file, row, column) and what was expected,
so that a calibration scientist can fix the CSV without reading code.
"""

from __future__ import annotations

__all__ = [
    "BayescalError",
    "TableError",
    "SpecError",
    "OutputError",
    "PosteriorError",
    "FitFailedError",
    "FitFailedWarning",
    "MissingExtraError",
    "optional",
]


class BayescalError(Exception):
    """Base class of every bayescal error.

    Examples
    --------
    >>> import bayescal as bc
    >>> try:
    ...     bc.load_spec("seed00")
    ... except bc.BayescalError as err:  # every error of bayescal's own; SpecError here
    ...     print(type(err).__name__, "-", err)
    SpecError - no such model spec (TOML): seed00; did you mean 'seed000' (a shipped example; ...)?
    """


class TableError(BayescalError, ValueError):
    """A measurement table is malformed.

    Attributes
    ----------
    row : int or None
        1-based data row (the header is row 0; in a CSV file the line number
        is ``row + 1``), or ``None`` when the problem is not tied to one row.
    column : str or None
        Offending column, or ``None``.

    Examples
    --------
    >>> import bayescal as bc
    >>> print(bc.TableError("expected a number", row=3, column="dn_mean"))
    row 3, column 'dn_mean': expected a number
    """

    def __init__(self, message: str, *, row: int | None = None, column: str | None = None):
        where = []
        if row is not None:
            where.append(f"row {row}")
        if column is not None:
            where.append(f"column '{column}'")
        prefix = f"{', '.join(where)}: " if where else ""
        super().__init__(prefix + message)
        self.row = row
        self.column = column


class SpecError(BayescalError, ValueError):
    """A model specification or design is malformed (names the key at fault).

    Examples
    --------
    >>> import bayescal as bc
    >>> issubclass(bc.SpecError, ValueError)  # a bad value, caught as one by code that knows nothing of bayescal
    True
    """


class OutputError(BayescalError, ValueError):
    """An output path cannot be written, or holds files bayescal must not replace."""


class PosteriorError(BayescalError, ValueError):
    """A fit directory or ``posterior.nc`` is missing, unreadable or not written by bayescal."""


class FitFailedError(BayescalError, RuntimeError):
    """Raised when a fit's diagnostics fail and the caller asked for strictness.

    Examples
    --------
    >>> import bayescal as bc
    >>> issubclass(bc.FitFailedError, bc.BayescalError)  # raised by fit(..., strict=True); else a warning
    True
    """


class MissingExtraError(BayescalError, ImportError):
    """A feature needs an optional package that is not installed (the message names the extra to install)."""


class FitFailedWarning(UserWarning):
    """Warned when a fit's diagnostics fail (divergences, R-hat, ESS).

    Examples
    --------
    >>> import warnings
    >>> import bayescal as bc
    >>> with warnings.catch_warnings():
    ...     warnings.simplefilter("error", bc.FitFailedWarning)  # a script that must stop on a failed fit
    ...     issubclass(bc.FitFailedWarning, UserWarning)
    True
    """


#: the optional packages and the extra of ``pyproject.toml`` that installs each
EXTRAS = {
    "emcee": "emcee",
    "blackjax": "blackjax",
    "dask": "maps",
    "zarr": "maps",
    "distributed": "cluster",
    "astropy": "fits",
}


def optional(module: str, needed_for: str):
    """Import the optional package ``module`` (a dotted name within it is fine), or raise
    :class:`MissingExtraError` saying what needs it and which extra installs it."""
    import importlib

    try:
        return importlib.import_module(module)
    except ImportError:
        extra = EXTRAS.get(module.split(".")[0])
        hint = f"pip install 'bayescal[{extra}]'" if extra else f"pip install {module.split('.')[0]}"
        raise MissingExtraError(f"{needed_for} needs the optional package '{module.split('.')[0]}': {hint}") from None
