"""Readers on the real CPlantBox day and the TERENO-layout fixture, and every bad-input case."""

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from lightfit.errors import InputError
from lightfit.weather import read_cplantbox_day, read_tereno, read_weather, resample, units, window
from lightfit.weather.bundled import DATA_DIR, bundled_path

FIXTURE = DATA_DIR / "fixtures" / "tereno_SE_EC_001_fixture.csv"
CPB = DATA_DIR / "weather" / "selhausen_cplantbox_day.txt"


def _table_lines(path: Path) -> tuple[list[str], int]:
    lines = path.read_text(encoding="utf-8").splitlines()
    hdr = next(i for i, ln in enumerate(lines) if ln.startswith("Timestamp"))
    return lines, hdr


def _variant(tmp_path, edit) -> Path:
    """A copy of the fixture with ``edit(lines, header_index)`` applied."""
    lines, hdr = _table_lines(FIXTURE)
    lines = edit(lines, hdr) or lines
    p = tmp_path / "export.csv"
    p.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return p


def test_tereno_fixture_reads_and_converts():
    df = read_tereno(FIXTURE)
    lines, hdr = _table_lines(FIXTURE)
    first = lines[hdr + 1].split(",")
    # Timestamps are UTC+1 in the file -> one hour earlier in UTC.
    assert df.index[0] == pd.Timestamp(first[0], tz="UTC") - pd.Timedelta("1h")
    assert df.index.tz is not None and str(df.index.tz) == "UTC"
    assert len(df) == len(lines) - hdr - 1
    # Unit conversions of the first row, by the independent formulas in units.py.
    t, ah, p_mbar, co2 = float(first[4]), float(first[5]), float(first[6]), float(first[7])
    assert df["tair_c"].iloc[0] == pytest.approx(t)
    assert df["pair_kpa"].iloc[0] == pytest.approx(p_mbar / 10)
    assert df["rh"].iloc[0] == pytest.approx(units.relative_humidity_from_absolute(ah, t))
    assert df["co2_ppm"].iloc[0] == pytest.approx(units.co2_ppm_from_mmol_m3(co2, t, p_mbar / 10))
    assert df.attrs["provenance"] == "synthetic"  # its header says "SYNTHETIC FIXTURE" (and data/README.md)
    # The quality flags are read (and not listed as unused), each with the column it flags.
    assert df.attrs["quality_flags"] == {"ghi_w_m2": "RadiationGlobal_Avg10min QualityFlag"}
    assert "RadiationGlobal_Avg10min QualityFlag" not in df.attrs["unused_columns"]
    assert not df.isna().any().any()


def test_tereno_fixture_night_offsets_clamped_and_counted():
    df = read_tereno(FIXTURE)
    clamp = [q for q in df.attrs["qc"] if q["kind"] == "clamped" and q["column"] == "par_umol_m2_s"]
    assert clamp and clamp[0]["count"] == 2
    assert (df["par_umol_m2_s"] >= 0).all()


def test_a_missing_temperature_does_not_lose_the_co2_and_humidity_it_converts(tmp_path):
    """CO2 in mmol m⁻³ and absolute humidity convert with the row's air temperature: where only the
    temperature is missing they are converted with it interpolated in time, and the checks say so (a
    review: the file's CO2 was lost there and then reported as "missing, interpolated")."""
    text = FIXTURE.read_text(encoding="utf-8").splitlines(True)
    gap = ("2016-04-20 04:30:00,", "2016-04-20 04:40:00,")
    blanked = []
    for ln in text:
        if ln.startswith(gap):
            cells = ln.split(",")
            cells[4] = ""  # AirTemperature
            ln = ",".join(cells)
        blanked.append(ln)
    f = tmp_path / "no_t.csv"
    f.write_text("".join(blanked), encoding="utf-8")
    ref, df = read_tereno(FIXTURE), read_tereno(f)
    at = pd.Timestamp("2016-04-20 04:30", tz="Etc/GMT-1")
    # the temperature's own gap is filled (and said) as before; CO2 and RH keep the file's readings,
    # converted at the interpolated 10.393 °C instead of the file's 10.39 °C
    assert df.loc[at, "co2_ppm"] == pytest.approx(ref.loc[at, "co2_ppm"], rel=1e-4)
    assert df.loc[at, "rh"] == pytest.approx(ref.loc[at, "rh"], rel=1e-3)
    notes = {q["column"]: q["detail"] for q in df.attrs["qc"] if q["kind"] == "converted across a gap"}
    assert notes["co2_ppm"].startswith("1 value(s) converted with the air temperature interpolated in time")
    assert notes["rh"].startswith("2 value(s) converted with the air temperature interpolated in time")
    assert not any(q["kind"] == "converted across a gap" for q in ref.attrs["qc"])
    assert not any(q["column"] == "co2_ppm" and q["kind"] == "interpolated" for q in df.attrs["qc"])


