"""Timestamps of interval means: the sun at each interval's centre, resampling that keeps whole
intervals, the convention carried through lightfit's CSV and the observations file, observations
matched to the step whose interval holds them, and bad input refused.

The reference for the sun is the NOAA solar calculator (``tests/test_weather_solar.py``,
independent of pvlib), evaluated minute by minute over each interval.
"""

import math

import numpy as np
import pandas as pd
import pytest
from test_weather_solar import noaa_apparent_elevation_deg

from lightfit.errors import InputError
from lightfit.inference.likelihood import GaussianLikelihood
from lightfit.inference.multiday import MultiDayModel
from lightfit.inference.observations import align, read_observations, write_observations
from lightfit.model.parameters import Theta
from lightfit.weather import (
    SELHAUSEN,
    add_solar,
    read_lightfit_csv,
    read_source,
    read_tereno,
    resample,
    window,
    write_lightfit_csv,
)
from lightfit.weather.bundled import DATA_DIR
from lightfit.weather.timestamps import Timestamps, step_of

FIXTURE = DATA_DIR / "fixtures" / "tereno_SE_EC_001_fixture.csv"


def _noaa(t: pd.Timestamp) -> float:
    return noaa_apparent_elevation_deg(t, SELHAUSEN.latitude_deg, SELHAUSEN.longitude_deg)


def test_sun_of_a_10_min_mean_is_its_intervals_mean_sun():
    """For end-stamped 10-min means, sin β lightfit uses equals the interval's minute-by-minute mean
    of NOAA's sin β to 0.5 % from 5° up (the stamp's own sin β is 16 % off at 5°, 8 % at 9°)."""
    df = add_solar(read_tereno(FIXTURE))
    rows = df[(df["sun_elevation_deg"] > 5) & (df["sun_elevation_deg"] < 25)]
    assert len(rows) >= 10
    for t, beta in rows["sun_elevation_deg"].items():
        minutes = [t - pd.Timedelta(seconds=30 + 60 * k) for k in range(10)]  # the interval's minute centres
        mean_sin = np.mean([math.sin(math.radians(_noaa(m))) for m in minutes])
        assert math.sin(math.radians(beta)) == pytest.approx(mean_sin, rel=5e-3)
        assert beta == pytest.approx(_noaa(t - pd.Timedelta(minutes=5)), abs=0.05)
    t0, beta0 = rows.index[0], rows["sun_elevation_deg"].iloc[0]
    assert abs(math.sin(math.radians(_noaa(t0))) / math.sin(math.radians(beta0)) - 1) > 0.08


def test_sun_elevation_is_described_as_what_it_is(tmp_path):
    """sun_elevation_deg is the apparent (refracted) elevation at the centre of each stamp's interval:
    NOAA's apparent elevation 5 min before the end-stamps of 10-min means (0.8° below the stamp's
    own at 9.4° in the morning; the refraction there lifts it 0.09° above the true one). Its
    descriptions said "apparent solar elevation" (lightfit's CSV) and "solar elevation angle"
    (results.nc's long_name), neither saying when."""
    from lightfit.model.schema import VARIABLES
    from lightfit.weather.series import COLUMNS

    df = add_solar(read_tereno(FIXTURE))
    t = df.index[(df["sun_elevation_deg"] > 8) & (df["sun_elevation_deg"] < 12)][0]
    assert df.loc[t, "sun_elevation_deg"] == pytest.approx(_noaa(t - pd.Timedelta("5min")), abs=0.05)
    assert _noaa(t) - df.loc[t, "sun_elevation_deg"] > 0.4  # not the stamp's sun
    for said in (VARIABLES["sun_elevation_deg"].long_name, COLUMNS["sun_elevation_deg"]):
        assert "apparent" in said and "refraction" in said and "centre of" in said and "interval" in said, said
    assert "same instant as sun_elevation_deg" in VARIABLES["sun_azimuth_deg"].long_name
    csv = write_lightfit_csv(df, tmp_path / "w.csv", {"provenance": "synthetic"})
    (columns,) = [x for x in csv.read_text(encoding="utf-8").splitlines() if x.startswith("# columns:")]
    assert "sun_elevation_deg: apparent (refraction-corrected) solar elevation at the centre of" in columns


