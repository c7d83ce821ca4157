"""Leaf optics from PROSPECT-D traits: PAR R/T against the package, published ranges, the BSDF
mapping measured with the light estimator, presets and bad traits."""

import math

import numpy as np
import pytest
import xleaf

import lightfit  # noqa: F401
from lightfit.errors import InputError
from lightfit.light.backend import mitsuba
from lightfit.light.estimator import SegmentEstimator
from lightfit.light.leaf_optics import (
    PAPER_LEAF,
    LeafTraits,
    leaf_bsdf_parameters,
    par_optics,
    preset_parameters,
)
from lightfit.light.scene import FieldScene, Optics
from lightfit.plant.mesh import Mesh


def _planck_photons(lam_nm, t_k=5800.0):
    """Photon spectral flux of a blackbody, written out independently: B_λ / (hc/λ)."""
    h, c, k = 6.62607015e-34, 2.99792458e8, 1.380649e-23
    lam = lam_nm * 1e-9
    b_lambda = 2 * h * c**2 / lam**5 / np.expm1(h * c / (lam * k * t_k))
    return b_lambda * lam / (h * c)


def test_default_par_optics_match_the_package_called_directly():
    t = LeafTraits()
    r, tr = xleaf.simulate_leaf(chl=t.Cab, car=t.Car, antho=t.Anth, ewt=t.Cw, lma=t.Cm, N=t.N, transmittance=True)
    lam = np.asarray(xleaf.wavelengths) * 1000.0
    par = (lam > 399.5) & (lam < 700.5)
    w = _planck_photons(lam[par])
    expect_r = np.sum(r[par] * w) / np.sum(w)  # uniform 1 nm grid: sums suffice
    expect_t = np.sum(tr[par] * w) / np.sum(w)
    got = par_optics(t)
    assert got.R == pytest.approx(expect_r, abs=2e-4)
    assert got.T == pytest.approx(expect_t, abs=2e-4)


def test_default_wheat_leaf_is_in_the_published_ranges():
    p = par_optics()
    assert 0.06 <= p.R <= 0.09
    assert 0.02 <= p.T <= 0.08
    assert 0.83 <= p.A <= 0.92


def test_more_chlorophyll_absorbs_more():
    a = [par_optics(LeafTraits(Cab=c)).A for c in (10, 25, 40, 55, 80)]
    assert np.all(np.diff(a) > 0)
    base = [Optics.from_traits(LeafTraits(Cab=c)).base_color for c in (10, 40, 80)]
    assert np.all(np.diff(base) < 0)


def test_bsdf_parameters_reproduce_r_and_t():
    from lightfit.light.bsdf import SPECULAR_F0_SCALE, ggx_white_sky_albedo

    p = par_optics()
    for s, rough in ((0.5, 0.5), (0.3, 0.8), (0.6, 0.3)):
        leaf = leaf_bsdf_parameters(specular=s, roughness=rough)
        f0 = SPECULAR_F0_SCALE * s
        assert f0 * ggx_white_sky_albedo(rough) + (1 - f0) * (1 - leaf["subsurface"]) * leaf["base_color"] == (
            pytest.approx(p.R, rel=1e-9)
        )
        assert (1 - f0) * leaf["subsurface"] * leaf["base_color"] == pytest.approx(p.T, rel=1e-9)
        assert 0 < leaf["base_color"] < 1 and 0 < leaf["subsurface"] < 1


def test_presets():
    assert preset_parameters("paper") == PAPER_LEAF
    pro = Optics.preset("prospect")
    assert Optics() == pro  # the class's own defaults are the default leaf, not the paper's grey one
    assert Optics(specular=0.7).base_color == pro.base_color  # a leaf parameter alone keeps the leaf
    assert pro == Optics.from_traits(LeafTraits())
    assert (pro.specular, pro.roughness, pro.soil_albedo) == (0.5, 0.5, 0.12)
    assert 0.05 < pro.base_color < 0.1 and 0.5 < pro.subsurface < 0.7
    assert Optics.preset("prospect", soil_albedo=0.0).soil_albedo == 0.0
    with pytest.raises(InputError, match="preset"):
        Optics.preset("grey")


def _leaf_and_sensor():
    """A 10 cm horizontal leaf 1 m above the soil (id 7) and a 2 cm sensor 1 mm below it (id 8)."""

    def square(h, z):
        return np.array([[-h, -h, z], [h, -h, z], [h, h, z], [-h, h, z]], float)

    faces = np.array([[0, 1, 2], [0, 2, 3]])
    return Mesh(
        np.vstack([square(0.05, 1.0), square(0.01, 0.999)]),
        np.vstack([faces, faces + 4]),
        np.array([7, 7, 8, 8]),
        np.ones(4, bool),
    )


