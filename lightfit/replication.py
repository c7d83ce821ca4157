"""The main job: a diurnal run of CPlantBox wheat at a site, by default the 20 April 2016 Selhausen replication.

CPlantBox wheat grown from 5 March (2016-03-05) to the run's date (default 2016-04-20), a 10 × 10-plant
measurement area as one cell of an infinite periodic field (default; ``boundary="finite"`` with
two buffer rows is the reference paper's setup), the day's forcing (bundled reconstruction of
20 April 2016 unless a weather file or bundled name is given), a window of local time at the
site (default 05:00–19:00 local in 30-minute steps, 29 steps, at Selhausen; :class:`Window`,
:class:`Site`), light and photosynthesis per segment. Several dates make several days, each with
its plants grown to its date, concatenated along time (:func:`run`).
Outputs: results netCDF (time × segment; its attrs record the dates, window and site), a
Fig-4-like PNG (PAR with its spread across segments, canopy net CO2 uptake, observations where
present), the forcing, and a summary table.
"""

from __future__ import annotations

import datetime as dt
import json
import shutil
from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path

import numpy as np
import pandas as pd
import xarray as xr

from lightfit import weather
from lightfit.defaults import (
    DEFAULT_DATE,
    DEFAULT_PLANT_SPACING_M,
    DEFAULT_RAYS_PER_M2,
    DEFAULT_ROW_SPACING_M,
    HEADINGS,
    SEASON_START_MONTH_DAY,
    SHEATHS,
    SOIL_ALBEDO,
)
from lightfit.errors import InputError, check_fraction, parse_date
from lightfit.files import is_netcdf, replace_text, replaced
from lightfit.inference.likelihood import GaussianLikelihood, resolve_use
from lightfit.inference.observations import (
    SERIES,
    align,
    check_an_area,
    check_light_scale,
    check_sds,
    read_observations,
    read_offsets_s,
)
from lightfit.light.estimator import bounces_for_tolerance
from lightfit.light.leaf_optics import DEFAULT_PRESET, LeafTraits, check_leaf, leaf_traits
from lightfit.light.projection import check_rays
from lightfit.light.scene import Optics
from lightfit.model import schema
from lightfit.model.coupled import CoupledModel, unconverged_per_step
from lightfit.model.observe import CONVERGENCE_KEY
from lightfit.model.parameters import Theta, as_theta
from lightfit.model.scenario import (
    BOUNCE_TOLERANCE,
    SETTINGS,
    Scenario,
    check_set_name,
    check_settings,
    main_job_samples,
    projected_rays,
    resolve_direct,
)
from lightfit.photosynthesis.canopy import check_profile, profile_for
from lightfit.photosynthesis.parameters import (
    check_acclimates,
    check_growth_temperature,
    check_overrides,
    growth_temperature,
    growth_temperature_setting,
)
from lightfit.plant import Field
from lightfit.plant.field import DEFAULT_BUFFER_ROWS
from lightfit.plant.growth import GrowthConfig, parameter_file_setting
from lightfit.report import fit_attribute, plot, summary, summary_metadata
from lightfit.weather import timestamps
from lightfit.weather.bundled import DATA_DIR
from lightfit.weather.readers import lightfit_csv_text, metadata_lines
from lightfit.weather.series import MONTH_BEFORE_DAYS, MONTH_BEFORE_MIN_DAYS, check_how, cut_at_ends
from lightfit.weather.site import SELHAUSEN, Site, Window, zone_label

#: ``growth_temperature_c`` that takes each date's month before from the weather series.
GROWTH_FROM_SERIES = "series"


def weather_source(weather_file: str | Path | None) -> str | Path:
    """The weather a run reads: ``weather_file``, or without one the bundled forcing of
    :data:`DEFAULT_DATE` (a bundled name, as ``--weather`` takes it)."""
    return weather_file if weather_file else DEFAULT_DATE


def as_dates(value: str | tuple | list) -> tuple[str, ...]:
    """One date or several as sorted ``YYYY-MM-DD`` strings; empty or repeated dates are an error."""
    dates = tuple(str(parse_date(d, "date")) for d in ((value,) if isinstance(value, str) else value))
    if not dates or len(set(dates)) != len(dates):
        raise InputError(f"dates={value!r}", parameter="date", expected="one or more different dates YYYY-MM-DD")
    return tuple(sorted(dates))


OBSERVATIONS = DATA_DIR / "observations" / "chamber_2016-04-20_record.csv"


