"""Virtual horizontal quantum sensors (ceptometer at the soil, sensors at a height), issue 14 item 3.

Independent references: the analytic above-canopy sensor DNI·sin β + DHI (above the canopy and
on the soil of an empty field), Beer–Lambert transmittance of a homogeneous random canopy of
small black leaves in a periodic cell (the canopy of tests/test_periodic.py), and energy
conservation (black leaves on black soil: what the leaves absorb plus what reaches the soil is
what arrives above, so the one-sensor fAPAR ≈ 1 − τ equals the rendered canopy fAPAR).
"""

import dataclasses
import math

import numpy as np
import pytest
from test_periodic import BLACK, canopy, square

import lightfit  # noqa: F401
from lightfit.errors import InputError
from lightfit.light.estimator import SegmentEstimator
from lightfit.light.scene import FieldScene, Optics
from lightfit.light.sensors import (
    Sensor,
    SensorEstimator,
    ceptometer,
    default_sensors,
    measured_area,
)
from lightfit.plant import Field
from lightfit.plant.periodic import PeriodicCell

GREY = Optics(specular=0.5, roughness=0.4, subsurface=0.5, base_color=0.5, soil_albedo=0.3)
CELL = PeriodicCell(0.5, 0.5, row_direction_deg=90.0)


@pytest.fixture(scope="module")
def spherical():
    """LAI 0.5 of 1 cm leaves with spherical angles in 0.1–1.0 m, in a 0.5 m periodic cell."""
    mesh, n = canopy(CELL, 0.5, "spherical", np.random.default_rng(11), sensors=0)
    return mesh, n


def test_sensor_above_the_canopy_reads_the_analytic_above_canopy_value(spherical):
    """Every ray of an upward sensor above the canopy top escapes: DNI sin β + DHI, for both skies."""
    mesh, _ = spherical
    above = ceptometer(CELL, height_m=1.2, placements=3)
    for sky in ("isotropic", "overcast"):
        fs = FieldScene(mesh, GREY, sky=sky, cell=CELL)
        for el in (20.0, 65.0):
            fs.set_sun(el, 140.0)
            r = SensorEstimator(fs, [above], samples=256, bounces=2, seed=1).render()
            assert r.incident_sun[0] == pytest.approx(math.sin(math.radians(el)), abs=1e-5)
            # Isotropic: π L = 1 on every ray; overcast: the sky's radiance is normalised to DHI = 1.
            assert r.incident_sky[0] == pytest.approx(1.0, abs=max(4 * r.se["incident_sky"][0], 1e-5)), sky


def test_sensor_on_the_soil_of_an_empty_field_reads_the_analytic_value():
    """A finite field whose only leaf is 50 m away: the soil sensor sees the whole sky and the sun."""
    far = square([50.0, 0.0, 0.5], [0, 0, 1], 0.05, 1)
    fs = FieldScene(far, GREY)
    soil = ceptometer(CELL, placements=4)
    for el in (15.0, 50.0):
        fs.set_sun(el, 180.0)
        r = SensorEstimator(fs, [soil], samples=128, bounces=3, seed=2).render()
        assert r.incident_sun[0] == pytest.approx(math.sin(math.radians(el)), abs=1e-5)
        assert r.incident_sky[0] == pytest.approx(1.0, abs=1e-5)


@pytest.mark.parametrize("el", [30.0, 60.0])
def test_ceptometer_direct_transmittance_follows_beer_lambert(spherical, el):
    """τ_dir = exp(−G·LAI/sin β), G = ½ (spherical leaves), from 8 bars of 0.8 m across the cell."""
    mesh, _ = spherical
    fs = FieldScene(mesh, BLACK, cell=CELL)
    fs.set_sun(el, 150.0)
    r = SensorEstimator(fs, [ceptometer(CELL)], samples=4096, bounces=0, seed=3).render()
    s = math.sin(math.radians(el))
    tau, se = r.incident_sun[0] / s, r.se["incident_sun"][0] / s
    expected = math.exp(-0.5 * 0.5 / s)
    # 4 SE plus 0.02 for the one random canopy of finite 1 cm leaves (tests/test_periodic.py).
    assert tau == pytest.approx(expected, abs=4 * se + 0.02), (tau, expected, se)
    assert se < 0.02
    assert r.meta["periodic"]["sun"]["capped"] == 0


