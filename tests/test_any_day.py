"""Any day, any site (issue 14 item 4): the run's date, window and site reach the forcing, the sun and the plants."""

from dataclasses import replace

import numpy as np
import pandas as pd
import pvlib
import pytest
from typer.testing import CliRunner

from lightfit import replication as rep
from lightfit import weather
from lightfit.cli import app
from lightfit.errors import InputError
from lightfit.plant import GrowthConfig
from lightfit.report import step_instants
from lightfit.weather import Site, Window, timestamps
from lightfit.weather.bundled import DATA_DIR

runner = CliRunner()
REAL_DAY = DATA_DIR / "weather" / "selhausen_cplantbox_day.txt"


def test_default_forcing_is_bitwise_the_replications():
    """The default run's forcing is exactly what the fixed 2016-04-20 05:00 + 14 h window gave before
    date, window and site became options (the old code path, written out here)."""
    old = weather.window(
        weather.add_solar(weather.read_weather(weather.bundled_path("2016-04-20"))),
        "2016-04-20 05:00",
        14.0,
        "30min",
        how="sample",
    )
    for new in (rep.forcing(), rep.forcing_of(rep.ReplicationConfig())):
        pd.testing.assert_frame_equal(new, old, check_exact=True)
    assert len(old) == 29


def test_site_and_date_move_the_sun_as_pvlib_says(tmp_path):
    """Another site (southern hemisphere, other time zone) and date: the window's steps start at the
    local clock time there and the sun angles are pvlib's for those coordinates (called directly),
    at the centres of the file's 10-min means (stamped at their ends). Selhausen's light does not
    fit a Cape Town winter day (refused), so the geometry is checked on the day's weather under
    Cape Town's clear-sky light."""
    site = Site(-34.0, 18.5, 40.0, "Cape Town", "Africa/Johannesburg")
    win = Window("10:00", 2.0, "1h")
    with pytest.raises(InputError, match="more light than their sun can give"):
        rep.forcing(REAL_DAY, dates="2016-06-23", window=win, site=site)
    path = _clear_sky_csv(tmp_path / "cape_town.csv", site, "2016-06-23")
    w = rep.forcing(path, dates="2016-06-23", window=win, site=site)
    t = pd.date_range("2016-06-23 10:00", periods=3, freq="1h", tz="Africa/Johannesburg").tz_convert("UTC")
    assert w.index.equals(t)
    sp = pvlib.solarposition.get_solarposition(t - pd.Timedelta("5min"), -34.0, 18.5, altitude=40.0)
    np.testing.assert_allclose(w["sun_elevation_deg"], sp["apparent_elevation"], atol=1e-9)
    np.testing.assert_allclose(w["sun_azimuth_deg"], sp["azimuth"], atol=1e-9)
    # Winter noon at 34 °S is lower than spring noon at Selhausen (50.9 °N, 27 April): about 32.5° vs 53°.
    sel = rep.forcing(REAL_DAY, dates="2016-04-27", window=Window("13:30", 0.5), site=weather.SELHAUSEN)
    assert w["sun_elevation_deg"].max() < 33 < 52 < sel["sun_elevation_deg"].max() < 54


def _clear_sky_csv(path, site: Site, date: str):
    """The bundled TERENO day's weather under ``site``'s clear sky (Haurwitz) on ``date``, as a lightfit CSV."""
    day = weather.read_cplantbox_day(REAL_DAY, date)
    zen = pvlib.solarposition.get_solarposition(
        day.index - pd.Timedelta("5min"), site.latitude_deg, site.longitude_deg, altitude=site.altitude_m
    )
    day["par_umol_m2_s"] = 2.285 * pvlib.clearsky.haurwitz(zen["apparent_zenith"])["ghi"].to_numpy()
    return weather.write_lightfit_csv(day, path, {"provenance": "synthetic"})


