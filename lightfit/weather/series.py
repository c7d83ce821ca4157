"""The weather series contract (docs/design.md §3) and the checks every reader passes through.

A weather series is a ``pandas.DataFrame`` indexed by tz-aware UTC timestamps with unit-named
columns (:data:`COLUMNS`). Readers hand :func:`check_and_repair` a frame plus the source line
number of every row; it either raises :class:`~lightfit.errors.InputError` naming file, line,
column and expectation, or applies a documented repair and records it in
``df.attrs["qc"]`` (a list of dicts: ``kind``, ``column``, ``count``, ``detail``). Nothing is
dropped silently and no NaN leaves this module.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from lightfit.errors import InputError
from lightfit.weather import timestamps
from lightfit.weather.site import SELHAUSEN, localize, zone_label
from lightfit.weather.timestamps import Timestamps

#: Contract columns and their units (also in the names).
COLUMNS: dict[str, str] = {
    "ghi_w_m2": "global horizontal irradiance, W m⁻²",
    "par_umol_m2_s": "photosynthetically active photon flux density, µmol m⁻² s⁻¹",
    "diffuse_w_m2": "diffuse horizontal irradiance, measured or a reconstruction's (optional), W m⁻²",
    "par_diffuse_umol_m2_s": "diffuse PAR photon flux density, measured (optional), µmol m⁻² s⁻¹",
    "tair_c": "air temperature, °C",
    "rh": "relative humidity, 0–1",
    "pair_kpa": "air pressure, kPa",
    "co2_ppm": "CO2 mole fraction in air, ppm (µmol mol⁻¹)",
    "dni_w_m2": "direct normal irradiance, W m⁻² (derived)",
    "dhi_w_m2": "diffuse horizontal irradiance, W m⁻² (derived)",
    "sun_elevation_deg": "apparent (refraction-corrected) solar elevation at the centre of the interval each "
    "stamp labels (at the stamp for instants), degrees (derived)",
    "sun_azimuth_deg": "solar azimuth at the same instant as sun_elevation_deg, degrees clockwise from north (derived)",
}


@dataclass(frozen=True)
class Bounds:
    """Plausible range of a measured column; values outside are errors, not repairs.

    ``clamp_below`` / ``clamp_above`` define a tolerance band just outside the range in which
    values are clamped (and counted) instead: sensor offsets such as night-time PAR of
    −2 µmol m⁻² s⁻¹ or RH of 1.02 in fog.
    """

    low: float
    high: float
    clamp_below: float | None = None
    clamp_above: float | None = None


#: Physical plausibility at a temperate field site. Radiation sensors read slightly negative at
#: night (thermal offset of thermopile pyranometers, dark offset of quantum sensors).
BOUNDS: dict[str, Bounds] = {
    "ghi_w_m2": Bounds(0.0, 1400.0, clamp_below=-30.0),
    "par_umol_m2_s": Bounds(0.0, 3000.0, clamp_below=-30.0),
    "diffuse_w_m2": Bounds(0.0, 1000.0, clamp_below=-30.0),
    "par_diffuse_umol_m2_s": Bounds(0.0, 2300.0, clamp_below=-30.0),
    "tair_c": Bounds(-45.0, 50.0),
    "rh": Bounds(0.0, 1.0, clamp_above=1.05),
    # Down to ≈ 5 500 m (fields grow up to ≈ 4 500 m): hPa or Pa (≈ 10³, 10⁵) and atm (≈ 1)
    # still fall outside. 80 kPa, the bound before, refused sites above ≈ 1 900 m that Site takes.
    "pair_kpa": Bounds(50.0, 110.0),
    "co2_ppm": Bounds(200.0, 1500.0),
}

#: Columns a series may lack: one with a gap that cannot be interpolated is dropped (and the drop
#: recorded) instead of refusing the series; what needs it falls back (the direct/diffuse split to
#: a decomposition model, :func:`lightfit.weather.solar.add_solar`).
OPTIONAL = ("diffuse_w_m2", "par_diffuse_umol_m2_s")
#: Columns every series must have, with at least one of ``ghi_w_m2`` and ``par_umol_m2_s``.
REQUIRED = ("tair_c", "rh", "pair_kpa", "co2_ppm")

#: Numeric sentinels that loggers and data portals use for "no value".
MISSING_SENTINELS = (-9999.0, -999.0, -99999.0)

DEFAULT_MAX_GAP = pd.Timedelta("30min")


def _record(qc: list[dict], kind: str, column: str | None, count: int, detail: str) -> None:
    qc.append({"kind": kind, "column": column, "count": int(count), "detail": detail})


def record_sorted(qc: list[dict], times: pd.DatetimeIndex, lines: pd.Series, zone: str) -> None:
    """Record in ``qc`` that rows out of time order (``times``, each row's file ``lines``, read in
    ``zone``) are sorted, naming the first row earlier than the one before it."""
    back = int(np.flatnonzero(np.diff(times.asi8) < 0)[0]) + 1
    at = _clock(times[back], zone)
    _record(
        qc,
        "sorted",
        None,
        len(times),
        f"rows were not in time order and were sorted (the first out of order: line {int(lines.iloc[back])}, "
        f"{at}, before line {int(lines.iloc[back - 1])}'s time)",
    )


def _line_of(lines: pd.Series, ts) -> int | None:
    try:
        return int(lines.loc[ts])
    except (KeyError, TypeError, ValueError):
        return None


def duration(value, name: str, *, zero: bool = False) -> pd.Timedelta:
    """A time span such as ``"30min"`` or ``"1h"`` (a pandas Timedelta), > 0 (≥ 0 with ``zero``),
    or :class:`InputError` naming ``name``. A span under a second other than 0 is refused: pandas reads
    a number without a unit (``--max-gap 10``) as nanoseconds, which turned interpolation off unsaid
    and made ``--resample 7`` a traceback."""
    try:
        d = pd.Timedelta(value)
    except (ValueError, TypeError):
        d = None
    if (
        d is None
        or pd.isna(d)
        or d < pd.Timedelta(0)
        or (d == pd.Timedelta(0) and not zero)
        or pd.Timedelta(0) < d < pd.Timedelta(seconds=1)
    ):
        raise InputError(
            f"{name}={value!r}",
            parameter=name,
            expected="a time span with its unit, such as 30min or 1h" + (", ≥ 0" if zero else ", > 0"),
        )
    return d


def _file_zone(attrs: dict) -> str:
    """The zone a file's timestamps were read in (UTC unless the reader assumed another)."""
    return attrs.get("timezone_assumed") or "UTC"


