"""The metadata lines (``# key: value``) of lightfit's own weather CSV (reviews)."""

from __future__ import annotations

import pandas as pd
import pytest

from lightfit.errors import InputError
from lightfit.weather import read_weather

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
