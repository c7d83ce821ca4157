"""Bad weather input is refused with one line naming file, line and column, and nothing is called
measured that does not say so: radiation and humidity in the wrong unit, provenance, quality flags,
unknown columns, malformed rows, dates and zones (review of the weather readers)."""

import re
from pathlib import Path

import pandas as pd
import pvlib
import pytest
from typer.testing import CliRunner

from lightfit import replication as rep
from lightfit.cli import app
from lightfit.errors import InputError
from lightfit.weather import (
    Window,
    add_solar,
    read_cplantbox_day,
    read_lightfit_csv,
    read_tereno,
    read_weather,
    solar_position,
    write_lightfit_csv,
)
from lightfit.weather.bundled import DATA_DIR, bundled_path
from lightfit.weather.series import window as weather_window

FIXTURE = DATA_DIR / "fixtures" / "tereno_SE_EC_001_fixture.csv"
CPB = DATA_DIR / "weather" / "selhausen_cplantbox_day.txt"
RECON = bundled_path("2016-04-20")
runner = CliRunner()

# The fixture's table: 0 Timestamp, 1 global radiation, 2 its quality flag, 3 PAR, 4 air temperature,
# 5 absolute humidity, 6 pressure, 7 CO2 (30 min).
GHI, FLAG, PAR, TAIR, HUM = 1, 2, 3, 4, 5


def _tereno(tmp_path: Path, edit=None, name="export.csv", header_edit=None) -> Path:
    """A copy of the fixture: ``edit(rows)`` on its data rows (lists of cells), ``header_edit(lines)``
    on the lines above them."""
    lines = FIXTURE.read_text(encoding="utf-8").splitlines()
    hdr = next(i for i, ln in enumerate(lines) if ln.startswith("Timestamp"))
    head, rows = lines[: hdr + 1], [ln.split(",") for ln in lines[hdr + 1 :]]
    if header_edit:
        head = header_edit(head) or head
    if edit:
        rows = edit(rows) or rows
    p = tmp_path / name
    p.write_text("\n".join(head + [",".join(r) for r in rows]) + "\n", encoding="utf-8")
    return p


def _line_of(path: Path, needle: str) -> int:
    """The 1-based line of the first line containing ``needle``: found in the text, not by the reader."""
    return next(i + 1 for i, ln in enumerate(path.read_text(encoding="utf-8").splitlines()) if needle in ln)


def _cli_error(args, *words):
    r = runner.invoke(app, args)
    assert r.exit_code == 2, r.output
    assert isinstance(r.exception, SystemExit), r.exception
    err = " ".join(r.stderr.split())
    assert err.startswith("error:") and "Traceback" not in r.output, err
    for w in words:
        assert w in err, (w, err)
    return err


# 1. radiation in the wrong unit ------------------------------------------------------------------


def test_global_radiation_in_kw_is_refused_naming_column_and_unit(tmp_path):
    """kW m⁻² under a [W*m-2] header (values 1000× too small) passed; without a PAR column it is
    refused by the clear-sky check, with one by the PAR / global radiation check."""

    def kw(rows):
        for r in rows:
            r[GHI] = f"{float(r[GHI]) / 1000:.5f}"

    def drop_par(rows):
        kw(rows)
        return [r[:PAR] + r[PAR + 1 :] for r in rows]

    def drop_par_header(head):
        cells = head[-1].split(",")
        head[-1] = ",".join(cells[:PAR] + cells[PAR + 1 :])

    alone = _tereno(tmp_path, drop_par, "alone.csv", drop_par_header)
    with pytest.raises(InputError, match=r"column 'RadiationGlobal_Avg10min \[W\*m-2\]'.*clear sky.*W m⁻²"):
        add_solar(read_tereno(alone))
    _cli_error(["weather", "show", str(alone)], "alone.csv", "RadiationGlobal_Avg10min", "W m⁻²")
    with pytest.raises(InputError, match=r"PAR reaches .* global radiation never exceeds 50 W m⁻²"):
        add_solar(read_tereno(_tereno(tmp_path, kw)))


def _clear_day(share: float, column: str = "ghi_w_m2") -> pd.DataFrame:
    """20 April 2016 at Selhausen, ``share`` of pvlib's Ineichen–Perez clear sky (a model other than
    the check's Haurwitz), 10-min steps; PAR (if asked) at 0.50 × 4.57 µmol J⁻¹."""
    t = pd.date_range("2016-04-20 00:00", "2016-04-20 23:50", freq="10min", tz="UTC")
    loc = pvlib.location.Location(50.865, 6.447, altitude=103)
    ghi = share * loc.get_clearsky(t, model="ineichen")["ghi"].to_numpy()
    value = ghi if column == "ghi_w_m2" else 2.285 * ghi
    return pd.DataFrame({column: value, "tair_c": 15.0, "rh": 0.6, "pair_kpa": 100.0, "co2_ppm": 400.0}, index=t)


@pytest.mark.parametrize("column", ["ghi_w_m2", "par_umol_m2_s"])
def test_overcast_days_pass_and_unit_slips_do_not(column):
    """A thick overcast (8 % of clear sky, below the 10–20 % such skies give) is weather; 1 % all day
    with the sun above 20° is not (a unit slip is ≈ 0.1 %)."""
    for share in (0.08, 0.2, 1.0):
        assert len(add_solar(_clear_day(share, column))) == 144
    for share in (0.01, 1e-3):
        with pytest.raises(InputError, match=rf"column '{column}'.*clear sky"):
            add_solar(_clear_day(share, column))


def test_radiation_is_judged_only_with_the_sun_high():
    """Night or a low sun only: no step to judge by, nothing refused (a winter morning stays readable)."""
    night = _clear_day(1.0).iloc[:24]  # 00:00–03:50 UTC
    assert (solar_position(night.index)["sun_elevation_deg"] < 20).all()
    assert (add_solar(night.assign(ghi_w_m2=0.0))["ghi_w_m2"] == 0).all()


# 2. humidity: a fraction in a % column -----------------------------------------------------------


def test_relative_humidity_fraction_in_a_percent_column_is_refused(tmp_path):
    def pct(value):
        def edit(rows):
            for r in rows:
                r[HUM] = value

        return edit

    def header(head):
        head[-1] = head[-1].replace("AirHumidity_2m_Avg10min [g*m-3]", "AirHumidity_2m_Avg10min [%]")

    ok = read_tereno(_tereno(tmp_path, pct("80"), "ok.csv", header))
    assert (ok["rh"] == 0.80).all()  # 80 % by hand
    with pytest.raises(InputError, match=r"AirHumidity_2m_Avg10min \[%\].*peaks at 0\.8 %.*fraction"):
        read_tereno(_tereno(tmp_path, pct("0.80"), "frac.csv", header))


# 3. provenance -----------------------------------------------------------------------------------