def _clock(ts: pd.Timestamp, zone: str, seconds: bool = False) -> str:
    """``"YYYY-MM-DD HH:MM"`` (``:SS`` with ``seconds``) of the instant ``ts`` in ``zone``, as a file's
    lines read."""
    return ts.tz_convert(zone).strftime("%Y-%m-%d %H:%M:%S" if seconds else "%Y-%m-%d %H:%M")


def _whole_steps(out: pd.DataFrame, whole, attrs: dict, freq, needs: str, stamped: str, dropped: list) -> pd.DataFrame:
    """``out`` (new steps of :func:`resample`) without those ``whole`` marks False, the steps at the
    series' ends that it covers only in part, each named in a ``"dropped"`` entry appended to
    ``dropped`` (the series' ``qc``): a mean needs ``needs``; ``stamped``: where each mean is stamped."""
    whole = np.asarray(whole, bool)
    if whole.all():
        return out
    dropped.append(
        {
            "kind": "dropped",
            "column": None,
            "count": int((~whole).sum()),
            "detail": f"{int((~whole).sum())} {freq} step(s) at the series' ends that it covers only in part "
            f"(a mean needs {needs}): "
            + ", ".join(_in_file_zone(attrs)(t) for t in out.index[~whole])
            + f" ({_zone_said(attrs)}, stamped at each mean's {stamped})",
        }
    )
    return out[whole]


def _zone_said(attrs: dict) -> str:
    """The file's zone as people write it (``UTC+1``, not tzdata's ``Etc/GMT-1``)."""
    return zone_label(_file_zone(attrs))


def _in_file_zone(attrs: dict, seconds: bool = False):
    """``ts → "YYYY-MM-DD HH:MM"`` (``:SS`` with ``seconds``) in the file's own time zone, as its lines read."""
    tz = _file_zone(attrs)
    return lambda ts: _clock(ts, tz, seconds)


def _gap_problem(run: pd.Series, present: pd.DatetimeIndex, lines: pd.Series, attrs: dict, col: str) -> str:
    """A gap in the file's own terms: its timestamps (in the file's time zone) and line numbers.

    Missing *rows* (timestamps absent from the file) are named by the lines around them; missing
    *values* (empty cells, sentinels) by their own lines.
    """
    tz = _zone_said(attrs)
    at = _in_file_zone(attrs)
    first, last = run.iloc[0], run.iloc[-1]
    times = f"{at(first)} … {at(last)} ({tz})"
    if not present.isin(run.index).any():  # every missing step is a missing row (none is in the file)
        before = present[present < first]
        after = present[present > last]
        around = [f"line {_line_of(lines, t)} ({at(t)})" for t in (before[-1:].tolist() + after[:1].tolist())]
        return f"{len(run)} row(s) missing from the file, {times}: nothing between " + " and ".join(around)
    rows = [r for r in (_line_of(lines, t) for t in run) if r is not None]
    where = f", lines {min(rows)}–{max(rows)}" if rows else ""
    return f"{len(run)} missing value(s) of {col}, {times}{where}"