def test_instants_keep_the_sun_at_their_stamps():
    """The bundled reconstruction is computed at instants: its sun is at its stamps."""
    df = add_solar(read_source("2016-04-20"))
    assert df.attrs["timestamps"] == Timestamps()
    t = pd.Timestamp("2016-04-20 06:00", tz="UTC")
    assert df.loc[t, "sun_elevation_deg"] == pytest.approx(_noaa(t), abs=0.05)
    assert not [q for q in df.attrs["qc"] if q["kind"] == "sun at centres"]


def test_mean_resampling_keeps_whole_intervals_and_their_stamps():
    """30-min means of end-stamped 10-min means: the three rows that end within (t − 30 min, t],
    stamped at t, the sun 15 min before t."""
    df = add_solar(read_tereno(FIXTURE))
    r = resample(df, "30min", "mean")
    assert r.attrs["timestamps"] == Timestamps("end", pd.Timedelta("30min"))
    t = pd.Timestamp("2016-04-20 07:00", tz="UTC")
    rows = df.loc[t - pd.Timedelta("20min") : t, "ghi_w_m2"]
    assert len(rows) == 3
    assert r.loc[t, "ghi_w_m2"] == pytest.approx(rows.mean(), rel=1e-12)
    assert r.loc[t, "sun_elevation_deg"] == pytest.approx(_noaa(t - pd.Timedelta("15min")), abs=0.05)
    # Sub-sampling keeps the 10-min means and their meaning.
    s = resample(df, "30min", "sample")
    assert s.attrs["timestamps"] == df.attrs["timestamps"]
    assert s.loc[t, "sun_elevation_deg"] == df.loc[t, "sun_elevation_deg"]


def test_instant_series_mean_resampling_is_centred():
    df = add_solar(read_source("2016-04-20"))
    r = resample(df, "30min", "mean")
    assert r.attrs["timestamps"] == Timestamps("center", pd.Timedelta("30min"))
    t = pd.Timestamp("2016-04-20 12:00", tz="UTC")
    window = df.loc[t - pd.Timedelta("10min") : t + pd.Timedelta("10min"), "ghi_w_m2"]
    assert r.loc[t, "ghi_w_m2"] == pytest.approx(window.mean())
    assert r.loc[t, "sun_elevation_deg"] == df.loc[t, "sun_elevation_deg"]


def test_mean_of_instants_drops_steps_the_series_covers_only_in_part():
    """10-min instants 09:00 … 11:00 UTC of a linear ramp (1 W m⁻² per minute) at 30 min: the windows
    centred on 09:00 and 11:00 reach 15 min past the series (it covers 08:55 … 11:05, each row
    standing for its 10 min) and were kept as whole means, 09:00's the mean of the rows 09:00 and
    09:10 (5 W m⁻², the ramp's value at 09:05, stamped 09:00); they are dropped and said, as for
    means of means, and a series covering no step whole is refused rather than returned empty."""
    t = pd.date_range("2016-04-20 09:00", "2016-04-20 11:00", freq="10min", tz="UTC")
    minutes = np.asarray((t - t[0]) / pd.Timedelta(minutes=1), float)
    df = pd.DataFrame({"ghi_w_m2": minutes, "tair_c": 10.0, "rh": 0.5, "pair_kpa": 100.0, "co2_ppm": 400.0}, index=t)
    r = resample(df, "30min", "mean")
    assert list(r.index) == list(pd.date_range("2016-04-20 09:30", "2016-04-20 10:30", freq="30min", tz="UTC"))
    np.testing.assert_allclose(r["ghi_w_m2"], [30.0, 60.0, 90.0], rtol=0, atol=1e-9)  # the ramp at each stamp
    (drop,) = [q for q in r.attrs["qc"] if q["kind"] == "dropped"]
    assert drop["count"] == 2 and "09:00" in drop["detail"] and "11:00" in drop["detail"]
    h = resample(df, "1h", "mean")
    assert list(h.index) == [pd.Timestamp("2016-04-20 10:00", tz="UTC")] and h["ghi_w_m2"].iloc[0] == 60.0
    with pytest.raises(InputError, match=r"parameter 'freq'.*covers no 1h step whole"):
        resample(df.iloc[:3], "1h", "mean")
    with pytest.raises(InputError, match="cover only"):  # a window whose first step is partial
        window(df, "2016-04-20 09:00", 1, "30min", how="mean", tz="UTC")


