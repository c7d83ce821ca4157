"""Sun position against the NOAA solar calculator formulas (independent of pvlib) and split closure."""

import math
import warnings

import numpy as np
import pandas as pd
import pvlib
import pytest

from lightfit.errors import InputError
from lightfit.weather import SELHAUSEN, Site, add_solar, read_tereno, resample, solar_position, split_direct_diffuse
from lightfit.weather.bundled import DATA_DIR
from lightfit.weather.solar import pvlib_deprecations_quiet

FIXTURE = DATA_DIR / "fixtures" / "tereno_SE_EC_001_fixture.csv"


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


@pytest.mark.parametrize("model", ["erbs", "boland"])
def test_the_split_takes_the_true_zenith_and_the_beam_the_apparent_sun(model):
    """Erbs and Boland were fitted with the true (unrefracted) zenith, which pvlib asks for: the
    split's DHI is pvlib's at the true zenith (the apparent one gave more diffuse light at a low
    sun), and the rest of GHI comes as beam from the apparent sun, closing exactly on it. The
    reference is pvlib called directly on SPA's true zenith."""
    t = pd.date_range("2016-04-20 03:30", "2016-04-20 19:30", freq="10min", tz="UTC")
    sp = pvlib.solarposition.get_solarposition(t, SELHAUSEN.latitude_deg, SELHAUSEN.longitude_deg, SELHAUSEN.altitude_m)
    ghi = pd.Series(np.clip(0.6 * 1361 * np.sin(np.radians(sp["elevation"])), 0, None) + 20.0, index=t)
    df = add_solar(pd.DataFrame({"ghi_w_m2": ghi}, index=t).assign(air_temperature_c=10.0), split_model=model)
    if model == "erbs":
        want = pvlib.irradiance.erbs(ghi, sp["zenith"], t)["dhi"]
    else:
        want = pvlib.irradiance.boland(ghi, sp["zenith"], t, a_coeff=8.645, b_coeff=0.613)["dhi"]
    day = sp["apparent_elevation"] > 0
    np.testing.assert_allclose(df["dhi_w_m2"][day], want[day], rtol=1e-12)
    np.testing.assert_allclose(df["dhi_w_m2"][~day], ghi[~day], rtol=1e-12)
    sin_app = np.sin(np.radians(sp["apparent_elevation"].clip(lower=0)))
    np.testing.assert_allclose(df["dni_w_m2"] * sin_app + df["dhi_w_m2"], ghi, rtol=1e-12)
    # at a low sun the true zenith matters: the apparent one's DHI is larger, far beyond the tolerance
    low = day & (sp["elevation"] > 3) & (sp["elevation"] < 8)
    apparent = split_direct_diffuse(ghi, sp["apparent_elevation"], model)["dhi_w_m2"]
    assert low.any() and (apparent[low] >= want[low]).all() and (apparent[low] / want[low] - 1).max() > 0.01


def test_unknown_split_model():
    t = pd.DatetimeIndex([pd.Timestamp("2016-04-20 12:00", tz="UTC")])
    with pytest.raises(InputError, match="split model"):
        split_direct_diffuse(pd.Series([500.0], index=t), pd.Series([50.0], index=t), "magic")


def _two_sensor_day(par_per_ghi: float) -> pd.DataFrame:
    """A clear 20 April 2016 (GHI = 0.75 × 1361 W m⁻² × sin β) with a PAR sensor reading
    ``par_per_ghi`` × GHI, and the other columns a forcing needs."""
    t = pd.date_range("2016-04-20 00:00", "2016-04-20 23:30", freq="30min", tz="UTC")
    el = solar_position(t)["sun_elevation_deg"]
    ghi = np.clip(0.75 * 1361 * np.sin(np.radians(el)), 0, None)
    return pd.DataFrame(
        {"ghi_w_m2": ghi, "par_umol_m2_s": par_per_ghi * ghi, "tair_c": 15.0, "rh": 0.6, "pair_kpa": 100.0},
        index=t,
    ).assign(co2_ppm=400.0)