def test_a_southern_site_grows_its_plants_from_its_own_season_start():
    """5 March is a northern spring: south of the equator the default would grow a full canopy for a
    winter's day (or refuse a spring one as 199 days on), so the run asks for the season's start and
    grows every date from it (a review: only `lightfit field` took one)."""
    from lightfit.cli.options import ModelOptions, resolve

    site = Site(-35.1, 147.4, 200.0, "Wagga Wagga", "Australia/Sydney")
    with pytest.raises(InputError, match=r"5 March, is a northern spring date.*-35.1° \(south"):
        rep.ReplicationConfig(site=site, dates=("2016-09-20",))
    cfg = rep.ReplicationConfig(site=site, dates=("2016-09-20",), season_start="2016-05-15")
    g = cfg.field().growth
    assert (g.season_start, g.target_date, g.days) == ("2016-05-15", "2016-09-20", 128)
    assert g == GrowthConfig(season_start="2016-05-15", target_date="2016-09-20")
    # a northern run keeps 5 March of its year unless told otherwise
    assert rep.ReplicationConfig().field().growth.season_start == "2016-03-05"
    assert rep.ReplicationConfig(season_start="2015-10-20", dates=("2016-03-01",)).field().growth.days == 133

    where = {"latitude": -35.1, "longitude": 147.4, "timezone": "UTC+10", "dates": ["2016-09-20"]}
    with pytest.raises(InputError, match=r"--season-start: the default season start, 5 March"):
        resolve(ModelOptions(quick=True, **where))
    with pytest.raises(InputError, match=r"--season-start 2016-10-01 \(--date 2016-09-20\): target_date"):
        resolve(ModelOptions(quick=True, season_start="2016-10-01", **where))
    s = resolve(ModelOptions(quick=True, season_start="2016-05-15", **where))
    assert s.season_start == "2016-05-15" and s.replication_config().field().growth.days == 128
    # the coordinates' label says S and W, and --timezone takes UTC±H as --tz does
    assert (s.site.name, s.site.timezone) == ("35.1° S, 147.4° E", "Etc/GMT-10")
    from lightfit.weather.site import zone_label

    assert zone_label(s.site.timezone) == "UTC+10"  # as tables and figures write it (not Etc/GMT-10's sign)
    # the option given is the one named (it blamed the default --date), and the default's own date given
    # explicitly is the same run (a resume was refused as 'None → 2016-03-05')
    from lightfit.cli.options import changed_settings

    with pytest.raises(InputError, match=r"--season-start 2016-05-01 \(the default --date 2016-04-20\)"):
        resolve(ModelOptions(quick=True, season_start="2016-05-01"))
    plain = resolve(ModelOptions(quick=True))
    assert changed_settings(plain.as_dict(), resolve(ModelOptions(quick=True, season_start="2016-03-05"))) == []
    assert changed_settings(plain.as_dict(), resolve(ModelOptions(quick=True, season_start="2016-03-01"))) == [
        "season_start: None → '2016-03-01'"
    ]
    west = resolve(ModelOptions(quick=True, latitude=38.0, longitude=-98.0, timezone="America/Chicago"))
    assert west.site.name == "38° N, 98° W"


def test_weather_show_takes_the_site(tmp_path):
    """`weather show` took the sun at Selhausen whatever the file: a clear day at another site was
    refused as light its sun cannot give (a review). With the site's options its sun is pvlib's there,
    and the converted CSV carries that sun."""
    site = Site(-34.0, 18.5, 40.0, "Cape Town", "Africa/Johannesburg")
    path = _clear_sky_csv(tmp_path / "cape_town.csv", site, "2016-06-23")
    r = runner.invoke(app, ["weather", "show", str(path)])
    assert r.exit_code == 2 and "at Selhausen" in r.output, r.output
    where = ["--latitude", "-34", "--longitude", "18.5", "--altitude-m", "40", "--timezone", "Africa/Johannesburg"]
    out = tmp_path / "converted.csv"
    r = runner.invoke(app, ["weather", "show", str(path), *where, "--csv", str(out)])
    assert r.exit_code == 0, r.output
    w = weather.read_weather(out)
    sp = pvlib.solarposition.get_solarposition(w.index - pd.Timedelta("5min"), -34.0, 18.5, altitude=40.0)
    np.testing.assert_allclose(w["sun_elevation_deg"], sp["apparent_elevation"], atol=1e-6)


def test_bundled_real_day_by_name_and_by_path_is_the_same_forcing():
    by_name = rep.forcing("selhausen-cplantbox-day", dates="2016-04-27", window=Window("12:00", 1.0))
    by_path = rep.forcing(REAL_DAY, dates="2016-04-27", window=Window("12:00", 1.0))
    pd.testing.assert_frame_equal(by_name, by_path, check_exact=True)
    assert by_name.attrs["provenance"] == "measured"


def test_undated_file_needs_a_date_and_the_window_must_be_in_the_file():
    with pytest.raises(InputError, match="selhausen_cplantbox_day.txt, parameter 'date': the file has no date"):
        rep.forcing(REAL_DAY)
    with pytest.raises(InputError, match=r"day.txt: the window 2016-04-27 20:00 \+ 6 h .* not covered.*window.start"):
        rep.forcing(REAL_DAY, dates="2016-04-27", window=Window("20:00", 6.0))
    # A date the file's light does not fit: dark with the sun up (data/README.md)
    with pytest.raises(InputError, match=r"PAR .* with the sun at 10.4°.*darker than any sky") as wrong_date:
        rep.forcing(REAL_DAY, dates="2016-06-23", window=Window("12:00", 1.0))
    assert "W m⁻²" not in str(wrong_date.value)  # × 4.57 leaves its dawn dark: not taken for a unit slip


def test_par_in_watts_under_a_micromole_header_is_named_a_unit_slip(tmp_path):
    """The measured day's PAR ÷ 4.57 (W m⁻² of PAR in the µmol column): its dawn is "darker than any
    sky with the sun up", which blamed the timestamps alone; the series × 4.57 fits its sun, so the
    unit is named too."""
    lines = REAL_DAY.read_text().splitlines()
    cut = [lines[0]] + ["\t".join([f[0], repr(float(f[1]) / 4.57), *f[2:]]) for f in (x.split("\t") for x in lines[1:])]
    path = tmp_path / "watts.txt"
    path.write_text("\n".join(cut) + "\n")
    with pytest.raises(InputError, match=r"column 'PAR'.*darker than any sky.*× 4.57 µmol J⁻¹ every step would fit"):
        rep.forcing(path, dates="2016-04-27")
    with pytest.raises(InputError, match="parameter 'dates': no bundled forcing for 2016-06-23"):
        rep.forcing(dates="2016-06-23")


