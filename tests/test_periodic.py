"""Periodic boundaries: the measured plants as one cell of an infinite field (issue 13).

Independent references: Beer–Lambert gap fraction of a homogeneous random canopy, energy
conservation, translation invariance of an infinite field, finite differences for the gradient.
Every canopy is hand-made (small square leaves in a small cell), so each test takes seconds.
"""

import math

import numpy as np
import pytest

import lightfit  # noqa: F401
from lightfit.errors import InputError
from lightfit.light.estimator import PARTS, SegmentEstimator
from lightfit.light.periodic import crossing_cap
from lightfit.light.scene import FieldScene, Optics
from lightfit.plant import Field, build
from lightfit.plant.mesh import Mesh
from lightfit.plant.periodic import PeriodicCell

BLACK = Optics(specular=0.0, roughness=0.5, subsurface=0.0, base_color=0.0, soil_albedo=0.0)
SENSOR_ID0 = 100_000


def square(center, normal, size, seg_id):
    """A square blade of side ``size`` (two triangles, counter-clockwise around ``normal``)."""
    n = np.asarray(normal, float) / np.linalg.norm(normal)
    a = np.cross(n, [0.0, 0.0, 1.0] if abs(n[2]) < 0.9 else [1.0, 0.0, 0.0])
    a /= np.linalg.norm(a)
    b = np.cross(n, a)
    c, h = np.asarray(center, float), size / 2
    v = np.array([c - h * a - h * b, c + h * a - h * b, c + h * a + h * b, c - h * a + h * b])
    return Mesh(v, np.array([[0, 1, 2], [0, 2, 3]]), np.array([seg_id, seg_id]), np.array([True, True]))


def canopy(cell, lai, angles, rng, *, leaf=0.01, z=(0.1, 1.0), sensors=50, sensor_size=0.005):
    """Random canopy filling ``cell`` (leaf k has segment id k + 1) over a grid of soil sensors.

    Leaves: squares of side ``leaf`` with uniform random centres in the cell × ``z``, normals
    vertical (``"horizontal"``) or uniform on the sphere (``"spherical"``). Sensors: a
    ``sensors`` × ``sensors`` grid of small horizontal squares 1 mm above the soil, ids from
    :data:`SENSOR_ID0`, one at the centre of each grid cell (a uniform sample of the ground).
    """
    n = int(round(lai * cell.area_m2 / leaf**2))
    A, B = cell.size_m
    ab = np.column_stack([rng.uniform(-A / 2, A / 2, n), rng.uniform(-B / 2, B / 2, n)])
    centers = np.column_stack([cell.to_world(ab), rng.uniform(*z, n)])
    normals = np.tile([0.0, 0.0, 1.0], (n, 1)) if angles == "horizontal" else rng.normal(size=(n, 3))
    parts = [square(c, nn, leaf, k + 1) for k, (c, nn) in enumerate(zip(centers, normals))]
    g = (np.arange(sensors) + 0.5) / sensors - 0.5
    ga, gb = np.meshgrid(g * A, g * B)
    xy = cell.to_world(np.column_stack([ga.ravel(), gb.ravel()]))
    parts += [square([x, y, 0.001], [0, 0, 1], sensor_size, SENSOR_ID0 + i) for i, (x, y) in enumerate(xy)]
    return Mesh.concatenate(parts), n


def sensor_ids(mesh):
    return np.unique(mesh.face_segment[mesh.face_segment >= SENSOR_ID0])


def leaf_ids(mesh):
    return np.unique(mesh.face_segment[mesh.face_segment < SENSOR_ID0])


# -- geometry ---------------------------------------------------------------------------------
def test_cell_wrap_and_images_of_overhanging_faces():
    cell = PeriodicCell(1.0, 2.0, row_direction_deg=90.0)  # along = x (1 m), across = y (2 m)
    assert cell.bounds_m == ((-0.5, 0.5), (-1.0, 1.0))
    assert cell.wrap([[0.7, -1.3, 0.2]]) == pytest.approx(np.array([[-0.3, 0.7, 0.2]]))
    inside = square([0.0, 0.0, 0.5], [0, 0, 1], 0.2, 1)
    side = square([0.5, 0.0, 0.5], [0, 0, 1], 0.2, 2)  # over the +x face
    corner = square([0.5, 1.0, 0.5], [0, 0, 1], 0.2, 3)  # over the +x, +y corner
    long_leaf = square([0.0, 0.0, 0.5], [0, 0, 1], 2.5, 4)  # longer than the cell both ways
    img = cell.images(Mesh.concatenate([inside, side, corner, long_leaf]))
    per_seg = np.bincount(img.face_segment)
    assert per_seg[1] == 2 and per_seg[2] == 4 and per_seg[3] == 8  # faces: 1, 2, 4 images × 2 triangles
    assert per_seg[4] >= 2 * 3 * 2  # spans ≥ 3 periods along x and 2 across y
    # Every image is a whole lattice vector away from its original.
    shift = img.vertices[img.faces[img.face_segment == 2]][:, 0, :2] - side.vertices[side.faces][:, 0, :2].repeat(2, 0)
    assert sorted({round(float(s), 9) for s in shift[:, 0]}) == [-1.0, 0.0]


