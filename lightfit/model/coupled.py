r"""The coupled forward model: weather → plants → light → photosynthesis → observables.

:class:`CoupledModel` builds the geometry of one :class:`~lightfit.model.scenario.Scenario` once
and gets the light at its measured segments from an injectable source of *light parts*: by
default a full render of the field at every daytime step's sun position
(:func:`lightfit.light.bridge.make_irradiance`, sun and sky parts per unit DNI / DHI); or the
emulator, or stored renders (``model.with_light(parts_fn)``, sharing geometry and forcing).
Whatever the source, :mod:`lightfit.model.observe` turns parts into observables: PAR at the
plants (incident or absorbed, with its spread and Monte Carlo SD) and canopy net CO2 uptake (with
its Monte Carlo SD), from the JAX photosynthesis of every leaf blade (leaf temperature = air
temperature, CO2 at the leaf surface = air CO2: documented simplifications).

Everything is differentiable with ``jax.grad`` with respect to specular, roughness, subsurface
(PRB through the Mitsuba bridge), the light factor and a Vcmax scale (implicit differentiation
through the photosynthesis fixed point).
"""

from __future__ import annotations

import copy
import json
from collections.abc import Callable, Mapping
from dataclasses import asdict
from functools import cached_property
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd

from lightfit.errors import InputError
from lightfit.files import replaced
from lightfit.killpoint import kill_point
from lightfit.light.bridge import make_irradiance
from lightfit.light.estimator import CLEAR_DAY_DHI_PER_DNI
from lightfit.light.scene import FieldScene
from lightfit.light.sensors import Sensor, default_sensors
from lightfit.model import schema
from lightfit.model.observe import OBSERVABLES, ObservationOperator, an_denominator, an_noise_bias, area_total
from lightfit.model.parameters import Theta, as_theta
from lightfit.model.scenario import Forcing, Scenario, adaptive_limits, projected_rays, sun_positions_deg
from lightfit.photosynthesis.canopy import capacity_factor, leaf_area_above, profile_for
from lightfit.photosynthesis.parameters import growth_temperature, kattge_knorr_growth_temperature
from lightfit.plant import build, centre_height_m, one_sided_area_m2, organ_class
from lightfit.precision import PRECISION, precision
from lightfit.progress import progress_bar
from lightfit.weather import timestamps
from lightfit.weather.reconstruct import Anchor

#: A source of light parts: ``light(theta) -> (values, se)``, each (T_day, 4, S + P) in
#: :data:`~lightfit.light.estimator.PARTS` order, per unit DNI / DHI: S measured segments, then
#: P virtual sensors (:attr:`CoupledModel.sensors`).
LightParts = Callable[[Theta], tuple[jax.Array, jax.Array]]


def allocation_point(
    forcing: Forcing, sun_deg: np.ndarray, leaf: np.ndarray
) -> tuple[np.ndarray, np.ndarray, float, float]:
    """``(leaf, sun_deg, dni_par, dhi_par)`` of the daytime step with the highest sun (the largest
    light, which dominates daily sums), its PAR weighting the sun and sky parts; with no daytime
    step, the highest sun and a clear day's mix (DHI / DNI = 0.3). ``sun_deg``: (T, 2) elevation
    and azimuth, degrees, of the steps of ``forcing``."""
    steps = np.flatnonzero(forcing.day)
    i = steps[np.argmax(sun_deg[steps, 0])] if len(steps) else int(np.argmax(sun_deg[:, 0]))
    dni, dhi = float(forcing.dni_par[i]), float(forcing.dhi_par[i])
    if dni + dhi <= 0:
        dni, dhi = 1.0, CLEAR_DAY_DHI_PER_DNI
    return np.asarray(leaf, np.float64), np.asarray(sun_deg[i], np.float64).copy(), dni, dhi


