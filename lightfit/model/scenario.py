r"""What a coupled run needs besides the calibrated parameters: the :class:`Scenario`, and the
per-step :class:`Forcing` the observation operator reads from its weather.

A step is *daytime* (rendered) when :math:`\mathrm{DNI} + \mathrm{DHI} > 0` and the sun is above
−1° elevation, or in civil twilight (the sun above :data:`TWILIGHT_SUN_MIN_DEG`, −6°) with diffuse
light, DHI > 0: the sky alone lights the canopy then, the sun's part is 0 below the horizon
(:func:`daytime`); night steps get zero light. The weather's DNI and DHI are turned
into photon fluxes by :func:`lightfit.weather.solar.par_direct_diffuse`: scaled to the measured PAR
where the series has a PAR sensor, else 0.50 × 4.57 = 2.285 µmol J⁻¹, with PAR's diffuse fraction
from global radiation's (Spitters et al. 1986).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from dataclasses import dataclass
from dataclasses import field as dc_field

import numpy as np
import pandas as pd

from lightfit.defaults import DARK_FLOOR, DEFAULT_PARAMETER_SET, DEFAULT_RAYS_PER_M2, MAX_ADAPTIVE_SAMPLES, SKY_MODELS
from lightfit.errors import InputError, check_real
from lightfit.light.estimator import bounces_for_tolerance, check_bounces, check_run_samples, check_target_rse
from lightfit.light.leaf_optics import DEFAULT_PRESET
from lightfit.light.projection import check_rays
from lightfit.light.scene import Optics, check_sky
from lightfit.model.parameters import Theta
from lightfit.photosynthesis import PARAMETER_SET_NAMES, parameter_set
from lightfit.photosynthesis.canopy import check_profile, profile_for, resolve_kn
from lightfit.photosynthesis.model import INPUT_RANGES, RH_RANGE
from lightfit.photosynthesis.parameters import check_overrides, growth_temperature_setting, with_overrides
from lightfit.plant import Field
from lightfit.plant.field import Tile
from lightfit.weather.solar import par_direct_diffuse

#: Weather columns a scenario needs (a contract series with solar columns).
WEATHER_COLUMNS = (
    "sun_elevation_deg",
    "sun_azimuth_deg",
    "dni_w_m2",
    "dhi_w_m2",
    "tair_c",
    "rh",
    "pair_kpa",
    "co2_ppm",
)


#: The range of each weather column a run takes, (lo, hi, what): the drivers' ranges are those the leaf
#: solve accepts (:data:`~lightfit.photosynthesis.model.INPUT_RANGES`; leaf temperature = air
#: temperature); light and the sun's position as a contract series has them.
WEATHER_RANGES = {
    "sun_elevation_deg": (-90.0, 90.0, "a sun elevation in [−90, 90]°"),
    "sun_azimuth_deg": (-np.inf, np.inf, "a finite sun azimuth, degrees"),
    "dni_w_m2": (0.0, np.inf, "a direct normal irradiance ≥ 0 W m⁻²"),
    "dhi_w_m2": (0.0, np.inf, "a diffuse horizontal irradiance ≥ 0 W m⁻²"),
    "tair_c": (
        *INPUT_RANGES["tleaf_c"][:2],
        "an air temperature in [{lo:g}, {hi:g}] °C (the leaves' too, as modelled)",
    ),
    "rh": RH_RANGE,
    "pair_kpa": INPUT_RANGES["pair_kpa"],
    "co2_ppm": INPUT_RANGES["co2_umol_mol"],
}


def check_weather_values(weather: pd.DataFrame) -> None:
    """Every value of :data:`WEATHER_COLUMNS` finite and in :data:`WEATHER_RANGES`, else
    :class:`InputError` naming the column, the first bad step and how many there are. The readers
    check files (:func:`lightfit.weather.read_weather`); a series built in code meets this instead,
    where a NaN DNI would have made a midday step night and a NaN air temperature an error of the
    leaf solve's ``tleaf_c`` after the plants grew."""
    for col, (lo, hi, what) in WEATHER_RANGES.items():
        v = pd.to_numeric(weather[col], errors="coerce").to_numpy(np.float64)
        bad = ~(np.isfinite(v) & (v >= lo) & (v <= hi))
        if bad.any():
            i = int(np.argmax(bad))
            raise InputError(
                f"weather value {v[i]:g} at {weather.index[i]} ({int(bad.sum())} such step(s))",
                column=col,
                expected=what.format(lo=lo, hi=hi),
            )