@pytest.mark.parametrize("preset", ["prospect", "paper"])
def test_isolated_leaf_absorptance_under_a_uniform_sky(preset):
    """The estimator on an isolated horizontal leaf over black soil, isotropic sky: the leaf absorbs
    1 − R − T, its white-sky reflectance and transmittance written out from the BSDF's parameters
    (for PROSPECT-D also PROSPECT's own A), and the sensor 1 mm under it receives T plus the light
    it reflects back up and the leaf's underside returns, T·(1 + R²) at 3 bounces (the sensor has
    the leaf's optics and sees ≈ only the leaf)."""
    from lightfit.light.bsdf import SPECULAR_F0_SCALE, ggx_white_sky_albedo

    optics = Optics.preset(preset, soil_albedo=0.0)
    f0 = SPECULAR_F0_SCALE * optics.specular
    refl = f0 * ggx_white_sky_albedo(optics.roughness) + (1 - f0) * (1 - optics.subsurface) * optics.base_color
    trans = (1 - f0) * optics.subsurface * optics.base_color
    fs = FieldScene(_leaf_and_sensor(), optics, sky="isotropic")
    fs.set_sun(60.0, 180.0)
    r = SegmentEstimator(fs, [7, 8], samples=2048, bounces=3, seed=0).render()
    leaf_abs = r.absorbed_sky[0] / r.incident_sky[0]
    assert r.incident_sky[0] == pytest.approx(1.0, abs=0.005)  # the sensor hides a negligible share of the sky
    assert leaf_abs == pytest.approx(1 - refl - trans, abs=0.005)
    assert r.incident_sky[1] == pytest.approx(trans * (1 + refl**2), rel=0.03)
    if preset == "prospect":
        p = par_optics()
        assert 0.83 <= leaf_abs <= 0.92
        assert leaf_abs == pytest.approx(p.A, abs=0.005)


def test_direct_sun_is_absorbed_with_the_leafs_absorptance_at_the_suns_angle():
    """The path estimator's direct beam on an unshaded horizontal leaf (black soil, no scattering):
    absorbed / incident = 1 − ρ(μ_sun), the leaf's directional albedo at the sun's cosine
    (``leaf_albedo``, itself checked against the BSDF plugin's sampled albedo in
    tests/test_light_bsdf.py). A glossy leaf (F0 = 0.08, smooth) makes ρ depend on the angle: a
    mutation audit took the absorptance at the scattered sample's direction instead, off by
    F0·(E(μ_sun) − E(μ_d)), which the isolated-leaf tests' 0.005 tolerance did not see. (Measured:
    0.864 at 15°, 0.859 at 75°: GGX's shadowing and masking lower the glossy albedo at grazing.)"""
    from lightfit.light.bsdf import leaf_albedo

    mi = mitsuba()
    optics = Optics.preset("prospect", soil_albedo=0.0, specular=1.0, roughness=0.3)
    fs = FieldScene(_leaf_and_sensor(), optics, sky="isotropic")
    ratios = []
    for el in (15.0, 75.0):
        fs.set_sun(el, 180.0)
        r = SegmentEstimator(fs, [7], samples=64, bounces=0, seed=0, direct="paths").render()
        mu = math.sin(math.radians(el))
        assert r.incident_sun[0] == pytest.approx(mu, rel=1e-5)  # unshaded: the beam's cosine, no noise
        expected = 1.0 - float(leaf_albedo(fs.bsdf, mi.Float(mu))[0])
        ratios.append(r.absorbed_sun[0] / r.incident_sun[0])
        assert ratios[-1] == pytest.approx(expected, abs=1e-4), el
    assert abs(ratios[0] - ratios[1]) > 0.003  # ρ depends on the angle enough for the test to tell them apart


@pytest.mark.parametrize(
    "bad",
    [
        {"Cab": -1.0},
        {"Cab": math.nan},
        {"Car": math.inf},
        {"Anth": 99.0},
        {"N": 0.5},
        {"Cw": 1.0},
        {"Cm": -0.001},
        {"Cab": "40"},
        {"N": True},
    ],
)
def test_bad_traits_name_the_trait(bad):
    (name,) = bad
    with pytest.raises(InputError, match=name) as err:
        LeafTraits(**bad)
    assert err.value.column == name


def test_specular_too_strong_for_prospect_reflectance():
    with pytest.raises(InputError, match="specular"):
        leaf_bsdf_parameters(LeafTraits(Cab=100.0), specular=1.0, roughness=0.1)
    with pytest.raises(InputError, match="roughness"):
        leaf_bsdf_parameters(roughness=math.nan)


