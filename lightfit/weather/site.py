"""Where and when a run happens: the field :class:`Site` and the diurnal :class:`Window`.

One home for both: solar geometry (:func:`lightfit.weather.solar.solar_position`) reads the
site's coordinates, and a run's window reads its start in the site's local time zone
(:meth:`Window.bounds_utc`). Named sites are in :data:`SITES`.
"""

from __future__ import annotations

import datetime as dt
import re
from dataclasses import dataclass
from zoneinfo import ZoneInfo, ZoneInfoNotFoundError

import pandas as pd

from lightfit.errors import InputError, check_real, parse_date


def check_timezone(name: str, column: str = "timezone") -> str:
    """``name`` if it is an IANA time zone (``Europe/Berlin``, ``UTC``, ``Etc/GMT-1``), else :class:`InputError`."""
    try:
        ZoneInfo(str(name))
    except (ZoneInfoNotFoundError, ValueError):
        raise InputError(
            f"{column}={name!r} is not a time zone",
            parameter=column,
            expected="an IANA name such as Europe/Berlin or UTC",
        ) from None
    return str(name)


def localize(stamps, timezone: str, *, file=None, row=None, column: str = "time", parameter: str | None = None):
    """``stamps`` (a naive :class:`pandas.Timestamp` or ``DatetimeIndex``) read as local times in
    ``timezone``; a time that a clock change skips or repeats there is an :class:`InputError`
    naming ``file``/``row``/``column`` (or the ``parameter`` the times came from), not pandas' traceback."""
    try:
        return stamps.tz_localize(timezone, ambiguous="raise", nonexistent="raise")
    except ValueError as e:  # pandas' AmbiguousTimeError / NonExistentTimeError, whose advice is for coders
        error = e
    naive = pd.DatetimeIndex([stamps] if isinstance(stamps, pd.Timestamp) else stamps)
    bad = naive[naive.tz_localize(timezone, ambiguous="NaT", nonexistent="NaT").isna() & naive.notna()]
    if not len(bad):  # not a clock change
        raise error
    first = bad[0].to_pydatetime()
    zone = ZoneInfo(timezone)
    twice = first.replace(tzinfo=zone).astimezone(dt.UTC).astimezone(zone).replace(tzinfo=None) == first
    raise InputError(
        f"local time {first:%Y-%m-%d %H:%M} "
        + ("happens twice (the clocks go back)" if twice else "does not exist (the clocks go forward)")
        + f" in {timezone}"
        + (f"; {len(bad)} such times" if len(bad) > 1 else ""),
        file=file,
        row=row,
        **({"column": column} if parameter is None else {"parameter": parameter}),
        expected="times that exist once in that zone (not inside a daylight-saving change), or times with a UTC offset",
    )


@dataclass(frozen=True)
class Site:
    """A field site.

    Attributes:
        latitude_deg: degrees north (−90 … 90).
        longitude_deg: degrees east (−180 … 180).
        altitude_m: metres above sea level (Selhausen: 103 m, FLUXNET DE-RuS metadata; the
            reference paper prints 203 m — the difference changes sun angles by < 0.001°).
        name: label for plots and metadata.
        timezone: IANA time zone of the site's local civil time, in which a run's window
            starts (:class:`Window`) and results are labelled.
    """

    latitude_deg: float = 50.865
    longitude_deg: float = 6.447
    altitude_m: float = 103.0
    name: str = "Selhausen"
    timezone: str = "Europe/Berlin"

    def __post_init__(self):
        for attr, low, high, what in (
            ("latitude_deg", -90.0, 90.0, "degrees north, −90 … 90"),
            ("longitude_deg", -180.0, 180.0, "degrees east, −180 … 180"),
            # Dead Sea shore to above the highest fields (pvlib's pressure model needs a sane value).
            ("altitude_m", -500.0, 9000.0, "metres above sea level, −500 … 9000"),
        ):
            # stored as a float: numpy's scalars pass the check but not json.dumps of a run's settings
            object.__setattr__(self, attr, check_real(getattr(self, attr), attr, low, high, expected=what))
        check_timezone(self.timezone)

    def attrs(self) -> dict[str, str | float]:
        """The site as netCDF attributes (``site``, ``site_latitude_deg`` …): what :meth:`from_attrs` reads."""
        return {
            "site": self.name,
            "site_latitude_deg": self.latitude_deg,
            "site_longitude_deg": self.longitude_deg,
            "site_altitude_m": self.altitude_m,
            "site_timezone": self.timezone,
        }

    @staticmethod
    def from_attrs(attrs) -> Site:
        """The site a results file records (:meth:`attrs`); Selhausen's for files written before
        sites were options (they all ran there), key by key."""
        base = Site()
        return Site(
            latitude_deg=float(attrs.get("site_latitude_deg", base.latitude_deg)),
            longitude_deg=float(attrs.get("site_longitude_deg", base.longitude_deg)),
            altitude_m=float(attrs.get("site_altitude_m", base.altitude_m)),
            name=str(attrs.get("site", base.name)),
            timezone=str(attrs.get("site_timezone", base.timezone)),
        )


#: Selhausen field minirhizotron facility (TERENO Rur catchment), the reference paper's site:
#: 50.865 N, 6.447 E (Baker et al. 2025, in silico Plants diaf018; Cai et al. 2016, Vadose Zone J.
#: 15), 103 m (FLUXNET DE-RuS), local civil time CET/CEST.
SELHAUSEN = Site()

#: Named sites for ``--site``.
SITES: dict[str, Site] = {"selhausen": SELHAUSEN}