class CoupledModel:
    """Geometry, forcing and observation operator of one :class:`Scenario`, built once.

    Args:
        scenario: the run.
        light: source of light parts (default: full renders, :meth:`render`).
        progress: show plant growth, and a bar over the steps while an eager run renders them.
        sensors: virtual horizontal sensors rendered with the segments (:mod:`lightfit.light.sensors`);
            default (``None``): a ceptometer on the soil of the measurement area
            (:func:`~lightfit.light.sensors.default_sensors`: ≈ 0.2 % of the main job's
            evaluations, so it is always rendered); ``()``: none (its observables are NaN).
        keep_steps: a folder in which :meth:`render` keeps each step as soon as it is rendered and
            from which it reads the steps already there, so that a run killed half-way and started
            again renders only the rest, to the same bits (:meth:`step_files`; not while JAX traces).
    """

    def __init__(
        self,
        scenario: Scenario,
        *,
        light: LightParts | None = None,
        progress: bool = False,
        sensors: tuple[Sensor, ...] | None = None,
        keep_steps: str | Path | None = None,
    ):
        if precision() != PRECISION:  # JAX would truncate every float64 array, with a warning each
            raise InputError(
                f"JAX computes in {precision()}",
                parameter="precision",
                expected=f"{PRECISION}: call lightfit.precision.use_float64() before building a CoupledModel "
                "(lightfit has no float32 mode; importing it does not change JAX's configuration)",
            )
        self.scenario = sc = scenario
        self.progress = progress
        self.keep_steps = None if keep_steps is None else Path(keep_steps)
        self.sensors = default_sensors(sc.field, sc.ceptometer_height_m) if sensors is None else tuple(sensors)
        self.geometry = build(sc.field, tile=sc.measured_tile, progress=progress)
        seg = self.geometry.segments
        meas = seg[seg["measured"]].sort_values("segment_id")
        self.segments = meas.reset_index(drop=True)
        self.segment_id = meas["segment_id"].to_numpy()
        self.area_m2 = one_sided_area_m2(meas)
        self.is_blade = organ_class(meas) == "blade"
        if not self.is_blade.any():
            raise InputError(
                "no leaf blades in the measurement area",
                parameter="field",
                expected="plants grown long enough to have leaves",
            )
        self.ground_area_m2 = sc.ground_area_m2
        params = sc.photosynthesis_params()
        #: the capacity profile's kn (per unit LAI) and each measured blade's LAI above it (m² m⁻²)
        self.kn = sc.kn()
        self.lai_above, lai = self._lai_above()
        w = sc.weather
        self.times = w.index
        #: what ``times`` label: the forcing's :class:`~lightfit.weather.timestamps.Timestamps`
        self.timestamps = timestamps.of(w)
        #: the forcing's step (its rows' shortest spacing; 0 for one row: nothing to read between),
        #: kept by cut models (:func:`~lightfit.model.emulator.restrict`): observations between two
        #: steps this far apart are read between them (:func:`~lightfit.inference.observations.interpolation`)
        self.step = timestamps.step_of(w.index) or pd.Timedelta(0)
        self.forcing = Forcing.of(w)
        self.day = self.forcing.day
        self.sun_deg = sun_positions_deg(w)
        self.operator = ObservationOperator(
            forcing=self.forcing,
            area_m2=self.area_m2,
            is_blade=self.is_blade,
            par_kind=sc.par_kind,
            denominator_m2=an_denominator(self.area_m2[self.is_blade], sc.an_per, self.ground_area_m2),
            params=params,
            ground_area_m2=self.ground_area_m2,
            sun_elevation_deg=self.sun_deg[:, 0].copy(),
            soil_respiration_umol_m2_s=sc.soil_respiration_umol_m2_s,
            soil_respiration_q10=sc.soil_respiration_q10,
            sensors=tuple(s.name for s in self.sensors),
            capacity=None if self.kn == 0 else capacity_factor(self.lai_above, self.kn),
            capacity_base=float(capacity_factor(lai, self.kn)),
            segment_id=self.segment_id,
            times=self.times,
        )
        self.light = self.render if light is None else light

    def _lai_above(self) -> tuple[np.ndarray, float]:
        """(B,) each measured blade segment's cumulative LAI above its centre (m² m⁻²), and the LAI of the
        whole canopy, from every blade the geometry grew (measured and buffer plants) over the ground
        those plants stand on: a horizontally uniform canopy, and the same for every tile of a
        distributed run that grows the same plants."""
        # Sorted by id: the sums then run in one order whatever order a tile's geometry has.
        seg = self.geometry.segments.sort_values("segment_id")
        blade = organ_class(seg) == "blade"
        z = centre_height_m(seg)[blade]
        area = one_sided_area_m2(seg)[blade]
        ground = len(self.geometry.plants) * self.scenario.field.area_per_plant_m2
        lai = pd.Series(leaf_area_above(z, area, ground), index=seg["segment_id"].to_numpy()[blade])
        return lai.loc[self.segment_id[self.is_blade]].to_numpy(), float(area.sum() / ground)

    @property
    def n_columns(self) -> int:
        """Columns of the light parts: measured segments, then virtual sensors."""
        return len(self.segment_id) + len(self.sensors)

    def with_light(self, light: LightParts) -> CoupledModel:
        """This model with another source of light parts (geometry and forcing shared, not rebuilt)."""
        other = copy.copy(self)
        other.light = light
        return other

    # -- forward -----------------------------------------------------------------------
    def theta(self, theta: Theta | Mapping[str, float] | None = None) -> Theta:
        """``theta`` completed with this scenario's defaults (the leaf parameters of its optics)."""
        return as_theta(theta, base=self.scenario.theta)

    @cached_property
    def irradiance(self):
        """The Mitsuba scene's JAX irradiance function of the measured segments (built on first use)."""
        sc = self.scenario
        scene = FieldScene(self.geometry.mesh, sc.optics, sky=sc.sky, cell=self.geometry.cell)
        return make_irradiance(
            scene,
            self.segment_id,
            samples=sc.samples,
            bounces=sc.bounces,
            sensors=self.sensors,
            target_rse=sc.target_rse,
            allocate_at=self.allocation_point if sc.target_rse is not None else None,
            **adaptive_limits(),
            direct=sc.direct,
            direct_rays_per_m2=sc.direct_rays_per_m2,
        )

    @property
    def allocation_point(self) -> tuple[np.ndarray, np.ndarray, float, float]:
        """``(leaf, sun_deg, dni_par, dhi_par)`` at which adaptive sampling (``Scenario.target_rse``)
        chooses each segment's K, once, kept for every step and leaf: ``Scenario.allocate_at``
        where given, else :func:`allocation_point` of this model's steps. A fixed point, so
        renders are a pure function of the leaf parameters (gradients and the emulator's cache
        stay valid)."""
        sc = self.scenario
        if sc.allocate_at is not None:
            leaf, sun, dni, dhi = sc.allocate_at
            return np.asarray(leaf, np.float64), np.asarray(sun, np.float64), float(dni), float(dhi)
        return allocation_point(self.forcing, self.sun_deg, np.asarray(sc.theta.leaf, np.float64))

    def _allocated_at(self) -> dict:
        """Results attributes naming where adaptive sampling chose each segment's K (what
        ``reached_rse`` refers to): the sun and the PAR weighting of the sun and sky parts. None
        for a run of night steps only that allocates by itself: its point is a sun below the
        horizon weighted 1 : 0.3, not a step's PAR."""
        if self.scenario.allocate_at is None and not self.day.any():
            return {}
        leaf, sun, dni, dhi = self.allocation_point
        return {
            "allocation_sun_elevation_deg": float(sun[0]),
            "allocation_sun_azimuth_deg": float(sun[1]),
            "allocation_dni_par_umol_m2_s": float(dni),
            "allocation_dhi_par_umol_m2_s": float(dhi),
        }

    def step_files(self, leaf, steps) -> list[Path]:
        """The files in :attr:`keep_steps` that keep the renders of ``steps`` (indices of
        :attr:`times`) at ``leaf`` (3,): named by everything a render depends on
        (:func:`~lightfit.model.emulator.render_key`, the leaf, the step's time, and the Mitsuba
        variant and CPU target that render it: other kernels round otherwise, and a run resumed on
        another machine or with another ``LIGHTFIT_LLVM_TARGET`` mixed two backends' steps, its
        results those of neither), so a run with other settings never reads them."""
        from lightfit.light.backend import info
        from lightfit.model.emulator import render_file, render_key  # the emulator builds on this module

        backend = info()  # configures Mitsuba as the render would: the variant and target it renders with
        # hashes the geometry: once for all the steps
        key = render_key(self) | {"mitsuba_variant": backend.variant, "llvm_target": backend.llvm_target}
        leaf = np.asarray(leaf, np.float64)
        return [
            render_file(self.keep_steps, key | {"step_utc": str(self.times[i].tz_convert("UTC"))}, leaf) for i in steps
        ]

    def render(self, theta: Theta | Mapping[str, float]):
        """Rendered parts for every daytime step: values and SE arrays of shape (T_day, 4, S + P)."""
        leaf = self.theta(theta).leaf
        vals, ses = [], []
        days = np.flatnonzero(self.day)
        # Not while JAX traces (calibration's jit and grad): the loop runs once then, at trace time.
        eager = not isinstance(leaf, jax.core.Tracer)
        show = self.progress and len(days) > 0 and eager
        keep = self.step_files(leaf, days) if self.keep_steps is not None and eager else [None] * len(days)
        kept = sum(f is not None and f.exists() for f in keep)
        label = "rendering steps" + (f" ({kept} of {len(days)} kept by an interrupted run)" if kept else "")
        first = "choosing each segment's K" if self.scenario.target_rse is not None else ""
        with progress_bar(label, len(days), show=show) as bar:
            bar.update(info=first)
            for n, (i, file) in enumerate(zip(days, keep)):
                if file is not None and file.exists():
                    with np.load(file) as z:
                        v, s = jnp.asarray(z["values"]), jnp.asarray(z["se"])
                else:
                    v, s = self.irradiance(leaf, jnp.asarray(self.sun_deg[i]), self.scenario.seed)
                    if file is not None:
                        file.parent.mkdir(parents=True, exist_ok=True)
                        with replaced(file) as tmp:  # a kill leaves the step whole or absent
                            np.savez(tmp, values=np.asarray(v), se=np.asarray(s))
                        kill_point("step", n + 1)
                if show:  # JAX dispatches asynchronously: the bar moves when the step is rendered
                    jax.block_until_ready(v)
                vals.append(v)
                ses.append(s)
                bar.update(completed=n + 1, info=f"sun {self.sun_deg[i, 0]:.0f}°")
        if not vals:  # only night steps: nothing to render (and no scene to build)
            none = jnp.zeros((0, 4, self.n_columns), jnp.asarray(leaf).dtype)
            return none, none
        return jnp.stack(vals), jnp.stack(ses)

    def render_many(self, thetas):
        """:meth:`render` at each of ``thetas`` (Theta or mappings), tracing the paths once for all
        (:meth:`lightfit.light.estimator.SegmentEstimator.render_many`): yields, per theta as soon
        as it is done, numpy ``(values, se)`` each (T_day, 4, S + P), bitwise :meth:`render`'s."""
        leaf = np.stack([np.asarray(jnp.asarray(self.theta(t).leaf)) for t in thetas])
        days = np.flatnonzero(self.day)
        if len(days) == 0:
            for _ in leaf:
                yield np.zeros((0, 4, self.n_columns), leaf.dtype), np.zeros((0, 4, self.n_columns), leaf.dtype)
            return
        # the sun positions as render() hands them to the irradiance function (in the leaf's dtype)
        suns = np.stack([np.asarray(jnp.asarray(jnp.asarray(self.sun_deg[i]), leaf.dtype)) for i in days])
        yield from self.irradiance.render_many(leaf, suns, self.scenario.seed)

    def parts(self, theta: Theta | Mapping[str, float]):
        """Light parts from this model's source (:meth:`render` unless injected), each (T_day, 4, S + P)."""
        return self.light(self.theta(theta))

    def observe(self, theta: Theta | Mapping[str, float]) -> dict:
        """Observables and per-segment fields for all time steps (night steps: zero light).

        Returns a dict of JAX arrays (see :meth:`ObservationOperator.__call__`): the
        :data:`~lightfit.model.observe.OBSERVABLES` (T,), per segment (T, S) incident and absorbed
        PAR and their Monte Carlo SDs, per blade (T, B) leaf An and its Monte Carlo SD, the full
        photosynthesis result on the blades under ``"photosynthesis"`` and ``"blade_index"``.
        """
        theta = self.theta(theta)
        return self.operator(*self.parts(theta), theta)

    # -- results ---------------------------------------------------------------------
    def simulate(self, theta: Theta | Mapping[str, float] | None = None):
        """Run forward at ``theta`` (defaults for missing values) and return an xarray Dataset.

        Variables, units and meanings: :mod:`lightfit.model.schema` (written as attributes).
        """
        import xarray as xr

        th = self.theta(theta)
        o = self.observe(th)
        b = o["blade_index"]
        # Jensen bias of An from the light's Monte Carlo noise: reported, not subtracted (docs/model.md).
        an_bias = an_noise_bias(
            o["absorbed_par_umol_m2_s"][:, b],
            o["absorbed_par_mc_sd_umol_m2_s"][:, b],
            self.forcing,
            self.operator.photosynthesis_params(th.vcmax_scale),
            leaf=self.operator.leaf(),
        )
        canopy_bias = area_total(an_bias, jnp.zeros_like(an_bias), self.area_m2[b], self.operator.denominator_m2)[0]
        ps = o["photosynthesis"]
        light = ("incident_par_umol_m2_s", "absorbed_par_umol_m2_s")
        light += tuple(k.replace("_par_", "_par_mc_sd_") for k in light)
        leaf = {
            "leaf_an_umol_m2_s": ps.an_umol_m2_s,
            "leaf_an_mc_sd_umol_m2_s": o["leaf_an_mc_sd_umol_m2_s"],
            "leaf_an_mc_bias_umol_m2_s": an_bias,
            "leaf_gs_mol_m2_s": ps.gs_mol_m2_s,
            "leaf_ci_umol_mol": ps.ci_umol_mol,
            "leaf_vc_umol_m2_s": ps.vc_umol_m2_s,
            "leaf_vj_umol_m2_s": ps.vj_umol_m2_s,
            "limitation": ps.limitation,
            "converged": ps.converged,
        }
        w = self.scenario.weather
        weather = {"weather_par_umol_m2_s": "par_umol_m2_s", "dni_w_m2": "dni_w_m2", "dhi_w_m2": "dhi_w_m2"}
        weather |= {k: k for k in ("tair_c", "co2_ppm", "rh", "pair_kpa", "sun_elevation_deg", "sun_azimuth_deg")}
        ds = xr.Dataset(
            {
                **{k: (("time", "segment"), np.asarray(o[k])) for k in light},
                **{k: (("time", "segment"), schema.on_segments(k, v, self.is_blade)) for k, v in leaf.items()},
                **{k: ("time", np.asarray(o[k])) for k in OBSERVABLES},
                "canopy_an_mc_bias_umol_m2_s": ("time", np.asarray(canopy_bias)),
                **{k: ("time", w[c].to_numpy(np.float64)) for k, c in weather.items() if c in w},
            },
            coords={
                "time": self.times.tz_convert("UTC").tz_localize(None).values,
                **schema.segment_coords(self.segments),
            },
        )
        capacity = np.ones(len(b)) if self.operator.capacity is None else self.operator.capacity
        ds["leaf_area_above"] = ("segment", schema.on_segments("leaf_area_above", self.lai_above, self.is_blade))
        ds["capacity_factor"] = ("segment", schema.on_segments("capacity_factor", capacity, self.is_blade))
        sc = self.scenario
        if sc.target_rse is not None:
            alloc = self.irradiance.allocation(sc.seed)
            ds["samples_per_segment"] = ("segment", np.asarray(alloc.meta["samples_per_segment"], np.int64))
            ds["reached_rse"] = ("segment", np.asarray(alloc.meta["reached_rse"], np.float64))
            ds["stopped_on_floor"] = ("segment", np.asarray(alloc.meta["stopped_on_floor"], np.int8))
        bounds = self.timestamps.bounds(self.times.tz_convert("UTC").tz_localize(None))
        if bounds is not None:
            ds["time_bnds"] = (("time", "bound"), np.column_stack([b.values for b in bounds]))
        schema.annotate(ds)
        warn_unconverged(ds)
        fld = sc.field
        t_g = growth_temperature(sc.photosynthesis, sc.growth_temperature_c)
        rays = projected_rays(sc.direct, sc.direct_rays_per_m2)
        ds.attrs = {
            "title": "lightfit coupled run",
            "conventions": "variable attributes: lightfit.model.schema (CF-style units, long_name)",
            "precision": precision(),
            "time_zone": "UTC",
            **weather_attrs(w),
            **fld.attrs(),
            "n_tiles": sc.n_tiles,
            "tile": -1 if sc.tile is None else sc.tile,
            "ground_area_m2": self.ground_area_m2,
            "samples": sc.samples,
            **(
                {}
                if sc.target_rse is None
                else {"target_rse": sc.target_rse, **adaptive_limits(), **self._allocated_at()}
            ),
            "bounces": sc.bounces,
            "direct": sc.direct,
            **({} if rays is None else {"direct_rays_per_m2": rays}),
            "render_seed": sc.seed,
            "photosynthesis": sc.photosynthesis,
            # a JSON object (netCDF attributes hold no mappings): "{}" where the set is as named
            "photosynthesis_overrides": json.dumps(dict(sc.photosynthesis_overrides)),
            "vcmax_profile": str(profile_for(sc.vcmax_profile, sc.photosynthesis)),
            **(
                {}
                if t_g is None
                else {"growth_temperature_c": t_g, "growth_temperature_applied_c": kattge_knorr_growth_temperature(t_g)}
            ),
            "kn_per_lai": self.kn,
            "par_kind": sc.par_kind,
            "an_per": sc.an_per,
            "soil_respiration_umol_m2_s": self.operator.soil_respiration_umol_m2_s,
            "soil_respiration_q10": self.operator.soil_respiration_q10,
            "sky": sc.sky,
            "ceptometer": describe_sensors(self.sensors),
            "soil_albedo": sc.optics.soil_albedo,
            "base_color": sc.optics.base_color,
            **{f"theta_{k}": v for k, v in th.to_dict().items()},
            "leaf_temperature": "air temperature (assumption)",
            "co2_at_leaf_surface": "air CO2 (assumption)",
            **software_attrs(),
        }
        return ds


