"""Per-segment irradiance against analytic physics, Mitsuba's irradiancemeter and finite differences."""

import math

import numpy as np
import pandas as pd
import pytest

import lightfit  # noqa: F401
from lightfit.errors import InputError
from lightfit.light import backend
from lightfit.light.bridge import make_irradiance
from lightfit.light.estimator import PARTS, SegmentEstimator, bounces_for_tolerance, render_adaptive
from lightfit.light.scene import FieldScene, Optics, sun_vector
from lightfit.plant import Field, build
from lightfit.plant.mesh import Mesh

mi = backend.mitsuba()
BLACK = Optics(specular=0.0, roughness=0.5, subsurface=0.0, base_color=0.0, soil_albedo=0.0)


def square(center, normal, size, seg_id, blade=True):
    """Two triangles, counter-clockwise around ``normal``."""
    n = np.asarray(normal, float) / np.linalg.norm(normal)
    a = np.cross(n, [0.0, 0.0, 1.0] if abs(n[2]) < 0.9 else [1.0, 0.0, 0.0])
    a /= np.linalg.norm(a)
    b = np.cross(n, a)
    c = np.asarray(center, float)
    h = size / 2
    v = np.array([c - h * a - h * b, c + h * a - h * b, c + h * a + h * b, c - h * a + h * b])
    return Mesh(v, np.array([[0, 1, 2], [0, 2, 3]]), np.array([seg_id, seg_id]), np.array([blade, blade]))


def tilted_leaf(beta_deg, azimuth_deg=180.0):
    """A 10 cm square leaf 1 m above the soil, tilted by β towards ``azimuth_deg``."""
    b, az = math.radians(beta_deg), math.radians(azimuth_deg)
    n = [math.sin(b) * math.sin(az), math.sin(b) * math.cos(az), math.cos(b)]
    return square([0, 0, 1.0], n, 0.1, 7), np.array(n)


@pytest.mark.parametrize("beta, el, az", [(0, 60, 180), (40, 35, 180), (70, 20, 90), (120, 45, 0)])
def test_unoccluded_tilted_plane_matches_analytic(beta, el, az):
    rho = 0.2
    mesh, n = tilted_leaf(beta)
    fs = FieldScene(mesh, Optics(specular=0.0, base_color=0.0, subsurface=0.0, soil_albedo=rho))
    fs.set_sun(el, az)
    r = SegmentEstimator(fs, [7], samples=6000, bounces=2, seed=3).render()
    cb = math.cos(math.radians(beta))
    s = sun_vector(el, az)
    cos_i = float(n @ s)
    ground_view = (1 - cb) / 2
    # Front side: direct sun + sky view factor + soil (lit by sky and sun) seen below the horizon.
    exp_sun = max(cos_i, 0.0) + rho * s[2] * ground_view
    exp_sky = (1 + cb) / 2 + rho * 1.0 * ground_view
    front_sun, front_sky = r.front("incident_sun")[0], r.front("incident_sky")[0]
    assert front_sun == pytest.approx(exp_sun, abs=0.01)
    assert front_sky == pytest.approx(exp_sky, abs=0.01)
    # Both sides together see the full sphere: sky 1 + soil ρ·(DHI 1 + DNI sin el).
    assert r.incident_sky[0] == pytest.approx(1 + rho, abs=0.015)
    assert r.incident_sun[0] == pytest.approx(abs(cos_i) + rho * s[2], abs=0.015)
    # A black leaf absorbs everything it receives.
    assert r.absorbed_sky[0] == pytest.approx(r.incident_sky[0], rel=1e-6)