def test_global_radiation_in_kw_is_converted(tmp_path):
    """A global-radiation column labelled kW m⁻² (values a thousandth) reads as the W m⁻² one (a
    review found the unit refused)."""

    def edit(lines, hdr):
        lines[hdr] = lines[hdr].replace("RadiationGlobal_Avg10min [W*m-2]", "RadiationGlobal_Avg10min [kW*m-2]", 1)
        for i in range(hdr + 1, len(lines)):
            cells = lines[i].split(",")
            if len(cells) > 1 and cells[1]:
                cells[1] = repr(float(cells[1]) / 1000.0)
            lines[i] = ",".join(cells)

    ref, df = read_tereno(FIXTURE), read_tereno(_variant(tmp_path, edit))
    np.testing.assert_allclose(df["ghi_w_m2"].to_numpy(), ref["ghi_w_m2"].to_numpy(), rtol=1e-12, atol=1e-9)
    assert "kW" in df.attrs["columns_used"]["ghi_w_m2"]


def test_tereno_zone_by_convention_is_said(tmp_path):
    """A TERENO export without a 'Time zone:' line is read in UTC+1, the convention, and its checks say
    so (a review found it assumed without a word); the header's line, where present, says nothing."""
    said = [q["detail"] for q in read_tereno(FIXTURE).attrs["qc"] if "Time zone" in q["detail"]]
    assert said == []
    bare = tmp_path / "no_zone.csv"
    text = FIXTURE.read_text(encoding="utf-8")
    bare.write_text("".join(ln for ln in text.splitlines(True) if not ln.startswith("Time zone:")), encoding="utf-8")
    df = read_tereno(bare)
    (note,) = [q["detail"] for q in df.attrs["qc"] if "Time zone" in q["detail"]]
    assert note.startswith("no 'Time zone:' line in the header: the timestamps are read as UTC+1")
    assert df.attrs["timezone_assumed"] == "Etc/GMT-1"
    assert df.index.equals(read_tereno(FIXTURE).index)  # the header said UTC+1: the same instants


def test_tereno_co2_30min_held_and_reported():
    df = read_tereno(FIXTURE)
    held = [q for q in df.attrs["qc"] if q["kind"] == "held"]
    assert held and held[0]["column"] == "co2_ppm"
    # The stamps end their means: the 10-min rows inside a 30-min interval take the mean that
    # closes it, i.e. the next 30-min value, and rows past the last mean keep it.
    raw = read_tereno(FIXTURE).attrs["timestamps"]
    assert (raw.label, raw.interval) == ("end", pd.Timedelta("10min"))
    first, second = df["co2_ppm"].iloc[0], df["co2_ppm"].iloc[3]
    assert df["co2_ppm"].iloc[1] == df["co2_ppm"].iloc[2] == second != first
    assert df["co2_ppm"].iloc[-1] == df["co2_ppm"].iloc[-3]
    # Start-stamped means cover the rows after their stamp.
    start = read_tereno(FIXTURE, time_label="start")
    assert start["co2_ppm"].iloc[1] == start["co2_ppm"].iloc[2] == first


def test_header_found_by_content_with_long_preamble_and_semicolons(tmp_path):
    def edit(lines, hdr):
        pre = [f"Comment line {i}: metadata, with, commas" for i in range(90)]
        return pre + [ln.replace(",", ";") for ln in lines[hdr:]]

    df = read_tereno(_variant(tmp_path, edit))
    assert len(df) == len(read_tereno(FIXTURE))
    assert np.allclose(df["rh"], read_tereno(FIXTURE)["rh"])


def test_timezone_is_a_parameter(tmp_path):
    """Where the header states no zone, tz= sets it (default UTC+1); where it does, a tz that
    disagrees is refused and one that agrees (UTC+1 is Etc/GMT-1) accepted."""
    a = read_tereno(FIXTURE)
    assert a.attrs["timezone_assumed"] == "Etc/GMT-1"  # the header's "Time zone: UTC+1"
    no_zone = _variant(tmp_path, lambda lines, hdr: [ln for ln in lines if not ln.startswith("Time zone")])
    assert read_tereno(no_zone).index.equals(a.index)  # the TERENO default, UTC+1
    b = read_tereno(no_zone, tz="UTC")
    assert (b.index - a.index == pd.Timedelta("1h")).all()
    assert read_tereno(FIXTURE, tz="UTC+1").index.equals(a.index)
    with pytest.raises(
        InputError, match=r"line 7, parameter 'tz': tz='UTC' disagrees with the header's 'Time zone: UTC\+1'"
    ):
        read_tereno(FIXTURE, tz="UTC")


