"""Run CPlantBox's own C++ photosynthesis (``plantbox.functional.Photosynthesis``) on
given per-segment inputs, for peer validation and benchmarks.

CPlantBox solves photosynthesis on the leaf segments of a ``MappedPlant`` together with
the xylem water flow. We build one small wheat plant (``Triticum_aestivum_test_2021``,
14 days, in wet soil) and feed the requested (PAR, leaf temperature, CO2) points to its
leaf-blade segments, a chunk at a time. Requires the ``cplantbox`` package (imported
lazily).
"""

from __future__ import annotations

import dataclasses
import functools
import os
import time
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike

from .parameters import PhotosynthesisParams, TemperatureParams
from .stomata import saturation_vapour_pressure_tetens_kpa

_SECONDS_PER_DAY = 24 * 3600
#: Air temperature of the CPlantBox run [°C]: its vapour pressures, and the leaves left without a point.
_AIR_C = 20.0


class PeerOutput(NamedTuple):
    """CPlantBox results per input point, in lightfit units.

    Attributes:
        an_umol_m2_s, vc_umol_m2_s, vj_umol_m2_s: net assimilation and gross rates.
        gs_mol_m2_s: CPlantBox ``gco2`` (stomatal conductance to CO2).
        ci_umol_mol: intercellular CO2.
        fw: water-stress factor CPlantBox computed for the segment.
        solve_seconds: wall time of the C++ solves only (plant set-up excluded).
        n_solves: number of ``solve_photosynthesis`` calls.
        blade_segments: leaf-blade segments per solve.
    """

    an_umol_m2_s: np.ndarray
    vc_umol_m2_s: np.ndarray
    vj_umol_m2_s: np.ndarray
    gs_mol_m2_s: np.ndarray
    ci_umol_mol: np.ndarray
    fw: np.ndarray
    solve_seconds: float
    n_solves: int
    blade_segments: int


@functools.lru_cache(maxsize=4)
def _plant(plant_age_d: float):
    import plantbox as pb

    base = os.path.join(os.path.dirname(pb.__file__), "modelparameter")
    plant = pb.MappedPlant(1)
    plant.readParameters(os.path.join(base, "structural", "plant", "Triticum_aestivum_test_2021.xml"))
    plant.setGeometry(pb.SDF_PlantContainer(np.inf, np.inf, 60.0, True))
    plant.setSoilGrid(lambda x, y, z: max(int(np.floor(-z)), -1))
    plant.initialize(False)
    plant.simulate(plant_age_d, False)
    return plant, base


def _check_comparable(params: PhotosynthesisParams) -> None:
    if params.stomata.model != "cplantbox":
        raise ValueError("params.stomata.model must be 'cplantbox' to compare with CPlantBox")
    ref = TemperatureParams.cplantbox()
    # Every number, activation and deactivation energies and entropies too: CPlantBox runs on its
    # own whatever it is given, so a changed Ea was compared silently against the default's (Vc
    # 13.1 against 9.8 µmol m-2 s-1 at 30 °C with ea_vcmax_j_mol 80 000 instead of 58 520).
    differ = [
        f.name
        for f in dataclasses.fields(ref)
        if f.name != "form"
        and not np.allclose(np.asarray(getattr(params.temperature, f.name)), np.asarray(getattr(ref, f.name)))
    ]
    if params.temperature.form != "cplantbox" or differ:
        raise ValueError(
            "params.temperature must be TemperatureParams.cplantbox(): CPlantBox's "
            "temperature constants are compiled in" + (f" (these differ: {', '.join(differ)})" if differ else "")
        )
    if not np.isclose(float(params.fvcb.rd_to_vcmax), 0.015) or not params.fvcb.clip_rates:
        raise ValueError("CPlantBox fixes rd_to_vcmax = 0.015 and clips the rates")