@pytest.mark.parametrize("shaded", [0.0, 0.3, 0.5, 0.85])
def test_direct_sun_on_a_partly_shaded_square_matches_its_sunlit_share(shaded):
    """A horizontal 10 cm square leaf under an opaque black board 5 cm above it, placed so that its
    shadow covers the share ``shaded`` of the leaf (a straight edge across it), sun at 50°: the
    direct irradiance on the upper side is sin 50° · (1 − shaded) exactly (no scattering: black
    board, leaf and soil, 0 bounces). Unshaded, every point gets cos θ and the SE is 0; shaded,
    the estimate is within 4 SE of the exact value (the SE has 7 degrees of freedom: over 12
    seeds the largest |error| ÷ SE was 2.6 and the mean of its square 1.3–1.5, as expected of a
    Student t with 7 degrees of freedom, 1.4)."""
    el, az, h, size = 50.0, 200.0, 0.05, 0.1
    s = sun_vector(el, az)
    meshes = [square([0, 0, 0.5], [0, 0, 1], size, 7)]
    if shaded > 0:
        # The board covers leaf points with x < x_edge (and all y); lifted along the sun ray.
        x_edge = -size / 2 + shaded * size
        meshes.append(square(np.array([x_edge - 0.5, 0.0, 0.5]) + h * s / s[2], [0, 0, 1], 1.0, 8))
    fs = FieldScene(Mesh.concatenate(meshes), BLACK)
    fs.set_sun(el, az)
    r = SegmentEstimator(fs, [7], samples=64, bounces=0, seed=2).render()
    exact = math.sin(math.radians(el)) * (1 - shaded)
    got, se = r.front("incident_sun")[0], r.se["incident_sun"][0]
    assert r.incident_sun[0] == got  # the lower side faces away from the sun
    if shaded == 0:
        assert got == pytest.approx(exact, rel=1e-6) and se < 1e-6 * exact
    else:
        assert 0 < se and abs(got - exact) <= 4 * se, (got, exact, se)


def test_sun_below_horizon_gives_exactly_zero_sun_part():
    """Below or on the horizon: no sun part at all. Half a degree above it, an unoccluded leaf
    gets the analytic beam |n·s| on the side facing the sun plus the soil's reflection ρ·sin β
    (both sides together see the whole lower hemisphere; the leaf's own shadow falls ≈ 100 m
    away), within 4 SE."""
    mesh, n = tilted_leaf(30)
    rho = 0.3
    fs = FieldScene(mesh, Optics.preset("paper", soil_albedo=rho))
    for el in (-0.5, -20.0, 0.0):
        fs.set_sun(el, 120)
        r = SegmentEstimator(fs, [7], samples=64, bounces=3, seed=1).render()
        assert r.incident_sun[0] == 0.0 and r.absorbed_sun[0] == 0.0 and r.se["incident_sun"][0] == 0.0
        assert r.incident_sky[0] > 0.5
    fs.set_sun(0.5, 120)
    r = SegmentEstimator(fs, [7], samples=256, bounces=3, seed=1).render()
    s = sun_vector(0.5, 120)
    exact = abs(float(n @ s)) + rho * s[2]
    assert r.incident_sun[0] == pytest.approx(exact, abs=4 * r.se["incident_sun"][0] + 1e-3)


def test_overcast_sky_is_normalised_and_zenith_weighted():
    # Horizontal leaf: sees DHI = 1 from either sky; a vertical one sees less under overcast
    # (L ∝ 1 + 2 cos θz): view factor ∫ over half the sky = 3/7·(1/2 + 2/3·1/π·... ) computed numerically.
    flat, _ = tilted_leaf(0)
    wall, _ = tilted_leaf(90)
    vals = {}
    for sky in ("isotropic", "overcast"):
        for name, mesh in (("flat", flat), ("wall", wall)):
            fs = FieldScene(mesh, BLACK, sky=sky)
            fs.set_sun(-10, 0)
            vals[sky, name] = (
                SegmentEstimator(fs, [7], samples=4000, bounces=1, seed=2).render().front("incident_sky")[0]
            )
    assert vals["isotropic", "flat"] == pytest.approx(1.0, abs=0.01)
    assert vals["overcast", "flat"] == pytest.approx(1.0, abs=0.01)
    assert vals["isotropic", "wall"] == pytest.approx(0.5, abs=0.01)
    # Vertical surface under the CIE overcast sky: (9/7)(1/2·1/3... ) = 0.5·(3 + 2·4/(3π)·... ) closed form:
    # E = ∫ L(θ) cos(angle to wall normal) dω = L0/3 [π/2 + 2·(2/3)] with L0 = 9/(7π) -> 0.3954...
    expected = 9 / (7 * math.pi) / 3 * (math.pi / 2 + 4 / 3)
    assert vals["overcast", "wall"] == pytest.approx(expected, abs=0.01)


