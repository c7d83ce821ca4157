"""The results schema: every variable and coordinate of a coupled run's results (results.nc).

Each entry gives the variable's dimensions and CF-style attributes: ``units`` (UDUNITS strings,
``"1"`` for dimensionless numbers and flags), ``long_name`` and, where the basis of an area flux
matters, a ``comment`` saying which area it is per. Monte Carlo uncertainty is always a standard
deviation (``*_mc_sd_*``), in the unit of the quantity.

Area bases: PAR at a segment is per unit *one-sided* area of that segment (a leaf blade's area,
or the lateral surface of a stem or sheath); leaf photosynthesis is per one-sided leaf area;
canopy net CO2 uptake is per ground area of the measured plants (their number × plant spacing ×
row spacing) or per one-sided leaf area of the measured blades (results attribute ``an_per``);
canopy APAR and chamber NEE are always per ground area of the measured plants; above-canopy PAR
is per unit horizontal area.

:meth:`lightfit.model.coupled.CoupledModel.simulate` writes these attributes (:func:`annotate`),
takes the coordinates along ``segment`` from :func:`segment_coords` and fills the variables of the
leaf blades alone on the other segments with :func:`on_segments`, as the synthetic results do
(:func:`lightfit.dataset.synthetic_results`); readers (:mod:`lightfit.dataset`,
:func:`lightfit.distributed.gather`) take units and meaning from here (:func:`units`), not from
variable names.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lightfit.errors import InputError
from lightfit.plant.growth import centre_height_m, one_sided_area_m2, organ_class

UMOL = "umol m-2 s-1"
#: Several-day results (lightfit.replication.concat_days): each day has its own plants, so a segment has
#: no value at the steps of the other days.
_OTHER_DAYS = "in several-day results also at the steps of another day than the segment's"
_SEGMENT_AREA = (
    "per unit one-sided area of the segment (leaf blade, or stem/sheath lateral surface); NaN " + _OTHER_DAYS
)
_SD_BOUND = (
    "hypot(DNI SE_sun, DHI SE_sky) of the step: an upper bound, without the sun-sky covariance that "
    "reached_rse includes (1.00x at the blades' median, 1.25x at their 90th percentile; docs/model.md)"
)
_LEAF_AREA = f"per unit one-sided leaf area; leaf blades only (NaN elsewhere, {_OTHER_DAYS})"
_CANOPY_AREA = (
    "per unit ground area of the measured plants (an_per = 'ground') or per unit one-sided leaf area "
    "of the measured blades (an_per = 'leaf'), see the attribute an_per"
)
_NEE = (
    "per unit ground area of the measured plants; positive = CO2 released to the air; "
    "soil respiration (attribute soil_respiration_umol_m2_s at 10 degC, times soil_respiration_q10 "
    "per 10 K of air temperature) minus canopy net uptake"
)
_CEPTOMETER = (
    "per unit horizontal area; upward-facing bars across the rows at the height of the results attribute "
    "ceptometer (default on the soil, ceptometer_height_m), mean over the placements; NaN where the run "
    "renders no ceptometer"
)
_PLANT_PAR = "incident or absorbed PAR (attribute par_kind), per unit one-sided segment area, area-weighted"


@dataclass(frozen=True)
class Variable:
    """One results variable: dimensions and CF attributes (``units`` None: none, e.g. time).

    ``off_blade``: for a variable of the leaf blades alone, its value on the other segments (stems,
    sheaths), whose numpy type is the variable's dtype (:func:`on_segments`); None where every
    segment has a value."""

    dims: tuple[str, ...]
    units: str | None
    long_name: str
    comment: str = ""
    flags: str = ""
    off_blade: np.generic | None = None

    def attrs(self) -> dict:
        a = {"long_name": self.long_name}
        if self.units is not None:
            a["units"] = self.units
        if self.comment:
            a["comment"] = self.comment
        if self.flags:
            values, meanings = zip(*(f.split(" ", 1) for f in self.flags.split(", ")))
            # CF 1.x section 3.5: flag_values is a list of the variable's own type, not text; every flag
            # variable is written as int8 (booleans too: lightfit.replication.write_netcdf).
            a["flag_values"] = np.array([int(v) for v in values], dtype=np.int8)
            a["flag_meanings"] = " ".join(m.replace(" ", "_") for m in meanings)
        return a


TS, T, S = ("time", "segment"), ("time",), ("segment",)
_NAN = np.float64(np.nan)

#: Observables of the virtual sensors (:mod:`lightfit.light.sensors`): NaN where a run renders none.
SENSOR_OBSERVABLES = (
    "transmitted_par_umol_m2_s",
    "transmitted_par_mc_sd_umol_m2_s",
    "ceptometer_transmittance",
    "ceptometer_transmittance_mc_sd",
    "ceptometer_fapar",
    "ceptometer_fapar_mc_sd",
)

#: The observation operator's outputs per time step (:mod:`lightfit.model.observe`).
OBSERVABLES = (
    "plant_par_umol_m2_s",
    "plant_par_spread_umol_m2_s",
    "plant_par_mc_sd_umol_m2_s",
    "canopy_an_umol_m2_s",
    "canopy_an_mc_sd_umol_m2_s",
    "above_canopy_par_umol_m2_s",
    "above_canopy_par_mc_sd_umol_m2_s",
    "canopy_apar_umol_m2_s",
    "canopy_apar_mc_sd_umol_m2_s",
    "fapar",
    "fapar_mc_sd",
    "nee_umol_m2_s",
    "nee_mc_sd_umol_m2_s",
    *SENSOR_OBSERVABLES,
)

#: Every variable and coordinate of results.nc.
VARIABLES: dict[str, Variable] = {
    # -- coordinates ------------------------------------------------------------------------
    "time": Variable(T, None, "time (UTC) of the step"),
    "time_bnds": Variable(
        ("time", "bound"),
        None,
        "start and end (UTC) of the interval whose mean the step's weather is",
        comment="CF cell bounds of time (its attribute bounds); present only where the weather holds means "
        "(attribute weather_timestamps); the sun is taken at the interval's centre",
    ),
    "day": Variable(
        T, None, "date of the step's day (plants grown to it), YYYY-MM-DD", comment="several-day results only"
    ),
    "segment": Variable(S, "1", "segment id (CPlantBox shoot segment, stable for a given field)"),
    "plant_id": Variable(S, "1", "plant id of the segment (grid position in the field)"),
    "organ_type": Variable(S, None, "organ of the segment: leaf (blade or sheath) or stem"),
    "area_m2": Variable(S, "m2", "one-sided area of the segment", "blade area, or 2 pi r l for stems and sheaths"),
    "is_blade": Variable(S, "1", "segment is a leaf blade (has photosynthesis)", flags="0 no, 1 yes"),
    "height_m": Variable(S, "m", "height of the segment's centre above the soil", "mean of its end points' z"),
    "leaf_area_above": Variable(
        S,
        "m2 m-2",
        "cumulative leaf area index above the blade segment's centre",
        "one-sided blade area of the grown plants above it per their ground area; NaN for stems and sheaths",
        off_blade=_NAN,
    ),
    "capacity_factor": Variable(
        S,
        "1",
        "photosynthetic capacity per area relative to the parameter set's (Vcmax, Jmax, Rd, g0)",
        "exp(-kn * leaf_area_above), attributes vcmax_profile and kn_per_lai (docs/photosynthesis.md, "
        "Capacity through the canopy); NaN for stems and sheaths",
        off_blade=_NAN,
    ),
    # -- per segment: light -----------------------------------------------------------------
    "incident_par_umol_m2_s": Variable(TS, UMOL, "PAR incident on the segment", _SEGMENT_AREA),
    "absorbed_par_umol_m2_s": Variable(TS, UMOL, "PAR absorbed by the segment", _SEGMENT_AREA),
    "incident_par_mc_sd_umol_m2_s": Variable(
        TS, UMOL, "Monte Carlo standard deviation of incident PAR", _SEGMENT_AREA + "; " + _SD_BOUND
    ),
    "absorbed_par_mc_sd_umol_m2_s": Variable(
        TS, UMOL, "Monte Carlo standard deviation of absorbed PAR", _SEGMENT_AREA + "; " + _SD_BOUND
    ),
    # Adaptive sampling only (attribute target_rse; absent at a fixed K, attribute samples).
    "samples_per_segment": Variable(
        S,
        "1",
        "irradiance sample points of the segment (adaptive sampling to target_rse)",
        "chosen once at the allocation point (highest daytime sun, the scenario's default leaf) and kept; "
        "= attribute max_samples where neither the target nor the light floor was reached "
        "(variable stopped_on_floor)",
    ),
    "reached_rse": Variable(
        S,
        "1",
        "relative Monte Carlo standard error of absorbed PAR reached by adaptive sampling",
        "at the allocation point (highest daytime sun, PAR DNI/DHI of that step: attributes allocation_*; "
        "sun-sky covariance included, so it can be below absorbed_par_mc_sd / absorbed_par there); inf for "
        "segments receiving no light",
    ),
    "stopped_on_floor": Variable(
        S,
        "1",
        "segment done by adaptive sampling's light floor rather than the relative target",
        "its absorbed PAR is below attribute dark_floor times the PAR on a horizontal surface above the "
        "canopy and, after 3 / dark_floor sample points, its absolute Monte Carlo SE is below target_rse "
        "times that floor or it has received no light at all (lightfit.light.estimator.render_adaptive)",
        flags="0 no, 1 yes",
    ),
    # -- per segment: leaf photosynthesis (blades) ------------------------------------------
    "leaf_an_umol_m2_s": Variable(TS, UMOL, "leaf net CO2 assimilation", _LEAF_AREA, off_blade=_NAN),
    "leaf_an_mc_sd_umol_m2_s": Variable(
        TS,
        UMOL,
        "Monte Carlo standard deviation of leaf net CO2 assimilation",
        _LEAF_AREA + "; |dAn/dPAR| times the absorbed-PAR Monte Carlo SD",
        off_blade=_NAN,
    ),
    "leaf_an_mc_bias_umol_m2_s": Variable(
        TS,
        UMOL,
        "expected shift of leaf net CO2 assimilation caused by Monte Carlo noise in absorbed PAR",
        _LEAF_AREA + "; Jensen bias (negative where An saturates), not subtracted from leaf_an",
        off_blade=_NAN,
    ),
    "leaf_gs_mol_m2_s": Variable(
        TS,
        "mol m-2 s-1",
        "stomatal conductance to CO2",
        _LEAF_AREA + "; x 1.6 for water vapour (Medlyn et al. 2011); with the cplantbox and giraud2023 sets CPlantBox's"
        " diagnostic from the gross rate (gs (cs - ci) = An + Rd, docs/photosynthesis.md)",
        off_blade=_NAN,
    ),
    "leaf_ci_umol_mol": Variable(
        TS,
        "umol mol-1",
        "intercellular CO2 mole fraction",
        f"leaf blades only (NaN elsewhere, {_OTHER_DAYS})",
        off_blade=_NAN,
    ),
    "leaf_vc_umol_m2_s": Variable(
        TS,
        UMOL,
        "Rubisco-limited gross CO2 assimilation rate",
        _LEAF_AREA + "; carboxylation minus photorespiratory CO2 release, Vcmax (c - G*) / (c + Km)",
        off_blade=_NAN,
    ),
    "leaf_vj_umol_m2_s": Variable(
        TS,
        UMOL,
        "electron-transport-limited gross CO2 assimilation rate",
        _LEAF_AREA + "; carboxylation minus photorespiratory CO2 release, J (c - G*) / (4 c + 8 G*)",
        off_blade=_NAN,
    ),
    "limitation": Variable(
        TS,
        "1",
        "limiting process of leaf photosynthesis",
        "-1 where not a leaf blade, " + _OTHER_DAYS,
        flags="-1 no value, 0 Rubisco limited, 1 electron transport limited",
        off_blade=np.int8(-1),
    ),
    "converged": Variable(
        TS,
        "1",
        "photosynthesis solver converged",
        "1 where not a leaf blade, " + _OTHER_DAYS,
        flags="0 no, 1 yes",
        off_blade=np.True_,
    ),
    # -- per time: observables (lightfit.model.observe) ---------------------------------------
    "plant_par_umol_m2_s": Variable(T, UMOL, "mean PAR at the measured plants", _PLANT_PAR + " mean over segments"),
    "plant_par_spread_umol_m2_s": Variable(
        T, UMOL, "spread of PAR across the measured plants' segments", _PLANT_PAR + " standard deviation"
    ),
    "plant_par_mc_sd_umol_m2_s": Variable(T, UMOL, "Monte Carlo standard deviation of mean PAR at the plants"),
    "canopy_an_umol_m2_s": Variable(T, UMOL, "net CO2 uptake of the measured leaf blades", _CANOPY_AREA),
    "canopy_an_mc_sd_umol_m2_s": Variable(
        T, UMOL, "Monte Carlo standard deviation of canopy net CO2 uptake", _CANOPY_AREA
    ),
    "canopy_an_mc_bias_umol_m2_s": Variable(
        T,
        UMOL,
        "expected shift of canopy net CO2 uptake caused by Monte Carlo noise in the blades' PAR",
        _CANOPY_AREA + "; Jensen bias, not subtracted from canopy_an (lightfit.model.observe.an_noise_bias)",
    ),
    "above_canopy_par_umol_m2_s": Variable(
        T,
        UMOL,
        "PAR on a horizontal quantum sensor above the canopy (model)",
        "per unit horizontal area; light_factor * (DNI_PAR sin(sun elevation) + DHI_PAR)",
    ),
    "above_canopy_par_mc_sd_umol_m2_s": Variable(
        T, UMOL, "Monte Carlo standard deviation of above-canopy PAR", "zero: analytic, not rendered"
    ),
    "canopy_apar_umol_m2_s": Variable(
        T, UMOL, "PAR absorbed by the measured plants (APAR)", "per unit ground area of the measured plants"
    ),
    "canopy_apar_mc_sd_umol_m2_s": Variable(
        T, UMOL, "Monte Carlo standard deviation of canopy APAR", "per unit ground area of the measured plants"
    ),
    "fapar": Variable(
        T,
        "1",
        "fraction of absorbed PAR",
        "canopy APAR (per unit ground area of the measured plants, attribute ground_area_m2) / PAR on a "
        "horizontal plane above the canopy; 0 at night; at most 1 in a periodic field, but on a finite field "
        "(attribute boundary) it can exceed 1, most at low sun: the measured plants also take light through "
        "the field's sides",
    ),
    "fapar_mc_sd": Variable(T, "1", "Monte Carlo standard deviation of fAPAR"),
    "nee_umol_m2_s": Variable(
        T,
        UMOL,
        "net ecosystem CO2 exchange of the chamber footprint",
        _NEE,
    ),
    "nee_mc_sd_umol_m2_s": Variable(T, UMOL, "Monte Carlo standard deviation of NEE", _NEE),
    "transmitted_par_umol_m2_s": Variable(
        T, UMOL, "PAR on a line quantum sensor (ceptometer) under the canopy or at a height in it", _CEPTOMETER
    ),
    "transmitted_par_mc_sd_umol_m2_s": Variable(
        T, UMOL, "Monte Carlo standard deviation of transmitted PAR", _CEPTOMETER
    ),
    "ceptometer_transmittance": Variable(
        T,
        "1",
        "canopy PAR transmittance read by the ceptometer",
        "transmitted PAR / above-canopy PAR; 0 at night; on a finite field (attribute boundary) light through "
        "the field's sides reaches the bars too, so it reads more than under a field without edges",
    ),
    "ceptometer_transmittance_mc_sd": Variable(T, "1", "Monte Carlo standard deviation of the transmittance"),
    "ceptometer_fapar": Variable(
        T,
        "1",
        "fAPAR from a ceptometer, one-sensor approximation 1 - transmittance",
        "neglects the PAR reflected by canopy and soil (an upward+downward pair would subtract it); 0 at night",
    ),
    "ceptometer_fapar_mc_sd": Variable(T, "1", "Monte Carlo standard deviation of the ceptometer fAPAR"),
    # -- per time: forcing ------------------------------------------------------------------
    "weather_par_umol_m2_s": Variable(
        T,
        UMOL,
        "PAR of the weather series (station quantum sensor or derived from global radiation)",
        "per unit horizontal area; not scaled by light_factor",
    ),
    "dni_w_m2": Variable(T, "W m-2", "direct normal irradiance (weather)", "per unit area normal to the sun"),
    "dhi_w_m2": Variable(T, "W m-2", "diffuse horizontal irradiance (weather)", "per unit horizontal area"),
    "tair_c": Variable(T, "degC", "air temperature (taken as leaf temperature)"),
    "co2_ppm": Variable(T, "ppm", "air CO2 mole fraction (taken as CO2 at the leaf surface)"),
    "rh": Variable(T, "1", "relative humidity (fraction, 0-1)"),
    "pair_kpa": Variable(T, "kPa", "air pressure"),
    "sun_elevation_deg": Variable(
        T,
        "degree",
        "apparent (refraction-corrected) solar elevation angle at the centre of each step's interval",
        "NREL SPA (pvlib) with refraction for the site altitude's standard pressure and 12 degC; at the step's "
        "stamp for instants, else at the centre of the interval it labels (weather_timestamps, time_bnds); "
        "the true (geometric) elevation is lower by the refraction, about 0.5 degree at the horizon",
    ),
    "sun_azimuth_deg": Variable(
        T, "degree", "solar azimuth angle (clockwise from north) at the same instant as sun_elevation_deg"
    ),
    # -- per time: observations added by the replication (lightfit.inference.observations) ----
    "obs_plant_par_umol_m2_s": Variable(T, UMOL, "observed mean PAR at the plants", _PLANT_PAR),
    "obs_plant_par_sd_umol_m2_s": Variable(T, UMOL, "SD stated with the observed PAR at the plants"),
    "obs_canopy_an_umol_m2_s": Variable(T, UMOL, "observed canopy net CO2 uptake", _CANOPY_AREA),
    "obs_canopy_an_sd_umol_m2_s": Variable(T, UMOL, "SD stated with the observed canopy net CO2 uptake"),
    "obs_above_canopy_par_umol_m2_s": Variable(
        T, UMOL, "observed PAR on a horizontal quantum sensor above the canopy", "per unit horizontal area"
    ),
    "obs_above_canopy_par_sd_umol_m2_s": Variable(T, UMOL, "SD stated with the observed above-canopy PAR"),
    "obs_canopy_apar_umol_m2_s": Variable(T, UMOL, "observed canopy APAR", "per unit ground area"),
    "obs_canopy_apar_sd_umol_m2_s": Variable(T, UMOL, "SD stated with the observed canopy APAR"),
    "obs_fapar": Variable(T, "1", "observed fraction of absorbed PAR"),
    "obs_fapar_sd": Variable(T, "1", "SD stated with the observed fAPAR"),
    "obs_nee_umol_m2_s": Variable(T, UMOL, "observed chamber net ecosystem CO2 exchange", _NEE),
    "obs_nee_sd_umol_m2_s": Variable(T, UMOL, "SD stated with the observed NEE"),
    "obs_transmitted_par_umol_m2_s": Variable(
        T, UMOL, "observed PAR on a line quantum sensor on the soil", _CEPTOMETER
    ),
    "obs_transmitted_par_sd_umol_m2_s": Variable(T, UMOL, "SD stated with the observed transmitted PAR"),
    "obs_ceptometer_transmittance": Variable(T, "1", "observed canopy PAR transmittance (ceptometer)"),
    "obs_ceptometer_transmittance_sd": Variable(T, "1", "SD stated with the observed transmittance"),
    "obs_ceptometer_fapar": Variable(T, "1", "observed fAPAR from a ceptometer (1 - transmittance)"),
    "obs_ceptometer_fapar_sd": Variable(T, "1", "SD stated with the observed ceptometer fAPAR"),
}
# Where the model is read for each series' observations (lightfit.inference.observations.interpolation;
# one entry per name of its SERIES, which tests/test_observation_interpolation.py checks).
VARIABLES |= {
    f"obs_{name}_time_offset_s": Variable(
        T,
        "s",
        f"time from the step to where the model is read for the {name} observations",
        "linear interpolation in time between two instants; 0 at the step itself",
    )
    for name in (
        "above_canopy_par",
        "plant_par",
        "canopy_apar",
        "fapar",
        "canopy_an",
        "nee",
        "transmitted_par",
        "ceptometer_transmittance",
        "ceptometer_fapar",
    )
}


def variable(name: str) -> Variable:
    """The schema entry of ``name``; :class:`InputError` for a name outside the schema."""
    try:
        return VARIABLES[name]
    except KeyError:
        raise InputError(
            f"results variable {name!r} is not in the schema",
            column=name,
            expected="a name of lightfit.model.schema.VARIABLES",
        ) from None


def units(name: str) -> str:
    """The units of a results variable (``"1"`` when dimensionless)."""
    return variable(name).units or "1"


def segment_coords(segments) -> dict:
    """The results' coordinates along ``segment`` of a segment table (``FieldGeometry.segments``'
    rows, in their order), for ``xarray.Dataset(coords=...)``: ``segment`` (id), ``plant_id``,
    ``organ_type``, ``area_m2`` (one-sided, m²), ``is_blade`` and ``height_m`` (centre, m).

    Every writer of results takes them from here, so that a synthetic file and a rendered run
    describe the same plants' segments alike (:data:`VARIABLES` gives their attributes)."""
    on_segment = {
        "plant_id": segments["plant_id"].to_numpy(np.int64),
        "organ_type": segments["organ_type"].astype(str).to_numpy(),
        "area_m2": one_sided_area_m2(segments),
        "height_m": centre_height_m(segments),
        "is_blade": organ_class(segments) == "blade",
    }
    return {"segment": segments["segment_id"].to_numpy(np.int64)} | {k: ("segment", v) for k, v in on_segment.items()}


