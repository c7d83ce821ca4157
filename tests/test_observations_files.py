"""Observation files: metadata keys and what write_observations writes (reviews)."""

from __future__ import annotations

import pandas as pd
import pytest

from lightfit.errors import InputError
from lightfit.inference.observations import read_observations, write_observations

BODY = "time,canopy_an_umol_m2_s,canopy_an_sd_umol_m2_s\n2016-04-20T10:00:00Z,2.5,0.5\n"


@pytest.mark.parametrize(
    ("key", "value", "meant"),
    [
        ("an_per", "leaf", "canopy_an_per"),
        ("timezone", "UTC", "time_zone"),
        ("Time_Label", "end", "time_label"),
        ("canopy-an-per", "leaf", "canopy_an_per"),
    ],
)
def test_a_misspelt_metadata_key_is_refused_naming_the_key_it_resembles(tmp_path, key, value, meant):
    """`# an_per: leaf` for `# canopy_an_per: leaf` was read as a free key and ignored: the file's
    canopy An then counted per ground area, LAI × off, unsaid. Refused now, naming the file, the key
    and the known key it resembles; free keys unlike any known one are still read (and ignored)."""
    path = tmp_path / "obs.csv"
    path.write_text(f"# provenance: measured\n# {key}: {value}\n" + BODY)
    with pytest.raises(InputError) as e:
        read_observations(path)
    said = str(e.value)
    assert "obs.csv" in said and repr(key) in said and repr(meant) in said and e.value.column == key
    free = tmp_path / "free.csv"
    # notes that only resemble a known key, their values none it takes, stay free (a second reading
    # of the check: "# canopy: winter wheat" was refused as resembling canopy_an_per)
    notes = "# canopy: winter wheat\n# provenance_note: chamber 3's logs\n# time_zone_note: logger kept CET\n"
    free.write_text("# provenance: measured\n# site: Jülich\n# title: chamber 3\n# source: logger\n" + notes + BODY)
    obs = read_observations(free)
    assert obs.attrs["canopy_an_per"] == "ground" and obs.attrs["metadata"]["site"] == "Jülich"


def test_write_observations_refuses_a_key_its_reader_would_refuse(tmp_path):
    """What write_observations writes, read_observations reads: a misspelt key in ``metadata`` is
    refused at the writing, not at the next read."""
    df = pd.DataFrame(
        {"canopy_an_umol_m2_s": [2.5], "canopy_an_sd_umol_m2_s": [0.5]},
        index=pd.DatetimeIndex(["2016-04-20T10:00:00Z"]),
    )
    with pytest.raises(InputError, match="'an_per' resembles 'canopy_an_per'"):
        write_observations(df, tmp_path / "o.csv", {"provenance": "synthetic", "an_per": "leaf"})
    assert not (tmp_path / "o.csv").exists()


def test_write_observations_without_an_sd_column_names_it(tmp_path):
    """The file format pairs every value column with its SD column (the reader refuses one alone);
    a table with canopy An but no SD column raised a bare KeyError listing both columns. Refused now
    naming the SD column; a value without an SD in a present column is refused as the reader would."""
    t = pd.DatetimeIndex(["2016-04-20T10:00:00Z", "2016-04-20T10:30:00Z"])
    df = pd.DataFrame({"canopy_an_umol_m2_s": [2.5, 3.0]}, index=t)
    with pytest.raises(InputError, match="no SD column canopy_an_sd_umol_m2_s") as e:
        write_observations(df, tmp_path / "o.csv", {"provenance": "synthetic"})
    assert e.value.column == "canopy_an_sd_umol_m2_s"
    df["canopy_an_sd_umol_m2_s"] = [0.5, float("nan")]
    with pytest.raises(InputError, match="canopy_an_sd_umol_m2_s"):
        write_observations(df, tmp_path / "o.csv", {"provenance": "synthetic"})
    assert not (tmp_path / "o.csv").exists()
    df["canopy_an_sd_umol_m2_s"] = [0.5, 0.25]
    back = read_observations(write_observations(df, tmp_path / "o.csv", {"provenance": "synthetic"}))
    assert back["canopy_an_sd_umol_m2_s"].tolist() == [0.5, 0.25]


def test_write_observations_without_time_zone_names_the_index(tmp_path):
    """The index must be tz-aware times (the file is written in UTC); a naive DatetimeIndex raised
    pandas' TypeError and a RangeIndex an AttributeError. Refused naming the index and the remedy."""
    an = {"canopy_an_umol_m2_s": [2.5], "canopy_an_sd_umol_m2_s": [0.5]}
    for index, says in (
        (pd.DatetimeIndex(["2016-04-20 10:00"]), "DatetimeIndex without a time zone"),
        (pd.RangeIndex(1), "RangeIndex"),
    ):
        with pytest.raises(InputError, match=says) as e:
            write_observations(pd.DataFrame(an, index=index), tmp_path / "o.csv", {"provenance": "measured"})
        assert e.value.column == "df" and "tz_localize" in str(e.value)
    assert not (tmp_path / "o.csv").exists()
    local = pd.DataFrame(an, index=pd.DatetimeIndex(["2016-04-20 12:00"]).tz_localize("Europe/Berlin"))
    back = read_observations(write_observations(local, tmp_path / "o.csv", {"provenance": "measured"}))
    assert back.index[0] == pd.Timestamp("2016-04-20 10:00", tz="UTC")  # CEST is UTC+2
