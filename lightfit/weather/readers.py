"""Readers: TERENO data-portal exports, CPlantBox's one-day file, lightfit's own CSV.

Each reader returns a contract series (see :mod:`lightfit.weather.series`) with
``attrs``: ``source`` (path), ``format``, ``provenance`` (``"measured"``,
``"reconstructed"``, ``"synthetic"``, or ``"unstated"`` where neither the file nor the caller
says), ``timezone_assumed``, ``columns_used`` (contract column → source column and unit),
``unused_columns`` and ``qc`` (repairs).

Provenance. Only the file or the caller can say what a series is: a TERENO export's header
block may state it (``provenance: synthetic``, or the words "synthetic" / "reconstructed", as
the bundled fixture's does), a lightfit CSV states it in its ``# provenance:`` line, and the
caller may declare it (``provenance=``, ``--provenance``) where the file says nothing; a
declaration that contradicts the file is refused. Otherwise the series is ``"unstated"``, never
``"measured"`` by default.

Timezones. TERENO stations log in UTC+1 without daylight saving (CET); that is the
default ``tz`` of :func:`read_tereno` unless the export's header states its zone
(``Time zone: UTC+1``), which is then used (a ``tz`` that disagrees with it is refused).
CPlantBox's undated day file is in local civil time (its PAR is symmetric about 13:45, i.e.
solar noon at Selhausen in CEST), so its default is ``Europe/Berlin``. Everything is converted
to UTC. Timestamps must be ISO 8601 (``2016-04-20 12:10:00``, the TERENO export's own format,
or with ``T`` and a UTC offset): day/month dates such as ``04/05/2016`` are refused, since
which is the day cannot be told.

Timestamps of means. Both formats hold interval means stamped at the interval's end, the
loggers' convention (``time_label="end"`` to change; :mod:`lightfit.weather.timestamps`): the
CPlantBox day's PAR is symmetric about 13:45, five minutes after the centre of its 10-minute
means, and solar noon at Selhausen falls at 13:30–13:40 CEST. The series records it in
``attrs["timestamps"]``, and the sun is taken at each interval's centre.
"""

from __future__ import annotations

import csv
import datetime as dt
import difflib
import re
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from lightfit.errors import InputError, listed, parse_date
from lightfit.files import NETCDF_MAGIC, replace_text
from lightfit.weather import timestamps, units
from lightfit.weather.series import COLUMNS, DEFAULT_MAX_GAP, check_and_repair, parse_numeric, record_sorted
from lightfit.weather.site import check_timezone, localize, offset_label, zone_label
from lightfit.weather.solar import SPLIT_MODELS, check_split_model
from lightfit.weather.timestamps import Timestamps

TERENO_TZ = "Etc/GMT-1"  # POSIX sign convention: Etc/GMT-1 is UTC+1
CPLANTBOX_TZ = "Europe/Berlin"
#: What a file may say it is (an observations file's ``# provenance:`` line, a TERENO header); a lightfit
#: weather CSV may also say ``unstated`` (:data:`WEATHER_PROVENANCES`).
PROVENANCES = ("measured", "reconstructed", "synthetic")
#: difflib similarity from which a free metadata key reads as a misspelling of a known one
#: (:func:`check_metadata_keys`): ``an_per`` 0.63 against ``canopy_an_per``, ``timezone`` 0.94
#: against ``time_zone``, where ``title`` 0.53, ``station`` 0.50, ``source`` 0.38 are free.
MISSPELT_KEY_RATIO = 0.6


def _norm_unit(u: str) -> str:
    return re.sub(r"[\s*·^]", "", u.strip().lower().replace("µ", "u").replace("°", "deg"))


