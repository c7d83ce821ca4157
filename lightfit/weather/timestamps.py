"""What a weather series' timestamps stand for: instants, or the start, centre or end of averages.

A station logger writes the mean of an interval (TERENO's ``RadiationGlobal_Avg10min``) under one
timestamp, usually the interval's end. The geometry of a 10-minute mean taken at its end-stamp is
five minutes late: the sun's elevation moves up to ≈ 0.8° in that time (April, Selhausen), which
at a sun 5° up is ≈ 15 % in sin β, the clearness index and the beam the split puts on the canopy.
The solar geometry that represents an interval mean is the geometry at the interval's centre
(pvlib's guidance for interval-averaged data; to second order in the interval, the mean of sin β
over the interval is sin β at its centre). This module is the one home of that convention: every
series carries a :class:`Timestamps` in ``attrs["timestamps"]`` (absent: instants),
:func:`lightfit.weather.add_solar` evaluates the sun at :meth:`Timestamps.centres`, and
:func:`lightfit.weather.resample` keeps averages aligned with their stamps.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import pandas as pd

from lightfit.errors import InputError

#: How a timestamp relates to the value it labels.
LABELS = ("instant", "start", "center", "end")


@dataclass(frozen=True)
class Timestamps:
    """The meaning of a series' timestamps.

    Attributes:
        label: ``"instant"`` (values at the stamp: a model or a reconstruction), or ``"start"``,
            ``"center"``, ``"end"``: each value is the mean over ``interval`` that the stamp
            starts, centres or ends.
        interval: the averaging interval (``None`` for instants), e.g. ``pd.Timedelta("10min")``.
    """

    label: str = "instant"
    interval: pd.Timedelta | None = None

    def __post_init__(self):
        if self.label not in LABELS:
            raise InputError(f"time label {self.label!r}", column="time_label", expected=" / ".join(LABELS))
        if (self.label == "instant") != (self.interval is None):
            raise InputError(
                f"time label {self.label!r} with averaging interval {self.interval}",
                column="averaging_interval",
                expected="no interval for instants, a positive one for averages",
            )
        if self.interval is not None:
            iv = pd.Timedelta(self.interval)
            if pd.isna(iv) or iv <= pd.Timedelta(0):  # NaT ('nan', 'NaT') compares False: every mean at one step
                raise InputError(f"averaging interval {self.interval}", column="averaging_interval", expected="> 0")
            object.__setattr__(self, "interval", iv)

    @property
    def centre_offset(self) -> pd.Timedelta:
        """Stamp → centre of what it labels: −interval/2 for end-stamps, +interval/2 for starts."""
        if self.label == "end":
            return -self.interval / 2
        if self.label == "start":
            return self.interval / 2
        return pd.Timedelta(0)

    def centres(self, index: pd.DatetimeIndex) -> pd.DatetimeIndex:
        """The instants each stamp's value represents (where the sun's position is taken)."""
        return index + self.centre_offset

    def bounds(self, index: pd.DatetimeIndex) -> tuple[pd.DatetimeIndex, pd.DatetimeIndex] | None:
        """Start and end of the interval each stamp's mean covers (CF ``time_bnds``); None for instants."""
        if self.interval is None:
            return None
        c = self.centres(index)
        return c - self.interval / 2, c + self.interval / 2

    def describe(self) -> str:
        """E.g. ``"ends of 10-min means"`` or ``"instants"``."""
        if self.label == "instant":
            return "instants"
        minutes = self.interval / pd.Timedelta(minutes=1)
        word = {"start": "starts", "center": "centres", "end": "ends"}[self.label]
        return f"{word} of {minutes:g}-min means"

    def metadata(self) -> dict[str, str]:
        """The ``# key: value`` lines of a lightfit CSV (:func:`from_metadata` reads them back)."""
        if self.label == "instant":
            return {"time_label": "instant"}
        return {"time_label": self.label, "averaging_interval": f"{self.interval / pd.Timedelta(minutes=1):g}min"}

    @classmethod
    def from_metadata(cls, meta: dict[str, str], file=None) -> Timestamps:
        """From a lightfit CSV's metadata; a file without ``time_label`` holds instants."""
        label = meta.get("time_label", "instant")
        raw = meta.get("averaging_interval")
        try:  # a bare number ("30", "1800") is a duration in nanoseconds to pandas: means read as instants
            bare = math.isfinite(float(raw))
        except (TypeError, ValueError):
            bare = False
        if bare:
            raise InputError(
                f"metadata line '# averaging_interval: {raw}' has no unit (it would read as {raw} nanoseconds)",
                file=file,
                column="averaging_interval",
                expected="a duration with its unit such as 30min, 10min or 1h",
            )
        try:
            interval = None if raw is None else pd.Timedelta(raw)
        except ValueError as e:
            raise InputError(
                f"metadata line '# averaging_interval: {raw}'", file=file, expected="a duration such as 10min"
            ) from e
        try:
            return cls(label, interval)
        except InputError as e:
            raise e.in_file(file) from None


INSTANTS = Timestamps()


def check_mean_label(label: str) -> str:
    """``label`` if it places a mean's stamp in its interval (a reader's ``time_label``), else an error."""
    if label not in LABELS[1:]:
        raise InputError(f"time_label={label!r}", parameter="time_label", expected="'start', 'center' or 'end'")
    return label


def of(df: pd.DataFrame) -> Timestamps:
    """The series' :class:`Timestamps` (instants where it says nothing)."""
    return df.attrs.get("timestamps", INSTANTS)


def step_of(index: pd.DatetimeIndex) -> pd.Timedelta | None:
    """A series' step: the shortest spacing of its rows (None for fewer than two rows)."""
    if len(index) < 2:
        return None
    return pd.Series(index).diff().min()