#: Cell texts that say "no value" in the files lightfit reads (weather and observations alike).
MISSING_TEXTS = ("", "NaN", "nan", "NA", "null")


def cell_numbers(values: pd.Series, lines, file: str | Path, column: str) -> pd.Series:
    """A column's cells as floats: :data:`MISSING_TEXTS` (and absent cells) become NaN; any other
    text that is not a finite decimal number raises, naming the file, its line (``lines``: each
    row's line in the file) and the column, as does text that reads as infinite ("inf", "1e999":
    it was called implausible, "check the unit", or passed a column without bounds). The one
    reading of number cells of lightfit's file readers (weather and observations)."""
    if pd.api.types.is_numeric_dtype(values):
        return values.astype(float)
    text = values.astype("string").str.strip()
    empty = text.isna() | text.isin(MISSING_TEXTS)
    out = pd.to_numeric(text.where(~empty), errors="coerce")
    bad = (out.isna() & ~empty) | np.isinf(out.astype(float))
    if bad.any():
        i = int(np.flatnonzero(bad.to_numpy())[0])
        raise InputError(
            f"value {text.iloc[i]!r} is not a finite number",
            file=file,
            row=int(np.asarray(lines)[i]),
            column=column,
            expected="a decimal number ('.' as the decimal separator) or an empty cell for a missing value",
        )
    return out.astype(float)


def parse_numeric(values: pd.Series, lines: pd.Series, file: str | Path, column: str, qc: list[dict]) -> pd.Series:
    """Convert a column to float (:func:`cell_numbers`): empty cells, "NaN" and the sentinels
    :data:`MISSING_SENTINELS` become NaN (gaps that :func:`check_and_repair` interpolates or rejects;
    sentinels are counted in ``qc``)."""
    out = cell_numbers(values, lines, file, column)
    sentinel = out.isin(MISSING_SENTINELS)
    if sentinel.any():
        out = out.mask(sentinel)
        _record(
            qc,
            "sentinel",
            column,
            sentinel.sum(),
            f"{int(sentinel.sum())} value(s) in {MISSING_SENTINELS} read as missing",
        )
    return out


def cut_at_ends(df: pd.DataFrame) -> str:
    """``"; its ends were cut: …"`` when :func:`check_and_repair` cut rows off the series' ends (the
    ``trimmed`` repair), else ``""``: errors about the series' span name the cut, which changed it."""
    cut = [q["detail"] for q in df.attrs.get("qc", []) if q["kind"] == "trimmed"]
    return f"; {cut[0].replace('series cut at its ends', 'its ends were cut')}" if cut else ""


def _minutes(span: pd.Timedelta) -> str:
    """``30min``, ``3h``, ``90min``: a gap length as the options write it (not ``0 days 00:30:00``)."""
    m = pd.Timedelta(span) / pd.Timedelta(minutes=1)
    return f"{m / 60:g}h" if m % 60 == 0 else f"{m:g}min"


