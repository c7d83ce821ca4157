"""Observations: a CSV whose columns name the quantity each instrument measured, with their SDs.

Format (UTF-8 CSV; ``#`` metadata lines first, ``provenance`` required)::

    # provenance: measured            (or synthetic, reconstructed)
    # time_zone: Europe/Berlin        (zone of the times: an IANA name, UTC or UTC±H; required when a
                                      time has no offset, and a time's offset must agree with it)
    # time_label: instant             (optional; or start / center / end of means)
    # averaging_interval: 30min       (with start / center / end: the means' interval)
    # canopy_an_per: ground           (optional; or leaf: the area canopy An is per, as the run's an_per)
    time,above_canopy_par_umol_m2_s,above_canopy_par_sd_umol_m2_s
    2016-04-20 12:13:48,1549.31,77.47

Each observed quantity is a pair of columns, its value and its measurement standard deviation
(same unit), named after the coupled model's observable it is compared with (:data:`SERIES`,
operators in :mod:`lightfit.model.observe`). A file has any non-empty subset of these pairs:

============================  ==============================  ============  ==========================================
series (``--use``)            value column (SD: ``*_sd*``)    unit          what the instrument measures
============================  ==============================  ============  ==========================================
``above_canopy_par``          ``above_canopy_par_umol_m2_s``  µmol m⁻² s⁻¹  horizontal quantum sensor above the canopy
                                                                            (a station's or a chamber's PAR sensor)
``plant_par``                 ``plant_par_umol_m2_s``         µmol m⁻² s⁻¹  PAR at the plants: area-mean incident or
                                                                            absorbed PAR per one-sided area of the
                                                                            measured segments (run option ``par_kind``);
                                                                            no single instrument reads this
``canopy_apar``               ``canopy_apar_umol_m2_s``       µmol m⁻² s⁻¹  PAR absorbed by the canopy per ground area
                                                                            (e.g. above-canopy PAR × fAPAR)
``fapar``                     ``fapar``                       1             fraction of absorbed PAR, APAR / PAR above
                                                                            the canopy on a horizontal plane
``canopy_an``                 ``canopy_an_umol_m2_s``         µmol m⁻² s⁻¹  canopy net CO2 uptake of the leaf blades,
                                                                            per ground area (or leaf area: ``an_per``)
``nee``                       ``nee_umol_m2_s``               µmol m⁻² s⁻¹  chamber net ecosystem CO2 exchange per
                                                                            ground area, positive = CO2 released
``transmitted_par``           ``transmitted_par_umol_m2_s``   µmol m⁻² s⁻¹  line quantum sensor (ceptometer) on the soil
                                                                            under the canopy, mean over its placements
``ceptometer_transmittance``  ``ceptometer_transmittance``    1             canopy PAR transmittance, ceptometer below
                                                                            ÷ reading above the canopy
``ceptometer_fapar``          ``ceptometer_fapar``            1             fAPAR from a ceptometer, 1 − transmittance
                                                                            (one-sensor approximation)
============================  ==============================  ============  ==========================================

The short names ``par`` and ``an`` of earlier versions mean ``plant_par`` and ``canopy_an``.
Empty cells are missing observations (a row may have some quantities only). Every present value
needs its SD (> 0); fractions (unit 1) are refused beyond ±:data:`MAX_FRACTION` (a percentage
such as 94 is not a fraction); a quantity given twice at one time is refused (two
instruments may share a time on their own rows). CO2 fluxes beyond ±:data:`MAX_CO2_FLUX` are
refused (another unit); ones in mg CO2 m⁻² s⁻¹, 1 / 22.7 of µmol m⁻² s⁻¹ and inside that bound,
are cautioned where a run meets them with its forcing (:func:`co2_unit_caution`) or its model
(:func:`unit_slip_caution`, also for light in W m⁻²), through :func:`observation_cautions`.

Time zone. Times with an offset (``2016-04-20T12:13:48+02:00``, ``…Z``) are read as written; times
without one need the ``# time_zone`` line (e.g. ``Europe/Berlin`` for a chamber log kept in local
time, ``UTC``): a file without it is refused rather than read in a guessed zone.

Times. A row's time is an instant (a chamber closure, a spot reading) unless ``# time_label`` says
that the rows are means over ``# averaging_interval`` stamped at its start, centre or end (an eddy
covariance system's 30-min NEE, a logger's 10-min PAR), in the same convention as a weather
series (:mod:`lightfit.weather.timestamps`). :func:`align` assigns each observation to the run's
step whose *centre* is nearest the observation's centre, so a spot reading at 12:13:48 goes to the
10-min mean stamped 12:20 (its interval holds 12:13:48), not to the one stamped 12:10; several in
one step are averaged (the reference paper averaged too), weighted by their inverse variances (the
plain mean and sd/√n for equal SDs). A mean over more than a step stands for is refused, and so
is one that straddles two steps' intervals: run the model at the observation's interval instead
(``--step``, ``--how mean``). Against a run on instants, an instant between two steps meets the
model interpolated linearly in time between them (:func:`interpolation`, :func:`read_between`).
Files with the names before issue 12 (``par_umol_m2_s`` …) and unknown columns are refused with
a message naming the known columns.

Area of canopy An. A chamber's canopy An is per ground area, which a file means by default; a
``# canopy_an_per: leaf`` line says its values are per one-sided leaf area. A model run whose
``an_per`` is the other area is refused (:func:`check_an_area`): at LAI 4 the two differ 4×.

Other metadata keys (``# site: …``, ``# source: …``) are free and not read, unless one resembles a
key the reader knows and holds a value that key takes (:data:`METADATA_KEYS`, e.g. ``# an_per: leaf``
or ``# timezone: UTC``): that is refused naming the key it resembles (:func:`check_metadata_keys`),
as a typo would otherwise change the data's meaning unsaid. A note that only resembles a key
(``# canopy: winter wheat``, ``# provenance_note: …``) stays free.
"""

from __future__ import annotations

import hashlib
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from lightfit.errors import InputError, listed
from lightfit.files import replace_text
from lightfit.light.bsdf import LEAF_PARAMETERS
from lightfit.model.scenario import CHOICES, DAYTIME_RULE, daytime
from lightfit.weather import timestamps
from lightfit.weather.readers import (
    METADATA_VALUES,
    PROVENANCES,
    check_aware_index,
    check_metadata_keys,
    first_bad_row,
    metadata_lines,
    one_of,
    parse_times,
    read_csv_with_metadata,
    zone,
)
from lightfit.weather.series import cell_numbers
from lightfit.weather.timestamps import INSTANTS, Timestamps
from lightfit.weather.units import UMOL_PER_JOULE_PAR


@dataclass(frozen=True)
class Series:
    """One observed quantity: its short name (``--use``), the column/observable key of its values,
    the column of its measurement SD, the forward model's key of its Monte Carlo SD, its unit, what
    it is, and the model parameters its observable depends on (``depends_on``, names of
    :data:`lightfit.model.parameters.NAMES`; ``tests/test_observations_depend.py`` checks them
    against the gradients): a likelihood of other series is flat along the rest."""

    name: str
    value: str
    sd: str
    mc_sd: str
    unit: str = "umol m-2 s-1"
    meaning: str = ""
    nonnegative: bool = False
    depends_on: tuple[str, ...] = ()
    incident: bool = False  # read from incident light (a ceptometer), not absorbed: see dependencies()
    #: Largest |value| a reading may have in ``unit``: finite for the CO2 fluxes only (beyond it the
    #: file is in another unit, :data:`MAX_CO2_FLUX`; the message says which).
    max_abs: float = float("inf")


#: Largest |CO2 flux| an observations file may give, µmol m⁻² s⁻¹ (canopy net uptake, NEE). No crop
#: canopy comes near it: irrigated maize, a C4 crop among the most productive, peaks at ≈ 50–60
#: µmol m⁻² s⁻¹ of net uptake (eddy covariance, Suyker et al. 2004, Agric. For. Meteorol. 124, 1–13),
#: C3 wheat lower (this model's default field: ≈ 40 at noon). Beyond it a file is in another unit:
#: mg CO2 m⁻² h⁻¹ is 158 × µmol m⁻² s⁻¹ (44.01 µg µmol⁻¹ × 3 600 s), nmol 1 000 ×; fitted as given,
#: such readings drove vcmax_scale to 5.6 with only generic cautions (a newcomer review).
MAX_CO2_FLUX = 100.0
_CO2_UNIT = "a CO2 flux in umol m-2 s-1 (mg CO2 m-2 h-1 is 158 x that, nmol 1000 x)"