def test_default_leaf_is_prospect_everywhere():
    """Scenario's optics, Theta's leaf defaults and the leaf module's default preset are one leaf."""
    import pandas as pd

    from lightfit.light.leaf_optics import DEFAULT_PRESET
    from lightfit.model.parameters import Theta
    from lightfit.model.scenario import WEATHER_COLUMNS, Scenario

    assert DEFAULT_PRESET == "prospect"
    night = {c: 0.0 for c in WEATHER_COLUMNS} | {"tair_c": 10.0, "rh": 0.8, "pair_kpa": 100.0, "co2_ppm": 400.0}
    sc = Scenario(weather=pd.DataFrame({c: [v] for c, v in night.items()}))
    assert sc.optics == Optics.preset("prospect")
    th = Theta()
    assert (th.specular, th.roughness, th.subsurface) == (sc.optics.specular, sc.optics.roughness, sc.optics.subsurface)
    assert th.subsurface == pytest.approx(0.596, abs=1e-3)  # the value docs and the CHANGELOG state
    assert sc.theta == th
    paper = Theta.for_optics(Optics.preset("paper"), light_factor=2.0)
    assert (paper.subsurface, paper.light_factor, paper.vcmax_scale) == (0.3, 2.0, 1.0)


def test_informed_subsurface_prior_spans_prospect_transmittance():
    """The prior's stated bounds follow from the default leaf and PROSPECT-D's wheat T range 0.02–0.08."""
    from lightfit.inference.mcmc.priors import PRIORS_INFORMED, SUBSURFACE_INFORMED, subsurface_range
    from lightfit.light.bsdf import SPECULAR_F0_SCALE

    o = Optics.preset("prospect")
    per_unit = (1 - SPECULAR_F0_SCALE * o.specular) * o.base_color  # T per unit subsurface
    lo, hi = 0.02 / per_unit, min(1.0, 0.08 / per_unit)
    assert SUBSURFACE_INFORMED == pytest.approx((lo, hi), abs=0.005)
    assert PRIORS_INFORMED["subsurface"].support == SUBSURFACE_INFORMED
    assert lo < o.subsurface < hi  # the default lies inside its prior
    # subsurface's literal is the default leaf's computed range (a literal, so that importing the
    # priors starts no renderer); specular's bounds the upper surface's reflection 3.7–5.9 % over
    # the F0 scale
    assert SUBSURFACE_INFORMED == subsurface_range(Optics.preset("prospect"))
    assert PRIORS_INFORMED["specular"].support == pytest.approx((0.037 / SPECULAR_F0_SCALE, 0.059 / SPECULAR_F0_SCALE))


def test_chlorophyll_prior_range_follows_the_spad_fit():
    """CHLOROPHYLL_PRIOR_UG_CM2 is SPAD 32–52 through the photosynthesis module's SPAD fit (mg m⁻² → µg cm⁻²),
    and the default trait is SPAD 41."""
    from lightfit.light.leaf_optics import CHLOROPHYLL_PRIOR_UG_CM2
    from lightfit.photosynthesis import chlorophyll_from_spad_qian2021 as chl

    assert CHLOROPHYLL_PRIOR_UG_CM2 == pytest.approx((chl(32.0) / 10, chl(52.0) / 10), abs=0.05)
    assert LeafTraits().Cab == pytest.approx(chl(41.0) / 10, abs=0.05)
    lo, hi = CHLOROPHYLL_PRIOR_UG_CM2
    a_lo, a_hi = par_optics(LeafTraits(Cab=lo)).A, par_optics(LeafTraits(Cab=hi)).A
    # The prior range spans absorptance 0.873 … 0.922: credible wheat leaves (PROSPECT-D 0.83–0.92;
    # the top, SPAD 52, is 0.002 above that range's upper end).
    assert 0.83 <= a_lo < par_optics().A < a_hi <= 0.925


def test_informed_priors_follow_the_run_leaf():
    """informed_priors(optics) gives the default leaf's stored prior and, for the reference paper's grey
    leaf, the subsurface range that spans the same PROSPECT-D transmittance (0.02–0.08 / (0.96·0.5))."""
    from lightfit.inference.mcmc.priors import PRIORS_INFORMED, informed_priors

    assert informed_priors(Optics.preset("prospect"))["subsurface"].support == PRIORS_INFORMED["subsurface"].support
    grey = informed_priors(Optics.preset("paper"))
    assert grey["subsurface"].support == pytest.approx((0.02 / 0.48, 0.08 / 0.48), abs=0.005)
    assert {k: v for k, v in grey.items() if k != "subsurface"} == {
        k: v for k, v in PRIORS_INFORMED.items() if k != "subsurface"
    }