def test_rotated_cell_tiles_the_plane():
    cell = PeriodicCell(0.3, 0.5, row_direction_deg=30.0)
    rng = np.random.default_rng(0)
    p = np.column_stack([rng.uniform(-3, 3, (200, 2)), rng.uniform(0, 1, 200)])
    w = cell.wrap(p)
    ab = cell.to_local(w)
    assert (np.abs(ab) <= cell.size_m / 2 + 1e-12).all()
    # The move is a lattice vector: integer multiples of the periods in the cell frame.
    k = (cell.to_local(w) - cell.to_local(p)) / cell.size_m
    assert np.allclose(k, np.round(k)) and np.array_equal(w[:, 2], p[:, 2])


def test_field_boundary_api():
    fin = Field(boundary="finite", n_plants=9, seed=2)
    assert fin.boundary == "finite" and fin.buffer_rows == 2 and fin.cell is None
    per = Field(n_plants=9, seed=2, boundary="periodic")
    assert per.buffer_rows == 0 and per.b_along == 0 and per.m == 3
    assert per.cell.bounds_m == ((-0.045, 0.045), (-0.1875, 0.1875))  # 3 × 3 cm by 3 × 12.5 cm
    assert per.cell.area_m2 == pytest.approx(per.ground_area_m2)
    p = per.plants()
    assert len(p) == 9 and p["measured"].all()
    # The cell's plants are the finite field's measured plants (ids, seeds, positions).
    q = fin.plants()
    q = q[q["measured"]]
    assert np.array_equal(p.index, q.index) and np.array_equal(p["seed"], q["seed"])
    assert np.allclose(p[["x_m", "y_m"]], q[["x_m", "y_m"]])
    assert (np.abs(per.cell.to_local(p[["x_m", "y_m"]].to_numpy())) < per.cell.size_m / 2).all()
    # Tiles measure blocks; each needs the whole cell as geometry.
    tiles = per.tiles(3)
    assert np.array_equal(np.sort(np.concatenate([t.measured for t in tiles])), np.sort(p.index))
    for t in tiles:
        assert np.array_equal(t.plant_ids, np.sort(p.index))
    for kw, name in ((dict(buffer_rows=2), "buffer_rows"), (dict(buffer_along=4), "buffer_along")):
        with pytest.raises(InputError, match=name):
            Field(n_plants=9, boundary="periodic", **kw)
    assert Field(n_plants=9, boundary="periodic", buffer_rows=0, buffer_along=0).cell == per.cell
    # Periodic is the default; buffers without boundary='finite' are refused, naming the way out.
    assert Field(n_plants=9, seed=2) == per
    with pytest.raises(InputError, match="buffer_rows=2 with boundary='periodic'.*boundary='finite'"):
        Field(n_plants=9, buffer_rows=2)
    with pytest.raises(InputError, match="boundary"):
        Field(boundary="torus")
    # Rows in any compass direction: the cell turns with them and still holds every plant.
    skew = Field(n_plants=16, boundary="periodic", row_direction_deg=37.0)
    ab = skew.cell.to_local(skew.plants()[["x_m", "y_m"]].to_numpy())
    assert (np.abs(ab) < skew.cell.size_m / 2).all()
    assert np.unique(np.round(ab[:, 0] / skew.plant_spacing_m, 6)).size == 4  # 4 plants along each row


def test_a_periodic_tile_builds_the_whole_cell_and_measures_its_block():
    fld = Field(n_plants=4, seed=1, boundary="periodic")
    whole = build(fld)
    tile = fld.tiles(2)[1]
    part = build(fld, tile=tile)
    assert part.cell == fld.cell and part.mesh.n_faces == whole.mesh.n_faces
    measured = part.plants.loc[part.plants["plant_id"].isin(tile.measured)]
    assert len(measured) == 2 and part.segments["measured"].sum() < len(part.segments)


def test_periodic_tiles_of_a_count_rounded_up_to_a_square_carry_the_whole_cell():
    """n_plants = 7 grows a 3 × 3 cell (the next larger square): every tile's geometry is all 9 plants,
    whatever the tiling (a mutation audit: the cell's plants counted to n_plants, not N², survived on
    the square counts the tests used; the last two plants were then missing from other tiles' cells,
    a hole repeated through the periodic field)."""
    fld = Field(n_plants=7, boundary="periodic")
    every = np.sort(fld.plants().index.to_numpy())
    assert len(every) == 9
    for n_tiles in (1, 2, 3, 4):
        tiles = fld.tiles(n_tiles)
        np.testing.assert_array_equal(np.sort(np.concatenate([t.measured for t in tiles])), every)
        for t in tiles:
            np.testing.assert_array_equal(t.plant_ids, every)