@pytest.mark.parametrize(
    ("library", "args", "said"),
    [
        (
            lambda: rep.forcing(dates="2016-06-23"),
            ["--date", "2016-06-23"],
            ("parameter 'dates'", "option --date", ": no bundled forcing for 2016-06-23 (expected a weather_file"),
        ),
        (
            lambda: rep.forcing("selhausen-cplantbox-day"),
            ["--weather", "selhausen-cplantbox-day"],
            ("day.txt, parameter 'date'", "day.txt: option --date", ": the file has no date (a CPlantBox day file)"),
        ),
        (
            lambda: rep.check_growth_temperatures(
                rep.ReplicationConfig(growth_temperature_c="series"), rep.forcing(month_before=True)
            ),
            ["--growth-temperature-c", "series"],
            (
                "reconstructed.csv, parameter 'growth_temperature_c'",
                "reconstructed.csv: option --growth-temperature-c",
                ": growth_temperature_c='series': the weather series does not cover the month before 2016-04-20",
            ),
        ),
    ],
)
def test_library_errors_name_the_parameter_and_the_command_its_option(library, args, said, tmp_path):
    """Library errors named the command line's flags (--date, --start-time) to a Python caller: they
    name the parameter, and the command restates it as its option (lightfit.cli.common.error_message:
    its aliases, and the options applied to a file), before anything is written."""
    python, option, problem = said
    with pytest.raises(InputError) as e:
        library()
    assert python + problem in str(e.value) and "--date" not in str(e.value), str(e.value)
    r = runner.invoke(app, ["replicate", "--quick", "--out", str(tmp_path / "o"), *args])
    flat = " ".join(r.stderr.split())
    assert r.exit_code == 2 and flat.startswith("error: ") and option + problem in flat, r.output
    assert not (tmp_path / "o").exists()


def test_plants_are_grown_to_the_run_date_within_the_growth_models_range():
    cfg = rep.ReplicationConfig(dates=("2016-06-23", "2016-05-10"))
    assert cfg.dates == ("2016-05-10", "2016-06-23")  # sorted
    assert cfg.field().growth.target_date == "2016-05-10"
    assert cfg.field("2016-06-23").growth.target_date == "2016-06-23"
    assert cfg.field().growth.season_start == "2016-03-05"  # the season start is kept
    for bad in ("2016-03-01", "2016-11-30"):
        with pytest.raises(InputError, match="target_date"):
            rep.ReplicationConfig(dates=(bad,)).field()
    # another year's spring starts on its own 5 March (it was refused: 418 days after 2016-03-05)
    later = rep.ReplicationConfig(dates=("2017-04-27",)).field().growth
    assert later.season_start == "2017-03-05" and later.days == 53
    with pytest.raises(InputError, match=r"not after season_start 2017-03-05 \(the default: 5 March of its year"):
        rep.ReplicationConfig(dates=("2017-02-01",)).field()
    # given, it is kept: a field grown from the autumn's sowing is the user's call
    assert GrowthConfig(season_start="2016-01-10").season_start == "2016-01-10"


def test_bundled_real_day_runs_from_the_cli(tmp_path, monkeypatch):
    """The real TERENO day (undated) with --date, by bundled name, on a 2-step window, quick field."""
    monkeypatch.setenv("LIGHTFIT_CACHE", str(tmp_path / "cache"))
    args = ["replicate", "--quick", "--weather", "selhausen-cplantbox-day", "--date", "2016-04-27"]
    r = runner.invoke(app, [*args, "--start-time", "13:00", "--hours", "0.5", "--out", str(tmp_path / "o")])
    assert r.exit_code == 0, r.output
    import xarray as xr

    with xr.open_dataset(tmp_path / "o" / "results.nc") as ds:
        assert ds.sizes["time"] == 2
        assert ds.attrs["date"] == ds.attrs["target_date"] == "2016-04-27"
        assert ds.attrs["site"] == "Selhausen" and ds.attrs["site_timezone"] == "Europe/Berlin"
        assert ds.attrs["weather_provenance"] == "measured"
        assert (ds["canopy_an_umol_m2_s"].values > 0).all()  # around noon: net uptake
        assert not [v for v in ds.data_vars if v.startswith("obs_")]  # the 20 April record is not of this day
        # The day's rows are 10-min means stamped at their ends: CF bounds (t − 10 min, t).
        assert ds.attrs["weather_timestamps"] == "ends of 10-min means"
        assert ds["time"].attrs.get("bounds", ds["time"].encoding.get("bounds")) == "time_bnds"
        t = ds["time"].values
        np.testing.assert_array_equal(ds["time_bnds"].values, np.column_stack([t - np.timedelta64(10, "m"), t]))
        # and the figure draws each step at its interval's centre, where its sun was taken
        drawn = step_instants(ds).tz_localize(None).values
        np.testing.assert_array_equal(drawn, t - np.timedelta64(5, "m"))


def test_a_day_of_another_year_runs_from_the_cli(tmp_path, monkeypatch):
    """A newcomer's run of the bundled real day on a 2017 date was refused (its plants were grown
    from 2016-03-05, 418 days before); they now start on 5 March 2017."""
    monkeypatch.setenv("LIGHTFIT_CACHE", str(tmp_path / "cache"))
    args = ["replicate", "--quick", "--weather", "selhausen-cplantbox-day", "--date", "2017-04-27", "--steps", "14:15"]
    r = runner.invoke(app, [*args, "--out", str(tmp_path / "o")])
    assert r.exit_code == 0, r.output
    import xarray as xr

    with xr.open_dataset(tmp_path / "o" / "results.nc") as ds:
        assert (ds.attrs["season_start"], ds.attrs["target_date"]) == ("2017-03-05", "2017-04-27")
        assert str(ds["time"].values[0]).startswith("2017-04-27")