def test_provenance_comes_from_the_file_or_the_caller_never_a_default_measured(tmp_path):
    """The fixture's header says "SYNTHETIC FIXTURE" (data/README.md: synthetic); it was read as
    measured. A header that says nothing gives "unstated" unless the caller declares it; a caller
    that contradicts the file is refused."""
    assert "SYNTHETIC FIXTURE" in FIXTURE.read_text(encoding="utf-8").splitlines()[1]
    assert read_tereno(FIXTURE).attrs["provenance"] == "synthetic"
    with pytest.raises(InputError, match=r"provenance='measured' contradicts the file, which says 'synthetic'.*line 2"):
        read_tereno(FIXTURE, provenance="measured")

    def silent(head):
        return [ln for ln in head if "SYNTHETIC" not in ln]

    plain = _tereno(tmp_path, header_edit=silent)
    assert read_tereno(plain).attrs["provenance"] == "unstated"
    assert read_tereno(plain, provenance="measured").attrs["provenance"] == "measured"
    with pytest.raises(InputError, match="provenance='real'"):
        read_tereno(plain, provenance="real")
    stated = _tereno(tmp_path, header_edit=lambda h: [*silent(h)[:1], "provenance: measured", *silent(h)[1:]])
    assert read_tereno(stated).attrs["provenance"] == "measured"
    # The CPlantBox format says nothing: unstated unless declared; the bundled day keeps its documented word.
    assert read_cplantbox_day(CPB, "2016-04-27").attrs["provenance"] == "unstated"
    assert read_weather(CPB, date="2016-04-27", provenance="measured").attrs["provenance"] == "measured"


def test_weather_show_states_provenance_honestly(tmp_path, monkeypatch):
    monkeypatch.setenv("LIGHTFIT_CACHE", str(tmp_path / "cache"))
    r = runner.invoke(app, ["weather", "show", str(FIXTURE)])
    assert r.exit_code == 0, r.output
    assert "SYNTHETIC weather" in r.stdout and "MEASURED" not in r.stdout
    for source in ("selhausen-cplantbox-day", str(CPB)):  # bundled, by name or by path: its documented word
        r = runner.invoke(app, ["weather", "show", source, "--date", "2016-04-27"])
        assert r.exit_code == 0, r.output
        assert "MEASURED (undated file placed on 2016-04-27) weather" in " ".join(r.stdout.split())
    copy = tmp_path / "day.txt"
    copy.write_bytes(CPB.read_bytes())
    out = tmp_path / "day.csv"
    r = runner.invoke(app, ["weather", "show", str(copy), "--date", "2016-04-27", "--csv", str(out)])
    assert r.exit_code == 0, r.output
    said = " ".join(r.stdout.split())
    assert "UNSTATED-PROVENANCE (undated file placed on 2016-04-27) weather" in said and "MEASURED" not in said
    assert out.read_text(encoding="utf-8").splitlines()[0] == "# provenance: unstated"
    assert read_weather(out).attrs["provenance"] == "unstated"
    r = runner.invoke(app, ["weather", "show", str(copy), "--date", "2016-04-27", "--provenance", "measured"])
    assert r.exit_code == 0 and "MEASURED (undated file placed on 2016-04-27) weather" in " ".join(r.stdout.split())
    _cli_error(["weather", "show", str(FIXTURE), "--provenance", "measured"], "contradicts", "synthetic")


# 4. quality flags --------------------------------------------------------------------------------


def test_values_flagged_bad_are_gaps(tmp_path):
    """A spike flagged ``bad`` was read as a value; it is a gap now, interpolated from its neighbours
    (the file's own values) and reported with its line."""
    lines = FIXTURE.read_text(encoding="utf-8").splitlines()
    rows = [ln.split(",") for ln in lines[next(i for i, ln in enumerate(lines) if ln.startswith("Timestamp")) + 1 :]]
    k = 60
    before, after = float(rows[k - 1][GHI]), float(rows[k + 1][GHI])

    def spike(rows):
        rows[k][GHI], rows[k][FLAG] = "1350.00", "bad"

    p = _tereno(tmp_path, spike)
    df = read_tereno(p)
    assert df["ghi_w_m2"].iloc[k] == pytest.approx((before + after) / 2)
    (flagged,) = [q for q in df.attrs["qc"] if q["kind"] == "flagged bad"]
    assert flagged["column"] == "ghi_w_m2" and flagged["count"] == 1
    assert f"line {_line_of(p, '1350.00')}" in flagged["detail"]
    assert ("interpolated", "ghi_w_m2") in [(q["kind"], q["column"]) for q in df.attrs["qc"]]

    def unknown(rows):
        rows[k][FLAG] = "suspect"

    p = _tereno(tmp_path, unknown)
    with pytest.raises(InputError, match=rf"line {_line_of(p, 'suspect')}, column '.*QualityFlag'.*'suspect'"):
        read_tereno(p)


# 5. unknown columns in a lightfit CSV ------------------------------------------------------------


def test_unknown_lightfit_columns_are_refused(tmp_path):
    text = RECON.read_text(encoding="utf-8")
    typo = tmp_path / "typo.csv"
    typo.write_text(text.replace("par_umol_m2_s", "par_umol_m2s"), encoding="utf-8")
    header = _line_of(typo, "time_utc,")
    with pytest.raises(InputError, match=rf"line {header}: unknown column\(s\) \['par_umol_m2s'\].*par_umol_m2_s"):
        read_weather(typo)


# 6. one-line errors, not tracebacks --------------------------------------------------------------


@pytest.mark.parametrize("sep", [";", "\t"])
def test_a_file_separated_by_semicolons_or_tabs_is_named_so(tmp_path, sep):
    """Weather and observations files alike (one reader): a header without commas but with ';' or a
    tab says so, naming its line, instead of 'no time column' (the whole line read as one name)."""
    from lightfit.inference.observations import read_observations

    twin = DATA_DIR / "observations" / "twin_2016-04-20_synthetic.csv"
    weather = bundled_path("2016-04-20")
    for path, read in ((twin, read_observations), (weather, read_lightfit_csv)):
        lines = path.read_text().splitlines()
        out = tmp_path / path.name
        out.write_text("\n".join(x if x.startswith("#") else x.replace(",", sep) for x in lines) + "\n")
        header = next(i for i, x in enumerate(lines) if not x.startswith("#")) + 1
        with pytest.raises(InputError, match=rf"line {header}: the header line separates its columns by") as e:
            read(out)
        assert e.value.file is not None and "comma-separated" in e.value.expected


