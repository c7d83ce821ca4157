"""Errors for bad user input, each naming where the problem is and what was expected."""

from __future__ import annotations

import math
from pathlib import Path


class InputError(ValueError):
    """Bad input data or parameter.

    The message always starts with the file (or parameter) it concerns, then the row
    and column where known, then what was found and what was expected, so that a user can
    fix the input without reading lightfit's source. ``column`` names a column (or metadata
    key) of a file or table, ``parameter`` a function's argument or an option; either is
    :attr:`column` to code that maps errors to command-line options (:mod:`lightfit.cli.common`).
    """

    def __init__(
        self,
        problem: str,
        *,
        file: str | Path | None = None,
        row: int | None = None,
        column: str | None = None,
        expected: str | None = None,
        parameter: str | None = None,
    ):
        self.problem, self.file, self.row, self.expected = problem, file, row, expected
        self.parameter = parameter
        self.column = column if parameter is None else parameter
        where = []
        if file is not None:
            where.append(str(file))
        if row is not None:
            where.append(f"line {row}")
        if parameter is not None:
            where.append(f"parameter {parameter!r}")
        elif column is not None:
            where.append(f"column {column!r}")
        msg = (", ".join(where) + ": " if where else "") + problem
        if expected:
            msg += f" (expected {expected})"
        super().__init__(msg)

    def in_file(self, file: str | Path) -> InputError:
        """This error restated for the file its value came from (raised by a check that saw
        only the value, e.g. a camera's or a parameter's own): the name is then the file's
        (a column, attribute or key), so it is said as a column."""
        return InputError(self.problem, file=file, row=self.row, column=self.column, expected=self.expected)


def listed(items, n: int = 5) -> str:
    """The first ``n`` of ``items`` for a message, comma-separated, with "…" where there are more."""
    items = list(items)
    return ", ".join(map(str, items[:n])) + (", …" if len(items) > n else "")


def is_real(value) -> bool:
    """A real number (Python or numpy), not a bool."""
    from numbers import Real

    return isinstance(value, Real) and not isinstance(value, bool)


def check_real(
    value,
    name: str,
    lo: float = -math.inf,
    hi: float = math.inf,
    *,
    expected: str,
    parameter: str | None = None,
    open_lo: bool = False,
    open_hi: bool = False,
) -> float:
    """``value`` as a float if it is a finite real number (:func:`is_real`: numpy's float32 too,
    not a bool) in [``lo``, ``hi``] (without ``lo`` where ``open_lo``, ``hi`` where ``open_hi``),
    else :class:`InputError` ``name=value`` naming ``parameter`` (default ``name``) and saying
    ``expected``. The one check of a number's type and range: copies of it testing
    ``isinstance(v, (int, float))`` refused numpy's float32."""
    try:
        ok = is_real(value) and math.isfinite(value)
    except OverflowError:  # an int beyond a float's range
        ok = False
    ok = ok and (lo < value if open_lo else lo <= value) and (value < hi if open_hi else value <= hi)
    if not ok:
        raise InputError(f"{name}={value!r}", parameter=parameter or name, expected=expected)
    return float(value)


def check_fraction(value, name: str, *, parameter: str | None = None) -> float:
    """``value`` as a float in [0, 1] (:func:`check_real`): an albedo, a reflectance or
    transmittance, a leaf surface parameter."""
    return check_real(value, name, 0.0, 1.0, parameter=parameter, expected="a number in [0, 1]")


def check_integer(
    value,
    name: str,
    low: int,
    *,
    high: int | None = None,
    column: str | None = None,
    why: str = "",
    expected: str | None = None,
) -> int:
    """``value`` as an ``int`` if it is an integer (Python or numpy; not a bool) ≥ ``low`` (and
    < ``high`` where given), else :class:`InputError` ``name=value`` naming ``column`` (default
    ``name``) and saying ``expected`` (default the range, with ``why`` added)."""
    from numbers import Integral

    if (
        isinstance(value, bool)
        or not isinstance(value, Integral)
        or value < low
        or (high is not None and value >= high)
    ):
        rng = f"≥ {low}" if high is None else f"in [{low}, {high})"
        expected = expected or f"an integer {rng}" + (f" ({why})" if why else "")
        raise InputError(f"{name}={value!r}", parameter=column or name, expected=expected)
    return int(value)


def parse_date(value, name: str):
    """A calendar date from ``YYYY-MM-DD`` text or a date/datetime; anything else raises.

    Stricter than ``pandas.Timestamp``, which reads "April" as 0001-04-01.
    """
    import datetime as dt

    if isinstance(value, dt.datetime):
        return value.date()
    if isinstance(value, dt.date):
        return value
    try:
        return dt.date.fromisoformat(str(value).strip())
    except ValueError as err:
        raise InputError(f"{name} {value!r} is not a date", parameter=name, expected="YYYY-MM-DD") from err