#: Lowest sun elevation, degrees, at which a step's diffuse light is rendered: the end of civil
#: twilight. Below it the clear sky gives under ≈ 0.1 µmol m⁻² s⁻¹ of PAR, far below any leaf's
#: light compensation point, and a radiation sensor's reading there is its offset, not light (the
#: readers keep small positive night readings): rendering it would spend a render on every night step.
TWILIGHT_SUN_MIN_DEG = -6.0
#: :func:`daytime` in words, for messages (a Unicode minus in both angles, as the messages write one:
#: the second read "-6°" with the hyphen of :g beside "−1°").
DAYTIME_RULE = (
    "DNI + DHI > 0 with the sun above −1°, or DHI > 0 with the sun above "
    + f"{TWILIGHT_SUN_MIN_DEG:g}°".replace("-", "−")
)


def daytime(weather: pd.DataFrame) -> np.ndarray:
    """Steps the coupled model renders (bool, (T,)): DNI + DHI > 0 with the sun above −1° elevation
    (where refraction already shows the disc), or DHI > 0 with the sun above
    :data:`TWILIGHT_SUN_MIN_DEG` (civil twilight: the sky alone lights the canopy, and the sun's
    part is 0 below the horizon). A twilight step with diffuse light was left dark before, so its
    plants got no light under the above-canopy PAR of the forcing."""
    w = weather
    el = w["sun_elevation_deg"].to_numpy()
    lit = ((w["dni_w_m2"] + w["dhi_w_m2"]) > 0).to_numpy() & (el > -1)
    return lit | ((w["dhi_w_m2"] > 0).to_numpy() & (el > TWILIGHT_SUN_MIN_DEG))


@dataclass(frozen=True)
class Forcing:
    """Per-step inputs of the observation operator, float64 arrays of shape (T,).

    Attributes:
        day: :func:`daytime` mask.
        dni_par, dhi_par: direct-normal and diffuse PAR photon flux, µmol m⁻² s⁻¹
            (:func:`~lightfit.weather.solar.par_direct_diffuse`: the measured PAR, its diffuse
            fraction Spitters' from the global radiation's split).
        tair_c: air temperature (= leaf temperature, a documented simplification), °C.
        co2_ppm: air CO2 (= CO2 at the leaf surface), µmol mol⁻¹.
        rh: relative humidity, 0–1. pair_kpa: air pressure, kPa.
    """

    day: np.ndarray
    dni_par: np.ndarray
    dhi_par: np.ndarray
    tair_c: np.ndarray
    co2_ppm: np.ndarray
    rh: np.ndarray
    pair_kpa: np.ndarray

    @staticmethod
    def of(weather: pd.DataFrame) -> Forcing:
        w, dt = weather, np.float64
        par = w["par_umol_m2_s"] if "par_umol_m2_s" in w else None
        dni_par, dhi_par = par_direct_diffuse(w["dni_w_m2"], w["dhi_w_m2"], w["sun_elevation_deg"], par)
        return Forcing(
            day=daytime(w),
            dni_par=dni_par,
            dhi_par=dhi_par,
            tair_c=w["tair_c"].to_numpy(dt),
            co2_ppm=w["co2_ppm"].to_numpy(dt),
            rh=w["rh"].to_numpy(dt),
            pair_kpa=w["pair_kpa"].to_numpy(dt),
        )


def check_ceptometer_height(h) -> float:
    """The ceptometer's height above the soil, m: 0 … :data:`MAX_CEPTOMETER_HEIGHT_M`."""
    expected = f"a height above the soil in metres, 0 … {MAX_CEPTOMETER_HEIGHT_M}"
    return check_real(h, "ceptometer_height_m", 0, MAX_CEPTOMETER_HEIGHT_M, expected=expected)


