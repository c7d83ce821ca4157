r"""The coupled forward model: weather → plants → light → photosynthesis → observables.

For every daytime step t of a diurnal run the field is rendered once at that step's sun position
(:func:`lightfit.light.bridge.make_irradiance`, sun and sky parts per unit DNI / DHI), and the
weather rescales the parts:

.. math::

    I_{s,t} = f_{PAR}\,\big(\mathrm{DNI}^{PAR}_t\,i^{\odot}_s + \mathrm{DHI}^{PAR}_t\,i^{sky}_s\big)

with :math:`\mathrm{DNI}^{PAR} = 2.285\,\mathrm{DNI}` (µmol J⁻¹, 0.50 × 4.57) and ``light_factor``
:math:`f_{PAR}` (the reference paper rescaled TERENO PAR by a fitted 1.637). Absorbed PAR of the
leaf blades drives the JAX photosynthesis (leaf temperature = air temperature, CO2 at the leaf
surface = air CO2: documented simplifications). Observables per step, as a gas-exchange chamber
sees them:

- ``par_umol_m2_s``: area-weighted mean over the measured segments of incident (default) or
  absorbed PAR, per unit one-sided area, with its spread ``par_sd_umol_m2_s`` across segments;
- ``an_umol_m2_s``: net CO2 uptake of the measured leaf blades per unit leaf area (one-sided) or
  per unit ground area of the measurement area.

Everything is differentiable with ``jax.grad`` with respect to specular, roughness, subsurface
(PRB through the Mitsuba bridge), the light factor and a Vcmax scale (implicit differentiation
through the photosynthesis fixed point).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from dataclasses import field as dc_field

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd

from lightfit.errors import InputError
from lightfit.light.bridge import make_irradiance
from lightfit.light.estimator import PARTS
from lightfit.light.scene import FieldScene, Optics
from lightfit.model.parameters import Theta, as_theta
from lightfit.photosynthesis import parameter_set, solve
from lightfit.plant import Field, build
from lightfit.weather.units import par_from_ghi

#: Calibrated parameters and their domains: (lower, upper) — None means unbounded above.
PARAMETERS = {
    "specular": (0.0, 1.0),
    "roughness": (0.0, 1.0),
    "subsurface": (0.0, 1.0),
    "light_factor": (0.0, None),
    "vcmax_scale": (0.0, None),
}
#: The observation operator's outputs per time step (Monte Carlo uncertainty as an SD).
OBSERVABLES = (
    "plant_par_umol_m2_s",
    "plant_par_spread_umol_m2_s",
    "plant_par_mc_sd_umol_m2_s",
    "canopy_an_umol_m2_s",
    "canopy_an_mc_sd_umol_m2_s",
)
DEFAULT_THETA = {"specular": 0.5, "roughness": 0.5, "subsurface": 0.3, "light_factor": 1.0, "vcmax_scale": 1.0}


@dataclass
class Scenario:
    """Everything a forward run needs besides the calibrated parameters.

    Attributes:
        weather: contract series with solar columns at the run's time steps (e.g.
            ``weather.window(df, "2016-04-20 05:00", 14, "30min")``).
        field: the field (plants, buffers, seed, growth).
        samples, bounces, seed: irradiance estimator settings (seed: common random numbers).
        photosynthesis: parameter-set name (``lightfit.photosynthesis.parameter_set``).
        par_kind: ``"incident"`` or ``"absorbed"`` PAR for the PAR observable.
        an_per: ``"leaf"`` (per one-sided leaf area) or ``"ground"`` (per ground area).
        optics: soil albedo, base colour and the BSDF parameters used to freeze sampling.
        sky: ``"isotropic"`` or ``"overcast"``.
        n_tiles, tile: run only tile ``tile`` of ``field.tiles(n_tiles)`` (its plants measured,
            its buffer ring as geometry); ``None`` runs the whole measurement area.
    """

    weather: pd.DataFrame
    field: Field = dc_field(default_factory=lambda: Field(n_plants=9, buffer_rows=2, seed=1))
    samples: int = 32
    bounces: int = 3
    seed: int = 0
    photosynthesis: str = "giraud2023"
    par_kind: str = "incident"
    an_per: str = "ground"
    optics: Optics = dc_field(default_factory=Optics)
    sky: str = "isotropic"
    n_tiles: int = 1
    tile: int | None = None

    def __post_init__(self):
        if self.tile is not None and not 0 <= self.tile < self.n_tiles:
            raise InputError(f"tile={self.tile!r}", column="tile", expected=f"0 … {self.n_tiles - 1} or None")
        if self.par_kind not in ("incident", "absorbed"):
            raise InputError(f"par_kind={self.par_kind!r}", column="par_kind", expected="'incident' or 'absorbed'")
        if self.an_per not in ("leaf", "ground"):
            raise InputError(f"an_per={self.an_per!r}", column="an_per", expected="'leaf' or 'ground'")
        need = {"sun_elevation_deg", "sun_azimuth_deg", "dni_w_m2", "dhi_w_m2", "tair_c", "rh", "pair_kpa", "co2_ppm"}
        missing = need - set(self.weather.columns)
        if missing:
            raise InputError(
                f"weather lacks {sorted(missing)}",
                column="weather",
                expected="a contract series with solar columns (lightfit.weather.add_solar)",
            )


class CoupledModel:
    """Geometry, scene and JAX functions of one :class:`Scenario`, built once."""

    def __init__(self, scenario: Scenario, *, progress: bool = False):
        self.scenario = sc = scenario
        tile = sc.field.tiles(sc.n_tiles)[sc.tile] if sc.tile is not None else None
        self.geometry = build(sc.field, tile=tile, progress=progress)
        seg = self.geometry.segments
        meas = seg[seg["measured"]].sort_values("segment_id")
        self.segments = meas.reset_index(drop=True)
        self.segment_id = meas["segment_id"].to_numpy()
        self.area_m2 = (
            meas["blade_area_m2"].where(meas["blade_area_m2"] > 0, 2 * np.pi * meas["radius_m"] * meas["length_m"])
        ).to_numpy()
        self.is_blade = ((meas["organ_type"] == "leaf") & (meas["blade_area_m2"] > 0)).to_numpy()
        if not self.is_blade.any():
            raise InputError(
                "no leaf blades in the measurement area",
                column="field",
                expected="plants grown long enough to have leaves",
            )
        fld = sc.field
        n_measured = fld.n**2 if tile is None else len(tile.measured)
        self.ground_area_m2 = n_measured * fld.plant_spacing_m * fld.row_spacing_m
        self.scene = FieldScene(self.geometry.mesh, sc.optics, sky=sc.sky)
        self.irradiance = make_irradiance(self.scene, self.segment_id, samples=sc.samples, bounces=sc.bounces)
        w = sc.weather
        self.times = w.index
        self.day = ((w["dni_w_m2"] + w["dhi_w_m2"]) > 0).to_numpy() & (w["sun_elevation_deg"] > -1).to_numpy()
        dt = np.float64
        self.sun_deg = np.column_stack([w["sun_elevation_deg"], w["sun_azimuth_deg"]]).astype(dt)
        self.dni_par = np.asarray(par_from_ghi(w["dni_w_m2"]), dt)
        self.dhi_par = np.asarray(par_from_ghi(w["dhi_w_m2"]), dt)
        self.tair_c = w["tair_c"].to_numpy(dt)
        self.rh = w["rh"].to_numpy(dt)
        self.pair_kpa = w["pair_kpa"].to_numpy(dt)
        self.co2_ppm = w["co2_ppm"].to_numpy(dt)
        self.params = parameter_set(sc.photosynthesis)

    # -- forward -----------------------------------------------------------------------
    def parts(self, theta: Theta | Mapping[str, float]):
        """Rendered parts for every daytime step: values and SE arrays of shape (T_day, 4, S)."""
        leaf = as_theta(theta).leaf
        vals, ses = [], []
        for i in np.flatnonzero(self.day):
            v, s = self.irradiance(leaf, jnp.asarray(self.sun_deg[i]), self.scenario.seed)
            vals.append(v)
            ses.append(s)
        return jnp.stack(vals), jnp.stack(ses)

    def observe(self, theta: Theta | Mapping[str, float]) -> dict:
        """Observables and per-segment fields for all time steps (night steps: zero light).

        Returns a dict of JAX arrays: the :data:`OBSERVABLES` (T,), and per segment (T, S): ``incident_par``,
        ``absorbed_par``, ``an``, plus the photosynthesis result (blades only) under ``"ps"``.
        """
        theta = as_theta(theta)
        vals, ses = self.parts(theta)
        T, S = len(self.times), len(self.segment_id)
        day = np.flatnonzero(self.day)
        f = jnp.asarray(theta.light_factor, jnp.float64)
        dni = f * jnp.asarray(self.dni_par[day])[:, None]
        dhi = f * jnp.asarray(self.dhi_par[day])[:, None]
        ix = {p: PARTS.index(p) for p in PARTS}
        inc_d = dni * vals[:, ix["incident_sun"]] + dhi * vals[:, ix["incident_sky"]]
        abs_d = dni * vals[:, ix["absorbed_sun"]] + dhi * vals[:, ix["absorbed_sky"]]
        inc_se = jnp.sqrt((dni * ses[:, ix["incident_sun"]]) ** 2 + (dhi * ses[:, ix["incident_sky"]]) ** 2)
        abs_se = jnp.sqrt((dni * ses[:, ix["absorbed_sun"]]) ** 2 + (dhi * ses[:, ix["absorbed_sky"]]) ** 2)
        zeros = jnp.zeros((T, S))
        inc = zeros.at[day].set(inc_d)
        absorbed = zeros.at[day].set(abs_d)
        inc_se_full = zeros.at[day].set(inc_se)
        abs_se_full = zeros.at[day].set(abs_se)
        # PAR observable: area-weighted mean over all measured segments.
        w = jnp.asarray(self.area_m2 / self.area_m2.sum())
        par_field, par_se = (inc, inc_se_full) if self.scenario.par_kind == "incident" else (absorbed, abs_se_full)
        par_mean = par_field @ w
        par_sd = jnp.sqrt(jnp.maximum((par_field - par_mean[:, None]) ** 2 @ w, 0.0))
        par_mc_var = (par_se**2) @ (w**2)
        # Photosynthesis on the leaf blades.
        b = np.flatnonzero(self.is_blade)
        params = eqx.tree_at(
            lambda p: p.fvcb.vcmax_ref_umol_m2_s,
            self.params,
            self.params.fvcb.vcmax_ref_umol_m2_s * jnp.asarray(theta.vcmax_scale, jnp.float64),
        )
        q = jnp.maximum(absorbed[:, b], 0.0)
        shape = q.shape
        t_c, co2 = jnp.broadcast_to(self.tair_c[:, None], shape), jnp.broadcast_to(self.co2_ppm[:, None], shape)
        rh, p_kpa = jnp.broadcast_to(self.rh[:, None], shape), jnp.broadcast_to(self.pair_kpa[:, None], shape)
        ps = solve(q, t_c, co2, rh, p_kpa, params)
        # dAn/dPAR per segment (segments are independent) for the Monte Carlo variance of An.
        _, dan = jax.jvp(lambda x: solve(x, t_c, co2, rh, p_kpa, params).an_umol_m2_s, (q,), (jnp.ones_like(q),))
        a_leaf = jnp.asarray(self.area_m2[b])
        denom = a_leaf.sum() if self.scenario.an_per == "leaf" else self.ground_area_m2
        an = ps.an_umol_m2_s @ a_leaf / denom
        an_mc_var = (jax.lax.stop_gradient(dan) * abs_se_full[:, b]) ** 2 @ (a_leaf / denom) ** 2
        return {
            "plant_par_umol_m2_s": par_mean,
            "plant_par_spread_umol_m2_s": par_sd,
            "plant_par_mc_sd_umol_m2_s": jax.lax.stop_gradient(jnp.sqrt(par_mc_var)),
            "canopy_an_umol_m2_s": an,
            "canopy_an_mc_sd_umol_m2_s": jax.lax.stop_gradient(jnp.sqrt(an_mc_var)),
            "incident_par": inc,
            "absorbed_par": absorbed,
            "incident_se": inc_se_full,
            "absorbed_se": abs_se_full,
            "ps": ps,
            "blade_index": b,
        }

    # -- results ---------------------------------------------------------------------
    def simulate(self, theta: Theta | Mapping[str, float] | None = None):
        """Run forward at ``theta`` (defaults for missing keys) and return an xarray Dataset."""
        import xarray as xr

        th = as_theta(theta)
        o = self.observe(th)
        b = o["blade_index"]
        T, S = len(self.times), len(self.segment_id)

        def per_segment(x, fill=np.nan, dtype=float):
            out = np.full((T, S), fill, dtype=dtype)
            out[:, b] = np.asarray(x)
            return out

        ps = o["ps"]
        times = self.times.tz_convert("UTC").tz_localize(None).values
        seg = self.segments
        ds = xr.Dataset(
            {
                "incident_par_umol_m2_s": (("time", "segment"), np.asarray(o["incident_par"])),
                "absorbed_par_umol_m2_s": (("time", "segment"), np.asarray(o["absorbed_par"])),
                "incident_par_se_umol_m2_s": (("time", "segment"), np.asarray(o["incident_se"])),
                "absorbed_par_se_umol_m2_s": (("time", "segment"), np.asarray(o["absorbed_se"])),
                "an_umol_m2_s": (("time", "segment"), per_segment(ps.an_umol_m2_s)),
                "gs_mol_m2_s": (("time", "segment"), per_segment(ps.gs_mol_m2_s)),
                "ci_umol_mol": (("time", "segment"), per_segment(ps.ci_umol_mol)),
                "vc_umol_m2_s": (("time", "segment"), per_segment(ps.vc_umol_m2_s)),
                "vj_umol_m2_s": (("time", "segment"), per_segment(ps.vj_umol_m2_s)),
                "limitation": (("time", "segment"), per_segment(ps.limitation, -1, np.int8)),
                "converged": (("time", "segment"), per_segment(ps.converged, True, bool)),
                **{k: ("time", np.asarray(o[k])) for k in OBSERVABLES},
                "sun_elevation_deg": ("time", self.sun_deg[:, 0]),
                "sun_azimuth_deg": ("time", self.sun_deg[:, 1]),
                "dni_w_m2": ("time", self.scenario.weather["dni_w_m2"].to_numpy(float)),
                "dhi_w_m2": ("time", self.scenario.weather["dhi_w_m2"].to_numpy(float)),
                "tair_c": ("time", self.tair_c),
                "co2_ppm": ("time", self.co2_ppm),
            },
            coords={
                "time": times,
                "segment": self.segment_id,
                "plant_id": ("segment", seg["plant_id"].to_numpy()),
                "organ_type": ("segment", seg["organ_type"].astype(str).to_numpy()),
                "area_m2": ("segment", self.area_m2),
                "is_blade": ("segment", self.is_blade),
            },
        )
        fld, g = self.scenario.field, self.scenario.field.growth
        ds.attrs = {
            "title": "lightfit coupled run",
            "time_zone": "UTC",
            "weather_provenance": str(self.scenario.weather.attrs.get("provenance", "unknown")),
            "weather_source": str(self.scenario.weather.attrs.get("source", "")),
            "n_plants": fld.n_plants,
            "buffer_rows": fld.buffer_rows,
            "buffer_along": fld.b_along,
            "seed": fld.seed,
            "n_tiles": self.scenario.n_tiles,
            "tile": -1 if self.scenario.tile is None else self.scenario.tile,
            "row_spacing_m": fld.row_spacing_m,
            "plant_spacing_m": fld.plant_spacing_m,
            "row_direction_deg": fld.row_direction_deg,
            "parameter_file": g.parameter_file,
            "season_start": g.season_start,
            "target_date": g.target_date,
            "samples": self.scenario.samples,
            "bounces": self.scenario.bounces,
            "render_seed": self.scenario.seed,
            "photosynthesis": self.scenario.photosynthesis,
            "par_kind": self.scenario.par_kind,
            "an_per": self.scenario.an_per,
            "sky": self.scenario.sky,
            "soil_albedo": self.scenario.optics.soil_albedo,
            "base_color": self.scenario.optics.base_color,
            **{f"theta_{k}": float(v) for k, v in th.to_dict().items()},
            "leaf_temperature": "air temperature (assumption)",
            "co2_at_leaf_surface": "air CO2 (assumption)",
        }
        return ds


__all__ = ["CoupledModel", "DEFAULT_THETA", "OBSERVABLES", "PARAMETERS", "Scenario"]