# What each observable depends on (Series.depends_on). Light at the plants depends on the leaf and
# scales with the forcing's light (light_factor); ratios of two lights do not (it cancels); only
# CO2 fluxes see the photosynthetic capacity (vcmax_scale); the sensor above the canopy sees the
# sky alone.
_LIGHT = (*LEAF_PARAMETERS, "light_factor")
_RATIO = LEAF_PARAMETERS
_CO2 = (*LEAF_PARAMETERS, "light_factor", "vcmax_scale")

#: The observable quantities, in likelihood order.
SERIES = (
    Series(
        "plant_par",
        "plant_par_umol_m2_s",
        "plant_par_sd_umol_m2_s",
        "plant_par_mc_sd_umol_m2_s",
        meaning="area-mean incident or absorbed PAR at the measured plants",
        depends_on=_LIGHT,
        nonnegative=True,
    ),
    Series(
        "canopy_an",
        "canopy_an_umol_m2_s",
        "canopy_an_sd_umol_m2_s",
        "canopy_an_mc_sd_umol_m2_s",
        meaning="canopy net CO2 uptake of the measured leaf blades",
        depends_on=_CO2,
        max_abs=MAX_CO2_FLUX,
    ),
    Series(
        "above_canopy_par",
        "above_canopy_par_umol_m2_s",
        "above_canopy_par_sd_umol_m2_s",
        "above_canopy_par_mc_sd_umol_m2_s",
        meaning="PAR on a horizontal quantum sensor above the canopy",
        depends_on=("light_factor",),
        nonnegative=True,
    ),
    Series(
        "canopy_apar",
        "canopy_apar_umol_m2_s",
        "canopy_apar_sd_umol_m2_s",
        "canopy_apar_mc_sd_umol_m2_s",
        meaning="PAR absorbed by the canopy per ground area",
        depends_on=_LIGHT,
        nonnegative=True,
    ),
    Series(
        "fapar",
        "fapar",
        "fapar_sd",
        "fapar_mc_sd",
        unit="1",
        meaning="fraction of absorbed PAR",
        nonnegative=True,
        depends_on=_RATIO,
    ),
    Series(
        "nee",
        "nee_umol_m2_s",
        "nee_sd_umol_m2_s",
        "nee_mc_sd_umol_m2_s",
        meaning="chamber net ecosystem CO2 exchange per ground area (positive: release)",
        depends_on=_CO2,
        max_abs=MAX_CO2_FLUX,
    ),
    Series(
        "transmitted_par",
        "transmitted_par_umol_m2_s",
        "transmitted_par_sd_umol_m2_s",
        "transmitted_par_mc_sd_umol_m2_s",
        meaning="PAR on a line quantum sensor (ceptometer) under the canopy (on the soil or at ceptometer_height_m)",
        depends_on=_LIGHT,
        incident=True,
        nonnegative=True,
    ),
    Series(
        "ceptometer_transmittance",
        "ceptometer_transmittance",
        "ceptometer_transmittance_sd",
        "ceptometer_transmittance_mc_sd",
        unit="1",
        meaning="canopy PAR transmittance from a ceptometer (below / above the canopy)",
        depends_on=_RATIO,
        incident=True,
        nonnegative=True,
    ),
    Series(
        "ceptometer_fapar",
        "ceptometer_fapar",
        "ceptometer_fapar_sd",
        "ceptometer_fapar_mc_sd",
        unit="1",
        meaning="fAPAR from a ceptometer, 1 - transmittance (one-sensor approximation)",
        depends_on=_RATIO,
        incident=True,
    ),
)
BY_NAME = {s.name: s for s in SERIES}


def dependencies(series: Series, *, bounces: int = 1, par_kind: str = "absorbed") -> tuple[str, ...]:
    """The model parameters ``series``' observable depends on in a run with ``bounces`` and
    ``par_kind``: :attr:`Series.depends_on` when light is scattered (bounces ≥ 1). Without
    scattering the leaf acts only through the share it absorbs (its albedo: specular and roughness;
    subsurface only splits scattered light), so series of incident light (the ceptometer's, and
    ``plant_par`` with ``par_kind="incident"``) depend on none of the leaf parameters, and no series on
    subsurface (checked against the gradients in ``tests/test_observations_depend.py``)."""
    if bounces >= 1:
        return series.depends_on
    incident = series.incident or (series.name == "plant_par" and par_kind == "incident")
    drop = set(LEAF_PARAMETERS) if incident else {"subsurface"}
    return tuple(p for p in series.depends_on if p not in drop)


#: Largest |value| a fraction (unit "1": fAPAR, ceptometer transmittance) may have in an
#: observations file: beyond 1 only by measurement noise; a percentage (e.g. 94) is refused.
MAX_FRACTION = 1.5

#: SDs an observation may have, in its value's units: beyond them its inverse-variance weight
#: (SD⁻², :func:`_per_step`) or a residual over it squared (the likelihood's χ²) leaves float64, and
#: the reading became NaN and dropped out of the fit unsaid (a review: SD 1e200).
SD_RANGE = (1e-100, 1e100)
#: Metadata line naming the area canopy An is per (:func:`check_an_area`), and its values.
AN_PER_KEY = "canopy_an_per"
AN_AREAS = CHOICES["an_per"]
#: The metadata keys :func:`read_observations` reads, each with a test of its values; any other key is
#: free (not read), unless it resembles one of these with a value it takes
#: (:func:`~lightfit.weather.readers.check_metadata_keys`).
METADATA_KEYS = METADATA_VALUES | {AN_PER_KEY: one_of(*AN_AREAS)}
#: Short names of earlier versions.
ALIASES = {"par": "plant_par", "an": "canopy_an"}
COLUMNS = tuple(c for s in SERIES for c in (s.value, s.sd))
#: Column names before the observables were renamed (issue 12), and their new names.
RENAMED = {
    "par_umol_m2_s": "plant_par_umol_m2_s",
    "par_sd_umol_m2_s": "plant_par_sd_umol_m2_s",
    "an_umol_m2_s": "canopy_an_umol_m2_s",
    "an_sd_umol_m2_s": "canopy_an_sd_umol_m2_s",
}


def series(name: str) -> Series:
    """The :class:`Series` of a short name (or its alias ``par``/``an``); :class:`InputError` otherwise."""
    s = BY_NAME.get(ALIASES.get(name, name))
    if s is None:
        raise InputError(f"use={name!r}", parameter="use", expected="series names " + ", ".join([*BY_NAME, *ALIASES]))
    return s


def observed(obs: pd.DataFrame) -> tuple[str, ...]:
    """Short names of the series with at least one value in ``obs``, in :data:`SERIES` order."""
    return tuple(s.name for s in SERIES if s.value in obs.columns and obs[s.value].notna().any())


def reading_rules(s: Series) -> list[tuple[str, object, str, object]]:
    """The rules every present reading of ``s`` obeys, in files (:func:`read_observations`) and in
    tables built in code (:func:`check_sds`) alike: ``(column, bad, expected, problem)``, where
    ``bad(v, sd)`` marks the offending rows of the value and SD arrays (float, NaN where missing;
    only rows with a value are judged) and ``problem(v, sd, i)`` says what row i holds."""

    def sd_given(sd, i):
        return "missing" if np.isnan(sd[i]) else f"{sd[i]:g}"

    rules = [
        (
            s.sd,
            lambda v, sd: ~(np.isfinite(sd) & (sd > 0)),
            "a finite SD > 0 wherever the value is present",
            lambda v, sd, i: f"{s.value} is given without a positive standard deviation (SD {sd_given(sd, i)})",
        ),
        (
            s.sd,
            lambda v, sd: (sd < SD_RANGE[0]) | (sd > SD_RANGE[1]),
            "an SD in [{:g}, {:g}] (its inverse square, the reading's weight, stays a number)".format(*SD_RANGE),
            lambda v, sd, i: f"{s.value}'s standard deviation is {sd[i]:g}",
        ),
    ]
    if s.nonnegative:
        rules.append((s.value, lambda v, sd: v < 0, "a value ≥ 0", lambda v, sd, i: f"negative value of {s.value}"))
    if s.unit == "1":  # a fraction; 94 is a percentage (noise may take a fraction a little past 1)
        rules.append(
            (
                s.value,
                lambda v, sd: np.abs(v) > MAX_FRACTION,
                f"a fraction (|value| ≤ {MAX_FRACTION:g}), not a percentage",
                lambda v, sd, i: f"{s.value} = {v[i]:g}",
            )
        )
    if np.isfinite(s.max_abs):
        rules.append(
            (
                s.value,
                lambda v, sd: np.abs(v) > s.max_abs,
                f"|value| ≤ {s.max_abs:g}: {_CO2_UNIT}",
                lambda v, sd, i: f"{s.value} = {v[i]:g}",
            )
        )
    return rules