def check_seed(seed) -> int:
    """The render seed (the estimator's common random numbers): an integer in [0, 2³²)."""
    from lightfit.light.keyed_random import check_seed as check_render_seed

    return check_render_seed(seed, column="render_seed")


#: The values of a scenario's choices (what PAR at the plants means, what canopy An refers to).
CHOICES = {"par_kind": ("incident", "absorbed"), "an_per": ("leaf", "ground")}


def check_choice(name: str, value) -> str:
    """``value`` if it is one of :data:`CHOICES` ``[name]``, else :class:`InputError` naming it."""
    if value not in CHOICES[name]:
        raise InputError(f"{name}={value!r}", parameter=name, expected=" or ".join(repr(c) for c in CHOICES[name]))
    return value


#: Highest ceptometer a scenario accepts, m (well above any wheat canopy: a typo guard).
MAX_CEPTOMETER_HEIGHT_M = 10.0


def sun_positions_deg(weather: pd.DataFrame) -> np.ndarray:
    """(T, 2) sun elevation and azimuth of the weather's steps, degrees (its solar columns)."""
    return np.column_stack([weather["sun_elevation_deg"], weather["sun_azimuth_deg"]]).astype(np.float64)


def adaptive_limits() -> dict:
    """What bounds adaptive sampling besides its target (results attributes, the render cache
    key): the cap :data:`MAX_ADAPTIVE_SAMPLES` and the light floor
    :data:`~lightfit.defaults.DARK_FLOOR`."""
    return {"max_samples": MAX_ADAPTIVE_SAMPLES, "dark_floor": DARK_FLOOR}


def check_allocate_at(value) -> tuple:
    """``(leaf (3,) in [0, 1], sun_deg (2,) finite, dni_par ≥ 0, dhi_par ≥ 0, not both 0)`` as
    floats, else :class:`InputError` naming ``allocate_at``."""
    expected = (
        "(leaf: 3 numbers in [0, 1], sun_deg: elevation and azimuth in degrees, dni_par ≥ 0, dhi_par ≥ 0, not both 0)"
    )
    try:
        leaf, sun, dni, dhi = value
        leaf = tuple(float(x) for x in np.asarray(leaf, np.float64).reshape(3))
        sun = tuple(float(x) for x in np.asarray(sun, np.float64).reshape(2))
        dni, dhi = float(dni), float(dhi)
    except (TypeError, ValueError) as e:
        raise InputError(f"allocate_at={value!r}", parameter="allocate_at", expected=expected) from e
    ok = all(0 <= x <= 1 for x in leaf) and all(np.isfinite(sun)) and dni >= 0 and dhi >= 0 and dni + dhi > 0
    if not (ok and np.isfinite(dni) and np.isfinite(dhi)):
        raise InputError(f"allocate_at={value!r}", parameter="allocate_at", expected=expected)
    return leaf, sun, dni, dhi


#: Soil (and root) respiration of the chamber footprint at :data:`SOIL_RESPIRATION_T_REF_C`
#: (R₁₀), µmol m⁻² ground s⁻¹, for the chamber NEE (:func:`lightfit.model.observe.soil_respiration`).
#: lightfit models neither, so the default adds nothing; a user comparing with a chamber on soil
#: gives a value (``Scenario.soil_respiration_umol_m2_s``, ``--soil-respiration``).
SOIL_RESPIRATION_UMOL_M2_S = 0.0
#: Temperature sensitivity of soil respiration, the factor per 10 K: ≈ 2 for soils of temperate
#: croplands (Raich & Schlesinger 1992, Tellus 44B:81; Davidson & Janssens 2006, Nature 440:165).
SOIL_RESPIRATION_Q10 = 2.0
#: Reference temperature of :data:`SOIL_RESPIRATION_UMOL_M2_S`, °C (R₁₀, Lloyd & Taylor 1994).
SOIL_RESPIRATION_T_REF_C = 10.0
#: Q₁₀ accepted: 1 (no temperature dependence) to 5, beyond the range soils show (≈ 1.3–3.5 at
#: temperate temperatures; Lloyd & Taylor's 1994 fit implies 3.3–4.4 between −5 and 10 °C).
SOIL_RESPIRATION_Q10_RANGE = (1.0, 5.0)
#: Highest R₁₀ accepted, µmol m⁻² ground s⁻¹: a typo guard. Soil (and root) respiration of arable
#: soils at 10 °C is ≈ 0.5–10 µmol m⁻² s⁻¹ (Raich & Schlesinger 1992; Davidson & Janssens 2006; the
#: summer peaks of manured, irrigated croplands, ≈ 15–20 at 20–25 °C, are ≈ 10 at 10 °C): 100 is
#: ten times the top of that range. Beyond any bound, 1e308 made the chamber NEE infinite.
MAX_SOIL_RESPIRATION_UMOL_M2_S = 100.0