def test_a_glossy_lobe_brighter_than_prospects_reflectance_is_refused_even_with_transmittance_left():
    """With PROSPECT-D's R (xleaf called directly, photon-weighted over 400–700 nm) below the glossy
    lobe's white-sky reflectance F0·Ē but R + T above it, a leaf would need a negative diffuse
    reflection (subsurface T/(R + T − F0·Ē) > 1): refused. The default wheat leaf has R ≈ 0.061,
    T ≈ 0.038, and specular 1 at roughness 0.5 reflects 0.08·Ē ≈ 0.070."""
    from lightfit.light.bsdf import ggx_white_sky_albedo

    t = LeafTraits()
    r, _ = xleaf.simulate_leaf(chl=t.Cab, car=t.Car, antho=t.Anth, ewt=t.Cw, lma=t.Cm, N=t.N, transmittance=True)
    lam = np.asarray(xleaf.wavelengths) * 1000.0
    par = (lam > 399.5) & (lam < 700.5)
    w = _planck_photons(lam[par])
    r_par = np.sum(r[par] * w) / np.sum(w)
    glossy = 0.08 * ggx_white_sky_albedo(0.5)
    assert r_par < glossy < r_par + par_optics(t).T  # the case: transmittance would absorb the excess
    with pytest.raises(InputError, match="specular"):
        leaf_bsdf_parameters(t, specular=1.0, roughness=0.5)
    ok = leaf_bsdf_parameters(t, specular=0.5, roughness=0.5)
    assert 0 <= ok["subsurface"] <= 1 and 0 <= ok["base_color"] <= 1


def test_band_average_takes_the_photon_weighted_mean_over_400_to_700_nm_only():
    """band_average on a 300–900 nm grid: values outside 400–700 nm (5 below, 7 above) must not
    enter, so a function equal to 1 in the band averages to exactly 1 (a band starting at 380 nm
    is invisible on PROSPECT's grid, which starts at 400 nm). And the photon-weighted mean
    wavelength of a 5800 K blackbody over the band, against scipy's adaptive quadrature of the
    Planck photon flux written out from SI constants (not the module's weights): ≈ 556 nm;
    energy weighting (λ⁻⁵, W instead of µmol) or another temperature moves it by nanometres."""
    from scipy.integrate import quad

    from lightfit.light.leaf_optics import band_average

    lam = np.arange(300.0, 901.0)
    inside = (lam >= 400) & (lam <= 700)
    assert band_average(lam, np.where(inside, 1.0, np.where(lam < 400, 5.0, 7.0))) == pytest.approx(1.0, abs=1e-12)
    num = quad(lambda x: x * _planck_photons(np.array(x)), 400.0, 700.0, epsabs=0, epsrel=1e-12)[0]
    den = quad(lambda x: _planck_photons(np.array(x)), 400.0, 700.0, epsabs=0, epsrel=1e-12)[0]
    assert 550.0 < num / den < 560.0
    assert band_average(lam, lam) == pytest.approx(num / den, abs=1e-3)  # trapezoid on 1 nm: ~1e-5 nm


def test_a_given_chlorophyll_is_the_leaf_the_run_makes_and_records():
    """leaf_traits: chlorophyll given → the default traits with that Cab (only Cab changes), none →
    the defaults, the paper's grey leaf → None (not made from traits). A run's recorded
    configuration (ReplicationConfig.effective, which goes through leaf_traits) names the chlorophyll
    its leaf optics were made from, not the default 50.5."""
    import dataclasses

    from lightfit.light.leaf_optics import leaf_traits
    from lightfit.replication import ReplicationConfig

    assert leaf_traits("prospect", 36.4) == dataclasses.replace(LeafTraits(), Cab=36.4)
    assert leaf_traits("prospect") == LeafTraits() and leaf_traits("paper") is None
    cfg = ReplicationConfig(chlorophyll_ug_cm2=36.4)
    assert cfg.effective()["chlorophyll_ug_cm2"] == 36.4
    assert cfg.leaf_optics() == Optics.from_traits(leaf_traits("prospect", 36.4), soil_albedo=cfg.soil_albedo)


def test_traits_without_absorbers_are_refused_by_name():
    """A leaf without absorbers (every pigment, water and dry matter 0, each inside its range) has
    PROSPECT-D's R + T = 1, which the diffuse lobe reproduces only with a base colour of 1.005 beside
    the default glossy lobe: Optics.from_traits then refused 'base_color', a parameter the user never
    gave (a review). Refused here naming the traits; a leaf that absorbs a little still maps."""
    bare = LeafTraits(Cab=0.0, Car=0.0, Anth=0.0, Cw=0.0, Cm=0.0)
    with pytest.raises(InputError, match="absorbs") as e:
        Optics.from_traits(bare)
    assert e.value.parameter == "traits"
    leaf = leaf_bsdf_parameters(LeafTraits(Cab=0.5, Car=0.0, Anth=0.0, Cw=0.0, Cm=0.0))
    assert 0.9 < leaf["base_color"] < 1