def test_extra_field_and_mixed_offsets_name_their_lines(tmp_path, monkeypatch):
    monkeypatch.setenv("LIGHTFIT_CACHE", str(tmp_path / "cache"))

    def extra(rows):
        rows[30].append("99")

    p = _tereno(tmp_path, extra, "extra.csv")
    with pytest.raises(InputError, match=rf"line {_line_of(p, ',99')}: 9 fields, the header .* has 8"):
        read_tereno(p)

    def decimal_commas(rows):
        for r in rows:
            r[TAIR] = r[TAIR].replace(".", ",")

    p = _tereno(tmp_path, decimal_commas, "comma.csv")
    with pytest.raises(InputError, match=r"9 fields, the header .* has 8; decimal commas\? \(e\.g\. '-?\d+,\d+'\)"):
        read_tereno(p)
    with pytest.raises(InputError) as plain:
        read_tereno(_tereno(tmp_path, extra, "extra2.csv"))
    assert "decimal" not in str(plain.value)  # an integer stray field is not called a decimal comma

    def offset(rows):
        rows[30][0] += "+01:00"

    p = _tereno(tmp_path, offset, "offset.csv")
    n = _line_of(p, "+01:00")
    with pytest.raises(InputError, match=rf"line {n}, column 'Timestamp'.*has a UTC offset"):
        read_tereno(p)
    _cli_error(["weather", "show", str(p)], "offset.csv", f"line {n}")
    _cli_error(["replicate", "--quick", "--out", str(tmp_path / "o"), "--weather", str(p)], "offset.csv", f"line {n}")


def test_time_zone_option_errors_and_utc_offsets(tmp_path, monkeypatch):
    monkeypatch.setenv("LIGHTFIT_CACHE", str(tmp_path / "cache"))
    _cli_error(["weather", "show", str(FIXTURE), "--tz", "Foo/Bar"], "Foo/Bar", "not a time zone")
    no_zone = _tereno(tmp_path, header_edit=lambda h: [ln for ln in h if not ln.startswith("Time zone")])
    with pytest.raises(InputError, match="export.csv.*'Foo/Bar' is not a time zone"):
        read_weather(no_zone, tz="Foo/Bar")
    # UTC+2 is two hours ahead of UTC (pandas read the text "UTC+2" as a POSIX zone, two hours behind).
    first = no_zone.read_text(encoding="utf-8").splitlines()[_line_of(no_zone, "Timestamp")].split(",")[0]
    assert read_weather(no_zone, tz="UTC+2").index[0] == pd.Timestamp(first, tz="UTC") - pd.Timedelta("2h")
    with pytest.raises(InputError, match="whole-hour"):
        read_weather(no_zone, tz="UTC+5:30")


def test_a_latin1_file_is_refused_naming_its_line(tmp_path):
    text = RECON.read_text(encoding="utf-8") + "2016-04-21T00:00:00Z,0,0,10.8,0.85,100.1,400\n"
    lines = text.splitlines()
    lines.insert(3, "# note: temperatures in °C")
    p = tmp_path / "latin1.csv"
    p.write_bytes(("\n".join(lines) + "\n").encode("latin-1"))
    with pytest.raises(InputError, match=r"latin1\.csv, line 4: byte 0xb0 is not UTF-8"):
        read_weather(p)
    _cli_error(["weather", "show", str(p)], "latin1.csv", "line 4", "UTF-8")


# 8. day/month dates ------------------------------------------------------------------------------


@pytest.mark.parametrize("date", ["04/05/2016", "04/20/2016", "20.04.2016"])
def test_day_month_dates_are_refused(tmp_path, date):
    """04/05/2016 was read as 4 May and 04/20/2016 as 20 April, silently; only ISO 8601 is read."""

    def edit(rows):
        for r in rows:
            r[0] = f"{date} {r[0].split(' ')[1]}"

    p = _tereno(tmp_path, edit)
    with pytest.raises(InputError, match=rf"line {_line_of(p, date)}, column 'Timestamp'.*not ISO 8601"):
        read_tereno(p)


# 9. the header's time zone -----------------------------------------------------------------------


def test_header_time_zone_is_read(tmp_path):
    """``Time zone: UTC`` was read as UTC+1 (a one-hour shift)."""
    p = _tereno(tmp_path, header_edit=lambda h: [("Time zone: UTC" if ln.startswith("Time zone") else ln) for ln in h])
    first = FIXTURE.read_text(encoding="utf-8").splitlines()[_line_of(FIXTURE, "Timestamp")].split(",")[0]
    df = read_tereno(p)
    assert df.index[0] == pd.Timestamp(first, tz="UTC") and df.attrs["timezone_assumed"] == "UTC"
    with pytest.raises(InputError, match=r"tz='Europe/Berlin' disagrees with the header's 'Time zone: UTC'"):
        read_tereno(p, tz="Europe/Berlin")
    cet = _tereno(
        tmp_path, header_edit=lambda h: [("Time zone: CET" if ln.startswith("Time zone") else ln) for ln in h]
    )
    with pytest.raises(InputError, match=r"line 7: the header's time zone 'CET'"):
        read_tereno(cet)
    assert read_tereno(cet, tz="UTC+1").index.equals(read_tereno(FIXTURE).index)  # the caller says what it means
    worded = _tereno(
        tmp_path,
        header_edit=lambda h: [("Time zone: UTC (no DST)" if ln.startswith("Time zone") else ln) for ln in h],
        name="worded.csv",
    )
    assert read_tereno(worded).index.equals(df.index)


# 10. options that do not apply -------------------------------------------------------------------


def test_tz_and_date_that_do_not_apply_are_refused(tmp_path, monkeypatch):
    monkeypatch.setenv("LIGHTFIT_CACHE", str(tmp_path / "cache"))
    with pytest.raises(InputError, match="tz='Europe/Berlin' given for a lightfit CSV"):
        read_weather(RECON, tz="Europe/Berlin")
    with pytest.raises(InputError, match="date=1999-01-01 given for a file whose timestamps carry their dates"):
        read_weather(FIXTURE, date="1999-01-01")
    _cli_error(["weather", "show", str(FIXTURE), "--date", "1999-01-01"], "--date 1999-01-01")
    _cli_error(["weather", "show", "2016-04-20", "--tz", "UTC"], "lightfit CSV")


# 11., 12. empty times, line numbers after blank lines --------------------------------------------


def test_empty_time_names_its_line(tmp_path):
    def edit(rows):
        rows[30][0] = ""
        rows[30][TAIR] = "12.345"

    p = _tereno(tmp_path, edit)
    with pytest.raises(InputError, match=rf"line {_line_of(p, '12.345')}, column 'Timestamp': empty time"):
        read_tereno(p)


def test_line_numbers_survive_blank_lines(tmp_path):
    lines = RECON.read_text(encoding="utf-8").splitlines()
    first = next(i for i, ln in enumerate(lines) if ln.startswith("time_utc"))
    lines.insert(first + 3, "")
    cells = lines[first + 20].split(",")
    cells[lines[first].split(",").index("tair_c")] = "abc"
    lines[first + 20] = ",".join(cells)
    p = tmp_path / "blank.csv"
    p.write_text("\n".join(lines) + "\n", encoding="utf-8")
    with pytest.raises(InputError, match=rf"line {_line_of(p, ',abc,')}, column 'tair_c': value 'abc'"):
        read_weather(p)