def check_soil_respiration(r10, q10) -> tuple[float, float]:
    """``(R₁₀ in [0, :data:`MAX_SOIL_RESPIRATION_UMOL_M2_S`], Q₁₀ in :data:`SOIL_RESPIRATION_Q10_RANGE`)``
    as floats, else :class:`InputError` naming the parameter."""
    r10 = check_real(
        r10,
        "soil_respiration_umol_m2_s",
        0,
        MAX_SOIL_RESPIRATION_UMOL_M2_S,
        expected="soil respiration at 10 °C in µmol m⁻² s⁻¹, a number in "
        f"[0, {MAX_SOIL_RESPIRATION_UMOL_M2_S:g}] (CO2 released; arable soils ≈ 0.5–10)",
    )
    lo, hi = SOIL_RESPIRATION_Q10_RANGE
    return r10, check_real(
        q10, "soil_respiration_q10", lo, hi, expected=f"a factor per 10 K in [{lo:g}, {hi:g}] (1: constant)"
    )


#: Values of :attr:`Scenario.direct` (``"auto"`` resolves by the field's boundary).
DIRECT_CHOICES = ("auto", "projection", "paths")


def projected_rays(direct: str, rays_per_m2) -> list[float] | None:
    """The projection's (sun, sky) rays per m² of ground as a record states them (a JSON list), for
    a resolved ``direct`` (:func:`resolve_direct`); ``None`` where the paths carry the direct light:
    they cast no projected rays, and results, cache keys and recorded settings leave them out."""
    return list(rays_per_m2) if direct == "projection" else None


def resolve_direct(direct: str, boundary: str) -> str:
    """``direct`` (:data:`DIRECT_CHOICES`) for a field with ``boundary``: ``"auto"`` → projection in
    a periodic field, paths in a finite one; projection in a finite field is refused."""
    if direct not in DIRECT_CHOICES:
        raise InputError(f"direct={direct!r}", parameter="direct", expected=" or ".join(map(repr, DIRECT_CHOICES)))
    if direct == "auto":
        return "projection" if boundary == "periodic" else "paths"
    if direct == "projection" and boundary != "periodic":
        raise InputError(
            f"direct='projection' with a {boundary} field",
            parameter="direct",
            expected="a periodic field (boundary 'periodic'), or direct 'paths' (or 'auto')",
        )
    return direct


#: The main job's samples per segment K for each resolved direct light (:func:`main_job_samples`).
MAIN_JOB_SAMPLES = {"projection": 32, "paths": 64}


def main_job_samples(direct: str) -> int:
    """Samples per segment K of the main job (``ReplicationConfig(samples=None)``) for a resolved
    ``direct``: 32 with the projection, which leaves the paths only light scattered twice and more
    (K = 64 gave the 20 April run's plant-PAR and canopy-An Monte Carlo SD within 0.2 % of K = 32's,
    for ≈ 1.3× the time: docs/light-sampling.md, "The soil's light, and fewer continued rays"); 64 with the
    paths, which carry all the light."""
    return MAIN_JOB_SAMPLES[direct]