@pytest.mark.parametrize(("source", "freq"), [("10min", "1h"), ("30min", "1h"), ("10min", "20min")])
def test_mean_of_instants_over_an_even_number_of_rows_is_centred_on_its_stamp(source, freq):
    """With an even number of source rows per step, one row lies on each bound of a centred window:
    it counts half in each (the trapezoid rule), so that the mean of a quantity linear in time is its
    value at the stamp. A half-open window counted it whole in the later step: the hourly mean of
    10-min instants was the value 5 min before the stamp (15 min for 30-min instants)."""
    t = pd.date_range("2016-04-20 00:00", "2016-04-20 23:50", freq=source, tz="UTC")
    minutes = (t - t[0]) / pd.Timedelta(minutes=1)
    df = pd.DataFrame(
        {"ghi_w_m2": np.asarray(minutes, float), "tair_c": 10.0, "rh": 0.5, "pair_kpa": 100.0, "co2_ppm": 400.0},
        index=t,
    )
    r = resample(df, freq, "mean")
    assert r.attrs["timestamps"] == Timestamps("center", pd.Timedelta(freq))
    inside = r.index[(r.index > t[0] + pd.Timedelta(freq)) & (r.index < t[-1] - pd.Timedelta(freq))]
    assert len(inside) > 10
    expected = (inside - t[0]) / pd.Timedelta(minutes=1)  # a linear ramp's mean over a centred window
    np.testing.assert_allclose(r.loc[inside, "ghi_w_m2"], expected, rtol=0, atol=1e-9)
    np.testing.assert_allclose(r.loc[inside, "tair_c"], 10.0)


def test_lightfit_csv_carries_the_convention(tmp_path):
    df = add_solar(read_tereno(FIXTURE))
    p = write_lightfit_csv(df, tmp_path / "forcing.csv", {"provenance": "synthetic"})
    text = p.read_text(encoding="utf-8")
    assert "# time_label: end\n# averaging_interval: 10min\n" in text
    back = read_lightfit_csv(p)
    assert back.attrs["timestamps"] == df.attrs["timestamps"]
    np.testing.assert_allclose(add_solar(back)["sun_elevation_deg"], df["sun_elevation_deg"], atol=1e-9)
    # A file that does not say holds instants.
    lines = [ln for ln in text.splitlines() if not ln.startswith(("# time_label", "# averaging_interval"))]
    old = tmp_path / "old.csv"
    old.write_text("\n".join(lines) + "\n", encoding="utf-8")
    assert read_lightfit_csv(old).attrs["timestamps"] == Timestamps()


@pytest.mark.parametrize(
    ("meta", "match"),
    [
        ({"time_label": "middle", "averaging_interval": "10min"}, "time_label.*middle"),
        ({"time_label": "end"}, "averaging_interval"),
        ({"time_label": "end", "averaging_interval": "ten minutes"}, "averaging_interval: ten minutes"),
        ({"time_label": "instant", "averaging_interval": "10min"}, "averaging_interval"),
        # NaT compared False with 0: the file was read, and every mean went to one step's centre
        ({"time_label": "end", "averaging_interval": "nan"}, "averaging_interval"),
        # a bare number is nanoseconds to pandas: 30-min means were read as instants at their stamps
        ({"time_label": "end", "averaging_interval": "30"}, "averaging_interval: 30' has no unit"),
    ],
)
def test_bad_metadata_names_the_file_and_key(tmp_path, meta, match):
    df = read_source("2016-04-20").iloc[:3]
    p = write_lightfit_csv(df, tmp_path / "bad.csv", {"provenance": "synthetic"} | meta)
    with pytest.raises(InputError, match=match) as e:
        read_lightfit_csv(p)
    assert "bad.csv" in str(e.value)


def test_bad_time_label_argument():
    with pytest.raises(InputError, match="time_label"):
        read_tereno(FIXTURE, time_label="middle")
    with pytest.raises(InputError, match="averaging_interval"):
        Timestamps("end", pd.Timedelta("-10min"))