# 13. sorting before the 30-min CO2 is spread -----------------------------------------------------


def test_unsorted_rows_give_the_sorted_files_series(tmp_path):
    """A row with a 30-min CO2 mean swapped with the row after it: the series equals the fixture's
    (the CO2 was spread over the rows in file order, before sorting: the later row took the earlier
    interval's mean)."""

    def swap(rows):
        assert rows[3][7] and not rows[4][7]
        rows[3], rows[4] = rows[4], rows[3]

    df, ref = read_tereno(_tereno(tmp_path, swap)), read_tereno(FIXTURE)
    pd.testing.assert_frame_equal(df, ref)
    assert any(q["kind"] == "sorted" for q in df.attrs["qc"])


# 14., help ---------------------------------------------------------------------------------------


def test_chamber_record_cites_a_section_in_the_repository():
    record = DATA_DIR / "observations" / "chamber_2016-04-20_record.csv"
    source = next(ln for ln in record.read_text(encoding="utf-8").splitlines() if ln.startswith("# source:"))
    m = re.match(r"# source: (\S+) §(\d+)", source)
    assert m, source
    doc = (DATA_DIR.parent / m[1]).read_text(encoding="utf-8")
    section = doc.split(f"\n## {m[2]}.")[1].split("\n## ")[0]
    time, par = pd.read_csv(record, comment="#").iloc[0, :2]
    assert f"{time}, PAR {par}" in section  # the section states the recorded point


def test_weather_help_says_what_show_does():
    r = runner.invoke(app, ["weather", "--help"], env={"COLUMNS": "200"})
    assert r.exit_code == 0
    text = " ".join(r.output.split())
    assert "'show' reads one" in text and "--csv" in text and "--plot" in text


def test_derived_columns_of_a_file_are_recomputed_and_differences_reported(tmp_path):
    """A lightfit CSV carries sun angles and a DNI/DHI split; they are recomputed for the run's site
    and split model, and where that changes them the series' QC says so (nothing replaced silently)."""
    from lightfit.weather import write_lightfit_csv
    from lightfit.weather.site import Site

    series = add_solar(read_tereno(FIXTURE))
    csv = write_lightfit_csv(series, tmp_path / "w.csv", {"provenance": "synthetic"})
    back = read_weather(csv)
    same = add_solar(back)
    assert not [q for q in same.attrs["qc"] if q["kind"] == "recomputed"]
    pd.testing.assert_series_equal(same["dni_w_m2"], series["dni_w_m2"], check_freq=False, atol=0.5)

    other = add_solar(back, split_model="boland")
    notes = {q["column"]: q for q in other.attrs["qc"] if q["kind"] == "recomputed"}
    assert set(notes) == {"dni_w_m2", "dhi_w_m2"}
    moved = (other["dni_w_m2"] - back["dni_w_m2"]).abs()
    assert notes["dni_w_m2"]["count"] == int((moved > 0.5).sum()) > 0

    elsewhere = Site(latitude_deg=40.0, name="south")
    moved_sun = {q["column"] for q in add_solar(back, site=elsewhere).attrs["qc"] if q["kind"] == "recomputed"}
    assert {"sun_elevation_deg", "sun_azimuth_deg"} <= moved_sun
    # and on the model commands' path (the run's window resamples and adds the sun again)
    series_south = add_solar(read_tereno(FIXTURE), site=elsewhere)
    south = write_lightfit_csv(series_south, tmp_path / "s.csv", {"provenance": "synthetic"})
    run_qc = rep.forcing(south, dates="2016-04-20", window=Window("10:00", 2.0)).attrs["qc"]
    assert {"sun_elevation_deg", "dni_w_m2"} <= {q["column"] for q in run_qc if q["kind"] == "recomputed"}


def test_light_that_its_sun_cannot_give_is_refused(tmp_path):
    """An undated day placed on a date its light does not fit (daylight with the sun below the
    horizon, Erbs DNI above the solar constant) is refused naming the file, the column and a step;
    the dates the light fits (data/README.md) and every bundled series pass."""
    with pytest.raises(InputError, match=r"column 'PAR'.*2016-03-25 .*sun at -?\d+\.\d°.*more light than their sun"):
        add_solar(read_cplantbox_day(CPB, "2016-03-25"))
    _cli_error(
        ["weather", "show", "selhausen-cplantbox-day", "--date", "2016-12-23"], "selhausen_cplantbox_day.txt", "--date"
    )
    for date in ("2016-04-19", "2016-04-27", "2016-08-15"):
        ok = add_solar(read_cplantbox_day(CPB, date))
        assert ok["dni_w_m2"].max() < 1361.0  # below the solar constant
    add_solar(read_weather(RECON))
    add_solar(read_tereno(FIXTURE))

    def one_glitch(rows):  # a single night spike is a glitch, left to the caller
        rows[3][PAR] = "400"

    add_solar(read_tereno(_tereno(tmp_path, one_glitch, "glitch.csv")))

    def shifted(rows):  # each value three hours (18 ten-minute rows) early: noon light at a low sun
        return [[r[0], *rows[(i + 18) % len(rows)][1:]] for i, r in enumerate(rows)]

    with pytest.raises(InputError, match="more light than their sun can give"):
        add_solar(read_tereno(_tereno(tmp_path, shifted, "shifted.csv")))


