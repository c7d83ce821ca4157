"""How far is each blade's temperature from the air's, and what does taking leaf T = air T cost?

    python experiments/leaf_temperature_check.py [--quick] [--out experiments/results/leaf_temperature_check.json]

lightfit evaluates every blade's photosynthesis at the air temperature of its step (docs/model.md).
This script bounds that simplification on the main job's day (the 20 April 2016 reconstruction,
the default canopy) with a steady-state leaf energy balance per blade and step, solved jointly with
the blade's photosynthesis and stomatal conductance, and reports the change in the canopy's net CO2
uptake. The light is the run's own: each blade's absorbed PAR from the render.

Energy balance per unit (one-sided) leaf area (Campbell & Norman 1998, *An Introduction to
Environmental Biophysics*, ch. 7, 10, 11, 12, 14), both faces:

    S + ε σ T_a⁴ [2 − τ_d (1 − ε_a)] = 2 ε σ T_l⁴ + 2 c_p g_Ha (T_l − T_a) + λ g_v (e_s(T_l) − e_a) / P

* S: absorbed shortwave, W m⁻². PAR from the render (q / 4.57 µmol J⁻¹); near-infrared from the
  same q scaled by the energy ratio of NIR (700–2 500 nm) to PAR (400–700 nm) in the ASTM G173
  global reference spectrum (1.20; pvlib's copy), the leaf's NIR/PAR absorptance ratio (PROSPECT-D,
  the default leaf, NIR absorptance weighted by the same spectrum) and, in the "enriched" rows,
  the relative enrichment of NIR with depth in a scattering turbid medium,
  exp(k_d (√a_PAR − √a_NIR) L) (Goudriaan 1977; L the leaf area above the blade, k_d 0.7):
  scattered NIR reaches deep leaves that PAR does not. It multiplies all of a blade's PAR, its
  direct beam too (which is not enriched), so those rows bound the deep blades' NIR from above.
* Longwave: the upper face sees the sky with the diffuse gap fraction τ_d = exp(−k_d L) (clear
  sky emissivity ε_a of Brutsaert 1975), otherwise leaves and soil at air temperature; the lower
  face sees leaves and soil at air temperature; leaf emissivity ε 0.97.
* Sensible heat: g_Ha = 0.135 √(u/d) mol m⁻² s⁻¹ per face (C&N eq. 7.30, forced convection; d =
  0.72 × the 9 mm blade width); outdoors conductances run ≈ 1.4× this (C&N), so ΔT is an upper
  bound at a given wind.
* Latent heat: g_v = 1/(1/(1.6 g_s) + 1/(2 g_va)), g_va = 0.147 √(u/d) per face (eq. 7.33); g_s
  the blade's stomatal conductance to CO2 from its photosynthesis at T_l and at the leaf-to-air
  vapour pressure deficit e_s(T_l) − e_a.
* Wind at a blade: u = u_h exp(−a L / LAI) (an exponential profile in cumulative leaf area,
  a = 2.5; u_h at the canopy top). The forcing has no wind: u_h is a scenario (0.5–4 m s⁻¹;
  Selhausen's April wind at 2 m is typically 2–4 m s⁻¹, less at a 0.4 m canopy's top).

Each blade: photosynthesis (lightfit.photosynthesis.solve with the run's parameter set, its
capacity through the canopy and the growth temperature) at T_l, then the balance solved for T_l by
bisection, repeated to |ΔT_l| < 0.005 K. The first pass at T_l = T_a reproduces the run's own
per-blade An (checked; the scaling of Vcmax, g0 and gm per blade here is independent of the
coupled model's capacity identity). No leaf boundary layer for CO2 (as the coupled model): the
change is the temperature's alone. Writes JSON and prints a table.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np

import lightfit  # noqa: F401  (before drjit)
from lightfit.precision import use_float64

use_float64()  # lightfit's precision policy, before any JAX array exists

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import equinox as eqx  # noqa: E402
import jax.numpy as jnp  # noqa: E402
from provenance import wide_console, write_result  # noqa: E402  (commit, cores, load and command with every JSON)
from pvlib.spectrum import get_reference_spectra  # noqa: E402
from rich.table import Table  # noqa: E402

from lightfit import replication as rep  # noqa: E402
from lightfit.light.leaf_optics import LeafTraits, par_optics, prospect_d  # noqa: E402
from lightfit.photosynthesis import solve  # noqa: E402
from lightfit.photosynthesis.canopy import vcmax25  # noqa: E402
from lightfit.photosynthesis.stomata import saturation_vapour_pressure_tetens_kpa as _es_kpa  # noqa: E402
from lightfit.weather.units import UMOL_PER_JOULE_PAR  # noqa: E402

OUT = Path(__file__).resolve().parent / "results" / "leaf_temperature_check.json"
SIGMA = 5.670374e-8  # W m-2 K-4
CP = 29.3  # J mol-1 K-1, molar heat capacity of air (C&N)
LAMBDA = 44.0e3  # J mol-1, latent heat of vaporisation near 20 °C (C&N)
EPS_LEAF = 0.97
K_D = 0.7  # diffuse extinction coefficient (spherical leaf angles, C&N ch. 15)
WIND_DECAY = 2.5
BLADE_WIDTH_M = 0.009  # docs/plant.md: every blade 34 cm × 9 mm
D_M = 0.72 * BLADE_WIDTH_M
WINDS_M_S = (0.5, 1.0, 2.0, 4.0)


def saturation_vapour_pressure_kpa(t_c):
    """The leaf's saturation vapour pressure (kPa; the photosynthesis' own Tetens form, so that the
    vapour pressure deficit at T_l = T_a is the coupled model's)."""
    return np.asarray(_es_kpa(jnp.asarray(t_c)))