#: Share of light the default bounces may truncate (``Scenario.bounces`` and
#: ``ReplicationConfig.bounces`` ``None``). The default leaf absorbs 90 %, so 2 orders suffice: at
#: 12:00 on 20 April the canopy-total absorbed PAR is 0.14 % (default field) / 0.3 % (quick) below
#: its 8-bounce value (experiments/defaults_check.py).
BOUNCE_TOLERANCE = 0.01


#: The run settings :func:`check_settings` checks: a :class:`Scenario`'s, and under the same names a
#: :class:`lightfit.replication.ReplicationConfig`'s (which checks them when it is made).
SETTINGS = (
    "samples",
    "bounces",
    "seed",
    "target_rse",
    "direct",
    "direct_rays_per_m2",
    "ceptometer_height_m",
    "photosynthesis",
    "growth_temperature_c",
    "photosynthesis_overrides",
    "vcmax_profile",
    "par_kind",
    "an_per",
    "sky",
    "soil_respiration_umol_m2_s",
    "soil_respiration_q10",
)


def check_set_name(name) -> str:
    """A photosynthesis parameter set's name (:data:`~lightfit.photosynthesis.PARAMETER_SET_NAMES`),
    else :class:`InputError` naming ``photosynthesis``."""
    if name not in PARAMETER_SET_NAMES:
        raise InputError(
            f"photosynthesis={name!r}", parameter="photosynthesis", expected=" or ".join(PARAMETER_SET_NAMES)
        )
    return name


def run_params(photosynthesis: str, growth_temperature_c: float | None, overrides=()):
    """The :class:`~lightfit.photosynthesis.PhotosynthesisParams` a run takes: the set
    ``photosynthesis`` at its growth temperature, with the run's ``overrides``
    (:func:`~lightfit.photosynthesis.parameters.with_overrides`)."""
    return with_overrides(parameter_set(photosynthesis, growth_temperature_c), overrides)


def kn_of(vcmax_profile, photosynthesis: str, growth_temperature_c: float | None, overrides=()) -> float:
    """kn (per unit LAI) of ``vcmax_profile`` for the set ``photosynthesis`` at its growth temperature
    with ``overrides`` (:func:`run_params`; :func:`~lightfit.photosynthesis.canopy.resolve_kn`; 0: uniform)."""
    return resolve_kn(
        profile_for(vcmax_profile, photosynthesis), run_params(photosynthesis, growth_temperature_c, overrides)
    )


def check_settings(*, boundary: str, **settings) -> dict:
    """The :data:`SETTINGS` checked and normalised (``direct`` resolved for ``boundary``; ``bounces``
    ``None`` left to the leaf's rule): :class:`InputError` naming the first one a run would refuse,
    before any plant grows. The one list of these checks, for :class:`Scenario` and for
    :class:`lightfit.replication.ReplicationConfig`."""
    out = dict(settings)
    out["samples"] = check_run_samples(settings["samples"], settings["target_rse"])
    if settings["bounces"] is not None:
        out["bounces"] = check_bounces(settings["bounces"])
    if settings["target_rse"] is not None:
        out["target_rse"] = check_target_rse(settings["target_rse"])
    out["direct"] = resolve_direct(settings["direct"], boundary)
    out["direct_rays_per_m2"] = check_rays(settings["direct_rays_per_m2"])
    check_ceptometer_height(settings["ceptometer_height_m"])
    check_sky(settings["sky"])
    check_seed(settings["seed"])
    check_choice("par_kind", settings["par_kind"])
    check_choice("an_per", settings["an_per"])
    out["vcmax_profile"] = check_profile(settings["vcmax_profile"])
    name = check_set_name(settings["photosynthesis"])
    t_g = out["growth_temperature_c"] = growth_temperature_setting(name, settings["growth_temperature_c"])
    overrides = out["photosynthesis_overrides"] = check_overrides(settings["photosynthesis_overrides"])
    # refused before plants grow, as is a growth temperature the set does not take or a value outside
    # its parameter's domain
    kn_of(out["vcmax_profile"], name, t_g, overrides)
    out["soil_respiration_umol_m2_s"], out["soil_respiration_q10"] = check_soil_respiration(
        settings["soil_respiration_umol_m2_s"], settings["soil_respiration_q10"]
    )
    return out


