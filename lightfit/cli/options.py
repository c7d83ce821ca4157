"""The options shared by every command that runs the coupled model, and the one place that turns them into a model.

``replicate``, ``calibrate``, ``posterior`` and ``field-run`` are decorated with
:func:`model_options`: each gets the same field / light / photosynthesis / weather / day-and-site options (same
names, same help, same defaults) and receives them as one :class:`ModelOptions` argument.
:func:`resolve` fills what was not given from the main job's configuration
(:class:`lightfit.replication.ReplicationConfig`, or its ``quick()`` size), and
:func:`scenario` builds the :class:`~lightfit.model.scenario.Scenario` from the result.

Defaults are ``None`` here ("not given") so that ``--quick`` can change the size while an
explicit option still wins, e.g. ``--quick --samples 32``.
"""

from __future__ import annotations

import dataclasses
import datetime as dt
import inspect
import json
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Annotated, Any

import typer

# The help texts' values, from the module that imports nothing: the library modules that use them
# import JAX, pvlib and pandas, which the commands import when they run, not for --help.
from lightfit.defaults import (
    DARK_FLOOR,
    DEFAULT_PARAMETER_FILE,
    DEFAULT_PARAMETER_SET,
    DEFAULT_PLANT_SPACING_M,
    DEFAULT_RAYS_PER_M2,
    DEFAULT_ROW_DIRECTION_DEG,
    DEFAULT_ROW_SPACING_M,
    MAX_ADAPTIVE_SAMPLES,
    MAX_BOUNCES_FOR_TOLERANCE,
    MAX_SPACING_M,
    MIN_PILOT,
    SEASON_START_MONTH_DAY,
    SKY_MODELS,
    SOIL_ALBEDO,
)
from lightfit.errors import InputError

if TYPE_CHECKING:
    from lightfit.weather.site import Site, Window

_FIELD, _LIGHT, _PHOTO, _WEATHER, _WHEN = "Field", "Light", "Photosynthesis", "Weather", "Day and site"

#: Help of the field options (shared with the ``field`` command).
ROW_SPACING_HELP = (
    f"Distance between wheat rows, m, at most {MAX_SPACING_M:g} (default {DEFAULT_ROW_SPACING_M:g}: drill rows, "
    "common German practice)."
)
PLANT_SPACING_HELP = (
    f"Distance between plants in a row, m, at most {MAX_SPACING_M:g} (default {DEFAULT_PLANT_SPACING_M:g}: with "
    "the default rows "
    f"{1 / (DEFAULT_ROW_SPACING_M * DEFAULT_PLANT_SPACING_M):.0f} plants m⁻²)."
)
ROW_DIRECTION_HELP = (
    f"Compass azimuth of the rows, degrees in [0, 360) (default {DEFAULT_ROW_DIRECTION_DEG:g} = east–west)."
)
PARAMETER_FILE_HELP = (
    f"CPlantBox plant XML: a bundled name (default {DEFAULT_PARAMETER_FILE}) or a path (./NAME for an edited "
    "copy under a bundled name)."
)
SEASON_START_HELP = (
    "First day of growth, YYYY-MM-DD: sowing, or spring regrowth after a dormant winter (default: "
    f"{dt.date(2016, *SEASON_START_MONTH_DAY):%-d %B} of the date's year, a northern spring; needed south of the "
    "equator)."
)
#: Help of --split (shared with ``weather show``).
SPLIT_HELP = (
    "How the weather's global radiation is split into beam and sky: erbs, boland (decomposition "
    "models) or diffuse (the series' own diffuse_w_m2 / par_diffuse_umol_m2_s column). Default: diffuse "
    "where the series has such a column, else erbs."
)
BOUNDARY_HELP = (
    "Field boundary: periodic (default: the measurement area is one cell of an infinite field, "
    "no buffer plants) or finite (buffer rows on bare soil; --boundary finite with its default "
    "2 buffer rows is the reference paper's setup)."
)
BUFFER_ROWS_HELP = (
    "Finite fields only: rows of unmeasured buffer plants around the measurement area "
    "(default 2, the reference paper's)."
)
SHEATHS_HELP = (
    "Leaf sheaths: wrapped (default: each a tube around the stem up to the collar, where the blade "
    "starts) or rods (CPlantBox's thin rods at the leaf's insertion angle, the reference paper's)."
)
HEADINGS_HELP = (
    "Plant headings: random (default: each plant turned about its base by its own angle, as in a "
    "field) or aligned (every plant as CPlantBox grows it, facing the same way, the reference paper's)."
)
PLANTS_PER_ROW_HELP = (
    "Plants along each row of the measurement area, which is then whole rows of them (--n-plants 500 "
    "--plants-per-row 25: 20 rows × 25). Default: a square N×N, ≈ 4× longer across the rows than "
    "along them in metres; ≈ 4× as many plants per row as rows makes it as wide as long, which cuts "
    "a finite field's edge light (+52 % → +30 % with 2 buffer rows on 100 plants)."
)
BUFFER_ALONG_HELP = (
    "Finite fields only: buffer plants along each row end (default: = buffer rows; "
    "≈ 4× buffer rows makes the buffer as wide in metres both ways)."
)


@dataclass(frozen=True)
class ModelOptions:
    """The shared model options as given on the command line (``None``: not given)."""

    quick: bool = False
    n_plants: int | None = None
    plants_per_row: int | None = None
    boundary: str | None = None
    buffer_rows: int | None = None
    buffer_along: int | None = None
    sheaths: str | None = None
    headings: str | None = None
    row_spacing_m: float | None = None
    plant_spacing_m: float | None = None
    row_direction_deg: float | None = None
    parameter_file: str | None = None
    field_seed: int | None = None
    samples: int | None = None
    bounces: int | None = None
    target_rse: float | None = None
    direct: str | None = None
    direct_rays_per_m2: str | None = None
    ceptometer_height_m: float | None = None
    render_seed: int | None = None
    par_kind: str | None = None
    photosynthesis: str | None = None
    vcmax_profile: str | None = None
    growth_temperature_c: str | None = None
    photosynthesis_override: list[str] | None = None
    an_per: str | None = None
    soil_respiration: float | None = None
    soil_respiration_q10: float | None = None
    preset: str | None = None
    optics: str | None = None
    chlorophyll_ug_cm2: float | None = None
    soil_albedo: float | None = None
    sky: str | None = None
    weather_file: str | None = None
    weather_provenance: str | None = None
    weather_tz: str | None = None
    weather_time_label: str | None = None
    split: str | None = None
    how: str | None = None
    steps: str | None = None
    dates: list[str] | None = None
    season_start: str | None = None
    start_time: str | None = None
    hours: float | None = None
    step: str | None = None
    site: str | None = None
    latitude: float | None = None
    longitude: float | None = None
    altitude_m: float | None = None
    timezone: str | None = None

    def __post_init__(self):
        # A repeatable option given no times reaches the command as an empty tuple: not given, as
        # any other option (args() wrote it back as the flag "--date ()").
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if isinstance(value, tuple | list):
                object.__setattr__(self, f.name, list(value) or None)

    def args(self) -> list[str]:
        """These options as command-line arguments (the given ones only), e.g. ``["--quick",
        "--date", "2016-04-20"]``: what another command needs to run the same model."""
        out = []
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if value is None or value is False:
                continue
            info = _OPTIONS[f.name][1]  # in Annotated form typer takes the first argument as a flag
            decls = [d for d in (info.default, *(info.param_decls or ())) if isinstance(d, str) and d.startswith("--")]
            flag = decls[0] if decls else "--" + f.name.replace("_", "-")
            if value is True:
                out.append(flag)
            else:
                for v in value if isinstance(value, list) else [value]:
                    out += [flag, str(v)]
        return out


