"""Unit conversions against hand-computed values and standard tables."""

import numpy as np
import pytest

from lightfit.weather import units


@pytest.mark.parametrize("t_c, table_kpa", [(0.0, 0.6112), (20.0, 2.3389), (30.0, 4.2460), (-10.0, 0.28627)])
def test_saturation_vapour_pressure_matches_tables(t_c, table_kpa):
    # Values over liquid water from the Smithsonian / WMO psychrometric tables (Buck 1981, Table 1).
    assert units.saturation_vapour_pressure_alduchov_kpa(t_c) == pytest.approx(table_kpa, rel=4e-3)


def test_absolute_humidity_to_relative_by_hand():
    # e = 8.65e-3 kg m-3 * 461.5 J kg-1 K-1 * 293.15 K = 1170.247 Pa; es(20 °C) = 2.3335 kPa -> RH 0.5015
    assert units.vapour_pressure_from_absolute_humidity_kpa(8.65, 20.0) == pytest.approx(1.170247, rel=1e-6)
    assert units.relative_humidity_from_absolute(8.65, 20.0) == pytest.approx(0.5015, abs=5e-4)
    # Saturated air at 20 °C holds 17.3 g m-3 of water vapour (standard table value).
    assert units.relative_humidity_from_absolute(17.30, 20.0) == pytest.approx(1.0, abs=5e-3)


def test_co2_mmol_m3_to_ppm_by_hand():
    # Air molar density at 20 °C, 101.325 kPa: 101325 / (8.314462618 * 293.15) = 41.5711 mol m-3,
    # so 400 ppm is 16.6284 mmol m-3.
    assert units.co2_ppm_from_mmol_m3(16.6284, 20.0, 101.325) == pytest.approx(400.0, abs=0.01)
    # Colder, lower pressure: 0 °C, 95 kPa -> 95000 / (8.314462618 * 273.15) = 41.8302 mol m-3;
    # 16.732 mmol m-3 -> 400.0 ppm
    assert units.co2_ppm_from_mmol_m3(16.732, 0.0, 95.0) == pytest.approx(400.0, abs=0.05)


def test_pressure_and_par():
    assert units.kpa_from_mbar(1013.25) == pytest.approx(101.325)
    # PAR share of global radiation 0.5 × 4.57 µmol J⁻¹ of PAR quanta (McCree 1972).
    assert units.par_from_ghi(1000.0) == pytest.approx(0.5 * 4.57 * 1000.0)
    assert units.par_from_ghi(np.array([0.0, 500.0]))[1] == pytest.approx(1142.5)


def test_the_two_saturation_forms_agree_within_their_stated_difference():
    """The weather's Magnus (Alduchov & Eskridge) and the leaf's Tetens (FAO-56) e_s stay within
    0.21 % of each other from 0 to 40 °C, as their docstrings say."""
    from lightfit.photosynthesis.stomata import saturation_vapour_pressure_tetens_kpa as tetens

    t = np.linspace(0.0, 40.0, 81)
    rel = np.asarray(tetens(t)) / units.saturation_vapour_pressure_alduchov_kpa(t) - 1
    assert np.abs(rel).max() < 2.1e-3
