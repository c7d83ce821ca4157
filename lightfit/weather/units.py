"""Unit conversions for meteorological series. One function per conversion.

All temperatures in °C at the interface, pressures in kPa, humidity as a 0–1 fraction.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from lightfit.constants import GAS_CONSTANT_J_MOL_K as R_GAS
from lightfit.constants import ZERO_CELSIUS_K as T0

#: Specific gas constant of water vapour, J kg⁻¹ K⁻¹ (e.g. Monteith & Unsworth 2013, App. 2).
R_WATER_VAPOUR = 461.5
#: Fraction of broadband global radiation that is PAR (400–700 nm), energy basis. Published values
#: span ≈ 0.43–0.50: 0.50 is the crop models' convention (Monteith 1973; Spitters et al. 1986) and
#: docs/design.md §6's choice, at the top of the range; Meek et al. (1984, Agron. J. 76:939) measured
#: 2.04 µmol J⁻¹ of global, i.e. 0.45 × 4.57; the ASTM G173 global spectrum gives 0.43. Only series
#: without a PAR sensor depend on it for their light (10 % less PAR at 0.45), and the split of a
#: series whose global radiation it estimates from PAR (docs/weather.md). The bundled reconstructed
#: day writes PAR = 0.50 × 4.57 × its global radiation and carries its own diffuse part.
PAR_FRACTION = 0.50
#: Photon-to-energy ratio of sunlight PAR, µmol J⁻¹ (McCree 1972: 4.57).
UMOL_PER_JOULE_PAR = 4.57
#: PAR photons per joule of global radiation, µmol J⁻¹: :data:`PAR_FRACTION` × :data:`UMOL_PER_JOULE_PAR`
#: (≈ 2.29; Meek et al. 1984 measured 2.04), the factor :func:`par_from_ghi` applies.
PAR_PER_GHI_UMOL_J = PAR_FRACTION * UMOL_PER_JOULE_PAR


def saturation_vapour_pressure_alduchov_kpa(tair_c: ArrayLike) -> np.ndarray:
    r"""Saturation vapour pressure over water, kPa.

    Magnus form with the Alduchov & Eskridge (1996, J. Appl. Meteor. 35, 601) coefficients:

    .. math:: e_s(T) = 0.61094 \exp\!\left(\frac{17.625\,T}{T + 243.04}\right)

    with T in °C; better than 0.4 % from −40 to 50 °C. Used to convert the weather's humidity; the
    leaf's vapour pressure deficit takes FAO-56's Tetens form instead
    (:func:`lightfit.photosynthesis.stomata.saturation_vapour_pressure_tetens_kpa`, as CPlantBox does, for
    the peer comparison), at most 0.21 % apart from 0 to 40 °C.
    """
    t = np.asarray(tair_c, dtype=float)
    return 0.61094 * np.exp(17.625 * t / (t + 243.04))


def vapour_pressure_from_absolute_humidity_kpa(ah_g_m3: ArrayLike, tair_c: ArrayLike) -> np.ndarray:
    r"""Vapour pressure (kPa) from absolute humidity ρ_v (g m⁻³) by the ideal gas law.

    .. math:: e = \rho_v R_v (T + 273.15)
    """
    return np.asarray(ah_g_m3, dtype=float) * 1e-3 * R_WATER_VAPOUR * (np.asarray(tair_c, dtype=float) + T0) * 1e-3


def relative_humidity_from_absolute(ah_g_m3: ArrayLike, tair_c: ArrayLike) -> np.ndarray:
    """Relative humidity (0–1) from absolute humidity (g m⁻³) and air temperature (°C)."""
    return vapour_pressure_from_absolute_humidity_kpa(ah_g_m3, tair_c) / saturation_vapour_pressure_alduchov_kpa(tair_c)


def co2_ppm_from_mmol_m3(c_mmol_m3: ArrayLike, tair_c: ArrayLike, pair_kpa: ArrayLike) -> np.ndarray:
    r"""CO2 mole fraction (ppm = µmol mol⁻¹) from molar concentration (mmol m⁻³).

    Ideal gas: the molar density of air is n/V = p / (R T), so

    .. math:: x = \frac{c}{p/(R T)} = c\,\frac{R\,(T + 273.15)}{p}
    """
    c = np.asarray(c_mmol_m3, dtype=float) * 1e-3  # mol m⁻³
    air = np.asarray(pair_kpa, dtype=float) * 1e3 / (R_GAS * (np.asarray(tair_c, dtype=float) + T0))
    return c / air * 1e6


def kpa_from_mbar(p_mbar: ArrayLike) -> np.ndarray:
    """Pressure in kPa from mbar (= hPa)."""
    return np.asarray(p_mbar, dtype=float) * 0.1


def kpa_from_pa(p_pa: ArrayLike) -> np.ndarray:
    """Pressure in kPa from Pa."""
    return np.asarray(p_pa, dtype=float) / 1000.0


def par_from_ghi(ghi_w_m2: ArrayLike) -> np.ndarray:
    """PAR photon flux density (µmol m⁻² s⁻¹) from global radiation (W m⁻²).

    PAR = f_PAR · k · GHI with f_PAR ≈ 0.50 (energy share of 400–700 nm) and
    k = 4.57 µmol J⁻¹ (McCree 1972), i.e. :data:`PAR_PER_GHI_UMOL_J` ≈ 2.29 µmol J⁻¹ of global radiation.
    """
    return np.asarray(ghi_w_m2, dtype=float) * PAR_PER_GHI_UMOL_J