# quantity -> (column-name pattern, preferred exact name, {normalised unit: converter tag})
TERENO_QUANTITIES: dict[str, tuple[str, str, dict[str, str]]] = {
    "ghi_w_m2": (r"^RadiationGlobal", "RadiationGlobal_Avg10min", {"wm-2": "same", "w/m2": "same", "kwm-2": "kilo"}),
    "par_umol_m2_s": (
        r"^RadiationPhotosyntheticActive",
        "RadiationPhotosyntheticActive_2m_Avg10min",
        {"umolm-2s-1": "same", "umol/m2/s": "same", "umol/(m2s)": "same"},
    ),
    # TERENO's naming of its other radiation columns; no export seen here carries diffuse radiation.
    "diffuse_w_m2": (
        r"^RadiationDiffuse",
        "RadiationDiffuse_Avg10min",
        {"wm-2": "same", "w/m2": "same", "kwm-2": "kilo"},
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
#: How a TERENO export names each contract column (missing-column errors): the preferred header
#: with a unit it may carry.
_TERENO_UNIT_EXAMPLES = {
    "ghi_w_m2": "W*m-2",
    "par_umol_m2_s": "umol*m-2*s-1",
    "diffuse_w_m2": "W*m-2",
    "tair_c": "°C",
    "humidity": "% or g*m-3",
    "pair_kpa": "hPa",
    "co2_ppm": "ppm or mmol*m-3",
}


def _contract(qty: str) -> str:
    """The contract column a TERENO quantity is read into: ``rh`` for ``humidity`` (relative or absolute)."""
    return "rh" if qty == "humidity" else qty


TERENO_NAMES = {
    _contract(qty): f"a header like {preferred} [{_TERENO_UNIT_EXAMPLES[qty]}]"
    for qty, (_, preferred, _) in TERENO_QUANTITIES.items()
}
_TIME_NAMES = re.compile(r"^(timestamp|time|date|datetime|date_time|zeitstempel)\b", re.IGNORECASE)
_COL = re.compile(r"^\s*(?P<name>[^\[]+?)\s*(\[(?P<unit>[^\]]*)\])?\s*$")


def _is_flag_column(name: str) -> bool:
    """A quality-flag column: its name says quality or flag, or ends or begins with a separate ``QF``
    (``RadiationGlobal_Avg10min_QF``, ``QF_RadiationGlobal_Avg10min``), which :data:`_FLAG_COL` reads.
    The QF suffix was matched there but not here, so that such a column's ``bad`` flags were ignored
    (the column listed as not used) and the values it flagged read as good."""
    return bool(
        re.search(r"(qual|flag)", name, re.IGNORECASE) or re.search(r"(^|[\s_])qfs?$|^qfs?[\s_]", name, re.IGNORECASE)
    )


def _split_header(name: str) -> tuple[str, str | None]:
    m = _COL.match(name)
    return (m.group("name"), m.group("unit")) if m else (name.strip(), None)


#: How alike (difflib's ratio) an unread column's first word must be to a quantity's TERENO word to
#: be taken for a misspelling of it (AirTemperatur: 0.96, AirPresure: 0.95; SoilTemperature against
#: AirTemperature: 0.83, RadiationNet against RadiationDiffuse: 0.71).
NEAR_MISS_RATIO = 0.92


def _check_near_misses(table: pd.DataFrame, used: dict[str, str], time_col: str, path, hdr: int) -> None:
    """Refuse a column whose name is a near miss of a quantity the table lacks (``RadiationPhotosynth\
    ticActive``): read as unknown, it would be replaced by an estimate (PAR from global radiation)
    or fail later naming the quantity, not the column."""
    import difflib

    for c in table.columns:
        if c == time_col or c in used.values() or _is_flag_column(c):
            continue
        name = _split_header(c)[0]
        for qty, (pattern, preferred, _) in TERENO_QUANTITIES.items():
            if qty in used:
                continue
            # the quantity's word (height, interval and sensor follow; AirConcentration_H2O is not a miss)
            a, b = name.split("_")[0].lower(), preferred.split("_")[0].lower()
            if a != b and difflib.SequenceMatcher(None, a, b).ratio() >= NEAR_MISS_RATIO:
                raise InputError(
                    f"column {c!r} looks like a misspelt {preferred.split('_')[0]} ({qty}), which lightfit reads "
                    f"from names starting {pattern.lstrip('^')!r}",
                    file=path,
                    row=hdr + 1,
                    column=c,
                    expected=f"the TERENO name (e.g. {preferred}): rename the column in the file, or in Python "
                    f"read_tereno(..., columns={{{qty!r}: {c!r}}})",
                )


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


#: Signatures of binary files a user may give for a CSV, and what to call them.
_BINARY = {
    b"PK\x03\x04": "a ZIP archive (e.g. an Excel .xlsx workbook: export the sheet as CSV)",
    b"\xd0\xcf\x11\xe0": "an Office document (e.g. an Excel .xls workbook: export the sheet as CSV)",
    b"\x89PNG": "a PNG image",
    b"\xff\xd8\xff": "a JPEG image",
    b"%PDF": "a PDF document",
    # files.NETCDF_MAGIC: netCDF-4 is HDF5
    **{magic: "an HDF5 / netCDF file" for magic in NETCDF_MAGIC},
}


def _read_text(path: str | Path, expected: str, *, strict: bool = True) -> str:
    """The text of a user's file (weather, observations), or :class:`InputError` saying ``expected``
    where there is none: no such file, a folder, a file without text (an export that failed; each
    format's own check said only what its first line lacked, and the CPlantBox reader raised
    IndexError). A file that is not UTF-8 is refused naming the line of its first foreign byte;
    ``strict=False`` reads such bytes as U+FFFD instead (to tell formats apart)."""
    path = Path(path)
    if not path.exists():
        raise InputError("file not found", file=path, expected=expected)
    if path.is_dir():
        raise InputError("a folder, not a file", file=path, expected=expected)
    data = path.read_bytes()
    try:
        text = data.decode("utf-8-sig", errors="strict" if strict else "replace")
    except UnicodeDecodeError as e:
        kind = next((k for magic, k in _BINARY.items() if data.startswith(magic)), None)
        if kind:  # "save it as UTF-8" misleads for a spreadsheet or an image given as a CSV
            raise InputError(f"the file is {kind}, not text", file=path, expected=expected) from None
        line = data[: e.start].count(b"\n") + 1
        other = "UTF-16" if data[:2] in (b"\xff\xfe", b"\xfe\xff") else "another encoding, e.g. Latin-1"
        raise InputError(
            f"byte 0x{data[e.start]:02x} is not UTF-8 text (the file is in {other})",
            file=path,
            row=line,
            expected="a UTF-8 file: save it as UTF-8",
        ) from None
    if not text.strip():
        raise InputError(f"the file is empty ({len(data)} bytes, no text)", file=path, expected=expected)
    return text


_DECIMAL_COMMA = re.compile(r"(?:^|,)(?P<n>-?\d+,\d+)(?=,|$)")


def _decimal_commas(text_lines: list[str], first: int, n_columns: int):
    """The first decimal comma of row ``first`` (a match with group ``n``) when it and the rows after
    it (up to 5) all have their surplus of fields explained by numbers written with a decimal comma
    (every data row of such an export has them); ``None`` for a stray field on one row."""
    rows = [ln for ln in text_lines[first : first + 6] if ln.strip()]
    for ln in rows:
        surplus = len(next(csv.reader([ln]), [])) - n_columns
        if surplus < 1 or len(_DECIMAL_COMMA.findall(ln)) < surplus:
            return None
    return _DECIMAL_COMMA.search(rows[0]) if len(rows) >= min(3, len(text_lines) - first) else None


def _table_rows(
    text_lines: list[str], header: int, delim: str, file, *, short_rows: str = "error"
) -> tuple[pd.DataFrame, pd.Series]:
    """The table whose header is ``text_lines[header]``: its cells (strings) and each row's line
    number in the file (1-based).

    Blank lines (and rows of empty cells) are skipped; the line numbers stay the file's. A row
    with more cells than the header is an error naming its line; so is one with fewer, unless
    ``short_rows="pad"`` (then its missing cells are empty, and its line is in the table's
    ``attrs["short_rows"]``, to be said).
    """
    cols = [c.strip().strip('"') for c in next(csv.reader([text_lines[header]], delimiter=delim))]
    dup = sorted({c for c in cols if cols.count(c) > 1})
    if dup:
        raise InputError(
            f"column(s) {dup} appear more than once in the header",
            file=file,
            row=header + 1,
            expected="one column per name",
        )
    rows, numbers, short = [], [], []
    for i in range(header + 1, len(text_lines)):
        cells = next(csv.reader([text_lines[i]], delimiter=delim), [])
        if not any(c.strip() for c in cells):
            continue
        if len(cells) > len(cols) or (len(cells) < len(cols) and short_rows != "pad"):
            # A decimal comma in a comma-separated file splits every number in two.
            comma = delim == "," and len(cells) > len(cols) and _decimal_commas(text_lines, i, len(cols))
            raise InputError(
                f"{len(cells)} fields, the header (line {header + 1}) has {len(cols)}"
                + (f"; decimal commas? (e.g. '{comma['n']}')" if comma else ""),
                file=file,
                row=i + 1,
                expected=f"one value per column, separated by {delim!r} (a stray or missing separator?)"
                + ("; numbers with a decimal point (export with '.' as decimal separator)" if comma else ""),
            )
        if len(cells) < len(cols):
            short.append(i + 1)
        rows.append(cells + [""] * (len(cols) - len(cells)))
        numbers.append(i + 1)
    table = pd.DataFrame(rows, columns=cols, dtype=str) if rows else pd.DataFrame(columns=cols, dtype=str)
    table.attrs["short_rows"] = tuple(short)
    return table, pd.Series(numbers, dtype=int)


_UTC_OFFSET = re.compile(r"^(?:UTC|GMT)\s*(?:(?P<sign>[+-])\s*(?P<h>\d{1,2})(?::?(?P<m>\d{2}))?)?$", re.IGNORECASE)


#: tzdata zone names that loggers use for a fixed offset (their standard time) all year.
_TWO_MEANINGS = {"WET": 0, "CET": 1, "MET": 1, "EET": 2}


def zone(name: str, column: str = "tz") -> str:
    """An IANA time zone for ``name``: an IANA name as it is, ``UTC±H`` (also ``GMT±H``, ``UTC±HH:00``)
    as ``Etc/GMT∓H`` (whose POSIX sign is the other way round), else :class:`InputError`."""
    text = str(name).strip()
    m = _UTC_OFFSET.match(text)
    if m:
        if m["sign"] is None or (int(m["h"]) == 0 and not int(m["m"] or 0)):
            return "UTC"
        if int(m["m"] or 0) == 0 and int(m["h"]) <= 14:
            return f"Etc/GMT{'-' if m['sign'] == '+' else '+'}{int(m['h'])}"
        raise InputError(
            f"{column}={name!r} is not a whole-hour offset",
            parameter=column,
            expected="UTC±H in whole hours (UTC+1 is Etc/GMT-1), or an IANA name such as Asia/Kolkata",
        )
    if text.upper() in _TWO_MEANINGS:
        # tzdata's CET is the zone with summer time; a logger's "CET" usually means UTC+1 all year.
        raise InputError(
            f"{column}={name!r} could mean two things: UTC{_TWO_MEANINGS[text.upper()]:+d} all year, as "
            f"loggers mean it, or tzdata's zone with summer time",
            parameter=column,
            expected=f"UTC{_TWO_MEANINGS[text.upper()]:+d} (no summer time; TERENO logs so) or an IANA city "
            "name such as Europe/Berlin (with summer time)",
        )
    try:
        return check_timezone(text, column)
    except InputError as e:
        raise InputError(
            e.problem, parameter=column, expected="an IANA name such as Europe/Berlin or UTC, or UTC±H such as UTC+1"
        ) from None


def _preamble_line(text_lines: list[str], end: int, pattern: str) -> tuple[int, re.Match] | None:
    """The first line before ``end`` matching ``pattern`` (its index and match)."""
    rx = re.compile(pattern, re.IGNORECASE)
    for i in range(end):
        m = rx.search(text_lines[i])
        if m:
            return i, m
    return None


def _header_zone(text_lines: list[str], end: int, file, tz: str | None) -> tuple[str, bool]:
    """The zone of a TERENO export's timestamps: its header's ``Time zone:`` line, ``tz`` where
    the header says none (default UTC+1); a ``tz`` that disagrees with the header is refused. With
    whether the zone was stated (by the header or ``tz``) rather than the format's default."""
    found = _preamble_line(text_lines, end, r"^\s*#?\s*(?:time\s*zone|timezone|zeitzone)\s*[:=]\s*(?P<v>\S.*?)\s*$")
    given = None if tz is None else zone(tz)
    if found is None:
        return given or TERENO_TZ, given is not None
    i, m = found
    raw = m["v"]
    # "UTC+1", "UTC+1 (no daylight saving)", "Europe/Berlin": the leading offset or IANA name
    lead = re.match(r"(?:UTC|GMT)(?:\s*[+-]\s*\d{1,2}(?::?\d{2})?)?(?![\w:+-])", raw, re.IGNORECASE)
    name = lead.group(0) if lead else next((w for w in raw.split() if "/" in w), None)
    stated = None
    if name is not None:
        try:
            stated = zone(name)
        except InputError:
            stated = None
    if stated is None:
        if given is not None:
            return given, True  # the caller says what the header means
        raise InputError(
            f"the header's time zone {raw!r} is not one lightfit can read unambiguously",
            file=file,
            row=i + 1,
            expected="UTC, UTC±H or an IANA name in the header, or tz= / --tz naming the zone it means",
        )
    if given is not None and given != stated:
        raise InputError(
            f"tz={tz!r} disagrees with the header's 'Time zone: {raw}' ({stated})",
            file=file,
            row=i + 1,
            parameter="tz",
            expected=f"no tz (the header's zone is used) or tz={stated!r}",
        )
    return stated, True


#: What a weather series can be (docs: data/README.md); ``"unstated"``: neither file nor caller said.
WEATHER_PROVENANCES = ("measured", "reconstructed", "synthetic", "unstated")


def _check_provenance(value: str | None, file=None) -> str | None:
    if value is not None and value not in WEATHER_PROVENANCES:
        raise InputError(
            f"provenance={value!r}", file=file, parameter="provenance", expected=" / ".join(WEATHER_PROVENANCES)
        )
    return value


def _resolve_provenance(stated: str | None, where: str, given: str | None, file) -> str:
    """The series' provenance: the file's (``stated``, from ``where``), else the caller's, else
    ``"unstated"``; a caller's word that contradicts the file's is refused."""
    _check_provenance(given, file)
    if stated not in (None, "unstated") and given not in (None, stated):
        raise InputError(
            f"provenance={given!r} contradicts the file, which says {stated!r} ({where})",
            file=file,
            parameter="provenance",
            expected=f"no provenance (the file's is used) or {stated!r}",
        )
    if stated not in (None, "unstated"):
        return stated
    return given or stated or "unstated"


def _header_provenance(text_lines: list[str], end: int, file) -> tuple[str | None, str]:
    """What a TERENO export's header block says it is: a ``provenance: …`` line, else the words
    "synthetic" or "reconstructed/reconstruction" (as the bundled fixture's "SYNTHETIC FIXTURE");
    None where it says nothing. Nothing in free text makes a file "measured"."""
    found = _preamble_line(text_lines, end, r"^\s*#?\s*provenance\s*[:=]\s*(?P<v>\S+)")
    if found is not None:
        i, m = found
        v = m["v"].strip().lower()
        if v not in PROVENANCES:
            raise InputError(
                f"header line 'provenance: {m['v']}'", file=file, row=i + 1, expected=" / ".join(PROVENANCES)
            )
        return v, f"line {i + 1}"
    words = {"synthetic": r"\bsynthetic\b", "reconstructed": r"\breconstruct(?:ed|ion)\b"}
    hits = {k: f for k, pat in words.items() if (f := _preamble_line(text_lines, end, pat)) is not None}
    if len(hits) > 1:
        raise InputError(
            "the header calls the file both synthetic (line {}) and reconstructed (line {})".format(
                hits["synthetic"][0] + 1, hits["reconstructed"][0] + 1
            ),
            file=file,
            expected="one header line 'provenance: measured|reconstructed|synthetic'",
        )
    for k, (i, _) in hits.items():
        said = text_lines[i].strip()
        return k, f"line {i + 1}: {said if len(said) <= 50 else said[:50] + ' …'!r}"
    return None, ""


#: The years a file's timestamps may be in: pandas' nanosecond range (1677-09-21 … 2262-04-11), whole years.
YEARS = (1678, 2261)
_ISO = re.compile(r"\d{4}-\d{2}-\d{2}(?:[T ]\d{2}:\d{2}(?::\d{2}(?:\.\d+)?)?)?\s*(?P<offset>Z|[+-]\d{2}(?::?\d{2})?)?")
_DAY_MONTH = re.compile(r"^\d{1,2}[./-]\d{1,2}[./-]\d{2,4}\b")


def parse_times(
    raw: pd.Series, lines: pd.Series, file, column: str, tz: str | None, no_zone: str = "", *, stated: bool = True
) -> pd.DatetimeIndex:
    """ISO 8601 timestamps (naive ones in ``tz``; all or none with a UTC offset) → UTC; the one
    reader of a file's times (weather and observations). ``lines``: each row's line in the file,
    for messages. ``tz`` ``None``: naive times are refused, ``no_zone`` saying what was expected.
    Offsets written in the times must be ``tz``'s where the zone was ``stated`` (by the file or the
    caller, not a format's default), UTC itself (``Z``, ``+00:00``) always allowed."""
    text = raw.astype("string").fillna("").str.strip().reset_index(drop=True)
    lines = lines.reset_index(drop=True)
    expected = "ISO 8601 timestamps such as 2016-04-20 12:10:00 (YYYY-MM-DD, optionally T and a UTC offset)"
    empty = text == ""
    if empty.any():
        i = int(np.flatnonzero(empty.to_numpy())[0])
        raise InputError(
            f"empty time ({int(empty.sum())} row(s) without one)",
            file=file,
            row=int(lines.iloc[i]),
            column=column,
            expected="a timestamp on every data row",
        )
    parts = text.str.extract(f"^(?:{_ISO.pattern})$")
    iso = text.str.fullmatch(_ISO.pattern).to_numpy(dtype=bool)
    if not iso.all():
        i = int(np.flatnonzero(~iso)[0])
        s = text.iloc[i]
        why = (
            ": not ISO 8601 (a day.month or month/day date, whose order lightfit does not guess: "
            "04/05/2016 is 4 May or 5 April)"
            if _DAY_MONTH.match(s)
            else ""
        )
        raise InputError(
            f"cannot parse time {s!r}{why}", file=file, row=int(lines.iloc[i]), column=column, expected=expected
        )
    offset = parts["offset"].notna().to_numpy()
    first_bad_row(
        offset != offset[:1],  # none: no row differs
        lines,
        file,
        column,
        f"all timestamps with a UTC offset, or none (then they are read in {tz or 'the time zone the file states'})",
        lambda i: (
            f"time {text.iloc[i]!r} {'has a UTC offset' if offset[i] else 'has no UTC offset'}, "
            f"unlike line {int(lines.iloc[0])}'s {text.iloc[0]!r}"
        ),
    )
    if tz is None and not offset.all():
        # Local times read as UTC would move every reading by hours, silently.
        raise InputError(
            f"time {text.iloc[0]!r} has no UTC offset and no time zone is given",
            file=file,
            row=int(lines.iloc[0]),
            column=column,
            expected=no_zone or "times with a UTC offset",
        )
    t = pd.to_datetime(text, format="ISO8601", errors="coerce", utc=bool(offset.all()))
    bad = t.isna().to_numpy()
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise InputError(
            f"cannot parse time {text.iloc[i]!r}", file=file, row=int(lines.iloc[i]), column=column, expected=expected
        )
    # pandas reads any year, but lightfit's time arithmetic (nanosecond Timedeltas, plots) stops with a
    # traceback outside pandas' nanosecond range: 0001 or 9999 in a weather file is a slip in the year.
    years = t.dt.year.to_numpy()
    first_bad_row(
        (years < YEARS[0]) | (years > YEARS[1]),
        lines,
        file,
        column,
        f"a timestamp in the years {YEARS[0]}–{YEARS[1]} (a slip in the year?)",
        lambda i: f"time {text.iloc[i]!r} is in the year {years[i]}, outside the years lightfit computes with",
    )
    idx = pd.DatetimeIndex(t)
    if idx.tz is None:
        try:
            idx = localize(idx, tz, file=file, column=column)
        except InputError:
            for t, n in zip(idx, lines):  # the first time a clock change skips or repeats, by its line
                localize(t, tz, file=file, row=int(n), column=column)
            raise
    elif tz is not None and stated:
        _offsets_agree(idx, parts["offset"], text, lines, tz, file, column)
    return idx.tz_convert("UTC")


_OFFSET = re.compile(r"(?P<sign>[+-])(?P<h>\d{2}):?(?P<m>\d{2})?")


def _offsets_agree(t: pd.DatetimeIndex, offsets: pd.Series, text: pd.Series, lines: pd.Series, tz, file, column):
    """Times written with a UTC offset in a file that also states its zone ``tz``: each offset other
    than UTC's must be the zone's at that instant, else :class:`InputError` at the first that is not
    (a ``UTC`` zone line over ``+02:00`` times contradicts itself, and which of the two is meant
    cannot be told; ``Z`` is ISO's UTC whatever the file's zone)."""

    def parse(o: str) -> pd.Timedelta:
        m = _OFFSET.fullmatch(o)
        if m is None:  # "Z"
            return pd.Timedelta(0)
        return (1 if m["sign"] == "+" else -1) * pd.Timedelta(hours=int(m["h"]), minutes=int(m["m"] or 0))

    written = offsets.reset_index(drop=True).map({o: parse(o) for o in offsets.unique()}).to_numpy("m8[ns]")
    utc = t.tz_convert("UTC").tz_localize(None)
    zoned = (t.tz_convert(tz).tz_localize(None) - utc).to_numpy("m8[ns]")
    first_bad_row(
        (written != zoned) & (written != np.timedelta64(0, "ns")),  # Z and +00:00 say UTC outright
        lines,
        file,
        column,
        "offsets that are the stated zone's, or the zone stated as the times are written",
        lambda i: (
            f"time {text.iloc[i]!r} is in {offset_label(pd.Timedelta(written[i]))}, but the stated time "
            f"zone {zone_label(tz)} was at {offset_label(pd.Timedelta(zoned[i]))} then"
        ),
    )


def first_bad_row(bad, lines, file, column: str, expected: str, problem) -> None:
    """:class:`InputError` at the first data row where ``bad`` (a boolean array over the rows) holds,
    naming its line (``lines``: each row's line in the file) and column; ``problem(i)`` describes
    row i. The one first-bad-row check of lightfit's file readers (weather and observations)."""
    bad = np.asarray(bad)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise InputError(problem(i), file=file, row=int(np.asarray(lines)[i]), column=column, expected=expected)


#: Quality flags of a TERENO export where its header does not list them (``Quality flags: …``).
TERENO_FLAGS = ("ok", "doubtful", "bad", "unevaluated")
#: A flag column's name: its value column's name then the flag word (``<name> QualityFlag``,
#: ``<name>_QF``), or the flag word first (``QualityFlag <name>``, ``QF_<name>``); ``base`` or
#: ``base_after`` is the value column's name.
_FLAG_WORD = r"(?:quality[\s_]*flag|qualityflag|flag|qf)s?"
_FLAG_COL = re.compile(rf"^(?:(?P<base>.*?)[\s_]*{_FLAG_WORD}|{_FLAG_WORD}[\s_]+(?P<base_after>.+?))$", re.IGNORECASE)


def _flag_vocabulary(text_lines: list[str], end: int) -> tuple[str, ...]:
    found = _preamble_line(text_lines, end, r"^\s*#?\s*quality\s*flags?\s*:\s*(?P<v>\S.*?)\s*$")
    if found is None:
        return TERENO_FLAGS
    return tuple(w.strip().lower() for w in re.split(r"[,;]", found[1]["v"]) if w.strip())


def _quality_flags(table: pd.DataFrame, used: dict[str, str]) -> dict[str, str]:
    """Quantity → the quality-flag column of its source column (``<name> QualityFlag``)."""
    out = {}
    for c in table.columns:
        m = _FLAG_COL.match(c)
        if not m or not _is_flag_column(c):
            continue
        base = (m["base"] if m["base"] is not None else m["base_after"]).strip()
        for qty, src in used.items():
            if base and base in (src, _split_header(src)[0]):
                out[qty] = c
    return out


def _mask_flagged_bad(
    value: pd.Series, flags: pd.Series, lines: pd.Series, vocabulary, file, flag_col: str, qty: str, qc: list[dict]
) -> pd.Series:
    """``value`` with the cells its flag column marks ``bad`` made missing (then repaired or refused as
    any gap), counted in ``qc``; a flag outside the export's vocabulary is an error."""
    f = flags.astype("string").fillna("").str.strip().str.lower()
    unknown = (f != "") & ~f.isin(vocabulary)
    if unknown.any():
        i = int(np.flatnonzero(unknown.to_numpy())[0])
        raise InputError(
            f"quality flag {flags.iloc[i]!r} not understood",
            file=file,
            row=int(lines.iloc[i]),
            column=flag_col,
            expected="one of " + ", ".join(vocabulary) + " (or an empty cell)",
        )
    bad = (f == "bad").to_numpy() & value.notna().to_numpy()
    doubtful = int(((f == "doubtful").to_numpy() & value.notna().to_numpy()).sum())
    if bad.any() or doubtful:
        rows = lines[bad].tolist()
        where = f" (line{'s' if len(rows) > 1 else ''} {listed(rows)})" if rows else ""
        kept = f"; {doubtful} value(s) flagged 'doubtful' kept" if doubtful else ""
        qc.append(
            {
                "kind": "flagged bad",
                "column": qty,
                "count": int(bad.sum()),
                "detail": f"{int(bad.sum())} value(s) flagged 'bad' in {flag_col!r} read as missing{where}{kept}",
            }
        )
    return value.mask(bad)


#: Relative humidity declared in % must reach this (as a fraction) somewhere in the series: RH
#: below 5 % all day and night does not occur at a field site (even desert afternoons reach a few
#: % only at their driest, and nights are moister), while RH written as a fraction (0.80) under a
#: [%] header reads as 0.008.
RH_PERCENT_MIN_PEAK = 0.05


def _across_gaps(x: pd.Series, values: pd.Series, column: str, what: str, qc: list[dict]) -> pd.Series:
    """``x`` (air temperature or pressure) interpolated linearly in time over its gaps inside the series,
    for converting ``values`` of another quantity: a reading kept where only ``x`` is missing (it was
    lost, and then reported as a missing value of its own). The rows converted so are recorded in ``qc``."""
    filled = x.interpolate(method="time", limit_area="inside")
    has = ~np.isnan(np.asarray(values, dtype=float))
    n = int((x.isna().to_numpy() & filled.notna().to_numpy() & has).sum())
    if n:
        qc.append(
            {
                "kind": "converted across a gap",
                "column": column,
                "count": n,
                "detail": f"{n} value(s) converted with the {what} interpolated in time (missing at their rows)",
            }
        )
    return filled


def read_tereno(
    path: str | Path,
    *,
    tz: str | None = None,
    columns: dict[str, str] | None = None,
    max_gap: str | pd.Timedelta = DEFAULT_MAX_GAP,
    provenance: str | None = None,
    time_label: str = "end",
) -> pd.DataFrame:
    """Read a TERENO data-portal CSV export (e.g. station SE_EC_001) into a contract series.

    The table header is found by content (a line with a time column and a TERENO quantity
    such as ``RadiationGlobal_Avg10min [W*m-2]``), not by line count; the delimiter (``,``,
    ``;`` or tab) is detected. Units in brackets are checked and converted: absolute humidity
    (g m⁻³) → relative humidity with air temperature; CO2 (mmol m⁻³) → ppm with air
    temperature and pressure; mbar/hPa → kPa; K → °C. Values whose quality flag column
    (``<column> QualityFlag``) says ``bad`` are read as missing (then interpolated or refused as
    any gap, and counted in ``attrs["qc"]``). Timestamps must be ISO 8601.

    Args:
        path: the export file (UTF-8).
        tz: timezone of the timestamps; default the header's ``Time zone:`` line, else UTC+1 (the
            TERENO convention). ``UTC+1`` is read as ``Etc/GMT-1``. A tz that disagrees with the
            header is refused.
        columns: override which source column feeds a quantity, e.g.
            ``{"tair_c": "AirTemperature_2m_Avg10min_Sensor2 [°C]"}``. Keys: ``ghi_w_m2``,
            ``par_umol_m2_s``, ``diffuse_w_m2``, ``tair_c``, ``humidity``, ``pair_kpa``, ``co2_ppm``.
        max_gap: longest gap that is interpolated (see :func:`~lightfit.weather.series.check_and_repair`).
        provenance: what the file is, where its header does not say (``"measured"`` only for a real
            export); default the header's word, else ``"unstated"``.
        time_label: where the stamp of each mean lies in its interval (``"end"``, ``"start"``,
            ``"center"``); the interval is the radiation columns' (``Avg10min``: 10 min).
    """
    path = Path(path)
    timestamps.check_mean_label(time_label)
    text_lines = _read_text(path, "a TERENO CSV export").splitlines()
    hdr, delim = _find_table(text_lines, path)
    try:
        tz, zone_stated = _header_zone(text_lines, hdr, path, tz)
    except InputError as e:
        raise (e if e.file is not None else e.in_file(path)) from None
    stated, where = _header_provenance(text_lines, hdr, path)
    provenance = _resolve_provenance(stated, where, provenance, path)
    table, lines = _table_rows(text_lines, hdr, delim, path)

    time_col = next(c for c in table.columns if _TIME_NAMES.match(c))
    times = parse_times(table[time_col], lines, path, time_col, tz, stated=zone_stated)
    qc: list[dict] = []
    if not zone_stated:  # said, as every other assumption is (a review: read as UTC+1 without a word)
        qc.append(
            {
                "kind": "checked",
                "column": None,
                "count": len(times),
                "detail": "no 'Time zone:' line in the header: the timestamps are read as UTC+1, the TERENO "
                "convention (--tz / tz= names another zone)",
            }
        )
    if not times.is_monotonic_increasing:
        # Sorted before anything reads neighbouring rows (the 30-min CO2 below), not after.
        record_sorted(qc, times, lines, tz)
        order = np.argsort(times.asi8, kind="stable")
        table, lines, times = (
            table.iloc[order].reset_index(drop=True),
            lines.iloc[order].reset_index(drop=True),
            times[order],
        )
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
            cands = [c for c in table.columns if re.search(pattern, _split_header(c)[0]) and not _is_flag_column(c)]
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
                expected="one of " + ", ".join(f"[{u}]" for u in unit_map) + ", compared in lower case without "
                "spaces, '*', '·' or '^' (e.g. [W*m-2] reads as [wm-2])",
            )
        raw[qty] = parse_numeric(table[src].set_axis(times), lines.set_axis(times), path, src, qc)
        conv[qty], used[qty] = tag, f"{src}"
    _check_near_misses(table, used, time_col, path, hdr)
    flag_cols = _quality_flags(table, used)
    if flag_cols:
        vocabulary = _flag_vocabulary(text_lines, hdr)
        for qty, fc in flag_cols.items():
            raw[qty] = _mask_flagged_bad(
                raw[qty], table[fc].set_axis(times), lines.set_axis(times), vocabulary, path, fc, _contract(qty), qc
            )
    for qty in ("ghi_w_m2", "diffuse_w_m2"):
        if conv.get(qty) == "kilo":  # kW m-2, as some loggers export
            raw[qty] = raw[qty] * 1000.0
    if "tair_c" in raw and conv["tair_c"] == "kelvin":
        raw["tair_c"] = raw["tair_c"] - units.T0
    if "pair_kpa" in raw:
        raw["pair_kpa"] = {"mbar": units.kpa_from_mbar, "pa": units.kpa_from_pa, "same": lambda p: p}[conv["pair_kpa"]](
            raw["pair_kpa"]
        )
    out = pd.DataFrame(index=times)
    for qty in ("ghi_w_m2", "par_umol_m2_s", "diffuse_w_m2", "tair_c", "pair_kpa"):
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
            t = _across_gaps(out["tair_c"], raw["humidity"], "rh", "air temperature", qc)
            out["rh"] = units.relative_humidity_from_absolute(raw["humidity"], t)
        else:
            out["rh"] = raw["humidity"] / 100.0
            peak = out["rh"].max()
            if pd.notna(peak) and peak < RH_PERCENT_MIN_PEAK:
                raise InputError(
                    f"relative humidity declared in % peaks at {peak * 100:.3g} %: the values look like a "
                    "fraction (0–1) in a % column",
                    file=path,
                    row=hdr + 1,
                    column=used["humidity"],
                    expected="percent, 0–100 (e.g. 80 for 0.80)",
                )
    if "co2_ppm" in raw:
        if conv["co2_ppm"] == "mmol_m3":
            if not {"tair_c", "pair_kpa"} <= set(out.columns):
                raise InputError(
                    "CO2 in mmol m-3 needs air temperature and pressure to convert to ppm",
                    file=path,
                    expected="AirTemperature and AirPressure columns",
                )
            t = _across_gaps(out["tair_c"], raw["co2_ppm"], "co2_ppm", "air temperature", qc)
            p = _across_gaps(out["pair_kpa"], raw["co2_ppm"], "co2_ppm", "air pressure", qc)
            out["co2_ppm"] = units.co2_ppm_from_mmol_m3(raw["co2_ppm"], t, p)
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
            first = co2.first_valid_index()
            if first is not None:  # only the rows past the file's last 30-min stamp keep its mean
                # (a last mean missing from its stamp's row is a gap, cut or refused as any other:
                # its interval's rows took the mean before, as if it were the interval after it)
                stamps = co2.index[(co2.index - first) % pd.Timedelta("30min") == pd.Timedelta(0)]
                last = stamps[-1]
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
        # keyed by contract column (humidity is read into rh), as the checks and repairs look the file's names up
        "columns_used": {_contract(qty): src for qty, src in used.items()},
        "column_names": TERENO_NAMES,
        "unused_columns": [
            c for c in table.columns if c not in used.values() and c != time_col and c not in flag_cols.values()
        ],
        "quality_flags": flag_cols,
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
    provenance: str | None = None,
    time_label: str = "end",
) -> pd.DataFrame:
    """Read CPlantBox's one-day weather file (``climate/Selhausen_weather_data.txt`` format).

    Tab-separated, quoted header ``"time" "PAR" "co2" "RH" "Tair" "Pair" ...`` with time
    HH:MM:SS, PAR in mol m⁻² s⁻¹, co2 in mol mol⁻¹, RH 0–1, Tair °C, Pair kPa. The file has
    no date: ``date`` supplies it. Extra columns (soil water potential ``ps``, ``nm``) are
    listed in ``attrs["unused_columns"]``. Its rows are means over the rows' step stamped at
    ``time_label`` (the module's docstring says why the end). The file says nothing of its
    provenance: ``provenance`` (default ``"unstated"``) is the caller's word (the bundled day's
    is ``"measured"``, :data:`lightfit.weather.bundled.BUNDLED`).
    """
    path = Path(path)
    timestamps.check_mean_label(time_label)
    day = parse_date(date, "date")
    try:
        tz = zone(tz)
    except InputError as e:
        raise e.in_file(path) from None
    provenance = _resolve_provenance(None, "", provenance, path)
    table, lines = _table_rows(_read_text(path, "a CPlantBox weather file").splitlines(), 0, "\t", path)
    need = {"time": None, "PAR": "par_umol_m2_s", "co2": "co2_ppm", "RH": "rh", "Tair": "tair_c", "Pair": "pair_kpa"}
    missing = [c for c in need if c not in table.columns]
    if missing:
        raise InputError(f"missing column(s) {missing}", file=path, row=1, expected=f"columns {list(need)}")
    clock = table["time"].str.strip().str.strip('"')
    empty = (clock == "").to_numpy()
    if empty.any():
        raise InputError(
            "empty time",
            file=path,
            row=int(lines.iloc[int(np.flatnonzero(empty)[0])]),
            column="time",
            expected="a clock time HH:MM:SS on every data row",
        )
    stamps = pd.Series([f"{day.isoformat()} {c}" for c in clock])
    times = parse_times(stamps, lines, path, "time", tz)
    qc: list[dict] = []
    lt = lines.set_axis(times)
    out = pd.DataFrame(index=times)
    # CPlantBox's units: PAR in mol m⁻² s⁻¹ and CO2 as a mole fraction (the bundled day's 0.000393)
    file_units = {"par_umol_m2_s": ("mol m⁻² s⁻¹", 1e6), "co2_ppm": ("mol mol⁻¹", 1e6)}
    scale = {col: factor for col, (_, factor) in file_units.items()}
    out["par_umol_m2_s"] = parse_numeric(table["PAR"].set_axis(times), lt, path, "PAR", qc) * scale["par_umol_m2_s"]
    out["tair_c"] = parse_numeric(table["Tair"].set_axis(times), lt, path, "Tair", qc)
    out["rh"] = parse_numeric(table["RH"].set_axis(times), lt, path, "RH", qc)
    out["pair_kpa"] = parse_numeric(table["Pair"].set_axis(times), lt, path, "Pair", qc)
    out["co2_ppm"] = parse_numeric(table["co2"].set_axis(times), lt, path, "co2", qc) * scale["co2_ppm"]
    out.attrs = {
        "source": str(path),
        "format": "cplantbox",
        "provenance": provenance,
        "date_given": day.isoformat(),  # the file has none: the caller placed it on this date
        "timezone_assumed": tz,
        "columns_used": {v: k for k, v in need.items() if v},
        "file_units": file_units,
        "unused_columns": [c for c in table.columns if c not in need],
        "qc": qc,
    }
    return _with_means(check_and_repair(out, lt, path, max_gap=max_gap), time_label)