def check_sds(obs: pd.DataFrame) -> None:
    """Observations built in code (not read from a file, which :func:`read_observations` checks
    line by line): every present value finite, then :func:`reading_rules` (an SD of 0 makes the
    likelihood infinite, a negative one is no SD). :class:`InputError` naming the column and time."""
    for s in SERIES:
        if s.value not in obs.columns:
            continue
        v = pd.to_numeric(obs[s.value], errors="coerce").to_numpy(float)
        sd = (
            pd.to_numeric(obs[s.sd], errors="coerce").to_numpy(float)
            if s.sd in obs.columns
            else np.full(len(v), np.nan)
        )
        present = ~np.isnan(v)
        rules = [(s.value, lambda v, sd: ~np.isfinite(v), "a finite value", None), *reading_rules(s)]
        for col, bad, expected, _ in rules:
            with np.errstate(invalid="ignore"):
                hit = present & bad(v, sd)
            if hit.any():
                i = int(np.flatnonzero(hit)[0])
                raise InputError(
                    f"{col} at {obs.index[i]}: {obs[col].iloc[i] if col in obs.columns else 'missing'}",
                    file=obs.attrs.get("source"),
                    column=col,
                    expected=expected,
                )


def read_observations(path: str | Path) -> pd.DataFrame:
    """Read an observations CSV into a DataFrame indexed by UTC time (attrs: provenance, source,
    ``timestamps``: the rows' :class:`~lightfit.weather.timestamps.Timestamps`, instants unless the
    file's ``# time_label`` says otherwise)."""
    path = Path(path)
    meta, header_line, df = read_csv_with_metadata(path, "an observations CSV", known_keys=METADATA_KEYS)
    if "time" not in df.columns:
        raise InputError("no 'time' column", file=path, row=header_line, expected="columns time, " + ", ".join(COLUMNS))
    old = [c for c in RENAMED if c in df.columns]
    if old:
        raise InputError(
            "old-style column names " + ", ".join(f"{c} (now {RENAMED[c]})" for c in old),
            file=path,
            row=header_line,
            expected="columns time, " + ", ".join(COLUMNS),
        )
    unknown = [c for c in df.columns if c != "time" and c not in COLUMNS]
    if unknown:
        raise InputError(
            f"unknown column(s) {unknown}",
            file=path,
            row=header_line,
            expected="time and value/SD column pairs of " + ", ".join(COLUMNS),
        )
    present = [s for s in SERIES if s.value in df.columns or s.sd in df.columns]
    missing = [c for s in present for c in (s.value, s.sd) if c not in df.columns]
    if missing or not present:
        raise InputError(
            f"missing column(s) {missing}" if missing else "no observed quantity",
            file=path,
            row=header_line,
            expected="time and at least one value/SD column pair of " + ", ".join(COLUMNS),
        )
    if df.empty:
        raise InputError("no data rows", file=path, row=header_line + 1, expected="at least one row of observations")
    if "time_zone" in meta:  # read as --timezone reads it: an IANA name, UTC or UTC±H
        try:
            meta["time_zone"] = zone(meta["time_zone"], "time_zone")
        except InputError as e:
            raise InputError(e.problem, file=path, column="time_zone", expected=e.expected) from None
    tz = meta.get("time_zone")
    stamps = Timestamps.from_metadata(meta, path)
    an_per = an_area_of(meta, path)
    line = df.attrs["lines"].to_numpy()  # each row's line in the file (blank lines skipped)
    out = pd.DataFrame(index=range(len(df)))
    out["time"] = parse_times(
        df["time"],
        pd.Series(line),
        path,
        "time",
        tz,
        no_zone="a '# time_zone: Europe/Berlin' (or UTC) header line, or times with an offset such as "
        "2016-04-20T12:13:48+02:00",
    )
    for c in (c for s in present for c in (s.value, s.sd)):
        out[c] = cell_numbers(df[c], line, path, c)
    times = pd.DatetimeIndex(out["time"])
    for c in (s.value for s in present):
        # Two values of one quantity stamped alike are a copy slip or a clock fault, not a mean (two
        # instruments may share a time on separate rows, each with its own quantity).
        has = out[c].notna().to_numpy()
        given = times[has]
        if given.duplicated().any():
            t = given[given.duplicated()][0]
            i, j = np.flatnonzero((times == t) & has)[:2]
            raise InputError(
                f"{c} at {df['time'].iloc[j].strip()!r} on line {line[j]} repeats line {line[i]}'s time",
                file=path,
                row=int(line[j]),
                column=c,
                expected="one value of a quantity per time (readings within a step are averaged, at distinct times)",
            )
    # An SD without its value is no reading and is ignored; said (sd_without_value), as it may be a
    # value forgotten (a constant SD column over rows without readings is common, so not refused).
    alone = {s.sd: tuple(int(x) for x in line[out[s.value].isna() & out[s.sd].notna()]) for s in present}
    for s in present:
        v, sd = out[s.value].to_numpy(float), out[s.sd].to_numpy(float)
        for col, bad, expected, problem in reading_rules(s):
            with np.errstate(invalid="ignore"):
                hit = ~np.isnan(v) & bad(v, sd)
            first_bad_row(hit, line, path, col, expected, lambda i, v=v, sd=sd, p=problem: p(v, sd, i))
    if not any(out[s.value].notna().any() for s in present):  # a comparison with nothing in it is a slip
        raise InputError(
            f"no reading: {', '.join(s.value for s in present)} empty in every row",
            file=path,
            expected="at least one value to compare with (an empty cell is a missing reading)",
        )
    for c in COLUMNS:  # absent quantities: all missing, so every reader sees the same columns
        if c not in out:
            out[c] = np.nan
    out["_line"] = line
    out = out.set_index(pd.DatetimeIndex(out.pop("time")).rename("time_utc")).sort_index(kind="stable")
    lines = out.pop("_line").to_numpy()
    out.attrs = {"provenance": meta["provenance"], "source": str(path), "metadata": meta, "timestamps": stamps}
    out.attrs[AN_PER_KEY] = an_per
    # each row's line in the file, for errors found later (align); a tuple, as pandas compares attrs
    # with == (concat), which an array cannot answer
    out.attrs["lines"] = tuple(int(x) for x in lines)
    out.attrs["sd_without_value"] = tuple((c, rows) for c, rows in alone.items() if rows)
    out.attrs["short_rows"] = df.attrs.get("short_rows", ())
    return out


def sd_without_value(obs: pd.DataFrame) -> str | None:
    """A caution naming the file, columns and lines where :func:`read_observations` found an SD
    without its value (ignored: no reading), else ``None``."""
    found = obs.attrs.get("sd_without_value", ())
    if not found:
        return None
    said = "; ".join(f"{c} on {len(rows)} line(s) ({listed(rows)})" for c, rows in found)
    return f"{obs.attrs.get('source', 'observations')}: an SD without its value, ignored (no reading): {said}"


def short_rows(obs: pd.DataFrame) -> str | None:
    """A note naming the file and lines where :func:`read_observations` read a row with fewer cells
    than the header (its last columns: no reading, as a sparse hand-written file means them; a cut
    row means the same unsaid), else ``None``."""
    lines = obs.attrs.get("short_rows", ())
    if not lines:
        return None
    return (
        f"{obs.attrs.get('source', 'observations')}: {len(lines)} row(s) with fewer cells than the header "
        f"(line(s) {listed(lines)}): their last columns are read as no reading"
    )