def test_black_canopy_energy_closes_so_one_minus_tau_is_fapar(spherical):
    """Black leaves on black soil: APAR/above + τ = 1 for sun and sky, i.e. the ceptometer's
    1 − τ equals the canopy fAPAR rendered on the leaves (to Monte Carlo error)."""
    mesh, n = spherical
    fs = FieldScene(mesh, BLACK, cell=CELL)
    fs.set_sun(40.0, 200.0)
    leaves = SegmentEstimator(fs, np.arange(1, n + 1), samples=16, bounces=1, seed=4).render()
    soil = SensorEstimator(fs, [ceptometer(CELL)], samples=4096, bounces=1, seed=4).render()
    arriving = {"sun": math.sin(math.radians(40.0)), "sky": 1.0}
    for part, above in arriving.items():
        apar = (leaves.meta["area_m2"] * getattr(leaves, f"absorbed_{part}")).sum() / CELL.area_m2
        apar_se = math.sqrt(((leaves.meta["area_m2"] * leaves.se[f"absorbed_{part}"]) ** 2).sum()) / CELL.area_m2
        tau = getattr(soil, f"incident_{part}")[0] / above
        se = math.hypot(apar_se / above, soil.se[f"incident_{part}"][0] / above)
        assert apar / above == pytest.approx(1.0 - tau, abs=4 * se + 0.01), (part, apar / above, tau, se)


def test_sensors_give_gradients_and_do_not_change_the_segments(spherical):
    """Scattered light reaches the soil sensor through the leaves' BSDF: the sensor has a
    gradient by the leaf parameters (checked against finite differences, common random numbers),
    and rendering the sensor and its gradient leaves the segments' render as it was (bitwise)."""
    mesh, n = spherical
    fs = FieldScene(mesh, GREY, cell=CELL)
    fs.set_sun(50.0, 120.0)
    leaves = SegmentEstimator(fs, np.arange(1, n + 1), samples=4, bounces=2, seed=5)
    before = leaves.render()
    est = SensorEstimator(fs, [ceptometer(CELL, placements=2)], samples=512, bounces=2, seed=5)
    h = 1e-2
    for part in ("incident_sky", "incident_sun"):
        g = est.vjp({part: np.ones(1)})
        for k in ("subsurface", "specular"):
            x = getattr(GREY, k)
            fs.set_optics(**{k: x + h})
            plus = getattr(est.render(), part)[0]
            fs.set_optics(**{k: x - h})
            minus = getattr(est.render(), part)[0]
            fs.set_optics(**{k: x})
            fd = (plus - minus) / (2 * h)
            if k == "subsurface":
                assert fd > 0  # more transmission through the leaves, more light on the soil
            # Frozen sampling: AD and the central difference estimate one smooth function. Measured
            # ≤ 4e-7 relative for subsurface (linear in it), ≤ 2.3e-5 for specular (float32 round-off
            # in the difference); the test allowed 5 % before. About 10× the measured, or more.
            assert g[k] == pytest.approx(fd, rel=1e-5 if k == "subsurface" else 2e-4), (part, k, g[k], fd)
    after = leaves.render()
    for p in ("incident_sun", "incident_sky", "absorbed_sun", "absorbed_sky"):
        np.testing.assert_array_equal(getattr(after, p), getattr(before, p), err_msg=p)


def test_sensor_layouts_and_bad_input():
    fld = Field(boundary="finite", n_plants=9, buffer_rows=1)
    (cep,) = default_sensors(fld)
    a, b = cep.lines()
    area = measured_area(fld)
    assert len(a) == 8 and cep.height_m == 0.0
    # Across the rows (⊥ to the row direction), clipped to the finite area's width.
    length = np.linalg.norm(b - a, axis=1)
    assert length == pytest.approx(min(0.8, area.size_m[1]))
    ea, _ = area.axes
    assert np.abs((b - a)[:, :2] @ ea) == pytest.approx(0.0, abs=1e-12)
    ab = np.concatenate([area.to_local(a), area.to_local(b)])
    assert (np.abs(ab) <= area.size_m / 2 + 1e-12).all()
    periodic = Field(n_plants=9, buffer_rows=0, boundary="periodic")
    (p,) = default_sensors(periodic)
    assert np.linalg.norm(np.subtract(*p.lines()), axis=1) == pytest.approx(0.8)
    with pytest.raises(InputError, match="heights"):
        Sensor("tilted", ((0, 0, 0),), ((1, 0, 0.1),))
    with pytest.raises(InputError, match="placements"):
        ceptometer(area, placements=0)
    with pytest.raises(InputError, match="sensors"):
        SensorEstimator(FieldScene(square([0, 0, 0.5], [0, 0, 1], 0.1, 1), GREY), [])
    pt = Sensor("grid", ((0.0, 0.0, 0.3), (0.1, 0.0, 0.3)), ((0.0, 0.0, 0.3), (0.1, 0.0, 0.3)))  # two points
    assert pt.height_m == pytest.approx(0.3)