def test_the_canopy_is_lit_with_the_measured_par():
    """With a PAR sensor beside the pyranometer, the light model's horizontal PAR is the
    measured PAR and its diffuse fraction Spitters' from the global radiation's split; before, it
    was 0.50 × 4.57 µmol J⁻¹ × GHI whatever the PAR sensor said (14 % more light at 2.0 µmol J⁻¹)."""
    from lightfit.model.observe import above_canopy_par
    from lightfit.model.scenario import Forcing
    from lightfit.weather import add_solar
    from lightfit.weather.solar import par_diffuse_fraction

    df = _two_sensor_day(2.0)
    dawn = df.index[np.flatnonzero(df["ghi_w_m2"] > 0)[0]]
    df.loc[dawn, "par_umol_m2_s"] = -0.8  # a sensor offset
    w = add_solar(df)
    assert [q for q in w.attrs["qc"] if q["kind"] == "checked"][0]["detail"].startswith("PAR / global radiation 2.000")
    # Resampled, the series is checked again and its source's check replaced, not repeated.
    assert sum(q["kind"] == "checked" for q in resample(w, "60min", "mean").attrs["qc"]) == 1
    f = Forcing.of(w)
    sin_b = np.sin(np.radians(w["sun_elevation_deg"].clip(lower=0).to_numpy()))
    horizontal = f.dni_par * sin_b + f.dhi_par
    lit = (w["ghi_w_m2"] > 0).to_numpy() & (w.index != dawn)
    assert np.allclose(horizontal[lit], w["par_umol_m2_s"][lit], rtol=1e-12)
    kd = (w["dhi_w_m2"] / w["ghi_w_m2"])[lit].to_numpy()
    kd_par = f.dhi_par[lit] / horizontal[lit]
    assert np.allclose(kd_par, par_diffuse_fraction(kd, w["sun_elevation_deg"][lit]), rtol=1e-12)
    assert horizontal[w.index.get_loc(dawn)] == 0.0  # no negative light
    assert (horizontal[~(w["ghi_w_m2"] > 0).to_numpy()] == 0).all()
    assert np.allclose(
        above_canopy_par(f.dni_par, f.dhi_par, w["sun_elevation_deg"].to_numpy())[lit], df["par_umol_m2_s"][lit]
    )


@pytest.mark.parametrize("measured", ["ghi_w_m2", "par_umol_m2_s"])
def test_one_sensor_keeps_the_constant_photon_ratio(measured):
    """Global radiation alone (PAR derived) or PAR alone (global radiation derived): 0.50 ×
    4.57 µmol J⁻¹ (McCree 1972) converts global radiation, and the horizontal PAR is the
    series' PAR."""
    from lightfit.model.observe import above_canopy_par
    from lightfit.model.scenario import Forcing
    from lightfit.weather import add_solar

    w = add_solar(_two_sensor_day(0.5 * 4.57)[[measured, "tair_c", "rh", "pair_kpa", "co2_ppm"]])
    f = Forcing.of(w)
    el = w["sun_elevation_deg"].to_numpy()
    assert np.allclose(above_canopy_par(f.dni_par, f.dhi_par, el), w["par_umol_m2_s"], rtol=1e-12, atol=1e-9)
    assert np.allclose(above_canopy_par(f.dni_par, f.dhi_par, el), 0.5 * 4.57 * w["ghi_w_m2"], rtol=1e-12, atol=1e-9)
    assert not any(q["kind"] == "checked" for q in w.attrs["qc"])


# k_d, sun elevation (°), Spitters et al. (1986) eqs. 9–10 worked by hand:
# [1 + 0.3 (1 − k_d²)] k_d / [1 + (1 − k_d²) sin²β cos³β].
SPITTERS_BY_HAND = [
    (0.15, 39.2, 0.1939875 / (1 + 0.9775 * 0.399461 * 0.465384)),  # clear sky, near the circumsolar term's peak
    (0.15, 15.0, 0.1939875 / (1 + 0.9775 * 0.066987 * 0.901221)),  # clear, low sun
    (0.15, 60.0, 0.1939875 / (1 + 0.9775 * 0.75 * 0.125)),  # clear, high sun
    (0.5, 30.0, 0.5 * 1.225 / (1 + 0.75 * 0.25 * 0.649519)),  # broken cloud
    (1.0, 30.0, 1.0),  # overcast: all diffuse either way
    (0.0, 30.0, 0.0),
]


