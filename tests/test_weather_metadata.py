"""The metadata lines (``# key: value``) of lightfit's own weather CSV (reviews)."""

from __future__ import annotations

import pandas as pd
import pytest
from typer.testing import CliRunner

from lightfit.cli import app
from lightfit.errors import InputError
from lightfit.weather import load, read_weather, write_lightfit_csv
from lightfit.weather.bundled import DATA_DIR
from lightfit.weather.readers import lightfit_csv_text, sniff_format

BODY = (
    "time_utc,ghi_w_m2,tair_c,rh,pair_kpa,co2_ppm\n"
    "2016-04-20T10:00:00,500,15,0.6,100,400\n"
    "2016-04-20T10:10:00,510,15.2,0.6,100,400\n"
    "2016-04-20T10:20:00,520,15.4,0.6,100,400\n"
)


@pytest.mark.parametrize("said", ["Europe/Berlin", "UTC+1", "Etc/GMT-2"])
def test_a_time_zone_line_other_than_utc_is_refused(tmp_path, said):
    """A lightfit CSV's times are UTC (column time_utc): a ``# time_zone: Europe/Berlin`` line was
    ignored and the local times it announces read as UTC, 1–2 h off. Refused now, naming the file
    and the line."""
    path = tmp_path / "local.csv"
    path.write_text(f"# provenance: measured\n# time_zone: {said}\n" + BODY)
    with pytest.raises(InputError, match="whose times are UTC") as e:
        read_weather(path)
    assert "local.csv" in str(e.value) and said in str(e.value) and e.value.column == "time_zone"


@pytest.mark.parametrize("said", ["UTC", "UTC+0", "Etc/UTC", "GMT"])
def test_a_time_zone_line_saying_utc_is_read(tmp_path, said):
    """A line that says UTC agrees with the column: the naive stamps are read as UTC, 10:00 → 10:00Z."""
    path = tmp_path / "utc.csv"
    path.write_text(f"# provenance: measured\n# time_zone: {said}\n" + BODY)
    df = read_weather(path)
    assert df.index[0] == pd.Timestamp("2016-04-20 10:00", tz="UTC") and len(df) == 3


MEANS = "# time_label: end\n# averaging_interval: 10min\n"


@pytest.mark.parametrize(
    ("lines", "key", "meant"),
    [
        ("# provenence: measured\n" + MEANS, "provenence", "provenance"),
        ("# provenance: measured\n# time_lable: end\n# averaging_interval: 10min\n", "time_lable", "time_label"),
        (
            "# provenance: measured\n# time_label: end\n# averaging interval: 10min\n",
            "averaging interval",
            "averaging_interval",
        ),
        ("# provenance: measured\n" + MEANS + "# timezone: UTC\n", "timezone", "time_zone"),
        ("# provenance: measured\n" + MEANS + "# time label: start\n", "time label", "time_label"),
        ("# provenance: measured\n# split-model: boland\n", "split-model", "split_model"),
    ],
)
def test_a_misspelt_metadata_key_is_refused_naming_the_key_it_resembles(tmp_path, lines, key, meant):
    """A misspelt key was read as a free key and ignored: the reader's default took its place unsaid
    (``# split-model: boland`` read with the default split, ``# time label: start`` beside
    ``# time_label: end`` ignored), or an error blamed another line (``# time_lable: end`` read as
    instants with a 10-min interval). Refused now, as the observations reader refuses them, naming
    the file, the key and the known key it resembles."""
    path = tmp_path / "w.csv"
    path.write_text(lines + BODY)
    with pytest.raises(InputError, match="resembles") as e:
        read_weather(path)
    said = str(e.value)
    assert "w.csv" in said and repr(key) in said and repr(meant) in said and e.value.column == key


def test_free_metadata_keys_are_still_read(tmp_path):
    """Keys unlike any known one (the bundled file's, those lightfit writes) stay free: the file reads,
    its stamps the 10-min means ending at 10:00, 10:10, 10:20 UTC that it says."""
    free = "# title: plot 3\n# site: Selhausen\n# source: logger\n# note: x\n# qc: []\n# columns: all\n"
    path = tmp_path / "free.csv"
    path.write_text("# provenance: reconstructed\n" + MEANS + free + "# sun_site: Selhausen\n" + BODY)
    df = read_weather(path)
    assert df.attrs["provenance"] == "reconstructed" and df.attrs["metadata"]["site"] == "Selhausen"
    assert df.attrs["timestamps"].label == "end" and df.attrs["timestamps"].interval == pd.Timedelta("10min")
    assert list(df.index) == list(pd.date_range("2016-04-20 10:00", periods=3, freq="10min", tz="UTC"))