def an_area_of(meta: dict, file: str | Path | None = None) -> str:
    """The area a file's metadata ``meta`` says its canopy An is per (the ``# canopy_an_per:`` line;
    ``"ground"`` where unsaid), or :class:`InputError` naming ``file`` and the line."""
    an_per = str(meta.get(AN_PER_KEY, "ground")).strip().lower()
    if an_per not in AN_AREAS:
        raise InputError(
            f"{AN_PER_KEY}: {meta[AN_PER_KEY]!r}", file=file, column=AN_PER_KEY, expected=" or ".join(AN_AREAS)
        )
    return an_per


def an_area(obs: pd.DataFrame) -> str:
    """The area ``obs``'s canopy An is per: ``"ground"`` or ``"leaf"`` (attrs ``canopy_an_per``, as
    the file's ``# canopy_an_per:`` line says; ground where unsaid, as a chamber measures)."""
    return obs.attrs.get(AN_PER_KEY, "ground")


#: Metadata lines of an observations file that say what it is, kept in a result fitted to it
#: (:func:`declared`) beside its provenance.
DECLARED_KEYS = ("title", "source", "generator")


def declared(obs: pd.DataFrame) -> dict:
    """What the observations a result was fitted to are, for that result's record (calibration.json,
    a posterior's summary.json): ``observations`` (the file, absolute), ``observations_provenance``
    (its ``# provenance:`` line: measured or synthetic, as results.nc's attribute of that name) and
    ``observations_metadata`` (its ``# title:``, ``# source:``, ``# generator:`` lines, those present):
    a reader of the result alone can tell a fit to a synthetic twin from one to measurements."""
    meta, src = obs.attrs.get("metadata") or {}, obs.attrs.get("source")
    return {
        "observations": str(Path(src).resolve()) if src else None,  # observations made in code: no file
        "observations_provenance": str(obs.attrs.get("provenance", "unstated")),
        "observations_metadata": {k: str(meta[k]) for k in DECLARED_KEYS if meta.get(k)},
    }


def check_an_area(obs: pd.DataFrame, an_per: str) -> None:
    """Refuse observations whose canopy An is per another area than a run's ``an_per`` (``"ground"``
    or ``"leaf"``): compared as they stand, a chamber's per-ground-area uptake met the model's per
    leaf area, ≈ LAI × smaller, unsaid (a review)."""
    col = BY_NAME["canopy_an"].value
    if col in obs and obs[col].notna().any() and an_area(obs) != an_per:
        raise InputError(
            f"canopy An per {an_area(obs)} area (the file's {AN_PER_KEY}"
            + (")" if AN_PER_KEY in obs.attrs.get("metadata", {}) else ", unsaid: a chamber's area)")
            + f" against a run whose An is per {an_per} area",
            file=obs.attrs.get("source"),
            column=col,
            expected=f"the run's --an-per {an_area(obs)}, or readings per {an_per} area with a "
            f"'# {AN_PER_KEY}: {an_per}' line",
        )


def write_observations(df: pd.DataFrame, path: str | Path, metadata: dict[str, str]) -> Path:
    """Write observations (index: tz-aware times) with ``# key: value`` metadata incl. provenance
    and the rows' time label (``attrs["timestamps"]``, instants where absent) and canopy An's area
    (``attrs["canopy_an_per"]``, ground where absent). ``metadata`` may state the time label
    (``time_label``, ``averaging_interval``) and ``canopy_an_per`` of a table whose attrs do not;
    one that contradicts its attrs is refused, naming the key."""
    if metadata.get("provenance") not in PROVENANCES:
        raise InputError("metadata must state provenance", column="provenance", expected="measured or synthetic")
    check_metadata_keys(metadata, METADATA_KEYS)  # a key its reader would refuse
    check_aware_index(df, "table")  # a TypeError/AttributeError before
    path = Path(path)
    stamps, area = timestamps.of(df), an_area(df)
    # What metadata states of the rows is written, not overwritten by the attrs' defaults (a stated
    # 'canopy_an_per: leaf' was written as ground, LAI × off, and a stated 10-min interval beside
    # 'time_label: instant', a file its reader refuses).
    if "time_label" in metadata or "averaging_interval" in metadata:
        said = Timestamps.from_metadata(metadata)
        if "timestamps" not in df.attrs:
            stamps = said
        elif said != stamps:
            raise InputError(
                f"metadata says {said.describe()}, the table's attrs['timestamps'] {stamps.describe()}",
                column="time_label",
                expected="metadata that agrees with the table's time label, or leave it to the attrs",
            )
    if AN_PER_KEY in metadata:
        said_area = an_area_of(metadata)
        if AN_PER_KEY not in df.attrs:
            area = said_area
        elif said_area != area:
            raise InputError(
                f"metadata says canopy An per {said_area} area, the table's attrs['{AN_PER_KEY}'] per {area} area",
                column=AN_PER_KEY,
                expected="metadata that agrees with the table's area, or leave it to the attrs",
            )
    # The reader needs every value column's SD column and an SD > 0 at every value: refused here,
    # naming the column (a value column without its SD raised a bare KeyError).
    no_sd = [s.sd for s in SERIES if s.value in df.columns and s.sd not in df.columns]
    if no_sd:
        raise InputError(
            f"no SD column {', '.join(no_sd)} beside its value column",
            column=no_sd[0],
            expected="each value column with its measurement SD column (same unit): the file format needs both",
        )
    check_sds(df)
    path.parent.mkdir(parents=True, exist_ok=True)
    body = df[[c for s in SERIES if s.value in df.columns for c in (s.value, s.sd)]].copy()
    utc = df.index.tz_convert("UTC")
    # whole seconds unless a time has a fraction (cut, two readings 0.4 s apart read back as one time)
    fraction = (utc != utc.floor("s")).any()
    body.insert(0, "time", utc.strftime("%Y-%m-%dT%H:%M:%S.%fZ" if fraction else "%Y-%m-%dT%H:%M:%SZ"))
    meta = {k: v for k, v in metadata.items() if k not in ("time_label", "averaging_interval", AN_PER_KEY)}
    meta = {**meta, "time_zone": "UTC", **stamps.metadata()}
    if BY_NAME["canopy_an"].value in body:
        meta[AN_PER_KEY] = area
    head = metadata_lines(meta)
    replace_text(path, head + body.to_csv(index=False, float_format="%.6g", lineterminator="\n"))
    return path


def _spacing(times: pd.DatetimeIndex, stamps: Timestamps) -> pd.Timedelta:
    """The run's steps' spacing: the shortest gap between two steps, or for a run of one step a day
    (its steps a day or more apart: several dates cut to one step each) 30 min, or the averaging
    interval if longer, as for a one-step run. A run's steps lie within a day's window, so two steps
    a day apart are never neighbours (the first two steps' gap made readings from 14 hours around
    a one-step day all that step's)."""
    one = max(pd.Timedelta("30min"), stamps.interval or pd.Timedelta(0))
    gap = pd.Series(times).diff().min() if len(times) > 1 else None
    return one if gap is None or gap >= pd.Timedelta("1D") else gap


def with_reading(obs: pd.DataFrame) -> np.ndarray:
    """Rows of ``obs`` with at least one value (a row of empty cells is no observation)."""
    values = [s.value for s in SERIES if s.value in obs.columns]
    return obs[values].notna().any(axis=1).to_numpy() if values else np.zeros(len(obs), bool)


def far_from_steps(obs: pd.DataFrame, times: pd.DatetimeIndex, stamps: Timestamps = INSTANTS) -> np.ndarray:
    """Rows of ``obs`` more than half a step (:func:`align`'s spacing) from the centre of every one of
    the run's steps ``times`` (labelled as ``stamps`` says), whether or not they hold a value; those
    with a value are what :func:`align` refuses."""
    _, dist = nearest_steps(obs, times, stamps)
    return _beyond_half_step(dist, _spacing(times, stamps))


def _beyond_half_step(dist: np.ndarray, spacing: pd.Timedelta) -> np.ndarray:
    return dist > spacing.to_timedelta64() / 2