#: The results attributes that describe the forcing (:func:`weather_attrs`): the optional ones
#: (``weather_date_given``, ``weather_anchor``) are absent where the forcing has none.
WEATHER_ATTRS = (
    "weather_provenance",
    "weather_date_given",
    "weather_source",
    "weather_timestamps",
    "weather_split_model",
    "weather_anchor",
)


def weather_attrs(w) -> dict:
    """What the forcing ``w`` is, as results attributes (:data:`WEATHER_ATTRS`): its declared
    provenance, date, source file, timestamps, direct/diffuse split and anchor — from its
    attributes, which a scenario's digest does not hash (it hashes the rows), so a field-run
    resumed with a copy of the forcing under another name or provenance takes them from here, not
    from a kept task (:func:`lightfit.distributed.run.gather`)."""
    a = Anchor.of(w.attrs)
    return {
        "weather_provenance": str(w.attrs.get("provenance", "unknown")),
        **({"weather_date_given": w.attrs["date_given"]} if w.attrs.get("date_given") else {}),
        "weather_source": str(w.attrs.get("source", "")),
        "weather_timestamps": timestamps.of(w).describe(),
        "weather_split_model": str(w.attrs.get("split_model", "unknown")),
        **({"weather_anchor": json.dumps(asdict(a))} if a else {}),
    }