# -- the observation operator -------------------------------------------------------------------
@pytest.fixture(scope="module")
def small_model():
    from lightfit import replication as rep
    from lightfit.model.coupled import CoupledModel
    from lightfit.model.scenario import Scenario

    weather = rep.forcing().iloc[[1, 14]]  # 05:30 local (night), 12:00
    sc = Scenario(
        weather=weather, field=Field(boundary="finite", n_plants=4, buffer_rows=1, seed=1), samples=8, bounces=1
    )
    return CoupledModel(sc)


def test_ceptometer_observables_are_the_sensor_render_scaled_by_the_weather(small_model):
    """transmitted = f·(DNI_PAR·e_sun + DHI_PAR·e_sky) of an independent SensorEstimator render at
    the step's sun; τ = transmitted / above; ceptometer fAPAR = 1 − τ; 0 at night; NaN without sensors."""
    from lightfit.model.parameters import Theta

    m = small_model
    th = m.theta(Theta(light_factor=1.2))
    o = m.observe(th)
    sc = m.scenario
    fs = FieldScene(m.geometry.mesh, sc.optics, sky=sc.sky, cell=m.geometry.cell)
    fs.set_optics(**dict(zip(("specular", "roughness", "subsurface"), np.asarray(th.leaf, float))))
    fs.set_sun(*m.sun_deg[1])
    r = SensorEstimator(fs, m.sensors, bounces=sc.bounces, seed=sc.seed).render()
    fc = m.forcing
    expected = 1.2 * (fc.dni_par[1] * r.incident_sun[0] + fc.dhi_par[1] * r.incident_sky[0])
    got = np.asarray(o["transmitted_par_umol_m2_s"])
    assert got[0] == 0.0 and got[1] == pytest.approx(expected, rel=1e-5)
    above = np.asarray(o["above_canopy_par_umol_m2_s"])
    tau = np.asarray(o["ceptometer_transmittance"])
    assert tau[1] == pytest.approx(got[1] / above[1], rel=1e-9) and 0 < tau[1] < 1
    assert np.asarray(o["ceptometer_fapar"]) == pytest.approx([0.0, 1 - tau[1]])
    sd = 1.2 * math.hypot(fc.dni_par[1] * r.se["incident_sun"][0], fc.dhi_par[1] * r.se["incident_sky"][0])
    assert float(o["transmitted_par_mc_sd_umol_m2_s"][1]) == pytest.approx(sd, rel=1e-4)
    # The above-canopy PAR is exact, so SD(τ) = SD(transmitted) / above, and 1 − τ has τ's SD (a
    # mutation audit set the fAPAR's SD to 0 and no test saw it; the likelihood weighs by it).
    tau_sd = np.asarray(o["ceptometer_transmittance_mc_sd"])
    assert tau_sd[1] == pytest.approx(sd / above[1], rel=1e-4) and tau_sd[1] > 0
    np.testing.assert_allclose(np.asarray(o["ceptometer_fapar_mc_sd"]), tau_sd, rtol=1e-12)
    parts = m.render(th)
    assert parts[0].shape[-1] == len(m.segment_id) + 1 == m.n_columns
    bare = m.with_light(lambda _: tuple(x[..., :-1] for x in parts))
    bare.operator = dataclasses.replace(m.operator, sensors=())
    assert np.isnan(np.asarray(bare.observe(th)["ceptometer_transmittance"])[1])