def test_cplantbox_day_reads_as_end_stamped_means():
    """The bundled real day: its lit rows (PAR > 0) are centred nearest solar transit (NOAA's
    11:32 UTC on the examples' date, 2016-04-27) when the stamps end their 10-min means: 8 min
    after it, against 13 min read as instants and 18 min as starts. Evidence for the default, not
    proof: a sensor's dark threshold need not be symmetric."""
    df = read_source("selhausen-cplantbox-day", date="2016-04-27")
    stamps = df.attrs["timestamps"]
    assert (stamps.label, stamps.interval) == ("end", pd.Timedelta("10min"))
    lit = df.index[df["par_umol_m2_s"] > 0]
    mid = lit[0] + (lit[-1] - lit[0]) / 2
    minutes = pd.date_range("2016-04-27 11:00", "2016-04-27 12:00", freq="1min", tz="UTC")
    transit = minutes[int(np.argmax([_noaa(m) for m in minutes]))]
    assert abs(transit - pd.Timestamp("2016-04-27 11:32", tz="UTC")) <= pd.Timedelta("1min")
    ten = pd.Timedelta("10min")
    off = {label: abs(mid + Timestamps(label, ten).centre_offset - transit) for label in ("start", "end")}
    off["instant"] = abs(mid - transit)
    assert off["end"] < off["instant"] < off["start"]
    assert off["end"] <= pd.Timedelta("10min")


def test_mean_resampling_drops_partial_steps_and_refuses_misfits():
    """Steps the series covers only in part are dropped and reported, a step that is not a multiple
    of the means' interval is refused, and so is a window whose first step reaches before the data."""
    df = add_solar(read_tereno(FIXTURE)).loc["2016-04-20 08:20":"2016-04-20 09:10"]
    r = resample(df, "30min", "mean")
    assert list(r.index) == [pd.Timestamp("2016-04-20 09:00", tz="UTC")]
    assert r["ghi_w_m2"].iloc[0] == pytest.approx(df.loc["2016-04-20 08:40":"2016-04-20 09:00", "ghi_w_m2"].mean())
    dropped = [q for q in r.attrs["qc"] if q["kind"] == "dropped"]
    assert dropped and dropped[0]["count"] == 2
    with pytest.raises(InputError, match="multiple"):
        resample(df, "15min", "mean")
    with pytest.raises(InputError, match="multiple"):  # means of sampled means would be mislabelled
        resample(resample(add_solar(read_tereno(FIXTURE)), "30min", "sample"), "60min", "mean")
    with pytest.raises(InputError, match="whole 30min steps"):
        window(df, "2016-04-20 08:20", 0.5, "30min", how="mean", tz="UTC")


def test_co2_of_a_missing_30_min_mean_is_a_gap_not_the_previous_one(tmp_path):
    """A blank 30-min CO2 value leaves its interval's rows empty for the gap repair (interpolated
    across, as any gap), instead of holding the previous interval's mean forward."""
    lines = FIXTURE.read_text(encoding="utf-8").splitlines()
    i = next(k for k, ln in enumerate(lines) if ln.startswith("2016-04-20 04:30:00"))
    lines[i] = lines[i].rsplit(",", 1)[0] + ","
    p = tmp_path / "gap.csv"
    p.write_text("\n".join(lines) + "\n", encoding="utf-8")
    df = read_tereno(p)
    before, after = df.loc["2016-04-20 03:00", "co2_ppm"], df.loc["2016-04-20 04:00", "co2_ppm"]
    # 03:10–03:30 UTC were the missing mean's rows: a gap between 03:00 and 03:40, which with
    # 03:50 belongs to the mean stamped 04:00.
    mid = df.loc["2016-04-20 03:10":"2016-04-20 03:50", "co2_ppm"].to_numpy()
    np.testing.assert_allclose(mid[:3], np.interp([1, 2, 3], [0, 4], [before, after]), rtol=1e-12)
    assert (mid[:3] != before).all() and (mid[3:] == after).all()


# -- observations ---------------------------------------------------------------------------

END10 = Timestamps("end", pd.Timedelta("10min"))
STEPS = pd.date_range("2016-04-20 10:10", "2016-04-20 12:00", freq="10min", tz="UTC")  # ends of 10-min means


def _obs(index, label=None, interval=None, source="obs.csv"):
    df = pd.DataFrame(
        {"above_canopy_par_umol_m2_s": np.arange(len(index), dtype=float) + 1.0, "above_canopy_par_sd_umol_m2_s": 1.0},
        index=pd.DatetimeIndex(index),
    )
    df.attrs = {"source": source} | ({} if label is None else {"timestamps": Timestamps(label, interval)})
    return df


