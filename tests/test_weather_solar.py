"""Sun position against the NOAA solar calculator formulas (independent of pvlib) and split closure."""

import math

import numpy as np
import pandas as pd
import pytest

from lightfit.errors import InputError
from lightfit.weather import SELHAUSEN, solar_position, split_direct_diffuse


def noaa_apparent_elevation_deg(ts: pd.Timestamp, lat: float, lon: float) -> float:
    """NOAA Global Monitoring Division solar calculator (spreadsheet formulas, Meeus-based)."""
    ts = ts.tz_convert("UTC")
    jd = ts.to_julian_date()
    jc = (jd - 2451545.0) / 36525.0
    L = (280.46646 + jc * (36000.76983 + jc * 0.0003032)) % 360
    M = 357.52911 + jc * (35999.05029 - 0.0001537 * jc)
    e = 0.016708634 - jc * (0.000042037 + 0.0000001267 * jc)
    r = math.radians
    C = (
        math.sin(r(M)) * (1.914602 - jc * (0.004817 + 0.000014 * jc))
        + math.sin(r(2 * M)) * (0.019993 - 0.000101 * jc)
        + math.sin(r(3 * M)) * 0.000289
    )
    app_long = L + C - 0.00569 - 0.00478 * math.sin(r(125.04 - 1934.136 * jc))
    mean_obl = 23 + (26 + (21.448 - jc * (46.815 + jc * (0.00059 - jc * 0.001813))) / 60) / 60
    obl = mean_obl + 0.00256 * math.cos(r(125.04 - 1934.136 * jc))
    decl = math.degrees(math.asin(math.sin(r(obl)) * math.sin(r(app_long))))
    y = math.tan(r(obl / 2)) ** 2
    eot = 4 * math.degrees(
        y * math.sin(2 * r(L))
        - 2 * e * math.sin(r(M))
        + 4 * e * y * math.sin(r(M)) * math.cos(2 * r(L))
        - 0.5 * y * y * math.sin(4 * r(L))
        - 1.25 * e * e * math.sin(2 * r(M))
    )
    minutes = ts.hour * 60 + ts.minute + ts.second / 60
    tst = (minutes + eot + 4 * lon) % 1440
    ha = tst / 4 - 180 if tst / 4 >= 0 else tst / 4 + 180
    cosz = math.sin(r(lat)) * math.sin(r(decl)) + math.cos(r(lat)) * math.cos(r(decl)) * math.cos(r(ha))
    el = 90 - math.degrees(math.acos(cosz))
    t = math.tan(r(el))
    refr = (58.1 / t - 0.07 / t**3 + 0.000086 / t**5) / 3600 if 5 < el < 85 else 0.0
    return el + refr


@pytest.mark.parametrize(
    "utc", ["2016-04-20 09:00", "2016-04-20 11:30", "2016-04-20 11:13:48", "2016-04-20 15:00", "2016-06-23 11:30"]
)
def test_elevation_matches_noaa(utc):
    t = pd.DatetimeIndex([pd.Timestamp(utc, tz="UTC")])
    ours = solar_position(t, SELHAUSEN)["sun_elevation_deg"].iloc[0]
    assert ours == pytest.approx(
        noaa_apparent_elevation_deg(t[0], SELHAUSEN.latitude_deg, SELHAUSEN.longitude_deg), abs=0.05
    )


def test_noon_elevation_is_colatitude_plus_declination():
    t = pd.date_range("2016-04-20 10:30", "2016-04-20 12:30", freq="1min", tz="UTC")
    el = solar_position(t)["sun_elevation_deg"]
    # Declination on 2016-04-20 ≈ +11.6° (almanac): max elevation ≈ 90 − 50.865 + 11.6 + refraction ≈ 50.75 … 50.95.
    assert 50.7 < el.max() < 51.0
    noon = el.idxmax()
    # Solar noon at 6.447° E: 12:00 − 25.8 min (longitude) − ~1.2 min (equation of time) ≈ 11:33 UTC.
    assert abs((noon - pd.Timestamp("2016-04-20 11:33", tz="UTC")).total_seconds()) <= 120


def test_naive_times_rejected():
    with pytest.raises(InputError, match="timezone-naive"):
        solar_position(pd.DatetimeIndex([pd.Timestamp("2016-04-20 12:00")]))


@pytest.mark.parametrize("model", ["erbs", "boland"])
def test_split_closure_and_night(model):
    t = pd.date_range("2016-04-20 00:00", "2016-04-20 23:50", freq="10min", tz="UTC")
    el = solar_position(t)["sun_elevation_deg"]
    # Clearness index 0.75 (a clear day): GHI = 0.75 × 1361 W m-2 × sin(elevation).
    ghi = pd.Series(np.clip(0.75 * 1361 * np.sin(np.radians(el)), 0, None), index=t)
    s = split_direct_diffuse(ghi, el, model)
    closure = s["dni_w_m2"] * np.sin(np.radians(el.clip(lower=0))) + s["dhi_w_m2"]
    assert np.allclose(closure, ghi, atol=1e-6)
    assert (s >= 0).all().all()
    assert (s.loc[el <= 0, "dni_w_m2"] == 0).all()
    # A clear sky at high sun is mostly direct; an overcast one (low GHI) mostly diffuse.
    noon = el.idxmax()
    assert s.loc[noon, "dhi_w_m2"] < 0.35 * ghi[noon]
    dull = split_direct_diffuse(ghi * 0.2, el, model)
    assert dull.loc[noon, "dhi_w_m2"] > 0.9 * 0.2 * ghi[noon]


def test_unknown_split_model():
    t = pd.DatetimeIndex([pd.Timestamp("2016-04-20 12:00", tz="UTC")])
    with pytest.raises(InputError, match="split model"):
        split_direct_diffuse(pd.Series([500.0], index=t), pd.Series([50.0], index=t), "magic")