# -- Beer–Lambert -------------------------------------------------------------------------------
@pytest.fixture(scope="module", params=["spherical", "horizontal"])
def random_canopy(request):
    cell = PeriodicCell(0.5, 0.5, row_direction_deg=90.0)
    lai = 0.5 if request.param == "spherical" else 0.8
    mesh, _ = canopy(cell, lai, request.param, np.random.default_rng(11))
    return request.param, lai, cell, mesh


def gap_fraction(fs, mesh, el):
    """Mean direct-sun visibility of the soil sensors and its standard error (sensor spread)."""
    fs.set_sun(el, 150)
    r = SegmentEstimator(fs, sensor_ids(mesh), samples=4, bounces=0, seed=1).render()
    v = r.front("incident_sun") / math.sin(math.radians(el))
    return v.mean(), v.std(ddof=1) / math.sqrt(len(v)), r


def test_beer_lambert_gap_fraction_in_a_periodic_cell(random_canopy):
    """exp(−G·LAI/sin β) at 10–90° in a 0.5 m cell; shadows are up to 5.7 m long (11 cells)."""
    angles, lai, cell, mesh = random_canopy
    fs = FieldScene(mesh, BLACK, cell=cell)
    for el in (10.0, 30.0, 60.0, 90.0):
        gap, se, r = gap_fraction(fs, mesh, el)
        s = math.sin(math.radians(el))
        expected = math.exp(-(s if angles == "horizontal" else 0.5) * lai / s)
        # Binomial spread over 2 500 sensors ≈ 0.008; 4 SE plus 0.01 for the one random canopy
        # and its finite 1 cm leaves.
        assert gap == pytest.approx(expected, abs=4 * se + 0.01), (angles, el, gap, expected, se)
        assert r.meta["periodic"]["sun"]["capped"] == 0


def test_beer_lambert_fails_in_the_finite_cell_at_low_sun(random_canopy):
    angles, lai, cell, mesh = random_canopy
    gap, _, r = gap_fraction(FieldScene(mesh, BLACK), mesh, 10.0)
    expected = math.exp(-(1.0 if angles == "horizontal" else 0.5 / math.sin(math.radians(10))) * lai)
    assert "periodic" not in r.meta
    assert gap > expected + 0.3  # light leaks in under the edges of the 0.5 m patch


# -- overhangs ----------------------------------------------------------------------------------
def test_overhanging_leaf_shades_the_opposite_side_and_is_sampled_once():
    cell = PeriodicCell(1.0, 1.0)
    leaf = square([0.5, 0.5, 0.5], [0, 0, 1], 0.4, 1)  # centred on the +x, +y corner
    where = {2: (-0.45, -0.45), 3: (0.45, 0.45), 4: (-0.45, 0.45), 5: (0.45, -0.45), 6: (0.0, 0.0)}
    sensors = [square([x, y, 0.001], [0, 0, 1], 0.01, k) for k, (x, y) in where.items()]
    mesh = Mesh.concatenate([leaf, *sensors])
    fs = FieldScene(mesh, BLACK, cell=cell)
    fs.set_sun(90.0, 0.0)
    r = SegmentEstimator(fs, [1, 2, 3, 4, 5, 6], samples=64, bounces=1, seed=0).render()
    lit = r.front("incident_sun")
    assert lit[1:5] == pytest.approx(0.0, abs=1e-6)  # every corner lies under an image of the leaf
    assert lit[5] == pytest.approx(1.0, abs=1e-6)
    assert r.meta["area_m2"][0] == pytest.approx(0.16)  # sampled on the original faces only
    # Its points (¾ of them outside the cell) see the open sky above and black soil below.
    assert r.front("incident_sun")[0] == pytest.approx(1.0, abs=1e-6)
    assert r.front("incident_sky")[0] == pytest.approx(1.0, abs=1e-6)
    finite = SegmentEstimator(FieldScene(mesh, BLACK), [2, 3, 4, 5], samples=64, bounces=1, seed=0).render()
    assert finite.front("incident_sun") == pytest.approx([1.0, 0.0, 1.0, 1.0], abs=1e-6)