def test_irradiancemeter_peer_for_diffuse_and_scattered_light():
    """Front-side sky irradiance of one isolated tilted leaf vs Mitsuba's own irradiancemeter."""
    beta, rho = 50.0, 0.3
    mesh, n = tilted_leaf(beta)
    fs = FieldScene(mesh, Optics.preset("paper", soil_albedo=rho))
    fs.set_sun(-5, 0)
    ours = SegmentEstimator(fs, [7], samples=8000, bounces=3, seed=5).render().front("incident_sky")[0]
    T = mi.ScalarTransform4f
    b = math.radians(beta)
    meter = mi.load_dict(
        {
            "type": "scene",
            "integrator": {"type": "path", "max_depth": 4},
            "leaf": {
                "type": "rectangle",
                "to_world": T.translate([0, 0, 1.0]).rotate([1, 0, 0], math.degrees(b)).scale(0.05),
                "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.0, 0.0, 0.0]}},
                "sensor": {
                    "type": "irradiancemeter",
                    "sampler": {"type": "independent", "sample_count": 1},
                    "film": {
                        "type": "hdrfilm",
                        "width": 1,
                        "height": 1,
                        "rfilter": {"type": "box"},
                        "pixel_format": "luminance",
                    },
                },
            },
            "ground": {
                "type": "rectangle",
                "to_world": T.scale([500, 500, 1]),
                "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [rho] * 3}},
            },
            "sky": {"type": "constant", "radiance": {"type": "rgb", "value": [1 / math.pi] * 3}},
        }
    )
    img = mi.render(meter, spp=200_000, seed=1)
    peer = float(np.asarray(img).ravel()[0])
    # Mitsuba's rectangle normal +z rotated about x by +β tilts towards −y; ours towards azimuth 180 (−y).
    assert n[1] < 0
    expected = (1 + math.cos(b)) / 2 + rho * (1 - math.cos(b)) / 2
    assert peer == pytest.approx(expected, abs=0.01)
    assert ours == pytest.approx(peer, abs=0.012)


def _random_canopy(lai, angles, rng, half=3.5, z=(0.2, 1.0), leaf=0.04):
    n_leaves = int(round(lai * (2 * half) ** 2 / leaf**2))
    centers = np.column_stack(
        [rng.uniform(-half, half, n_leaves), rng.uniform(-half, half, n_leaves), rng.uniform(*z, n_leaves)]
    )
    if angles == "horizontal":
        normals = np.tile([0.0, 0.0, 1.0], (n_leaves, 1))
    else:  # spherical: normals uniform on the sphere
        normals = rng.normal(size=(n_leaves, 3))
    parts = [square(c, nn, leaf, 1) for c, nn in zip(centers, normals)]
    # 2500 small horizontal sensors on the soil, 4 cm apart in the central 2 m × 2 m, ids 100+;
    # shadows are ~4 cm wide, so the sensors are nearly independent samples of the gap fraction.
    sx, sy = np.meshgrid(np.linspace(-1.0, 1.0, 50), np.linspace(-1.0, 1.0, 50))
    parts += [square([x, y, 0.001], [0, 0, 1], 0.01, 100 + i) for i, (x, y) in enumerate(zip(sx.ravel(), sy.ravel()))]
    return Mesh.concatenate(parts)


@pytest.mark.parametrize("angles, G", [("horizontal", None), ("spherical", 0.5)])
def test_beer_lambert_gap_fraction(angles, G):
    lai = 1.5
    mesh = _random_canopy(lai, angles, np.random.default_rng(11))
    fs = FieldScene(mesh, BLACK)
    sensors = np.arange(100, 2600)
    for el in (30.0, 50.0, 70.0):
        fs.set_sun(el, 150)
        r = SegmentEstimator(fs, sensors, samples=4, bounces=0, seed=1).render()
        cos_z = math.sin(math.radians(el))
        gap = r.front("incident_sun").mean() / cos_z
        g = cos_z if G is None else G
        # Binomial SE over ~2500 independent sensors ≈ 0.008; tolerance ≈ 3.5 SE.
        assert gap == pytest.approx(math.exp(-g * lai / cos_z), abs=0.03), (angles, el)