def check_aware_index(df: pd.DataFrame, what: str) -> None:
    """:class:`InputError` naming ``df`` unless its index is times with a zone: lightfit's CSV writers
    write UTC, and a naive index (or none of times) was written as if it were UTC, or failed in pandas."""
    if not isinstance(df.index, pd.DatetimeIndex) or df.index.tz is None:
        raise InputError(
            f"the {what}'s index is {type(df.index).__name__}"
            + (" without a time zone" if isinstance(df.index, pd.DatetimeIndex) else ""),
            parameter="df",
            expected="a DatetimeIndex with a time zone (e.g. index.tz_localize('Europe/Berlin') for local times): "
            "the file is written in UTC",
        )


def metadata_lines(metadata: dict) -> str:
    """``# key: value`` lines, one per item: the header of lightfit's CSV files, which
    :func:`read_csv_with_metadata` reads (and ``pandas.read_csv(path, comment="#")`` skips)."""
    return "".join(f"# {k}: {v}\n" for k, v in metadata.items())


def one_of(*choices: str):
    """A metadata value test (:func:`check_metadata_keys`): the value is one of ``choices``."""
    return lambda value: value.strip().lower() in choices


def _is_zone(value: str) -> bool:
    try:
        zone(value.strip(), "time_zone")
    except InputError:
        return False
    return True