def align(obs: pd.DataFrame, times: pd.DatetimeIndex, stamps: Timestamps = INSTANTS) -> dict[str, np.ndarray]:
    """Observations on the run's time steps: values and SDs (NaN where missing) per step, for
    every column of :data:`COLUMNS` (all NaN for a quantity ``obs`` does not have).

    ``stamps`` says what the run's ``times`` label (the forcing's
    :class:`~lightfit.weather.timestamps.Timestamps`, e.g. ``model.timestamps``), and
    ``obs.attrs["timestamps"]`` what the observations' do (instants where absent). Each
    observation goes to the step whose centre is nearest its own centre (an instant on the border
    of two intervals goes to the interval that holds it: the later one for start-stamps, the
    earlier otherwise); where that is an instant between two instants, the model is read between
    them (:func:`interpolation`). Raised as :class:`InputError`, naming the file:

    * an observation more than half a step (the steps' spacing; 30 min, or the averaging interval
      if longer, for a one-step run) from every step's centre (:func:`far_from_steps`; a row
      without any value is no observation);
    * means over a longer interval than what a step stands for (its averaging interval; for a run
      on instants, the spacing): the model's value at one step is not their mean;
    * where the run's means tile time, a mean that straddles two of them.

    Several in one step are combined as their inverse-variance weighted mean, SD (Σ sd⁻²)^(-1/2)
    (equal SDs: the plain mean and sd/√n); the plain mean, SD √(Σ sd²)/n, kept 1/25 of the
    information of readings 20 ± 1 and 30 ± 10 in one step.
    """
    spacing = _spacing(times, stamps)
    span = stamps.interval if stamps.interval is not None else spacing
    own = timestamps.of(obs)
    source = obs.attrs.get("source")
    if own.interval is not None and own.interval > span:
        raise InputError(
            f"observations are {own.describe()}, the run's steps {stamps.describe()} "
            f"{spacing / pd.Timedelta(minutes=1):g} min apart",
            file=source,
            column="averaging_interval",
            expected="means over at most what one step stands for (run the model at theirs: --step, --how mean)",
        )
    idx, dist = nearest_steps(obs, times, stamps)
    has = with_reading(obs)
    far = has & _beyond_half_step(dist, spacing)
    if far.any():
        k = int(np.flatnonzero(far)[0])
        lines = obs.attrs.get("lines")
        tz = obs.attrs.get("metadata", {}).get("time_zone")

        def told(t):  # in the file's own zone, as its reader wrote it (UTC said the same in another clock)
            return t.tz_convert(tz).isoformat() if tz and tz != "UTC" else t.isoformat()

        raise InputError(
            f"observation at {told(obs.index[k])} lies outside the run "
            f"({told(times[0])} … {told(times[-1])}, {stamps.describe()})",
            file=source,
            row=int(lines[k]) if lines is not None and len(lines) == len(obs) else None,
            column="time",
            expected="observation times within the simulated window",
        )
    if own.interval is not None and stamps.interval is not None and spacing == stamps.interval:
        straddle = has & (dist > ((stamps.interval - own.interval) / 2).to_timedelta64())
        if straddle.any():
            k = int(np.flatnonzero(straddle)[0])
            raise InputError(
                f"the mean stamped {obs.index[k].isoformat()} ({own.describe()}) straddles two of the "
                f"run's steps ({stamps.describe()})",
                file=source,
                column="time",
                expected="means whose intervals lie within one step's interval",
            )
    out = {}
    for s in SERIES:
        out[s.value], out[s.sd] = _per_step(obs, s, idx, len(times), obs.get(s.value))
    return out


#: Observed light series whose daytime values stand in a known proportion to the forcing's PAR
#: above the canopy: the light above it, at the plants, absorbed by the canopy.
LIGHT_SERIES = ("above_canopy_par", "plant_par", "canopy_apar")
#: The range of an observed light series ÷ the forcing's PAR, median over daylight steps, that is
#: taken for the same unit: below it a value in mmol m⁻² s⁻¹ (10⁻³), above it no PAR of this sky.
#: Wide: a spot reading in a sunfleck against a forcing's mean under broken cloud can be several
#: times it (the bundled chamber record against the CPlantBox day's 20 April forcing: 3.5).
LIGHT_RATIO_RANGE = (0.01, 20.0)
#: Forcing PAR (µmol m⁻² s⁻¹) from which a step counts as daylight for :func:`check_light_scale`.
DAYLIGHT_PAR_UMOL_M2_S = 200.0


def observation_table_digest(obs: pd.DataFrame) -> str:
    """SHA-256 of a whole observation table as the run compares it (:func:`read_observations`, less
    the rows ``--steps`` leaves out): times, every series' values and SDs (used or not: a run is
    refused another table even where it fits only some series).
    The likelihood's :func:`~lightfit.inference.likelihood.observations_digest` covers the used
    series on the run's steps only, and needs the model's steps; this one is known before the plants
    grow."""
    # CSV text at full precision, not pandas' object hash (whose values may change between versions)
    text = pd.DataFrame(obs).to_csv(float_format="%.17g", date_format="%Y-%m-%dT%H:%M:%S.%f%z")
    stamps = timestamps.of(obs)  # how the readings meet the steps: instants, or means stamped where
    text += f"\ntime label: {stamps.label}, interval: {stamps.interval}"
    return hashlib.sha256(b"lightfit observation table v1\n" + text.encode()).hexdigest()


#: How near a step of the forcing a reading must lie for the plausibility checks below to compare it
#: with that step's PAR (the comparisons themselves, :func:`align`, take each step's half step).
NEAR_STEP = np.timedelta64(3600, "s")


def check_light_scale(obs: pd.DataFrame, forcing: pd.DataFrame) -> None:
    """:class:`InputError` naming the observations' file and column where an observed light series
    (:data:`LIGHT_SERIES`) is not on the forcing's scale: the median, over observations whose
    nearest step of ``forcing`` (a weather frame with ``par_umol_m2_s``) is daylight, of value ÷
    forcing PAR outside :data:`LIGHT_RATIO_RANGE`. A file in mmol m⁻² s⁻¹ (a unit slip the weather
    reader refuses in the forcing) otherwise calibrated a light factor of 0.001 with a caution. Also
    refused: a reading of a ratio of light (:data:`RATIO_SERIES`) whose nearest step has no forcing
    PAR (night), where the model's ratio is 0 by convention, not a value (:func:`check_ratios_lit`)."""
    check_ratios_lit(obs, forcing)
    lo, hi = LIGHT_RATIO_RANGE
    for name, (ratio, n) in _light_ratios(obs, forcing).items():
        if not lo <= ratio <= hi:
            raise InputError(
                f"{name} is {ratio:.3g} × the forcing's PAR above the canopy at the {n} daylight "
                "observation(s) (median)",
                file=obs.attrs.get("source"),
                column=BY_NAME[name].value,
                expected=f"µmol m-2 s-1, {lo:g}–{hi:g} × the forcing's PAR (a value in mmol m-2 s-1 is 10⁻³ of it)",
            )


#: Observed series that are ratios of two lights (dimensionless: fAPAR, a ceptometer's τ and fAPAR).
RATIO_SERIES = tuple(s.name for s in SERIES if s.unit == "1")


def check_ratios_lit(obs: pd.DataFrame, forcing: pd.DataFrame) -> None:
    """:class:`InputError` naming the file, line and column of the first reading of a ratio of light
    (:data:`RATIO_SERIES`) that the model would read at a step of ``forcing`` without PAR above the
    canopy: its nearest step, or the neighbour it is interpolated towards between two instants
    (:func:`interpolation`: a reading at dawn between a dark step and a lit one). At night the
    model's ratio is 0 by convention (:func:`lightfit.model.observe.fapar`, no 0/0), so a reading
    there (a logger's fAPAR of 1 in the dark) would weigh in the fit against a number that is not
    the model's, and one read between would meet a share of that 0 (a fAPAR of 0.9 at 06:50 between
    a dark 06:30 and 07:00's 0.94 met 0.63). A step with PAR that is not rendered (the sun below
    :data:`~lightfit.model.scenario.TWILIGHT_SUN_MIN_DEG`, :func:`~lightfit.model.scenario.daytime`:
    a sensor's offset, not light) sends no light to the plants or the ceptometer, so it is dark to
    these readings too; a civil-twilight step with diffuse light is rendered and lit."""
    if "par_umol_m2_s" not in forcing.columns or not len(obs):
        return
    par = forcing["par_umol_m2_s"].to_numpy(float)
    if {"sun_elevation_deg", "dni_w_m2", "dhi_w_m2"} <= set(forcing.columns):
        par = np.where(daytime(forcing), par, 0.0)  # PAR above, but nothing rendered (below civil twilight)
    check_ratios_lit_at(obs, forcing.index, timestamps.of(forcing), par > 0)