def on_segments(name: str, on_blades, is_blade) -> np.ndarray:
    """A variable of the leaf blades alone on every segment: ``on_blades`` (..., B) its values on
    the blades (``is_blade``'s true segments, in order), its ``off_blade`` value on the others, in
    that value's dtype.

    Every writer of results fills these variables here, so that a synthetic file and a rendered run
    have no value on the same segments, in the same dtype."""
    fill = variable(name).off_blade
    if fill is None:
        raise ValueError(f"{name} has a value on every segment, not on the blades alone")
    is_blade = np.asarray(is_blade, bool)
    on_blades = np.asarray(on_blades)
    out = np.full((*on_blades.shape[:-1], is_blade.size), fill, dtype=np.asarray(fill).dtype)
    out[..., is_blade] = on_blades
    return out


def annotate(ds):
    """``ds`` with the schema's attributes on every variable and coordinate (in place; returned).

    Raises :class:`InputError` for a variable the schema does not know, so that no variable is
    written without units.
    """
    for name in ds.variables:
        ds[name].attrs.update(variable(str(name)).attrs())
    if "time_bnds" in ds.variables:
        ds["time"].attrs["bounds"] = "time_bnds"
    return ds


__all__ = [
    "OBSERVABLES",
    "SENSOR_OBSERVABLES",
    "VARIABLES",
    "Variable",
    "annotate",
    "on_segments",
    "segment_coords",
    "units",
    "variable",
]