def test_several_days_in_one_results_set(tmp_path, monkeypatch):
    """Two dates: one Dataset along time with a ``day`` coordinate, plants grown to each date
    (more leaf area on the later one), segments the union of both days'."""
    monkeypatch.setenv("LIGHTFIT_CACHE", str(tmp_path / "cache"))
    cfg = rep.ReplicationConfig(
        n_plants=1, samples=4, bounces=1, dates=("2016-04-20", "2016-04-27"), window=Window("12:00", 0.5)
    )
    ds, obs = rep.run(cfg, weather_file=REAL_DAY)  # the bundled record (20 April, 12:13 local) falls in it
    assert list(ds["day"].values) == ["2016-04-20"] * 2 + ["2016-04-27"] * 2
    assert obs is not None and np.isfinite(ds["obs_above_canopy_par_umol_m2_s"].values).sum() == 1
    assert ds["day"].attrs["long_name"].startswith("date of the step's day")  # from the schema
    assert ds.attrs["target_date"] == "2016-04-20; 2016-04-27"
    # Each day's plants are its own (CPlantBox renumbers segments as a plant grows): segments of
    # one day are NaN on the other's steps, and each day's canopy values are its own run's.
    day_of_segment = ds["segment"].values // rep.DAY_SEGMENT_STRIDE
    par = ds["absorbed_par_umol_m2_s"].values
    for k, steps in enumerate((slice(0, 2), slice(2, 4))):
        assert np.isfinite(par[steps][:, day_of_segment == k]).all()
        assert np.isnan(par[steps][:, day_of_segment != k]).all()
        other = ds.isel(time=steps, segment=day_of_segment != k)  # no leaf there: the schema's off-blade values
        assert (other["limitation"] == -1).all() and other["converged"].all()
        assert np.isnan(other["leaf_an_umol_m2_s"]).all()
    assert ds["limitation"].dtype == np.int8 and ds["converged"].dtype == bool
    alone, _ = rep.run(replace(cfg, dates=("2016-04-27",)), weather_file=REAL_DAY, observations=None)
    np.testing.assert_array_equal(ds["canopy_an_umol_m2_s"].values[2:], alone["canopy_an_umol_m2_s"].values)
    assert (ds["organ_type"].values[day_of_segment == 1] == alone["organ_type"].values).all()
    for v in ("leaf_area_above", "capacity_factor", "height_m"):  # per segment, each day's plants their own
        assert ds[v].dims == ("segment",), v
        np.testing.assert_array_equal(ds[v].values[day_of_segment == 1], alone[v].values)
    rep.write_netcdf(ds, tmp_path / "r.nc")  # the union is writable
    t = ds["time"].values
    np.testing.assert_array_equal(ds["time_bnds"].values[:, 1], t)  # both days' bounds, end-stamps


def test_growth_temperature_from_the_series_month_before(tmp_path):
    """--growth-temperature-c series: each date's mean air temperature of the 30 local days before,
    each day weighted alike (one day keeps half its rows), from a 36-day synthetic series whose
    local days have known temperatures; refused naming the option where the series does not cover
    them (the bundled single day)."""
    base = weather.read_cplantbox_day(REAL_DAY, "2016-04-20")
    series = pd.concat([base.set_axis(base.index + pd.Timedelta(days=k - 35)) for k in range(36)])
    centres = timestamps.of(series).centres(series.index)  # 10-min means stamped at their ends
    local = pd.DatetimeIndex(centres.tz_convert("Europe/Berlin").date)  # each row's local date
    day = (local - pd.Timestamp("2016-03-16")).days.to_numpy()  # naive dates: whole days across DST
    series["tair_c"] = 4.0 + 0.25 * day
    series = series[(local != pd.Timestamp("2016-04-01")) | (np.arange(len(series)) % 2 == 0)]
    expect = np.mean(4.0 + 0.25 * np.arange(5, 35))  # the local days 21 March … 19 April
    assert weather.month_before_mean_tair_c(series, "2016-04-20") == pytest.approx(expect, abs=1e-12)
    path = weather.write_lightfit_csv(series, tmp_path / "month.csv", {"provenance": "synthetic"})
    w = rep.forcing(path, dates="2016-04-20", window=Window("12:00", 1.0), month_before=True)
    assert "month_before_tair_c" not in rep.forcing(path, dates="2016-04-20", window=Window("12:00", 1.0)).attrs
    # Read back, the half day's missing rows are filled by the reader's interpolation (its first
    # row from the day before's last): 0.125 / 144 on that day, 3e-5 on the month.
    assert w.attrs["month_before_tair_c"]["2016-04-20"] == pytest.approx(expect, abs=5e-5)
    cfg = rep.ReplicationConfig(n_plants=1, growth_temperature_c="series", window=Window("12:00", 1.0))
    assert rep.scenario_for(cfg, w).growth_temperature_c == w.attrs["month_before_tair_c"]["2016-04-20"]
    # recorded as the run takes it (the number), "series" only where the forcing is not at hand
    assert cfg.effective(w)["growth_temperature_c"] == rep.scenario_for(cfg, w).growth_temperature_c
    assert cfg.effective()["growth_temperature_c"] == "series"
    short = rep.forcing(path, dates="2016-03-30", window=Window("12:00", 1.0), month_before=True)  # 14 days
    with pytest.raises(InputError, match="growth_temperature_c='series'.*month before 2016-03-30"):
        rep.scenario_for(replace(cfg, dates=("2016-03-30",)), short)
    r = runner.invoke(app, ["replicate", "--quick", "--growth-temperature-c", "series", "--out", str(tmp_path / "o")])
    assert r.exit_code == 2 and "month before 2016-04-20" in " ".join(r.stderr.split())
    assert not (tmp_path / "o").exists()  # refused before anything is written


