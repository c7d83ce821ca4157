"""Physical constants shared by the photosynthesis modules (SI units unless stated); the gas
constant and the kelvin offset are lightfit's (:mod:`lightfit.constants`)."""

from lightfit.constants import GAS_CONSTANT_J_MOL_K, ZERO_CELSIUS_K

__all__ = [
    "AIR_O2_MMOL_MOL",
    "GAMMA_STAR_REFERENCE_O2_MMOL_MOL",
    "GAS_CONSTANT_J_MOL_K",
    "REFERENCE_PRESSURE_KPA",
    "T25_K",
    "ZERO_CELSIUS_K",
]

#: 25 °C, the temperature rates are most often tabulated at [K].
T25_K = ZERO_CELSIUS_K + 25.0

#: Pressure at which Michaelis constants are tabulated as mole fractions [kPa].
REFERENCE_PRESSURE_KPA = 101.325

#: O2 mole fraction at which Γ* is tabulated [mmol mol⁻¹] (21 %, Bernacchi et al. 2001's air).
#: Γ* = 0.5·O / S_c/o (von Caemmerer 2000, eq. 2.16) is proportional to O2.
GAMMA_STAR_REFERENCE_O2_MMOL_MOL = 210.0

#: O2 mole fraction of air at the leaf [mmol mol⁻¹] (20.95 %, rounded as every parameter set takes it).
AIR_O2_MMOL_MOL = 210.0