def software_attrs() -> dict:
    """What made a results file, as netCDF attributes: ``software_versions`` (JSON: lightfit, its
    estimator and projection, Mitsuba, Dr.Jit, JAX, CPlantBox), ``mitsuba_variant`` (the one this
    process rendered with) and ``llvm_target`` (the CPU its kernels were compiled for): results are
    reproducible to the bit on both, others round otherwise (``LIGHTFIT_LLVM_TARGET`` fixes the CPU's)."""
    import json

    from lightfit.light.backend import llvm_target_in_use, variant_in_use
    from lightfit.model.emulator import run_versions  # emulator imports this module: here, not at the top

    variant = variant_in_use()
    return {
        "software_versions": json.dumps(run_versions()),
        "mitsuba_variant": variant or "none: the light was not rendered in this process",
        "llvm_target": llvm_target_in_use() or "none: the light was not rendered on the CPU in this process",
    }


def describe_sensors(sensors) -> str:
    """One line per run for results attributes: each sensor's placements, bar length and height."""
    if not sensors:
        return "none (not rendered)"
    out = []
    for s in sensors:
        a, b = s.lines()
        length = float(np.linalg.norm(b - a, axis=1).mean())
        out.append(f"{s.name}: {len(a)} bar(s) of {length:.2f} m across the rows at {s.height_m:.2f} m, upward-facing")
    return "; ".join(out)