def test_month_before_across_a_daylight_saving_change_at_midnight():
    """Santiago's clocks jumped from 00:00 to 01:00 on 14 August 2016: there is no local midnight
    that day, and the month before 13 September is counted in calendar days all the same. A file's
    first evening (two hours of a day) does not count as a day of the month."""
    t = pd.date_range("2016-08-01", "2016-09-14", freq="1h", tz="UTC")
    local = pd.DatetimeIndex(t.tz_convert("America/Santiago").date)
    df = pd.DataFrame({"tair_c": (local - pd.Timestamp("2016-08-01")).days.to_numpy() * 0.1}, index=t)
    got = weather.month_before_mean_tair_c(df, "2016-09-13", "America/Santiago")
    assert got == pytest.approx(np.mean([0.1 * k for k in range(13, 43)]), abs=1e-12)  # 14 Aug … 12 Sep
    # From 22:00 on the month's first day: that evening is not a day, the 29 after it are.
    late = df[df.index >= pd.Timestamp("2016-08-14 22:00", tz="America/Santiago")]
    after = np.mean([0.1 * k for k in range(14, 43)])
    assert weather.month_before_mean_tair_c(late, "2016-09-13", "America/Santiago") == pytest.approx(after, abs=1e-12)
    assert weather.month_before_mean_tair_c(df[df.index >= "2016-08-20"], "2016-09-13", "America/Santiago") is None


def test_growth_temperature_settings_are_one_per_model():
    """An explicit 15 °C is winter_wheat's own (one setting, one digest); a history stored before the
    option existed was the set's own, so it does not resume at another growth temperature; several
    days of "series" list each day's value; the run's label names a growth temperature not the set's."""
    from lightfit.inference.calibration import _check_same_data, _model_digest
    from lightfit.report import run_label

    w = rep.forcing().iloc[[14]]
    assert rep.ReplicationConfig(growth_temperature_c=15.0).growth_temperature_c is None
    assert rep.ReplicationConfig(growth_temperature_c="9").growth_temperature_c == 9.0
    assert rep.ReplicationConfig(growth_temperature_c=9.0).preset is None
    with pytest.raises(InputError, match="growth_temperature_c"):
        rep.ReplicationConfig(growth_temperature_c=True)
    with pytest.raises(InputError, match="growth_temperature_c='series' with the 'giraud2023' set"):
        rep.ReplicationConfig(photosynthesis="giraud2023", growth_temperature_c="series")
    m = lambda s: type("M", (), {"scenario": s})()  # noqa: E731
    base = rep.scenario_for(rep.ReplicationConfig.quick(), w)
    assert _model_digest(m(replace(base, growth_temperature_c=15.0))) == _model_digest(m(base))
    warm = _model_digest(m(replace(base, growth_temperature_c=9.0)))
    old = {k: v for k, v in _model_digest(m(base)).items() if k != "growth_temperature_c"}
    with pytest.raises(InputError, match="growth_temperature_c"):
        _check_same_data(
            {"key": {"data": {"observations": "o", "model": old}}}, {"observations": "o", "model": warm}, None, print
        )
    assert "T_g 9 °C" in run_label({"photosynthesis": "winter_wheat", "growth_temperature_c": 9.0})
    assert "T_g" not in run_label({"photosynthesis": "winter_wheat", "growth_temperature_c": 15.0})
    assert "T_g 9.3; 13.1 °C" in run_label({"photosynthesis": "winter_wheat", "growth_temperature_c": "9.3; 13.1"})


def test_several_days_list_each_days_growth_temperature():
    """Days of a "series" run with different growth temperatures: results list each, rounded as one
    day's is, and the run's label names them; days alike keep the one value."""
    import xarray as xr

    from lightfit.report import run_label

    def part(date, t_g):
        t = pd.date_range(f"{date} 10:00", periods=2, freq="30min")
        return xr.Dataset(
            {
                "limitation": (("time", "segment"), np.zeros((2, 2), np.int8)),
                "converged": (("time", "segment"), np.ones((2, 2), bool)),
            },
            coords={
                "time": t,
                "segment": [1, 2],
                "plant_id": ("segment", [0, 0]),
                "organ_type": ("segment", ["leaf"] * 2),
                "area_m2": ("segment", [1.0, 1.0]),
                "is_blade": ("segment", [True, True]),
                "height_m": ("segment", [0.1, 0.2]),
            },
            attrs={
                "date": date,
                "window": "w",
                "target_date": date,
                "growth_temperature_c": t_g,
                "photosynthesis": "winter_wheat",
            },
        )

    both = rep.concat_days([part("2016-04-20", 9.2875), part("2016-05-20", 13.104166666)])
    assert both.attrs["growth_temperature_c"] == "9.29; 13.1"
    assert "T_g 9.29; 13.1 °C" in run_label(both.attrs)
    # The fits clamp T_g to 11–35 °C (KATTGE_KNORR_RANGE_C): the value applied is listed and named too.
    applied = [part("2016-04-20", 9.2875), part("2016-05-20", 13.104166666)]
    for p, t in zip(applied, (11.0, 13.104166666)):
        p.attrs["growth_temperature_applied_c"] = t
    both = rep.concat_days(applied)
    assert both.attrs["growth_temperature_applied_c"] == "11; 13.1"
    assert "T_g 9.29; 13.1 °C, acting as 11; 13.1 °C" in run_label(both.attrs)
    same = rep.concat_days([part("2016-04-20", 15.0), part("2016-05-20", 15.0)])
    assert same.attrs["growth_temperature_c"] == 15.0 and "T_g" not in run_label(same.attrs)


