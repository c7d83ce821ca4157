"""What lightfit's figures share: the check of a figure's file name that a user chooses (``field
--preview``, ``weather show --plot``; the format comes from the suffix, as matplotlib reads it) and
the local-time axis."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pandas as pd

from lightfit.errors import InputError

#: Suffixes matplotlib writes without a display through lightfit's dependencies (Pillow for the
#: raster formats beyond PNG): its own list less pgf (needs LaTeX) and the raw buffers.
FORMATS = ("png", "pdf", "svg", "svgz", "eps", "ps", "jpg", "jpeg", "tif", "tiff", "webp", "gif", "avif")


def figure_format(path: str | Path) -> str:
    """The image format a file name asks for (:data:`FORMATS`), or :class:`InputError` naming
    the file. Callers check before the work that the figure shows, so that a typo costs nothing."""
    path = Path(path)
    fmt = path.suffix.lower().lstrip(".")
    if fmt not in FORMATS:
        raise InputError(
            f"unknown image format {path.suffix!r}" if fmt else "no image format in the file name",
            file=path,
            expected="a file name ending in " + ", ".join(f".{k}" for k in FORMATS),
        )
    return fmt


_SUPERSCRIPT = str.maketrans("-0123456789", "⁻⁰¹²³⁴⁵⁶⁷⁸⁹")


def unit_label(units: str) -> str:
    """A UDUNITS string of the results schema as lightfit's figures write units: ``umol m-2 s-1``
    as ``µmol m⁻² s⁻¹``, ``mol m-2 s-1`` as ``mol m⁻² s⁻¹``; ``"1"`` (CF's dimensionless) as
    ``dimensionless``."""
    if units.strip() == "1":
        return "dimensionless"
    words = []
    for word in units.split():
        m = re.fullmatch(r"([A-Za-z]+?)(-?\d+)?", word)
        if m is None:  # a word that is no unit with a power: as given
            words.append(word)
            continue
        base = "µ" + m[1][1:] if m[1].startswith("u") and m[1][1:] in ("mol", "m", "g", "s") else m[1]
        words.append(base + (m[2] or "").translate(_SUPERSCRIPT))
    return " ".join(words)


def date_span(local) -> str:
    """The local date(s) of the times ``local`` (already in the site's zone) as a time axis names
    them: ``2016-04-20``, or ``2016-04-20 to 2016-04-21`` over several; ``""`` without times. The
    clock alone names no day."""
    days = sorted({f"{x:%Y-%m-%d}" for x in local})
    return " to ".join(dict.fromkeys(days[:1] + days[-1:]))


def clock_axis(ax, tz: str) -> None:
    """Ticks of a time axis drawn with aware instants, placed and labelled ``HH:MM`` in ``tz``;
    where the axis, as drawn so far, spans more than a day (several dates), ticks at midnight read
    the date (``21 Apr``) and the others ``HH:MM``: a clock alone repeats every day, and daily ticks
    all read ``00:00``."""
    import matplotlib.dates as mdates

    lo, hi = ax.get_xlim()  # days
    locator = mdates.AutoDateLocator(tz=tz)
    ax.xaxis.set_major_locator(locator)
    if hi - lo <= 1:
        ax.xaxis.set_major_formatter(mdates.DateFormatter("%H:%M", tz=tz))
        return
    dated = mdates.ConciseDateFormatter(locator, tz=tz, show_offset=False)
    dated.formats = ["%Y", "%b", "%d %b", "%H:%M", "%H:%M", "%S.%f"]
    dated.zero_formats = ["", "%Y", "%d %b", "%d %b", "%H:%M", "%H:%M"]
    ax.xaxis.set_major_formatter(dated)


def day_breaks(t: pd.DatetimeIndex) -> pd.DatetimeIndex:
    """The middle of each gap in the instants ``t`` longer than three of its median steps: the
    nights between the dates of a run over several days (``--date`` twice), where a line drawn
    from one day's last step to the next day's first would invent the hours between."""
    t = pd.DatetimeIndex(t)
    if len(t) < 3:
        return t[:0]
    dt = t[1:] - t[:-1]
    at = np.flatnonzero(dt > 3 * dt.median())
    return t[at] + dt[at] / 2


def gapped(t: pd.DatetimeIndex, *ys) -> tuple:
    """``t`` and each series of ``ys`` with a masked point at every :func:`day_breaks` instant, so
    that a line or a ``fill_between`` band stops there; as given where there is no gap."""
    t, breaks = pd.DatetimeIndex(t), day_breaks(t)
    if breaks.empty:
        return (t, *ys)
    order = np.argsort(np.r_[np.arange(len(t)), np.searchsorted(t, breaks) - 0.5])
    nan = np.full(len(breaks), np.nan)
    return (t.append(breaks)[order], *(np.ma.masked_invalid(np.r_[np.asarray(y, float), nan][order]) for y in ys))