def reference_spectrum() -> tuple[np.ndarray, np.ndarray]:
    """ASTM G173-03 global tilt spectrum (nm, W m⁻² nm⁻¹): sunlight at the ground, with the water
    vapour bands a blackbody lacks."""
    g = get_reference_spectra(standard="ASTM G173-03")["global"]
    return g.index.to_numpy(float), g.to_numpy(float)


def band_energy(wl_nm, e, lo_nm: float, hi_nm: float) -> float:
    m = (wl_nm >= lo_nm) & (wl_nm <= hi_nm)
    return float(np.trapezoid(e[m], wl_nm[m]))


def nir_absorptance(traits: LeafTraits = LeafTraits()) -> float:
    """700–2 500 nm absorptance of the PROSPECT-D leaf, weighted by the reference spectrum's energy."""
    wl, r, t = prospect_d(traits)
    swl, se = reference_spectrum()
    e = np.interp(wl, swl, se)
    m = wl >= 700
    return float(np.trapezoid((1.0 - r[m] - t[m]) * e[m], wl[m]) / np.trapezoid(e[m], wl[m]))


def sky_emissivity(tair_c, e_kpa):
    """Clear-sky emissivity, Brutsaert (1975): 1.24 (e / T)^(1/7), e in hPa, T in K."""
    return 1.24 * (10.0 * e_kpa / (tair_c + 273.15)) ** (1.0 / 7.0)


def conductances(u_m_s, gs):
    """(g_Ha per face, g_v of the leaf) in mol m⁻² s⁻¹: forced convection (C&N eqs. 7.30, 7.33) and
    the stomata (1.6 g_s for water vapour) in series with both faces' boundary layers."""
    g_ha = 0.135 * np.sqrt(u_m_s / D_M)
    g_va = 0.147 * np.sqrt(u_m_s / D_M)
    return g_ha, 1.0 / (1.0 / np.maximum(1.6 * gs, 1e-9) + 1.0 / (2.0 * g_va))


def longwave_in(tair_c, lai_above, eps_a):
    """Longwave absorbed by both faces, W m⁻²: the upper face's sky part τ_d at ε_a, the rest at T_a."""
    return EPS_LEAF * SIGMA * (tair_c + 273.15) ** 4 * (2.0 - np.exp(-K_D * lai_above) * (1.0 - eps_a))