def check_and_repair(
    df: pd.DataFrame,
    lines: pd.Series,
    file: str | Path,
    *,
    max_gap: str | pd.Timedelta = DEFAULT_MAX_GAP,
) -> pd.DataFrame:
    """Validate a freshly read series and apply the documented repairs.

    Args:
        df: columns from :data:`COLUMNS`, index tz-aware UTC (``lines`` shares it).
        lines: source line number (1-based) per row, for error messages.
        file: source name for messages.
        max_gap: longest run of missing values (or missing timestamps) that is linearly
            interpolated; longer gaps raise. ``"0min"`` turns interpolation off.

    Repairs (each recorded in ``attrs["qc"]``): rows sorted by time; rows at either end without a
    value of a column other than :data:`OPTIONAL` cut off (they cannot be interpolated); missing values
    (empty cells, NaN or sentinels :data:`MISSING_SENTINELS`) and missing timestamps of a
    regular series interpolated over gaps up to ``max_gap``; values in a column's clamp band
    clamped to the range (e.g. night-time negative PAR set to 0).

    Errors: missing required columns (:data:`REQUIRED`), duplicated timestamps, an irregular time step, gaps
    longer than ``max_gap``, values outside the plausible range (:data:`BOUNDS`).
    """
    max_gap = duration(max_gap, "max_gap", zero=True)
    attrs = dict(df.attrs)
    qc: list[dict] = list(attrs.get("qc", []))
    df = df.copy()
    missing = [c for c in REQUIRED if c not in df.columns]
    if not ({"ghi_w_m2", "par_umol_m2_s"} & set(df.columns)):
        missing.append("ghi_w_m2 or par_umol_m2_s")
    if missing:
        # how the file's format names a quantity, where it is not the key
        here = {c: f"; here {n}" for c, n in attrs.get("column_names", {}).items()}

        def wanted(col: str) -> str:
            return " or ".join(f"{c} ({COLUMNS[c]}{here.get(c, '')})" for c in col.split(" or "))

        raise InputError(
            f"missing column(s) {', '.join(missing)}",
            file=file,
            expected=f"{'; '.join(wanted(c) for c in missing)}; found {', '.join(df.columns) or 'none'}. A quantity "
            "the station did not record goes into the file as a column of its own, with the header given above "
            "for it in this format (e.g. a constant CO2, with the file's provenance saying it)",
        )
    if len(df) < 2:
        raise InputError(f"only {len(df)} data row(s)", file=file, expected="a time series of at least 2 rows")

    dup = df.index.duplicated(keep=False)
    if dup.any():
        first = df.index[dup][0]
        rows = [int(x) for x in lines[df.index == first].tolist()[:6]]
        at = _in_file_zone(attrs)
        raise InputError(
            f"duplicated timestamp {at(first)} ({_zone_said(attrs)}) on lines {rows} "
            f"({int(dup.sum())} rows share a timestamp)",
            file=file,
            row=rows[0],
            expected="one row per timestamp",
        )
    if not df.index.is_monotonic_increasing:
        record_sorted(qc, df.index, lines, _file_zone(attrs))
        order = np.argsort(df.index.asi8, kind="stable")
        df, lines = df.iloc[order], lines.iloc[order]

    for col in df.columns:
        df[col] = parse_numeric(df[col], lines, file, col, qc)

    # Regular time step: the most common spacing. Missing timestamps become missing rows.
    steps = pd.Series(df.index[1:] - df.index[:-1])
    step = steps.mode().iloc[0]
    off_grid = ((df.index - df.index[0]) % step) != pd.Timedelta(0)
    if off_grid.any():
        bad, at = df.index[off_grid][0], _in_file_zone(attrs, seconds=True)  # an off-grid stamp may be off by seconds
        raise InputError(
            f"timestamp {at(bad)} ({_zone_said(attrs)}) is off the regular {_minutes(step)} grid starting "
            f"{at(df.index[0])}",
            file=file,
            row=_line_of(lines, bad),
            expected=f"a regular time step of {_minutes(step)}",
        )
    full = pd.date_range(df.index[0], df.index[-1], freq=step)
    present = df.index  # rows the file has (the rest of ``full`` are missing rows)
    if len(full) != len(df):
        n_new = len(full) - len(df)
        df = df.reindex(full)
        inserted = f"{n_new} missing timestamp(s) of the {_minutes(step)} grid inserted as gaps"
        _record(qc, "missing_timestamps", None, n_new, inserted)

    # Rows at either end without a value of a column that is not optional cannot be filled (nothing
    # on one side to interpolate from): the series is cut to the rows between, and the cut recorded.
    needed = [c for c in df.columns if c not in OPTIONAL]
    complete = df[needed].notna().all(axis=1).to_numpy()
    if complete.any() and not (complete[0] and complete[-1]):
        i, j = int(np.argmax(complete)), len(df) - 1 - int(np.argmax(complete[::-1]))
        at, said, named = _in_file_zone(attrs), [], attrs.get("columns_used", {})
        for part in (df.index[:i], df.index[j + 1 :]):
            own = part[part.isin(present)]  # the file's rows; the rest are timestamps inserted above
            if len(own):
                lacking = [named.get(c, c) for c in needed if df.loc[own, c].isna().any()]
                rows = [_line_of(lines, t) for t in (own[0], own[-1])]
                said.append(
                    f"{len(own)} row(s) {at(own[0])} … {at(own[-1])} ({_zone_said(attrs)}, lines {rows[0]}–{rows[1]})"
                    f" without {', '.join(lacking)}"
                    + (f", and {len(part) - len(own)} inserted timestamp(s)" if len(part) > len(own) else "")
                )
        _record(qc, "trimmed", None, len(df) - (j + 1 - i), "series cut at its ends: " + "; ".join(said))
        df = df.iloc[i : j + 1]
        if len(df) < 2:
            raise InputError(
                f"only {len(df)} row(s) with every column present, after cutting " + "; ".join(said),
                file=file,
                expected="a time series of at least 2",
            )

    for col in list(df.columns):
        na = df[col].isna()
        if not na.any():
            continue
        # Length of each run of consecutive missing values, in time.
        run_id = (na != na.shift()).cumsum()[na]
        for _, run in df.index[na].to_series().groupby(run_id.values):
            span = run.iloc[-1] - run.iloc[0] + step
            at_edge = run.iloc[0] == df.index[0] or run.iloc[-1] == df.index[-1]
            if span > max_gap or at_edge:
                why = (
                    "at the start or end of the series (cannot interpolate)"
                    if at_edge
                    else f"longer than max_gap={_minutes(max_gap)}"
                )
                rows_missing = not present.isin(run.index).any()
                if col in OPTIONAL and not rows_missing:
                    _record(
                        qc,
                        "dropped",
                        col,
                        len(df),
                        f"{attrs.get('columns_used', {}).get(col, col)} not used: {int(na.sum())} missing value(s), "
                        f"a gap {why}; the direct/diffuse split falls back to the other diffuse column, else Erbs",
                    )
                    df = df.drop(columns=col)
                    if attrs.get("split_model") == "diffuse" and not set(OPTIONAL) & set(df.columns):
                        attrs.pop("split_model")  # the file's split needed the column: the default decides
                    break
                raise InputError(
                    _gap_problem(run, present, lines, attrs, col) + f", {why}",
                    file=file,
                    row=_line_of(lines, run.iloc[0]),
                    # Missing rows lack every column: name the column only for missing values.
                    column=None if rows_missing else attrs.get("columns_used", {}).get(col, col),
                    expected="rows with every column present (the series is cut to them at its ends; here none)"
                    if at_edge
                    else "complete data, or gaps short enough to interpolate (max_gap: `lightfit weather show "
                    "FILE --max-gap 3h --csv filled.csv` writes the series with longer gaps filled, for --weather)",
                )
        if col not in df.columns:
            continue
        df[col] = df[col].interpolate(method="time", limit_area="inside")
        first = df.index[na][0]
        line = _line_of(lines, first)  # none where the whole row was missing (a timestamp inserted)
        _record(
            qc,
            "interpolated",
            col,
            na.sum(),
            f"{int(na.sum())} missing value(s) linearly interpolated (gaps ≤ {_minutes(max_gap)}; the first at "
            f"{_in_file_zone(attrs)(first)}{f', line {line}' if line else ''})",
        )

    for col, b in BOUNDS.items():
        if col not in df.columns:
            continue
        v = df[col]
        low_band = (v < b.low) & (v >= b.clamp_below) if b.clamp_below is not None else pd.Series(False, index=v.index)
        high_band = (
            (v > b.high) & (v <= b.clamp_above) if b.clamp_above is not None else pd.Series(False, index=v.index)
        )
        out = ((v < b.low) & ~low_band) | ((v > b.high) & ~high_band)
        if out.any():
            ts = v.index[out][0]
            src = attrs.get("columns_used", {}).get(col, col)
            read = "" if src == col else f" (read from {src}, in {COLUMNS[col]})"  # a converted value: say from what
            if col in attrs.get("file_units", {}):  # a fixed unit of the format: the value as the file holds it
                unit, factor = attrs["file_units"][col]
                read = f" ({v[ts] / factor:g} {unit} in the file's {src}, the format's unit)"
            raise InputError(
                f"value {v[ts]:g}{read} at {_in_file_zone(attrs)(ts)} ({_zone_said(attrs)}) is implausible "
                f"({int(out.sum())} such value(s)); "
                "check the unit",
                file=file,
                row=_line_of(lines, ts),
                column=col,
                expected=f"{b.low:g} … {b.high:g} ({COLUMNS[col]})",
            )
        if low_band.any():
            df.loc[low_band, col] = b.low
            _record(
                qc,
                "clamped",
                col,
                low_band.sum(),
                f"{int(low_band.sum())} value(s) in [{b.clamp_below:g}, {b.low:g}) set to {b.low:g} (sensor offset)",
            )
        if high_band.any():
            df.loc[high_band, col] = b.high
            _record(
                qc,
                "clamped",
                col,
                high_band.sum(),
                f"{int(high_band.sum())} value(s) in ({b.high:g}, {b.clamp_above:g}] set to {b.high:g}",
            )
    df.index.name = "time_utc"
    df.attrs = attrs | {"qc": qc}
    return df


