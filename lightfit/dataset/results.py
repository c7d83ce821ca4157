"""Read a coupled-model results file and rebuild the field it was computed on.

Contract (netCDF, written by the coupled model): dims ``(time, segment)``; coordinate
``segment`` = segment id (int64) and ``plant_id`` along it; data variables of the results
schema (:mod:`lightfit.model.schema`, which gives their units and meaning) such as
``absorbed_par_umol_m2_s``, ``leaf_an_umol_m2_s``, ``leaf_vc_umol_m2_s``, ``leaf_vj_umol_m2_s``,
``leaf_gs_mol_m2_s`` and ``limitation`` (int8: 1 = electron-transport limited, Fj < Fc; 0 = Rubisco
limited); attrs describing the field (``n_plants``, ``buffer_rows``, ``seed``,
``parameter_file``, ``season_start``, ``target_date``, ``row_spacing_m``, ``plant_spacing_m``,
optionally ``row_direction_deg``, ``buffer_along``, ``boundary``: ``"finite"`` when absent,
as files written before the periodic boundary are, ``sheaths``: ``"rods"`` when absent, as
files written before wrapped sheaths are, and ``headings``: ``"aligned"`` when absent, as files
written before plants faced their own ways are; a value that is not a valid setting is an error
naming the file and the attribute). Optional time series ``sun_elevation_deg``,
``sun_azimuth_deg``, ``dni_w_m2``, ``dhi_w_m2`` set the light of the data scene; without them it
comes from a weather series (the bundled one for the target date by default).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from lightfit.dataset.scene import Lighting
from lightfit.defaults import SKY_MODELS
from lightfit.errors import InputError
from lightfit.files import is_netcdf
from lightfit.model import schema
from lightfit.weather.site import localize

#: Short quantity names → results variables (units: :mod:`lightfit.model.schema`).
QUANTITIES = {
    "absorbed_par": "absorbed_par_umol_m2_s",
    "an": "leaf_an_umol_m2_s",
    "vc": "leaf_vc_umol_m2_s",
    "vj": "leaf_vj_umol_m2_s",
    "gs": "leaf_gs_mol_m2_s",
    "limitation": "limitation",
}
#: Derived: (Vj − Vc)/(Vj + Vc), dimensionless in [−1, 1]; > 0 where Fj > Fc (Rubisco limited,
#: red in the gallery), < 0 where Fj < Fc (electron-transport limited, blue) — the divergent
#: scale of the reference paper's Fig. 3.
MARGIN = "limitation_margin"
REQUIRED_ATTRS = ("n_plants", "buffer_rows", "seed")
LIGHT_VARS = ("sun_elevation_deg", "sun_azimuth_deg", "dni_w_m2", "dhi_w_m2")


@dataclass
class Results:
    """A loaded results file.

    Attributes:
        ds: the xarray Dataset (loaded into memory).
        path: where it was read from.
        times: its time coordinate as tz-aware UTC timestamps.
    """

    ds: object
    path: Path | None
    times: pd.DatetimeIndex

    def variable(self, name: str) -> str:
        """The dataset variable of a quantity (short name, full name of a per-segment variable of the
        results schema, or ``limitation_margin``)."""
        full = QUANTITIES.get(name, name)
        # Schema variables only: the labels take their units from it (:meth:`units`), so one outside
        # it was accepted, rendered, and failed on its units once every image was written.
        per_segment = {str(v) for v in self.ds.data_vars if "segment" in self.ds[v].dims and str(v) in schema.VARIABLES}
        if full == MARGIN or full in per_segment:
            return full
        avail = sorted({q for q, v in QUANTITIES.items() if v in per_segment} | per_segment | {MARGIN})
        if full in self.ds.data_vars and "segment" in self.ds[full].dims:
            raise InputError(
                f"quantity {name!r}: results variable {full} is not in the results schema, so the units of "
                "its labels are unknown",
                file=self.path or "results",
                parameter="quantities",
                expected=f"a variable of lightfit.model.schema: one of {', '.join(avail)}",
            )
        if name in QUANTITIES:  # a known quantity these results lack (not a typo)
            raise InputError(
                f"quantity {name!r}: the results have no variable {full}",
                file=self.path or "results",
                parameter="quantities",
                expected=f"one of {', '.join(avail)}",
            )
        raise InputError(f"unknown quantity {name!r}", parameter="quantities", expected=f"one of {', '.join(avail)}")

    def values(self, name: str, time_index: int) -> pd.Series:
        """Per-segment values of a quantity at one time step, indexed by segment id (:meth:`units`)."""
        full = self.variable(name)
        if full == MARGIN:
            vc, vj = (self.values(q, time_index).astype(float) for q in ("vc", "vj"))
            total = vj + vc
            return ((vj - vc) / total.where(total != 0)).rename(MARGIN)
        da = self.ds[full]
        if "time" in da.dims:
            da = da.isel(time=time_index)
        return pd.Series(np.asarray(da.values), index=self.ds["segment"].values.astype(np.int64), name=full)

    def units(self, name: str) -> str:
        """Units of a quantity, from the results schema (``"1"``: dimensionless)."""
        full = self.variable(name)
        return "1" if full == MARGIN else schema.units(full)


def synthetic_values(attrs) -> bool:
    """Whether results attrs say the values are synthetic (:func:`lightfit.dataset.synthetic_results`),
    not a model run."""
    return str(attrs.get("synthetic", "")).lower() in ("1", "true", "yes")


def open_results(source) -> Results:
    """Load a results netCDF (path) or wrap an in-memory ``xarray.Dataset``; check the contract."""
    import xarray as xr

    path = None
    if isinstance(source, (str, Path)):
        path = Path(source)
        if not path.is_file():  # a folder was "not found" too, though it is there (a review of bad input)
            problem = "a folder, not a file" if path.is_dir() else "results file not found"
            raise InputError(problem, file=path, expected="a netCDF written by the coupled model")
        if not is_netcdf(path):  # xarray's own message lists backends and their web pages
            raise InputError("not a netCDF file", file=path, expected="a results.nc written by the coupled model")
        try:
            ds = xr.load_dataset(path)
        except Exception as err:  # noqa: BLE001 - any reader failure is a bad input file
            raise InputError(f"cannot read as netCDF: {err}", file=path, expected="a netCDF results file") from err
    else:
        ds = source
    where = path or "results"
    if "segment" not in ds.coords:
        raise InputError(
            "no 'segment' coordinate", file=where, expected="dims (time, segment) with segment = segment id"
        )
    if "time" not in ds.coords or ds.sizes.get("time", 0) < 1:
        raise InputError("no 'time' coordinate with at least one step", file=where, expected="dims (time, segment)")
    missing = [a for a in REQUIRED_ATTRS if a not in ds.attrs]
    if missing:
        raise InputError(
            f"missing field attribute(s) {missing}",
            file=where,
            expected="attrs n_plants, buffer_rows, seed (and growth settings) describing the field",
        )
    # The labels take their units from the schema: a file saying other units would be labelled wrongly.
    for v in ds.data_vars:
        given = ds[v].attrs.get("units")
        if given is not None and str(v) in schema.VARIABLES and str(given) != schema.units(str(v)):
            raise InputError(
                f"variable {v} in units {given!r}",
                file=where,
                expected=f"{schema.units(str(v))!r}, as lightfit writes it (the labels are in those units)",
            )
    times = pd.DatetimeIndex(ds["time"].values)
    times = times.tz_localize("UTC") if times.tz is None else times.tz_convert("UTC")
    return Results(ds, path, times)


def field_of(res: Results):
    """The :class:`lightfit.plant.Field` described by the results' attrs (``boundary`` included:
    a periodic run is rebuilt as its periodic cell, not as a finite block without buffers; so are
    ``sheaths``: a file without them had CPlantBox's rods): :meth:`Field.from_attrs`."""
    from lightfit.plant import Field

    dates = str(res.ds.attrs.get("target_date", ""))
    if ";" in dates:  # replicate's results of several --date: one field per day
        raise InputError(
            f"results of several days ({dates}): each day has its own plants",
            file=res.path or "results",
            expected="one day's results (run replicate once per --date)",
        )
    return Field.from_attrs(res.ds.attrs, file=res.path)