def test_write_lightfit_csv_refuses_a_key_its_reader_would_refuse(tmp_path):
    """What write_lightfit_csv writes, read_lightfit_csv reads: a misspelt key in ``metadata`` is
    refused at the writing (naming it and the key it resembles), not at the next read."""
    df = load("2016-04-20").iloc[:3]
    with pytest.raises(InputError, match="'split-model' resembles 'split_model'"):
        write_lightfit_csv(df, tmp_path / "w.csv", {"provenance": "reconstructed", "split-model": "boland"})
    assert not (tmp_path / "w.csv").exists()


def test_the_bundled_lightfit_csv_files_still_read():
    """Their free keys (title, site, generator, anchor, assumptions, clear_sky_scale, columns) resemble
    no key the reader knows."""
    files = [p for p in sorted((DATA_DIR / "weather").iterdir()) if sniff_format(p) == "lightfit"]
    assert files
    for path in files:
        assert read_weather(path).attrs["provenance"] == "reconstructed"


def test_what_lightfit_writes_reads_back_with_its_metadata(tmp_path):
    """``weather show --csv`` (source, qc, split_model, columns, sun_site) and the main job's
    forcing.csv text (source, note) read back, keeping what they state: the 10-min means stamped at
    their start asked for, the boland split, the provenance."""
    out = tmp_path / "day.csv"
    args = ["weather", "show", "selhausen-cplantbox-day", "--date", "2016-04-27", "--time-label", "start"]
    r = CliRunner().invoke(app, [*args, "--split", "boland", "--csv", str(out)])
    assert r.exit_code == 0, r.output
    back = read_weather(out)
    assert back.attrs["split_model"] == "boland" and back.attrs["timestamps"].label == "start"
    assert back.attrs["timestamps"].interval == pd.Timedelta("10min")
    assert {"source", "qc", "columns"} <= set(back.attrs["metadata"])
    forcing = tmp_path / "forcing.csv"
    meta = {"provenance": back.attrs["provenance"], "source": str(out), "note": "144 steps, 10 min"}
    forcing.write_text(lightfit_csv_text(back, meta))
    again = read_weather(forcing)
    assert again.attrs["metadata"]["note"] == "144 steps, 10 min" and len(again) == len(back)
    assert again.attrs["provenance"] == back.attrs["provenance"]


def _local_series(tz):
    index = pd.date_range("2016-04-20 12:00", periods=3, freq="10min", tz=tz)
    values = {"ghi_w_m2": [500.0, 510, 520], "tair_c": 15.0, "rh": 0.6, "pair_kpa": 100.0, "co2_ppm": 400.0}
    return pd.DataFrame(values, index=index)


def test_write_lightfit_csv_writes_a_local_series_in_utc(tmp_path):
    """A series indexed in local time was written with its local clock marked Z: 12:00 CEST read
    back as 12:00 UTC, 2 h late. Written in UTC now: 12:00 CEST (UTC+2 on 20 April) is 10:00Z."""
    path = write_lightfit_csv(_local_series("Europe/Berlin"), tmp_path / "w.csv", {"provenance": "measured"})
    assert "\n2016-04-20T10:00:00Z," in path.read_text()
    back = read_weather(path)
    assert back.index[0] == pd.Timestamp("2016-04-20 10:00", tz="UTC")


def test_write_lightfit_csv_refuses_a_series_without_a_zone_or_a_local_time_zone_line(tmp_path):
    """A naive index was written as if UTC; a ``time_zone`` other than UTC in ``metadata`` gave a
    file its reader refuses. Both refused at the writing, nothing written."""
    with pytest.raises(InputError, match="without a time zone") as e:
        write_lightfit_csv(_local_series(None), tmp_path / "w.csv", {"provenance": "measured"})
    assert e.value.parameter == "df"
    meta = {"provenance": "measured", "time_zone": "Europe/Berlin"}
    with pytest.raises(InputError, match="whose times are UTC"):
        write_lightfit_csv(_local_series("UTC"), tmp_path / "w.csv", meta)
    assert not (tmp_path / "w.csv").exists()
