"""Weather: TERENO and CPlantBox readers, units, sun position, direct/diffuse split.

Every reader returns the docs/design.md §3 contract: a DataFrame indexed by tz-aware UTC timestamps
with unit-named columns (:data:`~lightfit.weather.series.COLUMNS`) and provenance in
``attrs``. Typical use::

    from lightfit import weather
    df = weather.load("2016-04-20")                    # bundled default for the day
    df = weather.read_weather("SE_EC_001.csv")         # a real TERENO export
    df = weather.add_solar(df)                         # sun angles, DNI/DHI
    df30 = weather.resample(df, "30min")
"""

from lightfit.weather.bundled import BUNDLED, bundled_path, load
from lightfit.weather.readers import (
    read_cplantbox_day,
    read_lightfit_csv,
    read_tereno,
    read_weather,
    sniff_format,
    write_lightfit_csv,
)
from lightfit.weather.reconstruct import Anchor, DayAssumptions, reconstruct_day
from lightfit.weather.series import BOUNDS, COLUMNS, check_and_repair, resample, window
from lightfit.weather.solar import SELHAUSEN, Site, add_solar, solar_position, split_direct_diffuse

__all__ = [
    "Anchor",
    "BOUNDS",
    "BUNDLED",
    "COLUMNS",
    "DayAssumptions",
    "SELHAUSEN",
    "Site",
    "add_solar",
    "bundled_path",
    "check_and_repair",
    "load",
    "read_cplantbox_day",
    "read_lightfit_csv",
    "read_tereno",
    "read_weather",
    "reconstruct_day",
    "resample",
    "sniff_format",
    "window",
    "solar_position",
    "split_direct_diffuse",
    "write_lightfit_csv",
]