@pytest.mark.parametrize(("kd", "elevation", "expected"), SPITTERS_BY_HAND)
def test_par_diffuse_fraction_is_spitters(kd, elevation, expected):
    from lightfit.weather.solar import par_diffuse_fraction

    assert par_diffuse_fraction(kd, elevation) == pytest.approx(expected, rel=2e-5)


def test_par_is_more_diffuse_than_global_radiation_and_conserved():
    """Over a grid of skies and suns PAR's diffuse fraction is in [k_d, 1] (the blue sky adds more
    than the circumsolar term removes), and the split keeps the horizontal PAR."""
    from lightfit.model.observe import above_canopy_par
    from lightfit.weather.solar import par_diffuse_fraction, par_direct_diffuse

    kd, el = np.meshgrid(np.linspace(0, 1, 21), np.linspace(0.5, 90, 40))
    f = par_diffuse_fraction(kd, el)
    assert ((f >= kd - 1e-15) & (f <= 1)).all()
    ghi = 800.0 * np.sin(np.radians(el))
    dni, dhi = (1 - kd) * ghi / np.sin(np.radians(el)), kd * ghi
    dni_par, dhi_par = par_direct_diffuse(dni, dhi, el, 2.0 * ghi)
    assert (dni_par >= 0).all() and (dhi_par >= 0).all()
    assert np.allclose(above_canopy_par(dni_par, dhi_par, el), 2.0 * ghi, rtol=1e-12)


@pytest.mark.parametrize("ratio", [0.45, 4.57e-3, 4.57])  # PAR in W m⁻², in mmol, all of it photons of PAR
def test_a_par_sensor_in_other_units_is_refused(ratio):
    from lightfit.weather import add_solar

    with pytest.raises(InputError, match=r"par_umol_m2_s/ghi_w_m2.*1\.5–3 µmol J⁻¹"):
        add_solar(_two_sensor_day(ratio))
    day = _two_sensor_day(ratio)
    day.attrs["source"] = "station.csv"  # a series read from a file: the error names it
    with pytest.raises(InputError, match=r"^station\.csv, column 'par_umol_m2_s/ghi_w_m2'"):
        add_solar(day)


def test_missing_par_where_there_is_light_is_refused():
    from lightfit.weather.solar import par_direct_diffuse

    with pytest.raises(InputError, match="par_umol_m2_s.*step 1"):
        par_direct_diffuse([0.0, 500.0], [0.0, 100.0], [-5.0, 40.0], [0.0, np.nan])
    # Missing at night is no light either way.
    dni, dhi = par_direct_diffuse([0.0, 500.0], [0.0, 100.0], [-5.0, 40.0], [np.nan, 800.0])
    assert dni[0] == dhi[0] == 0.0 and np.isfinite([dni, dhi]).all()


@pytest.mark.parametrize(("freq", "a", "b"), [("10min", 8.645, 0.613), ("30min", 8.645, 0.613), ("1h", 7.997, 0.586)])
def test_boland_takes_the_fit_of_the_series_interval(freq, a, b):
    # Boland, Scott & Luther (2001), Environmetrics 12:103: the logistic diffuse fraction
    # 1 / (1 + exp(a (k_t − b))) with (a, b) fitted per averaging interval (15 min, 1 h).
    t = pd.date_range("2016-04-20 11:00", periods=3, freq=freq, tz="UTC")
    el = solar_position(t)["sun_elevation_deg"]
    ghi = pd.Series(600.0, index=t)
    s = split_direct_diffuse(ghi, el, "boland")
    extra = pvlib.irradiance.get_extra_radiation(t).to_numpy()
    kt = ghi.to_numpy() / (extra * np.sin(np.radians(el.to_numpy())))
    assert np.allclose(s["dhi_w_m2"] / ghi, 1.0 / (1.0 + np.exp(a * (kt - b))), rtol=1e-9)


def test_missing_light_is_refused_not_taken_as_darkness():
    t = pd.date_range("2016-04-20 10:00", periods=4, freq="30min", tz="UTC")
    df = pd.DataFrame({"ghi_w_m2": [500.0, np.nan, 520.0, 510.0], "tair_c": 15.0}, index=t)
    with pytest.raises(InputError, match=r"column 'ghi_w_m2'.*1 missing value.*2016-04-20 10:30"):
        add_solar(df)