def test_unrecognised_files_say_what_each_format_needs(tmp_path):
    """A hand-made lightfit CSV without its metadata, or any other table, is told what is missing;
    --format is honoured before the format is sniffed (it was guessed first and the reason lost)."""
    plain = tmp_path / "plain.csv"
    plain.write_text("\n".join(ln for ln in RECON.read_text().splitlines() if not ln.startswith("#")) + "\n")
    with pytest.raises(InputError, match=r"line 1: a lightfit CSV \(time_utc, …\) without its metadata lines"):
        read_weather(plain)
    # metadata lines, then a table whose time column is not time_utc: the header is named, not the
    # metadata ("unrecognised weather file format (first line '# provenance: measured')" before)
    timed = tmp_path / "timed.csv"
    timed.write_text(
        "# provenance: measured\ntime,ghi_w_m2,tair_c,rh,co2_ppm,pair_kpa\n2016-05-10T09:00:00Z,680,15,0.65,400,100.5\n"
    )
    with pytest.raises(InputError, match=r"timed\.csv, line 2: .*no time_utc column \(header 'time,ghi_w_m2"):
        read_weather(timed)
    # the same said of a file lightfit wrote (its '# columns: time_utc …' line read as lightfit's:
    # "no time_utc column" without the header before), and with the format given
    renamed = tmp_path / "renamed.csv"
    renamed.write_text(RECON.read_text().replace("\ntime_utc,", "\ntime,", 1))
    for fmt in ("auto", "lightfit"):
        with pytest.raises(InputError, match=r"renamed\.csv, line 10: .*no time_utc column \(header 'time,ghi_w_m2"):
            read_weather(renamed, format=fmt)
    # a blank line between the metadata and the header: the header's own line, not the one after
    # the metadata (the last review: "line 10" named the blank line)
    renamed.write_text(RECON.read_text().replace("\ntime_utc,", "\n\ntime,", 1))
    with pytest.raises(InputError, match=r"renamed\.csv, line 11: .*no time_utc column"):
        read_weather(renamed)
    from lightfit.inference.observations import read_observations

    obs = tmp_path / "obs.csv"
    obs.write_text("# provenance: synthetic\n\nwhen,plant_par_umol_m2_s\n2016-04-20T10:00:00Z,300\n")
    with pytest.raises(InputError, match=r"obs\.csv, line 3: no 'time' column"):
        read_observations(obs)
    junk = tmp_path / "junk.csv"
    junk.write_text("a,b\n1,2\n")
    with pytest.raises(InputError, match=r"unrecognised weather file format \(first line 'a,b'\).*time<TAB>PAR"):
        read_weather(junk)
    _cli_error(["weather", "show", str(plain), "--format", "lightfit"], "plain.csv", "no metadata line '# provenance")
    # a metadata line's error is the file's, not an option's the user did not give
    tl = tmp_path / "tl.csv"
    tl.write_text(RECON.read_text().replace("# time_label: instant", "# time_label: bogus", 1))
    err = _cli_error(["weather", "show", str(tl)], "tl.csv", "bogus")
    assert "option --time-label" not in err
    twice = tmp_path / "twice.csv"
    twice.write_text(RECON.read_text().replace("# provenance:", "# time_label: end\n# provenance:", 1))
    with pytest.raises(InputError, match=r"line \d+: metadata key 'time_label' given twice"):
        read_weather(twice)


def test_clock_change_times_are_refused_naming_the_option(tmp_path):
    # 2016-03-27 02:30 does not exist in Europe/Berlin (clocks went 02:00 → 03:00); 2016-10-30 02:30
    # happened twice. Both are inside a season lightfit grows wheat for.
    forward, back = r"does not exist \(the clocks go forward\)", r"happens twice \(the clocks go back\)"
    for day, what in (("2016-03-27", forward), ("2016-10-30", back)):
        with pytest.raises(InputError, match=rf"parameter 'start_time'.*{day} 02:30 {what} in Europe/Berlin"):
            Window("02:30").bounds_utc(day, "Europe/Berlin")
    df = read_weather(RECON)
    with pytest.raises(InputError, match=r"parameter 'start_time'.*does not exist"):
        weather_window(df, "2016-03-27 02:30", 1)


@pytest.mark.parametrize("name", ["CET", "cet", "MET", "EET", "WET"])
def test_zone_names_with_two_meanings_are_refused_as_options(tmp_path, name):
    # tzdata's CET has summer time; a logger's "CET" means UTC+1 all year: --tz must say which.
    no_zone = _tereno(tmp_path, header_edit=lambda h: [ln for ln in h if not ln.startswith("Time zone")])
    with pytest.raises(InputError, match=rf"'{name}' could mean two things.*UTC\+\d.*Europe/Berlin"):
        read_weather(no_zone, tz=name)


def test_pressure_of_a_high_site_is_read(tmp_path):
    # 2 500 m: ≈ 75 kPa (pvlib.atmosphere.alt2pres), a site Site accepts; hPa would still be refused.
    assert 70.0 < pvlib.atmosphere.alt2pres(2500.0) / 1000 < 80.0
    text = RECON.read_text(encoding="utf-8")
    lines = text.splitlines()
    hdr = next(i for i, ln in enumerate(lines) if ln.startswith("time"))
    cols = lines[hdr].split(",")
    k = cols.index("pair_kpa")

    def with_pressure(v):
        rows = [ln.split(",") for ln in lines[hdr + 1 :]]
        for r in rows:
            r[k] = f"{v:g}"
        return "\n".join(lines[: hdr + 1] + [",".join(r) for r in rows]) + "\n"

    high = tmp_path / "high.csv"
    high.write_text(with_pressure(75.0), encoding="utf-8")
    assert (read_weather(high)["pair_kpa"] == 75.0).all()
    hpa = tmp_path / "hpa.csv"
    hpa.write_text(with_pressure(750.0), encoding="utf-8")
    with pytest.raises(InputError, match=r"hpa.csv.*column 'pair_kpa'.*check the unit"):
        read_weather(hpa)


def test_a_chamber_time_inside_a_clock_change_names_its_line(tmp_path):
    from lightfit.inference.observations import read_observations

    p = tmp_path / "chamber.csv"
    p.write_text(
        "# provenance: measured\n# time_zone: Europe/Berlin\n"
        "time,above_canopy_par_umol_m2_s,above_canopy_par_sd_umol_m2_s\n"
        "2016-10-30 01:30:00,10.0,1.0\n2016-10-30 02:30:00,12.0,1.0\n",
        encoding="utf-8",
    )
    with pytest.raises(InputError, match=r"chamber.csv, line 5, column 'time'.*2016-10-30 02:30 happens twice"):
        read_observations(p)


@pytest.mark.parametrize(
    ("stamp", "why"),
    [("20/04/2016 10:00", "not ISO 8601"), ("04/05/2016 10:00", "4 May or 5 April"), ("April 20 2016 10:00", "")],
)
def test_observation_times_are_iso_or_refused(tmp_path, stamp, why):
    # The weather's reader of times reads the observations' too: a day/month date is never guessed
    # (pandas took 05/04/2016 as 4 May and 20/04/2016 as 20 April, in one file).
    from lightfit.inference.observations import read_observations

    p = tmp_path / "obs.csv"
    p.write_text(
        "# provenance: measured\n# time_zone: UTC\ntime,above_canopy_par_umol_m2_s,above_canopy_par_sd_umol_m2_s\n"
        f"2016-04-20 09:00,10.0,1.0\n{stamp},12.0,1.0\n",
        encoding="utf-8",
    )
    with pytest.raises(InputError, match=rf"obs.csv, line 5, column 'time': cannot parse time.*{why}.*ISO 8601"):
        read_observations(p)
    p.write_text(p.read_text(encoding="utf-8").replace("# time_zone: UTC\n", "").replace(stamp, "2016-04-20 10:00"))
    with pytest.raises(InputError, match=r"line 3, column 'time'.*no UTC offset and no time zone.*'# time_zone"):
        read_observations(p)