def test_column_override_and_unknown_key():
    df = read_tereno(FIXTURE, columns={"tair_c": "AirTemperature_2m_Avg10min_Sensor1 [°C]"})
    assert df.attrs["columns_used"]["tair_c"].startswith("AirTemperature")
    with pytest.raises(InputError, match="unknown quantity"):
        read_tereno(FIXTURE, columns={"temperature": "x"})
    with pytest.raises(InputError, match="not in the table"):
        read_tereno(FIXTURE, columns={"tair_c": "Nope [°C]"})


def test_missing_column(tmp_path):
    def edit(lines, hdr):
        return [
            ",".join(c for j, c in enumerate(ln.split(",")) if j != 4) if i >= hdr else ln for i, ln in enumerate(lines)
        ]

    # Without air temperature, absolute humidity cannot become RH: the error says so.
    with pytest.raises(InputError, match=r"export\.csv.*AirTemperature"):
        read_tereno(_variant(tmp_path, edit))

    def no_radiation(lines, hdr):
        return [
            ",".join(c for j, c in enumerate(ln.split(",")) if j not in (1, 2, 3)) if i >= hdr else ln
            for i, ln in enumerate(lines)
        ]

    with pytest.raises(InputError, match=r"export\.csv: missing column\(s\) ghi_w_m2 or par_umol_m2_s"):
        read_tereno(_variant(tmp_path, no_radiation))


def test_unparseable_time_names_line(tmp_path):
    def edit(lines, hdr):
        lines[hdr + 5] = "20.04.2016 quarter past," + lines[hdr + 5].split(",", 1)[1]

    with pytest.raises(InputError, match=r"line \d+.*cannot parse time"):
        read_tereno(_variant(tmp_path, edit))


def test_duplicated_timestamp(tmp_path):
    """Named as the file writes it (its own zone, UTC+1 here) on the lines that share it."""

    def edit(lines, hdr):
        lines.insert(hdr + 4, lines[hdr + 3])

    with pytest.raises(InputError, match="duplicated timestamp") as e:
        p = _variant(tmp_path, edit)
        read_tereno(p)
    text = p.read_text(encoding="utf-8").splitlines()
    stamp = pd.Timestamp(text[e.value.row - 1].split(",")[0]).strftime("%Y-%m-%d %H:%M")
    assert f"duplicated timestamp {stamp} (" in str(e.value)
    assert text[e.value.row - 1] == text[e.value.row] and f"lines [{e.value.row}, {e.value.row + 1}]" in str(e.value)


def test_short_gap_interpolated_long_gap_rejected(tmp_path):
    def short(lines, hdr):
        del lines[hdr + 20]

    df = read_tereno(_variant(tmp_path, short))
    kinds = {q["kind"] for q in df.attrs["qc"]}
    assert {"missing_timestamps", "interpolated"} <= kinds
    ref = read_tereno(FIXTURE)
    assert df["tair_c"].iloc[19] == pytest.approx(0.5 * (ref["tair_c"].iloc[18] + ref["tair_c"].iloc[20]))

    def long(lines, hdr):
        del lines[hdr + 20 : hdr + 26]

    with pytest.raises(InputError, match=r"longer than max_gap=30min.*weather show FILE --max-gap 3h --csv"):
        read_tereno(_variant(tmp_path, long))
    # Allowed when the user raises the limit.
    assert len(read_tereno(_variant(tmp_path, long), max_gap="2h")) == len(ref)