@dataclass(frozen=True)
class ReplicationConfig:
    """Knobs of the replication; ``quick()`` is the under-a-minute first look (and the CI size).

    ``n_plants``: plants in the measurement area, a square N × N (rounded up) unless
    ``plants_per_row`` is given, then whole rows of that many plants (:attr:`Field.plants_per_row`).
    ``boundary``: ``"periodic"`` (default: the measurement area is one cell of an infinite field,
    no buffer plants; docs/light.md, "Periodic boundary") or ``"finite"`` (buffer rows on bare
    soil; with ``buffer_rows=None`` → 2, the reference paper's setup). ``buffer_rows`` /
    ``buffer_along``: ``None`` means the boundary's default (2 finite, 0 periodic); explicit
    non-zero buffers with a periodic boundary are refused (:class:`lightfit.plant.Field`).
    ``sheaths``: ``"wrapped"`` (default: each leaf's sheath a tube around the stem up to the collar)
    or ``"rods"`` (CPlantBox's thin rods, the reference paper's geometry; :attr:`Field.sheaths`).
    ``headings``: ``"random"`` (default: each plant turned about its base by its own angle) or
    ``"aligned"`` (every plant as CPlantBox grows it, facing the same way; the reference paper's
    field; :attr:`Field.headings`).
    ``row_spacing_m``, ``plant_spacing_m`` (0.125 m drill rows, common German practice, and 0.03 m: 267
    plants m⁻²; :data:`~lightfit.defaults.DEFAULT_ROW_SPACING_M`),
    ``row_direction_deg`` (compass azimuth of the rows, 90 = east–west) and ``parameter_file``
    (the CPlantBox plant XML, a path or a bundled name): the field's layout and its plants
    (:class:`~lightfit.plant.Field`, :class:`~lightfit.plant.growth.GrowthConfig`).
    ``soil_albedo``: the soil's Lambertian PAR albedo (:data:`~lightfit.defaults.SOIL_ALBEDO`,
    moist loam); ``sky``: the diffuse light's angular distribution, ``"isotropic"`` (default) or
    ``"overcast"`` (CIE standard overcast; :data:`~lightfit.defaults.SKY_MODELS`).
    ``season_start``: the day growth starts on, YYYY-MM-DD, for every date (``None``: 5 March of each
    date's year, :class:`~lightfit.plant.growth.GrowthConfig`'s default, a northern spring; a southern
    site needs one, :func:`check_season_start`).

    ``optics``: leaf optics preset, ``"prospect"`` (default: PROSPECT-D wheat leaf, PAR absorptance
    0.90) or ``"paper"`` (the reference paper's grey 0.5 leaf); ``chlorophyll_ug_cm2``: leaf
    chlorophyll a+b of the ``prospect`` leaf (``None``: the default trait, 50.5 µg cm⁻²; prior range
    :data:`lightfit.light.leaf_optics.CHLOROPHYLL_PRIOR_UG_CM2`). Named presets of the whole model
    setup: :data:`PAPER_PRESET` via :meth:`paper` / :meth:`with_preset` (docs/model.md, "Presets").
    ``bounces``: ``None`` (default) → as many scattering orders as keep the truncated light under
    :data:`BOUNCE_TOLERANCE` for the run's leaf (:func:`~lightfit.light.estimator.bounces_for_tolerance`:
    2 for the default leaf, 8 for the grey ``paper`` leaf; measured by experiments/defaults_check.py).
    ``samples``: points per segment K; ``None`` (default) → 32 where the direct light is
    projected, 64 from the paths (:meth:`render_samples`).
    ``target_rse``: ``None`` (default) → ``samples`` points on every segment; a number in (0, 1) →
    adaptive sampling to that per-segment relative SE of absorbed PAR, ``samples`` the starting count
    (:attr:`lightfit.model.scenario.Scenario.target_rse`).
    ``direct``: ``"auto"`` (default) → the direct light by projection in a periodic field, from the
    paths in a finite one; ``"projection"`` or ``"paths"`` to choose (:attr:`Scenario.direct`).
    ``vcmax_profile``: photosynthetic capacity through the canopy (:attr:`Scenario.vcmax_profile`;
    ``"auto"``: the set's own, Lloyd et al.'s profile for ``winter_wheat``, uniform for the paper's).
    ``growth_temperature_c``: Kattge & Knorr's growth temperature for sets that acclimate
    (:attr:`Scenario.growth_temperature_c`; ``None``: the set's own, 15 °C for ``winter_wheat``;
    ``"series"``: each date's mean air temperature of the 30 days before in the weather series,
    :func:`lightfit.weather.month_before_mean_tair_c`).
    ``photosynthesis_overrides``: numbers of the set replaced, name → value
    (:attr:`Scenario.photosynthesis_overrides`; default none).
    ``direct_rays_per_m2``: the projection's (sun, sky) rays per m² of ground
    (:attr:`Scenario.direct_rays_per_m2`; more rays, less per-segment noise, docs/light.md
    "Recommended settings").
    ``soil_respiration_umol_m2_s`` and ``soil_respiration_q10``: soil and root respiration added to
    NEE, µmol m⁻² s⁻¹ at 10 °C air temperature and its Q10 (:attr:`Scenario.soil_respiration_umol_m2_s`;
    default 0: the default NEE is −canopy An per ground area). ``how``: how the weather meets the steps, ``"sample"``
    (each step's instant, where its sun is taken) or ``"mean"`` (:func:`lightfit.weather.resample`).
    """

    n_plants: int = 100
    plants_per_row: int | None = None
    boundary: str = "periodic"
    buffer_rows: int | None = None
    buffer_along: int | None = None
    sheaths: str = SHEATHS[0]
    headings: str = HEADINGS[0]
    row_spacing_m: float = DEFAULT_ROW_SPACING_M
    plant_spacing_m: float = DEFAULT_PLANT_SPACING_M
    row_direction_deg: float = Field.row_direction_deg
    parameter_file: str = GrowthConfig.parameter_file
    seed: int = 1
    samples: int | None = None
    bounces: int | None = None
    target_rse: float | None = None
    direct: str = "auto"
    direct_rays_per_m2: tuple[float, float] = DEFAULT_RAYS_PER_M2
    ceptometer_height_m: float = 0.0
    render_seed: int = 0
    par_kind: str = Scenario.par_kind
    an_per: str = Scenario.an_per
    soil_respiration_umol_m2_s: float = Scenario.soil_respiration_umol_m2_s
    soil_respiration_q10: float = Scenario.soil_respiration_q10
    how: str = "sample"
    photosynthesis: str = Scenario.photosynthesis
    vcmax_profile: str | float = Scenario.vcmax_profile
    growth_temperature_c: float | str | None = Scenario.growth_temperature_c
    photosynthesis_overrides: tuple[tuple[str, float], ...] = Scenario.photosynthesis_overrides
    optics: str = DEFAULT_PRESET
    chlorophyll_ug_cm2: float | None = None
    soil_albedo: float = SOIL_ALBEDO
    sky: str = Scenario.sky
    dates: tuple[str, ...] = (DEFAULT_DATE,)
    season_start: str | None = None
    window: Window = Window()
    site: Site = SELHAUSEN

    def __post_init__(self):
        for f in fields(self):  # numpy's scalars as Python's: the configuration is stored as JSON
            if isinstance(v := getattr(self, f.name), np.generic):
                object.__setattr__(self, f.name, v.item())
        object.__setattr__(self, "dates", as_dates(self.dates))
        object.__setattr__(self, "season_start", check_season_start(self.season_start, self.site))
        # One form whatever it came from (one number, a list read back from JSON): configurations
        # compare equal when they render the same rays.
        object.__setattr__(self, "direct_rays_per_m2", check_rays(self.direct_rays_per_m2))
        check_set_name(self.photosynthesis)  # before the growth temperature it decides
        t_g = growth_temperature_setting(self.photosynthesis, parse_growth_temperature(self.growth_temperature_c))
        if t_g == GROWTH_FROM_SERIES:  # read with the weather; whether the set takes one, now
            check_acclimates(self.photosynthesis, t_g)
        elif t_g is not None:
            check_growth_temperature(self.photosynthesis, t_g)
        object.__setattr__(self, "growth_temperature_c", t_g)
        # one form (sorted pairs) whatever it came from: a mapping, or lists read back from JSON
        object.__setattr__(self, "photosynthesis_overrides", check_overrides(self.photosynthesis_overrides))
        object.__setattr__(self, "vcmax_profile", check_profile(self.vcmax_profile))
        object.__setattr__(self, "parameter_file", parameter_file_setting(self.parameter_file))
        self.check()

    def check(self) -> None:
        """Refuse, naming it, any setting the run would refuse, when the configuration is made (it
        runs this) rather than minutes into a run: the field (:meth:`field`: layout, spacings, row
        direction, sheaths, headings, plant file, the first date's growth range), the leaf and
        soil (:meth:`leaf_optics`), ``how`` the weather is windowed
        (:func:`~lightfit.weather.series.check_how`) and the scenario's settings
        (:func:`~lightfit.model.scenario.check_settings`; ``bounces=None`` is the leaf's rule's,
        applied at the run). The dates' growth range is left to :meth:`field` at the run, so that a
        configuration may be changed a field at a time (``replace(cfg, season_start=…)``, then its
        dates); the leaf's spectra are not computed (no renderer needed to make a configuration)."""
        self._layout(GrowthConfig(parameter_file=self.parameter_file))
        check_leaf(self.optics, self.chlorophyll_ug_cm2)
        check_fraction(self.soil_albedo, "soil_albedo")
        check_how(self.how)
        settings = {k: getattr(self, k) for k in SETTINGS}
        settings |= {"samples": self.render_samples(), "seed": self.render_seed}  # `seed` here grows the plants
        if self.growth_temperature_c == GROWTH_FROM_SERIES:  # checked above; its value comes with the weather
            settings["growth_temperature_c"] = None
        check_settings(boundary=self.boundary, **settings)

    @staticmethod
    def quick() -> ReplicationConfig:
        return ReplicationConfig(n_plants=4, samples=16, bounces=2)

    @staticmethod
    def paper() -> ReplicationConfig:
        """The reference paper's whole setup at the main job's size (:data:`PAPER_PRESET`)."""
        return ReplicationConfig().with_preset("paper")

    def with_preset(self, name: str) -> ReplicationConfig:
        """This configuration with the model choices of a named preset (:data:`PRESETS`): ``"default"``
        (lightfit's credible default: the class defaults) or ``"paper"`` (:data:`PAPER_PRESET`). The
        run's size (plants, samples, bounces, seeds) is kept: ``quick().with_preset("paper")`` is the
        paper's setup at the CI size."""
        if name == "paper":
            return replace(self, **PAPER_PRESET)
        if name == "default":
            base = ReplicationConfig()
            return replace(self, **{k: getattr(base, k) for k in PAPER_PRESET})
        raise InputError(f"preset={name!r}", parameter="preset", expected=" or ".join(PRESETS))

    @property
    def needs_month_before(self) -> bool:
        """Whether the forcing must carry each date's month before (``growth_temperature_c="series"``)."""
        return self.growth_temperature_c == GROWTH_FROM_SERIES

    @property
    def preset(self) -> str | None:
        """The named preset whose model choices this configuration has (``None``: neither)."""
        for name in PRESETS:
            ref = ReplicationConfig().with_preset(name)
            # growth_temperature_c is normalised (None: the set's own), the profile compared as resolved
            choices = (
                "boundary",
                "sheaths",
                "headings",
                "optics",
                "photosynthesis",
                "par_kind",
                "growth_temperature_c",
                "photosynthesis_overrides",
                "parameter_file",
                "soil_albedo",
                "sky",
            )
            same_profile = profile_for(self.vcmax_profile, self.photosynthesis) == profile_for(
                ref.vcmax_profile, ref.photosynthesis
            )
            if same_profile and all(getattr(self, k) == getattr(ref, k) for k in choices):
                return name
        return None

    def effective(self, w: pd.DataFrame | None = None) -> dict:
        """This configuration as its run takes it, JSON-ready (a results file's ``replication_config``,
        the ``config`` a calibration or posterior records): every setting left to a rule (``None``,
        ``"auto"``) is the value the run uses, from the objects the run is made of: K and bounces
        (:meth:`render_samples`, :meth:`render_bounces`), the direct light, the capacity profile,
        the leaf's chlorophyll (``None`` for a leaf not made from traits), the field's plants (its
        measurement area's, :attr:`~lightfit.plant.Field.n_measured`: ``n_plants=5`` builds 3 × 3, and
        its plants per row, :attr:`~lightfit.plant.Field.n_along`),
        buffers and each date's season start (:meth:`field`), and the growth temperature the set
        takes (``None`` for a set that does not acclimate). ``direct_rays_per_m2`` is ``None`` where
        the direct light comes from the paths: they cast no projected rays, and results and the
        emulator's key leave the rays out there too. ``w``: the run's forcing, for a growth
        temperature from the series (without it ``"series"`` is kept). A setting that differs
        between the dates is ``{date: value}``."""
        traits = leaf_traits(self.optics, self.chlorophyll_ug_cm2)
        fields_ = {d: self.field(d) for d in self.dates}
        first = fields_[self.dates[0]]
        t_g = dict.fromkeys(self.dates, self.growth_temperature_c)
        if self.needs_month_before and w is not None:  # each day's, as scenario_for gives its Scenario
            t_g |= {d: _growth_temperature(self, wd) for d, wd in days(self, w)}
        t_g = {d: t if t == GROWTH_FROM_SERIES else growth_temperature(self.photosynthesis, t) for d, t in t_g.items()}
        direct = resolve_direct(self.direct, self.boundary)
        out = json.loads(json.dumps(asdict(self)))
        out |= {
            "n_plants": first.n_measured,
            "plants_per_row": first.n_along,
            "samples": self.render_samples(),
            "bounces": self.render_bounces(),
            "direct": direct,
            "direct_rays_per_m2": projected_rays(direct, self.direct_rays_per_m2),
            "vcmax_profile": profile_for(self.vcmax_profile, self.photosynthesis),
            "chlorophyll_ug_cm2": None if traits is None else traits.Cab,
            "buffer_rows": first.buffer_rows,
            "buffer_along": first.b_along,
            "season_start": _one_or_each({d: f.growth.season_start for d, f in fields_.items()}),
            "growth_temperature_c": _one_or_each(t_g),
            "photosynthesis_overrides": dict(self.photosynthesis_overrides),  # a mapping, as the settings hold it
        }
        return out

    def render_samples(self) -> int:
        """Samples per segment K the run renders: ``samples``, or for ``None`` the main job's K for
        its direct light (:func:`~lightfit.model.scenario.main_job_samples`: 32 with the
        projection, 64 with the paths)."""
        if self.samples is not None:
            return self.samples
        return main_job_samples(resolve_direct(self.direct, self.boundary))

    def render_bounces(self) -> int:
        """Scattering orders the run renders: ``bounces``, or for ``None`` as many as keep the truncated
        light under :data:`BOUNCE_TOLERANCE` for the run's leaf (2 for the default leaf, 8 for the grey one)."""
        if self.bounces is not None:
            return self.bounces
        return bounces_for_tolerance(BOUNCE_TOLERANCE, self.leaf_optics())

    def leaf_optics(self) -> Optics:
        """The run's :class:`~lightfit.light.scene.Optics` (checks the preset and the chlorophyll)."""
        check_leaf(self.optics, self.chlorophyll_ug_cm2)
        if self.chlorophyll_ug_cm2 is None:
            return Optics.preset(self.optics, soil_albedo=self.soil_albedo)
        return Optics.from_traits(LeafTraits(Cab=self.chlorophyll_ug_cm2), soil_albedo=self.soil_albedo)

    def finite(self, buffer_rows: int = DEFAULT_BUFFER_ROWS, buffer_along: int | None = None) -> ReplicationConfig:
        """The same run on a finite field; the defaults are the reference paper's 2 buffer rows."""
        return replace(self, boundary="finite", buffer_rows=buffer_rows, buffer_along=buffer_along)

    def field(self, date: str | None = None) -> Field:
        """The run's :class:`~lightfit.plant.Field` with plants grown to ``date`` (default: the
        first of :attr:`dates`); checks boundary, buffers and the growth range."""
        return self._layout(
            GrowthConfig(
                parameter_file=self.parameter_file,
                season_start=self.season_start,
                target_date=self.dates[0] if date is None else str(parse_date(date, "date")),
            )
        )

    def _layout(self, growth: GrowthConfig) -> Field:
        """The run's :class:`~lightfit.plant.Field` with plants grown as ``growth`` says."""
        return Field(
            n_plants=self.n_plants,
            plants_per_row=self.plants_per_row,
            buffer_rows=self.buffer_rows,
            seed=self.seed,
            buffer_along=self.buffer_along,
            boundary=self.boundary,
            sheaths=self.sheaths,
            headings=self.headings,
            row_spacing_m=self.row_spacing_m,
            plant_spacing_m=self.plant_spacing_m,
            row_direction_deg=self.row_direction_deg,
            growth=growth,
        )

    def window_utc(self, date: str) -> tuple[pd.Timestamp, pd.Timestamp]:
        """First and last step of ``date``'s window, UTC."""
        return self.window.bounds_utc(date, self.site.timezone)

    def span_utc(self, date: str) -> tuple[pd.Timestamp, pd.Timestamp]:
        """The time ``date``'s window stands for, UTC: its first and last step ± half a step (each
        step stands for the half steps around it)."""
        t0, t1 = self.window_utc(date)
        half = pd.Timedelta(self.window.step) / 2
        return t0 - half, t1 + half

    def date_of(self, w: pd.DataFrame) -> str:
        """The date of :attr:`dates` whose window holds every step of the forcing ``w``."""
        for d in self.dates:
            t0, t1 = self.window_utc(d)
            if len(w) and w.index[0] >= t0 and w.index[-1] <= t1:
                return d
        raise InputError(
            f"the forcing's steps {w.index[0] if len(w) else '–'} … {w.index[-1] if len(w) else '–'} are not "
            f"inside one day's window of {', '.join(self.dates)}",
            parameter="date",
            expected="one day's forcing per scenario (replication.days splits a several-day forcing)",
        )