def test_horizontal_irradiance_is_the_cosine_law_with_no_beam_below_the_horizon():
    """DNI sin⁺β + DHI (Duffie & Beckman 2013, eq. 2.15.1 for a horizontal surface), by hand: 700 W m⁻²
    of beam at β = 30° adds 350 to the 100 of sky; at β = −10° the beam is behind the horizon and adds
    nothing, not |sin β| × 700 = 121.6 (a mutation audit: the absolute value for the cut at 0 survived,
    every caller's beam being 0 there)."""
    from lightfit.weather.solar import horizontal_irradiance

    got = horizontal_irradiance(np.array([700.0, 700.0, 700.0]), np.array([100.0] * 3), np.array([30.0, -10.0, 0.0]))
    np.testing.assert_allclose(got, [450.0, 100.0, 100.0], rtol=1e-12, atol=1e-12)


def test_beam_normal_inverts_the_cosine_law_and_is_dark_with_the_sun_down():
    """350 W m⁻² of beam on the ground at β = 30° is 700 along the sun (by hand, sin 30° = ½); the
    cosine law gives the 350 back at any elevation above the horizon; at or below it there is no
    beam (0, not ±∞ or 350 / |sin β|), and a missing value stays missing rather than turning dark."""
    from lightfit.weather.solar import beam_normal, horizontal_irradiance

    np.testing.assert_allclose(beam_normal(np.array([350.0]), np.array([30.0])), [700.0], rtol=1e-12)
    el = np.array([0.05, 1.0, 30.0, 89.9])
    np.testing.assert_allclose(horizontal_irradiance(beam_normal(350.0, el), 0.0, el), 350.0, rtol=1e-12)
    got = beam_normal(np.array([0.0, 5.0, np.nan, np.nan]), np.array([0.0, -10.0, -10.0, 20.0]))
    np.testing.assert_array_equal(got[:2], [0.0, 0.0])
    assert np.isnan(got[2:]).all()
    series = beam_normal(pd.Series([350.0]), pd.Series([30.0]))
    assert isinstance(series, pd.Series)


@pytest.mark.parametrize(("excess", "refused"), [(20.0, False), (25.0, True)])
def test_diffuse_par_may_exceed_par_by_the_two_instrument_margin_in_photons(excess, refused):
    """The margin of a diffuse column over its total is 1.15 × total + 10 W m⁻²; for diffuse PAR the
    10 W m⁻² is in photons, 10 × 0.50 × 4.57 = 22.85 µmol m⁻² s⁻¹ (McCree 1972). Two dawn steps whose
    diffuse PAR is 1.15 × PAR + 20 µmol m⁻² s⁻¹ are two instruments' rounding (cut to PAR); + 25 is
    refused (a mutation audit: the margin left at 10 µmol m⁻² s⁻¹, unscaled, survived)."""
    df = _two_sensor_day(0.5 * 4.57)
    df["par_diffuse_umol_m2_s"] = 0.3 * df["par_umol_m2_s"]
    el = solar_position(df.index)["sun_elevation_deg"]
    dawn = df.index[(el > 2.0) & (el < 20.0)][:2]
    df.loc[dawn, "par_diffuse_umol_m2_s"] = 1.15 * df.loc[dawn, "par_umol_m2_s"] + excess
    if refused:
        with pytest.raises(InputError, match=r"par_diffuse_umol_m2_s.*2 steps have more diffuse than PAR"):
            add_solar(df)
    else:
        out = add_solar(df)
        assert out.attrs["split_model"] == "diffuse"
        note = next(q["detail"] for q in out.attrs["qc"] if q["kind"] == "split")
        assert "diffuse cut to its total at 2 step(s)" in note
        np.testing.assert_allclose(out.loc[dawn, "dhi_w_m2"], out.loc[dawn, "ghi_w_m2"], rtol=1e-12)


def test_a_single_step_takes_bolands_15_minute_fit():
    """A one-row series has no step to choose Boland's fit by: it takes the 15-minute fit
    (a, b) = (8.645, 0.613) of Boland, Scott & Luther (2001), as boland_coeffs says, with k_t by hand
    from pvlib's extraterrestrial irradiance (a mutation audit: the hourly fit for one row survived)."""
    t = pd.DatetimeIndex([pd.Timestamp("2016-04-20 11:00", tz="UTC")])
    el = solar_position(t)["sun_elevation_deg"]
    ghi = pd.Series([600.0], index=t)
    kt = 600.0 / (pvlib.irradiance.get_extra_radiation(t).to_numpy() * np.sin(np.radians(el.to_numpy())))
    got = split_direct_diffuse(ghi, el, "boland")["dhi_w_m2"] / ghi
    np.testing.assert_allclose(got, 1.0 / (1.0 + np.exp(8.645 * (kt - 0.613))), rtol=1e-9)