def build_geometry(res: Results, cache_dir=None):
    """Rebuild the field geometry (plants are deterministic from the seeds; cached on disk).

    Raises :class:`InputError` when the rebuilt field is not the one the results were computed on:
    another growth fingerprint (an edited plant file, another CPlantBox version: the same segment ids,
    other plants), segment ids or plants the rebuild lacks, or segment areas that differ (files
    written before the fingerprint).
    """
    from lightfit.plant import build, one_sided_area_m2

    fld = field_of(res)
    stored, now = res.ds.attrs.get("growth_fingerprint"), fld.growth.fingerprint()
    if stored is not None and str(stored) != now:
        raise InputError(
            f"the results' plants were grown from another plant file or CPlantBox version (growth fingerprint "
            f"{stored}, now {now}): the field rebuilt from its attrs would be another",
            file=res.path or "results",
            expected="the plant parameter file and CPlantBox version of the run (or run the model again)",
        )
    stored, now = res.ds.attrs.get("layout_fingerprint"), fld.layout_fingerprint()
    if stored is not None and str(stored) != now:  # files written before it: the areas below only
        raise InputError(
            f"the results' plants stood or faced otherwise than in the field rebuilt from their attrs "
            f"(layout fingerprint {stored}, rebuilt {now})",
            file=res.path or "results",
            column="layout_fingerprint",
            expected="the attrs of the field the results were computed on (seed, headings, spacings, direction)",
        )
    geom = build(fld, cache_dir=cache_dir)
    ids = res.ds["segment"].values.astype(np.int64)
    unknown = np.setdiff1d(ids, geom.segments["segment_id"].to_numpy())
    if len(unknown):
        raise InputError(
            f"{len(unknown)} segment id(s) of the results are not in the field rebuilt from its attrs "
            f"(e.g. {unknown[:5].tolist()})",
            file=res.path or "results",
            expected="the attrs of the field the results were computed on",
        )
    whole = int(res.ds.attrs.get("tile", -1)) < 0  # a tile's results hold only its own plants
    if whole and "plant_id" in res.ds.coords:
        have = np.unique(res.ds["plant_id"].values.astype(np.int64))
        want = np.sort(geom.plants.loc[geom.plants["measured"], "plant_id"].to_numpy(np.int64))
        if not np.array_equal(have, want):  # e.g. n_plants edited: ids of a 2x2 field exist in a 3x3 one
            raise InputError(
                f"the results hold {len(have)} plants, the field rebuilt from its attrs measures {len(want)}",
                file=res.path or "results",
                expected="the attrs of the field the results were computed on (n_plants, buffers, seed)",
            )
    if "area_m2" in res.ds.coords:
        rebuilt = one_sided_area_m2(geom.segments.set_index("segment_id").loc[ids].reset_index())
        area = res.ds["area_m2"].values.astype(np.float64)
        off = ~np.isclose(area, rebuilt, rtol=1e-6, atol=0.0)
        if off.any():
            i = int(np.flatnonzero(off)[0])
            raise InputError(
                f"{int(off.sum())} segment(s) have another area in the field rebuilt from the results' attrs "
                f"(segment {ids[i]}: {area[i]:.6g} m² in the results, {rebuilt[i]:.6g} m² rebuilt)",
                file=res.path or "results",
                expected="the field the results were computed on (the same plant file, CPlantBox version and attrs)",
            )
    return geom