def _one_or_each(values: dict):
    """The value every key shares, else ``values`` itself (a setting per date)."""
    distinct = {json.dumps(v) for v in values.values()}
    return next(iter(values.values())) if len(distinct) == 1 else values


#: The reference paper's setup (Baker et al. 2025): a finite field with 2 buffer rows on bare soil,
#: CPlantBox's rod-like leaf sheaths, every plant facing the same way, the grey 0.5 leaf, the
#: giraud2023 photosynthesis set and, as PAR at the plants, the area-mean absorbed PAR of all leaf segments.
#: ``replication_quick_finite.json`` is its regression curve.
PAPER_PRESET = {
    "boundary": "finite",
    "buffer_rows": 2,
    "buffer_along": None,
    "sheaths": "rods",
    "headings": "aligned",
    "optics": "paper",
    "chlorophyll_ug_cm2": None,
    "photosynthesis": "giraud2023",
    "vcmax_profile": "auto",  # the set's own: uniform for giraud2023
    "growth_temperature_c": None,  # giraud2023 does not acclimate
    "par_kind": "absorbed",
    # the paper's plants, soil and sky are lightfit's own; listed so that a preset resets them
    # (--compare-preset runs the preset, not a hybrid with the run's soil) and names only its runs
    "parameter_file": GrowthConfig.parameter_file,
    "soil_albedo": SOIL_ALBEDO,
    "sky": Scenario.sky,
}


