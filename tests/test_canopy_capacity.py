"""Photosynthetic capacity through the canopy (lightfit.photosynthesis.canopy): the leaf area above a
blade, Lloyd et al.'s kn, the scaling identity every leaf evaluator goes through, and the knob's
path from the command line to results.nc."""

import dataclasses

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pandas as pd
import pytest

from lightfit.errors import InputError
from lightfit.model.observe import exact_leaf, tabulated_leaf, with_capacity
from lightfit.model.scenario import Forcing, Scenario
from lightfit.photosynthesis import parameter_set, solve
from lightfit.photosynthesis.canopy import (
    capacity_factor,
    kn_lloyd2010,
    leaf_area_above,
    profile_for,
    resolve_kn,
    vcmax25,
)
from lightfit.precision import use_float64

use_float64()


def test_leaf_area_above_counts_the_higher_leaves_per_ground_area():
    """Worked by hand: leaves at 0.5, 0.3, 0.3 and 0.1 m of 4, 2, 3 and 1 m² on 2 m² of ground."""
    z = np.array([0.1, 0.3, 0.3, 0.5])
    a = np.array([1.0, 2.0, 3.0, 4.0])
    np.testing.assert_allclose(leaf_area_above(z, a, 2.0), [4.5, 2.0, 2.0, 0.0])
    order = np.random.default_rng(3).permutation(4)  # the order of the rows does not matter
    np.testing.assert_allclose(leaf_area_above(z[order], a[order], 2.0), np.array([4.5, 2.0, 2.0, 0.0])[order])
    with pytest.raises(InputError, match="ground_area_m2"):
        leaf_area_above(z, a, 0.0)


@pytest.mark.parametrize(
    "height, area, name",
    [(np.nan, 1.0, "height_m"), (np.inf, 1.0, "height_m"), (0.3, -1.0, "area_m2"), (0.3, np.nan, "area_m2")],
)
def test_leaf_area_above_refuses_heights_and_areas_it_cannot_count(height, area, name):
    """A NaN height was counted below every leaf (LAI above it 4.0 here, with nothing said) and a
    negative area subtracted from the leaves beneath it (the lowest leaf's LAI above 3.0, not 3.5)."""
    z = np.array([0.1, height, 0.3, 0.5])
    a = np.array([1.0, area, 3.0, 4.0])
    with pytest.raises(InputError, match=name):
        leaf_area_above(z, a, 2.0)
    np.testing.assert_allclose(leaf_area_above(z[[0, 2, 3]], a[[0, 2, 3]], 2.0), [3.5, 2.0, 0.0])


def test_kn_of_lloyd_2010():
    """ln kn = 0.00963·Vcmax25 − 2.43 (Lloyd et al. 2010, eq. A2): 0.2306 at 100, 0.1425 at 50."""
    assert kn_lloyd2010(100.0) == pytest.approx(0.23062, abs=1e-5)
    assert kn_lloyd2010(50.0) == pytest.approx(0.14249, abs=1e-5)
    ww = parameter_set("winter_wheat")
    assert vcmax25(ww) == pytest.approx(100.0)  # the set's reference temperature is 25 °C
    # CPlantBox's sets refer to 20 °C (T_ref 293.2 K): 655 and 39.4 there, Arrhenius-deactivation to 25 °C.
    assert vcmax25(parameter_set("giraud2023")) == pytest.approx(965.6, abs=0.1)
    assert vcmax25(parameter_set("cplantbox")) == pytest.approx(58.0, abs=0.1)
    assert resolve_kn("lloyd2010", ww) == pytest.approx(kn_lloyd2010(100.0))
    assert resolve_kn("uniform", ww) == 0.0 and resolve_kn(0.4, ww) == 0.4 and resolve_kn("0.4", ww) == 0.4
    assert resolve_kn("depury1997", parameter_set("giraud2023")) == 0.713  # a crop's own kn, any set
    np.testing.assert_allclose(capacity_factor([0.0, 1.0, 3.0], 0.5), np.exp([0.0, -0.5, -1.5]))


def test_lloyds_kn_takes_the_sets_vcmax_at_25_c_not_at_its_own_reference():
    """Lloyd et al.'s fit is in Vcmax at 25 °C: CPlantBox's set has 39.4 at its own 20 °C and 58.0 at
    25 °C, so kn = exp(0.00963·58.0 − 2.43) = 0.154, not exp(0.00963·39.4 − 2.43) = 0.129 (a mutation
    audit: the set's ``vcmax_ref`` at its own reference passed every test, which resolved
    ``lloyd2010`` only for winter_wheat, whose reference is 25 °C)."""
    assert resolve_kn("lloyd2010", parameter_set("cplantbox")) == pytest.approx(np.exp(0.00963 * 58.0 - 2.43), rel=2e-3)


