"""One typed check per kind of input, at the boundary: numbers in their domain, dates, images.

Each check names where the value came from (an option, a file, a key) and what was expected,
and raises :class:`~bayescal.errors.SpecError` (options, keys, dates) or
:class:`~bayescal.errors.TableError` (arrays read from files), which the command line turns
into exit status 2.  The command line's argument types are built on the same checks.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

from bayescal.errors import SpecError, TableError

if TYPE_CHECKING:
    import numpy as np
    import pandas as pd

__all__ = ["number", "count", "probability", "date", "image", "within_bits", "require_spread"]


def number(value, what: str, *, positive: bool = False, minimum: float | None = None) -> float:
    """A finite real number; with ``positive`` above 0, with ``minimum`` at least that."""
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise SpecError(f"{what} = {value!r}; expected a number") from None
    if not math.isfinite(x):
        raise SpecError(f"{what} = {value!r}; expected a finite number")
    if positive and x <= 0:
        raise SpecError(f"{what} = {value!r}; expected a number above 0")
    if minimum is not None and x < minimum:
        raise SpecError(f"{what} = {value!r}; expected at least {minimum:g}")
    return x


def count(value, what: str, *, minimum: int = 1) -> int:
    """A whole number of at least ``minimum`` (a count or a size); ``True``/``False`` are not counts."""
    if isinstance(value, bool) or isinstance(value, float) and not value.is_integer():
        raise SpecError(f"{what} = {value!r}; expected a whole number >= {minimum}")
    try:
        n = int(str(value).strip()) if isinstance(value, str) else int(value)
    except (TypeError, ValueError):
        raise SpecError(f"{what} = {value!r}; expected a whole number >= {minimum}") from None
    if n < minimum:
        raise SpecError(f"{what} = {value!r}; expected a whole number >= {minimum}")
    return n


def probability(value, what: str) -> float:
    """A probability strictly between 0 and 1 (a risk, a credible level)."""
    p = number(value, what)
    if not 0.0 < p < 1.0:
        raise SpecError(f"{what} = {value!r}; expected a probability between 0 and 1 (exclusive)")
    return p


def date(value, what: str) -> pd.Timestamp:
    """An ISO calendar date (``2026-03-15``, a time of day allowed), as a day-resolution timestamp."""
    import pandas as pd

    text = str(value).strip()
    try:
        when = pd.Timestamp(text) if text else pd.NaT
    except (ValueError, TypeError, OverflowError):
        when = pd.NaT
    if pd.isna(when) or not text[:1].isdigit():
        raise SpecError(f"{what} '{value}' is not a date; expected an ISO date such as 2026-03-15")
    return when.normalize()


def image(img: np.ndarray, source: str) -> np.ndarray:
    """A DN image: real numbers (integer or float), 2-D or (H, W, C) with no empty axis, every value
    finite and not negative.  Returns it unchanged."""
    import numpy as np

    if img.dtype.kind not in "uif":
        kind = {"c": "complex", "O": "object", "b": "boolean", "U": "text", "S": "bytes"}.get(img.dtype.kind, "")
        raise TableError(f"{source}: {kind or str(img.dtype)} values ({img.dtype}); expected DN as integers or floats")
    if img.ndim not in (2, 3):
        raise TableError(f"{source}: expected a 2-D image or an (H, W, C) stack, got shape {img.shape}")
    if 0 in img.shape:
        raise TableError(f"{source}: the image is empty (shape {img.shape})")
    if img.dtype.kind == "f":
        bad = ~np.isfinite(img)
        if bad.any():
            where = tuple(int(i) for i in np.argwhere(bad)[0])
            raise TableError(
                f"{source}: {int(bad.sum())} pixel(s) are NaN or infinite (the first at {where}); "
                "expected finite DN (mask or replace them first)"
            )
    if img.dtype.kind in "if" and (img < 0).any():
        where = tuple(int(i) for i in np.argwhere(img < 0)[0])
        raise TableError(
            f"{source}: {int((img < 0).sum())} pixel(s) are negative (the first, {img[where].item()}, at {where}); "
            "expected raw DN >= 0"
        )
    return img


def within_bits(img: np.ndarray, full_scale: float, source: str) -> None:
    """Refuse an image with values above the sensor's full scale (``2^bits - 1``): another sensor's,
    or a bit depth mistaken."""
    import numpy as np

    top = float(np.max(img))
    if top > full_scale:
        n = int(np.count_nonzero(img > full_scale))
        raise TableError(
            f"{source}: {n} pixel(s) exceed the calibration's full scale of {full_scale:g} DN (largest {top:g}); "
            "is this image from another sensor or bit depth?"
        )


def require_spread(values: np.ndarray, option: str, column: str) -> None:
    """A term switched on (``option = true``) over a covariate needs the table to record two or more of its
    values: with one, nothing in the data informs the term and it would be fitted from its prior without a
    word.  Raises :class:`~bayescal.errors.TableError` naming the option, the column and the one value."""
    import numpy as np

    distinct = np.unique(np.asarray(values, dtype=float)[np.isfinite(values)])
    if distinct.size < 2:
        held = f"one value ({distinct[0]:g})" if distinct.size else "no value"
        raise TableError(
            f"{option} = true, but the table's '{column}' holds {held}: nothing in the data can inform it; "
            f"record two or more values of '{column}', or switch {option} off",
            column=column,
        )
