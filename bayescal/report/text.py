"""Plain-text summary of a fit for the terminal."""

from __future__ import annotations

import numpy as np
import pandas as pd

__all__ = ["render_summary"]


def render_summary(result) -> str:
    """Readable summary: model, verdict, coefficients with 95 % intervals beside least squares."""
    spec, layout = result.model.spec, result.model.layout
    ref = spec.reference
    lines = [
        f"Model {spec.name} ({result.backend}, seed {result.seed}): " + "; ".join(result.model.parts.describe()),
        f"Diagnostics: {result.diagnostics.verdict}"
        + (
            f" (max R-hat {result.diagnostics.max_rhat:.4f}, min bulk ESS {result.diagnostics.min_ess_bulk:.0f}, "
            f"{result.diagnostics.divergences} divergences)"
            if np.isfinite(result.diagnostics.max_rhat)
            else ""
        ),
        *([f"Note: {result.diagnostics.extra['retried']}"] if "retried" in result.diagnostics.extra else []),
        "",
        f"DN = A0 + A1 L + ... at exposure {ref.exposure_s:g} s, gain {ref.gain:g}, TDI {ref.tdi_stages:g}; "
        f"L in {layout.unit}",
    ]
    cmp = result.comparison
    if len(cmp) == 0:
        return "\n".join(lines)
    titles = ("least squares [95% CI]", "Bayes vs sphere [95%]", "Bayes absolute [95%]")
    header = f"{'ch':>4} {'coef':>4} " + " ".join(f"{t:>34}" for t in titles)
    lines += [header, "-" * len(header)]
    for _, r in cmp.iterrows():
        cells = [f"{r['channel']:>4}", f"{r['coefficient']:>4}"]
        for key in ("lsq", "bayes_rel", "bayes_abs"):
            if key in r and np.isfinite(r.get(key, np.nan)):
                cells.append(f"{_fmt(r[key]):>12} [{_fmt(r[key + '_lo'])}, {_fmt(r[key + '_hi'])}]".rjust(34))
            else:
                cells.append(f"{'-':>34}")
        lines.append(" ".join(cells))
    lines.append(
        "'vs sphere': relative to the sphere's radiance scale (what least squares sees); "
        f"'absolute': with its {spec.sphere.common_rel:.1%} scale uncertainty folded in."
    )
    if "lsq_r2" in cmp:
        r2 = cmp.groupby("channel", sort=False)["lsq_r2"].first()
        lines.append("Least-squares R^2: " + ", ".join(f"{c} {v:.5f}" for c, v in r2.items()))
    return "\n".join(lines)


def _fmt(x: float) -> str:
    return f"{x:.5g}"


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
    """A DataFrame as a Markdown table (numbers to 5 significant digits)."""
    head, rows = table_rows(df)
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines)