def run_cplantbox(
    par_abs_umol_m2_s: ArrayLike,
    tleaf_c: ArrayLike,
    co2_ppm: ArrayLike,
    params: PhotosynthesisParams,
    *,
    rh: float = 0.6,
    soil_psi_cm: float = -100.0,
    plant_age_d: float = 14.0,
) -> PeerOutput:
    """CPlantBox photosynthesis at each point of the 1-D input arrays (same length).

    Args:
        par_abs_umol_m2_s: absorbed PAR [µmol m⁻² s⁻¹].
        tleaf_c: leaf temperature [°C].
        co2_ppm: CO2 at the leaf surface [µmol mol⁻¹].
        params: a CPlantBox-comparable :class:`PhotosynthesisParams`.
        rh: relative humidity (CPlantBox requires 0 < RH < 1).
        soil_psi_cm: soil matric potential [cm] (wet soil by default).
        plant_age_d: age of the wheat plant built for the run [d].
    """
    import plantbox as pb
    from plantbox.functional.Photosynthesis import PhotosynthesisPython
    from plantbox.functional.PlantHydraulicParameters import PlantHydraulicParameters

    _check_comparable(params)
    par, tl, co2 = (np.asarray(a, float).ravel() for a in np.broadcast_arrays(par_abs_umol_m2_s, tleaf_c, co2_ppm))
    plant, base = _plant(plant_age_d)
    hyd = PlantHydraulicParameters()
    hyd.read_parameters(os.path.join(base, "functional", "plant_hydraulics", "wheat_Giraud2023adapted"))
    hm = PhotosynthesisPython(plant, hyd)
    f, s = params.fvcb, params.stomata
    hm.g0 = float(s.g0_mol_m2_s)
    hm.a1 = float(s.a1)
    hm.a3 = float(f.jmax_to_vcmax)
    hm.alpha = float(f.quantum_yield)
    hm.theta = float(f.curvature)
    hm.oi = float(f.o2_mmol_mol) * 1e-3
    # Vcmax_ref = VcmaxrefChl1·Chl + VcmaxrefChl2: pass the value through the intercept.
    hm.VcmaxrefChl1 = 0.0
    hm.VcmaxrefChl2 = float(f.vcmax_ref_umol_m2_s)

    leaf_ids = np.asarray(plant.getSegmentIds(4))
    blade = np.asarray(plant.leafBladeSurface)[leaf_ids] > 0
    slots = np.flatnonzero(blade)
    n_leaf, n_slot = len(leaf_ids), len(slots)
    out = {k: np.empty(par.size) for k in ("an", "vc", "vj", "gs", "ci", "fw")}
    # CPlantBox takes one air vapour pressure for the plant: air at 20 °C and ``rh``. It sets the
    # transpiration, hence fw, which lightfit is given; the leaf's own VPD is not compared here.
    es = float(saturation_vapour_pressure_tetens_kpa(_AIR_C))
    elapsed, n_solves = 0.0, 0
    for start in range(0, par.size, n_slot):
        idx = np.arange(start, min(start + n_slot, par.size))
        q = np.full(n_leaf, 0.0)
        t = np.full(n_leaf, _AIR_C)
        c = np.full(n_leaf, 400.0)
        q[slots[: idx.size]] = par[idx]
        t[slots[: idx.size]] = tl[idx]
        c[slots[: idx.size]] = co2[idx]
        hm.pCO2 = c * 1e-6
        t0 = time.perf_counter()
        hm.solve(
            sim_time=plant_age_d,
            rsx=np.full(60, soil_psi_cm),
            cells=True,
            ea=es * rh,
            es=es,
            PAR=q * 1e-6 * _SECONDS_PER_DAY / 1e4,
            TairC=t,
        )
        elapsed += time.perf_counter() - t0
        n_solves += 1
        sel = slots[: idx.size]
        out["an"][idx] = np.asarray(hm.An)[sel] * 1e6
        out["vc"][idx] = np.asarray(hm.Vc)[sel] * 1e6
        out["vj"][idx] = np.asarray(hm.Vj)[sel] * 1e6
        out["gs"][idx] = np.asarray(hm.gco2)[sel]
        out["ci"][idx] = np.asarray(hm.ci)[sel] * 1e6
        out["fw"][idx] = np.asarray(hm.fw)[sel]
    del pb
    return PeerOutput(out["an"], out["vc"], out["vj"], out["gs"], out["ci"], out["fw"], elapsed, n_solves, n_slot)
