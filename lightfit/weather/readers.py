"""Readers: TERENO data-portal exports, CPlantBox's one-day file, lightfit's own CSV.

Each reader returns a contract series (see :mod:`lightfit.weather.series`) with
``attrs``: ``source`` (path), ``format``, ``provenance`` (``"measured"``,
``"reconstructed"`` or ``"synthetic"``), ``timezone_assumed``, ``columns_used`` (contract
column → source column and unit), ``unused_columns`` and ``qc`` (repairs).

Timezones. TERENO stations log in UTC+1 without daylight saving (CET); that is the
default ``tz`` of :func:`read_tereno`. CPlantBox's undated day file is in local civil time
(its PAR is symmetric about 13:45, i.e. solar noon at Selhausen in CEST), so its default is
``Europe/Berlin``. Everything is converted to UTC.

Timestamps of means. Both formats hold interval means stamped at the interval's end, the
loggers' convention (``time_label="end"`` to change; :mod:`lightfit.weather.timestamps`): the
CPlantBox day's PAR is symmetric about 13:45, five minutes after the centre of its 10-minute
means, and solar noon at Selhausen falls at 13:30–13:40 CEST. The series records it in
``attrs["timestamps"]``, and the sun is taken at each interval's centre.
"""

from __future__ import annotations

import datetime as dt
import io
import re
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from lightfit.errors import InputError, parse_date
from lightfit.weather import timestamps, units
from lightfit.weather.series import DEFAULT_MAX_GAP, check_and_repair, parse_numeric
from lightfit.weather.timestamps import Timestamps

TERENO_TZ = "Etc/GMT-1"  # POSIX sign convention: Etc/GMT-1 is UTC+1
CPLANTBOX_TZ = "Europe/Berlin"


def _norm_unit(u: str) -> str:
    return re.sub(r"[\s*·^]", "", u.strip().lower().replace("µ", "u").replace("°", "deg"))


# quantity -> (column-name pattern, preferred exact name, {normalised unit: converter tag})
TERENO_QUANTITIES: dict[str, tuple[str, str, dict[str, str]]] = {
    "ghi_w_m2": (r"^RadiationGlobal", "RadiationGlobal_Avg10min", {"wm-2": "same", "w/m2": "same"}),
    "par_umol_m2_s": (
        r"^RadiationPhotosyntheticActive",
        "RadiationPhotosyntheticActive_2m_Avg10min",
        {"umolm-2s-1": "same", "umol/m2/s": "same", "umol/(m2s)": "same"},
    ),
    "tair_c": (r"^AirTemperature", "AirTemperature_2m_Avg10min_Sensor1", {"degc": "same", "c": "same", "k": "kelvin"}),
    "humidity": (r"^AirHumidity", "AirHumidity_2m_Avg10min", {"gm-3": "absolute", "g/m3": "absolute", "%": "percent"}),
    "pair_kpa": (
        r"^AirPressure",
        "AirPressure_1m_Avg10min",
        {"mbar": "mbar", "hpa": "mbar", "kpa": "same", "pa": "pa"},
    ),
    "co2_ppm": (
        r"^AirConcentration_?CO2",
        "AirConcentration_CO2_2m_Avg30min",
        {"mmolm-3": "mmol_m3", "mmol/m3": "mmol_m3", "ppm": "same", "umolmol-1": "same", "umol/mol": "same"},
    ),
}
_TIME_NAMES = re.compile(r"^(timestamp|time|date|datetime|date_time|zeitstempel)\b", re.IGNORECASE)
_COL = re.compile(r"^\s*(?P<name>[^\[]+?)\s*(\[(?P<unit>[^\]]*)\])?\s*$")


def _split_header(name: str) -> tuple[str, str | None]:
    m = _COL.match(name)
    return (m.group("name"), m.group("unit")) if m else (name.strip(), None)


def _find_table(text_lines: list[str], file) -> tuple[int, str]:
    """Index of the table's header line and its delimiter, found by content."""
    for i, line in enumerate(text_lines):
        if line.lstrip().startswith("#"):
            continue
        hits = sum(
            bool(re.search(pat, cell.strip().strip('"')))
            for pat, _, _ in TERENO_QUANTITIES.values()
            for cell in re.split(r"[,;\t]", line)
        )
        if hits >= 1:
            delim = max([",", ";", "\t"], key=line.count)
            cells = [c.strip().strip('"') for c in line.split(delim)]
            if any(_TIME_NAMES.match(c) for c in cells):
                return i, delim
    raise InputError(
        "no table header found: no line names a time column and a TERENO quantity such as "
        "'RadiationGlobal_Avg10min [W*m-2]'",
        file=file,
        expected="a TERENO data-portal CSV export (header lines, then a table with a Timestamp column)",
    )


