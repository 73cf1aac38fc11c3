"""A fleet's measurement table split into units: one camera measured in one campaign.

The table is an ordinary measurement table (:mod:`bayescal.table`) with a
``camera`` column (the unit's serial number or name) and, optionally, a
``campaign`` column (the date the camera was calibrated, ISO ``YYYY-MM-DD``).
Each (camera, campaign) is one unit, fitted on its own in the first stage of
the fleet model (docs/architecture.md, section 8).
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np
import pandas as pd

from bayescal.errors import TableError
from bayescal.io.table import MeasurementTable, read_frame

__all__ = ["FleetTable", "Unit", "load_fleet_table", "fleet_from_frame", "to_years"]

#: days per year for dates as decimal years
DAYS_PER_YEAR = 365.25


@dataclass(frozen=True)
class Unit:
    """One camera measured in one campaign.

    Attributes
    ----------
    camera : str
    campaign : pandas.Timestamp or None
        The campaign's date (None when the table has no ``campaign`` column).
    table : MeasurementTable
    rows : ndarray of int
        The unit's 1-based data rows in the fleet file.
    """

    camera: str
    campaign: pd.Timestamp | None
    table: MeasurementTable
    rows: np.ndarray

    @property
    def label(self) -> str:
        """``camera @ date`` (or the camera alone)."""
        return self.camera if self.campaign is None else f"{self.camera} @ {self.campaign.date().isoformat()}"


@dataclass(frozen=True)
class FleetTable:
    """A fleet's units, sorted by camera, then campaign date.

    Attributes
    ----------
    units : tuple of Unit
    cameras : tuple of str
        In order of first appearance in the file.
    source : str
    """

    units: tuple[Unit, ...]
    cameras: tuple[str, ...]
    source: str = "<frame>"

    @property
    def campaigns(self) -> tuple[pd.Timestamp, ...]:
        """Distinct campaign dates, sorted (empty without a campaign column)."""
        return tuple(sorted({u.campaign for u in self.units if u.campaign is not None}))

    @property
    def origin(self) -> pd.Timestamp | None:
        """The first campaign's date: time 0 of the drift model."""
        return self.campaigns[0] if self.campaigns else None


def load_fleet_table(path: str | os.PathLike) -> FleetTable:
    """Read a fleet table (CSV or Parquet) with ``camera`` and optional ``campaign`` columns.

    Raises
    ------
    TableError
        Naming the row and column: no ``camera`` column, a ``campaign`` column
        without one, a date that does not parse, a single camera, a camera
        with no illuminated rows, or any error of an ordinary table.

    Examples
    --------
    >>> import os, tempfile
    >>> import bayescal as bc
    >>> design = bc.FleetDesign(n_cameras=2, campaigns=("2024-03-01", "2025-03-01"), n_pixels=8, n_frames=2)
    >>> path = os.path.join(tempfile.mkdtemp(), "fleet.csv")
    >>> bc.simulate_fleet(design, seed=1)[0].to_csv(path, index=False)
    >>> bc.load_fleet_table(path).cameras
    ('SN001', 'SN002')
    """
    return fleet_from_frame(read_frame(path), source=str(path))