# -- energy closure -----------------------------------------------------------------------------
def test_energy_closure_of_downward_transport_through_a_periodic_canopy():
    """Arriving = absorbed by leaves + arriving at the soil, for sun and sky.

    Horizontal leaves that only transmit (specular 0, subsurface 1, albedo 0.5) over black soil:
    light only moves down, so nothing escapes upwards and the budget closes with what reaches
    the soil, measured by a uniform grid of small sensors 1 mm above it. Any light lost or
    gained through the cell's sides (by the first rays, shadow rays or transmitted path
    segments) breaks the closure; the finite version of the cell must break it.
    """
    cell = PeriodicCell(0.4, 0.6, row_direction_deg=110.0)
    mesh, _ = canopy(cell, 1.0, "horizontal", np.random.default_rng(5), z=(0.05, 0.6), sensors=40)
    optics = Optics(specular=0.0, roughness=0.5, subsurface=1.0, base_color=0.5, soil_albedo=0.0)
    leaves, sensors = leaf_ids(mesh), sensor_ids(mesh)

    def budget(fs, el):
        fs.set_sun(el, 200.0)
        ids = np.concatenate([leaves, sensors])
        r = SegmentEstimator(fs, ids, samples=16, bounces=6, seed=3).render()
        is_leaf = np.isin(r.segment_id, leaves)
        area = r.meta["area_m2"][is_leaf]
        out = {}
        for part, arriving in (("sun", math.sin(math.radians(el))), ("sky", 1.0)):
            canopy_abs = (area * getattr(r, f"absorbed_{part}")[is_leaf]).sum() / cell.area_m2
            soil = r.front(f"incident_{part}")[~is_leaf]
            se = math.hypot(
                math.sqrt(((area * r.se[f"absorbed_{part}"][is_leaf]) ** 2).sum()) / cell.area_m2,
                soil.std(ddof=1) / math.sqrt(len(soil)),
            )
            out[part] = ((canopy_abs + soil.mean()) / arriving, se / arriving)
        return out

    periodic = budget(FieldScene(mesh, optics, cell=cell), 20.0)
    for part, (ratio, se) in periodic.items():
        # 6 transmissions leave ≤ 0.5⁷ ≈ 0.8 % of the light that met 7 leaves (almost none
        # does at LAI 1); the crossing cap truncates ≤ 0.1 %.
        assert ratio == pytest.approx(1.0, abs=4 * se + 0.01), (part, ratio, se)
    finite = budget(FieldScene(mesh, optics), 20.0)
    assert abs(finite["sun"][0] - 1.0) > 0.2  # the sun enters through the patch's sides


# -- translation invariance ---------------------------------------------------------------------
def test_shifting_every_face_by_a_fraction_of_the_cell_changes_nothing():
    cell = PeriodicCell(0.3, 0.45, row_direction_deg=30.0)  # rows not along an axis
    mesh, _ = canopy(cell, 2.0, "spherical", np.random.default_rng(7), leaf=0.02, z=(0.05, 0.5), sensors=2)
    ids = leaf_ids(mesh)
    shift = cell.lattice_shift(0.37, 0.61)
    moved = mesh.vertices.copy()
    moved[:, :2] += shift
    # Wrap every face (by its centroid) back into the cell: leaves straddle the seams now.
    tri = moved[mesh.faces]
    centroid = tri.mean(1)
    tri[..., :2] += (cell.wrap(centroid) - centroid)[:, None, :2]
    wrapped = Mesh(
        tri.reshape(-1, 3), np.arange(3 * mesh.n_faces).reshape(-1, 3), mesh.face_segment, mesh.face_is_blade
    )
    totals = []
    for m in (mesh, wrapped):
        fs = FieldScene(m, Optics.preset("paper"), cell=cell)
        fs.set_sun(25.0, 230.0)
        r = SegmentEstimator(fs, ids, samples=16, bounces=2, seed=9).render()
        area = r.meta["area_m2"]
        totals.append({p: ((area * getattr(r, p)).sum(), math.sqrt(((area * r.se[p]) ** 2).sum())) for p in PARTS})
    for p in PARTS:
        (a, se), (b, _) = totals[0][p], totals[1][p]
        # The same infinite field, sampled at the same points: equal up to float32 round-off
        # (measured: 1e-8 relative), far inside the Monte Carlo error (≈ 1 %).
        assert abs(a - b) <= min(se, 1e-4 * abs(a)), (p, a, b, se)


# -- gradients ----------------------------------------------------------------------------------
def test_gradient_matches_finite_differences_with_common_random_numbers():
    """The reverse pass against central differences of the same frozen-sampling render (common random
    numbers), per seed: subsurface (step 0.1; the render is linear in it) and specular (step 0.01: the
    absorptance's albedo term F0·E + (1 − F0)·c carries its derivative)."""
    cell = PeriodicCell(0.3, 0.3, row_direction_deg=90.0)
    mesh, _ = canopy(cell, 1.5, "spherical", np.random.default_rng(3), leaf=0.03, z=(0.05, 0.5), sensors=2)
    ids = leaf_ids(mesh)
    paper = Optics.preset("paper")
    fs = FieldScene(mesh, paper, cell=cell)
    fs.set_sun(20.0, 160.0)
    ct = {"absorbed_sun": np.ones(len(ids)), "absorbed_sky": np.full(len(ids), 0.3)}

    def J(r):
        return sum(np.sum(ct[p] * getattr(r, p)) for p in ct)

    steps = {"subsurface": 0.1, "specular": 0.01}
    G, F = {k: [] for k in steps}, {k: [] for k in steps}
    for seed in range(4):
        est = SegmentEstimator(fs, ids, samples=16, bounces=2, seed=seed)
        g = est.vjp(ct)
        for k, h in steps.items():
            x = getattr(paper, k)
            G[k].append(g[k])
            fs.set_optics(**{k: x + h})
            jp = J(est.render())
            fs.set_optics(**{k: x - h})
            jm = J(est.render())
            fs.set_optics(**{k: x})
            F[k].append((jp - jm) / (2 * h))
    # Frozen sampling: AD and CRN differences estimate the same smooth function (see
    # tests/test_light_irradiance.py). Measured: ≤ 2.2e-6 relative (subsurface) and ≤ 2.2e-5
    # (specular: float32 round-off in the difference) per seed; the test allowed 3 % of the largest
    # before, for subsurface alone. Tolerances ≈ 10× the measured.
    for k, rtol in (("subsurface", 2e-5), ("specular", 2e-4)):
        G[k], F[k] = np.array(G[k]), np.array(F[k])
        assert (np.abs(F[k]) > 0.1).all(), (k, F[k])  # a derivative to check at every seed
        np.testing.assert_allclose(G[k], F[k], rtol=rtol, err_msg=k)


