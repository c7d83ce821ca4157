"""Photosynthesis: FvCB + stomatal conductance fixed point in JAX.

Public API::

    from lightfit.photosynthesis import solve, parameter_set
    res = solve(par_abs_umol_m2_s, tleaf_c, co2_ppm, rh, pair_kpa, parameter_set("winter_wheat"))
    res.an_umol_m2_s, res.gs_mol_m2_s, res.ci_umol_mol, res.converged

See ``docs/photosynthesis.md`` for the model, solver, parameter sets and validation.
"""

from lightfit.defaults import DEFAULT_PARAMETER_SET

from .fvcb import (
    LeafCapacities,
    assimilation,
    electron_limited_rate,
    electron_transport_rate,
    leaf_capacities,
    rubisco_compensation_point,
    rubisco_limited_rate,
)
from .model import (
    ELECTRON_TRANSPORT_LIMITED,
    MAX_PAR_ABS_UMOL_M2_S,
    RUBISCO_LIMITED,
    Environment,
    PhotosynthesisResult,
    co2_balance_residual,
    prepare_environment,
    solve,
    solve_plain_iteration,
    solve_with_par_slope,
)
from .parameters import (
    PARAMETER_SET_NAMES,
    FvCBParams,
    PhotosynthesisParams,
    StomataParams,
    TemperatureParams,
    chlorophyll_from_spad_qian2021,
    growth_temperature,
    parameter_set,
    vcmax_ref_from_chlorophyll,
)
from .solver import SolverConfig, bracketed_newton, fixed_point_iteration
from .stomata import (
    cplantbox_conductance,
    cplantbox_intercellular_co2,
    leuning_conductance,
    medlyn_conductance,
    saturation_vapour_pressure_tetens_kpa,
    tuzet_conductance,
    vapour_pressure_deficit_kpa,
    water_stress_factor,
)
from .temperature import arrhenius, deactivation, peaked_arrhenius

__all__ = [
    "ELECTRON_TRANSPORT_LIMITED",
    "MAX_PAR_ABS_UMOL_M2_S",
    "RUBISCO_LIMITED",
    "DEFAULT_PARAMETER_SET",
    "PARAMETER_SET_NAMES",
    "Environment",
    "FvCBParams",
    "LeafCapacities",
    "PhotosynthesisParams",
    "PhotosynthesisResult",
    "SolverConfig",
    "StomataParams",
    "TemperatureParams",
    "arrhenius",
    "assimilation",
    "bracketed_newton",
    "chlorophyll_from_spad_qian2021",
    "co2_balance_residual",
    "cplantbox_conductance",
    "cplantbox_intercellular_co2",
    "deactivation",
    "electron_limited_rate",
    "electron_transport_rate",
    "fixed_point_iteration",
    "leaf_capacities",
    "leuning_conductance",
    "medlyn_conductance",
    "growth_temperature",
    "parameter_set",
    "peaked_arrhenius",
    "prepare_environment",
    "rubisco_compensation_point",
    "rubisco_limited_rate",
    "saturation_vapour_pressure_tetens_kpa",
    "solve",
    "solve_plain_iteration",
    "solve_with_par_slope",
    "tuzet_conductance",
    "vapour_pressure_deficit_kpa",
    "vcmax_ref_from_chlorophyll",
    "water_stress_factor",
]