def test_rows_at_the_ends_without_a_value_are_cut_and_said(tmp_path):
    """Missing values in the first or last rows cannot be interpolated (nothing on one side): they
    were refused, with a --max-gap hint that could not help, even hours before any run's window.
    Now the series is cut to the rows between, recorded with their times and lines; inside gaps
    are interpolated as before; a column without any complete row is still refused, naming it."""
    ref = read_tereno(FIXTURE)

    def blank(rows_from_header, col):
        def edit(lines, hdr):
            for k in rows_from_header:
                cells = lines[hdr + k].split(",")
                cells[col] = ""
                lines[hdr + k] = ",".join(cells)

        return edit

    _, hdr = _table_lines(FIXTURE)
    n = len(ref)
    df = read_tereno(_variant(tmp_path, blank([1, 2, 3, n, 30], 4)))  # 3 first rows, the last, one inside
    assert df.index[0] == ref.index[3] and df.index[-1] == ref.index[-2] and len(df) == n - 4
    (cut,) = [q for q in df.attrs["qc"] if q["kind"] == "trimmed"]
    assert cut["count"] == 4
    assert "3 row(s)" in cut["detail"] and f"lines {hdr + 2}–{hdr + 4}" in cut["detail"]
    assert "1 row(s)" in cut["detail"] and f"lines {hdr + n + 1}–{hdr + n + 1}" in cut["detail"]
    assert "AirTemperature" in cut["detail"]
    assert ("interpolated", "tair_c") in [(q["kind"], q["column"]) for q in df.attrs["qc"]]
    pd.testing.assert_frame_equal(df.drop(index=ref.index[29]), ref.iloc[3:-1].drop(index=ref.index[29]))
    with pytest.raises(InputError, match=r"at the start or end of the series.*every column present"):
        read_tereno(_variant(tmp_path, blank(range(1, n + 1), 4)))
    # a window that needs the cut rows names the cut (it gave the shorter span alone: a review)
    with pytest.raises(InputError, match=r"not covered by the series .*; its ends were cut: 3 row\(s\)"):
        window(df, ref.index[0], 1)

    def blank_then_missing(lines, hdr):  # the first row lacks tair, the second row is gone
        blank([1], 4)(lines, hdr)
        del lines[hdr + 2]

    df = read_tereno(_variant(tmp_path, blank_then_missing))
    (cut,) = [q["detail"] for q in df.attrs["qc"] if q["kind"] == "trimmed"]
    assert df.index[0] == ref.index[2] and "1 row(s)" in cut and f"lines {hdr + 2}–{hdr + 2})" in cut, cut
    assert "without AirTemperature" in cut and "RelativeHumidity" not in cut and "1 inserted timestamp(s)" in cut


def test_empty_cell_and_sentinel_are_gaps(tmp_path):
    def edit(lines, hdr):
        cells = lines[hdr + 30].split(",")
        cells[4] = ""
        lines[hdr + 30] = ",".join(cells)
        cells = lines[hdr + 40].split(",")
        cells[1] = "-9999"
        lines[hdr + 40] = ",".join(cells)

    df = read_tereno(_variant(tmp_path, edit))
    kinds = [(q["kind"], q["column"]) for q in df.attrs["qc"]]
    assert ("interpolated", "tair_c") in kinds
    assert any(k == "sentinel" for k, _ in kinds)
    assert not df.isna().any().any()


def test_not_a_number_names_line_and_column(tmp_path):
    def edit(lines, hdr):
        cells = lines[hdr + 10].split(",")
        cells[4] = "warm"
        lines[hdr + 10] = ",".join(cells)

    _, hdr = _table_lines(FIXTURE)
    # The edited row is list index hdr + 10, i.e. the file's line hdr + 11 (lines count from 1).
    with pytest.raises(
        InputError, match=rf"line {hdr + 11}, column 'AirTemperature[^']*': value 'warm' is not a finite number"
    ):
        read_tereno(_variant(tmp_path, edit))


def test_out_of_range_value(tmp_path):
    def edit(lines, hdr):
        cells = lines[hdr + 12].split(",")
        cells[4] = "300"
        lines[hdr + 12] = ",".join(cells)

    with pytest.raises(InputError, match=r"line \d+, column 'tair_c': value 300"):
        read_tereno(_variant(tmp_path, edit))


def test_large_negative_par_is_an_error_not_clamped(tmp_path):
    def edit(lines, hdr):
        cells = lines[hdr + 12].split(",")
        cells[3] = "-250"
        lines[hdr + 12] = ",".join(cells)

    with pytest.raises(InputError, match="par_umol_m2_s"):
        read_tereno(_variant(tmp_path, edit))


def test_unit_mismatch(tmp_path):
    def unknown_unit(lines, hdr):
        lines[hdr] = lines[hdr].replace("[mbar]", "[psi]")

    with pytest.raises(InputError, match=r"unit \[psi\] not understood"):
        read_tereno(_variant(tmp_path, unknown_unit))

    def pascal_labelled_mbar(lines, hdr):
        for i in range(hdr + 1, len(lines)):
            c = lines[i].split(",")
            c[6] = f"{float(c[6]) * 100:.1f}"
            lines[i] = ",".join(c)

    with pytest.raises(InputError, match="pair_kpa.*check the unit"):
        read_tereno(_variant(tmp_path, pascal_labelled_mbar))

    def celsius_labelled_kelvin(lines, hdr):
        assert "AirTemperature_2m_Avg10min_Sensor1 [°C]" in lines[hdr]
        lines[hdr] = lines[hdr].replace(
            "AirTemperature_2m_Avg10min_Sensor1 [°C]", "AirTemperature_2m_Avg10min_Sensor1 [K]"
        )

    # The value is the converted one (−263 °C): the message names the file's column it came from.
    with pytest.raises(InputError, match=r"value -26\d\.\d+ \(read from AirTemperature_2m_Avg10min_Sensor1 \[K\], in"):
        read_tereno(_variant(tmp_path, celsius_labelled_kelvin))