@pytest.mark.parametrize("periodic", [True, False], ids=["periodic", "finite"])
def test_paths_kept_across_suns_give_a_fresh_estimators_values(periodic):
    """A render reuses the geometry of the last one's paths (it depends on neither the sun nor the
    leaf parameters); the values must be bitwise those of a fresh estimator, for a new sun and for
    new leaf parameters (whose throughputs must be weighed anew: stale weights would keep the old
    absorbed light)."""
    cell = PeriodicCell(0.3, 0.3, row_direction_deg=70.0)
    mesh, _ = canopy(cell, 1.5, "spherical", np.random.default_rng(5), leaf=0.03, z=(0.05, 0.5), sensors=4)
    ids = np.unique(mesh.face_segment)
    fs = FieldScene(mesh, Optics.preset("paper"), cell=cell if periodic else None)

    def values(r):
        return np.stack([getattr(r, p) for p in PARTS])

    est = SegmentEstimator(fs, ids, samples=8, bounces=2, seed=1)
    for el, az, leaf in ((30.0, 150.0, {}), (-5.0, 80.0, {}), (60.0, 200.0, {}), (60.0, 200.0, {"subsurface": 0.6})):
        fs.set_optics(**leaf)
        fs.set_sun(el, az)
        kept = est.render()
        fresh = SegmentEstimator(fs, ids, samples=8, bounces=2, seed=1).render()
        np.testing.assert_array_equal(values(kept), values(fresh))
        if periodic:
            assert kept.meta["periodic"] == fresh.meta["periodic"]  # ray counts include the kept paths'
    # The paths' geometry depends on the frozen sampling only: kept across suns and leaf parameters.
    assert est._kept is not None and est._kept[0] == fs.bsdf.sampling


# -- crossing cap -------------------------------------------------------------------------------
@pytest.mark.parametrize("tol", [1e-2, 1e-3])
def test_crossing_cap_leaves_at_most_tau_of_a_cosine_lobe_uncounted(tol):
    """The geometry the cap stands for, sampled: rays from a cosine lobe about a vertical surface
    (the worst case) at the canopy top that would need more than C crossings of a 0.5 × 0.3 m
    cell's sides before leaving the 1 m layer (horizontal travel z / tan|e|, crossings ≤ |Δx|/A +
    |Δy|/B + 2). Their share is ≤ τ for every facing, and ≥ 0.5 τ for the worst: the cap is not
    wastefully long (2·10⁶ directions, SE ≤ 3 % of τ)."""
    cell = PeriodicCell(0.5, 0.3)
    a, b = cell.size_m
    cap = crossing_cap(cell, 1.0, tol)
    rng = np.random.default_rng(0)
    u1, u2 = rng.random(2_000_000), rng.random(2_000_000)
    lx, ly, lz = np.sqrt(u1) * np.cos(2 * np.pi * u2), np.sqrt(u1) * np.sin(2 * np.pi * u2), np.sqrt(1 - u1)
    shares = []
    for psi in np.radians([0.0, 30.0, 70.0, 90.0]):
        n = np.array([np.cos(psi), np.sin(psi), 0.0])  # a vertical surface's normal
        t1, t2 = np.array([0.0, 0.0, 1.0]), np.cross(n, [0.0, 0.0, 1.0])
        w = lx[:, None] * t1 + ly[:, None] * t2 + lz[:, None] * n
        with np.errstate(divide="ignore"):
            travel = 1.0 / np.abs(w[:, 2])  # horizontal distance per unit horizontal direction
        need = travel * (np.abs(w[:, 0]) / a + np.abs(w[:, 1]) / b) + 2
        shares.append(float(np.mean(need > cap)))
    assert max(shares) <= tol and max(shares) >= 0.5 * tol, shares