def _small_field():
    g = build(Field(boundary="finite", n_plants=4, buffer_rows=1, seed=1))
    ids = g.segments.loc[g.segments.measured, "segment_id"].to_numpy()
    return g, ids


@pytest.mark.parametrize("sun_azimuth_deg", [180.0, 270.0])
def test_gradients_match_central_differences_with_common_random_numbers(sun_azimuth_deg):
    g, ids = _small_field()
    # The albedo is a cubic (Catmull–Rom) in roughness between table nodes 1/32 apart, its slope
    # continuous across them: roughness 0.515 ± 0.0025 differences see a smooth function (while the
    # table was linear, a ±0.1 step across the node at 0.5 was off by a systematic 1–5 %).
    fs = FieldScene(g.mesh, Optics.preset("paper", roughness=0.515))
    fs.set_sun(45, sun_azimuth_deg)
    ct = {
        "absorbed_sun": np.ones(len(ids)),
        "absorbed_sky": np.full(len(ids), 0.3),
        "incident_sky": np.full(len(ids), 0.1),
    }

    def J(r):
        return sum(np.sum(ct[p] * getattr(r, p)) for p in ct)

    h = {"specular": 0.1, "roughness": 0.0025, "subsurface": 0.1}
    names = list(h)
    G, F = [], []
    for seed in range(8):
        est = SegmentEstimator(fs, ids, samples=32, bounces=2, seed=seed)
        grad = est.vjp(ct)
        fd = []
        for k in names:
            base = getattr(fs.optics, k)
            fs.set_optics(**{k: base + h[k]})
            jp = J(est.render())
            fs.set_optics(**{k: base - h[k]})
            jm = J(est.render())
            fs.set_optics(**{k: base})
            fd.append((jp - jm) / (2 * h[k]))
        G.append([grad[k] for k in names])
        F.append(fd)
    G, F = np.array(G), np.array(F)
    # G and F of one seed share their random numbers: the SE of their mean difference is the paired
    # one, std(G − F)/√n (measured ≤ 2e-5 relative; the unpaired SE would be 1–8 %, hiding a 25 % error).
    se = np.std(G - F, axis=0, ddof=1) / np.sqrt(len(G))
    # Frozen sampling makes AD and CRN differences estimate the same smooth function: in specular and
    # subsurface the render is a polynomial of degree ≤ bounces + 1 (O(h²) difference error), in
    # roughness smooth inside a table cell, where the central difference's own O(h²) error is what
    # remains: −9e-4 relative at h = 0.01 (−1.45e-3 with the sun in the west), 4× less per halving.
    # Measured |mean(G − F)| ≤ 2e-6 relative for specular and subsurface, 5.5e-5 (8.4e-5 in the west)
    # for roughness at h = 0.0025; 1e-3 allows float32.
    assert (np.abs(G.mean(0) - F.mean(0)) <= 3 * se + 1e-3 * np.abs(F.mean(0))).all(), (G.mean(0), F.mean(0), se)
    assert (np.abs(F.mean(0)) > 1.0).all(), F.mean(0)  # each derivative is far from 0 (−6.6, 6.2, 4.3)


@pytest.mark.parametrize("name", ["specular", "subsurface"])
def test_gradient_on_a_lower_bound_matches_a_one_sided_difference(name):
    """A parameter exactly on its bound 0 keeps its gradient (Dr.Jit's clip sent it all to the
    constant bound: the gradient was 0 there and an optimiser on the bound could not leave it)."""
    g, ids = _small_field()
    fs = FieldScene(g.mesh, Optics.preset("paper", **{name: 0.0}))
    fs.set_sun(45, 180)
    ct = {"absorbed_sun": np.ones(len(ids)), "absorbed_sky": np.full(len(ids), 0.3)}
    h, G, F = 0.02, [], []
    for seed in range(4):
        est = SegmentEstimator(fs, ids, samples=16, bounces=2, seed=seed)
        G.append(est.vjp(ct)[name])
        j0 = sum(np.sum(c * getattr(est.render(), p)) for p, c in ct.items())
        fs.set_optics(**{name: h})
        jh = sum(np.sum(c * getattr(est.render(), p)) for p, c in ct.items())
        fs.set_optics(**{name: 0.0})
        F.append((jh - j0) / h)
    G, F = np.array(G), np.array(F)
    assert (G != 0).all()
    # The one-sided difference's O(h) error: the render is a polynomial of degree ≤ bounces + 1 in
    # each parameter with frozen sampling; 3 % at h = 0.02 (measured 0.2–0.7 %).
    assert abs(G.mean() - F.mean()) <= 3 * np.std(G - F, ddof=1) / 2 + 0.03 * abs(F.mean()), (G, F)