def test_spot_observations_go_to_the_mean_whose_interval_holds_them():
    """Reference: the 10-min interval (stamp − 10 min, stamp] that holds an instant t is the one
    stamped at t rounded up to 10 min (interval arithmetic, not the code's nearest-centre rule).
    Matching by stamp instead sends every instant in the first half of an interval to the mean
    before it."""
    rng = np.random.default_rng(7)
    t = STEPS[0] - pd.Timedelta("10min") + pd.to_timedelta(rng.uniform(0.5, 599.5, 200) * 11, unit="s")
    t = t[t < STEPS[-1] - pd.Timedelta("1s")]
    obs = _obs(t)
    expected = np.searchsorted(STEPS, t.ceil("10min"))
    a = align(obs, STEPS, END10)
    for k in range(len(STEPS)):  # each step's value is the mean of the instants its interval holds
        held = obs["above_canopy_par_umol_m2_s"].to_numpy()[expected == k]
        got = a["above_canopy_par_umol_m2_s"][k]
        assert (np.isnan(got) and not len(held)) or got == pytest.approx(held.mean())
    # The reference paper's chamber reading at 12:13:48 (local 14:13:48 CEST): held by the mean
    # stamped 12:20 UTC, where matching by stamp would give 12:10.
    steps, chamber = STEPS.shift(3), _obs(pd.DatetimeIndex(["2016-04-20 12:13:48"], tz="UTC"))
    for stamps, stamp in ((END10, "12:20"), (Timestamps(), "12:10")):
        got = np.flatnonzero(np.isfinite(align(chamber, steps, stamps)["above_canopy_par_umol_m2_s"]))
        assert got.tolist() == [steps.get_loc(pd.Timestamp(f"2016-04-20 {stamp}", tz="UTC"))]


def test_means_meet_means_by_interval_not_by_stamp():
    """A logger's end-stamped 10-min means against a run stamped at the starts of the same
    intervals: the mean stamped 10:20 (10:10–10:20) is the run's step stamped 10:10."""
    starts = STEPS - pd.Timedelta("10min")
    obs = _obs(STEPS[2:5], "end", pd.Timedelta("10min"))
    a = align(obs, starts, Timestamps("start", pd.Timedelta("10min")))
    np.testing.assert_array_equal(np.flatnonzero(np.isfinite(a["above_canopy_par_umol_m2_s"])), [2, 3, 4])
    np.testing.assert_array_equal(a["above_canopy_par_umol_m2_s"][2:5], [1.0, 2.0, 3.0])
    lik = GaussianLikelihood(obs, starts, stamps=Timestamps("start", pd.Timedelta("10min")))
    np.testing.assert_array_equal(np.flatnonzero(np.asarray(lik.mask["above_canopy_par"])), [2, 3, 4])


def test_means_longer_than_a_step_are_refused():
    obs = _obs(STEPS[3:4], "end", pd.Timedelta("30min"), source="nee_30min.csv")
    with pytest.raises(InputError, match="30-min means") as e:
        align(obs, STEPS, END10)
    assert e.value.file is not None and "nee_30min.csv" in str(e.value.file)
    assert e.value.column == "averaging_interval"
    # A run sampled every 30 min from 10-min means (--how sample) still has 10-min means at its steps.
    with pytest.raises(InputError, match="30-min means"):
        align(obs, STEPS[::3], END10)


def test_a_mean_straddling_two_steps_is_refused():
    """12:05–12:15 against 10-min steps (12:00, 12:10], (12:10, 12:20]: half in each."""
    obs = _obs(pd.DatetimeIndex(["2016-04-20 11:15"], tz="UTC"), "end", pd.Timedelta("10min"), source="half.csv")
    with pytest.raises(InputError, match="straddles") as e:
        align(obs, STEPS, END10)
    assert "half.csv" in str(e.value.file)


def test_an_instant_on_a_border_goes_to_the_interval_that_holds_it():
    """11:10 ends (11:00, 11:10] of end-stamps and starts [11:10, 11:20) of start-stamps."""
    reading = _obs(pd.DatetimeIndex(["2016-04-20 11:10"], tz="UTC"))
    for stamps, steps, holder in (
        (END10, STEPS, "11:10"),  # the interval stamped 11:10 ends at the reading
        (Timestamps("start", pd.Timedelta("10min")), STEPS, "11:10"),  # the one stamped 11:10 starts at it
    ):
        got = np.flatnonzero(np.isfinite(align(reading, steps, stamps)["above_canopy_par_umol_m2_s"]))
        assert got.tolist() == [steps.get_loc(pd.Timestamp(f"2016-04-20 {holder}", tz="UTC"))], stamps