def test_observations_name_the_ceptometer_series(tmp_path):
    from lightfit.inference.observations import observed, read_observations, series

    f = tmp_path / "obs.csv"
    f.write_text(
        "# provenance: synthetic\n# time_zone: UTC\n"
        "time,ceptometer_transmittance,ceptometer_transmittance_sd,transmitted_par_umol_m2_s,"
        "transmitted_par_sd_umol_m2_s\n2016-04-20 11:00:00,0.2,0.03,300,40\n",
        encoding="utf-8",
    )
    obs = read_observations(f)
    assert observed(obs) == ("transmitted_par", "ceptometer_transmittance")
    assert series("ceptometer_fapar").unit == "1"
    f.write_text("# provenance: synthetic\ntime,ceptometer_transmittance,ceptometer_transmittance_sd\nx,-0.1,0.1\n")
    with pytest.raises(InputError):
        read_observations(f)


def test_ceptometer_height_is_a_scenario_knob():
    """Scenario.ceptometer_height_m moves the default ceptometer: above the canopy top it reads the
    analytic above-canopy PAR (τ = 1 exactly: every ray escapes), inside the canopy more than on the
    soil; bad heights are refused before any plant grows."""
    from lightfit import replication as rep
    from lightfit.model.coupled import CoupledModel
    from lightfit.model.parameters import Theta
    from lightfit.model.scenario import Scenario

    weather = rep.forcing().iloc[[14]]  # 12:00 local
    fld = Field(n_plants=4, seed=1, boundary="periodic")
    tau = {}
    for h in (0.0, 0.3, 2.0):
        m = CoupledModel(Scenario(weather=weather, field=fld, samples=8, bounces=1, ceptometer_height_m=h))
        assert m.sensors[0].height_m == h
        tau[h] = float(m.observe(Theta())["ceptometer_transmittance"][0])
    assert tau[2.0] == pytest.approx(1.0, abs=1e-6)
    assert tau[0.0] < tau[0.3] < tau[2.0]
    for bad in (-0.1, 11.0, True, "1"):
        with pytest.raises(InputError, match="ceptometer_height_m"):
            Scenario(weather=weather, field=fld, ceptometer_height_m=bad)


def test_each_placement_is_sampled_along_its_whole_length_and_each_sensor_reads_its_own_lines():
    """Zenith sun over a black 20 cm square leaf 0.3 m up (finite field): a sensor of two 40 cm bars,
    one half under the leaf and one in the open, reads (½ + 1)/2 = 0.75 of the sun; a second sensor,
    a point under the leaf, reads 0 (hand-traced shadows)."""
    leaf = square([-0.1, 0.0, 0.3], [0, 0, 1], 0.2, 1)  # covers x ∈ [−0.2, 0], y ∈ [−0.1, 0.1]
    fs = FieldScene(leaf, BLACK)
    fs.set_sun(90.0, 0.0)
    bars = Sensor("bars", ((-0.2, 0.0, 0.0), (-0.2, 0.5, 0.0)), ((0.2, 0.0, 0.0), (0.2, 0.5, 0.0)))
    under = Sensor("under", ((-0.1, 0.0, 0.0),), ((-0.1, 0.0, 0.0),))  # a point: a bar of length 0
    r = SensorEstimator(fs, [bars, under], samples=1024, bounces=0, seed=6).render()
    assert r.incident_sun == pytest.approx([0.75, 0.0], abs=max(4 * r.se["incident_sun"].max(), 0.02))


def test_ceptometer_bars_are_centred_on_equal_strips_along_the_rows():
    """Bar k of P lies across the rows, its centre at ((k + ½)/P − ½)·A along them (the docstring's
    stratified placements), in a rotated, off-centre area."""
    area = PeriodicCell(1.2, 0.5, row_direction_deg=30.0, center_xy=(2.0, -1.0))
    for placements in (1, 3, 8):
        a, b = ceptometer(area, placements=placements).lines()
        mid = area.to_local((a + b) / 2)
        np.testing.assert_allclose(mid[:, 0], ((np.arange(placements) + 0.5) / placements - 0.5) * 1.2, atol=1e-12)
        np.testing.assert_allclose(area.to_local(b) - area.to_local(a), [[0.0, 0.8]] * placements, atol=1e-12)