def leaf_temperature(s_w_m2, tair_c, e_kpa, p_kpa, gs, lai_above, u_m_s, eps_a):
    """T_l (°C) solving the balance in the module docstring by bisection (all arrays broadcast)."""
    g_ha, g_v = conductances(u_m_s, gs)
    lw_in = longwave_in(tair_c, lai_above, eps_a)

    def residual(t_c):
        tk = t_c + 273.15
        out = 2 * EPS_LEAF * SIGMA * tk**4 + 2 * CP * g_ha * (t_c - tair_c)
        return s_w_m2 + lw_in - out - LAMBDA * g_v * (saturation_vapour_pressure_kpa(t_c) - e_kpa) / p_kpa

    lo = np.broadcast_to(tair_c - 20.0, np.broadcast(s_w_m2, tair_c, gs).shape).copy()
    hi = lo + 45.0
    if not (np.all(residual(lo) > 0) and np.all(residual(hi) < 0)):
        raise RuntimeError("a blade's energy balance has no root within 20 K below to 25 K above the air")
    for _ in range(50):  # residual falls with T_l: bisection to 45 K / 2^50
        mid = 0.5 * (lo + hi)
        pos = residual(mid) > 0
        lo, hi = np.where(pos, mid, lo), np.where(pos, hi, mid)
    return 0.5 * (lo + hi)


def linearised_dt(s_w_m2, tair_c, e_kpa, p_kpa, gs, lai_above, u_m_s, eps_a):
    """T_l − T_a from the linearised (Penman–Monteith) balance, Campbell & Norman eq. 14.6:
    γ*/(s + γ*) [R_ni/(c_p g_Hr) − D/(p_a γ*)], with the isothermal net radiation R_ni, g_Hr the
    sensible and radiative conductances of both faces, γ* = γ g_Hr/g_v, s = Δ/p_a; an independent
    check of the bisection where ΔT is small (the linearisation's error grows as ΔT²)."""
    ta = tair_c + 273.15
    g_ha, g_v = conductances(u_m_s, gs)
    g_hr = 2 * g_ha + 2 * 4 * EPS_LEAF * SIGMA * ta**3 / CP
    r_ni = s_w_m2 + longwave_in(tair_c, lai_above, eps_a) - 2 * EPS_LEAF * SIGMA * ta**4
    es = saturation_vapour_pressure_kpa(tair_c)
    delta = (saturation_vapour_pressure_kpa(tair_c + 0.01) - saturation_vapour_pressure_kpa(tair_c - 0.01)) / 0.02
    s_slope = delta / p_kpa
    gamma_star = (CP / LAMBDA) * g_hr / g_v
    return gamma_star / (s_slope + gamma_star) * (r_ni / (CP * g_hr) - (es - e_kpa) / (p_kpa * gamma_star))


@dataclass
class Blades:
    """The main job's (or the quick configuration's) blades after one run: per step and blade
    (T, B) absorbed PAR, per blade area, capacity factor and leaf area above, per step (T, 1) the
    forcing, and their photosynthesis parameters (the set's, each blade's Vcmax, g0 and gm scaled
    by its capacity, as the coupled model's profile does)."""

    date: str
    ds: object
    q: np.ndarray
    an_run: np.ndarray
    area: np.ndarray
    lai_above: np.ndarray
    lai: float
    tair: np.ndarray
    e_a: np.ndarray
    p_kpa: np.ndarray
    co2: np.ndarray
    capacity: np.ndarray
    scenario: object

    @cached_property
    def params(self):
        """The scenario's parameter set (at its growth temperature), each blade's Vcmax, g0 and gm
        times its capacity factor, as the coupled model's profile scales them."""
        p = self.scenario.photosynthesis_params()
        m = jnp.asarray(self.capacity)
        return eqx.tree_at(
            lambda q: (q.fvcb.vcmax_ref_umol_m2_s, q.fvcb.gm_mol_m2_s, q.stomata.g0_mol_m2_s),
            p,
            (p.fvcb.vcmax_ref_umol_m2_s * m, p.fvcb.gm_mol_m2_s * m, p.stomata.g0_mol_m2_s * m),
        )

    @property
    def vcmax25_top(self) -> float:
        """Vcmax at 25 °C of the top of the canopy (capacity factor 1), µmol m⁻² s⁻¹."""
        return vcmax25(self.scenario.photosynthesis_params())

    def at_growth_temperature(self, growth_temperature_c: float) -> Blades:
        """These blades with the run's parameter set at another growth temperature (°C), e.g.
        leaves acclimated to a colder month."""
        sc = dataclasses.replace(self.scenario, growth_temperature_c=growth_temperature_c)
        return dataclasses.replace(self, scenario=sc)

    def solve(self, t_leaf, co2=None, vpd_kpa=None):
        """Photosynthesis of every blade at leaf temperature ``t_leaf`` (°C) and CO2 (default the
        run's), the vapour pressure deficit e_s(T_l) − e_a unless given; refuses non-convergence."""
        vpd = np.maximum(saturation_vapour_pressure_kpa(t_leaf) - self.e_a, 0.0) if vpd_kpa is None else vpd_kpa
        r = solve(
            jnp.asarray(self.q),
            jnp.asarray(t_leaf),
            jnp.asarray(self.co2 if co2 is None else co2),
            pair_kpa=jnp.asarray(self.p_kpa),
            params=self.params,
            vpd_kpa=jnp.asarray(vpd),
        )
        if not bool(np.all(np.asarray(r.converged))):
            raise RuntimeError("a blade's photosynthesis did not converge")
        return r