def select_times(res: Results, times: list[str] | None) -> list[int]:
    """Indices of the requested time steps: ISO timestamps (UTC unless zoned), a bare ``HH:MM`` (the
    site's local time on the results' one day, as the tables and figures label the steps), ``"all"``,
    or ``None`` = the step with the highest sun (or the first step when the sun is unknown)."""
    if not times:
        if "sun_elevation_deg" in res.ds:
            return [int(np.nanargmax(res.ds["sun_elevation_deg"].values))]
        return [int(np.argmax(_sun(res).sun_elevation_deg.to_numpy()))]
    if list(times) == ["all"]:
        return list(range(len(res.times)))
    out, tz = [], _site(res).timezone
    steps = res.times[~res.times.isna()]  # a step without a time can be asked for by no time
    local = steps.tz_convert(tz)
    expected = f"ISO 8601 with its date, e.g. 2016-04-20T10:00 (UTC unless zoned), or HH:MM local time ({tz})"
    for t in times:
        clock = re.fullmatch(r"\s*\d{1,2}:\d{2}(:\d{2})?\s*", str(t))
        # pandas dates a bare time today; a date's month and day may go unpadded (2016-4-20: it was
        # refused as having no date)
        if clock is None and not re.match(r"\s*(\d{4}-\d{1,2}-\d{1,2}|\d{4}-?\d{2}-?\d{2})", str(t)):
            raise InputError(f"time {t!r} has no date and is not HH:MM", parameter="times", expected=expected)
        if clock is not None:  # the site's clock on the results' one day
            days = sorted(set(local.date))
            if len(days) != 1:
                raise InputError(
                    f"time {t!r} has no date and the results span {len(days)} days",
                    parameter="times",
                    expected="a date with it, e.g. 2016-04-20T10:00 (UTC) or 2016-04-20T12:00+02:00",
                )
            t = f"{days[0]} {t.strip()}"
        try:
            ts = pd.Timestamp(t)
        except ValueError as err:
            raise InputError(f"time {t!r} is not a timestamp", parameter="times", expected=expected) from err
        if clock is not None:
            ts = localize(ts, tz, parameter="times")
        ts = ts.tz_localize("UTC") if ts.tz is None else ts.tz_convert("UTC")
        hit = np.flatnonzero(res.times == ts)
        if not len(hit):
            steps_are = (
                f"one of {steps[0]:%Y-%m-%d %H:%M} … {steps[-1]:%H:%M} UTC, {local[0]:%H:%M} … {local[-1]:%H:%M} "
                f"local time ({tz}) ({len(steps)} steps)"
                if len(steps)
                else "a step with a time (the results have none)"
            )
            raise InputError(f"time {ts} is not a step of the results", parameter="times", expected=steps_are)
        out.append(int(hit[0]))
    return list(dict.fromkeys(out))  # a time given twice is one image (it was listed twice, written once)