def _is_span(value: str) -> bool:
    try:
        return pd.Timedelta(value.strip()) > pd.Timedelta(0)
    except (ValueError, TypeError):
        return False


#: The metadata keys lightfit's CSV readers read, each with a test of the values it takes
#: (:func:`check_metadata_keys`: a free key that resembles one is refused where its value is one the
#: known key takes).
METADATA_VALUES = {
    "provenance": one_of(*PROVENANCES, "unstated"),
    "time_zone": _is_zone,
    "time_label": one_of(*timestamps.LABELS),
    "averaging_interval": _is_span,
}
#: The metadata keys :func:`read_lightfit_csv` reads and their values; any other key is free (not
#: read), unless it resembles one of these with a value it takes (:func:`check_metadata_keys`).
LIGHTFIT_CSV_KEYS = METADATA_VALUES | {"split_model": one_of(*SPLIT_MODELS)}


def check_metadata_keys(meta: dict, known: dict, file: str | Path | None = None) -> None:
    """:class:`InputError` naming ``file`` and the key where a metadata key is not one of ``known``
    (the keys its reader reads, each with a test of its values: :data:`METADATA_VALUES`) but
    resembles one (difflib ratio ≥ :data:`MISSPELT_KEY_RATIO`, case, spaces and hyphens aside) and
    holds a value that key takes: a typo was ignored as a free key and the reader's default taken
    unsaid (``# an_per: leaf`` in an observations file read per ground area; ``# provenence:
    reconstructed``, ``# time_lable: end`` in a weather CSV). A note that only resembles a key
    (``# canopy: winter wheat``, ``# provenance_note: …``, ``# time_zone_note: logger kept CET``)
    stays free. Shared by the readers of lightfit's CSV files and their writers (a key the reader
    would refuse is refused at the writing)."""
    for key, value in meta.items():
        if key in known:
            continue
        plain = key.strip().lower().replace(" ", "_").replace("-", "_")
        close = [
            k
            for k in difflib.get_close_matches(plain, list(known), n=3, cutoff=MISSPELT_KEY_RATIO)
            if known[k](str(value))
        ]
        if close:
            raise InputError(
                f"metadata key {key!r} resembles {close[0]!r}, which the reader knows, and would be ignored as "
                "a free key",
                file=file,
                column=key,
                expected=f"'# {close[0]}: …' if that is meant, else a free key that resembles none of "
                + ", ".join(known),
            )