def test_a_site_given_to_add_solar_overrides_the_series_own():
    """The site asked for places the sun, not the one a series carries in its attrs: pvlib called
    directly at Cape Town's coordinates (a mutation audit: the series' own site preferred survived)."""
    t = pd.date_range("2016-04-20 00:00", periods=4, freq="10min", tz="UTC")  # night at both sites
    df = pd.DataFrame({"ghi_w_m2": 0.0, "tair_c": 10.0}, index=t)
    df.attrs["site"] = SELHAUSEN
    cape = Site(-34.0, 18.5, 40.0, "Cape Town", "Africa/Johannesburg")
    out = add_solar(df, site=cape)
    sp = pvlib.solarposition.get_solarposition(t, -34.0, 18.5, altitude=40.0)
    np.testing.assert_allclose(out["sun_elevation_deg"], sp["apparent_elevation"], atol=1e-9)
    np.testing.assert_allclose(out["sun_azimuth_deg"], sp["azimuth"], atol=1e-9)
    assert out.attrs["site"] == cape


def test_a_diffuse_fraction_above_one_gives_no_negative_direct_par():
    """Spitters' PAR fraction lies in [0, 1] (its docstring): k_d is cut to [0, 1] first, and at k_d = 1
    eq. 9 is 1 by hand, at k_d = 0 it is 0. Unclipped, k_d = 1.2 at β = 39.2° would give
    1.0416 / (1 − 0.44 × 0.186) = 1.13. The case that reaches it: a hand-built forcing with DHI
    300 W m⁻² and a beam of −10 W m⁻² at β = 30° (horizontal total 295, k_d = 300/295 > 1) and 590 µmol
    of PAR gets all 590 as diffuse PAR and no beam, not a negative direct PAR of −14 µmol m⁻² s⁻¹
    (a mutation audit: the clip on k_d dropped passed every test)."""
    from lightfit.weather.solar import par_diffuse_fraction, par_direct_diffuse

    np.testing.assert_allclose(par_diffuse_fraction([1.2, 1.0, -0.1, 0.0], 39.2), [1.0, 1.0, 0.0, 0.0], atol=1e-15)
    dni_par, dhi_par = par_direct_diffuse([-10.0], [300.0], [30.0], [590.0])
    assert dni_par[0] == pytest.approx(0.0, abs=1e-12) and dhi_par[0] == pytest.approx(590.0, rel=1e-12)


def test_the_forcing_runs_under_warnings_as_errors_and_leaves_the_filters_as_they_were():
    """pvlib 0.16 reads pandas' deprecated ``dayofyear`` (a Pandas4Warning under pandas 3.1): with
    warnings as errors (``PYTHONWARNINGS=error``, a strict test harness) the main job stopped at its
    forcing. pvlib's own deprecations are silenced around its calls, and nothing else is."""
    from lightfit import replication as rep
    from lightfit.weather.reconstruct import reconstruct_day, solar_noon_utc

    times = pd.date_range("2016-04-20 04:00", "2016-04-20 18:00", freq="30min", tz="UTC")
    ghi = pd.Series(np.linspace(0.0, 600.0, len(times)), index=times)
    elevation = solar_position(times)["sun_elevation_deg"]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        # compared inside this block (and before pytest.warns): their exits restore the filters whatever
        # the calls left, so a filter leaked by the calls is seen only here
        before = list(warnings.filters)
        forcing = rep.forcing()  # the bundled day: sun, the split from its diffuse column, clear sky
        day = reconstruct_day("2016-04-20")
        noon = solar_noon_utc("2016-04-20")
        splits = [split_direct_diffuse(ghi, elevation, model=m) for m in ("erbs", "boland")]
        after = list(warnings.filters)
        with pytest.warns(DeprecationWarning, match="lightfit's own"):  # only pvlib's are silenced
            with pvlib_deprecations_quiet():
                warnings.warn("lightfit's own", DeprecationWarning, stacklevel=1)
    assert after == before
    assert len(forcing) and len(day) and noon.hour == 11  # Selhausen (6.45° E): transit ≈ 11:35 UTC
    for split in splits:
        assert np.isfinite(np.asarray(split, dtype=float)).all()