def zone_label(tz: str) -> str:
    """A time zone as people write it: ``Etc/GMT-10`` (POSIX signs, what ``UTC+10`` is stored as) as
    ``UTC+10``; an IANA city name as it is."""
    m = re.fullmatch(r"Etc/GMT([+-])(\d+)", tz)
    if m is None:
        return tz
    return offset_label(pd.Timedelta(hours=int(m[2]) * (1 if m[1] == "-" else -1)))


def local_clock(t: pd.DatetimeIndex, tz: str) -> pd.Index:
    """``HH:MM`` in ``tz`` for the aware instants ``t`` (in time order); where a local time repeats
    (the clock falls back inside the run) each with its offset, ``HH:MM UTC+11``, so that the repeated
    hour is told apart. Days on either side of a change, or a clock springing forward, keep ``HH:MM``."""
    local = t.tz_convert(tz)
    clock = local.strftime("%H:%M")
    wall = local.tz_localize(None)
    if not (wall.duplicated(keep=False) & ~t.duplicated(keep=False)).any() and (
        wall.is_monotonic_increasing or not t.is_monotonic_increasing
    ):  # no local time repeated by distinct instants, none out of order (days across a change are fine)
        return clock
    return pd.Index([f"{c} {offset_label(x.utcoffset())}" for c, x in zip(clock, local, strict=True)])


def offset_label(offset: pd.Timedelta) -> str:
    """A UTC offset as ``--timezone`` writes it: ``UTC+10``, ``UTC-5`` (ASCII minus), ``UTC`` for none;
    a zone's part-hour offset as ``UTC+10:30``, which ``--timezone`` does not take (whole hours only:
    give such a site its IANA name, e.g. Australia/Adelaide)."""
    minutes = round(offset.total_seconds() / 60)
    if minutes == 0:
        return "UTC"
    sign, minutes = ("+" if minutes > 0 else "-"), abs(minutes)
    return f"UTC{sign}{minutes // 60}" + (f":{minutes % 60:02d}" if minutes % 60 else "")


def site_named(name: str) -> Site:
    """The named site (case-insensitive), else :class:`InputError` listing :data:`SITES`."""
    key = str(name).strip().lower()
    if key not in SITES:
        raise InputError(f"no site named {name!r}", parameter="site", expected=" or ".join(SITES))
    return SITES[key]


#: The shortest step a :class:`Window` takes (no weather series is finer).
MIN_STEP = pd.Timedelta(minutes=1)

_HHMM = re.compile(r"^([01]?\d|2[0-3]):([0-5]\d)$")


@dataclass(frozen=True)
class Window:
    """A diurnal run window: ``start`` local time, ``hours`` long, one step every ``step``.

    Steps are ``start, start + step, …, start + hours`` inclusive; the defaults are the reference
    paper's 05:00–19:00 local in 30-minute steps (29 steps).

    Attributes:
        start: local clock time ``HH:MM`` (in the site's time zone).
        hours: window length, hours (> 0, ≤ 24).
        step: time step, a pandas offset with its unit such as ``30min`` or ``1h`` (≥ 1 min,
            ≤ ``hours``; a bare number is refused: pandas reads ``"30"`` as 30 ns).
    """

    start: str = "05:00"
    hours: float = 14.0
    step: str = "30min"

    def __post_init__(self):
        if not _HHMM.match(str(self.start)):
            raise InputError(
                f"start={self.start!r}", parameter="window.start", expected="a local clock time HH:MM, e.g. 05:00"
            )
        h = check_real(self.hours, "hours", 0, 24, open_lo=True, expected="a window length in hours, 0 < hours ≤ 24")
        object.__setattr__(self, "hours", h)
        try:
            # a bare number has no unit: pandas reads "30" (or 30) as 30 ns, and a day of such steps
            # ended in a MemoryError building the run's steps instead of this message
            step = None if re.fullmatch(r"\s*[-+]?[\d.]+\s*", str(self.step)) else pd.Timedelta(self.step)
        except (ValueError, TypeError):
            step = None
        # NaT ("", "nan", None) compares False with anything: refused here, not as an unnamed 'freq' later
        if step is None or pd.isna(step) or step < MIN_STEP or step > pd.Timedelta(hours=h):
            raise InputError(
                f"step={self.step!r}",
                parameter="step",
                expected=f"a time step with its unit, from 1min to the window ({h:g} h), e.g. 30min",
            )

    @property
    def n_steps(self) -> int:
        """Steps in each day's window, both ends counted (29 for the defaults)."""
        return int(pd.Timedelta(hours=self.hours) // pd.Timedelta(self.step)) + 1

    def start_local(self, date: str | dt.date, timezone: str) -> pd.Timestamp:
        """The window's first step on ``date`` as a tz-aware timestamp in ``timezone``."""
        day = parse_date(date, "date")
        return localize(pd.Timestamp(f"{day.isoformat()} {self.start}"), timezone, parameter="start_time")

    def bounds_utc(self, date: str | dt.date, timezone: str) -> tuple[pd.Timestamp, pd.Timestamp]:
        """First and last step on ``date`` (local ``start`` in ``timezone``), in UTC."""
        t0 = self.start_local(date, timezone).tz_convert("UTC")
        return t0, t0 + pd.Timedelta(hours=self.hours)

    def describe(self, date: str | dt.date, timezone: str) -> str:
        """``2016-04-20 05:00 + 14 h (Europe/Berlin), 30min steps``: for messages and metadata."""
        return f"{parse_date(date, 'date')} {self.start} + {self.hours:g} h ({timezone}), {self.step} steps"


__all__ = [
    "SELHAUSEN",
    "SITES",
    "Site",
    "Window",
    "check_timezone",
    "local_clock",
    "offset_label",
    "localize",
    "site_named",
    "zone_label",
]