def test_crossing_cap_bounds_truncation_and_is_reported():
    cell = PeriodicCell(0.5, 0.5)
    assert crossing_cap(cell, 1.0, 1e-2) < crossing_cap(cell, 1.0, 1e-3)
    with pytest.raises(InputError, match="crossing"):
        crossing_cap(cell, 1.0, 0.0)
    mesh, _ = canopy(cell, 0.2, "spherical", np.random.default_rng(2), sensors=10)
    ids = leaf_ids(mesh)[:50]
    share = {}
    for tol in (0.9, 1e-3):
        fs = FieldScene(mesh, Optics.preset("paper"), cell=cell, crossing_tolerance=tol)
        fs.set_sun(5.0, 100.0)
        r = SegmentEstimator(fs, ids, samples=16, bounces=2, seed=0).render()
        meta = r.meta["periodic"]
        assert meta["sun"]["capped"] == 0 and meta["nee"]["capped"] == 0  # sun rays: exact cap
        assert meta["sun_crossing_cap"] >= 1 / math.tan(math.radians(5)) / 0.5 * (1 - 1e-9)
        share[tol] = meta["capped_share"]
        assert 0 <= share[tol] <= 1 and meta["path"]["rays"] > 0
    # A loose tolerance caps rays (they count as dark); the default one caps far fewer, and
    # within its bound τ of the weight.
    assert share[0.9] > share[1e-3] and share[1e-3] <= 1e-3


# -- real plants --------------------------------------------------------------------------------
@pytest.mark.parametrize("plants_per_row", [None, 4], ids=["2x2", "1x4"])
def test_periodic_cell_of_real_plants_is_sheltered_by_its_copies(plants_per_row):
    """The same plants as one periodic cell and alone on bare soil: a 2 × 2 square and one row of 4
    (``plants_per_row``, a cell 4 plant spacings long by one row spacing wide)."""
    fld = Field(n_plants=4, seed=1, boundary="periodic", plants_per_row=plants_per_row)
    g = build(fld)
    assert g.cell == fld.cell and g.segments["measured"].all()
    ids = g.segments["segment_id"].to_numpy()
    fs_p = FieldScene(g.mesh, Optics.preset("paper"), cell=g.cell)
    fs_f = FieldScene(g.mesh, Optics.preset("paper"))  # the same plants alone on bare soil
    totals = []
    for fs in (fs_p, fs_f):
        fs.set_sun(30.0, 150.0)
        r = SegmentEstimator(fs, ids, samples=16, bounces=2, seed=0).render()
        for p in PARTS:
            assert np.isfinite(getattr(r, p)).all() and (getattr(r, p) >= 0).all()
        totals.append(r.total("absorbed", 1.0, 0.3) @ r.meta["area_m2"])
    # An endless canopy shades itself: much less light per plant than an isolated block of 4.
    assert totals[0] < 0.8 * totals[1]
    # A scene of the geometry itself takes its cell: the periodic render, bitwise.
    fs_g = FieldScene(g, Optics.preset("paper"))
    assert fs_g.cell == g.cell and fs_g.mesh is g.mesh
    fs_g.set_sun(30.0, 150.0)
    r = SegmentEstimator(fs_g, ids, samples=16, bounces=2, seed=0).render()
    assert r.total("absorbed", 1.0, 0.3) @ r.meta["area_m2"] == totals[0]


def test_coupled_model_renders_a_periodic_field_periodically(monkeypatch):
    from lightfit import replication as rep
    from lightfit.model import coupled
    from lightfit.model.parameters import Theta
    from lightfit.model.scenario import Scenario

    scenes = []

    def spy(*args, **kw):
        scenes.append(FieldScene(*args, **kw))
        return scenes[-1]

    monkeypatch.setattr(coupled, "FieldScene", spy)
    fld = Field(n_plants=4, seed=1, boundary="periodic")
    sc = Scenario(weather=rep.forcing().iloc[[14]], field=fld, samples=8, bounces=1)
    model = coupled.CoupledModel(sc)
    assert model.ground_area_m2 == pytest.approx(fld.cell.area_m2)
    vals, _ = model.render(Theta())
    assert scenes[0].cell == fld.cell and scenes[0].tracer is not None
    assert np.isfinite(np.asarray(vals)).all() and (np.asarray(vals) >= 0).all()


# -- the ray walk, ray by ray -------------------------------------------------------------------
def _walk_lanes(tracer, o, d, **kw):
    """``tracer.intersect`` of rays from numpy origins/directions (N, 3): status arrays and points."""
    mi = tracer.mi
    o = mi.Point3f(*(np.ascontiguousarray(o[:, c], dtype=np.float32) for c in range(3)))
    d = mi.Vector3f(*(np.ascontiguousarray(d[:, c], dtype=np.float32) for c in range(3)))
    hit_leaf, si, hit_soil, p_soil, escaped, capped, k = tracer.intersect(o, d, mi.Bool(True), **kw)
    as_np = lambda v: np.stack([np.asarray(v.x), np.asarray(v.y), np.asarray(v.z)], -1)  # noqa: E731
    prim = np.asarray(si.prim_index)
    return dict(
        leaf=np.asarray(hit_leaf),
        soil=np.asarray(hit_soil),
        sky=np.asarray(escaped),
        capped=np.asarray(capped),
        k=np.asarray(k),
        p=as_np(si.p),
        p_soil=as_np(p_soil),
        prim=prim,
    )