def check_ratios_lit_at(obs: pd.DataFrame, times: pd.DatetimeIndex, stamps, lit, step=None) -> None:
    """:func:`check_ratios_lit` at the steps ``times`` (their ``stamps``) whose light is ``lit``
    (bool, one per step): from a forcing's PAR and :func:`~lightfit.model.scenario.daytime` on the
    command line, before the plants grow; from a model's rendered steps (``model.day``) where a
    likelihood is built in code (:meth:`lightfit.inference.likelihood.GaussianLikelihood.of_model`:
    a fAPAR of 0.9 ± 0.05 read at night met 0 and added 324 to χ² unsaid). ``step``: the run's
    forcing step, as the likelihood reads between steps (:func:`interpolation`; ``model.step`` for a
    model cut to its observed steps, whose times are further apart: without it a reading the
    likelihood meets at its lit step was refused as read towards a dark neighbour an hour away)."""
    if not len(obs):
        return
    lit = np.asarray(lit, bool)
    idx, _ = nearest_steps(obs, times, stamps)
    read = interpolation(obs, times, stamps, step)
    dark = ~lit[idx]
    lines = obs.attrs.get("lines")
    for name in RATIO_SERIES:
        col = BY_NAME[name].value
        if col not in obs.columns:
            continue
        nb, w = (a[idx] for a in read[col])  # each row's step's neighbour and weight
        between = (w > 0) & ~lit[nb]
        bad = (dark | between) & obs[col].notna().to_numpy()
        if bad.any():
            k = int(np.flatnonzero(bad)[0])
            where = (
                f"night at its nearest step, {times[idx[k]].isoformat()}"
                if dark[k]
                else f"night at {times[nb[k]].isoformat()}, which the model is read towards from "
                f"{times[idx[k]].isoformat()}"
            )
            raise InputError(
                f"{name} read at {obs.index[k].isoformat()}, where the forcing has no PAR above the canopy "
                f"or the model no light (not rendered: {DAYTIME_RULE}) ({where}): a ratio of light has no value there",
                file=obs.attrs.get("source"),
                row=int(lines[k]) if lines is not None and len(lines) == len(obs) else None,
                column=col,
                expected="ratios of light read in daylight, between steps with PAR above the canopy (leave the "
                "night's cells empty; finer steps, --step, put a reading at dawn or dusk beside lit ones)",
            )


def _light_ratios(obs: pd.DataFrame, forcing: pd.DataFrame) -> dict[str, tuple[float, int]]:
    """Per observed light series (:data:`LIGHT_SERIES`) with a reading near a daylight step of
    ``forcing``: (median of value ÷ the step's forcing PAR, number of readings)."""
    if "par_umol_m2_s" not in forcing.columns or not len(obs):
        return {}
    idx, dist = nearest_steps(obs, forcing.index, timestamps.of(forcing))
    par = forcing["par_umol_m2_s"].to_numpy(float)[idx]
    near = dist <= NEAR_STEP
    out = {}
    for name in LIGHT_SERIES:
        col = BY_NAME[name].value
        if col not in obs.columns:
            continue
        sel = near & (par >= DAYLIGHT_PAR_UMOL_M2_S) & obs[col].notna().to_numpy()
        if sel.any():
            out[name] = (float(np.median(obs[col].to_numpy(float)[sel] / par[sel])), int(sel.sum()))
    return out


#: The range of an above-canopy PAR record ÷ the forcing's PAR, median over daylight steps, that
#: reads as PAR in W m⁻² (:func:`par_unit_caution`): 1 / 4.57 = 0.22 (McCree 1972's µmol J⁻¹,
#: :data:`~lightfit.weather.units.UMOL_PER_JOULE_PAR`), ± the 30 % by which a sensor and a
#: forcing can differ under broken cloud. Inside :data:`LIGHT_RATIO_RANGE`: a caution, not a refusal.
PAR_IN_W_M2_RATIO_RANGE = (0.15, 0.3)


def par_unit_caution(obs: pd.DataFrame, forcing: pd.DataFrame) -> str | None:
    """A caution naming the file and column where an above-canopy PAR record, which a horizontal
    sensor over the canopy should read at about the forcing's PAR, is
    :data:`PAR_IN_W_M2_RATIO_RANGE` × it (median over its daylight readings, as
    :func:`check_light_scale` takes it): PAR in W m⁻², a unit the file's column name does not
    allow but a logger may have written; else ``None``. Fitted as they were, such readings give a
    light factor near 0.22 with nothing else said."""
    ratio = _light_ratios(obs, forcing).get("above_canopy_par")
    lo, hi = PAR_IN_W_M2_RATIO_RANGE
    if ratio is None or not lo <= ratio[0] <= hi:
        return None
    col = BY_NAME["above_canopy_par"].value
    return (
        f"{obs.attrs.get('source', 'the observations')}, column {col!r}: above-canopy PAR is {ratio[0]:.3g} × the "
        f"forcing's PAR at the {ratio[1]} daylight reading(s) (median), where a sensor above the canopy reads "
        f"about 1 ×; PAR in W m⁻² reads {1 / UMOL_PER_JOULE_PAR:.2f} ×: if the column is in W m⁻², multiply it "
        f"by {UMOL_PER_JOULE_PAR:g} (µmol J⁻¹, McCree 1972)"
    )


#: Forcing PAR (µmol m⁻² s⁻¹) above which a green wheat canopy takes up CO2 (:func:`co2_sign_caution`):
#: its light compensation lies near 100–200 at the canopy's respiration (docs/photosynthesis.md).
UPTAKE_PAR_UMOL_M2_S = 800.0
#: The CO2 fluxes whose sign tells uptake from release: the sign of uptake in lightfit's convention,
#: what the caution calls the flux, and the convention's name.
UPTAKE_SIGN = {
    "nee": (-1, "NEE", "micrometeorological sign"),
    "canopy_an": (1, "canopy An", "photosynthesis's sign, NEE's opposite"),
}


def _readings_in_light(
    obs: pd.DataFrame, forcing: pd.DataFrame, col: str, par_min: float
) -> tuple[np.ndarray, np.ndarray]:
    """The finite readings of ``col`` whose nearest step of ``forcing`` (within :data:`NEAR_STEP`) has
    PAR ≥ ``par_min`` µmol m⁻² s⁻¹: a mask over ``obs``' rows and each row's step (index into ``forcing``)."""
    idx, dist = nearest_steps(obs, forcing.index, timestamps.of(forcing))
    par = forcing["par_umol_m2_s"].to_numpy(float)[idx]
    return (dist <= NEAR_STEP) & (par >= par_min) & np.isfinite(obs[col].to_numpy(float)), idx


def co2_sign_caution(obs: pd.DataFrame, forcing: pd.DataFrame, name: str = "nee") -> str | None:
    """A caution naming the file and column where every reading (two or more) of the CO2 flux
    ``name`` (:data:`UPTAKE_SIGN`) at a step of ``forcing`` with PAR above
    :data:`UPTAKE_PAR_UMOL_M2_S` is a release, else ``None``. A green canopy takes up CO2 in such
    light, so a release at every such reading is most likely uptake counted with the other sign:
    NEE is micrometeorological, negative for uptake (Baldocchi 2003), canopy An positive; fitted as
    they were, such readings drove vcmax_scale to 0 with only generic cautions (a review; canopy An
    in NEE's sign passed unsaid until a later one). A caution, not a refusal: a sparse canopy over a
    respiring soil (``--soil-respiration``) can release CO2 by day."""
    uptake, label, convention = UPTAKE_SIGN[name]
    col = BY_NAME[name].value
    if col not in obs.columns or "par_umol_m2_s" not in forcing.columns or not len(obs):
        return None
    sel, _ = _readings_in_light(obs, forcing, col, UPTAKE_PAR_UMOL_M2_S)
    value = obs[col].to_numpy(float)
    if sel.sum() >= 2 and (uptake * value[sel] < 0).all():
        release, taken = ("positive", "negative") if uptake < 0 else ("negative", "positive")
        nearest = value[sel].min() if uptake < 0 else value[sel].max()
        return (
            f"{obs.attrs.get('source', 'the observations')}, column {col!r}: {label} is {release} (a release) at "
            f"all {int(sel.sum())} readings in strong light (forcing PAR ≥ {UPTAKE_PAR_UMOL_M2_S:g} µmol m⁻² s⁻¹; "
            f"{'smallest' if uptake < 0 else 'largest'} {nearest:.3g}); lightfit's {label} is {taken} for uptake "
            f"({convention}): negate the column if the file counts uptake as {release}"
        )
    return None