def test_profiles_resolve_per_set_and_bad_ones_are_refused():
    assert profile_for("auto", "winter_wheat") == "lloyd2010"
    assert profile_for("auto", "giraud2023") == "uniform"  # the reference paper's set: none
    assert profile_for("0.3", "winter_wheat") == 0.3
    assert profile_for(0, "winter_wheat") == "uniform"  # one name for one model
    for bad in ("steep", -0.1, 2.5, float("nan"), None):
        with pytest.raises(InputError, match="vcmax_profile"):
            profile_for(bad, "winter_wheat")
    # Lloyd's fit is not extrapolated to the paper's Vcmax (≈ 970 at 25 °C).
    with pytest.raises(InputError, match="vcmax_profile.*Vcmax") as e:
        resolve_kn("lloyd2010", parameter_set("giraud2023"))
    assert "uniform" in e.value.expected


@pytest.mark.parametrize(
    "set_name, gm", [("winter_wheat", None), ("winter_wheat", 0.3), ("cplantbox", None), ("giraud2023_coupled", None)]
)
def test_profiled_leaf_is_a_leaf_with_every_capacity_scaled(set_name, gm):
    """with_capacity's identity A(q; m) = m·A(q/m) against the solver run on a leaf whose Vcmax (so
    Jmax, Rd), g0 and a finite mesophyll conductance gm are m times the set's (three closures:
    Medlyn, CPlantBox's, Tuzet); gs, ci and dAn/dq too, from darkness to full sun, frost to heat."""
    p = parameter_set(set_name)
    if gm is not None:
        p = eqx.tree_at(lambda x: x.fvcb.gm_mol_m2_s, p, gm)
    m = jnp.array([1.0, 0.7, 0.35, 0.1])
    q = jnp.array([[0.0, 40.0, 400.0, 1800.0], [2.0, 150.0, 900.0, 2500.0]])
    t = np.array([-4.0, 33.0])
    forcing = Forcing(
        day=np.array([True, True]),
        dni_par=np.zeros(2),
        dhi_par=np.zeros(2),
        tair_c=t,
        co2_ppm=np.array([180.0, 800.0]),
        rh=np.array([0.9, 0.3]),
        pair_kpa=np.array([101.3, 96.0]),
    )
    r = with_capacity(exact_leaf, m)(q, forcing, p)
    scaled = eqx.tree_at(
        lambda x: (x.fvcb.vcmax_ref_umol_m2_s, x.stomata.g0_mol_m2_s, x.fvcb.gm_mol_m2_s),
        p,
        (p.fvcb.vcmax_ref_umol_m2_s * m, p.stomata.g0_mol_m2_s * m, p.fvcb.gm_mol_m2_s * m),
    )
    env = [
        jnp.broadcast_to(jnp.asarray(x)[:, None], q.shape) for x in (t, forcing.co2_ppm, forcing.rh, forcing.pair_kpa)
    ]
    direct = solve(q, *env, scaled)
    assert bool(jnp.all(direct.converged)) and bool(jnp.all(r.converged))
    np.testing.assert_allclose(r.an, direct.an_umol_m2_s, rtol=1e-9, atol=1e-10)
    np.testing.assert_allclose(r.result.gs_mol_m2_s, direct.gs_mol_m2_s, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(r.result.ci_umol_mol, direct.ci_umol_mol, rtol=1e-9)
    np.testing.assert_allclose(r.result.rd_umol_m2_s, direct.rd_umol_m2_s, rtol=1e-12)
    h = 1e-3  # dAn/dq against central differences of the directly solved leaf
    fd = (solve(q + h, *env, scaled).an_umol_m2_s - solve(jnp.maximum(q - h, 0.0), *env, scaled).an_umol_m2_s) / (
        q + h - jnp.maximum(q - h, 0.0)
    )
    np.testing.assert_allclose(r.dan_dq, fd, rtol=1e-4, atol=1e-7)
    # A tabulated leaf goes through the same identity (its own interpolation error aside).
    tab = with_capacity(tabulated_leaf(256), m)(q, forcing, p)
    np.testing.assert_allclose(tab.an, direct.an_umol_m2_s, rtol=2e-3, atol=2e-3)


def test_profiles_resolve_for_the_scenarios_set(weather_quick):
    assert Scenario(weather=weather_quick, vcmax_profile="uniform").kn() == 0.0
    sc = Scenario(weather=weather_quick)
    assert sc.vcmax_profile == "auto" and sc.kn() == pytest.approx(kn_lloyd2010(100.0))  # winter_wheat's own
    # "auto" is kept, so another set by dataclasses.replace takes its own profile.
    assert dataclasses.replace(sc, photosynthesis="giraud2023").kn() == 0.0
    assert Scenario(weather=weather_quick, vcmax_profile="0.5").kn() == 0.5
    with pytest.raises(InputError, match="vcmax_profile"):
        Scenario(weather=weather_quick, photosynthesis="giraud2023", vcmax_profile="lloyd2010")


def test_results_carry_the_profile_computed_from_the_grown_plants(weather_quick):
    """results.nc's leaf_area_above against an independent count over the geometry's blades, the
    capacity factor its exponential, the attributes naming the profile."""
    from lightfit.model.coupled import CoupledModel
    from lightfit.plant import Field, one_sided_area_m2, organ_class

    sc = Scenario(weather=weather_quick, field=Field(n_plants=4, seed=1, boundary="periodic"), samples=8, bounces=1)
    model = CoupledModel(sc)
    ds = model.simulate()
    seg = model.geometry.segments
    blade = organ_class(seg) == "blade"
    z = 0.5 * (seg["z0"] + seg["z1"]).to_numpy()[blade]
    a = one_sided_area_m2(seg)[blade]
    ids = seg["segment_id"].to_numpy()[blade]
    ground = sc.field.ground_area_m2  # a periodic cell: every plant measured
    expect = {i: a[z > zi].sum() / ground for i, zi in zip(ids, z)}
    got = ds["leaf_area_above"].values
    is_blade = ds["is_blade"].values.astype(bool)
    np.testing.assert_allclose(got[is_blade], [expect[i] for i in ds["segment"].values[is_blade]], rtol=1e-12)
    assert np.isnan(got[~is_blade]).all()
    assert ds.attrs["vcmax_profile"] == "lloyd2010" and ds.attrs["kn_per_lai"] == pytest.approx(kn_lloyd2010(100.0))
    assert ds.attrs["growth_temperature_c"] == ds.attrs["growth_temperature_applied_c"] == 15.0  # winter_wheat's own
    np.testing.assert_allclose(ds["capacity_factor"].values[is_blade], np.exp(-ds.attrs["kn_per_lai"] * got[is_blade]))
    assert ds["capacity_factor"].attrs["units"] == "1" and ds["leaf_area_above"].attrs["units"] == "m2 m-2"
    # Every segment's centre height above the soil, by its id (a newcomer's review: plotting PAR
    # against height meant joining the model's segment table by hand); the LAI above a blade never
    # grows with its height.
    centre = pd.Series(0.5 * (seg["z0"] + seg["z1"]).to_numpy(), index=seg["segment_id"].to_numpy())
    np.testing.assert_array_equal(ds["height_m"].values, centre.loc[ds["segment"].values].to_numpy())
    assert ds["height_m"].attrs["units"] == "m" and ds["height_m"].dims == ("segment",)
    by_height = np.argsort(ds["height_m"].values[is_blade], kind="stable")
    assert (np.diff(got[is_blade][by_height]) <= 0).all()
    # Summed over the canopy (every blade measured in a periodic cell) the profile integrates
    # analytically: mean capacity = (1 − e^(−kn·LAI)) / (kn·LAI), up to the blades' finite size.
    kn, area = ds.attrs["kn_per_lai"], ds["area_m2"].values[is_blade]
    lai = area.sum() / ground
    mean = (area * ds["capacity_factor"].values[is_blade]).sum() / area.sum()
    assert mean == pytest.approx((1 - np.exp(-kn * lai)) / (kn * lai), rel=5e-3)
    # Deeper blades have less capacity, so less dark respiration: the night's canopy loss shrinks.
    uniform = CoupledModel(Scenario(**{**sc.__dict__, "vcmax_profile": "uniform"})).simulate()
    night = ds["sun_elevation_deg"].values < 0
    assert night.any()
    ratio = ds["canopy_an_umol_m2_s"].values[night] / uniform["canopy_an_umol_m2_s"].values[night]
    np.testing.assert_allclose(ratio, mean, rtol=1e-9)


@pytest.fixture(scope="module")
def weather_quick():
    from lightfit import replication as rep

    return rep.forcing().iloc[[1, 14]]  # 05:30 local (night), 12:00


def test_a_finite_fields_lai_is_over_the_ground_of_all_its_plants():
    """The same plants' canopy, periodic (4 plants) and finite with a buffer row (16 plants, 4
    measured): LAI is every grown blade's one-sided area over the ground all the grown plants stand
    on, so both give the wheat's LAI within the plants' spread (a mutation audit: the finite field's
    ground as the measured plants' alone, LAI × 4, survived), and so does each measured blade's LAI
    above at the bottom of the canopy."""
    from lightfit.model.coupled import CoupledModel
    from lightfit.model.scenario import Scenario
    from lightfit.plant import Field, one_sided_area_m2, organ_class
    from lightfit.replication import forcing

    w = forcing().iloc[[14]]
    lai = {}
    for kw in (dict(boundary="periodic"), dict(boundary="finite", buffer_rows=1)):
        m = CoupledModel(Scenario(weather=w, field=Field(n_plants=4, seed=1, **kw), samples=4, bounces=1))
        seg = m.geometry.segments
        blade = organ_class(seg) == "blade"
        by_hand = one_sided_area_m2(seg)[blade].sum() / (len(m.geometry.plants) * 0.125 * 0.03)
        above, lai[kw["boundary"]] = m._lai_above()
        assert lai[kw["boundary"]] == pytest.approx(by_hand, rel=1e-12)
        assert above.max() <= lai[kw["boundary"]] + 1e-12
    assert lai["finite"] == pytest.approx(lai["periodic"], rel=0.3)