def _ray(phi_deg, elevation_deg):
    """Unit direction of horizontal compass angle ``phi`` (counter-clockwise from +x) and ``elevation``."""
    p, e = math.radians(phi_deg), math.radians(elevation_deg)
    return np.array([math.cos(p) * math.cos(e), math.sin(p) * math.cos(e), math.sin(e)])


def test_walk_counts_the_side_faces_a_ray_crosses_before_it_leaves_above_the_canopy():
    """Rays going up from mid-height in a 1 × 0.5 m cell whose canopy top is 1 m: a ray whose horizontal
    run to the top is L crosses the faces at 0.5, 1.5, 2.5 … m (x) or 0.25, 0.75, … m (y), then leaves to
    the sky; with a cap of C crossings, a ray needing more is stopped after the C-th, as capped."""
    cell = PeriodicCell(1.0, 0.5)  # rows east–west: a along x, b along y
    top = square([0.3, 0.2, 1.0], [0, 0, 1], 0.02, 1)  # the canopy top, off every ray's line (y = 0 or x = 0)
    tracer = FieldScene(top, BLACK, cell=cell).tracer
    # (azimuth of the ray, its horizontal run L to z = 1 from z = 0.5, faces crossed)
    lanes = [(0.0, 0.3, 0), (0.0, 1.2, 1), (0.0, 3.2, 3), (180.0, 3.2, 3), (90.0, 1.3, 3), (270.0, 0.6, 1)]
    d = np.array([_ray(phi, math.degrees(math.atan2(0.5, run))) for phi, run, _ in lanes])
    o = np.tile([0.0, 0.0, 0.5], (len(lanes), 1))
    crossings = np.array([n for *_, n in lanes])
    r = _walk_lanes(tracer, o, d)
    assert r["sky"].all() and not (r["leaf"] | r["soil"] | r["capped"]).any()
    np.testing.assert_array_equal(r["k"], crossings)
    r = _walk_lanes(tracer, o, d, cap=2)
    np.testing.assert_array_equal(r["capped"], crossings > 2)
    np.testing.assert_array_equal(r["sky"], crossings <= 2)
    np.testing.assert_array_equal(r["k"], np.minimum(crossings, 2))


def test_walk_finds_leaves_and_soil_through_the_sides_of_a_rotated_cell():
    """In a rotated, off-centre cell, a ray from anywhere meets the leaf of the infinite field that lies
    on its line: the hand-traced point o + t·d wrapped into the cell (numpy), after crossing as many side
    faces as whole periods separate them; rays going down (also from above the canopy top) reach the soil
    plane at its wrapped point. The same ray started a lattice vector away finds the same."""
    cell = PeriodicCell(0.4, 0.3, row_direction_deg=30.0, center_xy=(0.1, -0.2))
    rng = np.random.default_rng(12)
    # Leaves: one per upward ray, at its own height, centred where that ray reaches the height.
    up = [(20.0, 25.0, 0.6), (110.0, 30.0, 0.7), (200.0, 20.0, 0.8), (290.0, 35.0, 0.9)]
    o_up = np.column_stack([cell.to_world(rng.uniform(-0.4, 0.4, (len(up), 2)) * cell.size_m), np.full(len(up), 0.1)])
    d_up = np.array([_ray(phi, e) for phi, e, _ in up])
    z_leaf = np.array([z for *_, z in up])
    at_leaf = o_up + d_up * ((z_leaf - 0.1) / d_up[:, 2])[:, None]
    leaves = [square(c, [0, 0, 1], 0.03, k + 1) for k, c in enumerate(cell.wrap(at_leaf))]
    fs = FieldScene(Mesh.concatenate(leaves), BLACK, cell=cell)
    # Soil: rays going down from below the leaves, and one from above the canopy top (0.9 m).
    down = [(45.0, -20.0, 0.3), (160.0, -35.0, 0.5), (300.0, -60.0, 1.4)]
    o_down = np.column_stack([cell.to_world(rng.uniform(-0.4, 0.4, (3, 2)) * cell.size_m), [z for *_, z in down]])
    d_down = np.array([_ray(phi, e) for phi, e, _ in down])
    at_soil = o_down + d_down * (-o_down[:, 2] / d_down[:, 2])[:, None]
    o, d = np.concatenate([o_up, o_down]), np.concatenate([d_up, d_down])
    end = np.concatenate([at_leaf, at_soil])
    lattice = np.rint((cell.to_local(end) - cell.to_local(cell.wrap(end))) / cell.size_m)
    faces = np.abs(lattice).sum(1)  # side faces between the (inside) origin and the end point
    assert faces.min() >= 1 and faces[:4].max() >= 4  # every ray wraps; some several times
    far = o.copy()
    far[:, :2] += cell.lattice_shift(3, -2)  # the same rays of the infinite field, from another cell
    for origin in (o, far):
        r = _walk_lanes(fs.tracer, origin, d)
        assert r["leaf"][:4].all() and r["soil"][4:].all() and not (r["sky"] | r["capped"]).any()
        np.testing.assert_array_equal(fs.scene_mesh.face_segment[r["prim"][:4]], [1, 2, 3, 4])
        np.testing.assert_allclose(r["p"][:4], cell.wrap(at_leaf), atol=2e-5)
        np.testing.assert_allclose(r["p_soil"][4:], cell.wrap(at_soil), atol=2e-5)
        np.testing.assert_array_equal(r["k"], faces)


