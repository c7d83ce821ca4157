"""Weather: TERENO and CPlantBox readers, units, sun position, direct/diffuse split.

Every reader returns the docs/design.md §3 contract: a DataFrame indexed by tz-aware UTC timestamps
with unit-named columns (:data:`~lightfit.weather.series.COLUMNS`) and provenance in
``attrs``. Typical use::

    from lightfit import weather
    df = weather.load("2016-04-20")                    # bundled default for the day
    df = weather.read_weather("SE_EC_001.csv", provenance="measured")  # a real TERENO export
    df = weather.read_source("selhausen-cplantbox-day", date="2016-04-27")  # bundled name or file
    df = weather.add_solar(df)                         # sun angles, DNI/DHI
    df30 = weather.resample(df, "30min")
"""

from lightfit.weather.bundled import BUNDLED, bundled_path, is_undated, load, read_source, require_date, source_path
from lightfit.weather.readers import (
    read_cplantbox_day,
    read_lightfit_csv,
    read_tereno,
    read_weather,
    sniff_format,
    write_lightfit_csv,
)
from lightfit.weather.reconstruct import Anchor, DayAssumptions, reconstruct_day
from lightfit.weather.series import BOUNDS, COLUMNS, check_and_repair, month_before_mean_tair_c, resample, window
from lightfit.weather.site import SELHAUSEN, SITES, Site, Window, site_named
from lightfit.weather.solar import add_solar, solar_position, split_direct_diffuse, split_from_diffuse

__all__ = [
    "Anchor",
    "BOUNDS",
    "BUNDLED",
    "COLUMNS",
    "DayAssumptions",
    "SELHAUSEN",
    "SITES",
    "Site",
    "Window",
    "add_solar",
    "bundled_path",
    "check_and_repair",
    "is_undated",
    "load",
    "month_before_mean_tair_c",
    "read_cplantbox_day",
    "read_lightfit_csv",
    "read_source",
    "read_tereno",
    "read_weather",
    "reconstruct_day",
    "require_date",
    "resample",
    "site_named",
    "sniff_format",
    "source_path",
    "window",
    "solar_position",
    "split_direct_diffuse",
    "split_from_diffuse",
    "write_lightfit_csv",
]