@pytest.mark.parametrize(
    "corner",
    [
        dict(specular=0.0, roughness=0.0, subsurface=0.0),
        dict(specular=1.0, roughness=1.0, subsurface=1.0),
        dict(specular=1.0, roughness=0.0, subsurface=1.0),
        dict(specular=0.0, roughness=1.0, subsurface=0.0),
    ],
)
def test_extreme_parameters_give_finite_values_and_gradients(corner):
    g, ids = _small_field()
    fs = FieldScene(g.mesh, Optics.preset("paper", **corner))
    for el in (89.0, 0.5):
        fs.set_sun(el, 200)
        est = SegmentEstimator(fs, ids, samples=8, bounces=3, seed=1)
        r = est.render()
        for p in PARTS:
            assert np.isfinite(getattr(r, p)).all() and (getattr(r, p) >= 0).all()
        for kind in ("sun", "sky"):  # a leaf absorbs at most what reaches it
            absorbed, incident = getattr(r, f"absorbed_{kind}"), getattr(r, f"incident_{kind}")
            assert (absorbed <= incident * (1 + 1e-6) + 1e-12).all()
        grad = est.vjp({p: np.ones(len(ids)) for p in PARTS})
        assert all(np.isfinite(v) for v in grad.values())


def test_degenerate_faces():
    leaf, _ = tilted_leaf(10)
    flat = Mesh(
        np.array([[0, 0, 0.5], [0.1, 0, 0.5], [0.2, 0, 0.5]]), np.array([[0, 1, 2]]), np.array([9]), np.array([True])
    )
    partial = Mesh(
        np.array([[0.3, 0, 0.5], [0.3, 0, 0.5], [0.4, 0.1, 0.5]]),
        np.array([[0, 1, 2]]),
        np.array([7]),
        np.array([True]),
    )
    fs = FieldScene(Mesh.concatenate([leaf, flat, partial]), Optics.preset("paper"))
    fs.set_sun(50, 180)
    est = SegmentEstimator(fs, [7, 9], samples=16, bounces=2, seed=0)
    r = est.render()
    assert all(np.isfinite(getattr(r, p)).all() for p in PARTS)
    assert r.incident_sky[1] == 0.0 and r.incident_sun[1] == 0.0  # segment 9 has no area
    assert r.incident_sky[0] > 0.5
    grad = est.vjp({"absorbed_sun": np.ones(2)})
    assert all(np.isfinite(v) for v in grad.values())


def test_deterministic_and_independent_of_the_requested_subset():
    g, ids = _small_field()
    fs = FieldScene(g.mesh, Optics.preset("paper"))
    fs.set_sun(40, 160)
    a = SegmentEstimator(fs, ids, samples=16, bounces=2, seed=4).render()
    b = SegmentEstimator(fs, ids, samples=16, bounces=2, seed=4).render()
    sub = ids[::7]
    c = SegmentEstimator(fs, sub, samples=16, bounces=2, seed=4).render()
    d = SegmentEstimator(fs, ids, samples=16, bounces=2, seed=5).render()
    for p in PARTS:
        assert np.array_equal(getattr(a, p), getattr(b, p))
        assert np.array_equal(getattr(a, p)[np.isin(a.segment_id, sub)], getattr(c, p))
    assert not np.array_equal(a.absorbed_sky, d.absorbed_sky)