@pytest.mark.parametrize(
    ("right", "wrong", "quantity"),
    [
        ("RadiationPhotosyntheticActive", "RadiationPhotosynthticActive", "par_umol_m2_s"),
        ("AirTemperature", "AirTemperatur", "tair_c"),
    ],
)
def test_a_misspelt_tereno_column_is_named_not_replaced_by_an_estimate(tmp_path, right, wrong, quantity):
    # Unread, a misspelt PAR column was replaced by PAR estimated from global radiation, said only on
    # stdout; a misspelt air temperature failed later, naming humidity's need instead of the column.
    def misspell(head):
        return [ln.replace(right, wrong) if ln.startswith("Timestamp") else ln for ln in head]

    p = _tereno(tmp_path, header_edit=misspell)
    n = _line_of(p, "Timestamp")
    with pytest.raises(InputError, match=rf"line {n}, column '{wrong}.*misspelt {right} \({quantity}\)"):
        read_tereno(p)
    # Other instruments' columns are not taken for misspellings of a quantity the table has.
    extra = "SoilTemperature_5cm_Avg10min [°C]"
    other = _tereno(
        tmp_path,
        name="soil.csv",
        header_edit=lambda h: [ln + "," + extra if ln.startswith("Timestamp") else ln for ln in h],
        edit=lambda rows: [[*r, "8.5"] for r in rows],
    )
    assert extra in read_tereno(other).attrs["unused_columns"]


def test_an_undated_file_placed_on_a_date_says_so_where_its_provenance_is_shown(tmp_path):
    # The CPlantBox day is a measurement of an unknown day: on a date the caller gives, titles say both.
    from lightfit.weather.plot import provenance_label

    df = read_cplantbox_day(CPB, "2016-04-27", provenance="measured")
    assert df.attrs["date_given"] == "2016-04-27"
    assert provenance_label(df.attrs) == "MEASURED (undated file placed on 2016-04-27)"
    assert provenance_label(read_weather(RECON).attrs) == "RECONSTRUCTED"
    r = runner.invoke(app, ["weather", "show", "selhausen-cplantbox-day", "--date", "2016-04-27"])
    assert r.exit_code == 0 and "MEASURED (undated file placed on 2016-04-27) weather" in " ".join(r.stdout.split())


def test_observation_times_mixing_offsets_without_a_zone_name_the_line(tmp_path):
    # Read by the weather's reader of times, which built its message with the zone: None was a TypeError.
    from lightfit.inference.observations import read_observations

    p = tmp_path / "mixed.csv"
    p.write_text(
        "# provenance: measured\ntime,above_canopy_par_umol_m2_s,above_canopy_par_sd_umol_m2_s\n"
        "2016-04-20T10:00:00+02:00,10,1\n2016-04-20 11:00:00,12,1\n",
        encoding="utf-8",
    )
    with pytest.raises(
        InputError, match=r"mixed.csv, line 4, column 'time'.*has no UTC offset.*the time zone the file"
    ):
        read_observations(p)


def test_daylight_at_night_is_a_timing_error_not_a_unit_slip():
    """A clear day whose clock is 12 h off (a file read in the wrong zone, or at the wrong site) has
    its light at night and little at the high sun: that is the timestamps' fault, and the error says
    so and names the site the sun was taken at, instead of calling the unit wrong."""
    day = _clear_day(1.0)
    shifted = day.set_axis(day.index + pd.Timedelta("12h"))
    with pytest.raises(InputError, match=r"with the sun at -?[\d.]+° at Selhausen.*more light than their sun.*site"):
        add_solar(shifted)


def test_a_missing_quantity_is_named_as_the_files_format_names_it(tmp_path):
    """A TERENO export without CO2 is told the header lightfit reads CO2 from, with its units (it said
    'expected columns for co2_ppm', the contract's name, which a TERENO file never has; a review)."""

    def drop_co2(rows):
        return [r[:7] for r in rows]

    def drop_co2_header(head):
        head[-1] = ",".join(head[-1].split(",")[:7])

    path = _tereno(tmp_path, drop_co2, "no_co2.csv", drop_co2_header)
    with pytest.raises(InputError, match=r"no_co2.csv: missing column\(s\) co2_ppm .*AirConcentration_CO2_2m_"):
        read_tereno(path)
    _cli_error(["weather", "show", str(path)], "no_co2.csv", "[ppm or mmol*m-3]", "CO2 mole fraction")
    # a lightfit CSV names its columns as the contract does
    df = read_weather(RECON).drop(columns=["co2_ppm"])
    lf = write_lightfit_csv(df, tmp_path / "lf.csv", {"provenance": "synthetic"})
    with pytest.raises(InputError, match=r"missing column\(s\) co2_ppm \(expected co2_ppm \(CO2 mole fraction in air"):
        read_weather(lf)


def test_daylight_with_the_sun_just_below_the_horizon_is_left_to_the_timing_check():
    """Light at two steps with the sun below the horizon (here in civil twilight, −3° and −1°) and
    little at the high sun is a timing error, which check_light_fits_sun names: the unit check does not
    judge such a series (its docstring; a mutation audit: 'below the horizon' taken as below −6°
    survived, the 12 h shift above putting the light far below it)."""
    from lightfit.weather.solar import check_light_fits_sun, check_radiation_scale

    t = pd.date_range("2016-04-20 10:00", periods=4, freq="10min", tz="UTC")
    df = pd.DataFrame({"ghi_w_m2": [300.0, 300.0, 1.0, 1.0]}, index=t)
    el = pd.Series([-3.0, -1.0, 30.0, 40.0], index=t)
    check_radiation_scale(df, el)  # 1 W m⁻² is 0.1 % of clear sky at 30–40°, but the timestamps are at fault
    with pytest.raises(InputError, match="more light than their sun can give"):
        check_light_fits_sun(df, el)


@pytest.mark.parametrize(("kpa", "ok"), [(108.33, True), (110.0, True), (112.0, False), (50.0, True), (49.0, False)])
def test_air_pressure_outside_what_a_field_can_have_is_refused(kpa, ok):
    """Station pressure 50–110 kPa (series.BOUNDS): the highest sea-level pressure on record is
    ≈ 108.3 kPa (Agata, Siberia, 31 Dec 1968; WMO archive of weather and climate extremes), so 112 kPa
    is a unit or offset slip; 50 kPa is ≈ 5 500 m (a mutation audit: the upper bound raised to 120 kPa survived)."""
    from lightfit.weather.series import check_and_repair

    t = pd.date_range("2016-04-20 10:00", periods=4, freq="10min", tz="UTC")
    df = pd.DataFrame({"ghi_w_m2": 500.0, "tair_c": 15.0, "rh": 0.6, "pair_kpa": 100.0, "co2_ppm": 400.0}, index=t)
    df.iloc[2, df.columns.get_loc("pair_kpa")] = kpa
    lines = pd.Series(range(2, 6), index=t)
    if ok:
        assert check_and_repair(df, lines, "w.csv")["pair_kpa"].iloc[2] == kpa
    else:
        with pytest.raises(InputError, match=r"w\.csv.*pair_kpa.*50 … 110"):
            check_and_repair(df, lines, "w.csv")