class NonConvergenceWarning(UserWarning):
    """Some leaf photosynthesis solves did not converge (their values are the solver's last iterate)."""


def unconverged_per_step(ds) -> np.ndarray:
    """Number of leaf blades whose photosynthesis solve did not converge, per time step (T,) ints."""
    blades = ds["is_blade"].values.astype(bool)
    return (~ds["converged"].values[:, blades].astype(bool)).sum(axis=1)


def warn_unconverged(ds) -> int:
    """Warn (:class:`NonConvergenceWarning`) naming the steps and blades whose solve did not converge.

    Returns the number of unconverged blade-steps (0: no warning). The results keep the flags
    (``converged``) and :func:`lightfit.report.summary` counts them per step.
    """
    n = unconverged_per_step(ds)
    if not n.any():
        return 0
    import warnings

    t = pd.DatetimeIndex(ds["time"].values)
    steps = ", ".join(f"{t[i]:%Y-%m-%d %H:%M} UTC ({n[i]} blades)" for i in np.flatnonzero(n))
    warnings.warn(
        f"leaf photosynthesis did not converge for {int(n.sum())} blade-step(s) of "
        f"{int(ds['is_blade'].values.astype(bool).sum())} blades at {np.count_nonzero(n)} step(s): {steps}; "
        "their values are the solver's last iterate (results.nc: converged = 0)",
        NonConvergenceWarning,
        stacklevel=3,
    )
    return int(n.sum())


__all__ = [
    "CoupledModel",
    "LightParts",
    "NonConvergenceWarning",
    "Scenario",
    "unconverged_per_step",
    "warn_unconverged",
]
