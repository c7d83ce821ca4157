"""Physical constants shared by the photosynthesis modules (SI units unless stated)."""

#: Molar gas constant [J mol⁻¹ K⁻¹] (CODATA 2018). CPlantBox uses 8.3143; the difference
#: changes Arrhenius factors by < 1e-5 relative over 5–35 °C.
GAS_CONSTANT_J_MOL_K = 8.314462618

#: 0 °C in kelvin.
ZERO_CELSIUS_K = 273.15

#: Pressure at which Michaelis constants are tabulated as mole fractions [kPa].
REFERENCE_PRESSURE_KPA = 101.325