def test_bolands_fit_follows_the_averaging_interval_not_the_step():
    """10-min means (the TERENO fixture, end-stamped) sampled every hour are still 10-min means: Boland,
    Scott & Luther's (2001) 15-minute fit (8.645, 0.613), k_t by hand from pvlib's extraterrestrial
    irradiance at the true zenith; the hourly fit (7.997, 0.586) was taken by the step (at k_t 0.68
    the diffuse fraction 0.32 for 0.36). Hourly means (resampled by averaging) take the hourly fit."""
    df = read_tereno(FIXTURE)
    for how, (a, b) in (("sample", (8.645, 0.613)), ("mean", (7.997, 0.586))):
        out = add_solar(resample(add_solar(df, split_model="boland"), "1h", how))
        lit = out["sun_elevation_deg"] > 20
        assert lit.sum() >= 5
        sp = solar_position(out.index[lit] + out.attrs["timestamps"].centre_offset)
        e0 = pvlib.irradiance.get_extra_radiation(out.index[lit]).to_numpy()
        kt = out.loc[lit, "ghi_w_m2"].to_numpy() / (e0 * np.sin(np.radians(sp["sun_true_elevation_deg"].to_numpy())))
        got = (out.loc[lit, "dhi_w_m2"] / out.loc[lit, "ghi_w_m2"]).to_numpy()
        np.testing.assert_allclose(got, 1.0 / (1.0 + np.exp(a * (kt - b))), rtol=1e-9, err_msg=how)


def test_par_only_series_in_w_m2_is_cautioned_not_read_silently_as_overcast(tmp_path):
    """A lightfit CSV with PAR only: global radiation is estimated as PAR / 2.285 µmol J⁻¹ and split by
    Erbs from that. PAR written in W m⁻² (the bundled clear 20 April ÷ 4.57) is then a sky at ≈ 20 % of
    clear sky, split as overcast (noon diffuse share ≈ 0.99 where the same day in µmol gives ≈ 0.27), and
    nothing said so. It is cautioned now, naming the column; the same day in µmol and the bundled real
    overcast day (PAR only, CPlantBox file on 2016-04-27, at most 67 % of clear sky) are not."""
    from typer.testing import CliRunner

    from lightfit.cli import app
    from lightfit.weather import read_lightfit_csv, read_source, write_lightfit_csv

    day = read_source("2016-04-20")[["par_umol_m2_s", "tair_c", "rh", "pair_kpa", "co2_ppm"]]
    noon = pd.Timestamp("2016-04-20 11:30", tz="UTC")
    for name, scale, cautioned in (("umol", 1.0, False), ("w", 1 / 4.57, True)):
        w = day.copy()
        w["par_umol_m2_s"] *= scale
        w.attrs = {}
        path = write_lightfit_csv(w, tmp_path / f"{name}.csv", {"provenance": "synthetic"})
        s = add_solar(read_lightfit_csv(path))
        kd = s.loc[noon, "dhi_w_m2"] / s.loc[noon, "ghi_w_m2"]
        assert (kd > 0.9) if cautioned else (kd < 0.35), (name, kd)
        cautions = [q for q in s.attrs["qc"] if q["kind"] == "caution"]
        assert bool(cautions) == cautioned, cautions
        if cautioned:
            assert cautions[0]["column"] == "par_umol_m2_s" and "PAR in W m⁻²" in cautions[0]["detail"]
            # kept once through resampling, and printed by `lightfit weather show`
            assert [q["kind"] for q in resample(s, "30min", "mean").attrs["qc"]].count("caution") == 1
            out = CliRunner().invoke(app, ["weather", "show", str(path)], terminal_width=400)
            assert out.exit_code == 0 and "caution par_umol_m2_s: PAR reaches at most 20% of clear-sky" in out.output
    real = add_solar(read_source("selhausen-cplantbox-day", date="2016-04-27"))
    assert not [q for q in real.attrs["qc"] if q["kind"] == "caution"]