def _parse_times(raw: pd.Series, lines: pd.Series, file, column: str, tz: str) -> pd.DatetimeIndex:
    text = raw.astype("string").str.strip()
    for kwargs in ({"format": "ISO8601"}, {"dayfirst": True, "format": "mixed"}):
        try:
            t = pd.to_datetime(text, **kwargs)
            break
        except (ValueError, TypeError):
            continue
    else:
        t = pd.to_datetime(text, format="ISO8601", errors="coerce")
        i = int(np.flatnonzero(t.isna().to_numpy())[0])
        raise InputError(
            f"cannot parse time {text.iloc[i]!r}",
            file=file,
            row=int(lines.iloc[i]),
            column=column,
            expected="timestamps like 2016-04-20 12:10:00",
        )
    idx = pd.DatetimeIndex(t)
    if idx.tz is None:
        try:
            idx = idx.tz_localize(tz, ambiguous="raise", nonexistent="raise")
        except ValueError as e:  # pandas' AmbiguousTimeError / NonExistentTimeError: a clock change
            raise InputError(
                f"local times that are ambiguous or do not exist in {tz} ({e})",
                file=file,
                column=column,
                expected="times that exist once in that zone: a day without a daylight-saving change, "
                "or times with a UTC offset",
            ) from None
    return idx.tz_convert("UTC")


