"""The weather files bundled in ``data/weather`` (provenance in ``data/README.md``)."""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from lightfit.errors import InputError
from lightfit.weather.readers import read_weather
from lightfit.weather.solar import add_solar

DATA_DIR = Path(__file__).resolve().parents[2] / "data"

#: name -> (file under data/weather, date for undated files, provenance)
BUNDLED: dict[str, tuple[str, str | None, str]] = {
    "2016-04-20": ("selhausen_2016-04-20_reconstructed.csv", None, "reconstructed"),
    "selhausen-cplantbox-day": ("selhausen_cplantbox_day.txt", None, "measured"),
}


def bundled_path(name: str) -> Path:
    """Path of a bundled weather file by name (see :data:`BUNDLED`)."""
    if name not in BUNDLED:
        raise InputError(f"no bundled weather named {name!r}", column="name", expected=" or ".join(BUNDLED))
    path = DATA_DIR / "weather" / BUNDLED[name][0]
    if not path.exists():
        raise InputError(
            "bundled file is missing from this installation",
            file=path,
            expected="a source checkout of lightfit (data/ is not part of the wheel)",
        )
    return path


def load(name: str = "2016-04-20", *, date: str | None = None, solar: bool = True) -> pd.DataFrame:
    """Load a bundled series by name, with solar columns unless ``solar=False``.

    The real CPlantBox day is undated: pass ``date`` to place it on a calendar day (it sets
    the sun angles); lightfit never invents one.
    """
    path = bundled_path(name)
    df = read_weather(path, date=date or BUNDLED[name][1])
    return add_solar(df) if solar and "sun_elevation_deg" not in df.columns else df
