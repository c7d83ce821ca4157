"""Chamber observations: a simple CSV of PAR at the plants and canopy net CO2 uptake with their SDs.

Format (UTF-8 CSV; ``#`` metadata lines first, ``provenance`` required)::

    # provenance: measured            (or synthetic)
    # time_zone: Europe/Berlin        (zone of naive timestamps; default UTC)
    time,plant_par_umol_m2_s,plant_par_sd_umol_m2_s,canopy_an_umol_m2_s,canopy_an_sd_umol_m2_s
    2016-04-20 12:13:48,1549.31,50,,
    ...

The value columns carry the names of the coupled model's observables
(:data:`lightfit.model.coupled.OBSERVABLES`): ``plant_par_umol_m2_s`` is mean PAR at the plants,
``canopy_an_umol_m2_s`` canopy net CO2 uptake, both µmol m⁻² s⁻¹; the ``*_sd_*`` columns are the
measurement standard deviations (same unit). Empty cells are missing observations (allowed: a row
may have PAR only). Every present value needs its SD (> 0). Observations are assigned to the
nearest time step of a run; several in one step are averaged (their SD combined as the SD of a
mean), which the reference paper also did. Files with the earlier names (``par_umol_m2_s`` …)
are refused with a message naming the new columns.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from lightfit.errors import InputError
from lightfit.weather.readers import read_csv_with_metadata


@dataclass(frozen=True)
class Series:
    """One observed series: its short name, the column/observable key of its values, the column of
    its measurement SD and the forward model's key of its Monte Carlo SD (all µmol m⁻² s⁻¹)."""

    name: str
    value: str
    sd: str
    mc_sd: str


#: The observed series, in likelihood order (PAR first).
SERIES = (
    Series("par", "plant_par_umol_m2_s", "plant_par_sd_umol_m2_s", "plant_par_mc_sd_umol_m2_s"),
    Series("an", "canopy_an_umol_m2_s", "canopy_an_sd_umol_m2_s", "canopy_an_mc_sd_umol_m2_s"),
)
COLUMNS = tuple(c for s in SERIES for c in (s.value, s.sd))
#: Column names before the observables were renamed (issue 12), and their new names.
RENAMED = {
    "par_umol_m2_s": "plant_par_umol_m2_s",
    "par_sd_umol_m2_s": "plant_par_sd_umol_m2_s",
    "an_umol_m2_s": "canopy_an_umol_m2_s",
    "an_sd_umol_m2_s": "canopy_an_sd_umol_m2_s",
}


def read_observations(path: str | Path) -> pd.DataFrame:
    """Read an observations CSV into a DataFrame indexed by UTC time (attrs: provenance, source)."""
    path = Path(path)
    if not path.exists():
        raise InputError("file not found", file=path, expected="an observations CSV")
    meta, n_meta, df = read_csv_with_metadata(path)
    if "time" not in df.columns:
        raise InputError("no 'time' column", file=path, row=n_meta + 1, expected="columns time, " + ", ".join(COLUMNS))
    old = [c for c in RENAMED if c in df.columns]
    if old:
        raise InputError(
            "old-style column names " + ", ".join(f"{c} (now {RENAMED[c]})" for c in old),
            file=path,
            row=n_meta + 1,
            expected="columns time, " + ", ".join(COLUMNS),
        )
    missing = [c for c in COLUMNS if c not in df.columns]
    if missing:
        raise InputError(
            f"missing column(s) {missing}", file=path, row=n_meta + 1, expected=", ".join(("time",) + COLUMNS)
        )
    tz = meta.get("time_zone", "UTC")
    out = pd.DataFrame(index=range(len(df)))
    for i, t in enumerate(df["time"]):
        try:
            ts = pd.Timestamp(t.strip())
        except ValueError as err:
            raise InputError(
                f"cannot parse time {t!r}",
                file=path,
                row=n_meta + 2 + i,
                column="time",
                expected="ISO 8601 such as 2016-04-20 12:13:48",
            ) from err
        ts = ts.tz_localize(tz) if ts.tzinfo is None else ts
        out.loc[i, "time"] = ts.tz_convert("UTC")
    first = n_meta + 2  # file line of the first data row
    for c in COLUMNS:
        text = df[c].str.strip()
        vals = pd.to_numeric(text.where(text != ""), errors="coerce")
        _first_bad(
            vals.isna() & (text != ""),
            path,
            first,
            c,
            "a number or an empty cell (missing)",
            lambda i, text=text: f"value {text.iloc[i]!r} is not a number",
        )
        out[c] = vals.astype(float)
    for s in SERIES:
        _first_bad(
            out[s.value].notna() & ~(out[s.sd] > 0),
            path,
            first,
            s.sd,
            "SD > 0 wherever the value is present",
            lambda i, s=s: f"{s.value} is given without a positive standard deviation",
        )
    par = SERIES[0].value
    _first_bad(out[par] < 0, path, first, par, "PAR ≥ 0", lambda i: "negative PAR")
    out = out.set_index(pd.DatetimeIndex(out.pop("time")).rename("time_utc")).sort_index()
    out.attrs = {"provenance": meta["provenance"], "source": str(path), "metadata": meta}
    return out