def test_off_grid_timestamp(tmp_path):
    def edit(lines, hdr):
        assert ":20:00" in lines[hdr + 3]
        lines[hdr + 3] = lines[hdr + 3].replace(":20:00", ":23:00", 1)

    with pytest.raises(InputError, match="off the regular 10min grid") as e:  # "0 days 00:10:00" before
        read_tereno(_variant(tmp_path, edit))
    assert "days" not in str(e.value)
    # in the file's terms (its UTC+1 clock, as its line reads), not UTC (a review)
    assert "timestamp 2016-04-20 04:23:00 (UTC+1) is off the regular 10min grid starting 2016-04-20 04:00:00" in str(
        e.value
    )


def test_unsorted_rows_are_sorted_and_reported(tmp_path):
    def edit(lines, hdr):
        lines[hdr + 5], lines[hdr + 6] = lines[hdr + 6], lines[hdr + 5]

    df = read_tereno(_variant(tmp_path, edit))
    assert df.index.is_monotonic_increasing
    assert any(q["kind"] == "sorted" for q in df.attrs["qc"])


def test_not_a_tereno_file(tmp_path):
    p = tmp_path / "x.csv"
    p.write_text("a,b\n1,2\n")
    with pytest.raises(InputError, match="no table header"):
        read_tereno(p)
    with pytest.raises(InputError, match="unrecognised"):
        read_weather(p)
    with pytest.raises(InputError, match="file not found"):
        read_weather(tmp_path / "missing.csv")


def test_cplantbox_real_day():
    df = read_cplantbox_day(CPB, "2016-06-23")
    raw = pd.read_csv(CPB, sep="\t")
    assert len(df) == len(raw) == 144
    # PAR mol m-2 s-1 -> µmol m-2 s-1, CO2 mol mol-1 -> ppm, local time (CEST) -> UTC.
    i = int(raw["PAR"].to_numpy().argmax())
    assert df["par_umol_m2_s"].iloc[i] == pytest.approx(raw["PAR"].iloc[i] * 1e6)
    assert df["co2_ppm"].iloc[0] == pytest.approx(raw["co2"].iloc[0] * 1e6)
    assert df.index[0] == pd.Timestamp("2016-06-22 22:00", tz="UTC")
    assert df.attrs["unused_columns"] == ["ps", "nm"]
    # The file's PAR is centred on solar noon (≈13:35 CEST) under the local-time assumption.
    par = df["par_umol_m2_s"]
    centre = (par * (par.index - par.index[0]).total_seconds()).sum() / par.sum()
    noon_utc = (pd.Timestamp("2016-06-23 11:35", tz="UTC") - par.index[0]).total_seconds()
    assert abs(centre - noon_utc) < 3600


def test_a_cplantbox_unit_slip_is_reported_as_the_file_holds_it(tmp_path):
    """PAR written in µmol under CPlantBox's mol m⁻² s⁻¹ is refused with the value as the file holds
    it and the format's unit (it showed only the converted 2.6e+11; a review)."""
    raw = pd.read_csv(CPB, sep="\t")
    raw["PAR"] = raw["PAR"] * 1e6  # µmol m⁻² s⁻¹ under a mol m⁻² s⁻¹ column
    bad = tmp_path / "umol.txt"
    raw.to_csv(bad, sep="\t", index=False)
    first = raw["PAR"][raw["PAR"] * 1e6 > 3000].iloc[0]  # the first implausible reading, as written
    with pytest.raises(
        InputError, match=rf"umol.txt.*\({first:g} mol m⁻² s⁻¹ in the file's PAR, the format's unit"
    ) as e:
        read_cplantbox_day(bad, "2016-04-27")
    # at the file's own clock (its local time, as its rows read), not UTC (a review)
    clock = raw["time"][raw["PAR"] * 1e6 > 3000].iloc[0][:5]
    assert f"at 2016-04-27 {clock} (Europe/Berlin) is implausible" in str(e.value), str(e.value)


def test_the_undated_day_fits_the_example_date_and_not_23_june():
    """The CPlantBox day's last dark readings before and after its light (06:30 and 21:00 local)
    must have the sun near or below the horizon on the date the docs give it (data/README.md):
    2016-04-27 fits (pvlib: 1.7° and −2.3°), 2016-06-23, which the docs suggested before, does not
    (8.3° and 6.0°: a working PAR sensor reads light then)."""
    import pvlib

    raw = pd.read_csv(CPB, sep="\t")
    lit = np.flatnonzero(raw["PAR"].to_numpy() > 0)
    dark = [lit[0] - 1, lit[-1] + 1]
    assert list(raw["time"].iloc[dark]) == ["06:30:00", "21:00:00"]
    for date, fits in (("2016-04-27", True), ("2016-06-23", False)):
        t = read_cplantbox_day(CPB, date).index[dark]
        el = pvlib.solarposition.get_solarposition(t, 50.8659, 6.4471)["apparent_elevation"].to_numpy()
        assert bool((el < 2.0).all()) == fits, (date, el)