def read_csv_with_metadata(
    path: Path,
    expected: str,
    *,
    known_keys: dict,
    provenances: tuple[str, ...] = PROVENANCES,
    short_rows: str = "pad",
) -> tuple[dict[str, str], int, pd.DataFrame]:
    """A CSV whose leading ``# key: value`` lines are metadata, ``provenance`` required (one of
    ``provenances``); a key that is not one of ``known_keys`` but resembles one and holds a value
    that key takes is refused (:func:`check_metadata_keys`).

    Returns (metadata, the header's line number in the file (1-based; blank lines may sit between
    it and the metadata; the line after the metadata where there is no table), table of strings);
    ``table.attrs["lines"]`` holds each row's line number in the file (blank lines are skipped, the
    numbers stay the file's). A
    file that is not UTF-8, or a row with more cells than the header (fewer: unless
    ``short_rows="pad"``), is refused naming its line; a missing or empty file, or a folder, saying
    ``expected`` (what the file should be). Shared by lightfit's own weather files and the
    observations CSV.
    """
    text = _read_text(path, expected).splitlines()
    meta: dict[str, str] = {}
    n_meta = 0
    for line in text:
        if not line.startswith("#"):
            break
        n_meta += 1
        if ":" in line:
            k, v = line[1:].split(":", 1)
            if k.strip() in meta:  # the later line would win silently
                raise InputError(
                    f"metadata key '{k.strip()}' given twice",
                    file=path,
                    row=n_meta,
                    expected="each '# key: value' line once",
                )
            meta[k.strip()] = v.strip()
    check_metadata_keys(meta, known_keys, path)  # before provenance: '# provenence:' names the typo
    if meta.get("provenance") not in provenances:
        said = meta.get("provenance")
        raise InputError(
            "no metadata line '# provenance: …' at the top of the file"
            if said is None
            else f"metadata line '# provenance: {said}'",
            file=path,
            row=1,
            expected="'# provenance: X' with X one of "
            + " / ".join(f"'{p}'" for p in provenances)
            + " as a first line: lightfit's own CSV files carry it (--provenance speaks for other formats)",
        )
    header = next((i for i in range(n_meta, len(text)) if text[i].strip()), None)  # blank lines may precede it
    if header is None:
        return meta, n_meta + 1, pd.DataFrame()
    other = [sep for sep in (";", "\t") if sep in text[header]]
    if "," not in text[header] and other:  # else one column named 'time;par…', refused as no 'time' column
        raise InputError(
            f"the header line separates its columns by {other[0]!r}",
            file=path,
            row=header + 1,
            expected="comma-separated columns (and '.' as the decimal separator)",
        )
    table, lines = _table_rows(text, header, ",", path, short_rows=short_rows)
    table.attrs["lines"] = lines
    return meta, header + 1, table