def fleet_from_frame(df: pd.DataFrame, *, source: str = "<frame>") -> FleetTable:
    """Validate a raw fleet frame (see :func:`load_fleet_table`).

    Examples
    --------
    >>> import bayescal as bc
    >>> design = bc.FleetDesign(n_cameras=2, campaigns=("2024-03-01", "2025-03-01"), n_pixels=8, n_frames=2)
    >>> table, _ = bc.simulate_fleet(design, seed=1)
    >>> fleet = bc.fleet_from_frame(table, source="fleet.csv")
    >>> fleet.cameras, len(fleet.units)  # a unit: one camera in one campaign
    (('SN001', 'SN002'), 4)
    """
    df = df.reset_index(drop=True)  # rows by position: a filtered frame keeps its labels, which are not positions
    df.columns = [str(c).strip() for c in df.columns]
    if len(df) == 0:
        raise TableError(f"{source} has no data rows")
    if "camera" not in df.columns:
        if "campaign" in df.columns:
            raise TableError(
                f"{source}: a 'campaign' column needs a 'camera' column naming the unit measured in each row",
                column="camera",
            )
        raise TableError(
            f"{source}: a fleet table needs a 'camera' column naming the unit of each row", column="camera"
        )
    camera = df["camera"].astype("string").str.strip()
    blank = camera.isna() | (camera == "")
    if blank.any():
        raise TableError(f"{source}: empty camera name", row=int(np.flatnonzero(blank)[0]) + 1, column="camera")
    cameras = tuple(dict.fromkeys(camera))
    if len(cameras) < 2:
        raise TableError(
            f"{source}: every row is camera '{cameras[0]}'; a fleet needs at least two cameras "
            "(fit a single camera with `bayescal fit`)",
            column="camera",
        )
    if "campaign" in df.columns:
        dates = _dates(df["campaign"], source)
    else:
        dates = pd.Series([pd.NaT] * len(df))
    keys = pd.DataFrame({"camera": camera, "campaign": dates})
    units = []
    for (cam, date), rows in keys.groupby(["camera", "campaign"], sort=True, dropna=False).groups.items():
        rows = np.asarray(sorted(rows))
        sub = df.iloc[rows].drop(columns=[c for c in ("camera", "campaign") if c in df.columns]).reset_index(drop=True)
        when = None if pd.isna(date) else pd.Timestamp(date)
        where = f"{source} camera '{cam}'" + ("" if when is None else f" campaign {when.date().isoformat()}")
        try:
            table = MeasurementTable.from_frame(sub, source=where)
        except TableError as exc:
            row = None if exc.row is None else int(rows[exc.row - 1]) + 1
            message = str(exc).split(": ", 1)[-1] if exc.row is not None or exc.column is not None else str(exc)
            raise TableError(f"{where}: {message}", row=row, column=exc.column) from None
        if not (table.frame["stimulus"] > 0).any():
            raise TableError(
                f"{where} has no illuminated rows (every stimulus is 0); each unit needs a radiance sweep",
                row=int(rows[0]) + 1,
                column=table.stimulus,
            )
        units.append(Unit(str(cam), when, table, rows + 1))
    units.sort(key=lambda u: (cameras.index(u.camera), u.campaign or pd.Timestamp(0)))
    return FleetTable(tuple(units), cameras, source)


def to_years(dates, origin: pd.Timestamp) -> np.ndarray:
    """Dates as decimal years since ``origin``."""
    delta = pd.to_datetime(pd.Series(dates)) - origin
    return (delta.dt.total_seconds() / 86400.0 / DAYS_PER_YEAR).to_numpy(dtype=float)


def _dates(col: pd.Series, source: str) -> pd.Series:
    text = col.astype("string").str.strip()
    parsed = pd.to_datetime(text, errors="coerce", format="ISO8601")
    bad = parsed.isna()
    if bad.any():
        i = int(np.flatnonzero(bad.to_numpy())[0])
        raise TableError(
            f"{source}: campaign date '{text.iloc[i]}' does not parse; expected an ISO date such as 2026-03-15",
            row=i + 1,
            column="campaign",
        )
    today = pd.Timestamp.now().normalize()
    odd = (parsed > today + pd.Timedelta(days=1)) | (parsed < pd.Timestamp("1950-01-01"))
    if odd.any():
        i = int(np.flatnonzero(odd.to_numpy())[0])
        raise TableError(
            f"{source}: campaign date {parsed.iloc[i].date().isoformat()} is "
            + ("in the future" if parsed.iloc[i] > today else "before 1950")
            + "; expected the date the campaign measured (a typo in the year?)",
            row=i + 1,
            column="campaign",
        )
    return parsed.dt.normalize()