#: Share of a day's clear-sky light a run's window may leave out before the command line says so
#: (:func:`light_outside_window`): the main job's 05:00–19:00 on 20 April at Selhausen leaves ≈ 1.3 %.
WINDOW_LIGHT_CAUTION = 0.02


def light_outside_window(cfg: ReplicationConfig, date: str) -> float:
    """Share of ``date``'s clear-sky global radiation at the run's site (Haurwitz, the sun every 5 min
    from local midnight to midnight) outside the run's window, each step standing for ± half a step:
    light the run does not model. 0.013 for the main job; 0.053 for 05:00–19:00 at 60° N on 21 June
    (a review: the default window is Selhausen's spring day)."""
    from lightfit.weather.solar import clear_sky_ghi_w_m2, solar_position

    midnight = pd.Timestamp(str(parse_date(date, "date")), tz=cfg.site.timezone)
    t = pd.date_range(midnight, midnight + pd.Timedelta(days=1), freq="5min", inclusive="left").tz_convert("UTC")
    ghi = clear_sky_ghi_w_m2(solar_position(t, cfg.site)["sun_elevation_deg"].to_numpy())
    t0, t1 = cfg.span_utc(date)
    inside = np.asarray((t >= t0) & (t <= t1))
    return float(ghi[~inside].sum() / ghi.sum()) if ghi.sum() > 0 else 0.0


def check_season_start(season_start, site: Site) -> str | None:
    """``season_start`` as ``YYYY-MM-DD`` (``None`` kept: the growth model's 5 March of each date's
    year), else :class:`InputError` naming it; ``None`` at a site south of the equator is refused too:
    5 March is a northern spring date (there it is autumn, before sowing), so plants grown from it
    would stand full-grown in the southern winter."""
    if season_start is not None:
        return parse_date(season_start, "season_start").isoformat()
    if site.latitude_deg < 0:
        default = dt.date(2016, *SEASON_START_MONTH_DAY)
        raise InputError(
            f"the default season start, {default:%-d %B}, is a northern spring date; {site.name} lies at "
            f"{site.latitude_deg:g}° (south of the equator), where wheat is sown in autumn, from April to June",
            parameter="season_start",
            expected="the day growth starts on at this site (YYYY-MM-DD): the sowing date where the crop grows "
            "on through a mild winter, the end of dormancy after a cold one",
        )
    return None