def read_tereno(
    path: str | Path,
    *,
    tz: str = TERENO_TZ,
    columns: dict[str, str] | None = None,
    max_gap: str | pd.Timedelta = DEFAULT_MAX_GAP,
    provenance: str = "measured",
    time_label: str = "end",
) -> pd.DataFrame:
    """Read a TERENO data-portal CSV export (e.g. station SE_EC_001) into a contract series.

    The table header is found by content (a line with a time column and a TERENO quantity
    such as ``RadiationGlobal_Avg10min [W*m-2]``), not by line count; the delimiter (``,``,
    ``;`` or tab) is detected. Units in brackets are checked and converted: absolute humidity
    (g m⁻³) → relative humidity with air temperature; CO2 (mmol m⁻³) → ppm with air
    temperature and pressure; mbar/hPa → kPa; K → °C.

    Args:
        path: the export file.
        tz: timezone of the timestamps (default UTC+1, the TERENO convention).
        columns: override which source column feeds a quantity, e.g.
            ``{"tair_c": "AirTemperature_2m_Avg10min_Sensor2 [°C]"}``. Keys: ``ghi_w_m2``,
            ``par_umol_m2_s``, ``tair_c``, ``humidity``, ``pair_kpa``, ``co2_ppm``.
        max_gap: longest gap that is interpolated (see :func:`~lightfit.weather.series.check_and_repair`).
        provenance: what the file is; only a real export is ``"measured"``.
        time_label: where the stamp of each mean lies in its interval (``"end"``, ``"start"``,
            ``"center"``); the interval is the radiation columns' (``Avg10min``: 10 min).
    """
    path = Path(path)
    if not path.exists():
        raise InputError("file not found", file=path, expected="a TERENO CSV export")
    timestamps.check_mean_label(time_label)
    text_lines = path.read_text(encoding="utf-8-sig", errors="replace").splitlines()
    hdr, delim = _find_table(text_lines, path)
    table = pd.read_csv(
        io.StringIO("\n".join(text_lines[hdr:])), sep=delim, dtype=str, keep_default_na=False, skip_blank_lines=False
    )
    table.columns = [c.strip().strip('"') for c in table.columns]
    lines = pd.Series(np.arange(len(table)) + hdr + 2)  # 1-based; header is line hdr+1
    keep = table.apply(lambda r: any(str(v).strip() for v in r), axis=1).to_numpy()
    table, lines = table[keep].reset_index(drop=True), lines[keep].reset_index(drop=True)

    time_col = next(c for c in table.columns if _TIME_NAMES.match(c))
    times = _parse_times(table[time_col], lines, path, time_col, tz)
    qc: list[dict] = []
    used: dict[str, str] = {}
    raw: dict[str, pd.Series] = {}
    conv: dict[str, str] = {}
    columns = dict(columns or {})
    unknown = set(columns) - set(TERENO_QUANTITIES)
    if unknown:
        raise InputError(
            f"unknown quantity key(s) {sorted(unknown)} in columns=", expected=", ".join(TERENO_QUANTITIES)
        )
    for qty, (pattern, preferred, unit_map) in TERENO_QUANTITIES.items():
        if qty in columns:
            if columns[qty] not in table.columns:
                raise InputError(
                    f"column {columns[qty]!r} requested for {qty} is not in the table",
                    file=path,
                    expected=f"one of {list(table.columns)}",
                )
            src = columns[qty]
        else:
            cands = [
                c
                for c in table.columns
                if re.search(pattern, _split_header(c)[0]) and not re.search(r"(qual|flag)", c, re.IGNORECASE)
            ]
            if not cands:
                continue
            src = next((c for c in cands if _split_header(c)[0] == preferred), cands[0])
        name, unit = _split_header(src)
        tag = unit_map.get(_norm_unit(unit or ""))
        if tag is None:
            raise InputError(
                f"unit [{unit}] not understood for {qty}",
                file=path,
                row=hdr + 1,
                column=src,
                expected="one of " + ", ".join(f"[{u}]" for u in unit_map),
            )
        raw[qty] = parse_numeric(table[src].set_axis(times), lines.set_axis(times), path, src, qc)
        conv[qty], used[qty] = tag, f"{src}"
    if "tair_c" in raw and conv["tair_c"] == "kelvin":
        raw["tair_c"] = raw["tair_c"] - units.T0
    if "pair_kpa" in raw:
        raw["pair_kpa"] = {"mbar": units.kpa_from_mbar, "pa": lambda p: p * 1e-3, "same": lambda p: p}[
            conv["pair_kpa"]
        ](raw["pair_kpa"])
    out = pd.DataFrame(index=times)
    for qty in ("ghi_w_m2", "par_umol_m2_s", "tair_c", "pair_kpa"):
        if qty in raw:
            out[qty] = raw[qty]
    if "humidity" in raw:
        if conv["humidity"] == "absolute":
            if "tair_c" not in out:
                raise InputError(
                    "absolute humidity needs air temperature to convert to relative humidity",
                    file=path,
                    expected="an AirTemperature column",
                )
            out["rh"] = units.relative_humidity_from_absolute(raw["humidity"], out["tair_c"])
        else:
            out["rh"] = raw["humidity"] / 100.0
    if "co2_ppm" in raw:
        if conv["co2_ppm"] == "mmol_m3":
            if not {"tair_c", "pair_kpa"} <= set(out.columns):
                raise InputError(
                    "CO2 in mmol m-3 needs air temperature and pressure to convert to ppm",
                    file=path,
                    expected="AirTemperature and AirPressure columns",
                )
            out["co2_ppm"] = units.co2_ppm_from_mmol_m3(raw["co2_ppm"], out["tair_c"], out["pair_kpa"])
        else:
            out["co2_ppm"] = raw["co2_ppm"]
    # Slower quantities (CO2 at 30 min) arrive as empty cells between their timestamps: each
    # 30-min mean covers the 10-min rows inside its own interval, which lie before an end-stamp
    # and after a start-stamp; rows past the last mean keep it (the interval it would close is
    # not in the file).
    if "co2_ppm" in out and "Avg30min" in used.get("co2_ppm", ""):
        co2 = out["co2_ppm"]
        if time_label == "end":
            held = co2.bfill(limit=2)
            last = co2.last_valid_index()
            if last is not None:  # only the rows past the last mean keep it
                held[held.index > last] = co2[last]
        elif time_label == "start":
            held = co2.ffill(limit=2)
        else:
            held = co2.ffill(limit=1).bfill(limit=1)
        n = int((held.notna() & co2.isna()).sum())
        if n:
            out["co2_ppm"] = held
            qc.append(
                {
                    "kind": "held",
                    "column": "co2_ppm",
                    "count": n,
                    "detail": f"{n} value(s) of the 30-min CO2 series held over the 10-min rows of their "
                    f"own interval (stamps at the {time_label})",
                }
            )
    out.attrs = {
        "source": str(path),
        "format": "tereno",
        "provenance": provenance,
        "timezone_assumed": tz,
        "columns_used": used,
        "unused_columns": [c for c in table.columns if c not in used.values() and c != time_col],
        "qc": qc,
    }
    out = check_and_repair(out, lines.set_axis(times), path, max_gap=max_gap)
    return _with_means(out, time_label, _averaging_interval(used))


def _averaging_interval(used: dict[str, str]) -> pd.Timedelta | None:
    """The radiation columns' averaging interval (``…_Avg10min``), if their names say it."""
    for qty in ("ghi_w_m2", "par_umol_m2_s"):
        m = re.search(r"Avg(\d+)min", used.get(qty, ""))
        if m:
            return pd.Timedelta(minutes=int(m.group(1)))
    return None