@pytest.mark.parametrize("step", ["30", 30, "1.5", "30s", "0min", "2x", "20h", "", "nan", None])
def test_a_window_step_needs_its_unit_and_at_least_a_minute(step):
    """A bare number is no step: pandas reads "30" as 30 ns, and --step 30 (or Window(step="30")) ended in
    a MemoryError allocating 20.8 TiB of steps, a traceback instead of this message (a newcomer's review)."""
    with pytest.raises(InputError, match=r"parameter 'step'.*a time step with its unit, from 1min to the window"):
        Window("10:00", 10.0, step)


def test_a_window_may_end_on_the_series_last_row():
    """A window inside the series' span is taken, its end included: the bundled day's instants run
    00:00–23:50 UTC, so 20:50 + 3 h ends on its last row and gives 7 half-hourly steps (a mutation
    audit: the window refused when it ended on the last row survived)."""
    df = read_weather(RECON)
    assert df.index[-1] == pd.Timestamp("2016-04-20 23:50", tz="UTC")
    w = weather_window(df, "2016-04-20 20:50+00:00", 3.0)
    assert list(w.index) == list(pd.date_range("2016-04-20 20:50", "2016-04-20 23:50", freq="30min", tz="UTC"))
    with pytest.raises(InputError, match="not covered by the series"):
        weather_window(df, "2016-04-20 21:00+00:00", 3.0)


@pytest.mark.parametrize(
    ("zone_line", "stamp", "expected"),
    [
        # An unknown zone was zoneinfo's traceback (exit 1); UTC±H, which --timezone and TERENO headers
        # take, was refused as "ambiguous or does not exist" (a helper's newcomer review).
        ("Mars/Base", "2016-04-20 12:13:48", r"obs.csv, column 'time_zone': time_zone='Mars/Base' is not a time zone"),
        ("UTC+2", "2016-04-20 12:13:48", "2016-04-20 10:13:48+00:00"),
        ("Europe/Berlin", "2016-04-20T12:13:48+02:00", "2016-04-20 10:13:48+00:00"),
        ("Europe/Berlin", "2016-04-20T10:13:48Z", "2016-04-20 10:13:48+00:00"),  # ISO's UTC, whatever the zone
        # A zone line and offsets that contradict each other: which is meant cannot be told.
        ("UTC", "2016-04-20T12:13:48+02:00", r"line 4, column 'time'.*is in UTC\+2, but the stated time zone UTC"),
        ("Europe/Berlin", "2016-01-20T12:13:48+02:00", r"stated time zone Europe/Berlin was at UTC\+1 then"),
    ],
)
def test_an_observation_files_zone_is_read_as_the_timezone_option_reads_it(tmp_path, zone_line, stamp, expected):
    from lightfit.inference.observations import read_observations

    p = tmp_path / "obs.csv"
    p.write_text(
        f"# provenance: measured\n# time_zone: {zone_line}\n"
        f"time,above_canopy_par_umol_m2_s,above_canopy_par_sd_umol_m2_s\n{stamp},1549.31,77\n",
        encoding="utf-8",
    )
    if expected.startswith("2016"):
        assert str(read_observations(p).index[0]) == expected
    else:
        with pytest.raises(InputError, match=expected):
            read_observations(p)


@pytest.mark.parametrize(
    ("column", "value"), [("canopy_an_umol_m2_s", 1200.0), ("nee_umol_m2_s", -20000.0), ("canopy_an_umol_m2_s", 101.0)]
)
def test_a_co2_flux_in_another_unit_is_refused_naming_the_units(tmp_path, column, value):
    """CO2 fluxes beyond 100 µmol m⁻² s⁻¹ (no crop canopy comes near it; observations.MAX_CO2_FLUX)
    are another unit, e.g. mg CO2 m⁻² h⁻¹ (158 ×): they were fitted as given, driving vcmax_scale to
    5.6 with generic cautions only (a newcomer review). 99 passes; the rule holds for tables built
    in code too (check_sds)."""
    from lightfit.inference.observations import check_sds, read_observations

    sd = column.replace("_umol", "_sd_umol")
    p = tmp_path / "obs.csv"
    p.write_text(
        f"# provenance: measured\n# time_zone: UTC\ntime,{column},{sd}\n"
        f"2016-04-20 10:00,-5.0,1.0\n2016-04-20 11:00,{value},2.0\n",
        encoding="utf-8",
    )
    with pytest.raises(
        InputError, match=rf"obs.csv, line 5, column '{column}'.*\|value\| ≤ 100.*mg CO2 m-2 h-1 is 158"
    ):
        read_observations(p)
    p.write_text(p.read_text(encoding="utf-8").replace(f",{value},", ",99.0,"), encoding="utf-8")
    obs = read_observations(p)
    check_sds(obs)
    obs.loc[obs.index[1], column] = value
    with pytest.raises(InputError, match=rf"column '{column}'.*\|value\| ≤ 100"):
        check_sds(obs)


def test_repairs_say_which_column_and_line(tmp_path):
    """`weather show` printed seven identical "1 missing value(s) linearly interpolated" lines for one
    empty row, and "sorted" without where (a newcomer review): each repair now names the file's column
    and the first line concerned, found here in the text, not by the reader."""
    rows_box = {}

    def blank_and_swap(rows):
        rows[10][TAIR] = ""  # one air temperature missing
        rows[20], rows[21] = rows[21], rows[20]  # two rows out of order
        rows_box["blank"], rows_box["late"] = rows[10][0], rows[21][0]

    p = _tereno(tmp_path, edit=blank_and_swap)
    r = runner.invoke(app, ["weather", "show", str(p)])
    assert r.exit_code == 0, r.output
    out = " ".join(r.stdout.split())
    tair = next(c for c in FIXTURE.read_text(encoding="utf-8").splitlines() if c.startswith("Timestamp")).split(",")[
        TAIR
    ]
    blank, swapped = _line_of(p, rows_box["blank"]), _line_of(p, rows_box["late"])
    assert f"repair interpolated: {tair}: 1 missing value(s)" in out
    assert f"line {blank})" in out
    assert f"the first out of order: line {swapped}," in out and f"before line {swapped - 1}'s time" in out


def test_a_tereno_file_without_a_zone_line_reads_times_with_offsets_by_them(tmp_path):
    """Only a zone the file or the caller states is held against offsets in the times: the format's
    default (UTC+1) is not (a review: `...Z` times without a `Time zone:` line were refused as
    contradicting a zone nobody stated). Stated, a contradicting offset is refused."""

    def utc(rows):
        for r in rows:  # the fixture's UTC+1 clock written as UTC instants
            r[0] = (pd.Timestamp(r[0]) - pd.Timedelta("1h")).strftime("%Y-%m-%dT%H:%M:%SZ")

    def offset_2h(rows):
        for r in rows:
            r[0] = (pd.Timestamp(r[0]) + pd.Timedelta("1h")).strftime("%Y-%m-%dT%H:%M:%S+02:00")

    no_zone = lambda head: [ln for ln in head if not ln.startswith("Time zone")]  # noqa: E731
    expected = read_tereno(FIXTURE).index
    assert read_tereno(_tereno(tmp_path, edit=utc, header_edit=no_zone)).index.equals(expected)
    assert read_tereno(_tereno(tmp_path, edit=offset_2h, header_edit=no_zone, name="b.csv")).index.equals(expected)
    with pytest.raises(InputError, match=r"is in UTC\+2, but the stated time zone UTC\+1 was at UTC\+1 then"):
        read_tereno(_tereno(tmp_path, edit=offset_2h, name="c.csv"))