#: Named presets of :meth:`ReplicationConfig.with_preset`; ``default`` is the class defaults.
PRESETS = ("default", "paper")


def forcing(
    weather_file: str | Path | None = None,
    how: str = "sample",
    *,
    dates: tuple[str, ...] | str | None = None,
    window: Window = Window(),
    site: Site = SELHAUSEN,
    provenance: str | None = None,
    split_model: str | None = None,
    month_before: bool = False,
    tz: str | None = None,
    time_label: str | None = None,
) -> pd.DataFrame:
    """The run's steps, with solar columns for ``site``: the ``window`` (local time at the site) of each date.

    ``weather_file``: a weather file or bundled name (:func:`lightfit.weather.read_source`);
    default the bundled reconstruction of 2016-04-20, the only day it covers. ``dates``: one or
    more dates (default 2016-04-20); an undated file (CPlantBox day) needs them given, and with
    several it is placed on each. Several dates give one series concatenated in time.
    ``provenance``: what the file is where it does not say (:func:`lightfit.weather.read_weather`;
    a contradiction is refused). ``split_model``: the direct/diffuse split
    (:func:`lightfit.weather.add_solar`; default: the series' diffuse column where it has one, else
    Erbs). Errors name the file and the parameter (``date``,
    ``start/hours``) when the window is not covered. ``month_before``: record each date's mean air
    temperature of the month before in ``attrs["month_before_tair_c"]`` (``{date: °C or None}``, for
    ``growth_temperature_c="series"``). ``tz``, ``time_label``: the zone of a TERENO or CPlantBox
    file's timestamps and where they sit in each mean's interval, where the file does not say
    (:func:`lightfit.weather.read_weather`; refused for a lightfit CSV); what the file's stamps were
    read as is ``attrs["file_time_label"]`` (``attrs["timestamps"]`` is the run's steps').
    """
    given = dates is not None
    dates = as_dates(dates or DEFAULT_DATE)
    source = weather_source(weather_file)
    if not weather_file and set(dates) != {DEFAULT_DATE}:
        raise InputError(
            f"no bundled forcing for {', '.join(d for d in dates if d != DEFAULT_DATE)}",
            parameter="dates",
            expected=f"a weather_file (--weather) covering the date(s); the bundled forcing is {DEFAULT_DATE} only",
        )
    weather.require_date(source, dates if given else None)
    undated = weather.is_undated(source)
    days = []
    month = {}  # each date's month before, for a growth temperature from the series
    src = None
    for d in dates:
        if src is None or undated:
            more = {k: v for k, v in (("provenance", provenance), ("time_label", time_label)) if v is not None}
            src = weather.add_solar(
                weather.read_source(source, date=d, tz=tz, **more), site=site, split_model=split_model
            )
            # the window relabels the stamps as the run's steps (--how mean: centred means); a run's
            # record says what the file's were read as (its own line, the reader's convention, time_label)
            src.attrs["file_time_label"] = timestamps.of(src).label
        t0, t1 = window.bounds_utc(d, site.timezone)
        if t0 < src.index[0] or t1 > src.index[-1]:
            # Three parameters, one error's name: each said both ways, the library's and the command line's
            raise InputError(
                f"the window {window.describe(d, site.timezone)} is not covered: the file spans "
                f"{_span(src, site.timezone)}",
                file=src.attrs.get("source"),
                expected="dates inside the file's span and a window within it "
                "(dates, window.start, window.hours: --date, --start-time, --hours)",
            )
        days.append(weather.window(src, t0, window.hours, window.step, how=how))
        if month_before:
            month[d] = None if undated else weather.month_before_mean_tair_c(src, d, site.timezone)
    out = days[0]
    if len(days) > 1:
        out = pd.concat(days)
        out.attrs = dict(days[0].attrs)
        if undated:  # placed on every date: the first day's alone named one date as the file's place
            out.attrs["date_given"] = "; ".join(str(d.attrs["date_given"]) for d in days)
    if month_before:
        out.attrs["month_before_tair_c"] = month
    return out


def _span(df: pd.DataFrame, tz: str) -> str:
    a, b = (t.tz_convert(tz).strftime("%Y-%m-%d %H:%M") for t in (df.index[0], df.index[-1]))
    return f"{a} … {b} ({zone_label(tz)}){cut_at_ends(df)}"