def test_measured_area_is_the_measured_plants_own_patches_in_a_rotated_oblong_field():
    """The measured area of a finite field of 2 rows × 5 plants (not a square: rows and plants per
    row told apart; 3 cm within a row, 12.5 cm between rows) whose rows run 30° east of north is
    found again from the plants alone: each measured plant stands in the middle of its own plant
    spacing × row spacing patch, so the area is their extent plus one spacing each way, 10 × 0.03 ×
    0.125 m² in all, centred on them. The row frame is worked by hand from the compass azimuth
    (along = (sin 30°, cos 30°), across = (−cos 30°, sin 30°)), and the default ceptometer's 8 bars
    lie across these rows (⊥ to the along vector), clipped to the 0.25 m width, inside the patches,
    centred on equal strips along the rows. A mutation audit: the area with rows and plants per row
    swapped, with the two spacings swapped, or without the row direction, passed every test (the
    tests' square, east–west fields could not tell)."""
    fld = Field(boundary="finite", n_plants=10, plants_per_row=5, buffer_rows=1, row_direction_deg=30.0)
    area = measured_area(fld)
    plants = fld.plants()
    xy = plants.loc[plants["measured"], ["x_m", "y_m"]].to_numpy()
    assert len(xy) == 10
    s, c = math.sin(math.radians(30.0)), math.cos(math.radians(30.0))
    along_hat, across_hat = np.array([s, c]), np.array([-c, s])
    centre = xy.mean(axis=0)
    a, b = (xy - centre) @ along_hat, (xy - centre) @ across_hat
    length = np.ptp(a) + 0.03  # 4 spacings between 5 plants, and half a spacing beyond each end
    width = np.ptp(b) + 0.125
    assert (length, width) == pytest.approx((5 * 0.03, 2 * 0.125), abs=1e-12)
    np.testing.assert_allclose(area.size_m, [length, width], atol=1e-12)
    np.testing.assert_allclose(area.center_xy, centre, atol=1e-12)
    assert area.area_m2 == pytest.approx(10 * 0.03 * 0.125, rel=1e-12)
    np.testing.assert_allclose(area.axes[0], along_hat, atol=1e-12)
    (cep,) = default_sensors(fld)
    p, q = cep.lines()
    d = (q - p)[:, :2]
    np.testing.assert_allclose(d @ along_hat, 0.0, atol=1e-12)  # across the rows
    np.testing.assert_allclose(np.abs(d @ across_hat), 0.25, atol=1e-12)  # clipped to the 2 rows' width
    for end in (p, q):
        ea, eb = (end[:, :2] - centre) @ along_hat, (end[:, :2] - centre) @ across_hat
        assert (np.abs(ea) <= length / 2 + 1e-12).all() and (np.abs(eb) <= width / 2 + 1e-12).all()
    mid = ((p + q)[:, :2] / 2 - centre) @ along_hat
    np.testing.assert_allclose(mid, (np.arange(8) + 0.5) / 8 * length - length / 2, atol=1e-12)
    # A periodic field's measured area is its cell, one spacing × spacing patch per plant too.
    per = Field(n_plants=10, plants_per_row=5, row_direction_deg=30.0)
    assert measured_area(per) == per.cell and per.cell.area_m2 == pytest.approx(10 * 0.03 * 0.125, rel=1e-12)


@pytest.mark.parametrize("placements", [3, 8, 20])
def test_clipped_bars_in_a_wide_area_stay_in_it_and_spread_across_the_rows(placements):
    """A finite area 2 m across the rows (16 rows of 12.5 cm) is wider than the 0.8 m bar: the bars'
    centres move across the rows over the free 1.2 m (2 − 0.8) so that every bar lies wholly in the
    area, and the placements measure different positions across the rows: P different centres,
    no stretch of the free width longer than 2/P of it left between two centres or at either end (a
    stratified spread; the golden-ratio Kronecker steps leave at most 1.8/P for P ≤ 30). Worked in
    the area's frame: rows running north (x across, y along), centre (1, −2). A mutation audit: the
    centres taken from 0 to the free width (not centred: bars 0.6 m beyond the area, over the
    buffer rows) and a Kronecker step of ½ (two positions only) passed every test, whose finite
    areas were narrower than a bar."""
    area = PeriodicCell(0.6, 2.0, row_direction_deg=0.0, center_xy=(1.0, -2.0))
    p, q = ceptometer(area, placements=placements, clip=True).lines()
    # Rows run north: along = y, across = −x (90° counter-clockwise from along), from the centre.
    for end in (p, q):
        assert (np.abs(end[:, 1] + 2.0) <= 0.3 + 1e-12).all()
        assert (np.abs(end[:, 0] - 1.0) <= 1.0 + 1e-12).all(), end[:, 0]
    np.testing.assert_allclose(np.abs(q[:, 0] - p[:, 0]), 0.8, atol=1e-12)
    centres = np.sort((p[:, 0] + q[:, 0]) / 2 - 1.0)
    assert len(np.unique(np.round(centres, 9))) == placements
    gaps = np.diff(np.concatenate([[-0.6], centres, [0.6]]))
    assert gaps.max() <= 2.0 / placements * 1.2 + 1e-12, gaps