def test_a_run_cut_to_one_step_keeps_the_observations_it_had():
    """Calibration cuts a run to its observed steps; a 10-min-means run sampled every 30 min cut to
    one step must still take the spot reading the whole run gave to that step."""
    sampled = STEPS[::3]  # 10:10, 10:40, …: 10-min means every 30 min
    reading = _obs(pd.DatetimeIndex(["2016-04-20 10:22"], tz="UTC"), source="spot.csv")
    whole = np.isfinite(align(reading, sampled, END10)["above_canopy_par_umol_m2_s"])
    assert np.flatnonzero(whole).tolist() == [1]  # centre 10:35, 13 min away; 10:05 is 17 min away
    cut = align(reading, sampled[1:2], END10)["above_canopy_par_umol_m2_s"]
    assert cut.tolist() == [1.0]


def test_observations_file_carries_its_time_label(tmp_path):
    obs = _obs(STEPS[:3], "end", pd.Timedelta("10min"))
    p = write_observations(obs, tmp_path / "o.csv", {"provenance": "synthetic"})
    text = p.read_text(encoding="utf-8")
    assert "# time_label: end\n" in text and "# averaging_interval: 10min\n" in text
    assert read_observations(p).attrs["timestamps"] == END10
    plain = tmp_path / "plain.csv"
    plain.write_text(
        "# provenance: measured\n# time_zone: UTC\ntime,above_canopy_par_umol_m2_s,above_canopy_par_sd_umol_m2_s\n"
        "2016-04-20 12:13:48,1549.31,77.47\n",
        encoding="utf-8",
    )
    assert read_observations(plain).attrs["timestamps"] == Timestamps()
    bad = tmp_path / "bad.csv"
    bad.write_text("# time_label: middle\n" + plain.read_text(encoding="utf-8"), encoding="utf-8")
    with pytest.raises(InputError, match="middle") as e:
        read_observations(bad)
    assert "bad.csv" in str(e.value.file) and e.value.column == "time_label"
    # an interval that is no duration ('nan' reads as NaT): both readings went to the first of the run's
    # steps, averaged into one observation, without a word
    bad.write_text("# time_label: start\n# averaging_interval: nan\n" + plain.read_text(encoding="utf-8"))
    with pytest.raises(InputError, match="averaging interval NaT") as e:
        read_observations(bad)
    assert "bad.csv" in str(e.value.file) and e.value.column == "averaging_interval"
    # minutes without their unit: pandas reads '30' as 30 ns, and end-stamped 30-min means were read
    # at their stamps, 15 min after their centres, without a word
    bad.write_text("# time_label: end\n# averaging_interval: 30\n" + plain.read_text(encoding="utf-8"))
    with pytest.raises(InputError, match="has no unit") as e:
        read_observations(bad)
    assert "bad.csv" in str(e.value.file) and e.value.column == "averaging_interval"


def test_write_observations_keeps_what_its_metadata_states(tmp_path):
    """A table built in code says nothing in its attrs; metadata that states the rows' time label or
    canopy An's area is what the file says (a stated 'canopy_an_per: leaf' was written as ground,
    LAI x off; a stated 10-min interval was written beside 'time_label: instant', a file its reader
    refuses). Metadata that contradicts the attrs is refused, naming the key."""
    times = pd.date_range("2016-04-20 09:10", periods=3, freq="10min", tz="UTC")
    df = pd.DataFrame({"canopy_an_umol_m2_s": [2.0, 3.0, 4.0], "canopy_an_sd_umol_m2_s": 0.5}, index=times)
    said = {"provenance": "measured", "canopy_an_per": "leaf", "time_label": "end", "averaging_interval": "10min"}
    back = read_observations(write_observations(df, tmp_path / "o.csv", said))
    assert back.attrs["canopy_an_per"] == "leaf"
    assert back.attrs["timestamps"] == Timestamps("end", pd.Timedelta("10min"))
    np.testing.assert_array_equal(back["canopy_an_umol_m2_s"], [2.0, 3.0, 4.0])
    df.attrs = {"canopy_an_per": "ground", "timestamps": Timestamps()}
    with pytest.raises(InputError, match="leaf area") as e:
        write_observations(df, tmp_path / "x.csv", {"provenance": "measured", "canopy_an_per": "leaf"})
    assert e.value.column == "canopy_an_per"
    with pytest.raises(InputError, match="ends of 10-min means") as e:
        write_observations(
            df, tmp_path / "x.csv", {"provenance": "measured", "time_label": "end", "averaging_interval": "10min"}
        )
    assert e.value.column == "time_label"