def describe_steps(cfg: ReplicationConfig, w: pd.DataFrame) -> str:
    """The steps of the forcing ``w`` in words (forcing.csv's note, the command's table of the forcing):
    each date's window (:meth:`Window.describe`); where ``w`` holds only some of their steps (the
    command's ``--steps``, a ``forcing_df`` cut short), its first and last step in the site's time
    and, where every day runs the same positions of its window, those positions ``a:b``."""
    tz, step = cfg.site.timezone, pd.Timedelta(cfg.window.step)
    windows = "; ".join(cfg.window.describe(d, tz) for d in cfg.dates)
    at = [tuple(int(i) for i in (wd.index - cfg.window_utc(d)[0]) // step) for d, wd in days(cfg, w)]
    if len(w) == len(cfg.dates) * cfg.window.n_steps and set(at) == {tuple(range(cfg.window.n_steps))}:
        return windows
    local = w.index.tz_convert(tz)
    last = f"{local[-1]:%H:%M}" if local[-1].date() == local[0].date() else f"{local[-1]:%Y-%m-%d %H:%M}"
    a, b = at[0][0], at[0][-1] + 1
    if len(local) == 1:  # not "12:00 … 12:00, steps 14:15"
        return f"{local[0]:%Y-%m-%d %H:%M}, step {a} of {windows}"
    which = f", steps {a}:{b}" if set(at) == {tuple(range(a, b))} else ""
    return f"{local[0]:%Y-%m-%d %H:%M} … {last}{which} of {windows}"


def days(cfg: ReplicationConfig, w: pd.DataFrame) -> list[tuple[str, pd.DataFrame]]:
    """A (several-day) forcing split into (date, that day's steps) by the configuration's windows."""
    out = []
    for d in cfg.dates:
        t0, t1 = cfg.window_utc(d)
        wd = w.loc[t0:t1]
        if len(wd):
            wd.attrs = dict(w.attrs)
            out.append((d, wd))
    return out


def forcing_of(cfg: ReplicationConfig, weather_file: str | Path | None = None, **kw) -> pd.DataFrame:
    """:func:`forcing` with the configuration's dates, window, site and resampling (and the month
    before where its growth temperature comes from the series); ``kw``: :func:`forcing`'s
    ``provenance``, ``split_model``, ``tz`` and ``time_label``."""
    return forcing(
        weather_file,
        cfg.how,
        dates=cfg.dates,
        window=cfg.window,
        site=cfg.site,
        month_before=cfg.needs_month_before,
        **kw,
    )


def when_attrs(cfg: ReplicationConfig, date: str) -> dict[str, str | float]:
    """netCDF attrs recording a run's day, window and site (the plants' ``target_date`` is the date)."""
    site = cfg.site
    return {"date": date, "window": cfg.window.describe(date, site.timezone), **site.attrs()}


def steps_attrs(cfg: ReplicationConfig, w: pd.DataFrame) -> dict[str, str]:
    """netCDF attr ``steps_run`` where the forcing ``w`` holds only some of the windows' steps
    (``--steps``, a ``forcing_df`` cut short): :func:`describe_steps`, beside the ``window`` that
    :func:`when_attrs` records whole; ``{}`` where every step of every window ran."""
    windows = "; ".join(cfg.window.describe(d, cfg.site.timezone) for d in cfg.dates)
    said = describe_steps(cfg, w)
    return {} if said == windows else {"steps_run": said}


def scenario_for(cfg: ReplicationConfig, w: pd.DataFrame) -> Scenario:
    """The :class:`Scenario` of a configuration over the forcing ``w`` (the one place that maps one to the other)."""
    optics = cfg.leaf_optics()
    return Scenario(
        weather=w,
        field=cfg.field(cfg.date_of(w)),
        samples=cfg.render_samples(),
        bounces=cfg.render_bounces(),
        seed=cfg.render_seed,
        target_rse=cfg.target_rse,
        direct=cfg.direct,
        direct_rays_per_m2=cfg.direct_rays_per_m2,
        ceptometer_height_m=cfg.ceptometer_height_m,
        par_kind=cfg.par_kind,
        an_per=cfg.an_per,
        soil_respiration_umol_m2_s=cfg.soil_respiration_umol_m2_s,
        soil_respiration_q10=cfg.soil_respiration_q10,
        photosynthesis=cfg.photosynthesis,
        vcmax_profile=cfg.vcmax_profile,
        growth_temperature_c=_growth_temperature(cfg, w),
        photosynthesis_overrides=cfg.photosynthesis_overrides,
        optics=optics,
        sky=cfg.sky,
    )


def parse_growth_temperature(value) -> float | str | None:
    """A configuration's growth temperature: ``None``, ``"series"`` or a number (text taken as its
    number; a bool is no temperature); :class:`InputError` naming ``growth_temperature_c``
    otherwise. The set and the range are checked by :class:`ReplicationConfig`."""
    if value is None or value == GROWTH_FROM_SERIES:
        return value
    try:
        if isinstance(value, bool):
            raise TypeError
        return float(value)
    except (TypeError, ValueError):
        raise InputError(
            f"growth_temperature_c={value!r}",
            parameter="growth_temperature_c",
            expected=f"a temperature in °C, or {GROWTH_FROM_SERIES!r} (the weather series' month before the run)",
        ) from None


def _growth_temperature(cfg: ReplicationConfig, w: pd.DataFrame) -> float | None:
    """The configuration's growth temperature for the day ``w``: from the series where it says so."""
    if cfg.growth_temperature_c != GROWTH_FROM_SERIES:
        return cfg.growth_temperature_c
    date = cfg.date_of(w)
    if "month_before_tair_c" not in w.attrs:
        raise InputError(
            "growth_temperature_c='series' with a forcing read without its month before",
            parameter="forcing_df",
            expected="the forcing of forcing_of(cfg) (forcing(..., month_before=True))",
        )
    t_g = w.attrs["month_before_tair_c"].get(date)
    if t_g is None:
        raise InputError(
            f"growth_temperature_c='series': the weather series does not cover the month before {date}"
            + cut_at_ends(w),
            file=w.attrs.get("source"),
            parameter="growth_temperature_c",
            expected=f"air temperature over at least {MONTH_BEFORE_MIN_DAYS} of the {MONTH_BEFORE_DAYS} days "
            "before the run, or a number (°C)",
        )
    problem = f"growth_temperature_c='series': the month before {date} averages {t_g:.2f} °C in the weather series"
    return check_growth_temperature(cfg.photosynthesis, t_g, problem=problem, file=w.attrs.get("source"))


def check_growth_temperatures(cfg: ReplicationConfig, w: pd.DataFrame) -> None:
    """Every date's growth temperature of ``w`` (:func:`_growth_temperature`), before anything runs:
    a several-day run would otherwise grow and render its first days before refusing a later one."""
    for _, wd in days(cfg, w):
        _growth_temperature(cfg, wd)


def model_for(
    cfg: ReplicationConfig, w: pd.DataFrame, progress: bool = False, keep_steps: Path | None = None
) -> CoupledModel:
    return CoupledModel(scenario_for(cfg, w), progress=progress, keep_steps=keep_steps)


def observations_for(w: pd.DataFrame, observations=OBSERVATIONS, optional: bool | None = None) -> pd.DataFrame | None:
    """Observations (a file, or a frame already read) checked against the forcing ``w``'s steps,
    before anything is rendered: a bad file or an observation outside the run fails in seconds,
    not after the simulation. ``None`` without observations, and for ``optional`` ones when the
    run's steps do not reach them (default: optional for the bundled chamber record,
    :data:`OBSERVATIONS`, 20 April 2016 12:13 local, which a run uses where it can); observations
    asked for (``optional=False``: the command line's ``--observations``, even the bundled file)
    outside the run are an :class:`InputError`."""
    if observations is None or (not isinstance(observations, pd.DataFrame) and not observations):
        return None
    bundled = isinstance(observations, (str, Path)) and Path(observations).resolve() == OBSERVATIONS.resolve()
    if optional is None:
        optional = bundled
    obs = observations if isinstance(observations, pd.DataFrame) else read_observations(observations)
    missing = [k for k in ("source", "provenance") if k not in obs.attrs]
    if missing:  # the results record where the observations came from and what they are
        raise InputError(
            f"an observations frame without attrs {missing}",
            parameter="observations",
            expected="a frame from lightfit.inference.observations.read_observations (attrs source and provenance)",
        )
    try:
        align(obs, w.index.tz_convert("UTC"), timestamps.of(w))
    except InputError:
        if not optional:
            raise
        return None
    check_sds(obs)  # a frame's readings obey a file's rules: the run's fit reads their SDs after it
    resolve_use(None, obs)  # ... and its values: a frame without any was refused by that fit
    check_light_scale(obs, w)
    return obs


def run(
    cfg: ReplicationConfig,
    *,
    weather_file=None,
    theta: Theta | dict | None = None,
    observations=OBSERVATIONS,
    out: Path | None = None,
    progress: bool = False,
    forcing_df: pd.DataFrame | None = None,
    compare: ReplicationConfig | None = None,
    keep_steps: Path | bool | None = None,
):
    """Run the replication. Returns (Dataset, observations or None).

    ``out``: a folder for results.nc, replication.png (:func:`lightfit.report.plot`), summary.csv,
    the forcing as forcing.csv (a lightfit CSV, :func:`lightfit.weather.write_lightfit_csv`) and forcing.png, and
    with ``compare`` results_compare.nc; written once everything is computed (default: none).

    ``keep_steps``: the folder that keeps each rendered step until the run has written its files
    (:attr:`CoupledModel.keep_steps`), so that a run killed half-way and started again renders only
    the steps it had not, to the same results; default ``out/.kept-steps`` where ``out`` is given
    (removed once every file is written), else none; ``False``: none. A folder given is the
    caller's to remove.

    ``compare``: a second configuration (e.g. ``cfg.with_preset("paper")``) run on the same forcing
    with its own leaf defaults (a second full run: twice the time); its results go to
    ``results_compare.nc`` and its curves into the figure beside this run's (:func:`lightfit.report.plot`).

    ``forcing_df``: the run's forcing if already read (:func:`forcing_of`). ``observations``: a
    file or a frame, checked against the forcing's steps before the simulation
    (:func:`observations_for`: the bundled chamber record, the default, is left out when the run's
    steps do not reach it; other observations outside the run are an error).
    """
    if not isinstance(cfg, ReplicationConfig):  # e.g. "quick": an AttributeError further in
        raise InputError(
            f"cfg of type {type(cfg).__name__}",
            parameter="cfg",
            expected="a ReplicationConfig, e.g. ReplicationConfig() or ReplicationConfig.quick()",
        )
    w = forcing_of(cfg, weather_file) if forcing_df is None else forcing_df
    check_growth_temperatures(cfg, w)
    obs = observations_for(w, observations)
    if obs is not None:
        check_an_area(obs, cfg.an_per)
    by_day = days(cfg, w)
    if not by_day:
        raise InputError(
            "the forcing has no step in the run's windows", parameter="date", expected=", ".join(cfg.dates)
        )
    if out is not None:  # forcing.csv's text, from the forcing alone: refused (its provenance) before the run
        meta = {
            "provenance": w.attrs.get("provenance", "unstated"),  # as provenance_label says a series that does not
            "source": str(w.attrs.get("source")),
            "note": f"{len(w)} steps, {describe_steps(cfg, w)}, {cfg.site.name} ({cfg.how})",
        }
        forcing_csv = lightfit_csv_text(w, meta)
    own = keep_steps is None and out is not None  # the run's own folder, removed at its end
    if own:
        keep_steps = Path(out) / UNFINISHED
    keep_steps = None if keep_steps in (None, False) else Path(keep_steps)
    parts, steps = [], []
    for date, wd in by_day:  # one model per day: its plants are grown to its date
        model = model_for(cfg, wd, progress, keep_steps)
        steps.append(model.step)
        d = model.simulate(as_theta(theta, model.scenario.theta))  # leaf defaults: the run's optics
        d.attrs |= when_attrs(cfg, date)
        parts.append(d)
    ds = parts[0] if len(parts) == 1 else concat_days(parts)
    ds.attrs |= steps_attrs(cfg, w)  # the window is recorded whole: which of its steps ran
    ds.attrs["replication_config"] = json.dumps(cfg.effective(w))  # what ran, not None for "the default"
    ds.attrs["preset"] = cfg.preset or "none"
    if theta:  # the values given, as given (the figure's title names them: not the preset's defaults)
        given = theta.to_dict() if isinstance(theta, Theta) else dict(theta)
        ds.attrs["theta_given"] = json.dumps({k: float(v) for k, v in given.items()})
    times = pd.DatetimeIndex(ds["time"].values).tz_localize("UTC")
    if obs is not None:
        a = align(obs, times, timestamps.of(w))
        offsets = read_offsets_s(obs, times, timestamps.of(w), max(steps))  # where the model is read for them
        for s in SERIES:  # the quantities the observations have, each beside its model observable
            if np.isfinite(a[s.value]).any():
                ds[f"obs_{s.value}"], ds[f"obs_{s.sd}"] = ("time", a[s.value]), ("time", a[s.sd])
                ds[f"obs_{s.name}_time_offset_s"] = ("time", offsets[s.name])
        schema.annotate(ds)
        lik = GaussianLikelihood(obs, times, stamps=timestamps.of(w), step=max(steps))
        ds.attrs["observations_fit"] = fit_attribute(lik.series_fit(outputs_of(ds, lik)))
        ds.attrs["observations"] = f"{obs.attrs['source']} ({obs.attrs['provenance']})"
        ds.attrs["observations_provenance"] = obs.attrs["provenance"]
    if out is not None:
        out = Path(out)
        # Everything is computed before the first file is replaced: a run interrupted in its compared
        # run left its own results.nc beside the last run's comparison, figure and summary.
        other = None
        if compare is not None:
            other, _ = run(
                compare,
                weather_file=weather_file,
                observations=obs,  # met by both runs: each run's results say how (observations_fit)
                progress=progress,
                forcing_df=w,
                keep_steps=keep_steps,
            )
        # The forcing is written with the results, not before the run: an interrupted run left its
        # forcing beside the last run's results (a review of interrupted runs). Imported here: the
        # module sets matplotlib's backend.
        from lightfit.weather.plot import plot_forcing, provenance_label

        title = f"{provenance_label(w.attrs)} forcing, {cfg.site.name} {', '.join(cfg.dates)}"
        out.mkdir(parents=True, exist_ok=True)
        write_netcdf(ds, out / "results.nc")
        if other is not None:
            write_netcdf(other, out / "results_compare.nc")
        else:  # an earlier run's comparison would sit beside results it does not belong to
            (out / "results_compare.nc").unlink(missing_ok=True)
        plot(ds, out / "replication.png", compare=other)
        table = summary(ds)
        if ds.attrs.get("an_per") == "leaf":  # the file names what its canopy An is per, as results.nc does
            table = table.rename(columns=lambda c: c.replace("canopy_an_", "canopy_an_per_leaf_area_"))
        replace_text(out / "summary.csv", metadata_lines(summary_metadata(ds)) + table.to_csv(float_format="%.4g"))
        replace_text(out / "forcing.csv", forcing_csv)  # whole or not at all (weather.write_lightfit_csv)
        plot_forcing(w, out / "forcing.png", title=title, tz=cfg.site.timezone)
        if own:  # a folder given stays the caller's
            shutil.rmtree(keep_steps, ignore_errors=True)
    return ds, obs


def outputs_of(ds: xr.Dataset, lik: GaussianLikelihood) -> dict:
    """The forward outputs that ``lik`` reads (each used series' value and Monte Carlo SD, (T,), and
    the unconverged blades per step) from a results set ``ds``."""
    m = {k: ds[k].values for s in lik.series for k in (s.value, s.mc_sd)}
    return m | {CONVERGENCE_KEY: unconverged_per_step(ds)}


#: The folder in a run's ``out`` that keeps its rendered steps until its files are written.
UNFINISHED = ".kept-steps"


#: Several-day results: a segment of day k has id ``segment_id + k · DAY_SEGMENT_STRIDE`` (ids of one day
#: stay below 10¹⁴: :data:`lightfit.plant.growth.SEGMENT_ID_STRIDE` × plant ids < 10⁸).
DAY_SEGMENT_STRIDE = 10**14


def concat_days(parts: list) -> xr.Dataset:
    """Several days' results (each from :meth:`CoupledModel.simulate`) as one Dataset along ``time``.

    Each day has its own plants, grown to its date, and CPlantBox renumbers a plant's segments as
    it grows: segment *i* on 20 April is not segment *i* on 23 June. So the days' segments are
    kept apart: day *k*'s segment ids are offset by *k* × :data:`DAY_SEGMENT_STRIDE`, and a
    per-segment value is NaN (``limitation`` −1, ``converged`` true) at the steps of other days;
    canopy variables are each day's own. ``day`` (time) names each step's date; the attrs the days
    share are kept, and ``date``/``window``/``target_date`` and every attribute whose value differs
    between the days (an adaptive run's ``allocation_*``, ``growth_fingerprint``, a forcing's
    ``weather_source`` …) list each day's value, ``"; "``-separated in date order.
    """
    # the segments' own coordinates (schema.segment_coords), along segment alone
    static = [c for c in parts[0].coords if c != "segment" and parts[0][c].dims == ("segment",)]
    # Per-segment data (leaf_area_above, capacity_factor, an adaptive run's samples): along segment too.
    per_segment = [v for v in parts[0].data_vars if parts[0][v].dims == ("segment",)]
    days_, statics, segments = [], [], []
    for k, p in enumerate(parts):
        p = p.assign_coords(segment=p["segment"].values + k * DAY_SEGMENT_STRIDE)
        statics.append(p[static].reset_coords()[static])
        segments.append(p[per_segment])
        p = p.reset_coords(static, drop=True).drop_vars(per_segment)
        days_.append(p.assign_coords(day=("time", [p.attrs["date"]] * p.sizes["time"])))
    # another day's segment has no leaf there: the schema's value off a blade (NaN, limitation -1), its dtype
    off = {v: schema.variable(v).off_blade for v in parts[0].data_vars if schema.variable(v).off_blade is not None}
    out = xr.concat(days_, dim="time", data_vars="all", join="outer", combine_attrs="override", fill_value=off)
    out = out.assign_coords(xr.concat(statics, dim="segment"))
    out = out.assign(xr.concat(segments, dim="segment").data_vars)
    for v, value in off.items():  # the outer join made int8 and bool float
        out[v] = out[v].astype(value.dtype)
    # Each day allocates adaptive sampling at its own highest sun: every day's point, in order.
    per_day = [k for k in parts[0].attrs if k.startswith("allocation_")]
    temperatures = ("growth_temperature_c", "growth_temperature_applied_c")
    # "series": each day's own, listed like the dates
    per_day += [k for k in temperatures if len({p.attrs.get(k) for p in parts}) > 1]
    # Any other attribute the days do not share (a growth fingerprint, which hashes the target date; a
    # forcing of another source or provenance where the days were run on their own): each day's, not
    # the first day's claimed for all.
    listed = ("date", "window", "target_date", *per_day)
    # a key some day lacks is listed too (empty for that day): one only a later day has (its forcing's
    # anchor, its date_given) was dropped with combine_attrs="override", which keeps the first day's
    every = dict.fromkeys(k for p in parts for k in p.attrs)
    per_day += [k for k in every if k not in listed and len({str(p.attrs.get(k)) for p in parts}) > 1]
    for k in ("date", "window", "target_date", *per_day):
        out.attrs[k] = "; ".join(f"{p.attrs[k]:.3g}" if k in temperatures else str(p.attrs.get(k, "")) for p in parts)
    return schema.annotate(out)


def check_netcdf_name(path: str | Path) -> Path:
    """``path`` if it names a netCDF file (``.nc``) that can be written, else :class:`InputError`
    naming it, before any work: a results file called ``r.csv`` would be netCDF under a name that
    every reader takes for text; a folder of that name, a file where its folder should be, or an
    existing file that is not netCDF (it would be overwritten) are refused too."""
    path = Path(path)
    if path.suffix.lower() != ".nc":
        raise InputError(
            "results are written as netCDF", file=path, parameter="out", expected="a file name ending in .nc"
        )
    if path.is_dir():
        raise InputError(
            "is a folder", file=path, parameter="out", expected="a netCDF file name (the file is written there)"
        )
    for parent in path.parents:
        if parent.exists():
            if not parent.is_dir():
                raise InputError(
                    f"{parent} is a file", file=path, parameter="out", expected="a path whose folders are folders"
                )
            break
    if path.is_file() and path.stat().st_size:  # an empty file (mktemp) is replaced freely
        if not is_netcdf(path):
            raise InputError(
                "exists and is not a netCDF file",
                file=path,
                parameter="out",
                expected="a new name, or a results file to replace",
            )
    return path


def write_netcdf(ds, path: Path) -> Path:
    """netCDF4 via h5netcdf (booleans stored as int8) at ``path`` (a ``.nc`` name)."""
    check_netcdf_name(path)
    ds = ds.copy()
    for v in list(ds.variables):
        if ds[v].dtype == bool:
            ds[v] = ds[v].astype(np.int8)
    if "time_bnds" in ds.variables:  # CF: a time and its bounds in one unit
        for v in ("time", "time_bnds"):
            ds[v].encoding.update(units="seconds since 1970-01-01 00:00:00", calendar="proleptic_gregorian")
    with replaced(path) as tmp:  # an interrupted write leaves the previous file whole
        ds.to_netcdf(tmp, engine="h5netcdf")
    return path