def test_walk_through_a_corner_shifts_both_axes_at_once():
    """A ray through the corner of a square cell re-enters through the diagonally opposite corner, in one
    crossing, and meets the leaf at the wrapped point of its line."""
    cell = PeriodicCell(0.5, 0.5, row_direction_deg=0.0)  # axes exactly ±x, ±y
    d = np.array([1.0, 1.0, 0.5]) / 1.5  # through (0.25, 0.25) from the centre, exactly diagonal
    leaf_at = np.array([0.35, 0.35, 0.2 + 0.35 * 0.5])  # where the ray is 0.1 m past the corner, each way
    fs = FieldScene(square(cell.wrap(leaf_at[None])[0], [0, 0, 1], 0.04, 1), BLACK, cell=cell)
    r = _walk_lanes(fs.tracer, np.array([[0.0, 0.0, 0.2]]), d[None])
    assert r["leaf"][0] and r["k"][0] == 1
    np.testing.assert_allclose(r["p"][0], [-0.15, -0.15, leaf_at[2]], atol=1e-5)


def _lattice_shifts(cell, img, original, seg_id):
    """The lattice vectors (i, j) by which the images of segment ``seg_id`` sit from its original
    (both faces of a square share their first vertex)."""
    v0 = original.vertices[original.faces[original.face_segment == seg_id][0, 0]]
    got = img.vertices[img.faces[img.face_segment == seg_id][:, 0]]
    k = (cell.to_local(got) - cell.to_local(v0)) / cell.size_m
    assert np.allclose(k, np.round(k), atol=1e-9)
    return sorted({(int(i), int(j)) for i, j in np.round(k)})


def test_faces_within_the_margin_outside_the_cell_keep_their_own_image_on_every_side():
    """Squares just outside the 1 m × 2 m cell: 0.5 µm outside (within IMAGE_MARGIN_M = 1 µm) they
    are kept where they are and shifted back in over that side; 2 µm outside only the shifted copy
    reaches the cell. Expected lattice vectors by hand, on each of the four sides."""
    cell = PeriodicCell(1.0, 2.0, row_direction_deg=90.0)  # along = x (A = 1 m), across = y (B = 2 m)
    h, near, far = 0.05, 5e-7, 2e-6  # half side of a 10 cm square, gaps outside the cell
    cases = {  # segment id: (centre x, centre y), expected (i, j)
        1: ((0.5 + near + h, 0.0), [(-1, 0), (0, 0)]),
        2: ((-0.5 - near - h, 0.0), [(0, 0), (1, 0)]),
        3: ((0.0, 1.0 + near + h), [(0, -1), (0, 0)]),
        4: ((0.0, -1.0 - near - h), [(0, 0), (0, 1)]),
        5: ((0.5 + far + h, 0.0), [(-1, 0)]),
        6: ((0.0, -1.0 - far - h), [(0, 1)]),
    }
    mesh = Mesh.concatenate([square([x, y, 0.3], [0, 0, 1], 2 * h, k) for k, ((x, y), _) in cases.items()])
    img = cell.images(mesh)
    for k, (_, expected) in cases.items():
        assert _lattice_shifts(cell, img, mesh, k) == expected, k


def test_every_image_keeps_its_faces_segment_id_and_blade_flag():
    """Faces of segments 9 (blade, inside), 3 (a prism face, over the +x side) and 7 (blade, over the
    +x, +y corner), given in that order at heights 0.1, 0.2, 0.3 m (a lattice shift never changes
    height): every image face carries the id and flag of the face at its height."""
    cell = PeriodicCell(1.0, 2.0, row_direction_deg=90.0)
    parts = [
        square([0.0, 0.0, 0.1], [0, 0, 1], 0.2, 9),
        square([0.5, 0.0, 0.2], [0, 0, 1], 0.2, 3),
        square([0.5, 1.0, 0.3], [0, 0, 1], 0.2, 7),
    ]
    parts[1] = Mesh(parts[1].vertices, parts[1].faces, parts[1].face_segment, np.array([False, False]))
    img = cell.images(Mesh.concatenate(parts))
    z = img.vertices[img.faces][:, :, 2]
    assert np.ptp(z, axis=1).max() == 0.0
    by_height = {0.1: (9, True), 0.2: (3, False), 0.3: (7, True)}
    got = [(int(s), bool(b)) for s, b in zip(img.face_segment, img.face_is_blade)]
    assert got == [by_height[round(float(h), 6)] for h in z[:, 0]]
    assert sorted(np.bincount(img.face_segment)[[9, 3, 7]]) == [2, 4, 8]  # 1, 2 and 4 images × 2 triangles