def test_sensor_heights_are_refused_below_the_soil_and_averaged_over_placements():
    """A sensor below the soil surface would read light through the ground: refused, as a tilted bar
    is; a sensor with placements at 0.2 m and 0.4 m has the mean height 0.3 m (the attribute's
    docstring; a mutation audit: negative heights accepted, and the highest placement taken, passed)."""
    with pytest.raises(InputError, match="heights"):
        Sensor("buried", ((0.0, 0.0, -0.05),), ((0.8, 0.0, -0.05),))
    two = Sensor("two", ((0.0, 0.0, 0.2), (0.0, 1.0, 0.4)), ((0.8, 0.0, 0.2), (0.8, 1.0, 0.4)))
    assert two.height_m == pytest.approx(0.3, abs=1e-12)


@pytest.mark.parametrize(
    "kw, name",
    [
        (dict(placements=True), "placements"),
        (dict(placements=2.0), "placements"),
        (dict(length_m="0.8"), "length_m"),
        (dict(length_m=math.inf), "length_m"),
        (dict(height_m=-0.1), "height_m"),
        (dict(height_m=math.nan), "height_m"),
        (dict(height_m="1"), "height_m"),
    ],
)
def test_ceptometer_arguments_are_refused_by_name(kw, name):
    """A bad ceptometer argument is the InputError naming it: placements=True stopped on a numpy
    TypeError, a text length or height on Python's, and a negative or NaN height was blamed on
    'sensors' (the end points) instead of height_m."""
    with pytest.raises(InputError, match=f"parameter '{name}'"):
        ceptometer(CELL, **kw)


def test_a_sensor_area_or_end_points_that_are_no_numbers_and_a_text_leaf_value_are_refused_by_name():
    """ceptometer(area=None) stopped on an AttributeError naming size_m, a Sensor of text or ragged end
    points on numpy's ValueError naming no sensor, and FieldScene.set_optics(specular="x") on
    float()'s ValueError (a review); each is the InputError naming its argument."""
    with pytest.raises(InputError, match="parameter 'area'"):
        ceptometer(None)
    for starts in ((("a", 0.0, 0.1),), ((0.0, 0.0, 0.1), (0.0, 0.1))):
        with pytest.raises(InputError, match="parameter 'sensors'.*numbers"):
            Sensor("s", starts, ((0.5, 0.0, 0.1),) * len(starts))
    scene = FieldScene(square((0.0, 0.0, 0.3), (0.0, 0.0, 1.0), 0.1, 1), Optics.preset("paper"))
    for bad in ("x", 1.5, math.nan):
        with pytest.raises(InputError, match="parameter 'specular'"):
            scene.set_optics(specular=bad)
    scene.set_optics(specular=0.25)
    assert scene.optics.specular == 0.25


def test_the_ceptometer_variables_do_not_put_a_raised_ceptometer_on_the_soil():
    """results.nc's long names and comments of the ceptometer's variables said "on the soil under
    the canopy" whatever --ceptometer-height-m was (a review): they name the height knob instead."""
    from lightfit.inference.observations import BY_NAME
    from lightfit.model.schema import VARIABLES

    for k in ("transmitted_par_umol_m2_s", "transmitted_par_mc_sd_umol_m2_s"):
        v = VARIABLES[k]
        assert "on the soil under" not in v.long_name and "bars on the soil" not in v.comment, k
        assert "ceptometer_height_m" in v.comment, k
    assert "ceptometer_height_m" in BY_NAME["transmitted_par"].meaning