def test_monte_carlo_error_falls_at_least_as_one_over_sqrt_k():
    """Randomised quasi-Monte Carlo: the error falls as K^-1/2 (plain Monte Carlo) or faster, at
    most as K^-1 (a QMC point set on a smooth integrand); 4× the samples divide the median SE by
    2 to 4 (measured 2.2–2.6 for seeds 1–3 since the point and first directions are
    low-dimensional Kronecker sequences; 1.9–2.1 with the clustered 31-dimensional one before)."""
    g, ids = _small_field()
    fs = FieldScene(g.mesh, Optics.preset("paper"))
    fs.set_sun(45, 180)
    # K = 32 and 128: both with 8 replicates (with 4, at K = 16, the median SE is biased low).
    rse = [np.median(SegmentEstimator(fs, ids, samples=k, bounces=2, seed=1).render().relative_se()) for k in (32, 128)]
    assert 2 * 0.8 <= rse[0] / rse[1] <= 4, rse


def test_bounces_for_tolerance_is_monotone():
    o = Optics.preset("paper")
    b = [bounces_for_tolerance(t, o) for t in (0.1, 0.01, 0.001)]
    assert b == sorted(b) and b[0] >= 1
    assert bounces_for_tolerance(0.01, Optics(base_color=0.0, specular=0.0, soil_albedo=0.0)) == 0
    with pytest.raises(InputError, match="tolerance"):
        bounces_for_tolerance(1.5, o)
    with pytest.raises(InputError, match="tolerance"):
        bounces_for_tolerance("0.01", o)
    # ρ^(b+1)/(1 − ρ) ≤ t: at ρ = 0.9 and t = 0.01, b + 1 ≥ ln(0.001)/ln(0.9) = 65.6, so b = 65, one
    # more than the cap; ρ = 0.999 would need 13 808 orders and ρ = 1 never converges: refused.
    for c in (0.9, 0.999, 1.0):
        with pytest.raises(InputError, match="bounces"):
            bounces_for_tolerance(0.01, Optics(base_color=c, specular=0.0, soil_albedo=0.1))
    # ρ = 0.5: 0.5^(b+1) ≤ 0.005 needs b + 1 ≥ 7.64, so b = 7.
    assert bounces_for_tolerance(0.01, Optics(base_color=0.5, specular=0.0, soil_albedo=0.1)) == 7