def test_cplantbox_needs_a_date():
    with pytest.raises(InputError, match="date"):
        read_weather(CPB)
    with pytest.raises(InputError, match="not a date"):
        read_cplantbox_day(CPB, "the twentieth")
    for clock_change in ("2016-03-27", "2016-10-30"):  # local 02:00–03:00 missing / twice: not a traceback
        with pytest.raises(InputError, match=r"02:00 (does not exist|happens twice) \(the clocks go .*\) in Europe/"):
            read_cplantbox_day(CPB, clock_change)


def test_resample_mean_and_sample():
    df = read_weather(bundled_path("2016-04-20"))
    s = resample(df, "30min", "sample")
    assert s["par_umol_m2_s"].loc["2016-04-20 11:00+00:00"] == df["par_umol_m2_s"].loc["2016-04-20 11:00+00:00"]
    m = resample(df, "30min", "mean")
    t = pd.Timestamp("2016-04-20 11:00", tz="UTC")
    win = df["par_umol_m2_s"].loc[t - pd.Timedelta("15min") : t + pd.Timedelta("14min")]
    assert m["par_umol_m2_s"].loc[t] == pytest.approx(win.mean())
    with pytest.raises(InputError, match="parameter 'how'.*expected 'mean' or 'sample'"):
        resample(df, "30min", "median")


def test_window_is_the_papers_29_steps():
    df = read_weather(bundled_path("2016-04-20"))
    w = window(df, "2016-04-20 05:00", 14, "30min")
    assert len(w) == 29
    assert w.index[0] == pd.Timestamp("2016-04-20 03:00", tz="UTC")
    assert "sun_elevation_deg" not in w.columns  # only recomputed where the input had it
    with pytest.raises(InputError, match="not covered"):
        window(df, "2016-04-20 20:00", 14)


def test_window_steps_run_through_its_start_or_it_says_why_not():
    """A start off the series' 30-min grid (05:15 local on 10-min data): averaged windows are centred
    on 05:15, 05:45, … (29 steps; they were silently moved to 05:30 with a step lost), sampled ones
    refuse what the source has no value at and take 05:10 as given; a step finer than the source's
    is refused when averaging too (it silently returned the source step); resampling keeps the
    input's direct/diffuse split model."""
    from lightfit.weather.solar import add_solar

    df = read_weather(bundled_path("2016-04-20"))
    t0 = pd.Timestamp("2016-04-20 03:15", tz="UTC")
    m = window(df, "2016-04-20 05:15", 14, "30min", how="mean")
    assert len(m) == 29 and m.index[0] == t0 and m.index[-1] == t0 + pd.Timedelta(hours=14)
    src = df["par_umol_m2_s"].loc[t0 - pd.Timedelta("15min") : t0 + pd.Timedelta("14min")]
    assert len(src) == 3 and m["par_umol_m2_s"].iloc[0] == pytest.approx(src.mean())
    with pytest.raises(
        InputError, match=r"parameter 'start_time': the window starts at 2016-04-20 05:15 .*rows every 10 min"
    ):
        window(df, "2016-04-20 05:15", 14, "30min")
    s = window(df, "2016-04-20 05:10", 14, "30min")
    assert len(s) == 29 and s["par_umol_m2_s"].iloc[0] == df["par_umol_m2_s"].loc["2016-04-20 03:10+00:00"]
    # the source's own step named, with a step that works (a review: "or how='mean'" led to the next refusal)
    with pytest.raises(InputError, match=r"cannot average at 5min.*rows are 10min apart.*e\.g\. 10min"):
        resample(df, "5min", "mean")
    hourly = df.iloc[::6]
    with pytest.raises(InputError, match=r"selhausen.*cannot sample at 30min: the source, rows 1h apart.*e\.g\. 1h"):
        resample(hourly, "30min", "sample")
    boland = add_solar(df, split_model="boland")
    assert resample(boland, "30min", "mean").attrs["split_model"] == "boland"
    # a hole, not the step: the first new timestamp without a value is named (rows absent, or a value NaN)
    holed = df.drop(df.loc["2016-04-20 09:55+00:00":"2016-04-20 11:05+00:00"].index)
    holed.loc["2016-04-20 14:00+00:00", "tair_c"] = np.nan
    msg = r"cannot sample at 30min.*no value at 4 of them, the first 2016-04-20 10:00 UTC \(fill or cut the gap"
    with pytest.raises(InputError, match=msg):
        resample(holed, "30min", "sample")


