"""The weather files bundled in ``data/weather`` (provenance in ``data/README.md``), and the one
resolver of a weather *source* that every command uses: a bundled name or a file path
(:func:`source_path`, :func:`read_source`)."""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from lightfit.errors import InputError
from lightfit.weather.readers import read_weather, sniff_format
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
        raise InputError(f"no bundled weather named {name!r}", parameter="name", expected=" or ".join(BUNDLED))
    path = DATA_DIR / "weather" / BUNDLED[name][0]
    if not path.exists():
        raise InputError(
            "bundled file is missing from this installation",
            file=path,
            expected="a source checkout of lightfit (data/ is not part of the wheel)",
        )
    return path


def source_path(source: str | Path) -> Path:
    """A weather source as a file: a bundled name (:data:`BUNDLED`) or an existing file path.

    The one place that decides what ``--weather`` / ``weather show SOURCE`` means, so that every
    command accepts the same sources.
    """
    if str(source) in BUNDLED:
        return bundled_path(str(source))
    path = Path(source)
    if not path.is_file():
        raise InputError(
            "a folder, not a file" if path.is_dir() else "no such weather file or bundled name",
            file=path,
            expected=f"a weather file or one of the bundled names {', '.join(BUNDLED)}",
        )
    return path


def source_setting(source: str | Path) -> str:
    """A weather source as a run records it: a bundled name as given, a file by its absolute path (a
    relative one names another file, or none, from another folder), as
    :func:`~lightfit.plant.growth.parameter_file_setting` records a plant file."""
    return str(source) if str(source) in BUNDLED else str(source_path(source).resolve())


def is_undated(source: str | Path, format: str = "auto") -> bool:
    """True when the source's timestamps carry no date (a CPlantBox day file): it needs one from the
    caller. ``format``: the file's format where the caller states it (``"auto"``: sniffed)."""
    if format != "auto":
        return format == "cplantbox"
    return sniff_format(source_path(source)) == "cplantbox"


def require_date(source: str | Path, date, format: str = "auto") -> None:
    """An undated source (CPlantBox day file) needs a date from the caller; lightfit never invents one."""
    if date is None and is_undated(source, format):
        raise InputError(
            "the file has no date (a CPlantBox day file) and none was given",
            file=source_path(source),
            parameter="date",
            expected="the day it was measured on, YYYY-MM-DD",
        )


def _bundled_name(path: Path) -> str | None:
    """The bundled name of ``path`` when it is one of the bundled files (by name or by path)."""
    for name, (file, _, _) in BUNDLED.items():
        if (DATA_DIR / "weather" / file).resolve() == path.resolve():
            return name
    return None


def read_source(source: str | Path, *, date: str | None = None, **kwargs) -> pd.DataFrame:
    """Read a weather source (bundled name or file; :func:`source_path`) into the contract, without solar columns.

    ``date`` places an undated file (CPlantBox day) on a calendar day; for dated files it is not
    passed on (a run's window selects the day; ``lightfit weather show`` refuses it). A bundled
    file, by name or by path, keeps its documented provenance (:data:`BUNDLED`, data/README.md);
    a ``provenance`` that contradicts it is refused. ``kwargs`` go to
    :func:`~lightfit.weather.read_weather`.
    """
    path = source_path(source)
    name = _bundled_name(path)
    bundled_date = BUNDLED[name][1] if name else None
    fmt = kwargs.get("format", "auto")
    fmt = sniff_format(path) if fmt == "auto" else fmt
    if fmt != "cplantbox":
        date = bundled_date = None
    if name and fmt != "lightfit":  # a lightfit CSV states its own provenance
        documented = BUNDLED[name][2]
        if kwargs.get("provenance") not in (None, documented):
            raise InputError(
                f"provenance={kwargs['provenance']!r} contradicts the bundled file's documented {documented!r}",
                file=path,
                parameter="provenance",
                expected=f"no provenance or {documented!r} (data/README.md)",
            )
        kwargs["provenance"] = documented
    return read_weather(path, date=date or bundled_date, **kwargs)


def load(name: str = "2016-04-20", *, date: str | None = None, solar: bool = True) -> pd.DataFrame:
    """Load a bundled series by name, with solar columns unless ``solar=False``.

    The real CPlantBox day is undated: pass ``date`` to place it on a calendar day (it sets
    the sun angles); lightfit never invents one.
    """
    bundled_path(name)  # only bundled names here
    df = read_source(name, date=date)
    return add_solar(df) if solar and "sun_elevation_deg" not in df.columns else df