@dataclass
class Scenario:
    """Everything a forward run needs besides the calibrated parameters.

    Attributes:
        weather: contract series with solar columns at the run's time steps (e.g.
            ``weather.window(df, "2016-04-20 05:00", 14, "30min")``).
        field: the field (plants, boundary and buffers, seed, growth). Default: 9 plants in a
            periodic cell (the measurement area one cell of an infinite field, no edge bias;
            docs/light.md, "Periodic boundary"); the reference paper's finite field with buffer
            rows is ``Field(..., boundary="finite")``.
        samples, bounces, seed: irradiance estimator settings (seed: common random numbers).
            ``bounces`` ``None`` (default): as many scattering orders as keep the truncated light
            under :data:`BOUNCE_TOLERANCE` for ``optics`` (2 for the default leaf, 8 for the grey
            one; :func:`~lightfit.light.estimator.bounces_for_tolerance`). Resolved at construction
            (like ``direct``): ``dataclasses.replace(sc, optics=...)`` keeps the number, so pass
            ``bounces=None`` with new optics to have it chosen again.
        target_rse: ``None`` (default): every measured segment gets ``samples`` points. A number
            in (0, 1): the per-segment relative standard error of absorbed PAR to reach, the
            accuracy knob traded against time (adaptive sampling,
            :class:`~lightfit.light.estimator.AdaptiveEstimator`; docs/light.md, "Adaptive
            sampling to a target error"); ``samples`` is then the starting count of every
            segment (at least 32) and :data:`MAX_ADAPTIVE_SAMPLES` the cap.
        allocate_at: where adaptive sampling chooses each segment's K: ``None`` (default) the
            daytime step with the highest sun of this scenario's weather, with its default leaf
            (:attr:`~lightfit.model.coupled.CoupledModel.allocation_point`); or ``(leaf (3,),
            sun_deg (2,), dni_par, dhi_par)``. A distributed run gives its time chunks the whole
            run's point, so that every chunk allocates alike.
        direct: where the renders' unscattered light (direct sun, directly seen sky) comes from:
            ``"projection"`` (periodic fields: rays cast down over the cell,
            :mod:`lightfit.light.projection`; same expectation as the paths, a fraction of their
            variance: docs/light-sampling.md, "Direct light by projection"), ``"paths"`` (each sample
            point's own shadow ray and first ray; what finite fields need), or ``"auto"``
            (default): projection where the field is periodic, paths where it is finite.
            Resolved at construction (the attribute then names the one used).
        direct_rays_per_m2: ``direct="projection"``: its rays per m² of ground, ``(sun, sky)``
            or one number for both (default :data:`lightfit.defaults.DEFAULT_RAYS_PER_M2`).
        ceptometer_height_m: height of the default virtual line quantum sensor (ceptometer,
            :func:`lightfit.light.sensors.default_sensors`) above the soil, m: 0 (default) reads
            the PAR transmitted to the soil, a height inside the canopy the PAR transmitted to it.
        photosynthesis: parameter-set name (``lightfit.photosynthesis.parameter_set``).
        growth_temperature_c: Kattge & Knorr's (2007) growth temperature T_g, the mean air
            temperature of the month before the run (°C), for sets that acclimate to it
            (``winter_wheat``); ``None`` (default): the set's own, 15 °C
            (:data:`~lightfit.photosynthesis.parameters.ACCLIMATING_SETS`).
        photosynthesis_overrides: numbers of the set replaced, a mapping name → value (e.g.
            ``{"vcmax_ref_umol_m2_s": 85, "a1": 4.5}``: a measured Vcmax at the set's reference
            temperature and Medlyn's g1), names from
            :data:`~lightfit.photosynthesis.parameters.OVERRIDABLE`; stored as sorted (name, value)
            pairs. Applied after the growth temperature (:func:`run_params`). Default none.
        vcmax_profile: photosynthetic capacity through the canopy (:mod:`lightfit.photosynthesis.canopy`):
            ``"lloyd2010"`` (Vcmax, Jmax, Rd fall as exp(−kn·L) with the leaf area L above a blade,
            kn from the set's Vcmax25 after Lloyd et al. 2010: 0.23 for ``winter_wheat``),
            ``"depury1997"`` (kn = 0.713 of de Pury & Farquhar's wheat canopy),
            ``"uniform"`` (every blade the set's capacity, as the reference paper), kn itself (a
            number in [0, 2] per unit LAI; 0 is ``"uniform"``), or ``"auto"`` (default): the set's own
            (:data:`~lightfit.photosynthesis.canopy.SET_PROFILES`: Lloyd's for ``winter_wheat``,
            uniform for the CPlantBox-derived sets; :meth:`kn` resolves it).
        par_kind: ``"incident"`` or ``"absorbed"`` PAR for the plant-PAR observable.
        an_per: ``"leaf"`` (per one-sided leaf area) or ``"ground"`` (per ground area of the
            measured plants) for canopy net CO2 uptake.
        optics: soil albedo, base colour and the BSDF parameters used to freeze sampling.
            Default: ``Optics.preset("prospect")``, the PROSPECT-D wheat leaf (PAR absorptance
            0.90; docs/light.md, "Leaf optics"); ``Optics.preset("paper")`` is the reference
            paper's grey 0.5 leaf. The leaf parameters rendered are the run's ``Theta``; its
            defaults for these optics are :attr:`theta` (``Theta.for_optics``).
        sky: ``"isotropic"`` or ``"overcast"``.
        soil_respiration_umol_m2_s, soil_respiration_q10: the soil's (and roots') respiration at
            10 °C, µmol m⁻² ground s⁻¹ (default 0: not modelled), and its Q₁₀ (default 2), added
            at each step's air temperature to the chamber NEE observable only
            (:func:`lightfit.model.observe.soil_respiration`). Take it from bare-soil readings, or
            from night readings minus the leaves' dark respiration that the model adds itself,
            brought to 10 °C: a reading R at air temperature T gives R / Q₁₀^((T − 10)/10).
        n_tiles, tile: run only tile ``tile`` of ``field.tiles(n_tiles)`` (its plants measured,
            its buffer ring as geometry); ``None`` runs the whole measurement area.
    """

    weather: pd.DataFrame
    field: Field = dc_field(default_factory=lambda: Field(n_plants=9, seed=1, boundary="periodic"))
    samples: int = 32
    bounces: int | None = None
    seed: int = 0
    target_rse: float | None = None
    allocate_at: tuple | None = None
    direct: str = "auto"
    direct_rays_per_m2: tuple[float, float] | float = DEFAULT_RAYS_PER_M2
    ceptometer_height_m: float = 0.0
    photosynthesis: str = DEFAULT_PARAMETER_SET
    growth_temperature_c: float | None = None
    photosynthesis_overrides: tuple[tuple[str, float], ...] = ()
    vcmax_profile: str | float = "auto"
    par_kind: str = "absorbed"
    an_per: str = "ground"
    optics: Optics = dc_field(default_factory=lambda: Optics.preset(DEFAULT_PRESET))
    sky: str = SKY_MODELS[0]
    soil_respiration_umol_m2_s: float = SOIL_RESPIRATION_UMOL_M2_S
    soil_respiration_q10: float = SOIL_RESPIRATION_Q10
    n_tiles: int = 1
    tile: int | None = None

    def __post_init__(self):
        if self.bounces is None:
            self.bounces = bounces_for_tolerance(BOUNCE_TOLERANCE, self.optics)
        # The estimator's own checks, here before plants grow.
        for k, v in check_settings(**{k: getattr(self, k) for k in SETTINGS}, boundary=self.field.boundary).items():
            setattr(self, k, v)
        if self.allocate_at is not None:
            self.allocate_at = check_allocate_at(self.allocate_at)
        if self.tile is not None and not 0 <= self.tile < self.n_tiles:
            raise InputError(f"tile={self.tile!r}", parameter="tile", expected=f"0 … {self.n_tiles - 1} or None")
        missing = set(WEATHER_COLUMNS) - set(self.weather.columns)
        if missing:
            raise InputError(
                f"weather lacks {sorted(missing)}",
                parameter="weather",
                expected="a contract series with solar columns (lightfit.weather.add_solar)",
            )
        check_weather_values(self.weather)

    @property
    def theta(self):
        """Default parameters of this scenario: the leaf parameters of its optics, the rest Theta's."""
        return Theta.for_optics(self.optics)

    def kn(self) -> float:
        """kn (per unit LAI) of :attr:`vcmax_profile` for :attr:`photosynthesis`
        (:func:`~lightfit.photosynthesis.canopy.resolve_kn`; 0: uniform)."""
        return kn_of(self.vcmax_profile, self.photosynthesis, self.growth_temperature_c, self.photosynthesis_overrides)

    def photosynthesis_params(self):
        """The run's :class:`~lightfit.photosynthesis.PhotosynthesisParams`: the set at the growth
        temperature (:attr:`growth_temperature_c`) with :attr:`photosynthesis_overrides`."""
        return run_params(self.photosynthesis, self.growth_temperature_c, self.photosynthesis_overrides)

    @property
    def measured_tile(self) -> Tile | None:
        """The tile this scenario measures (``None``: the whole measurement area)."""
        return None if self.tile is None else self.field.tiles(self.n_tiles)[self.tile]

    @property
    def ground_area_m2(self) -> float:
        """Ground area of the measured plants, m² (the denominator of canopy An per ground)."""
        return self.field.measured_area_m2(self.measured_tile)

    def digest(self) -> dict[str, str]:
        """A hash per field of what a run of this scenario computes from (weather rows and
        columns; field, optics, numbers and names by their repr, which is their value). Per field,
        so that a field added later (absent from a stored digest) can be told apart and a refusal
        can name what changed. Used to refuse resuming a calibration of other settings and to
        reuse a field-run's finished tasks. ``growth``: the growth parameter file's contents and
        CPlantBox's version (:meth:`~lightfit.plant.growth.GrowthConfig.fingerprint`; the field's
        repr names the file only), absent from digests stored before it was added, which are then
        compared without it."""
        # The profile the run uses: "auto" means another profile for another set.
        profile = digest_of(profile_for(self.vcmax_profile, self.photosynthesis))
        return settings_digest(self) | {"growth": self.field.growth.fingerprint(), "vcmax_profile": profile}


