"""Validated measurement tables (one row per measured condition and channel).

A row is the mean DN of a region of interest at one sphere level, exposure
time, gain, TDI stage count and temperature, for one colour channel (seed 000
section 4.3; seed 002 section 4.3).  Dark rows have zero stimulus.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from bayescal.errors import TableError
from bayescal.io.files import read_text
from bayescal.io.limits import limit
from bayescal.io.outputs import atomic_path
from bayescal.io.resources import did_you_mean

__all__ = ["MeasurementTable", "load_table", "read_frame", "REQUIRED_COLUMNS", "OPTIONAL_COLUMNS"]

STIMULUS_COLUMNS = ("radiance", "irradiance")
STIMULUS_UNITS = {"radiance": "W m^-2 sr^-1", "irradiance": "W m^-2"}
REQUIRED_COLUMNS = ("channel", "exposure_s", "gain", "dn_mean")
#: optional column -> default (None: stays absent when not given)
OPTIONAL_COLUMNS: dict[str, float | None] = {
    "level": None,
    "tdi_stages": 1.0,
    "temperature_c": None,
    "time_s": None,
    "n_frames": 1.0,
    "n_pixels": 1.0,
    "dn_var": None,
    "radiance_u_rel": None,
    "replicate": 0.0,
}
#: the limit (:data:`bayescal.io.limits.LIMITS`) each numeric column is checked against
COLUMN_LIMITS = {
    "radiance": "stimulus",
    "irradiance": "stimulus",
    "exposure_s": "exposure_s",
    "gain": "gain",
    "tdi_stages": "tdi_stages",
    "temperature_c": "temperature_c",
    "time_s": "time_s",
    "n_frames": "count",
    "n_pixels": "count",
    "dn_mean": "dn",
    "dn_var": "dn_var",
    "radiance_u_rel": "relative",
}
_CONDITION = ("channel", "stimulus", "exposure_s", "gain", "tdi_stages", "temperature_c", "level", "replicate")


@dataclass(frozen=True)
class MeasurementTable:
    """A validated table of calibration measurements.

    Build one with :func:`load_table` or :meth:`from_frame`; the constructor
    assumes a frame that was already validated.

    Attributes
    ----------
    frame : pandas.DataFrame
        Normalised columns: ``channel`` (str), ``stimulus`` (radiance or
        irradiance, float), ``exposure_s``, ``gain``, ``dn_mean``,
        ``tdi_stages``, ``n_frames``, ``n_pixels``, ``replicate``, ``level``
        (str id; dark rows "dark"), and the optional columns that were given.
    stimulus : {"radiance", "irradiance"}
        Which stimulus the ``stimulus`` column holds (seed 000 uses entrance-
        pupil radiance, seed 002 focal-plane irradiance).
    source : str
        Where the table came from (for error messages and provenance).

    Examples
    --------
    >>> import pandas as pd
    >>> import bayescal as bc
    >>> frame = pd.DataFrame({"channel": ["G"] * 3, "exposure_s": [0.004] * 3, "gain": [1.0] * 3,
    ...                       "radiance": [0.0, 5.0, 10.0], "dn_mean": [45.2, 195.1, 344.8]})
    >>> table = bc.MeasurementTable.from_frame(frame, source="bench.csv")
    >>> table.stimulus, len(table.frame)
    ('radiance', 3)
    >>> bc.MeasurementTable.from_frame(frame.assign(dn_mean=["45", "x", "1"]), source="bench.csv")
    Traceback (most recent call last):
    ...
    bayescal.errors.TableError: row 2, column 'dn_mean': 'x' is not a number
    """

    frame: pd.DataFrame
    stimulus: str
    source: str = "<frame>"

    @classmethod
    def from_frame(cls, df: pd.DataFrame, *, source: str = "<frame>") -> MeasurementTable:
        """Validate a DataFrame and return a table; raise :class:`TableError` otherwise.

        Rows are numbered from 1 in the frame's order, whatever its index (a filtered frame's
        index has gaps).
        """
        return cls(*_validate(df.reset_index(drop=True), source), source=source)

    @property
    def unit(self) -> str:
        """Unit of the stimulus column."""
        return STIMULUS_UNITS[self.stimulus]

    @property
    def channels(self) -> list[str]:
        """Channels in order of first appearance."""
        return list(dict.fromkeys(self.frame["channel"]))

    @property
    def is_dark(self) -> np.ndarray:
        """Boolean mask of dark rows (zero stimulus)."""
        return self.frame["stimulus"].to_numpy() == 0.0

    def __len__(self) -> int:
        return len(self.frame)

    def to_frame(self) -> pd.DataFrame:
        """The table in its file layout (``stimulus`` renamed back to its unit's column)."""
        return self.frame.rename(columns={"stimulus": self.stimulus})

    def write_csv(self, path: str | os.PathLike) -> None:
        """Write the table as CSV, atomically."""
        with atomic_path(path) as tmp:
            self.to_frame().to_csv(tmp, index=False, float_format="%.10g")


def load_table(path: str | os.PathLike) -> MeasurementTable:
    """Read and validate a CSV or Parquet measurement table.

    Parameters
    ----------
    path : path-like
        ``.csv`` (comma separated, header row) or ``.parquet``.

    Raises
    ------
    TableError
        Naming the row and column of the first problem found.

    Examples
    --------
    >>> import os, tempfile
    >>> import pandas as pd
    >>> import bayescal as bc
    >>> path = os.path.join(tempfile.mkdtemp(), "bench.csv")
    >>> pd.DataFrame({"channel": ["G", "G"], "exposure_s": [0.004, 0.004], "gain": [1.0, 1.0],
    ...               "radiance": [0.0, 10.0], "dn_mean": [45.2, 344.8]}).to_csv(path, index=False)
    >>> len(bc.load_table(path).frame)
    2
    """
    return MeasurementTable.from_frame(read_frame(path), source=str(path))


def read_frame(path: str | os.PathLike) -> pd.DataFrame:
    """The raw rows of a CSV (every cell a string) or Parquet file, before validation.

    Raises
    ------
    TableError
        The file is missing, empty, not text, or not a well-formed table.
    """
    import io

    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".parquet":
        if not path.is_file():
            raise TableError(
                f"no such file: {path}{did_you_mean(path)}" if not path.exists() else f"{path} is not a file"
            )
        try:
            return pd.read_parquet(path)
        except Exception as exc:  # pyarrow raises its own types for every kind of corrupt file
            raise TableError(f"{path} is not a readable Parquet file ({type(exc).__name__}: {exc})") from None
    if suffix in (".csv", ".txt"):
        text = read_text(path, TableError, "measurement table (CSV)")
        _comma_separated(text, path)
        try:
            return pd.read_csv(io.StringIO(text), dtype=str, skipinitialspace=True, comment="#")
        except pd.errors.EmptyDataError as exc:
            raise TableError(f"{path} is empty; expected a header row and data rows") from exc
        except pd.errors.ParserError as exc:
            raise TableError(f"{path} is not a well-formed CSV table: {exc}") from None
    raise TableError(f"{path}: expected a .csv or .parquet file, got '{suffix}'")


#: separators a spreadsheet writes where a CSV has commas, by name
_SEPARATORS = {";": "semicolons (';')", "\t": "tabs", "|": "vertical bars ('|')"}


def _comma_separated(text: str, path: Path) -> None:
    """Refuse a table whose header is separated by something other than commas (a spreadsheet's export
    in a locale with decimal commas), naming the separator, before it is read as one column."""
    header = next((line for line in text.splitlines() if line.strip() and not line.lstrip().startswith("#")), "")
    if "," in header:
        return
    for sep, name in _SEPARATORS.items():
        if header.count(sep) >= 2:
            raise TableError(
                f"{path}: the header row '{header.strip()[:80]}' is separated by {name}, not commas; save the "
                "table as comma-separated CSV with decimal points (a spreadsheet's 'CSV (comma delimited)')"
            )


def _validate(df: pd.DataFrame, source: str) -> tuple[pd.DataFrame, str]:
    df = df.copy()
    df.columns = [str(c).strip() for c in df.columns]
    if len(df) == 0:
        raise TableError(f"{source} has no data rows")
    for col in REQUIRED_COLUMNS:
        if col not in df.columns:
            raise TableError(
                f"missing required column; expected columns {', '.join(REQUIRED_COLUMNS)} "
                f"and one of radiance/irradiance, found {', '.join(df.columns)}",
                column=col,
            )
    given = [c for c in STIMULUS_COLUMNS if c in df.columns]
    if len(given) != 1:
        raise TableError(
            "expected exactly one stimulus column, 'radiance' (W m^-2 sr^-1) or "
            f"'irradiance' (W m^-2); found {given or 'neither'}",
            column="radiance",
        )
    stimulus = given[0]
    df = df.rename(columns={stimulus: "stimulus"})
    out = pd.DataFrame(index=range(len(df)))
    out["channel"] = _channel_column(df["channel"])
    for col in ("stimulus", "exposure_s", "gain", "dn_mean"):
        out[col] = _numeric(df[col], stimulus if col == "stimulus" else col)
    for col, default in OPTIONAL_COLUMNS.items():
        if col == "level":
            continue
        if col in df.columns:
            out[col] = _numeric(df[col], col)
        elif default is not None:
            out[col] = default
    _check_ranges(out, stimulus)
    out["level"] = _levels(df, out)
    _check_duplicates(out, stimulus)
    return out, stimulus


def _channel_column(col: pd.Series) -> pd.Series:
    values = col.astype("string").str.strip()
    for i, v in enumerate(values):
        if pd.isna(v) or v == "":
            raise TableError("empty channel name; expected e.g. R, G, B or a band name", row=i + 1, column="channel")
    return values.astype(str)


def _numeric(col: pd.Series, name: str) -> pd.Series:
    as_str = col.astype("string").str.strip()
    num = pd.to_numeric(as_str, errors="coerce")
    for i, (raw, val) in enumerate(zip(as_str, num, strict=True)):
        if pd.isna(raw) or raw == "" or str(raw).lower() == "nan":
            raise TableError("missing value (empty or NaN); expected a number", row=i + 1, column=name)
        if pd.isna(val):
            raise TableError(f"'{raw}' is not a number", row=i + 1, column=name)
        if not np.isfinite(val):
            raise TableError(f"'{raw}' is not finite; expected a finite number", row=i + 1, column=name)
    return num.astype(float)


def _check_ranges(out: pd.DataFrame, stimulus: str) -> None:
    for col, name in COLUMN_LIMITS.items():
        key = "stimulus" if col == stimulus else col
        if key in out and (col == stimulus or col not in STIMULUS_COLUMNS):
            lim = limit(name)
            values = out[key].to_numpy()
            bad = np.flatnonzero(~np.array([lim.holds(v) for v in values]))
            if bad.size:
                raise TableError(
                    f"{values[bad[0]]:g} {lim.fault(values[bad[0]])}; expected {lim.describe()}",
                    row=bad[0] + 1,
                    column=col,
                )
    for col in ("n_frames", "n_pixels", "tdi_stages"):
        v = out[col].to_numpy()
        bad = np.flatnonzero(v != np.round(v))
        if bad.size:
            raise TableError(f"{v[bad[0]]:g} is not a whole number", row=bad[0] + 1, column=col)
    if "time_s" in out:
        _check_times(out)


def _check_times(out: pd.DataFrame) -> None:
    """One ``time_s`` value is one moment of the session: the channels of one frame share it, but two
    settings or two sphere levels cannot have been measured at the same moment."""
    what = [c for c in ("stimulus", "exposure_s", "gain", "tdi_stages", "temperature_c", "replicate") if c in out]
    first = out.drop_duplicates("time_s")
    seen = dict(zip(first["time_s"], first.index, strict=True))
    for i, row in enumerate(out[["time_s", *what]].itertuples(index=False)):
        j = seen[row[0]]
        if j != i and tuple(out.loc[j, what]) != tuple(row[1:]):
            differs = next(c for c, a, b in zip(what, out.loc[j, what], row[1:], strict=True) if a != b)
            raise TableError(
                f"time {row[0]:g} s is also the time of row {j + 1}, which differs in {differs}; one moment of the "
                "session holds one setting (the channels of one frame share it); expected the time each frame "
                "was taken",
                row=i + 1,
                column="time_s",
            )


def _levels(df: pd.DataFrame, out: pd.DataFrame) -> pd.Series:
    """Sphere level ids: given, or one per distinct stimulus value; unlabelled dark rows -> 'dark'."""
    dark = out["stimulus"].to_numpy() == 0
    if "level" in df.columns:
        ids = df["level"].astype("string").str.strip()
        for i, v in enumerate(ids):
            if not dark[i] and (pd.isna(v) or v == ""):
                raise TableError("missing sphere level id for an illuminated row", row=i + 1, column="level")
        ids = ids.fillna("").astype(str)
        # one level must not carry two different stimulus values
        lit = out.loc[~dark].assign(level=ids[~dark])
        spread = lit.groupby("level")["stimulus"].agg(["min", "max"])
        for level, (lo, hi) in spread.iterrows():
            if not np.isclose(lo, hi, rtol=1e-9, atol=0):
                row = int(lit.index[lit["level"] == level][0]) + 1
                raise TableError(
                    f"sphere level '{level}' has two stimulus values ({lo:g} and {hi:g}); "
                    "expected one value per level (channels of one level see the same sphere setting)",
                    row=row,
                    column="level",
                )
        # dark rows keep the user's labels (two dark frames of one setting may be 'dark0' and 'dark1')
        return ids.where(~dark | (ids != ""), "dark")
    ids = out["stimulus"].map(lambda v: f"L{v:.10g}")
    return ids.where(~dark, "dark")


def _check_duplicates(out: pd.DataFrame, stimulus: str) -> None:
    key_cols = [c for c in _CONDITION if c in out]
    first_seen: dict[tuple, int] = {}
    for i, key in enumerate(out[key_cols].itertuples(index=False, name=None)):
        if key in first_seen:
            j = first_seen[key]
            a, b = out["dn_mean"].iloc[j], out["dn_mean"].iloc[i]
            what = "repeats" if a == b else f"conflicts with (dn_mean {a:g} vs {b:g})"
            raise TableError(
                f"this row {what} row {j + 1}: same channel, {stimulus}, exposure, gain, TDI stages, "
                "temperature and level; expected one row per condition (add a 'replicate' column for repeats)",
                row=i + 1,
                column="dn_mean",
            )
        first_seen[key] = i
