"""Numbers and tables as text: for terminals, Markdown and the cells of HTML tables."""

from __future__ import annotations

import numpy as np
import pandas as pd

__all__ = ["fmt", "table_rows", "markdown_table"]


def fmt(v, digits: int = 5) -> str:
    """A number as text for tables: 5 significant digits, '-' for missing."""
    if v is None or (isinstance(v, float) and not np.isfinite(v)):
        return "-" if v is None or np.isnan(v) else ("inf" if v > 0 else "-inf")
    if isinstance(v, (bool, np.bool_)):
        return str(bool(v))
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    if isinstance(v, (float, np.floating)):
        return f"{v:.{digits}g}"
    return str(v)


def table_rows(df: pd.DataFrame) -> tuple[list[str], list[list[str]]]:
    """Column names and the formatted cells of each row."""
    return list(df.columns), [[fmt(v) for v in row] for row in df.itertuples(index=False)]


def markdown_table(df: pd.DataFrame) -> str:
    """A DataFrame as a Markdown table (numbers to 5 significant digits, missing values '-'; tabulate)."""
    return df.astype(object).where(df.notna(), None).to_markdown(index=False, floatfmt=".5g", missingval="-")