def test_series_growth_temperature_needs_the_forcing_read_with_its_month():
    cfg = rep.ReplicationConfig(n_plants=1, growth_temperature_c="series")
    with pytest.raises(InputError, match="read without its month before"):
        rep.check_growth_temperatures(cfg, rep.forcing())


def test_a_clock_change_inside_a_run_neither_repeats_nor_folds_local_time(tmp_path, monkeypatch):
    """Sydney falls back from UTC+11 to UTC+10 at 03:00 on 3 April 2016: 02:00–02:59 happen twice.
    Local labels carry their offset where it changes within the run (summary.csv, the tables), and
    the figures draw each step at its instant, so the time axis runs forward (it folded back over the
    repeated hour: a review). One offset, plain HH:MM as before."""
    import matplotlib.dates as mdates
    import matplotlib.figure

    from lightfit.weather.plot import plot_forcing
    from lightfit.weather.site import local_clock

    t = pd.date_range("2016-04-02 15:00", periods=4, freq="30min", tz="UTC")
    assert list(local_clock(t, "Australia/Sydney")) == ["02:00 UTC+11", "02:30 UTC+11", "02:00 UTC+10", "02:30 UTC+10"]
    assert list(local_clock(t[:2], "Australia/Sydney")) == ["02:00", "02:30"]
    assert list(local_clock(t[:1], "Asia/Kolkata")) == ["20:30"]
    assert list(local_clock(pd.DatetimeIndex([t[0], t[0] + pd.Timedelta("200D")]), "Asia/Kolkata")) == ["20:30"] * 2
    days = pd.DatetimeIndex(["2016-03-20 11:00", "2016-04-20 10:00"], tz="UTC")  # two dates across a change
    assert list(local_clock(days, "Europe/Berlin")) == ["12:00", "12:00"]
    assert list(local_clock(t[[2, 0]], "Australia/Sydney")) == ["02:00 UTC+10", "02:00 UTC+11"]  # out of order
    # West of Greenwich and at UTC itself the offset is written as --timezone takes it (one formatter, zone_label's)
    ny = pd.date_range("2016-11-06 05:00", periods=4, freq="30min", tz="UTC")
    assert list(local_clock(ny, "America/New_York")) == ["01:00 UTC-4", "01:30 UTC-4", "01:00 UTC-5", "01:30 UTC-5"]
    uk = pd.date_range("2016-10-30 00:00", periods=4, freq="30min", tz="UTC")
    assert list(local_clock(uk, "Europe/London")) == ["01:00 UTC+1", "01:30 UTC+1", "01:00 UTC", "01:30 UTC"]

    site = Site(-35.1, 147.4, 200.0, "Wagga Wagga", "Australia/Sydney")
    day = weather.add_solar(weather.read_weather(_clear_sky_csv(tmp_path / "w.csv", site, "2016-04-02")), site=site)
    night = day.loc["2016-04-02 13:00":"2016-04-02 18:00"]
    drawn = []
    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", lambda fig, *a, **k: drawn.append(fig))
    plot_forcing(night, tmp_path / "f.png", tz=site.timezone)
    x = mdates.date2num(drawn[0].axes[0].lines[1].get_xdata())  # the PAR line
    assert (np.diff(x) > 0).all()
    np.testing.assert_allclose(x[-1] - x[0], (night.index[-1] - night.index[0]) / pd.Timedelta("1D"), rtol=1e-9)