#: Forcing PAR (µmol m⁻² s⁻¹) from which :func:`co2_unit_caution` judges a CO2 flux's size: full
#: light, where a green wheat canopy's net uptake is near its largest.
BRIGHT_PAR_UMOL_M2_S = 1000.0
#: mg CO2 per µmol CO2 (molar mass 44.01 g mol⁻¹): a flux in mg CO2 m⁻² s⁻¹ is this × the same flux
#: in µmol m⁻² s⁻¹, i.e. 1 / 22.7 of it.
MG_PER_UMOL_CO2 = 0.04401
#: Largest |CO2 flux| (µmol m⁻² s⁻¹, per ground or leaf area) at every reading in full light
#: (:data:`BRIGHT_PAR_UMOL_M2_S`) below which, without the model's values, the readings read as mg
#: CO2 m⁻² s⁻¹ (:func:`co2_unit_caution`): the most productive crop canopies' 50–60 µmol m⁻² s⁻¹
#: (:data:`MAX_CO2_FLUX`) are 2.2–2.6 in mg, this model's wheat field's ≈ 40 at noon 1.8 (the bundled
#: twin: 30–40 at forcing PAR ≥ 1000, 1.3–1.8 in mg), while a green wheat canopy of LAI ≥ 1 takes
#: up ≥ 10 in such light (per leaf area: a dense canopy's 40 over LAI 4–7 is 6–10). A caution, not a
#: refusal: a sparse or senescent canopy, or chamber NEE near its compensation over a respiring
#: soil, can read below it in µmol m⁻² s⁻¹ too.
CO2_IN_MG_MAX = 3.0
#: The fit factor k (model ≈ k × readings, least squares over the readings in full light) that reads
#: as a unit slip, per series, where the model's values are known (:func:`unit_slip_caution`): the
#: slip's factor ± what a model and a field can differ by (a factor 1.5). CO2 fluxes in mg CO2
#: m⁻² s⁻¹ read 1 / 22.7 of µmol m⁻² s⁻¹; PAR in W m⁻² reads 1 / 4.57 (McCree 1972).
UNIT_SLIPS = {
    "canopy_an": (1 / MG_PER_UMOL_CO2, "mg CO2 m⁻² s⁻¹"),
    "nee": (1 / MG_PER_UMOL_CO2, "mg CO2 m⁻² s⁻¹"),
    "plant_par": (UMOL_PER_JOULE_PAR, "W m⁻²"),
    "canopy_apar": (UMOL_PER_JOULE_PAR, "W m⁻²"),
    "transmitted_par": (UMOL_PER_JOULE_PAR, "W m⁻²"),
}
UNIT_SLIP_TOLERANCE = 1.5


def co2_unit_caution(obs: pd.DataFrame, forcing: pd.DataFrame, name: str = "canopy_an") -> str | None:
    """A caution naming the file and column where the CO2 flux ``name`` (``canopy_an`` or ``nee``)
    stays below :data:`CO2_IN_MG_MAX` in size at every reading in full light (forcing PAR ≥
    :data:`BRIGHT_PAR_UMOL_M2_S`): readings in mg CO2 m⁻² s⁻¹ (1 / 22.7 of µmol m⁻² s⁻¹), which pass
    the reader's bound (:data:`MAX_CO2_FLUX`) and were fitted as they were (vcmax_scale driven down
    unsaid); else ``None``. Judged from the forcing alone, before the plants grow; where the model's
    values are known, :func:`unit_slip_caution` judges against them instead."""
    col = BY_NAME[name].value
    if col not in obs.columns or "par_umol_m2_s" not in forcing.columns or not len(obs):
        return None
    sel, _ = _readings_in_light(obs, forcing, col, BRIGHT_PAR_UMOL_M2_S)
    if not sel.any():
        return None
    largest = float(np.abs(obs[col].to_numpy(float)[sel]).max())
    if largest >= CO2_IN_MG_MAX:
        return None
    return (
        f"{obs.attrs.get('source', 'the observations')}, column {col!r}: |{UPTAKE_SIGN[name][1]}| is at most "
        f"{largest:.3g} µmol m⁻² s⁻¹ at the {int(sel.sum())} reading(s) in full light (forcing PAR ≥ "
        f"{BRIGHT_PAR_UMOL_M2_S:g} µmol m⁻² s⁻¹), where a green wheat canopy exchanges ≈ 10–50; in mg CO2 m⁻² s⁻¹ "
        f"such a flux reads 1 / {1 / MG_PER_UMOL_CO2:.1f} of it: if the column is in mg CO2 m⁻² s⁻¹, divide it "
        f"by {MG_PER_UMOL_CO2:g} (mg µmol⁻¹); a sparse or senescent canopy can read this low in µmol m⁻² s⁻¹ too"
    )


def unit_slip_caution(obs: pd.DataFrame, forcing: pd.DataFrame, name: str, model: pd.Series) -> str | None:
    """A caution naming the file and column where the model's values of series ``name``
    (:data:`UNIT_SLIPS`) are k × the readings in full light (least squares, k = Σ m·y / Σ y², over
    the readings whose nearest step of ``forcing`` has PAR ≥ :data:`BRIGHT_PAR_UMOL_M2_S`; ``model``:
    the model's values indexed by the steps' times) with k within :data:`UNIT_SLIP_TOLERANCE` of
    the slip's factor: CO2 fluxes in mg CO2 m⁻² s⁻¹ (22.7), PAR in W m⁻² (4.57); else ``None``."""
    col = BY_NAME[name].value
    if col not in obs.columns or "par_umol_m2_s" not in forcing.columns or not len(obs):
        return None
    sel, idx = _readings_in_light(obs, forcing, col, BRIGHT_PAR_UMOL_M2_S)
    times = pd.DatetimeIndex(model.index)
    times = times.tz_localize("UTC") if times.tz is None else times.tz_convert("UTC")
    at = pd.Series(np.asarray(model, float), index=times).reindex(forcing.index[idx].tz_convert("UTC"))
    m = at.to_numpy(float)
    y = obs[col].to_numpy(float)
    sel &= np.isfinite(m)
    if not sel.any() or not (y[sel] ** 2).sum() > 0:
        return None
    k = float((m[sel] * y[sel]).sum() / (y[sel] ** 2).sum())
    factor, unit = UNIT_SLIPS[name]
    if not factor / UNIT_SLIP_TOLERANCE <= k <= factor * UNIT_SLIP_TOLERANCE:
        return None
    undo = f"divide it by {MG_PER_UMOL_CO2:g} (mg µmol⁻¹)" if factor > 10 else f"multiply it by {factor:g} (µmol J⁻¹)"
    return (
        f"{obs.attrs.get('source', 'the observations')}, column {col!r}: the model's {name} is {k:.3g} × the "
        f"readings at the {int(sel.sum())} reading(s) in full light (forcing PAR ≥ {BRIGHT_PAR_UMOL_M2_S:g} "
        f"µmol m⁻² s⁻¹; least squares); in {unit} they read 1 / {factor:.3g} of µmol m⁻² s⁻¹: if the column is "
        f"in {unit}, {undo}"
    )


def observation_cautions(obs: pd.DataFrame, forcing: pd.DataFrame, model=None) -> list[str]:
    """What to say of observations read against the run's forcing before they are fitted or
    compared: a sign slip in NEE or canopy An (:func:`co2_sign_caution`), above-canopy PAR in W m⁻²
    (:func:`par_unit_caution`), CO2 fluxes in mg CO2 m⁻² s⁻¹ (:func:`co2_unit_caution`). A unit slip
    past doubt is refused instead (:func:`check_light_scale`). ``model``: where the run's model values
    are known (a mapping of value column to a series over the steps' times, e.g. replicate's
    results), the CO2 fluxes and the light at the plants, on the canopy and under it are judged
    against them instead (:func:`unit_slip_caution`)."""
    said = [co2_sign_caution(obs, forcing, name) for name in UPTAKE_SIGN]
    said.append(par_unit_caution(obs, forcing))
    model = {} if model is None else model
    for name in UNIT_SLIPS:
        col = BY_NAME[name].value
        if col in model:
            said.append(unit_slip_caution(obs, forcing, name, model[col]))
        elif name in UPTAKE_SIGN:
            said.append(co2_unit_caution(obs, forcing, name))
    return [c for c in said if c]


