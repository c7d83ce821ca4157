"""Physical constants shared by the photosynthesis modules (SI units unless stated)."""

#: Molar gas constant [J mol⁻¹ K⁻¹] (CODATA 2018). CPlantBox uses 8.3143; the difference
#: changes Arrhenius factors by < 1e-5 relative over 5–35 °C.
GAS_CONSTANT_J_MOL_K = 8.314462618

#: 0 °C in kelvin.
ZERO_CELSIUS_K = 273.15

#: Pressure at which Michaelis constants are tabulated as mole fractions [kPa].
REFERENCE_PRESSURE_KPA = 101.325

#: O2 mole fraction at which Γ* is tabulated [mmol mol⁻¹] (21 %, Bernacchi et al. 2001's air).
#: Γ* = 0.5·O / S_c/o (von Caemmerer 2000, eq. 2.16) is proportional to O2.
GAMMA_STAR_REFERENCE_O2_MMOL_MOL = 210.0

#: O2 mole fraction of air at the leaf [mmol mol⁻¹] (20.95 %, rounded as every parameter set takes it).
AIR_O2_MMOL_MOL = 210.0