def test_a_window_that_leaves_much_of_the_days_light_out_is_said(tmp_path, monkeypatch):
    """The default window, 05:00–19:00, is Selhausen's spring day: at 60° N on 21 June it leaves 5 % of
    the day's light out, unsaid (a review). The share, from Haurwitz's clear sky, agrees with pvlib's
    Ineichen–Perez clear sky computed here to 1 % (absolute); above 2 % the command line cautions, and
    the main job (1.3 %) says nothing."""
    from lightfit.cli import common
    from lightfit.cli.options import ModelOptions, resolve, weather

    site = Site(60.0, 10.0, 0.0, "60° N", "Europe/Oslo")
    cfg = rep.ReplicationConfig(site=site, dates=("2016-06-21",))
    share = rep.light_outside_window(cfg, "2016-06-21")
    t = pd.date_range("2016-06-21", periods=24 * 60, freq="1min", tz="Europe/Oslo")
    ghi = pvlib.location.Location(60.0, 10.0, altitude=0.0).get_clearsky(t, model="ineichen")["ghi"]
    lo, hi = (pd.Timestamp(f"2016-06-21 {h}", tz="Europe/Oslo") for h in ("04:45", "19:15"))
    inside = (t >= lo) & (t <= hi)
    # two clear-sky models: Ineichen–Perez 4.4 %, Haurwitz 5.3 % (more low-sun light)
    assert share == pytest.approx(float(ghi[~inside].sum() / ghi.sum()), abs=0.01)
    assert 0.04 < share < 0.07 and rep.light_outside_window(rep.ReplicationConfig(), "2016-04-20") < 0.02

    said = []
    monkeypatch.setattr(common, "caution", said.append)
    weather(resolve(ModelOptions(quick=True)))
    assert said == []  # the main job's window
    path = _clear_sky_csv(tmp_path / "n60.csv", site, "2016-06-21")
    where = {"latitude": 60.0, "longitude": 10.0, "altitude_m": 0.0, "timezone": "Europe/Oslo"}
    weather(resolve(ModelOptions(quick=True, weather_file=str(path), dates=["2016-06-21"], **where)))
    (line,) = said
    assert f"leaves {share:.1%} of 2016-06-21's clear-sky light" in line and "--start-time and --hours" in line
    # a window the user chose is theirs: nothing said
    weather(resolve(ModelOptions(quick=True, weather_file=str(path), dates=["2016-06-21"], hours=10.0, **where)))
    assert len(said) == 1


@pytest.mark.parametrize(
    "where",
    [{"latitude_deg": 90.0}, {"latitude_deg": -90.0}, {"longitude_deg": 180.0}, {"longitude_deg": -180.0}],
)
def test_a_site_at_the_ends_of_the_coordinate_ranges_is_taken(where):
    """Latitude −90 … 90 and longitude −180 … 180 include their ends (a pole, the antimeridian), as
    Site's docstring states (a mutation audit: the ends refused survived)."""
    site = Site(**where)
    assert getattr(site, next(iter(where))) == next(iter(where.values()))


@pytest.mark.parametrize("attr", ["latitude_deg", "longitude_deg", "altitude_m"])
def test_a_site_coordinate_given_as_a_bool_is_refused(attr):
    """True is an int to Python (1°N, 1 m) but never a coordinate: refused naming the parameter (a
    mutation audit: the bool check dropped survived)."""
    with pytest.raises(InputError, match=attr):
        Site(**{attr: True})


def test_part_hour_offsets_are_written_with_their_minutes():
    """India (UTC+05:30, Asia/Kolkata), Newfoundland (UTC−03:30 in winter, America/St_Johns) and Nepal
    (UTC+05:45) as tables write them, by hand (a mutation audit: the minutes dropped, UTC+5 for India,
    survived)."""
    from lightfit.weather.site import local_clock, offset_label

    assert offset_label(pd.Timedelta(hours=5, minutes=30)) == "UTC+5:30"
    assert offset_label(-pd.Timedelta(hours=3, minutes=30)) == "UTC-3:30"
    assert offset_label(pd.Timedelta(hours=5, minutes=45)) == "UTC+5:45"
    assert offset_label(pd.Timedelta(0)) == "UTC" and offset_label(pd.Timedelta(hours=-5)) == "UTC-5"
    # a repeated local hour in a part-hour zone: Lord Howe Island falls back by 30 min (02:00 → 01:30)
    t = pd.DatetimeIndex(["2016-04-02 14:30", "2016-04-02 15:00"], tz="UTC")
    assert list(local_clock(t, "Australia/Lord_Howe")) == ["01:30 UTC+11", "01:30 UTC+10:30"]


def test_a_results_file_missing_some_site_keys_takes_selhausens_for_them():
    """Site.from_attrs reads key by key: a file recording only its latitude keeps Selhausen's longitude
    6.447° E, altitude 103 m and time zone (the reference paper's site, 50.865 N 6.447 E; a mutation
    audit: the latitude taken as the missing longitude's default survived)."""
    site = Site.from_attrs({"site": "south", "site_latitude_deg": -33.92})
    assert (site.latitude_deg, site.longitude_deg, site.altitude_m) == (-33.92, 6.447, 103.0)
    assert site.name == "south" and site.timezone == "Europe/Berlin"
    assert Site.from_attrs({}) == Site(50.865, 6.447, 103.0, "Selhausen", "Europe/Berlin")


def test_several_days_results_say_what_a_blades_value_at_another_days_step_is():
    """Several days' results (concat_days) have, at day 1's steps, day 2's blade segments with no value
    (limitation −1, converged 1, NaN): the file's own flag meanings and comments cover them. The −1 of
    limitation read "not_a_blade" on a segment whose is_blade is 1, and the comments said NaN / −1 / 1
    only where not a blade (a review)."""
    import xarray as xr

    def part(date):
        t = pd.DatetimeIndex([f"{date} 10:00"]).values
        return xr.Dataset(
            {
                "absorbed_par_umol_m2_s": (("time", "segment"), np.full((1, 2), 500.0)),
                "leaf_an_umol_m2_s": (("time", "segment"), np.array([[20.0, np.nan]])),
                "limitation": (("time", "segment"), np.array([[1, -1]], np.int8)),
                "converged": (("time", "segment"), np.array([[True, True]])),
            },
            coords={
                "time": t,
                "segment": [1, 2],
                "plant_id": ("segment", [0, 0]),
                "organ_type": ("segment", ["leaf", "stem"]),
                "area_m2": ("segment", [1.0, 1.0]),
                "is_blade": ("segment", [True, False]),
                "height_m": ("segment", [0.1, 0.2]),
            },
            attrs={"date": date, "window": "w", "target_date": date},
        )

    both = rep.concat_days([part("2016-04-20"), part("2016-05-20")])
    day2_blade = both.sel(segment=1 + rep.DAY_SEGMENT_STRIDE)
    assert bool(day2_blade["is_blade"]) and int(day2_blade["limitation"][0]) == -1  # a blade, day 1's step
    lim = both["limitation"].attrs
    meaning = dict(zip(lim["flag_values"].tolist(), lim["flag_meanings"].split()))[-1]
    assert meaning == "no_value"
    for name in ("limitation", "converged", "leaf_an_umol_m2_s", "absorbed_par_umol_m2_s"):
        assert "at the steps of another day" in both[name].attrs["comment"], name