#: How :func:`resample` changes a series' step: averaging, or taking the value at each new step.
RESAMPLE_HOW = ("mean", "sample")


def check_how(how) -> str:
    """A resampling method of :data:`RESAMPLE_HOW`, else :class:`InputError` naming ``how``."""
    if how not in RESAMPLE_HOW:
        raise InputError(f"how={how!r}", parameter="how", expected=" or ".join(map(repr, RESAMPLE_HOW)))
    return how


def resample(df: pd.DataFrame, freq: str = "30min", how: str = "mean", origin=None) -> pd.DataFrame:
    """Change the time step of a contract series.

    Args:
        freq: new step, a time span with its unit (:func:`duration`: ``"30min"`` as in the reference
            paper, ``"1h"``, ``"1 hour"``, ``"PT1H"``); a bare number or a calendar offset such as
            ``"MS"`` is refused.
        how: ``"mean"`` averages to means over ``freq`` (keeps daily radiation sums): for
            instants (and centred means), in a window centred on each new timestamp (a row
            on its bound counts half in each window: the trapezoid rule); for means
            stamped at their intervals' ends (starts), over the whole source intervals that end
            (start) within the new interval, stamped the same way (:mod:`lightfit.weather.timestamps`).
            ``"sample"`` takes the value at each new timestamp (what the reference paper did when
            it "sub-sampled the 10-minute intervals to 30-minute intervals", §3.2); the values keep their meaning.
        origin: a timestamp (tz-aware) the new steps pass through, e.g. a run's first step;
            ``None``: the series' first timestamp (``"sample"``) or midnight (``"mean"``).

    A step finer than the source's is refused for both (``"mean"`` would leave empty windows). A mean
    of start- or end-stamped means needs rows every interval and a step that is a multiple of it;
    new steps the series covers only in part (at its ends; for instants, each row standing for its
    spacing around it) are dropped and reported in ``qc``, and a series covering no step whole is refused.
    Solar geometry is recomputed at the new timestamps by :func:`lightfit.weather.add_solar`
    (with the input's split model) when the input had it; averaging sun angles would be wrong.
    """
    check_how(how)
    measured = [c for c in df.columns if c in BOUNDS]
    step = duration(freq, "freq")
    source = timestamps.of(df)
    gaps = df.index.to_series().diff().dropna()
    spacing = _minutes(gaps.median()) if len(gaps) else "?"  # the source step, as the options write it
    # a step the source's cannot give is the cause (say one that works); else values are missing there
    off_grid = bool(len(gaps)) and step % gaps.median() != pd.Timedelta(0)
    shorter = bool(len(gaps)) and step < gaps.median()

    def gap_note(missing: pd.DatetimeIndex) -> str:  # rows absent or values NaN there: name where it starts
        first = missing[0].tz_convert("UTC").strftime("%Y-%m-%d %H:%M UTC")
        return (
            f"; the source has no value at {len(missing)} of them, the first {first} (fill or cut the gap: "
            "`lightfit weather show FILE --max-gap …`)"
        )

    stamps, dropped = source, []  # sampling keeps the rows and their meaning
    if how == "sample":
        origin = df.index[0] if origin is None else origin
        first = origin - step * ((origin - df.index[0]) // step)  # the first new step in the series
        out = df[measured].reindex(pd.date_range(first, df.index[-1], freq=step))
        missing = out.index[out.isna().any(axis=1)]
        if len(missing):
            raise InputError(
                f"cannot sample at {freq}: the source, rows {spacing} apart, has no value at some new timestamps",
                file=df.attrs.get("source"),
                parameter="freq",
                expected=f"a step that is a multiple of the source's {spacing} (and starts on it)"
                + (f", e.g. {spacing}" if off_grid else gap_note(missing)),
            )
    else:  # "mean"
        if source.label in ("start", "end"):  # whole source intervals, stamped as the source's are
            rows = df.index.to_series().diff().dropna()
            if step % source.interval or (len(rows) and (rows != source.interval).any()):
                lo, hi = (_minutes(x) for x in (rows.min(), rows.max())) if len(rows) else ("–", "–")
                raise InputError(
                    f"cannot average {source.describe()} at {freq} (rows {lo if lo == hi else f'{lo} – {hi}'} apart)",
                    file=df.attrs.get("source"),
                    parameter="freq",
                    expected=f"rows every {_minutes(source.interval)} and a step that is a multiple of it",
                )
            # The new steps' bounds must be bounds of the source's intervals: a bound inside one puts the
            # intervals it cuts whole into the step on its side, so that the mean covers another span than
            # its stamp says (a window from 09:05 of end-stamped 10-min means: the rows ending 09:10 …
            # 09:30 cover 09:00–09:30, stamped 09:35, their sun taken 5 min late).
            edge = df.index[0].normalize() if origin is None else pd.Timestamp(origin)
            if len(df) and (edge - df.index[0]) % source.interval:
                said = "midnight" if origin is None else f"{edge.tz_convert('UTC'):%Y-%m-%d %H:%M} UTC"
                raise InputError(
                    f"cannot average {source.describe()} at {freq} from {said}: it falls inside a source interval "
                    f"(the intervals' bounds are the stamps, {df.index[0].tz_convert('UTC'):%H:%M} UTC and every "
                    f"{_minutes(source.interval)} from it)",
                    file=df.attrs.get("source"),
                    parameter="start_time" if origin is not None else "freq",
                    expected="steps starting on a bound of the source's intervals (a start time on its stamps), "
                    "or sampling (how='sample', --how sample)",
                )
            side = "right" if source.label == "end" else "left"
            bins = df[measured].resample(step, closed=side, label=side, origin=edge)
            out, n = bins.mean(), bins.size()
            whole = n == step // source.interval  # the series' first and last new steps may reach past its ends
            out = _whole_steps(out, whole, df.attrs, freq, "every source interval inside it", source.label, dropped)
            stamps = Timestamps(source.label, step)
        else:  # instants or centred means: a window centred on each new stamp
            shifted = df[measured].copy()
            shifted.index = shifted.index + step / 2
            start = "start_day" if origin is None else origin
            # A row on the bound of two windows (an even number of rows per step: 10-min instants at 1h)
            # counts half in each (the trapezoid rule): a half-open window took it whole into the later
            # step only, so that an hourly mean of 10-min instants was centred 5 min before its stamp
            # (15 min for 30-min instants), its sun taken at the stamp.
            halves = [shifted.resample(step, origin=start, closed=side, label="left") for side in ("left", "right")]
            total = halves[0].sum().add(halves[1].sum(), fill_value=0.0)
            count = halves[0].count().add(halves[1].count(), fill_value=0)
            out = total / count.where(count > 0)
            # A window the series covers only in part (at its ends: a 30-min mean of 10-min instants
            # stamped at the first row has the rows 0 and +10 min only) is no mean over the step: each
            # row stands for its own spacing around it, so the series covers its first row − spacing/2 …
            # its last + spacing/2, and a window reaching past that is dropped, as for means of means.
            if len(gaps):
                half = gaps.median() / 2
                whole = (out.index - step / 2 >= df.index[0] - half) & (out.index + step / 2 <= df.index[-1] + half)
                out = _whole_steps(out, whole, df.attrs, freq, "data over its whole window", "centre", dropped)
            stamps = Timestamps("center", step)
        if dropped and not len(out):  # every step reaches past the series' ends: no mean is whole
            raise InputError(
                f"cannot average at {freq}: the series ({_in_file_zone(df.attrs)(df.index[0])} … "
                f"{_in_file_zone(df.attrs)(df.index[-1])}, {_zone_said(df.attrs)}) covers no {freq} step whole",
                file=df.attrs.get("source"),
                parameter="freq",
                expected=f"a series spanning at least one whole {freq} step, or a shorter step",
            )
        missing = out.index[out.isna().all(axis=1)]
        if len(missing):
            raise InputError(
                f"cannot average at {freq}: some new steps have no source value in their window (the source's "
                f"rows are {spacing} apart)",
                file=df.attrs.get("source"),
                parameter="freq",
                expected=f"a step at least as long as the source's {spacing}"
                + (f", e.g. {spacing}" if shorter else gap_note(missing)),
            )
    out.attrs = dict(df.attrs)
    out.attrs["timestamps"] = stamps
    out.attrs["qc"] = [
        *df.attrs.get("qc", []),
        {"kind": "resampled", "column": None, "count": len(out), "detail": f"resampled to {freq} ({how})"},
        *dropped,
    ]
    out.index.name = "time_utc"
    if "sun_elevation_deg" in df.columns:
        from lightfit.weather.solar import add_solar

        # the source's split and its reason come with its attrs (split_model, split_why): not "asked" again
        out = add_solar(out, site=df.attrs.get("site"))
    return out


def window(
    df: pd.DataFrame,
    start: str | pd.Timestamp,
    hours: float,
    step: str = "30min",
    *,
    how: str = "sample",
    tz: str = SELHAUSEN.timezone,
) -> pd.DataFrame:
    """Time steps ``start, start + step, …, start + hours`` (inclusive), e.g. a diurnal run.

    The reference paper ran 2016-04-20 from 05:00 for 14 h in 30-minute steps (29 steps);
    ``window(df, "2016-04-20 05:00", 14)`` gives those, with ``start`` read in ``tz`` (local
    time unless it carries its own offset). ``how`` as in :func:`resample`.
    """
    t0 = pd.Timestamp(start)
    if t0.tzinfo is None:
        t0 = localize(t0, tz, file=df.attrs.get("source"), parameter="start_time")
    t0 = t0.tz_convert("UTC")
    t1 = t0 + pd.Timedelta(hours=hours)
    if t0 < df.index[0] or t1 > df.index[-1]:
        raise InputError(
            f"window {t0.isoformat()} … {t1.isoformat()} is not covered by the series "
            f"({df.index[0].isoformat()} … {df.index[-1].isoformat()}{cut_at_ends(df)})",
            file=df.attrs.get("source"),
            expected="a series spanning the requested window",
        )
    if how == "sample" and t0 not in df.index:  # sampling reads rows: the window must start on one
        rows = df.index.to_series().diff().dropna()
        every = f" (rows every {rows.median() / pd.Timedelta(minutes=1):g} min)" if len(rows) else ""
        raise InputError(
            f"the window starts at {t0.tz_convert(tz):%Y-%m-%d %H:%M} ({tz}), not a timestamp of the series{every}",
            file=df.attrs.get("source"),
            parameter="start_time",
            expected="a start time on the series' rows, or averaging instead of sampling (how='mean', --how mean)",
        )
    out = resample(df, step, how, origin=t0)  # the steps run through the window's start
    out = out.loc[t0:t1]
    if not len(out) or out.index[0] != t0 or out.index[-1] < t1 - pd.Timedelta(step):
        raise InputError(
            f"window {t0.isoformat()} … {t1.isoformat()}: the series' {timestamps.of(df).describe()} cover "
            f"only {out.index[0].isoformat() if len(out) else 'none'} … of its {_minutes(step)} steps",
            file=df.attrs.get("source"),
            expected=f"a series whose whole {_minutes(step)} steps span the requested window",
        )
    return out


#: Days before a run whose mean air temperature is Kattge & Knorr's (2007) growth temperature, and
#: the share of them a series must have air temperature on.
MONTH_BEFORE_DAYS = 30
MONTH_BEFORE_COVERAGE = 0.9
MONTH_BEFORE_MIN_DAYS = math.ceil(MONTH_BEFORE_COVERAGE * MONTH_BEFORE_DAYS)  # 27


def month_before_mean_tair_c(df: pd.DataFrame, date: str, tz: str = SELHAUSEN.timezone) -> float | None:
    """Mean air temperature (°C) of the :data:`MONTH_BEFORE_DAYS` local days before ``date`` (in
    ``tz``; each day the mean of its rows, taken at the rows' centres, so that gaps and uneven steps
    do not weight the days); ``None`` where fewer than :data:`MONTH_BEFORE_COVERAGE` of those days
    are covered, a day counting when its rows times their spacing span that share of 24 h (a
    file's first evening is not a day, a day of every other row is). Days are calendar dates: no
    local midnight is constructed, so a daylight-saving change at midnight (Santiago, Beirut) is no
    error."""
    first = (pd.Timestamp(date) - pd.Timedelta(days=MONTH_BEFORE_DAYS)).date()
    last = (pd.Timestamp(date) - pd.Timedelta(days=1)).date()
    t = df["tair_c"].dropna()
    local_date = pd.Series(timestamps.of(df).centres(t.index).tz_convert(tz).date, index=t.index)
    inside = (local_date >= first) & (local_date <= last)
    t, local_date = t[inside], local_date[inside]
    # A day's span: its rows times their usual spacing (every other row still spans the day; a
    # file's first two hours do not).
    hours = pd.Series((t.index - t.index[0]) / pd.Timedelta(hours=1) if len(t) else [], index=t.index, dtype=float)
    # A day of one row (daily means) spans the series' usual spacing.
    usual = float(np.median(np.diff(hours))) if len(hours) > 1 else 0.0
    spacing_h = hours.groupby(local_date).agg(lambda x: np.median(np.diff(x)) if len(x) > 1 else usual)
    span_h = spacing_h * hours.groupby(local_date).size()
    full = span_h >= MONTH_BEFORE_COVERAGE * 24
    if full.sum() < MONTH_BEFORE_MIN_DAYS:
        return None
    return float(t.groupby(local_date).mean()[full].mean())