def _with_means(df: pd.DataFrame, time_label: str, interval: pd.Timedelta | None = None) -> pd.DataFrame:
    """``df`` (repaired: a regular grid) marked as means over ``interval`` (default its step)."""
    df.attrs["timestamps"] = Timestamps(time_label, df.index[1] - df.index[0] if interval is None else interval)
    return df


def read_cplantbox_day(
    path: str | Path,
    date: str | dt.date,
    *,
    tz: str = CPLANTBOX_TZ,
    max_gap: str | pd.Timedelta = DEFAULT_MAX_GAP,
    provenance: str = "measured",
    time_label: str = "end",
) -> pd.DataFrame:
    """Read CPlantBox's one-day weather file (``climate/Selhausen_weather_data.txt`` format).

    Tab-separated, quoted header ``"time" "PAR" "co2" "RH" "Tair" "Pair" ...`` with time
    HH:MM:SS, PAR in mol m⁻² s⁻¹, co2 in mol mol⁻¹, RH 0–1, Tair °C, Pair kPa. The file has
    no date: ``date`` supplies it. Extra columns (soil water potential ``ps``, ``nm``) are
    listed in ``attrs["unused_columns"]``. Its rows are means over the rows' step stamped at
    ``time_label`` (the module's docstring says why the end).
    """
    path = Path(path)
    if not path.exists():
        raise InputError("file not found", file=path, expected="a CPlantBox weather file")
    timestamps.check_mean_label(time_label)
    day = parse_date(date, "date")
    table = pd.read_csv(path, sep="\t", dtype=str, keep_default_na=False)
    table.columns = [c.strip().strip('"') for c in table.columns]
    need = {"time": None, "PAR": "par_umol_m2_s", "co2": "co2_ppm", "RH": "rh", "Tair": "tair_c", "Pair": "pair_kpa"}
    missing = [c for c in need if c not in table.columns]
    if missing:
        raise InputError(f"missing column(s) {missing}", file=path, row=1, expected=f"columns {list(need)}")
    lines = pd.Series(np.arange(len(table)) + 2)
    clock = table["time"].str.strip().str.strip('"')
    stamps = pd.Series([f"{day.isoformat()} {c}" for c in clock])
    times = _parse_times(stamps, lines, path, "time", tz)
    qc: list[dict] = []
    lt = lines.set_axis(times)
    out = pd.DataFrame(index=times)
    out["par_umol_m2_s"] = parse_numeric(table["PAR"].set_axis(times), lt, path, "PAR", qc) * 1e6
    out["tair_c"] = parse_numeric(table["Tair"].set_axis(times), lt, path, "Tair", qc)
    out["rh"] = parse_numeric(table["RH"].set_axis(times), lt, path, "RH", qc)
    out["pair_kpa"] = parse_numeric(table["Pair"].set_axis(times), lt, path, "Pair", qc)
    out["co2_ppm"] = parse_numeric(table["co2"].set_axis(times), lt, path, "co2", qc) * 1e6
    out.attrs = {
        "source": str(path),
        "format": "cplantbox",
        "provenance": provenance,
        "timezone_assumed": tz,
        "columns_used": {v: k for k, v in need.items() if v},
        "unused_columns": [c for c in table.columns if c not in need],
        "qc": qc,
    }
    return _with_means(check_and_repair(out, lt, path, max_gap=max_gap), time_label)


PROVENANCES = ("measured", "reconstructed", "synthetic")


def read_csv_with_metadata(path: Path) -> tuple[dict[str, str], int, pd.DataFrame]:
    """A CSV whose leading ``# key: value`` lines are metadata, ``provenance`` required.

    Returns (metadata, number of metadata lines, table of strings). Shared by lightfit's own
    weather files and the observations CSV.
    """
    text = path.read_text(encoding="utf-8").splitlines()
    meta: dict[str, str] = {}
    n_meta = 0
    for line in text:
        if not line.startswith("#"):
            break
        n_meta += 1
        if ":" in line:
            k, v = line[1:].split(":", 1)
            meta[k.strip()] = v.strip()
    if meta.get("provenance") not in PROVENANCES:
        raise InputError(
            f"metadata line '# provenance: ...' is {meta.get('provenance')!r}",
            file=path,
            row=1,
            expected="'measured', 'reconstructed' or 'synthetic'",
        )
    table = pd.read_csv(io.StringIO("\n".join(text[n_meta:])), dtype=str, keep_default_na=False)
    return meta, n_meta, table