def test_several_days_results_list_each_days_attributes_where_the_days_differ():
    """Several days' results (concat_days) kept the first day's attributes but date/window/target_date:
    a second day grown to its own date (another growth fingerprint) or run on another forcing file
    (weather_source, weather_provenance) was described by the first day's values (a review). Each
    day's value is listed where the days differ; what they share stays as it was."""
    import xarray as xr

    def part(date, source, provenance, fingerprint):
        return xr.Dataset(
            {"absorbed_par_umol_m2_s": (("time", "segment"), np.full((1, 1), 500.0))},
            coords={"time": pd.DatetimeIndex([f"{date} 10:00"]).values, "segment": [1]},
            attrs={
                "date": date,
                "window": "w",
                "target_date": date,
                "weather_source": source,
                "weather_provenance": provenance,
                "growth_fingerprint": fingerprint,
                "n_plants": 9,
            },
        )

    both = rep.concat_days(
        [
            part("2016-04-20", "a.csv", "measured", "f1"),
            part("2016-05-20", "b.csv", "reconstructed", "f2"),
        ]
    )
    assert both.attrs["weather_source"] == "a.csv; b.csv"
    assert both.attrs["weather_provenance"] == "measured; reconstructed"
    assert both.attrs["growth_fingerprint"] == "f1; f2"
    assert both.attrs["n_plants"] == 9  # shared: kept as the value it is
    same = rep.concat_days(
        [part("2016-04-20", "a.csv", "measured", "f1"), part("2016-05-20", "a.csv", "measured", "f2")]
    )
    assert same.attrs["weather_source"] == "a.csv" and same.attrs["weather_provenance"] == "measured"


def test_several_days_with_their_own_weather_anchors_are_read_per_day():
    """concat_days lists an attribute the days do not share, "; "-separated: two days of forcings
    anchored on different readings gave weather_anchor two JSON objects joined, and the report's
    reader (json.loads) raised on it (a review). Each day's readings are now held against that day's
    anchor: the label says the forcing is scaled to a reading only where that day's anchor is it."""
    import json
    from dataclasses import asdict

    import xarray as xr

    from lightfit.report import _anchored
    from lightfit.weather.reconstruct import Anchor

    def part(date, anchor):
        t = pd.DatetimeIndex([f"{date} 10:00", f"{date} 12:00"]).values
        attrs = {"date": date, "window": "w", "target_date": date}
        if anchor is not None:
            attrs["weather_anchor"] = json.dumps(asdict(anchor))
        return xr.Dataset(
            {"absorbed_par_umol_m2_s": (("time", "segment"), np.full((2, 1), 500.0))},
            coords={"time": t, "segment": [1]},
            attrs=attrs,
        )

    a1 = Anchor(time_local="2016-04-20 12:00:00", par_umol_m2_s=1549.31)
    a2 = Anchor(time_local="2016-05-20 12:00:00", par_umol_m2_s=900.0)
    both = rep.concat_days([part("2016-04-20", a1), part("2016-05-20", a2)])
    assert both.attrs["weather_anchor"].count("par_umol_m2_s") == 2  # each day's, joined
    said = "; the forcing is scaled to it"
    # day 2's noon reading is day 2's anchor
    assert _anchored(both, "above_canopy_par", np.array([700.0, 1200.0, 600.0, 900.0])) == said
    # each day's reading is the other day's anchor: neither forcing was scaled to it
    assert _anchored(both, "above_canopy_par", np.array([700.0, 900.0, 600.0, 1549.31])) == ""
    assert _anchored(both, "plant_par", np.array([700.0, 1200.0, 600.0, 900.0])) == ""  # other series: never
    # a day without an anchor (listed empty) after one with
    one = rep.concat_days([part("2016-04-20", a1), part("2016-05-20", None)])
    assert one.attrs["weather_anchor"].endswith("; ")
    assert _anchored(one, "above_canopy_par", np.array([700.0, 1549.31, 600.0, 900.0])) == said
    assert _anchored(one, "above_canopy_par", np.array([700.0, 900.0, 600.0, 1549.31])) == ""
    # a day without an anchor before one with: the second day's was dropped (the first day's attrs kept)
    late = rep.concat_days([part("2016-04-20", None), part("2016-05-20", a2)])
    assert late.attrs["weather_anchor"].startswith("; ")
    assert _anchored(late, "above_canopy_par", np.array([700.0, 1200.0, 600.0, 900.0])) == said
    assert _anchored(late, "above_canopy_par", np.array([700.0, 900.0, 600.0, 1000.0])) == ""