@dataclass(frozen=True)
class ModelSettings:
    """The model options of a run with the defaults of its size and preset filled in; ``None`` (and a
    few names such as ``bounces``) still leave a setting to a rule the run applies. What a run
    records is :meth:`effective`."""

    quick: bool
    n_plants: int
    plants_per_row: int | None
    boundary: str
    buffer_rows: int | None
    buffer_along: int | None
    sheaths: str
    headings: str
    row_spacing_m: float
    plant_spacing_m: float
    row_direction_deg: float
    parameter_file: str
    field_seed: int
    samples: int
    bounces: int
    target_rse: float | None
    direct: str
    direct_rays_per_m2: tuple[float, float]
    ceptometer_height_m: float
    render_seed: int
    par_kind: str
    photosynthesis: str
    vcmax_profile: str | float
    growth_temperature_c: float | str | None
    photosynthesis_overrides: dict[str, float]
    an_per: str
    soil_respiration: float
    soil_respiration_q10: float
    preset: str
    optics: str
    chlorophyll_ug_cm2: float | None
    soil_albedo: float
    sky: str
    weather_file: str | None
    weather_provenance: str | None
    weather_tz: str | None
    weather_time_label: str | None
    split: str | None
    how: str
    steps: str | None
    dates: tuple[str, ...]
    season_start: str | None
    start_time: str
    hours: float
    step: str
    site: Site

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready (the site as a dict, dates as a list), as given: what runs recorded before they
        recorded :meth:`effective`, and what a record of theirs is compared with."""
        return json.loads(json.dumps(dataclasses.asdict(self)))

    def effective(self, w=None) -> dict[str, Any]:
        """The settings a run records (``config`` in calibration.json, settings.json and a posterior's
        run.h5), JSON-ready: :meth:`as_dict` with every setting left to a rule or a default taken from
        what the run is made of (:meth:`lightfit.replication.ReplicationConfig.effective`: the plants
        built, K, bounces, direct light and its rays (``None`` with the paths'), capacity profile,
        chlorophyll, buffers, season start, growth temperature), the weather by its bundled name or
        absolute path, ``steps`` as the positions ``a:b`` each day runs, and from the run's forcing
        ``w``, where given, its provenance, the time zone its file was read in and what its stamps
        were read as (``weather_time_label``: the file's own, e.g. ``"instant"``, where not given),
        and its beam/sky split. ``quick`` and ``preset`` stay what was asked."""
        from lightfit.replication import weather_source
        from lightfit.weather.bundled import source_setting

        out = self.as_dict()
        cfg = self.replication_config().effective(w)
        out |= {k: cfg[k] for k in _FROM_CONFIG}
        out["weather_file"] = source_setting(weather_source(self.weather_file))
        n = self.window().n_steps
        first, last, _ = _steps(self.steps or ":", n).indices(n)
        out["steps"] = f"{first}:{last}"
        if w is not None:
            read = {"weather_provenance": "provenance", "weather_tz": "timezone_assumed", "split": "split_model"}
            read["weather_time_label"] = "file_time_label"  # the file's stamps; results.nc has the steps'
            out |= {k: w.attrs[a] for k, a in read.items() if a in w.attrs}
        return out

    def window(self) -> Window:
        from lightfit.weather.site import Window

        return Window(self.start_time, self.hours, self.step)

    def replication_config(self):
        """The same settings as a :class:`lightfit.replication.ReplicationConfig`."""
        from lightfit.replication import ReplicationConfig

        return ReplicationConfig(
            n_plants=self.n_plants,
            plants_per_row=self.plants_per_row,
            boundary=self.boundary,
            buffer_rows=self.buffer_rows,
            buffer_along=self.buffer_along,
            sheaths=self.sheaths,
            headings=self.headings,
            row_spacing_m=self.row_spacing_m,
            plant_spacing_m=self.plant_spacing_m,
            row_direction_deg=self.row_direction_deg,
            parameter_file=self.parameter_file,
            seed=self.field_seed,
            samples=self.samples,
            bounces=self.bounces,
            target_rse=self.target_rse,
            direct=self.direct,
            direct_rays_per_m2=tuple(self.direct_rays_per_m2),
            ceptometer_height_m=self.ceptometer_height_m,
            render_seed=self.render_seed,
            par_kind=self.par_kind,
            an_per=self.an_per,
            soil_respiration_umol_m2_s=self.soil_respiration,
            soil_respiration_q10=self.soil_respiration_q10,
            how=self.how,
            photosynthesis=self.photosynthesis,
            vcmax_profile=self.vcmax_profile,
            growth_temperature_c=self.growth_temperature_c,
            photosynthesis_overrides=self.photosynthesis_overrides,
            optics=self.optics,
            chlorophyll_ug_cm2=self.chlorophyll_ug_cm2,
            soil_albedo=self.soil_albedo,
            sky=self.sky,
            dates=self.dates,
            season_start=self.season_start,
            window=self.window(),
            site=self.site,
        )


#: The settings :meth:`ModelSettings.effective` takes from
#: :meth:`lightfit.replication.ReplicationConfig.effective`.
_FROM_CONFIG = (
    "n_plants",
    "plants_per_row",
    "samples",
    "bounces",
    "direct",
    "direct_rays_per_m2",
    "vcmax_profile",
    "chlorophyll_ug_cm2",
    "growth_temperature_c",
    "buffer_rows",
    "buffer_along",
    "season_start",
)

# name → (type, typer option). One table, so every model command has the same options and help.
_OPTIONS: dict[str, tuple[Any, Any]] = {
    "quick": (
        bool,
        typer.Option(
            "--quick",
            help="The model at the CI size: 4 plants, K=16, 2 bounces (replicate in under a minute; calibrate "
            "and posterior still render their design and sample: add --steps, --n-design, --max-steps to shrink "
            "them); explicit options still win.",
            rich_help_panel=_FIELD,
        ),
    ),
    "n_plants": (
        int | None,
        typer.Option(
            "--n-plants",
            help="Plants in the measurement area, rounded up to a square N×N, or to whole rows with "
            "--plants-per-row (default 100; --quick: 4).",
            rich_help_panel=_FIELD,
        ),
    ),
    "plants_per_row": (
        int | None,
        typer.Option(
            "--plants-per-row",
            help=PLANTS_PER_ROW_HELP,
            rich_help_panel=_FIELD,
        ),
    ),
    "boundary": (
        str | None,
        typer.Option(
            "--boundary",
            help=BOUNDARY_HELP,
            rich_help_panel=_FIELD,
        ),
    ),
    "buffer_rows": (
        int | None,
        typer.Option(
            "--buffer-rows",
            help=BUFFER_ROWS_HELP,
            rich_help_panel=_FIELD,
        ),
    ),
    "buffer_along": (
        int | None,
        typer.Option(
            "--buffer-along",
            help=BUFFER_ALONG_HELP,
            rich_help_panel=_FIELD,
        ),
    ),
    "sheaths": (
        str | None,
        typer.Option(
            "--sheaths",
            help=SHEATHS_HELP,
            rich_help_panel=_FIELD,
        ),
    ),
    "headings": (
        str | None,
        typer.Option(
            "--headings",
            help=HEADINGS_HELP,
            rich_help_panel=_FIELD,
        ),
    ),
    "row_spacing_m": (
        float | None,
        typer.Option(
            "--row-spacing",
            help=ROW_SPACING_HELP,
            rich_help_panel=_FIELD,
        ),
    ),
    "plant_spacing_m": (
        float | None,
        typer.Option(
            "--plant-spacing",
            help=PLANT_SPACING_HELP,
            rich_help_panel=_FIELD,
        ),
    ),
    "row_direction_deg": (
        float | None,
        typer.Option(
            "--row-direction",
            help=ROW_DIRECTION_HELP,
            rich_help_panel=_FIELD,
        ),
    ),
    "parameter_file": (
        str | None,
        typer.Option(
            "--parameter-file",
            help=PARAMETER_FILE_HELP,
            rich_help_panel=_FIELD,
        ),
    ),
    "field_seed": (
        int | None,
        typer.Option(
            "--field-seed",
            help="Field seed: plant seeds derive from it and each plant's grid position (default 1).",
            rich_help_panel=_FIELD,
        ),
    ),
    "samples": (
        int | None,
        typer.Option(
            "--samples",
            help="Irradiance samples per segment K, ≥ 2 (default 32 with the projected direct light, 64 with "
            "the paths; --quick: 16).",
            rich_help_panel=_LIGHT,
        ),
    ),
    "bounces": (
        int | None,
        typer.Option(
            "--bounces",
            help=f"Scattering orders, 0 = unscattered light only, at most {MAX_BOUNCES_FOR_TOLERANCE} (default: as "
            "many as keep the truncated light under 1 % for the leaf, "
            "2 for the default leaf, 8 for --optics paper; --quick: 2; docs/light.md, Recommended settings).",
            rich_help_panel=_LIGHT,
        ),
    ),
    "ceptometer_height_m": (
        float | None,
        typer.Option(
            "--ceptometer-height-m",
            help="Height of the virtual line quantum sensor (ceptometer) that gives transmitted_par, "
            "ceptometer_transmittance and ceptometer_fapar, m above the soil (default 0: on the soil; "
            "inside the canopy: PAR transmitted to that height).",
            rich_help_panel=_LIGHT,
        ),
    ),
    "target_rse": (
        float | None,
        typer.Option(
            "--target-rse",
            help="Accuracy knob: per-segment relative standard error of absorbed PAR to reach by adaptive "
            f"sampling, in (0, 1) (0.05 for 5 %); --samples is then each segment's pilot count (at least {MIN_PILOT}), "
            f"samples are added up to {MAX_ADAPTIVE_SAMPLES} where the error is above it (for segments absorbing "
            f"under {DARK_FLOOR:.1%} of the PAR above the canopy, an absolute error of the target times that "
            "light). Chosen once at the step with the highest sun and kept; results.nc reports each "
            "segment's samples and the error reached there. It spends samples on the noisy segments (stems, "
            "the worst tenth); --direct-rays-per-m2 lowers every segment's error at a fixed cost. Default: "
            "none (every segment gets --samples points).",
            rich_help_panel=_LIGHT,
        ),
    ),
    "direct": (
        str | None,
        typer.Option(
            "--direct",
            help="Where the segments' direct sun and directly seen sky come from: projection (rays cast "
            "down over the periodic cell: same expectation, a fraction of the noise), paths (each sample "
            "point's own rays; what finite fields need) or auto (default: projection in a periodic field, "
            "paths in a finite one).",
            rich_help_panel=_LIGHT,
        ),
    ),
    "direct_rays_per_m2": (
        str | None,
        typer.Option(
            "--direct-rays-per-m2",
            help="Rays per m² of ground the projection casts for the direct light: one number for sun and sky, "
            "or SUN,SKY (default {:g},{:g}). More rays, less per-segment noise at a cost per cell area "
            "(e.g. 1e7,1e7 or 1e7,6e7 for per-leaf light: docs/light.md, Recommended settings).".format(
                *DEFAULT_RAYS_PER_M2
            ),
            rich_help_panel=_LIGHT,
        ),
    ),
    "render_seed": (
        int | None,
        typer.Option(
            "--render-seed",
            help="Seed of the irradiance sample streams, an integer in [0, 2³²) (common random numbers; default 0).",
            rich_help_panel=_LIGHT,
        ),
    ),
    "par_kind": (
        str | None,
        typer.Option(
            "--par-kind", help="PAR observable: incident or absorbed (default absorbed).", rich_help_panel=_LIGHT
        ),
    ),
    "photosynthesis": (
        str | None,
        typer.Option(
            "--photosynthesis",
            help="Photosynthesis parameter set: winter_wheat, cplantbox, giraud2023 or giraud2023_coupled "
            f"(default: the main job's, {DEFAULT_PARAMETER_SET}; docs/photosynthesis.md).",
            rich_help_panel=_PHOTO,
        ),
    ),
    "vcmax_profile": (
        str | None,
        typer.Option(
            "--vcmax-profile",
            help="Photosynthetic capacity through the canopy: lloyd2010 (Vcmax, Jmax, Rd fall as exp(-kn L) "
            "with the leaf area L above a blade, kn from the set's Vcmax25), depury1997 (kn 0.713, de Pury & "
            "Farquhar's wheat canopy), uniform (every blade alike, as "
            "the reference paper), kn itself (a number in [0, 2] per unit LAI), or auto (default: the set's own, "
            "lloyd2010 for winter_wheat, uniform for the CPlantBox sets; docs/photosynthesis.md).",
            rich_help_panel=_PHOTO,
        ),
    ),
    "growth_temperature_c": (
        str | None,
        typer.Option(
            "--growth-temperature-c",
            help="Growth temperature of Kattge & Knorr (2007), the mean air temperature of the month "
            "before the run, °C, in [0, 35], or 'series' (each date's 30 days before in the weather "
            "series): sets Jmax/Vcmax and the optimum of their temperature responses (winter_wheat; "
            "default its 15 °C; docs/photosynthesis.md).",
            rich_help_panel=_PHOTO,
        ),
    ),
    "photosynthesis_override": (
        list[str] | None,
        typer.Option(
            "--photosynthesis-override",
            metavar="NAME=VALUE",
            help="Set one number of the photosynthesis set, e.g. vcmax_ref_umol_m2_s=85 (Vcmax at the set's "
            "reference temperature, 25 °C for winter_wheat) or a1=4.5 (Medlyn's g1, kPa^0.5, for winter_wheat); "
            "repeat for more. Applied after the growth temperature; each value within a range well beyond its "
            "published one (Vcmax ≤ 1000, a1 ≤ 50, …). Names, units and ranges: docs/photosynthesis.md, "
            "'Your own values'.",
            rich_help_panel=_PHOTO,
        ),
    ),
    "preset": (
        str | None,
        typer.Option(
            "--preset",
            help="Model setup: default (lightfit's credible default: periodic field, PROSPECT-D leaf, "
            "winter_wheat photosynthesis) or paper (the reference paper's: finite field with 2 buffer rows, "
            "grey 0.5 leaf, giraud2023; docs/model.md, 'Presets'). Explicit options still win.",
            rich_help_panel=_FIELD,
        ),
    ),
    "optics": (
        str | None,
        typer.Option(
            "--optics",
            help="Leaf optics: prospect (default: PROSPECT-D wheat leaf, PAR absorptance 0.90) or paper "
            "(the reference paper's grey 0.5 leaf, absorptance 0.49); docs/light.md, 'Leaf optics'.",
            rich_help_panel=_LIGHT,
        ),
    ),
    "chlorophyll_ug_cm2": (
        float | None,
        typer.Option(
            "--chlorophyll-ug-cm2",
            help="Leaf chlorophyll a+b of the prospect leaf, µg cm⁻², 0–200 (default 50.5 = SPAD 41; "
            "prior range 36.4–70.3 = SPAD 32–52 of wheat; changes leaf optics only).",
            rich_help_panel=_LIGHT,
        ),
    ),
    "soil_albedo": (
        float | None,
        typer.Option(
            "--soil-albedo",
            help=f"Soil PAR albedo, Lambertian, in [0, 1] (default {SOIL_ALBEDO:g}, moist loam; docs/model.md, "
            "Presets).",
            rich_help_panel=_LIGHT,
        ),
    ),
    "sky": (
        str | None,
        typer.Option(
            "--sky",
            help=f"Angular distribution of the diffuse light: {' or '.join(SKY_MODELS)} (default {SKY_MODELS[0]}; "
            "overcast: CIE standard overcast, 3× brighter at the zenith than at the horizon).",
            rich_help_panel=_LIGHT,
        ),
    ),
    "an_per": (
        str | None,
        typer.Option(
            "--an-per",
            help="Canopy net CO2 uptake per ground or leaf area (default ground).",
            rich_help_panel=_PHOTO,
        ),
    ),
    "soil_respiration": (
        float | None,
        typer.Option(
            "--soil-respiration",
            help="Soil and root respiration at 10 °C, µmol m⁻² s⁻¹, 0–100 (arable soils ≈ 0.5–10), added to "
            "the chamber NEE only (default 0: not modelled; from bare-soil readings, or night readings minus the "
            "leaves' dark respiration, which the model adds itself; a reading R at air temperature T is "
            "R / Q10^((T − 10)/10) at 10 °C).",
            rich_help_panel=_PHOTO,
        ),
    ),
    "soil_respiration_q10": (
        float | None,
        typer.Option(
            "--soil-respiration-q10",
            help="Q10 of that respiration, its factor per 10 K of air temperature, 1–5 (default 2; 1: constant).",
            rich_help_panel=_PHOTO,
        ),
    ),
    "weather_file": (
        str | None,
        typer.Option(
            "--weather",
            help="Weather: a TERENO export, CPlantBox day file or lightfit CSV covering the run's window, "
            "or a bundled name (2016-04-20, selhausen-cplantbox-day; the latter is undated and needs --date). "
            "Default: the bundled reconstructed forcing of 2016-04-20, the only day it covers.",
            rich_help_panel=_WEATHER,
        ),
    ),
    "weather_provenance": (
        str | None,
        typer.Option(
            "--weather-provenance",
            help="What the --weather file is where it does not say: measured (a real sensor record), "
            "reconstructed or synthetic. Default: the file's own word, else 'unstated'; contradicting "
            "the file (or a bundled file's documented word) is refused.",
            rich_help_panel=_WEATHER,
        ),
    ),
    "weather_tz": (
        str | None,
        typer.Option(
            "--weather-tz",
            help="Time zone of a TERENO or CPlantBox --weather file's timestamps, an IANA name or UTC±H (default: "
            "the TERENO header's 'Time zone:', else the format's convention; as `weather show --tz`); refused "
            "for a lightfit CSV (UTC).",
            rich_help_panel=_WEATHER,
        ),
    ),
    "weather_time_label": (
        str | None,
        typer.Option(
            "--weather-time-label",
            help="Where a TERENO or CPlantBox --weather file stamps each mean in its interval: end (the default), "
            "start or center (as `weather show --time-label`); the sun is taken at the interval's centre.",
            rich_help_panel=_WEATHER,
        ),
    ),
    "split": (
        str | None,
        typer.Option(
            "--split",
            help=SPLIT_HELP,
            rich_help_panel=_WEATHER,
        ),
    ),
    "how": (
        str | None,
        typer.Option(
            "--how",
            help="30-min steps from finer data: sample (as the reference paper) or mean (default sample).",
            rich_help_panel=_WEATHER,
        ),
    ),
    "steps": (
        str | None,
        typer.Option(
            "--steps",
            help="Time steps of each day to run: a count from the window's start (e.g. 5) or positions a:b, "
            "counted from 0 with b left out (14:16 is 12:00 and 12:30 of the default window; default: all, "
            "29 for the 05:00–19:00 window in 30-min steps).",
            rich_help_panel=_WEATHER,
        ),
    ),
    "dates": (
        list[str] | None,
        typer.Option(
            "--date",
            help="Day of the run, YYYY-MM-DD (default 2016-04-20); plants are grown to it from --season-start. "
            "Repeat for several days in one results set (replicate) or one calibration / posterior. "
            "Needed with an undated weather file.",
            rich_help_panel=_WHEN,
        ),
    ),
    "season_start": (
        str | None,
        typer.Option("--season-start", help=SEASON_START_HELP, rich_help_panel=_WHEN),
    ),
    "start_time": (
        str | None,
        typer.Option(
            "--start-time",
            help="Start of each day's window, local time HH:MM at the site (default 05:00).",
            rich_help_panel=_WHEN,
        ),
    ),
    "hours": (
        float | None,
        typer.Option(
            "--hours", help="Length of each day's window, hours, 0 < hours ≤ 24 (default 14).", rich_help_panel=_WHEN
        ),
    ),
    "step": (
        str | None,
        typer.Option(
            "--step", help="Time step of the window, e.g. 30min or 1h (default 30min).", rich_help_panel=_WHEN
        ),
    ),
    "site": (
        str | None,
        typer.Option(
            "--site",
            help="Named site: selhausen (default; 50.865° N, 6.447° E, 103 m, Europe/Berlin). "
            "Or give --latitude, --longitude and --timezone instead.",
            rich_help_panel=_WHEN,
        ),
    ),
    "latitude": (
        float | None,
        typer.Option("--latitude", help="Site latitude, degrees north (instead of --site).", rich_help_panel=_WHEN),
    ),
    "longitude": (
        float | None,
        typer.Option("--longitude", help="Site longitude, degrees east (instead of --site).", rich_help_panel=_WHEN),
    ),
    "altitude_m": (
        float | None,
        typer.Option(
            "--altitude-m", help="Site altitude, m above sea level (with --latitude; default 0).", rich_help_panel=_WHEN
        ),
    ),
    "timezone": (
        str | None,
        typer.Option(
            "--timezone",
            help="Site time zone, IANA name such as Europe/Berlin or UTC±H (with --latitude): the window's local time.",
            rich_help_panel=_WHEN,
        ),
    ),
}
assert set(_OPTIONS) == {f.name for f in dataclasses.fields(ModelOptions)}


def option(name: str):
    """The shared option ``name`` as an annotation, for a command that takes it alone (same flag and help)."""
    typ, opt = _OPTIONS[name]
    return Annotated[typ, opt]


#: ``--use`` of the commands that compare the model with observations (calibrate, posterior).
Use = Annotated[
    str,
    typer.Option(
        "--use",
        help="Observed series in the likelihood, comma-separated: above_canopy_par, plant_par (par), canopy_apar, "
        "fapar, canopy_an (an), nee, transmitted_par, ceptometer_transmittance, ceptometer_fapar "
        "(docs/calibration.md). Default: every series the observations file has.",
    ),
]

#: Help panel of the Dask options (``lightfit field-run``, ``calibrate``, ``posterior``).
DASK_PANEL = "Dask"

#: ``--scheduler``: one definition for every command that can use a Dask cluster.
Scheduler = Annotated[
    str,
    typer.Option(
        help="Join this Dask scheduler (e.g. tcp://host:8786) instead of starting an embedded LocalCluster.",
        rich_help_panel=DASK_PANEL,
    ),
]


def workers_option(default: str) -> Any:
    """``--workers`` (worker processes of an embedded LocalCluster); ``default``: what the command does
    without it."""
    return Annotated[
        int,
        typer.Option(
            min=1, help=f"Embedded cluster: worker processes (default: {default}).", rich_help_panel=DASK_PANEL
        ),
    ]


#: ``--workers`` of commands that always run on Dask (the embedded cluster's size when not given).
Workers = workers_option("one per GPU, else one per core, at most one per 2 GiB of memory")

#: ``--workers`` of commands whose Dask use is optional (the emulator design of calibrate and posterior).
DesignWorkers = workers_option("no cluster: the design is rendered in this process unless --workers or --scheduler")

#: ``--connect-timeout`` of every command with Dask options: how long to wait for the cluster.
ConnectTimeout = Annotated[
    float,
    typer.Option(
        help="Give up connecting to --scheduler, or to the embedded cluster, after this many seconds.",
        rich_help_panel=DASK_PANEL,
    ),
]


def model_options(func: Callable[..., Any]) -> Callable[..., Any]:
    """Give a command the shared model options; it receives them as its ``model: ModelOptions`` argument.

    Typer reads a command's options from its signature, so the wrapper's signature is the
    command's own parameters (without ``model``) followed by the shared ones.
    """
    own = [p for p in inspect.signature(func, eval_str=True).parameters.values() if p.name != "model"]
    shared = [
        inspect.Parameter(
            name,
            inspect.Parameter.KEYWORD_ONLY,
            default=False if name == "quick" else None,
            annotation=Annotated[typ, opt],
        )
        for name, (typ, opt) in _OPTIONS.items()
    ]

    def command(**kwargs: Any) -> Any:
        model = ModelOptions(**{name: kwargs.pop(name) for name in _OPTIONS})
        return func(model=model, **kwargs)

    command.__name__, command.__qualname__, command.__doc__ = func.__name__, func.__qualname__, func.__doc__
    command.__module__ = func.__module__
    params = own + shared
    command.__signature__ = inspect.Signature(params)
    command.__annotations__ = {p.name: p.annotation for p in params}
    return command


def _overrides(given: list[str] | None, base) -> dict[str, float]:
    """``--photosynthesis-override NAME=VALUE`` options as a mapping name → value (checked,
    sorted by name: :func:`~lightfit.photosynthesis.parameters.check_overrides`); none given: ``base``'s."""
    from lightfit.cli.common import name_value
    from lightfit.photosynthesis.parameters import check_overrides

    if not given:
        return dict(base)
    option, expected = "photosynthesis_override", "NAME=VALUE with a number, e.g. a1=4.5"
    return dict(check_overrides([name_value(t, option, expected) for t in given], parameter=option))


def resolve(opts: ModelOptions, say=None) -> ModelSettings:
    """Fill the options not given from the main job's configuration (or its ``--quick`` size).
    ``say``: where cautions about the settings go (default :func:`lightfit.cli.common.caution`)."""
    from lightfit.light.estimator import bounces_for_tolerance, truncation_bound
    from lightfit.model.scenario import (
        BOUNCE_TOLERANCE,
        main_job_samples,
        resolve_direct,
    )
    from lightfit.photosynthesis.canopy import profile_for
    from lightfit.plant.field import check_headings
    from lightfit.plant.growth import parameter_file_setting
    from lightfit.plant.sheaths import check_sheaths
    from lightfit.replication import ReplicationConfig
    from lightfit.weather.readers import WEATHER_PROVENANCES
    from lightfit.weather.solar import check_split_model

    base = ReplicationConfig.quick() if opts.quick else ReplicationConfig()
    preset = "default" if opts.preset is None else opts.preset
    base = base.with_preset(preset)  # the preset's model choices; explicit options below still win

    def given(value, default):
        return default if value is None else value

    boundary = given(opts.boundary, base.boundary)
    buffers = check_boundary(boundary, opts.buffer_rows, opts.buffer_along)
    direct = resolve_direct(given(opts.direct, base.direct), boundary)
    site = site_of(opts)
    season_start = _season_start(opts, site)
    s = ModelSettings(
        quick=opts.quick,
        n_plants=given(opts.n_plants, base.n_plants),
        plants_per_row=given(opts.plants_per_row, base.plants_per_row),
        boundary=boundary,
        buffer_rows=buffers[0],
        buffer_along=buffers[1],
        sheaths=check_sheaths(given(opts.sheaths, base.sheaths)),
        headings=check_headings(given(opts.headings, base.headings)),
        row_spacing_m=given(opts.row_spacing_m, base.row_spacing_m),
        plant_spacing_m=given(opts.plant_spacing_m, base.plant_spacing_m),
        row_direction_deg=given(opts.row_direction_deg, base.row_direction_deg),
        parameter_file=parameter_file_setting(given(opts.parameter_file, base.parameter_file)),
        field_seed=given(opts.field_seed, base.seed),
        samples=given(opts.samples, main_job_samples(direct) if base.samples is None else base.samples),
        bounces=given(opts.bounces, base.bounces),
        target_rse=given(opts.target_rse, base.target_rse),
        direct=direct,
        direct_rays_per_m2=_rays(opts.direct_rays_per_m2, direct, base.direct_rays_per_m2),
        ceptometer_height_m=given(opts.ceptometer_height_m, base.ceptometer_height_m),
        render_seed=given(opts.render_seed, base.render_seed),
        par_kind=given(opts.par_kind, base.par_kind),
        photosynthesis=given(opts.photosynthesis, base.photosynthesis),
        vcmax_profile=given(opts.vcmax_profile, base.vcmax_profile),
        growth_temperature_c=given(opts.growth_temperature_c, base.growth_temperature_c),
        photosynthesis_overrides=_overrides(opts.photosynthesis_override, base.photosynthesis_overrides),
        an_per=given(opts.an_per, base.an_per),
        soil_respiration=given(opts.soil_respiration, base.soil_respiration_umol_m2_s),
        soil_respiration_q10=given(opts.soil_respiration_q10, base.soil_respiration_q10),
        preset=preset,
        optics=given(opts.optics, base.optics),
        chlorophyll_ug_cm2=given(opts.chlorophyll_ug_cm2, base.chlorophyll_ug_cm2),
        soil_albedo=given(opts.soil_albedo, base.soil_albedo),
        sky=given(opts.sky, base.sky),
        weather_file=None if opts.weather_file is None else str(opts.weather_file),
        weather_provenance=opts.weather_provenance,
        weather_tz=opts.weather_tz,
        weather_time_label=opts.weather_time_label,
        split=opts.split,
        how=given(opts.how, base.how),
        steps=opts.steps,
        dates=_dates(opts, base.dates, season_start),
        season_start=season_start,
        start_time=given(opts.start_time, base.window.start),
        hours=given(opts.hours, base.window.hours),
        step=given(opts.step, base.window.step),
        site=site,
    )
    # Every setting is checked when the configuration is made (ReplicationConfig.check: bounces and
    # target_rse too), so that a typo fails before minutes of plant growth; the profile and the growth
    # temperature (a 'series' one comes with the weather) are then stored as the run uses them (the
    # leaf and bounces below do not depend on either).
    cfg = s.replication_config()
    s = dataclasses.replace(
        s, vcmax_profile=profile_for(s.vcmax_profile, s.photosynthesis), growth_temperature_c=cfg.growth_temperature_c
    )
    optics = cfg.leaf_optics()
    if s.bounces is None:  # chosen from the leaf and soil: one too bright for any number is refused now
        try:
            cfg.render_bounces()
        except InputError as e:  # the albedo is what was given (the leaf's stays below 1): say so
            raise InputError(
                f"{e.problem} (soil albedo {s.soil_albedo:g})",
                parameter="soil_albedo",
                expected=f"a soil albedo well below 1, or --bounces given ({e.expected})",
            ) from None
    else:  # given (or --quick's): say what it leaves out
        try:
            own = bounces_for_tolerance(BOUNCE_TOLERANCE, optics)
        except InputError:  # a leaf or soil too bright for any number the rule hands out: given, taken
            own = None
        if own is None or s.bounces < own:
            from lightfit.cli.common import caution

            source = f"--bounces {s.bounces}" if opts.bounces is not None else f"--quick's {s.bounces} bounces"
            default = (
                "no number of bounces the rule hands out keeps it under "
                f"{100 * BOUNCE_TOLERANCE:g} % for this leaf and soil"
                if own is None
                else f"this leaf's default, {own}, keeps that bound under {100 * BOUNCE_TOLERANCE:g} %"
                + ("" if opts.bounces is not None else f" (--bounces {own})")
            )
            bound = truncation_bound(s.bounces, optics)
            (say or caution)(
                f"{source} leaves out the light scattered more often, "
                + (f"up to {bound:.1%} of the unscattered light" if bound < 1 else "an amount with no useful bound")
                + f"; {default}"
            )
    if s.weather_provenance is not None and s.weather_provenance not in WEATHER_PROVENANCES:
        raise InputError(
            f"--weather-provenance {s.weather_provenance}",
            parameter="weather_provenance",
            expected=" / ".join(WEATHER_PROVENANCES),
        )
    _check_file_timing(s)
    if s.split is not None:
        check_split_model(s.split)
    option_error(s.window, "--start-time, --hours or --step")
    if s.steps:
        _steps(s.steps, s.window().n_steps)
    if s.weather_file is not None:
        from lightfit import weather as wx

        # The one resolver of weather sources (bundled name or file), before any plant grows.
        wx.require_date(s.weather_file, opts.dates or None)
    return s


def _check_file_timing(s: ModelSettings) -> None:
    """``--weather-tz`` and ``--weather-time-label``: values the readers take, for a file whose
    timestamps they describe (a lightfit CSV, the default forcing among them, states its own)."""
    from lightfit.weather.readers import sniff_format, zone
    from lightfit.weather.timestamps import check_mean_label

    if s.weather_tz is not None:
        option_error(lambda: zone(s.weather_tz, "weather_tz"), "--weather-tz")
    if s.weather_time_label is not None:
        option_error(lambda: check_mean_label(s.weather_time_label), "--weather-time-label")
    given = [f for f, v in (("--weather-tz", s.weather_tz), ("--weather-time-label", s.weather_time_label)) if v]
    if given:
        from lightfit import weather as wx
        from lightfit.replication import weather_source

        path = wx.source_path(weather_source(s.weather_file))
        if sniff_format(path) == "lightfit":
            raise InputError(
                f"{' and '.join(given)} given for a lightfit CSV ("
                + (path.name if s.weather_file else f"the default forcing, {path.name}")
                + "), whose times are UTC and whose '# time_label:' line says what its stamps mean",
                expected=f"{' and '.join(given)} only with a TERENO or CPlantBox --weather file",
            )


def option_error(make, flags: str):
    """``make()``, with an :class:`InputError` restated for the command line (naming ``flags``)."""
    try:
        return make()
    except InputError as e:
        raise InputError(f"{flags}: {e.problem}", expected=e.expected) from None


def _season_start(opts: ModelOptions, site: Site) -> str | None:
    """``--season-start`` checked; required at a southern site (:func:`~lightfit.replication.check_season_start`)."""
    from lightfit.replication import check_season_start

    return option_error(lambda: check_season_start(opts.season_start, site), "--season-start")


def _dates(opts: ModelOptions, default: tuple[str, ...], season_start: str | None) -> tuple[str, ...]:
    """``--date`` values checked: real dates, no repeats, inside the wheat growth model's range from
    ``season_start``."""
    from lightfit.plant.growth import GrowthConfig
    from lightfit.replication import as_dates

    dates = option_error(lambda: as_dates(opts.dates), "--date") if opts.dates else default
    for d in dates:
        # the option the user gave is the one to name: the default date against their --season-start
        flags = f"--date {d}" if opts.dates else f"the default --date {d}"
        flags = f"--season-start {season_start} ({flags})" if season_start else flags
        option_error(lambda d=d: GrowthConfig(season_start=season_start, target_date=d), flags)
    return dates


def site_of(opts: ModelOptions) -> Site:
    """``--site NAME`` or ``--latitude/--longitude/--timezone`` (``--altitude-m``, default 0): not both."""
    from lightfit.weather.site import SELHAUSEN, Site, site_named

    coords = {"--latitude": opts.latitude, "--longitude": opts.longitude, "--altitude-m": opts.altitude_m}
    coords["--timezone"] = opts.timezone
    given = [k for k, v in coords.items() if v is not None]
    if opts.site is not None and given:
        raise InputError(
            f"--site {opts.site} given with {', '.join(given)}",
            parameter="site",
            expected="either a named --site or --latitude, --longitude and --timezone",
        )
    if opts.site is not None:
        return option_error(lambda: site_named(opts.site), "--site")
    if not given:
        return SELHAUSEN
    missing = [k for k in ("--latitude", "--longitude", "--timezone") if coords[k] is None]
    if missing:
        raise InputError(
            f"{', '.join(given)} given without {', '.join(missing)}",
            expected="--latitude, --longitude and --timezone together (--altitude-m optional, default 0)",
        )
    from lightfit.weather.readers import zone

    timezone = option_error(lambda: zone(opts.timezone, "timezone"), "--timezone")  # UTC+10 as --tz takes it
    lat, lon = opts.latitude, opts.longitude
    name = f"{abs(lat):g}° {'N' if lat >= 0 else 'S'}, {abs(lon):g}° {'E' if lon >= 0 else 'W'}"
    alt = 0.0 if opts.altitude_m is None else opts.altitude_m
    return option_error(lambda: Site(lat, lon, alt, name, timezone), "--latitude/--longitude/--altitude-m")


def _rays(text: str | None, direct: str, default: tuple[float, float]) -> tuple[float, float]:
    """``--direct-rays-per-m2``: one number or ``SUN,SKY``, only with the projected direct light."""
    from lightfit.light.projection import MAX_RAYS_PER_M2, check_rays

    if text is None:
        return tuple(default)
    if direct != "projection":
        raise InputError(
            f"--direct-rays-per-m2 {text} with the direct light from the paths",
            parameter="direct_rays_per_m2",
            expected="the projected direct light (--direct projection or auto, a periodic field)",
        )
    try:
        parts = [float(v) for v in text.split(",")]
        return check_rays(parts[0] if len(parts) == 1 else tuple(parts))
    except (ValueError, InputError):
        raise InputError(
            f"--direct-rays-per-m2 {text}",
            parameter="direct_rays_per_m2",
            expected=f"rays per m² of ground in (0, {MAX_RAYS_PER_M2:.0e}]: one number, or SUN,SKY (e.g. 1e7,6e7)",
        ) from None


#: Settings that change what the model renders: a cached emulator is valid only for the same values.
RENDER_SETTINGS = (
    "n_plants",
    "plants_per_row",
    "boundary",
    "buffer_rows",
    "buffer_along",
    "sheaths",
    "headings",
    "row_spacing_m",
    "plant_spacing_m",
    "row_direction_deg",
    "parameter_file",
    "field_seed",
    "samples",
    "bounces",
    "target_rse",
    "direct",
    "direct_rays_per_m2",
    "ceptometer_height_m",
    "render_seed",
    "optics",
    "chlorophyll_ug_cm2",
    "soil_albedo",
    "sky",
    "weather_file",
    "weather_tz",
    "weather_time_label",
    "how",
    "steps",
    "dates",
    "season_start",
    "start_time",
    "hours",
    "step",
    "site",
)
#: Settings that change the model's outputs: a resumed calibration or posterior needs the same values.
MODEL_SETTINGS = (
    *RENDER_SETTINGS,
    "par_kind",
    "photosynthesis",
    "vcmax_profile",
    "growth_temperature_c",
    "photosynthesis_overrides",
    "an_per",
    "soil_respiration",
    "soil_respiration_q10",
    "split",  # the weather's beam/sky split (renders do not depend on it; the light parts' weights do)
)


def changed_settings(previous: dict | None, s: ModelSettings, keys=MODEL_SETTINGS, w=None) -> list[str]:
    """``"key: before → now"`` for each of ``keys`` that differs between a stored run's settings
    (its ``config``) and ``s`` as the run takes them (:meth:`ModelSettings.effective`; ``w``: its
    forcing, where read). Records written before runs recorded what they took hold settings as
    given (``None`` for a default, a relative path, ``--steps 5``): a stored value equal to this
    run's as given is the same (a default then is taken as today's, as it always was). Settings
    written before the periodic boundary have no ``boundary``: they were finite fields; settings
    written before leaf optics have no ``optics``: they had the grey leaf (``paper``); settings
    written before ``sheaths`` had CPlantBox's rods, before ``headings`` aligned plants; settings
    written before the projected direct light have no ``direct``: their paths carried it; settings
    written before ``--direct-rays-per-m2`` ran with its default, before ``--plants-per-row`` a
    square. The measurement area is compared as built (``n_plants`` and ``plants_per_row`` together).
    A run whose direct light comes from the paths records no rays (``None``); records written before
    hold the default's there, which this run has as given. ``previous=None`` (nothing stored): no difference.
    """
    from lightfit.plant.growth import default_season_start
    from lightfit.weather.site import SELHAUSEN

    if previous is None:
        return []
    now, given = s.effective(w), s.as_dict()
    # Settings stored before a key existed ran with what is now its default.
    before = {"boundary": "finite", "optics": "paper", "chlorophyll_ug_cm2": None, "direct": "paths", "sheaths": "rods"}
    before["headings"] = "aligned"  # before headings, every plant faced CPlantBox's way
    # Literals, not today's constants: they say what those runs ran with, whatever a default becomes.
    before |= {"soil_respiration": 0.0, "soil_respiration_q10": 2.0}
    before["vcmax_profile"] = "uniform"  # before capacity profiles every blade had the set's
    before["photosynthesis_overrides"] = {}  # before they were options, every set was as named
    before["direct_rays_per_m2"] = [2.5e6, 1e7]
    # before they were options, every run had the library's field layout, plant file, soil and sky
    before |= {"row_spacing_m": 0.125, "plant_spacing_m": 0.03, "row_direction_deg": 90.0}
    before |= {"parameter_file": "Triticum_aestivum_adapted_2023.xml", "soil_albedo": 0.12, "sky": "isotropic"}
    before["season_start"] = None  # before --season-start: 5 March of each date's year
    before |= {"weather_tz": None, "weather_time_label": None}  # before they were options: the file's own
    before = before | _WHEN_DEFAULTS | {"site": dataclasses.asdict(SELHAUSEN)} | dict(previous)
    # The measurement area is compared as built, its two settings together (each alone could pass as
    # given while the area changed: 90 plants in rows of 10 against 90 as a square, 10 × 10).
    area = _area_built(previous.get("n_plants"), previous.get("plants_per_row"))
    before |= area
    # a season start given as the default's own date (5 March of the first date's year) grows the same plants
    for d in (before, now, given):
        if d.get("season_start") == default_season_start(d["dates"]):
            d["season_start"] = None
    return [
        f"{k}: {before.get(k)!r} → {now[k]!r}"
        for k in keys
        if before.get(k) != now[k] and (k in area or before.get(k) != given[k])
    ]


def _area_built(n_plants, plants_per_row) -> dict:
    """The plants and plants per row a stored record's field builds (a record holds them as built,
    or, written before, ``n_plants`` as given and no ``plants_per_row``: a square); ``{}`` where the
    record holds no valid count."""
    from lightfit.plant.field import Field

    try:
        f = Field(n_plants=n_plants, plants_per_row=plants_per_row)
    except (InputError, TypeError):
        return {}
    return {"n_plants": f.n_measured, "plants_per_row": f.n_along}


#: The day-and-site settings every run had before they were options (the 20 April 2016 replication;
#: at Selhausen, which :func:`changed_settings` adds).
_WHEN_DEFAULTS = {"dates": ["2016-04-20"], "start_time": "05:00", "hours": 14.0, "step": "30min"}


def check_resumable(previous: dict | None, s: ModelSettings, file, what: str, w=None) -> None:
    """Refuse to resume a run stored with other model settings (it would mix two models); ``w``: the
    run's forcing (:func:`changed_settings`)."""
    diff = changed_settings(previous, s, w=w)
    if diff:
        raise InputError(
            f"the {what} there was made with other model settings ({'; '.join(diff)})",
            file=file,
            expected="the same settings as that run, --no-resume to start again, or another --out",
        )


def check_boundary(boundary: str, buffer_rows: int | None, buffer_along: int | None) -> tuple[int | None, int | None]:
    """``--boundary`` with the buffers given: (buffer_rows, buffer_along) of the field.

    Periodic: no buffers (``(None, None)``); ``--buffer-rows`` / ``--buffer-along`` given
    explicitly are an error naming them (a periodic field's neighbours are its own copies).
    Finite: the buffers as given; ``None`` rows → 2 (the reference paper's), ``None`` along → rows.
    """
    from lightfit.plant.field import BOUNDARIES, DEFAULT_BUFFER_ROWS

    if boundary not in BOUNDARIES:
        raise InputError(f"boundary={boundary!r}", parameter="boundary", expected=" or ".join(BOUNDARIES))
    if boundary == "periodic":
        given = [f"--{n}" for n, v in (("buffer-rows", buffer_rows), ("buffer-along", buffer_along)) if v is not None]
        if given:
            raise InputError(
                f"{' and '.join(given)} given with --boundary periodic",
                parameter="boundary",
                expected="no buffer options with a periodic field (its neighbours are its own copies), "
                "or --boundary finite",
            )
        return None, None
    return (DEFAULT_BUFFER_ROWS if buffer_rows is None else buffer_rows), buffer_along


def weather(s: ModelSettings):
    """The run's forcing: each date's window (default 2016-04-20 05:00–19:00 local, 30-min steps),
    or the ``--steps`` of each day."""
    import pandas as pd

    from lightfit.cli.common import caution
    from lightfit.replication import (
        WINDOW_LIGHT_CAUTION,
        check_growth_temperatures,
        days,
        forcing_of,
        light_outside_window,
    )
    from lightfit.weather.site import Window

    cfg = s.replication_config()
    timing = {"tz": s.weather_tz, "time_label": s.weather_time_label}
    w = forcing_of(cfg, s.weather_file, provenance=s.weather_provenance, split_model=s.split, **timing)
    check_growth_temperatures(cfg, w)  # every date's, before anything is grown or written
    if not s.steps:
        if (s.start_time, s.hours) == (Window().start, Window().hours):  # a window the user chose is theirs
            for d in s.dates:
                share = light_outside_window(cfg, d)
                if share > WINDOW_LIGHT_CAUTION:
                    caution(
                        f"the window ({cfg.window.describe(d, s.site.timezone)}) leaves {share:.1%} of {d}'s "
                        "clear-sky light at the site out: --start-time and --hours widen it"
                    )
        return w
    parts = [wd.iloc[_steps(s.steps, len(wd))] for _, wd in days(cfg, w)]
    out = pd.concat(parts)
    out.attrs = dict(w.attrs)
    return out


def scenario(s: ModelSettings, w=None):
    """The :class:`~lightfit.model.scenario.Scenario` of the settings (``w``: the forcing if already read)."""
    from lightfit.replication import scenario_for

    if len(s.dates) > 1:  # one scenario is one day's plants; replicate concatenates several runs
        raise InputError(
            f"--date given {len(s.dates)} times ({', '.join(s.dates)})",
            parameter="date",
            expected="one --date for this command (replicate takes several)",
        )
    return scenario_for(s.replication_config(), weather(s) if w is None else w)


def coupled_model(s: ModelSettings, w=None, progress: bool = True):
    """The :class:`~lightfit.model.coupled.CoupledModel` of the settings (grows the plants, builds the scene)."""
    from lightfit.model.coupled import CoupledModel

    return CoupledModel(scenario(s, w), progress=progress)


def run_model(s: ModelSettings, w=None, progress: bool = True):
    """The model of a calibration or posterior: one :class:`~lightfit.model.coupled.CoupledModel` for
    one date; for several ``--date`` a :class:`~lightfit.inference.multiday.MultiDayModel` of one model
    per date (plants grown to it, that day's forcing and window). ``w``: the run's forcing if already
    read (:func:`weather`)."""
    w = weather(s) if w is None else w
    if len(s.dates) <= 1:
        return coupled_model(s, w, progress)
    from lightfit.inference.multiday import MultiDayModel
    from lightfit.replication import days

    return MultiDayModel(
        {
            d: coupled_model(dataclasses.replace(s, dates=(d,)), wd, progress)
            for d, wd in days(s.replication_config(), w)
        }
    )


def _steps(text: str, n: int) -> slice:
    """``"5"`` → the first 5 steps; ``"a:b"`` → positions a to b (Python slice, either end optional)."""
    try:
        if ":" in text:
            a, _, b = text.partition(":")
            sl = slice(int(a) if a else None, int(b) if b else None)
            if not range(n)[sl]:
                raise ValueError
            return sl
        k = int(text)
        if not 1 <= k <= n:
            raise ValueError
        return slice(0, k)
    except ValueError:
        raise InputError(f"steps={text!r}", parameter="steps", expected=f"a count 1…{n} or positions a:b") from None