def _site(res: Results):
    """The run's site from its results attrs (:func:`lightfit.replication.when_attrs`); results
    written before sites were recorded are Selhausen runs."""
    from lightfit.weather.site import Site

    return Site.from_attrs(res.ds.attrs)


def _sun(res: Results) -> pd.DataFrame:
    from lightfit import weather

    return weather.solar_position(res.times, _site(res))


def lighting(res: Results, time_indices: list[int], weather_source: str | None = None) -> list[Lighting]:
    """Sun and sky per selected time step.

    From the results' own ``sun_elevation_deg``, ``sun_azimuth_deg``, ``dni_w_m2``, ``dhi_w_m2``
    when present; otherwise sun angles from the solar position at the site and DNI/DHI from
    ``weather_source`` (a bundled weather name or file; default the bundled series of the
    results' target date), interpolated in time. A ``weather_source`` for results that carry
    their own sun and sky is refused: the images would be lit by another sky than the labels.
    """
    ds = res.ds
    own = _carries_light(res)
    if own and weather_source is not None:
        raise InputError(
            f"weather {weather_source!r} given, but the results carry their own sun and sky "
            f"({', '.join(LIGHT_VARS)}), which lit the labels",
            parameter="weather",
            expected="no weather for these results (it is used only for results without them)",
        )
    if own:
        cols = {v: ds[v].values[time_indices].astype(float) for v in LIGHT_VARS}
    else:
        wx = _weather(res, weather_source)
        t = res.times[time_indices]
        sun = _sun(res).iloc[time_indices]
        joined = wx.index.union(t)
        # Sun angles exact at each step (no interpolation across the azimuth wrap); irradiance
        # interpolated linearly in time between weather records.
        cols = {v: sun[v].to_numpy(dtype=float) for v in LIGHT_VARS[:2]}
        cols |= {
            v: wx[v].reindex(joined).interpolate("time", limit_area="inside").reindex(t).to_numpy(dtype=float)
            for v in LIGHT_VARS[2:]
        }
        if np.isnan(np.concatenate(list(cols.values()))).any():
            raise InputError(
                f"weather {wx.attrs.get('source', weather_source)!r} does not cover the selected times "
                f"{list(t.astype(str))}",
                parameter="weather",
                expected="a series spanning the results' times",
            )
    sky = str(ds.attrs.get("sky", SKY_MODELS[0]))  # the run's sky lit its labels: the images take it too
    return [Lighting(*(float(cols[v][i]) for v in LIGHT_VARS), sky=sky) for i in range(len(time_indices))]


def _carries_light(res: Results) -> bool:
    """Whether the results carry their own sun and sky (:data:`LIGHT_VARS`)."""
    return all(v in res.ds for v in LIGHT_VARS)


def lighting_provenance(res: Results, weather_source: str | None = None) -> dict:
    """Where :func:`lighting`'s sun and sky come from, for a dataset's metadata: the results' own
    variables, or the weather series (its file and provenance) that lit results without them (the
    metadata named only the model run's weather, which had not lit the images; a review)."""
    if _carries_light(res):
        return {"from": "results", "variables": list(LIGHT_VARS)}
    wx = _weather(res, weather_source)
    out = {"from": "weather", "source": str(wx.attrs.get("source")), "provenance": str(wx.attrs.get("provenance"))}
    if wx.attrs.get("date_given"):  # an undated file (a CPlantBox day), placed on the results' target date
        out["placed_on_date"] = str(wx.attrs["date_given"])
    return out


def _weather(res: Results, source: str | None) -> pd.DataFrame:
    """The weather that lights ``res`` (``source`` or its target date's bundled series), read and
    given its solar columns once per results object and source: :func:`lighting` and
    :func:`lighting_provenance` both ask (it was read, and the sun computed, twice per dataset)."""
    read = res.__dict__.setdefault("_weather_read", {})
    if source not in read:
        read[source] = _read_weather(res, source)
    return read[source]


def _read_weather(res: Results, source: str | None) -> pd.DataFrame:
    from lightfit import weather

    date = str(res.ds.attrs.get("target_date", ""))
    if source is None and date not in weather.BUNDLED:
        raise InputError(
            f"the results carry no {', '.join(LIGHT_VARS)} and no weather is bundled for target_date {date!r}",
            parameter="weather",
            expected=f"a weather file or bundled name ({', '.join(weather.BUNDLED)})",
        )
    # The one resolver of weather sources (bundled names and files alike), placed on the run's
    # date if the file is undated, with the run's site for the direct/diffuse split.
    return weather.add_solar(weather.read_source(source or date, date=date or None), _site(res))