def test_bad_inputs():
    g, ids = _small_field()
    fs = FieldScene(g.mesh, Optics.preset("paper"))
    with pytest.raises(InputError, match="have no faces"):
        SegmentEstimator(fs, [123456789], samples=8)
    with pytest.raises(InputError, match="samples"):
        SegmentEstimator(fs, ids, samples=1)
    with pytest.raises(InputError, match="bounces"):
        SegmentEstimator(fs, ids, bounces=-1)
    # More orders than the bounce rule ever hands out (64: ρ⁶⁵/(1 − ρ) ≈ 1.1 % at ρ = 0.9) were
    # accepted, 10⁴ too, with memory growing as samples × bounces: refused naming the limit.
    for many in (65, 10_000):
        with pytest.raises(InputError, match=r"bounces.*\[0, 64\]"):
            SegmentEstimator(fs, ids, samples=8, bounces=many)
    assert SegmentEstimator(fs, ids, samples=8, bounces=64).bounces == 64
    with pytest.raises(InputError, match="sky"):
        FieldScene(g.mesh, sky="cloudy")
    with pytest.raises(InputError, match="soil_albedo"):
        Optics(soil_albedo=1.2)
    # numpy's reals are numbers (float32 was refused as "not a number"), a bool is not (True was 1.0);
    # stored as Python floats, so that equal leaves compare and print alike
    with pytest.raises(InputError, match="specular=True"):
        Optics(specular=True)
    leaf = Optics(specular=np.float32(0.5), roughness=np.float64(0.25))
    assert leaf == Optics(specular=0.5, roughness=0.25) and type(leaf.specular) is float
    with pytest.raises(InputError, match="subsurface"):
        fs.set_optics(subsurface=2.0)
    with pytest.raises(InputError, match="unknown output"):
        SegmentEstimator(fs, ids[:3], samples=4).vjp({"absorbed": np.ones(3)})
    # The wrong length, a preset's name for the optics, a name for the field: numpy's broadcast error
    # and AttributeErrors before (a review of the Python API)
    with pytest.raises(InputError, match=r"cotangent\['absorbed_sun'\] of shape \(4,\).*shape \(3,\)"):
        SegmentEstimator(fs, ids[:3], samples=4).vjp({"absorbed_sun": np.ones(4)})
    est = SegmentEstimator(fs, ids[:3], samples=4)
    one = est.vjp({"absorbed_sun": np.ones(1)})  # a length-1 cotangent broadcasts, as numpy's would
    assert all(np.array_equal(one[k], v) for k, v in est.vjp({"absorbed_sun": 1.0}).items())
    with pytest.raises(InputError, match=r"optics of type str.*Optics.preset"):
        FieldScene(g.mesh, "paper")
    from lightfit.plant import build

    with pytest.raises(InputError, match=r"fld of type str.*a Field"):
        build("x")
    with pytest.raises(InputError, match="segment_ids"):
        SegmentEstimator(fs, ids[:0], samples=8)
    # Ids out of order, repeated or not integers were sorted, merged or truncated unsaid, so results
    # came in another order or length than asked (a review of the Python API): refused, in
    # render_adaptive too; whole numbers as floats are ids.
    for bad, words in (
        (ids[:5][::-1], "comes after"),
        (np.r_[ids[:3], ids[2:4]], "repeats"),
        (ids[:3] + 0.4, "dtype float64"),
        (ids[:3].astype(bool), "dtype bool"),
    ):
        with pytest.raises(InputError, match=rf"segment_ids.*{words}.*(increasing order|integer)"):
            SegmentEstimator(fs, bad, samples=8)
        with pytest.raises(InputError, match=rf"segment_ids.*{words}"):
            render_adaptive(fs, bad, 0.1)
    assert np.array_equal(SegmentEstimator(fs, ids[:3].astype(float), samples=8).segment_id, ids[:3])
    assert np.array_equal(SegmentEstimator(fs, pd.array(ids[:3], dtype="Int64"), samples=8).segment_id, ids[:3])
    # float32 holds ids of 10⁶·plant + index only rounded (20 000 005 → 20 000 004, another segment)
    with pytest.raises(InputError, match="segment_ids of dtype float32"):
        SegmentEstimator(fs, ids[:3].astype(np.float32), samples=8)
    # A float seed would be rounded, a seed ≥ 2³² would repeat a smaller one's random numbers.
    for seed in (1.5, -1, 2**32, True):
        with pytest.raises(InputError, match="seed"):
            SegmentEstimator(fs, ids, samples=8, seed=seed)
    # NaN rays hit nothing (an unoccluded render), large offsets step over millimetre organs.
    for eps in (float("nan"), 0.0, -1e-5, 0.5):
        with pytest.raises(InputError, match="epsilon_m"):
            SegmentEstimator(fs, ids, samples=8, epsilon_m=eps)
    # An elevation above 90° would be a mirrored sun.
    for el, az in ((95.0, 0.0), (-91.0, 0.0), ("40", 0.0), (float("nan"), 0.0)):
        with pytest.raises(InputError, match="sun position"):
            fs.set_sun(el, az)


@pytest.mark.parametrize("periodic", [False, True])
def test_gradient_after_a_render_reuses_its_shadow_rays_bitwise(periodic):
    """A vjp at the sun of the last render reuses that render's shadow rays: the gradient is
    bitwise that of an estimator that never rendered; after the sun moves it casts its own."""
    if periodic:
        g = build(Field(n_plants=4, seed=1, boundary="periodic"))
        ids = g.segments.loc[g.segments.measured, "segment_id"].to_numpy()
    else:
        g, ids = _small_field()
    fs = FieldScene(g.mesh, Optics.preset("paper"), cell=g.cell)
    ct = {"absorbed_sun": np.ones(len(ids)), "incident_sky": np.full(len(ids), 0.1)}
    for el, az in ((45.0, 180.0), (20.0, 100.0)):
        fs.set_sun(el, az)
        fresh = SegmentEstimator(fs, ids, samples=16, bounces=2, seed=3).vjp(ct)
        est = SegmentEstimator(fs, ids, samples=16, bounces=2, seed=3)
        fs.set_sun(60.0, 200.0)
        est.render()  # shadow rays of another sun: not reused
        fs.set_sun(el, az)
        assert est.vjp(ct) == fresh
        est.render()
        assert est._sun_key() in est._suns_kept  # kept, and used by the next vjp
        assert est.vjp(ct) == fresh