def test_write_observations_keeps_fractions_of_a_second(tmp_path):
    """A chamber log's times to the tenth of a second are read as written; written back, they were
    cut to whole seconds: readings 0.2 s apart became one time, which the reader refuses."""
    p = tmp_path / "log.csv"
    p.write_text(
        "# provenance: measured\n# time_zone: UTC\n"
        "time,above_canopy_par_umol_m2_s,above_canopy_par_sd_umol_m2_s\n"
        "2016-04-20 12:10:00.5,1000,10\n2016-04-20 12:10:00.7,1010,10\n2016-04-20 12:11:00,1020,10\n",
        encoding="utf-8",
    )
    back = read_observations(
        write_observations(read_observations(p), tmp_path / "back.csv", {"provenance": "measured"})
    )
    expected = pd.DatetimeIndex(["2016-04-20 12:10:00.5", "2016-04-20 12:10:00.7", "2016-04-20 12:11:00"], tz="UTC")
    assert (back.index == expected).all()
    np.testing.assert_array_equal(back["above_canopy_par_umol_m2_s"], [1000.0, 1010.0, 1020.0])
    # whole seconds are written as before
    whole = write_observations(read_observations(p).iloc[2:], tmp_path / "whole.csv", {"provenance": "measured"})
    assert "\n2016-04-20T12:11:00Z," in whole.read_text(encoding="utf-8")


class _Day:
    """What :class:`MultiDayModel` reads of a day's model."""

    def __init__(self, times, stamps):
        self.times, self.timestamps = times, stamps
        self.step = step_of(times) or pd.Timedelta(0)
        self.day = np.ones(len(times), bool)
        self.scenario = type("S", (), {"theta": Theta()})()


def test_days_split_observations_by_interval():
    """An instant 1 min after day one's last stamp lies in day two's first interval (end-stamps)."""
    d1 = pd.date_range("2016-04-20 10:10", periods=3, freq="10min", tz="UTC")
    d2 = d1 + pd.Timedelta("30min")  # 10:40 …: interval of 10:40 is (10:30, 10:40]
    m = MultiDayModel({"2016-04-20a": _Day(d1, END10), "2016-04-20b": _Day(d2, END10)})
    obs = _obs(pd.DatetimeIndex(["2016-04-20 10:31", "2016-04-20 10:29"], tz="UTC"))
    parts = m.split(obs)
    assert parts["2016-04-20a"].index.minute.tolist() == [29]
    assert parts["2016-04-20b"].index.minute.tolist() == [31]
    with pytest.raises(InputError, match="stamps differ"):
        MultiDayModel({"a": _Day(d1, END10), "b": _Day(d2, Timestamps())})


def test_several_days_interpolate_within_their_longest_step_and_never_across_a_night():
    """MultiDayModel.step is the longest of its days' forcing steps (0 when every day has one step);
    a reading after day one's last step is then not read towards day two's first."""
    from lightfit.inference.observations import interpolated

    d1 = pd.date_range("2016-04-20 10:00", periods=3, freq="30min", tz="UTC")
    d2 = pd.date_range("2016-04-21 10:00", periods=4, freq="10min", tz="UTC")
    m = MultiDayModel({"2016-04-20": _Day(d1, Timestamps()), "2016-04-21": _Day(d2, Timestamps())})
    assert m.step == pd.Timedelta("30min")
    late = pd.DataFrame(
        {"above_canopy_par_umol_m2_s": [1500.0, 1500.0], "above_canopy_par_sd_umol_m2_s": [10.0, 10.0]},
        index=pd.DatetimeIndex(["2016-04-20 11:10", "2016-04-20 10:40"], tz="UTC"),
    )
    assert interpolated(late.iloc[1:], m.times, Timestamps(), m.step)  # between 10:30 and 11:00
    assert not interpolated(late.iloc[:1], m.times, Timestamps(), m.step)  # after 11:00: nearest
    ones = MultiDayModel({"a": _Day(d1[:1], Timestamps()), "b": _Day(d2[:1], Timestamps())})
    assert ones.step == pd.Timedelta(0)
    assert not interpolated(late.iloc[:1], ones.times, Timestamps(), ones.step)