def read_lightfit_csv(
    path: str | Path, *, max_gap: str | pd.Timedelta = DEFAULT_MAX_GAP, provenance: str | None = None
) -> pd.DataFrame:
    """Read lightfit's own series CSV: ``# key: value`` metadata lines, then contract columns.

    The ``time_utc`` column holds ISO 8601 UTC timestamps. The ``provenance`` metadata key is
    required: a file must say whether it is measured, reconstructed or synthetic (or
    ``unstated``, as lightfit writes a series whose source did not say); ``provenance`` may
    declare an unstated file's, never contradict a stated one. Every column must be a contract
    column (:data:`~lightfit.weather.series.COLUMNS`): an unknown (e.g. misspelt) one is refused
    rather than ignored. ``time_label`` and ``averaging_interval`` say what the stamps mean
    (:mod:`lightfit.weather.timestamps`; without them, instants); a ``time_zone`` line may only say
    ``UTC`` (the times are UTC: one naming another zone is refused, not ignored). Other keys are
    free (not read) unless one resembles a key of :data:`LIGHTFIT_CSV_KEYS` and holds a value that
    key takes (``# time_lable: end``): that is refused (:func:`check_metadata_keys`).
    """
    path = Path(path)
    meta, header_line, table = read_csv_with_metadata(
        path,
        "a lightfit weather CSV",
        known_keys=LIGHTFIT_CSV_KEYS,
        provenances=WEATHER_PROVENANCES,
        short_rows="error",
    )
    if "time_utc" not in table.columns:
        header = f" (header {','.join(map(str, table.columns))[:60]!r})" if len(table.columns) else ""
        raise InputError(
            f"a lightfit CSV whose table has no time_utc column{header}",
            file=path,
            row=header_line,
            expected="the time column named time_utc (UTC, ISO 8601), then contract columns such as "
            "ghi_w_m2, tair_c, rh, pair_kpa, co2_ppm",
        )
    unknown = [c for c in table.columns if c != "time_utc" and c not in COLUMNS]
    if unknown:
        raise InputError(
            f"unknown column(s) {unknown}",
            file=path,
            row=header_line,
            expected="time_utc and columns among " + ", ".join(COLUMNS),
        )
    provenance = _resolve_provenance(meta["provenance"], f"line '# provenance: {meta['provenance']}'", provenance, path)
    _check_utc_line(meta, path)
    lines = table.attrs["lines"]
    times = parse_times(table["time_utc"], lines, path, "time_utc", "UTC")
    lt = lines.set_axis(times)
    qc: list[dict] = []
    out = pd.DataFrame(index=times)
    for c in table.columns:
        if c != "time_utc":
            out[c] = parse_numeric(table[c].set_axis(times), lt, path, c, qc)
    out.attrs = {
        "source": str(path),
        "format": "lightfit",
        "provenance": provenance,
        "timezone_assumed": "UTC",
        "timestamps": Timestamps.from_metadata(meta, path),
        "metadata": meta,
        "columns_used": {c: c for c in out.columns},
        "unused_columns": [],
        "qc": qc,
    }
    if "split_model" in meta:  # the split the file was written with, kept unless a command asks for another
        try:
            out.attrs["split_model"] = check_split_model(meta["split_model"], where="# split_model")
        except InputError as e:
            raise e.in_file(path) from None
    return check_and_repair(out, lt, path, max_gap=max_gap)