@pytest.mark.parametrize("content", [b"", b"\xef\xbb\xbf", b"\r\n\r\n  \n"], ids=["0 bytes", "BOM only", "blank lines"])
def test_an_empty_file_or_a_folder_is_named_so_by_every_reader(tmp_path, content):
    """A failed export (0 bytes, a BOM, blank lines) was told only what its first line lacked ("no
    metadata line '# provenance'", "unrecognised weather file format (first line '')"), and the
    CPlantBox reader raised IndexError; a folder was the OS's IsADirectoryError, outside the CLI. Each
    reader now says the file is empty, or a folder, and what it expected."""
    from lightfit.inference.observations import read_observations

    empty = tmp_path / "export.csv"
    empty.write_bytes(content)
    folder = tmp_path / "folder.csv"
    folder.mkdir()
    readers = {
        "a TERENO CSV export": read_tereno,
        "a CPlantBox weather file": lambda p: read_cplantbox_day(p, "2016-04-27"),
        "a lightfit weather CSV": read_lightfit_csv,
        "a weather file": read_weather,
        "an observations CSV": read_observations,
    }
    for expected, read in readers.items():
        with pytest.raises(InputError, match=rf"export\.csv: the file is empty \({len(content)} bytes, no text\)") as e:
            read(empty)
        assert f"(expected {expected})" in str(e.value)
        with pytest.raises(InputError, match=rf"folder\.csv: a folder, not a file \(expected {expected}\)"):
            read(folder)
    _cli_error(["weather", "show", str(empty)], "export.csv", "the file is empty", "expected a weather file")
    _cli_error(["weather", "show", str(empty), "--format", "cplantbox", "--date", "2016-04-27"], "the file is empty")


@pytest.mark.parametrize("text", ["inf", "-Infinity", "1e999"])
def test_an_infinite_value_is_refused_as_not_a_number_not_as_a_unit(tmp_path, text):
    """'inf' in a weather column was read as a number: called implausible with "check the unit"
    (after a RuntimeWarning from the humidity conversion), or passed a column without bounds. It is
    refused as text, naming the file, line and column, as observations files refuse it."""

    def edit(rows):
        rows[40][TAIR] = text

    p = _tereno(tmp_path, edit)
    with pytest.raises(
        InputError, match=rf"line {_line_of(p, text)}, column 'AirTemperature[^']*': value '{text}' is not a finite"
    ):
        read_tereno(p)
    lf = tmp_path / "lf.csv"  # the 12:00 row's global radiation
    lf.write_text(re.sub(r"(?m)^(2016-04-20T12:00:00Z),[^,]*", rf"\1,{text}", RECON.read_text()))
    err = _cli_error(["weather", "show", str(lf)], "lf.csv", f"line {_line_of(lf, text)}", "column 'ghi_w_m2'")
    assert f"value '{text}' is not a finite number" in err and "check the unit" not in err


@pytest.mark.parametrize("year", ["0001", "1600", "2263", "9999"])
def test_a_year_outside_what_lightfit_computes_with_is_refused_naming_its_line(tmp_path, year):
    """A lightfit CSV in the year 0001 or 9999 (a slip in the year) was read, and `weather show` then
    stopped on pandas' OutOfBoundsDatetime traceback (its stamps cast to nanoseconds, which end in
    1677 and 2262); a TERENO export of such a year was read and shown as if it were weather. Both are
    refused naming line and column."""
    lf = tmp_path / "lf.csv"
    lf.write_text(RECON.read_text(encoding="utf-8").replace("2016-04-20T", f"{year}-04-20T"), encoding="utf-8")
    stamp = f"{year}-04-20T00:00:00Z"
    with pytest.raises(InputError, match=rf"lf\.csv, line {_line_of(lf, stamp)}, column 'time_utc': time '{stamp}'"):
        read_weather(lf)
    _cli_error(["weather", "show", str(lf)], "lf.csv", f"line {_line_of(lf, stamp)}", "1678–2261")

    def in_year(y):
        return lambda rows: [[r[0].replace("2016", y), *r[1:]] for r in rows]

    p = _tereno(tmp_path, edit=in_year(year))
    with pytest.raises(InputError, match=rf"export\.csv, line {_line_of(p, year + '-04-20')}, column 'Timestamp'"):
        read_tereno(p)
    assert len(read_tereno(_tereno(tmp_path, edit=in_year("2261")))) == len(read_tereno(FIXTURE))


def test_tereno_humidity_repairs_and_errors_name_the_files_column(tmp_path):
    """A TERENO export's humidity is read into rh, but the series recorded its source column under
    "humidity": every other column's repairs and errors named the file's column, humidity's said "rh",
    a column the file does not have (an interpolated gap, a value implausible after conversion)."""
    header = next(c for c in FIXTURE.read_text(encoding="utf-8").splitlines() if c.startswith("Timestamp"))
    hum = header.split(",")[HUM]

    def blank(rows):
        rows[10][HUM] = ""

    p = _tereno(tmp_path, edit=blank)
    assert read_tereno(p).attrs["columns_used"]["rh"] == hum
    r = runner.invoke(app, ["weather", "show", str(p)])
    assert r.exit_code == 0, r.output
    assert f"repair interpolated: {hum}: 1 missing value(s)" in " ".join(r.stdout.split())

    def wet(rows):
        rows[40][HUM] = "100"  # g m⁻³: far above saturation

    p = _tereno(tmp_path, edit=wet, name="wet.csv")
    with pytest.raises(
        InputError, match=rf"line {_line_of(p, ',100,')}, column 'rh': value .* \(read from {re.escape(hum)},"
    ):
        read_tereno(p)


@pytest.mark.parametrize("source", [FIXTURE, RECON, CPB])
def test_a_utf16_file_is_refused_for_its_encoding_not_as_an_unknown_format(tmp_path, source):
    """A UTF-16 file (Excel's "Unicode text") was called an "unrecognised weather file format", its
    first line shown as '��T\\x00E\\x00…'; the docs promise a file in another encoding is refused as such."""
    p = tmp_path / "utf16.csv"
    p.write_bytes(source.read_text(encoding="utf-8").encode("utf-16"))
    with pytest.raises(InputError, match=r"utf16\.csv, line 1: byte 0xff is not UTF-8 text \(the file is in UTF-16\)"):
        read_weather(p, **({"date": "2016-04-27"} if source == CPB else {}))
    err = _cli_error(["weather", "show", str(p)], "utf16.csv", "line 1", "UTF-16")
    assert "unrecognised" not in err