@pytest.mark.parametrize(
    "label, before, after",
    [("end", "10min", "0min"), ("start", "0min", "10min"), ("center", "5min", "5min")],
)
def test_time_bounds_cover_each_stamps_own_interval(label, before, after):
    """CF time_bnds by hand: an end-stamped 10-min mean covers (t − 10 min, t), a start-stamped one
    (t, t + 10 min), a centred one (t − 5 min, t + 5 min); instants have none. A mutation audit
    found only end stamps tested (bounds that assumed end stamps survived)."""
    t = pd.date_range("2016-04-20 10:00", periods=3, freq="10min", tz="UTC")
    lo, hi = Timestamps(label, pd.Timedelta("10min")).bounds(t)
    assert lo.equals(t - pd.Timedelta(before)) and hi.equals(t + pd.Timedelta(after))
    assert Timestamps().bounds(t) is None


def test_a_one_step_run_of_hourly_means_takes_a_reading_within_its_half_hour():
    """One step, an end-stamped 60-min mean (centre 10:30): a reading at 10:50, 20 min from the
    centre, is inside what the step stands for (half the averaging interval), 31 min is not. A
    mutation audit: the one-step spacing without the averaging interval (15 min) survived."""
    times = pd.DatetimeIndex(["2016-04-20 11:00"], tz="UTC")
    hourly = Timestamps("end", pd.Timedelta("60min"))

    def reading(at):
        obs = pd.DataFrame(
            {"above_canopy_par_umol_m2_s": [1500.0], "above_canopy_par_sd_umol_m2_s": [75.0]},
            index=pd.DatetimeIndex([at], tz="UTC"),
        )
        return align(obs, times, hourly)["above_canopy_par_umol_m2_s"]

    assert reading("2016-04-20 10:50")[0] == 1500.0
    assert reading("2016-04-20 10:10")[0] == 1500.0
    with pytest.raises(InputError, match="lies outside the run"):
        reading("2016-04-20 11:01")


def test_sampled_steps_pass_through_the_origin_from_the_series_start():
    """Sampling at 30 min through an origin inside the series (12:10 UTC) takes every row on that
    grid, from the first one in the series (00:10) to the last (23:40), not only those from the origin
    on (resample's docstring: the new steps pass through ``origin``; a mutation audit: the steps
    started at the origin itself survived, window() cutting there anyway)."""
    from lightfit.weather.bundled import bundled_path

    df = read_lightfit_csv(bundled_path("2016-04-20"))
    origin = pd.Timestamp("2016-04-20 12:10", tz="UTC")
    out = resample(df, "30min", "sample", origin=origin)
    want = pd.date_range("2016-04-20 00:10", "2016-04-20 23:40", freq="30min", tz="UTC")
    assert list(out.index) == list(want) and origin in out.index
    np.testing.assert_array_equal(out["tair_c"].to_numpy(), df.loc[want, "tair_c"].to_numpy())


def test_mean_steps_whose_bounds_cut_a_source_interval_are_refused():
    """A window of 30-min means from 07:05 UTC over end-stamped 10-min means: its first mean, stamped
    07:35, took the rows ending 07:10, 07:20, 07:30, which cover 07:00–07:30 (by hand), so its sun
    (07:20) was 5 min late against the data's centre (07:15). Refused, naming the start time; on the
    stamps' grid the mean is the three rows ending within (t − 30 min, t] and the sun at t − 15 min."""
    df = add_solar(read_tereno(FIXTURE))
    with pytest.raises(InputError, match="falls inside a source interval") as e:
        window(df, "2016-04-20 07:05", 1, "30min", how="mean", tz="UTC")
    assert e.value.parameter == "start_time"
    w = window(df, "2016-04-20 07:00", 1, "30min", how="mean", tz="UTC")
    t = pd.Timestamp("2016-04-20 07:30", tz="UTC")
    rows = df.loc[t - pd.Timedelta("20min") : t, "ghi_w_m2"]
    assert w.loc[t, "ghi_w_m2"] == pytest.approx(rows.mean(), rel=1e-12)
    assert w.loc[t, "sun_elevation_deg"] == pytest.approx(_noaa(t - pd.Timedelta("15min")), abs=0.05)