def _check_utc_line(meta: dict[str, str], path: Path) -> None:
    """A lightfit CSV's times are UTC (its ``time_utc`` column): a ``# time_zone:`` line may say
    so (``UTC``, ``UTC+0``, ``Etc/UTC``), and one naming another zone is refused. It was ignored,
    and local times stated as ``Europe/Berlin`` read as UTC, 1–2 h off, unsaid."""
    if "time_zone" not in meta:
        return
    said = meta["time_zone"]
    try:
        name = zone(said, "time_zone")
    except InputError as e:
        raise InputError(e.problem, file=path, column="time_zone", expected=e.expected) from None
    offsets = {pd.Timestamp(day, tz=name).utcoffset() for day in ("2016-01-01", "2016-07-01")}
    if offsets != {pd.Timedelta(0)}:
        raise InputError(
            f"metadata line '# time_zone: {said}' in a lightfit CSV, whose times are UTC (column time_utc)",
            file=path,
            column="time_zone",
            expected="'# time_zone: UTC' or no such line, and the times in UTC (ISO 8601, e.g. "
            "2016-04-20T10:10:00Z); local times convert to UTC before they are written",
        )


def write_lightfit_csv(df: pd.DataFrame, path: str | Path, metadata: dict[str, str]) -> Path:
    """Write :func:`lightfit_csv_text` at ``path`` (its folders made), whole or not at all."""
    text, path = lightfit_csv_text(df, metadata), Path(path)  # refused before a folder is made
    path.parent.mkdir(parents=True, exist_ok=True)
    # whole or not at all: a run killed while writing it left a cut forcing.csv beside its results
    return replace_text(path, text)