def read_lightfit_csv(path: str | Path, *, max_gap: str | pd.Timedelta = DEFAULT_MAX_GAP) -> pd.DataFrame:
    """Read lightfit's own series CSV: ``# key: value`` metadata lines, then contract columns.

    The ``time_utc`` column holds ISO 8601 UTC timestamps. The ``provenance`` metadata key is
    required: a file must say whether it is measured, reconstructed or synthetic. ``time_label``
    and ``averaging_interval`` say what the stamps mean (:mod:`lightfit.weather.timestamps`;
    without them, instants).
    """
    path = Path(path)
    if not path.exists():
        raise InputError("file not found", file=path, expected="a lightfit weather CSV")
    meta, n_meta, table = read_csv_with_metadata(path)
    if "time_utc" not in table.columns:
        raise InputError("no time_utc column", file=path, row=n_meta + 1, expected="a header starting with time_utc")
    lines = pd.Series(np.arange(len(table)) + n_meta + 2)
    times = _parse_times(table["time_utc"], lines, path, "time_utc", "UTC")
    lt = lines.set_axis(times)
    qc: list[dict] = []
    out = pd.DataFrame(index=times)
    for c in table.columns:
        if c != "time_utc":
            out[c] = parse_numeric(table[c].set_axis(times), lt, path, c, qc)
    out.attrs = {
        "source": str(path),
        "format": "lightfit",
        "provenance": meta["provenance"],
        "timezone_assumed": "UTC",
        "timestamps": Timestamps.from_metadata(meta, path),
        "metadata": meta,
        "columns_used": {c: c for c in out.columns},
        "unused_columns": [],
        "qc": qc,
    }
    return check_and_repair(out, lt, path, max_gap=max_gap)


def write_lightfit_csv(df: pd.DataFrame, path: str | Path, metadata: dict[str, str]) -> Path:
    """Write a contract series with ``# key: value`` metadata (must include ``provenance``).

    The series' timestamps' meaning (``attrs["timestamps"]``) is written with it unless
    ``metadata`` states it.
    """
    if metadata.get("provenance") not in ("measured", "reconstructed", "synthetic"):
        raise InputError(
            "metadata must state provenance", column="provenance", expected="'measured', 'reconstructed' or 'synthetic'"
        )
    if "time_label" not in metadata:
        metadata = metadata | timestamps.of(df).metadata()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    head = "".join(f"# {k}: {v}\n" for k, v in metadata.items())
    body = df.rename_axis("time_utc").reset_index()
    body["time_utc"] = body["time_utc"].dt.strftime("%Y-%m-%dT%H:%M:%SZ")
    path.write_text(head + body.to_csv(index=False, float_format="%.8g", lineterminator="\n"), encoding="utf-8")
    return path


def sniff_format(path: str | Path) -> str:
    """``"tereno"``, ``"cplantbox"`` or ``"lightfit"`` from the file's first lines."""
    path = Path(path)
    if not path.exists():
        raise InputError("file not found", file=path, expected="a weather file")
    head = path.read_text(encoding="utf-8-sig", errors="replace")[:20000]
    if head.startswith("#") and "time_utc" in head:
        return "lightfit"
    if head.startswith('"time"\t"PAR"') or head.startswith("time\tPAR"):
        return "cplantbox"
    if any(re.search(pat.lstrip("^"), head) for pat, _, _ in TERENO_QUANTITIES.values()):
        return "tereno"
    raise InputError(
        "unrecognised weather file format",
        file=path,
        expected="a TERENO CSV export, a CPlantBox weather file or a lightfit CSV",
    )


def read_weather(
    path: str | Path,
    *,
    format: str = "auto",
    date: str | dt.date | None = None,
    tz: str | None = None,
    **kwargs: Any,
) -> pd.DataFrame:
    """Read any supported weather file; ``format`` ``"auto"`` sniffs it.

    ``date`` is required for CPlantBox day files; ``tz`` overrides the format's default.
    """
    fmt = sniff_format(path) if format == "auto" else format
    if fmt == "tereno":
        return read_tereno(path, **({"tz": tz} if tz else {}), **kwargs)
    if fmt == "cplantbox":
        if date is None:
            raise InputError(
                "a CPlantBox weather file has no date", file=path, column="date", expected="date=YYYY-MM-DD"
            )
        return read_cplantbox_day(path, date, **({"tz": tz} if tz else {}), **kwargs)
    if fmt == "lightfit":
        if "time_label" in kwargs:
            raise InputError(
                "a lightfit CSV states what its stamps mean in its own '# time_label:' line",
                file=path,
                column="time_label",
                expected="no time_label for a lightfit CSV (edit its metadata instead)",
            )
        return read_lightfit_csv(path, **kwargs)
    raise InputError(f"unknown weather format {fmt!r}", column="format", expected="auto, tereno, cplantbox or lightfit")