#: Scenario settings added after digests were first stored whose absence from a stored digest
#: means a value other than today's default (before capacity profiles every blade was the set's).
DIGEST_WHEN_ABSENT = {"vcmax_profile": "uniform", "growth_temperature_c": None}


def digest_of(value) -> str:
    """One setting's digest, as :func:`settings_digest` hashes it (its repr, which is its value)."""
    return _sha(repr(value).encode())


def settings_digest(settings) -> dict[str, str]:
    """:meth:`Scenario.digest` of any dataclass of settings."""
    out = {}
    for f in dataclasses.fields(settings):
        v = getattr(settings, f.name)
        if isinstance(v, pd.DataFrame):
            rows = pd.util.hash_pandas_object(v, index=True).to_numpy()
            out[f.name] = _sha(rows.tobytes(), json.dumps([str(c) for c in v.columns]).encode())
        else:
            out[f.name] = digest_of(v)
    return out


def _sha(*parts: bytes) -> str:
    h = hashlib.sha256()
    for b in parts:
        h.update(len(b).to_bytes(8, "little") + b)  # lengths: parts cannot run into each other
    return h.hexdigest()[:16]


__all__ = [
    "DIRECT_CHOICES",
    "MAX_ADAPTIVE_SAMPLES",
    "adaptive_limits",
    "sun_positions_deg",
    "Forcing",
    "Scenario",
    "WEATHER_COLUMNS",
    "daytime",
    "TWILIGHT_SUN_MIN_DEG",
    "DAYTIME_RULE",
    "main_job_samples",
    "resolve_direct",
]
