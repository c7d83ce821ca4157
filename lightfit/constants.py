"""Physical constants more than one part of lightfit needs (one home each; SI units unless stated)."""

#: Molar gas constant [J mol⁻¹ K⁻¹] (CODATA 2018, exact). CPlantBox uses 8.3143; the difference
#: changes Arrhenius factors by < 1e-5 relative over 5–35 °C.
GAS_CONSTANT_J_MOL_K = 8.314462618

#: 0 °C in kelvin.
ZERO_CELSIUS_K = 273.15