def _first_bad(bad: pd.Series, path: Path, first: int, column: str, expected: str, problem) -> None:
    """:class:`InputError` at the first data row where ``bad`` holds; ``problem(i)`` describes row i."""
    if bad.any():
        i = int(np.flatnonzero(bad.to_numpy())[0])
        raise InputError(problem(i), file=path, row=first + i, column=column, expected=expected)


def write_observations(df: pd.DataFrame, path: str | Path, metadata: dict[str, str]) -> Path:
    """Write observations (index: tz-aware times) with ``# key: value`` metadata incl. provenance."""
    if metadata.get("provenance") not in ("measured", "synthetic", "reconstructed"):
        raise InputError("metadata must state provenance", column="provenance", expected="measured or synthetic")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    body = df[list(COLUMNS)].copy()
    body.insert(0, "time", df.index.tz_convert("UTC").strftime("%Y-%m-%dT%H:%M:%SZ"))
    head = "".join(f"# {k}: {v}\n" for k, v in {**metadata, "time_zone": "UTC"}.items())
    path.write_text(head + body.to_csv(index=False, float_format="%.6g", lineterminator="\n"), encoding="utf-8")
    return path


def align(obs: pd.DataFrame, times: pd.DatetimeIndex) -> dict[str, np.ndarray]:
    """Observations on the run's time steps: values and SDs (NaN where missing) per step.

    Each observation goes to the nearest step; observations more than half a step away from
    every step raise. Several in one step are averaged, SD of the mean = √(Σ sd²) / n.
    """
    step = (times[1] - times[0]) if len(times) > 1 else pd.Timedelta("30min")
    o_t = obs.index.tz_convert("UTC").tz_localize(None).to_numpy()
    m_t = times.tz_convert("UTC").tz_localize(None).to_numpy()
    idx = np.abs(o_t[:, None] - m_t[None, :]).argmin(1)
    dist = np.abs(o_t - m_t[idx])
    far = dist > step.to_timedelta64() / 2
    if far.any():
        raise InputError(
            f"observation at {obs.index[far][0].isoformat()} lies outside the run "
            f"({times[0].isoformat()} … {times[-1].isoformat()})",
            file=obs.attrs.get("source"),
            column="time",
            expected="observation times within the simulated window",
        )
    out = {}
    for v, sd in ((s.value, s.sd) for s in SERIES):
        val = np.full(len(times), np.nan)
        err = np.full(len(times), np.nan)
        for k in np.unique(idx):
            sel = (idx == k) & obs[v].notna().to_numpy()
            if sel.any():
                val[k] = obs[v].to_numpy()[sel].mean()
                err[k] = np.sqrt((obs[sd].to_numpy()[sel] ** 2).sum()) / sel.sum()
        out[v], out[sd] = val, err
    return out