def blades(quick: bool) -> Blades:
    """Run the main job's configuration (``quick``: the 4-plant one) once and take its blades."""
    cfg = rep.ReplicationConfig.quick() if quick else rep.ReplicationConfig()
    w = rep.forcing_of(cfg, None)
    model = rep.model_for(cfg, w, False)
    ds = model.simulate(model.scenario.theta)
    blade = ds["is_blade"].values.astype(bool)
    area = ds["area_m2"].values[blade]
    m = ds["capacity_factor"].values[blade] if "capacity_factor" in ds else np.ones(blade.sum())
    tair = ds["tair_c"].values[:, None]
    return Blades(
        date=str(cfg.dates[0]),
        ds=ds,
        q=ds["absorbed_par_umol_m2_s"].values[:, blade],  # per one-sided leaf area
        an_run=ds["leaf_an_umol_m2_s"].values[:, blade],
        area=area,
        lai_above=ds["leaf_area_above"].values[blade] if "leaf_area_above" in ds else np.zeros(blade.sum()),
        lai=float(area.sum() / float(ds.attrs["ground_area_m2"])),
        tair=tair,
        e_a=ds["rh"].values[:, None] * saturation_vapour_pressure_kpa(tair),
        p_kpa=ds["pair_kpa"].values[:, None],
        co2=ds["co2_ppm"].values[:, None],
        capacity=m,
        scenario=model.scenario,
    )


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="the quick configuration (default: the main job's)")
    ap.add_argument("--out", type=Path, default=OUT)
    a = ap.parse_args(argv)
    b = blades(a.quick)
    ds, q, area, lai_above, lai, tair, e_a, p_kpa = b.ds, b.q, b.area, b.lai_above, b.lai, b.tair, b.e_a, b.p_kpa
    eps_a = sky_emissivity(tair, e_a)

    def leaf(t_leaf):
        r = b.solve(t_leaf)
        return np.asarray(r.an_umol_m2_s), np.asarray(r.gs_mol_m2_s)

    t_same = np.broadcast_to(tair, q.shape)
    an0, gs0 = leaf(t_same)
    agree = float(np.max(np.abs(an0 - b.an_run)))
    a_par = par_optics().A
    a_nir = nir_absorptance()
    par_w = q / UMOL_PER_JOULE_PAR
    wl, e = reference_spectrum()
    nir_per_par = band_energy(wl, e, 700, 2500) / band_energy(wl, e, 400, 700)
    nir_flat = par_w * nir_per_par * a_nir / a_par
    depth = np.exp(K_D * (np.sqrt(a_par) - np.sqrt(a_nir)) * lai_above)
    day = ds["sun_elevation_deg"].values > 0
    total0 = float((an0 * area).sum())
    noon = int(np.argmax(ds["sun_elevation_deg"].values))
    rows = []
    for nir_depth in (False, True):
        s_w = par_w + nir_flat * (depth if nir_depth else 1.0)
        for u_h in WINDS_M_S:
            u = u_h * np.exp(-WIND_DECAY * lai_above / lai)
            t_l, gs = t_same, gs0
            n_it = 0
            for _ in range(30):
                n_it += 1
                t_new = leaf_temperature(s_w, tair, e_a, p_kpa, gs, lai_above, u, eps_a)
                an, gs = leaf(t_new)
                change = float(np.max(np.abs(t_new - t_l)))
                t_l = t_new
                if change < 0.005:
                    break
            else:
                raise RuntimeError(f"leaf temperature not converged at u_h {u_h} m/s: last change {change:.3f} K")
            dt = t_l - tair
            lin = linearised_dt(s_w, tair, e_a, p_kpa, gs, lai_above, u, eps_a)
            small = np.abs(dt) < 1.0
            sunlit = q[noon] > np.percentile(q[noon], 90)  # the top 10 % of blades by absorbed PAR
            night_mean = float((dt[~day] * area).sum() / (area.sum() * (~day).sum())) if (~day).any() else None
            rows.append(
                {
                    "wind_top_m_s": u_h,
                    "nir_enriched_with_depth": nir_depth,
                    "iterations": n_it,
                    "linearised_dT_max_abs_difference_K_where_below_1K": float(np.max(np.abs(lin - dt)[small])),
                    "noon_dT_mean_K": float((dt[noon] * area).sum() / area.sum()),
                    "noon_dT_top_decile_by_par_K": float(dt[noon][sunlit].mean()),
                    "noon_dT_range_K": [float(dt[noon].min()), float(dt[noon].max())],
                    "night_dT_mean_K": night_mean,
                    "day_an_change": float((an * area).sum()) / total0 - 1.0,
                    "noon_an_change": float((an[noon] * area).sum() / (an0[noon] * area).sum()) - 1.0,
                }
            )
    out = {
        "config": "quick" if a.quick else "main job",
        "date": b.date,
        "forcing": str(ds.attrs.get("weather_source", "")),
        "blades": int(len(area)),
        "lai": lai,
        "leaf_par_absorptance": a_par,
        "leaf_nir_absorptance": a_nir,
        "nir_to_par_energy_astm_g173": nir_per_par,
        "run_an_reproduced_max_abs_umol_m2_s": agree,
        "noon_utc": str(ds["time"].values[noon])[:16],
        "noon_tair_c": float(tair[noon, 0]),
        "noon_vpd_kpa": float(saturation_vapour_pressure_kpa(tair[noon, 0]) - e_a[noon, 0]),
        "rows": rows,
    }
    a.out.parent.mkdir(parents=True, exist_ok=True)
    write_result(a.out, out)
    t = Table(title=f"leaf − air temperature and canopy An, {out['date']} ({out['config']}, LAI {lai:.2f})")
    for c in (
        "wind at top",
        "NIR with depth",
        "noon ΔT mean",
        "noon ΔT, top 10 % by PAR",
        "noon ΔT range",
        "night ΔT",
        "day's An",
        "noon An",
    ):
        t.add_column(c, justify="right")
    for r in rows:
        t.add_row(
            f"{r['wind_top_m_s']:g} m/s",
            "yes" if r["nir_enriched_with_depth"] else "no",
            f"{r['noon_dT_mean_K']:+.2f} K",
            f"{r['noon_dT_top_decile_by_par_K']:+.2f} K",
            "{:+.1f} … {:+.1f} K".format(*r["noon_dT_range_K"]),
            f"{r['night_dT_mean_K']:+.2f} K" if r["night_dT_mean_K"] is not None else "—",
            f"{100 * r['day_an_change']:+.1f} %",
            f"{100 * r['noon_an_change']:+.1f} %",
        )
    wide_console().print(t)
    lin = max(r["linearised_dT_max_abs_difference_K_where_below_1K"] for r in rows)
    print(f"run's per-blade An reproduced at T_l = T_a to {agree:.1e} µmol m⁻² s⁻¹; the linearised balance")
    print(f"(Campbell & Norman eq. 14.6) within {lin:.3f} K of the bisection where |ΔT| < 1 K; wrote {a.out}")
    if agree > 1e-6:
        raise SystemExit("the blades' photosynthesis here is not the run's: the comparison would mix two models")


if __name__ == "__main__":
    main()