@pytest.mark.parametrize("direct", ["paths", "projection"])
def test_points_below_the_soil_receive_nothing(direct):
    # A vertical wall (a stem-like, one-sided face) standing half in the soil, alone over black soil:
    # its buried half gets nothing, so per unit of its whole area it sees half of what a free wall
    # does: DHI/4 of sky and cos(i)/2 of direct sun. A face entirely below the soil gets exactly 0.
    half = square([0.0, 0.0, 0.0], [0.0, -1.0, 0.0], 0.1, 7, blade=False)
    buried = square([0.5, 0.0, -0.2], [0.0, -1.0, 0.0], 0.1, 8, blade=False)
    mesh = Mesh.concatenate([half, buried])
    if direct == "paths":
        fs = FieldScene(mesh, BLACK)
    else:  # a periodic cell wide enough that the wall's images hardly shade it (< 0.1 %)
        from lightfit.plant.periodic import PeriodicCell

        fs = FieldScene(mesh, BLACK, cell=PeriodicCell(along_m=2.0, across_m=2.0))
    fs.set_sun(30.0, 180.0)
    kw = {} if direct == "paths" else dict(direct="projection", direct_rays_per_m2=(2e6, 2e6))
    r = SegmentEstimator(fs, [7, 8], samples=2000, bounces=1, seed=3, **kw).render()
    cos_i = math.cos(math.radians(30.0))
    assert r.incident_sky[0] == pytest.approx(0.25, abs=4 * r.se["incident_sky"][0] + 0.005)
    assert r.incident_sun[0] == pytest.approx(cos_i / 2, abs=4 * r.se["incident_sun"][0] + 0.005)
    for part in PARTS:
        assert getattr(r, part)[1] == 0.0


@pytest.mark.parametrize(
    "az, expected",
    [(0.0, (0, 1)), (90.0, (1, 0)), (180.0, (0, -1)), (270.0, (-1, 0)), (135.0, (0.5**0.5, -(0.5**0.5)))],
)
def test_sun_azimuth_is_clockwise_from_north(az, expected):
    """pvlib's convention: azimuth 0° north (+y), 90° east (+x), 180° south, 270° west."""
    el = 35.0
    c, s = math.cos(math.radians(el)), math.sin(math.radians(el))
    assert sun_vector(el, az) == pytest.approx([expected[0] * c, expected[1] * c, s], abs=1e-12)


def test_more_samples_than_a_render_can_hold_are_refused_naming_the_largest_that_fits():
    """K = 10⁸ ended in a Dr.Jit error (arrays past 2³² entries) instead of an error naming samples.
    A render holds at most 2 × S × K evaluations (both sides of a blade) in arrays of 2³² entries, and
    2²⁴ points per replicate (8 replicates): for S segments the largest K is the smaller of
    ⌊(2³² − 1) / 2S⌋ and 8 × 2²⁴ = 134 217 728, rounded down to a multiple of 8."""
    g, ids = _small_field()
    fs = FieldScene(g.mesh, Optics.preset("paper"))
    S = len(ids)
    largest = min((2**32 - 1) // (2 * S), 8 * 2**24) // 8 * 8
    for k in (10**8, largest + 8):
        with pytest.raises(InputError, match=rf"parameter 'samples'.*at most {largest} samples"):
            SegmentEstimator(fs, ids, samples=k, bounces=0)
    # One segment: the 2²⁴ points per replicate bound (it was refused as 'first=0').
    with pytest.raises(InputError, match=r"parameter 'samples'.*at most 134217728 samples"):
        SegmentEstimator(fs, ids[:1], samples=8 * 2**24 + 8, bounces=0)
    with pytest.raises(InputError, match="samples"):
        make_irradiance(fs, ids, samples=10**8, bounces=0)