def test_missing_rows_are_named_in_the_files_terms(tmp_path):
    """Two hours of rows absent from a TERENO export: the error names the lines around the hole and
    its time range in the file's own time zone (UTC+1), not a contract column in UTC (issue 17)."""
    lines = (DATA_DIR / "fixtures" / "tereno_SE_EC_001_fixture.csv").read_text(encoding="utf-8").splitlines()
    i = next(k for k, line in enumerate(lines) if line.startswith("2016-04-20 11:00"))
    bad = tmp_path / "holes.csv"
    bad.write_text("\n".join(lines[:i] + lines[i + 12 :]) + "\n", encoding="utf-8")
    with pytest.raises(InputError) as e:
        read_weather(bad)
    msg = str(e.value)
    assert "12 row(s) missing" in msg and "2016-04-20 11:00 … 2016-04-20 12:50 (UTC+1)" in msg
    assert f"line {i} (2016-04-20 10:50) and line {i + 1} (2016-04-20 13:00)" in msg
    assert "column" not in msg  # every column is missing there: none is singled out


def _series(n=12):
    """A plain 10-min contract series and its source lines (for check_and_repair)."""
    t = pd.date_range("2016-04-20 10:00", periods=n, freq="10min", tz="UTC")
    df = pd.DataFrame(
        {"ghi_w_m2": 500.0, "tair_c": np.linspace(10, 12, n), "rh": 0.6, "pair_kpa": 100.0, "co2_ppm": 400.0}, index=t
    )
    return df, pd.Series(np.arange(n) + 2, index=t)


@pytest.mark.parametrize("missing, filled", [(3, True), (4, False)])
def test_max_gap_is_the_span_of_the_missing_rows(missing, filled):
    """max_gap=30min on 10-min rows: 3 missing rows (a 30-min hole) are interpolated, 4 (40 min)
    refused, as docs/weather.md states (a mutation audit: the span without its one step survived)."""
    from lightfit.weather.series import check_and_repair

    df, lines = _series()
    df.iloc[4 : 4 + missing, df.columns.get_loc("tair_c")] = np.nan
    if filled:
        out = check_and_repair(df, lines, "w.csv", max_gap="30min")
        np.testing.assert_allclose(out["tair_c"], np.linspace(10, 12, 12))  # linear: the line itself
    else:
        with pytest.raises(InputError, match="longer than max_gap=30min"):
            check_and_repair(df, lines, "w.csv", max_gap="30min")


def test_relative_humidity_up_to_its_clamp_is_clamped_and_counted():
    """RH up to 1.05 (a sensor's overshoot) is set to 1 and counted in qc; above it refused
    (docs/weather.md; a mutation audit: '<' for '<=' at the clamp survived)."""
    from lightfit.weather.series import check_and_repair

    df, lines = _series()
    df.iloc[3, df.columns.get_loc("rh")] = 1.05
    out = check_and_repair(df, lines, "w.csv")
    assert out["rh"].iloc[3] == 1.0 and any(q["column"] == "rh" for q in out.attrs["qc"])
    df.iloc[3, df.columns.get_loc("rh")] = 1.06
    with pytest.raises(InputError, match="rh"):
        check_and_repair(df, lines, "w.csv")


def test_a_pressure_column_in_pascal_reads_as_kilopascal(tmp_path):
    """A TERENO pressure in [Pa] (101 325) is read as kPa (101.325): the fixture's mbar column
    rewritten in Pa gives the same series (a mutation audit: ×1e-2 for ×1e-3 survived, no test
    read Pa)."""
    text = FIXTURE.read_text(encoding="utf-8")
    lines = text.splitlines(keepends=True)
    head = next(i for i, x in enumerate(lines) if x.startswith("Timestamp,"))
    cols = lines[head].rstrip("\n").split(",")
    j = next(k for k, c in enumerate(cols) if c.startswith("AirPressure"))
    assert cols[j].endswith("[mbar]")
    cols[j] = cols[j].replace("[mbar]", "[Pa]")
    out = ["".join(lines[:head]).replace("[mbar]", "[Pa]"), ",".join(cols) + "\n"]
    for x in lines[head + 1 :]:
        f = x.rstrip("\n").split(",")
        if len(f) > j and f[j]:
            f[j] = f"{float(f[j]) * 100:.2f}"
        out.append(",".join(f) + "\n")
    pa = tmp_path / "pa.csv"
    pa.write_text("".join(out), encoding="utf-8")
    a, b = read_weather(FIXTURE), read_weather(pa)
    np.testing.assert_allclose(b["pair_kpa"], a["pair_kpa"], rtol=1e-12)
    assert 95 < b["pair_kpa"].median() < 105


