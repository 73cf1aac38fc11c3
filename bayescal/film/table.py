"""The film's measurement table: wedge densities per band and the meter's current on the target.

CSV or Parquet with ``band, step, density, meter_current``: one row per band and wedge step
(``step`` 1..N), ``meter_current`` the radiance meter's reading on the reference target for that
band, the same on every row of the band (seed 003 section 3).
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np
import pandas as pd

from bayescal.errors import TableError
from bayescal.io.table import read_frame

__all__ = ["FilmTable", "load_film_table", "COLUMNS"]

COLUMNS = ("band", "step", "density", "meter_current")


@dataclass(frozen=True)
class FilmTable:
    """Validated wedge densities: ``bands[name] = (meter current, densities by step)``."""

    bands: dict[str, tuple[float, np.ndarray]]
    frame: pd.DataFrame
    source: str = "<frame>"

    @classmethod
    def from_frame(cls, df: pd.DataFrame, *, source: str = "<frame>") -> FilmTable:
        """Validate a frame of the table's layout (every problem names its row and column)."""
        df = df.rename(columns=lambda c: str(c).strip())
        for col in COLUMNS:
            if col not in df:
                raise TableError(f"{source}: missing column; expected {', '.join(COLUMNS)}", column=col)
        if len(df) == 0:
            raise TableError(f"{source} has no data rows")
        out = pd.DataFrame({"band": df["band"].astype("string").str.strip().astype(str)})
        for col in ("step", "density", "meter_current"):
            values = pd.to_numeric(df[col].astype("string").str.strip(), errors="coerce").astype(float)
            bad = np.flatnonzero(~np.isfinite(values.to_numpy()))
            if bad.size:
                raise TableError(f"'{df[col].iloc[bad[0]]}' is not a finite number", row=int(bad[0]) + 1, column=col)
            out[col] = values
        bad = np.flatnonzero(out["meter_current"].to_numpy() <= 0)
        if bad.size:
            raise TableError("the meter current must be > 0", row=int(bad[0]) + 1, column="meter_current")
        bands = {}
        for band, g in out.groupby("band", sort=False):
            steps = g["step"].to_numpy()
            if not np.array_equal(np.sort(steps), np.arange(1, steps.size + 1)):
                raise TableError(
                    f"band {band}: steps {sorted(steps.tolist())}; expected 1..{steps.size} once each",
                    row=int(g.index[0]) + 1,
                    column="step",
                )
            currents = g["meter_current"].unique()
            if currents.size != 1:
                raise TableError(
                    f"band {band} has several meter_current values {list(currents)}; expected one per band",
                    row=int(g.index[0]) + 1,
                    column="meter_current",
                )
            g = g.sort_values("step")
            bands[str(band)] = (float(currents[0]), g["density"].to_numpy(dtype=float))
        return cls(bands, out, source)

    def __len__(self) -> int:
        return len(self.frame)

    def write_csv(self, path: str | os.PathLike) -> None:
        """Write the table as CSV, atomically."""
        from bayescal.io.outputs import write_text_atomic

        write_text_atomic(path, self.frame.to_csv(index=False, float_format="%.10g"))


def load_film_table(path: str | os.PathLike) -> FilmTable:
    """Read and validate a film table (CSV or Parquet)."""
    return FilmTable.from_frame(read_frame(path), source=str(path))