def lightfit_csv_text(df: pd.DataFrame, metadata: dict[str, str]) -> str:
    """A contract series as a lightfit CSV's text: ``# key: value`` metadata lines (which must include
    ``provenance``, one of :data:`WEATHER_PROVENANCES`: a series whose source did not say is written ``unstated``).
    A series with its DNI/DHI written says how they were split (``split_model``), which
    :func:`read_lightfit_csv` keeps.

    The times are written in UTC (an index in another zone is converted; one without a zone is
    refused). The series' timestamps' meaning (``attrs["timestamps"]``), its columns' meanings and units
    (:data:`~lightfit.weather.series.COLUMNS`) and the site its sun columns are for are written with
    it unless ``metadata`` states them.
    """
    if metadata.get("provenance") not in WEATHER_PROVENANCES:
        raise InputError(
            "metadata must state provenance", column="provenance", expected=" / ".join(WEATHER_PROVENANCES)
        )
    check_metadata_keys(metadata, LIGHTFIT_CSV_KEYS)  # a key its reader would refuse
    _check_utc_line(metadata, None)  # '# time_zone: Europe/Berlin' too
    check_aware_index(df, "series")
    if "time_label" not in metadata:
        metadata = metadata | timestamps.of(df).metadata()
    if "dhi_w_m2" in df.columns and df.attrs.get("split_model") and "split_model" not in metadata:
        metadata = metadata | {"split_model": df.attrs["split_model"]}  # how its DNI/DHI were split
    if "columns" not in metadata:  # each column's meaning and unit, as the bundled files say them
        said = [f"{c}: {COLUMNS[c]}" for c in df.columns if c in COLUMNS]
        metadata = metadata | {"columns": "time_utc: UTC; " + "; ".join(said)}
    site = df.attrs.get("site")
    if "sun_elevation_deg" in df.columns and site is not None and "sun_site" not in metadata:
        metadata = metadata | {"sun_site": f"{site.name}, {site.latitude_deg:g} N, {site.longitude_deg:g} E"}
    head = metadata_lines(metadata)
    # in UTC: a series indexed in local time was written with its local clock marked Z, 1-2 h off
    body = df.set_axis(df.index.tz_convert("UTC")).rename_axis("time_utc").reset_index()
    body["time_utc"] = body["time_utc"].dt.strftime("%Y-%m-%dT%H:%M:%SZ")
    return head + body.to_csv(index=False, float_format="%.8g", lineterminator="\n")


def sniff_format(path: str | Path) -> str:
    """``"tereno"``, ``"cplantbox"`` or ``"lightfit"`` from the file's first lines."""
    path = Path(path)
    head = _read_text(path, "a weather file", strict=False)[:20000]
    if head.startswith("#") and "time_utc" in head:
        return "lightfit"
    if head.startswith('"time"\t"PAR"') or head.startswith("time\tPAR"):
        return "cplantbox"
    if any(re.search(pat.lstrip("^"), head) for pat, _, _ in TERENO_QUANTITIES.values()):
        return "tereno"
    first = next((ln for ln in head.splitlines() if ln.strip()), "")
    if re.match(r"#\s*provenance\s*:", first):  # a lightfit CSV's metadata: its reader says what its table lacks
        return "lightfit"
    _read_text(path, "a weather file")  # a file not in UTF-8 (UTF-16): its encoding is what to fix, not its format
    if first.split(",")[0].strip().strip('"') == "time_utc":
        raise InputError(
            "a lightfit CSV (time_utc, …) without its metadata lines",
            file=path,
            row=1,
            expected="a first line '# provenance: measured' (or reconstructed, synthetic, unstated) above the header",
        )
    raise InputError(
        f"unrecognised weather file format (first line {first[:60]!r})",
        file=path,
        expected="a TERENO CSV export (columns such as 'RadiationGlobal_Avg10min [W*m-2]'), a CPlantBox day "
        "file (header 'time<TAB>PAR…') or a lightfit CSV ('# provenance: …' lines, then time_utc and "
        "contract columns such as par_umol_m2_s, tair_c, rh)",
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

    ``date`` is required for CPlantBox day files and refused for dated ones; ``tz`` overrides the
    format's default zone (for a TERENO export, only where its header states none or the same) and
    is refused for a lightfit CSV, whose times are UTC.
    """
    fmt = sniff_format(path) if format == "auto" else format
    if fmt in ("tereno", "lightfit") and date is not None:
        raise InputError(
            f"date={date!s} given for a file whose timestamps carry their dates ({fmt})",
            file=path,
            parameter="date",
            expected="no date (it places an undated CPlantBox day only)",
        )
    if fmt == "tereno":
        return read_tereno(path, **({"tz": tz} if tz else {}), **kwargs)
    if fmt == "cplantbox":
        if date is None:
            raise InputError(
                "a CPlantBox weather file has no date", file=path, parameter="date", expected="date=YYYY-MM-DD"
            )
        return read_cplantbox_day(path, date, **({"tz": tz} if tz else {}), **kwargs)
    if fmt == "lightfit":
        if "time_label" in kwargs:
            raise InputError(
                "a lightfit CSV states what its stamps mean in its own '# time_label:' line",
                file=path,
                parameter="time_label",
                expected="no time_label for a lightfit CSV (edit its metadata instead)",
            )
        if tz:
            raise InputError(
                f"tz={tz!r} given for a lightfit CSV, whose times are UTC (column time_utc)",
                file=path,
                parameter="tz",
                expected="no tz for a lightfit CSV",
            )
        return read_lightfit_csv(path, **kwargs)
    raise InputError(
        f"unknown weather format {fmt!r}", parameter="format", expected="auto, tereno, cplantbox or lightfit"
    )