def test_tereno_qf_flag_column_is_applied_not_ignored(tmp_path):
    """A flag column named '<column>_QF' (the reader's flag pattern names QF beside QualityFlag and
    Flag) was listed as 'not used' and its 'bad' flags ignored, the flagged value read as good. Its
    'bad' value is now missing, interpolated between its neighbours (10-min rows: their mean) and
    counted naming the column, as with 'QualityFlag'."""
    lines = FIXTURE.read_text(encoding="utf-8").splitlines()
    hdr = next(i for i, x in enumerate(lines) if x.startswith("Timestamp"))
    assert lines[hdr].count("RadiationGlobal_Avg10min QualityFlag") == 1
    lines[hdr] = lines[hdr].replace("RadiationGlobal_Avg10min QualityFlag", "RadiationGlobal_Avg10min_QF")
    i = hdr + 40  # a daylight row (2016-04-20 10:30 UTC+1)
    cells = lines[i].split(",")
    cells[1], cells[2] = "999.0", "bad"  # a spike the logger flagged
    lines[i] = ",".join(cells)
    before, after = (float(lines[j].split(",")[1]) for j in (i - 1, i + 1))
    path = tmp_path / "qf.csv"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    df = read_tereno(path)
    assert "RadiationGlobal_Avg10min_QF" not in df.attrs["unused_columns"]
    t = pd.Timestamp(cells[0], tz="Etc/GMT-1").tz_convert("UTC")
    assert df.loc[t, "ghi_w_m2"] == pytest.approx((before + after) / 2)
    (flagged,) = [q for q in df.attrs["qc"] if q["kind"] == "flagged bad"]
    assert flagged["column"] == "ghi_w_m2" and "'RadiationGlobal_Avg10min_QF'" in flagged["detail"]
    assert f"line {i + 1}" in flagged["detail"]


@pytest.mark.parametrize("flag_col", ["QualityFlag RadiationGlobal_Avg10min", "QF_RadiationGlobal_Avg10min"])
def test_tereno_flag_column_named_flag_word_first_is_applied(tmp_path, flag_col):
    """A flag column written with the flag word first ('QualityFlag <column>', 'QF_<column>') was not
    matched to its value column (the flag pattern read the word at the end only): listed as not used,
    its 'bad' flags ignored and the flagged spike read as good. The spike is now missing, interpolated
    between its neighbours (10-min rows: their mean) and counted naming the flag column."""
    lines = FIXTURE.read_text(encoding="utf-8").splitlines()
    hdr = next(i for i, x in enumerate(lines) if x.startswith("Timestamp"))
    assert lines[hdr].count("RadiationGlobal_Avg10min QualityFlag") == 1
    lines[hdr] = lines[hdr].replace("RadiationGlobal_Avg10min QualityFlag", flag_col)
    i = hdr + 40  # a daylight row (2016-04-20 10:30 UTC+1)
    cells = lines[i].split(",")
    cells[1], cells[2] = "999.0", "bad"  # a spike the logger flagged
    lines[i] = ",".join(cells)
    before, after = (float(lines[j].split(",")[1]) for j in (i - 1, i + 1))
    path = tmp_path / "qf_first.csv"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    df = read_tereno(path)
    assert flag_col not in df.attrs["unused_columns"]
    t = pd.Timestamp(cells[0], tz="Etc/GMT-1").tz_convert("UTC")
    assert df.loc[t, "ghi_w_m2"] == pytest.approx((before + after) / 2)
    (flagged,) = [q for q in df.attrs["qc"] if q["kind"] == "flagged bad"]
    assert flagged["column"] == "ghi_w_m2" and f"{flag_col!r}" in flagged["detail"]


def test_tereno_missing_last_co2_mean_is_a_gap_not_the_mean_before(tmp_path):
    """The 30-min CO2 of end-stamped means covers the 10-min rows of its own interval; only rows past
    the file's last 30-min stamp keep that stamp's mean. With the last mean's cell empty (19:30 UTC+1),
    the rows 19:10–19:50 took the 19:00 mean, as if it were theirs; they have no CO2 of their own now
    and are cut at the series' end (the 'trimmed' repair names them), as any end without a value."""
    lines = FIXTURE.read_text(encoding="utf-8").splitlines()
    last = max(i for i, x in enumerate(lines) if x[:1].isdigit() and x.split(",")[-1])
    assert lines[last].startswith("2016-04-20 19:30:00")
    lines[last] = lines[last].rsplit(",", 1)[0] + ","
    path = tmp_path / "co2.csv"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    df = read_tereno(path)
    assert df.index[-1] == pd.Timestamp("2016-04-20 19:00", tz="Etc/GMT-1")
    (cut,) = [q for q in df.attrs["qc"] if q["kind"] == "trimmed"]
    assert "5 row(s) 2016-04-20 19:10 … 2016-04-20 19:50" in cut["detail"] and "CO2" in cut["detail"]