def _per_step(obs: pd.DataFrame, s: Series, idx: np.ndarray, n_steps: int, x) -> tuple[np.ndarray, np.ndarray]:
    """Per step (``idx``: each row's step): the inverse-variance weighted mean of ``x`` (a column
    or array over the rows) over the rows with a value of series ``s``, weights ``obs[s.sd]⁻²``, and
    (Σ sd⁻²)^(-1/2); NaN at steps without one (everywhere when ``obs`` lacks the series)."""
    mean, err = np.full(n_steps, np.nan), np.full(n_steps, np.nan)
    if s.value not in obs.columns:
        return mean, err
    x = np.asarray(x, dtype=float)
    for k in np.unique(idx):
        sel = (idx == k) & obs[s.value].notna().to_numpy()
        if sel.any():  # inverse-variance weighted: the mean that keeps all the readings' information
            w = obs[s.sd].to_numpy()[sel] ** -2.0
            mean[k] = (w * x[sel]).sum() / w.sum()
            err[k] = w.sum() ** -0.5
    return mean, err


def interpolation(
    obs: pd.DataFrame, times: pd.DatetimeIndex, stamps: Timestamps = INSTANTS, step: pd.Timedelta | None = None
) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    r"""Where between the run's steps each series' observations lie: per series (value column of
    :data:`SERIES`) the neighbour step n_k and weight w_k ∈ [0, ½] of every step k, so that the model
    read at step k's observations is

    .. math:: \hat m_k = (1 - w_k)\, m_k + w_k\, m_{n_k},

    linear interpolation in time to the observations' (inverse-variance weighted) mean time t̄_k:
    w_k = |t̄_k − t_k| / |t_{n_k} − t_k|, n_k the step on t̄_k's side of t_k. A spot reading 14 min
    after a step of a 30-min run meets the model 14 min after that step, not the step's light (the
    sun moves ≈ 2 % in PAR in that time in the morning).

    Only on a run of instants, where means are read at their intervals' centres too: a 30-min mean
    ending at a step of a 30-min run lies halfway between two steps and meets their average (the
    trapezoid rule's mean over its interval; it met the earlier step, the model 15 min before the
    mean's centre). A run's mean over an interval holds an instant observation in it, and means
    are matched to means (:func:`align`): nothing is interpolated there. No interpolation
    (w_k = 0, n_k = k) where step k has no observation, where t̄_k is step k's time, or where the
    neighbour is missing or further than the run's ``step`` (the run's first and last steps
    outwards, a night or another day between two steps): there the observation meets its nearest
    step, as :func:`align` places it. ``step``: the forcing's (``model.step``: a model cut to the
    steps its observations need keeps it; 0: none is read between steps); ``None``: the shortest
    spacing of ``times`` (:func:`~lightfit.weather.timestamps.step_of`), right for a run that is not
    cut. Call after :func:`align`, which checks the times.
    """
    T = len(times)
    out = {s.value: (np.arange(T), np.zeros(T)) for s in SERIES}
    if T < 2 or stamps.interval is not None:
        return out
    idx, _ = nearest_steps(obs, times, stamps)
    utc = times.tz_convert("UTC")
    t_s = np.asarray((utc - utc[0]).total_seconds(), float)
    step = (timestamps.step_of(times) if step is None else pd.Timedelta(step)).total_seconds()  # 0: none
    centres = timestamps.of(obs).centres(obs.index.tz_convert("UTC"))  # instants: their own times
    offset_s = np.asarray((centres - utc[idx]).total_seconds(), float)
    for s in SERIES:
        nb, w = out[s.value]
        d, _ = _per_step(obs, s, idx, T, offset_s)
        for k in np.flatnonzero(np.isfinite(d) & (np.nan_to_num(d) != 0.0)):
            j = k + (1 if d[k] > 0 else -1)
            if 0 <= j < T and abs(t_s[j] - t_s[k]) <= step * (1 + 1e-9):
                nb[k], w[k] = j, abs(d[k]) / abs(t_s[j] - t_s[k])
    return out


def read_between(x, neighbour, weight, xp=np):
    """A model quantity over the steps (T,) read where the observations are
    (:func:`interpolation`'s ``neighbour`` and ``weight``): (1 − w_k)·x_k + w_k·x_{n_k}, and x_k
    itself at weight 0, whatever x_{n_k} is. ``xp``: numpy or jax.numpy."""
    x = xp.asarray(x)
    return xp.where(weight > 0, (1.0 - weight) * x + weight * x[neighbour], x)


def read_offsets_s(
    obs: pd.DataFrame, times: pd.DatetimeIndex, stamps: Timestamps = INSTANTS, step: pd.Timedelta | None = None
) -> dict[str, np.ndarray]:
    """Per series (short name): the time from each step to where the model is read for its
    observations (:func:`interpolation`), s, signed; 0 at steps read at themselves. Results and
    plots draw an observation at its step's time plus this."""
    utc = times.tz_convert("UTC")
    t_s = np.asarray((utc - utc[0]).total_seconds(), float)
    read = interpolation(obs, times, stamps, step)
    out = {}
    for s in SERIES:
        nb, w = read[s.value]
        out[s.name] = np.where(w > 0, w * (t_s[nb] - t_s), 0.0)
    return out


def interpolated(
    obs: pd.DataFrame,
    times: pd.DatetimeIndex,
    stamps: Timestamps = INSTANTS,
    step: pd.Timedelta | None = None,
    use: Sequence[str] | None = None,
) -> bool:
    """Whether any observation of the series ``use`` (short names; ``None``: all) is read between
    two steps (:func:`interpolation`)."""
    read = interpolation(obs, times, stamps, step)
    return any(read[s.value][1].any() for s in SERIES if use is None or s.name in use)


def observation_matching(
    obs: pd.DataFrame,
    times: pd.DatetimeIndex,
    stamps: Timestamps,
    step: pd.Timedelta | None = None,
    use: Sequence[str] | None = None,
) -> str:
    """How ``obs`` meet a run's steps ``times`` labelled by ``stamps`` (stored with posterior runs and
    calibration states), e.g. ``"instants to ends of 10-min means, by interval centre"``, or, where
    instants lie between instants, ``"instants to instants, interpolated linearly in time"``
    (:func:`interpolation` of the used series ``use``, with the run's ``step``; observations on the
    steps are matched as before it)."""
    how = "interpolated linearly in time" if interpolated(obs, times, stamps, step, use) else "by interval centre"
    return f"{timestamps.of(obs).describe()} to {stamps.describe()}, {how}"


def matched_as_by_stamp(
    obs: pd.DataFrame,
    times: pd.DatetimeIndex,
    stamps: Timestamps,
    step: pd.Timedelta | None = None,
    use: Sequence[str] | None = None,
) -> bool:
    """Whether matching by interval centre gives what matching by stamp (before it) gave: for
    instants on instants, where centres are stamps, none of them read between steps. Runs stored
    before may resume only then."""
    same = timestamps.of(obs).interval is None and stamps.interval is None
    return same and not interpolated(obs, times, stamps, step, use)


def nearest_steps(obs: pd.DataFrame, times: pd.DatetimeIndex, stamps: Timestamps) -> tuple[np.ndarray, np.ndarray]:
    """For each observation, the index of the step (``times`` labelled by ``stamps``) whose centre
    is nearest its own centre, and that distance (timedelta64); of two equally near, the interval
    that holds the instant: the later one for start-stamps, the earlier otherwise."""
    o_t = timestamps.of(obs).centres(obs.index.tz_convert("UTC")).tz_localize(None).to_numpy()
    m_t = stamps.centres(times.tz_convert("UTC")).tz_localize(None).to_numpy()
    if not len(o_t):
        return np.zeros(0, int), np.zeros(0, "timedelta64[ns]")
    d = np.abs(o_t[:, None] - m_t[None, :])
    idx = len(m_t) - 1 - d[:, ::-1].argmin(1) if stamps.label == "start" else d.argmin(1)
    return idx, np.abs(o_t - m_t[idx])
