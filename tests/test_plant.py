"""Plant structure (G1), mesh (G3), field layout, tiles, cache and exports."""

import logging
import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import trimesh

from lightfit.errors import InputError
from lightfit.plant import (
    Field,
    GrowthConfig,
    Mesh,
    MeshResolution,
    build,
    expected_area,
    export,
    grow_plant,
    load_or_grow,
    one_sided_area_m2,
    organ_class,
    plant_seed,
    shoot_mesh,
)
from lightfit.plant.cache import cache_key


@pytest.fixture(scope="module")
def plant_table():
    return grow_plant(GrowthConfig(), plant_seed(7, 3, 4), plant_id=11)


@pytest.fixture(scope="module")
def small_field(tmp_path_factory):
    fld = Field(boundary="finite", n_plants=9, buffer_rows=1, seed=3)
    return fld, build(fld, cache_dir=tmp_path_factory.mktemp("cache"))


def test_segment_table_contract(plant_table):
    t = plant_table
    assert set(t["organ_type"].unique()) == {"stem", "leaf"}  # roots dropped by default
    assert (t["plant_id"] == 11).all()
    assert (t["segment_id"] == 11 * 1_000_000 + t["segment_index"]).all()
    length = np.linalg.norm(t[["x1", "y1", "z1"]].to_numpy() - t[["x0", "y0", "z0"]].to_numpy(), axis=1)
    assert np.allclose(length, t["length_m"])
    leaf = t[t["organ_type"] == "leaf"]
    blade = leaf[leaf["blade_area_m2"] > 0]
    assert np.allclose(blade["blade_width_m"] * blade["length_m"], blade["blade_area_m2"], rtol=1e-12)
    # Wheat in late April: a plant some 0.3–0.8 m tall, blades 0.5–2 cm wide (CPlantBox file values).
    assert 0.3 < t[["z0", "z1"]].to_numpy().max() < 0.8
    assert 0.005 <= blade["blade_width_m"].max() <= 0.02
    assert (t["creation_time_d"].between(0, GrowthConfig().days + 1e-9)).all()
    b = t[["bx", "by", "bz"]].to_numpy()
    assert np.allclose(np.linalg.norm(b, axis=1), 1.0)


def test_creation_times_are_cplantbox_own_node_times_of_each_segment_end(plant_table):
    """creation_time_d of a segment is when its end node formed: CPlantBox's per-organ node time
    (``Organ.getNodeCT``, a second route to the times than the plant's ``nodeCTs`` the table reads),
    for every stem and leaf segment of the same plant grown again."""
    import plantbox as pb

    cfg = GrowthConfig()
    plant = pb.MappedPlant(int(plant_seed(7, 3, 4)))
    plant.readParameters(str(cfg.path))
    plant.initialize(False)
    plant.simulate(cfg.days, False)
    got = plant_table.set_index("segment_index")["creation_time_d"]
    seen = 0
    for organ_type in (3, 4):  # stems, leaves
        for organ in plant.getOrgans(organ_type):
            ids = list(organ.getNodeIds())
            for i in range(1, len(ids)):  # segment ids[i] - 1 ends at node ids[i]
                assert got[ids[i] - 1] == pytest.approx(organ.getNodeCT(i), abs=1e-12), (organ.getId(), i)
                seen += 1
    assert seen == len(plant_table)


def test_radii_and_branching_directions_are_cplantbox_own_organ_data(plant_table):
    """Each segment's radius is its organ's radius parameter (``Organ.getParameter("a")``, cm), and each
    organ's branching direction is the axis of its parent's segment ending at the branch node, found
    through the parent's own node list (or its first segment where the organ starts at the parent's
    first node): second routes to what the table reads from the plant's ``radii`` and segment order,
    for every stem and leaf of the same plant grown again. A mutation audit: radii halved, the leaf's
    own first segment as its branching direction, and the parent's first segment for every leaf all
    survived (the blade's width direction follows the branching direction)."""
    import plantbox as pb

    cfg = GrowthConfig()
    plant = pb.MappedPlant(int(plant_seed(7, 3, 4)))
    plant.readParameters(str(cfg.path))
    plant.initialize(False)
    plant.simulate(cfg.days, False)
    nodes = np.asarray(plant.getNodes(), dtype=float) * 0.01
    t = plant_table.set_index("segment_index")
    branched = 0
    for organ_type in (3, 4):  # stems, leaves
        for organ in plant.getOrgans(organ_type):
            ids = list(organ.getNodeIds())
            rows = t.loc[[i - 1 for i in ids[1:]]]  # segment i - 1 ends at node i
            np.testing.assert_allclose(rows["radius_m"], organ.getParameter("a") * 0.01, rtol=1e-12)
            parent = organ.getParent()
            if parent.organType() < 2:  # the main stem grows from the seed: vertical
                np.testing.assert_array_equal(rows[["bx", "by", "bz"]].to_numpy(), [[0.0, 0.0, 1.0]] * len(rows))
                continue
            pids = list(parent.getNodeIds())
            k = max(pids.index(ids[0]), 1)
            axis = nodes[pids[k]] - nodes[pids[k - 1]]
            np.testing.assert_allclose(
                rows[["bx", "by", "bz"]].to_numpy(), np.tile(axis / np.linalg.norm(axis), (len(rows), 1)), atol=1e-12
            )
            branched += 1
    assert branched >= 5


def test_roots_kept_available():
    full = grow_plant(GrowthConfig(include_roots=True), 5)
    shoot_only = grow_plant(GrowthConfig(), 5)
    assert (full["organ_type"] == "root").sum() > 1000
    sh = full[full["organ_type"] != "root"].reset_index(drop=True)
    cols = ["segment_index", "x0", "y0", "z0", "x1", "y1", "z1", "blade_area_m2"]
    assert np.array_equal(sh[cols].to_numpy(), shoot_only[cols].to_numpy())


def test_same_seed_same_plant_bit_for_bit_and_seeds_differ():
    g = GrowthConfig()
    a, b = grow_plant(g, 123), grow_plant(g, 123)
    assert a.equals(b)
    c = grow_plant(g, 124)
    assert not np.array_equal(a[["x1", "y1", "z1"]].to_numpy(), c[["x1", "y1", "z1"]].to_numpy())
    assert plant_seed(1, 2, 3) == plant_seed(1, 2, 3) != plant_seed(1, 3, 2)


@pytest.mark.parametrize("res", [MeshResolution(), MeshResolution(3, 2, 8), MeshResolution(1, 4, 3)])
def test_mesh_area_equals_segment_area(plant_table, res):
    m = shoot_mesh(plant_table, res)
    exp = expected_area(plant_table)
    got = m.area_per_segment().reindex(exp.index).fillna(0.0)
    # Stated tolerance: 1e-9 relative (planar blade rectangles; prisms with perimeter-matched radius).
    assert np.allclose(got, exp, rtol=1e-9, atol=1e-15)
    blade = (plant_table["organ_type"] == "leaf") & (plant_table["blade_width_m"] > 0)
    n_blade, n_tube = int(blade.sum()), int((~blade).sum())
    assert m.n_faces == n_blade * 2 * res.along * res.across + n_tube * 2 * res.along * res.around
    # trimesh, an independent geometry library, finds the same areas on the exported mesh
    tm = m.to_trimesh()
    per_segment = pd.Series(tm.area_faces).groupby(tm.face_attributes["segment_id"]).sum()
    assert np.allclose(per_segment.reindex(exp.index).fillna(0.0), exp, rtol=1e-9, atol=1e-15)


def test_organ_classes_split_each_leaf_into_its_basal_sheath_and_its_blade(plant_table):
    """Sheaths are exactly the leaf segments where CPlantBox gives no blade surface, and each leaf
    is its sheath (the basal zone) then its blade; the one-sided area is the blade's or 2πrL."""
    cls = organ_class(plant_table)
    assert cls.dtype.kind == "U"  # plain strings, which np.savez stores without pickle
    leaf = plant_table["organ_type"].astype(str).to_numpy() == "leaf"
    assert set(cls[leaf]) == {"blade", "sheath"} and set(cls[~leaf]) <= {"stem", "root", "other"}
    np.testing.assert_array_equal(cls[leaf] == "sheath", plant_table["blade_area_m2"].to_numpy()[leaf] == 0)
    for _, g in plant_table[leaf].groupby("organ_id"):
        blade = organ_class(g.sort_values("segment_index")) == "blade"
        assert blade.any() and np.all(np.diff(blade.astype(int)) >= 0)  # sheath first, then blade
    area = one_sided_area_m2(plant_table)
    t = plant_table
    np.testing.assert_array_equal(area[cls == "blade"], t["blade_area_m2"].to_numpy()[cls == "blade"])
    lateral = 2 * np.pi * t["radius_m"].to_numpy() * t["length_m"].to_numpy()
    np.testing.assert_array_equal(area[cls != "blade"], lateral[cls != "blade"])


def test_blade_perpendicular_to_branching_and_segment(plant_table):
    m = shoot_mesh(plant_table)
    seg = plant_table.set_index("segment_id")
    sel = m.face_is_blade
    n = m.normals()[sel]
    s = seg.loc[m.face_segment[sel]]
    t = (s[["x1", "y1", "z1"]].to_numpy() - s[["x0", "y0", "z0"]].to_numpy()) / s[["length_m"]].to_numpy()
    b = s[["bx", "by", "bz"]].to_numpy()
    w = np.cross(n, t)  # width direction recovered from the face
    assert np.abs(np.einsum("ij,ij->i", n, t)).max() < 1e-9  # blade contains the segment direction
    ok = np.linalg.norm(np.cross(t, b), axis=1) > 1e-6  # (where t is not parallel to b)
    assert np.abs(np.einsum("ij,ij->i", w[ok], b[ok])).max() < 1e-9
    assert (n[:, 2] >= -1e-12).all()  # upper side up
    # Prism faces face away from their segment's axis.
    tube = ~m.face_is_blade
    c = m.vertices[m.faces[tube]].mean(1)
    st = seg.loc[m.face_segment[tube]]
    a = st[["x0", "y0", "z0"]].to_numpy()
    ax = (st[["x1", "y1", "z1"]].to_numpy() - a) / st[["length_m"]].to_numpy()
    radial = (c - a) - np.einsum("ij,ij->i", c - a, ax)[:, None] * ax
    assert (np.einsum("ij,ij->i", m.normals()[tube], radial) > 0).all()


def test_stems_and_sheaths_seen_from_the_side_are_cylinders_from_every_azimuth(small_field):
    """Reference: a cylinder of radius r and length L seen along d has the projected area
    2rL·√(1 − (t·d)²), the same from every azimuth. Each prism has the cylinder's lateral area, but a
    hexagon's width depends on the azimuth (√3 R to 2R); with every organ's prisms turned alike the
    field's stems and sheaths showed −9.3 % to +4.7 % of the cylinders' area with a 60° period (a
    shared pattern in their direct sun). Each plant's turned by its own angle, they match the
    cylinders to 1 % at every azimuth (≤ 0.4 % measured on this field at 0.25° steps)."""
    _, g = small_field
    seg = g.segments.set_index("segment_id")
    tube = ~np.asarray(g.mesh.face_is_blade)
    v = g.mesh.vertices[g.mesh.faces[tube]]
    area_normals = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]) / 2
    st = seg.loc[np.unique(g.mesh.face_segment[tube])]
    t = st[["x1", "y1", "z1"]].to_numpy() - st[["x0", "y0", "z0"]].to_numpy()
    length = np.linalg.norm(t, axis=1)
    t /= length[:, None]
    for phi in np.radians(np.arange(0.0, 60.0, 7.5)):
        d = np.array([np.cos(phi), np.sin(phi), 0.0])
        prisms = 0.5 * np.abs(area_normals @ d).sum()  # a closed convex solid's shadow: half Σ|n·d|A
        cylinders = (2 * st["radius_m"].to_numpy() * length * np.sqrt(1 - (t @ d) ** 2)).sum()
        assert prisms == pytest.approx(cylinders, rel=0.01), np.degrees(phi)


def test_prism_turns_spread_over_one_sector():
    """prism_turn depends on the plant id alone and spreads the plants over [0, 2π/n): a prism
    repeats itself every 2π/n, so that sector is every orientation (the ids of a 26 × 26 field with
    its buffer rows)."""
    from lightfit.plant.field import plant_id
    from lightfit.plant.mesh import prism_turn

    rows, cols = np.meshgrid(np.arange(-2, 24), np.arange(-2, 24))
    plants = plant_id(rows.ravel(), cols.ravel())
    turn = prism_turn(plants, 6)
    assert ((turn >= 0) & (turn < np.pi / 3)).all()
    counts, _ = np.histogram(turn, bins=12, range=(0, np.pi / 3))
    assert counts.min() >= 0.8 * counts.mean() and counts.max() <= 1.2 * counts.mean(), counts


def test_hand_built_leaf_lies_flat():
    # A leaf leaving a vertical stem horizontally along +x: blade horizontal, normal +z, area w·L.
    t = pd.DataFrame(
        {
            "plant_id": [0, 0],
            "segment_index": [0, 1],
            "segment_id": [0, 1],
            "organ_type": pd.Categorical(["stem", "leaf"], categories=["root", "stem", "leaf", "other"]),
            "organ_id": [1, 2],
            "x0": [0.0, 0.0],
            "y0": [0.0, 0.0],
            "z0": [0.0, 0.1],
            "x1": [0.0, 0.2],
            "y1": [0.0, 0.0],
            "z1": [0.1, 0.1],
            "length_m": [0.1, 0.2],
            "radius_m": [0.002, 0.0003],
            "blade_width_m": [0.0, 0.01],
            "blade_area_m2": [0.0, 0.002],
            "creation_time_d": [1.0, 2.0],
            "bx": [0, 0.0],
            "by": [0, 0.0],
            "bz": [1, 1.0],
        }
    )
    m = shoot_mesh(t, MeshResolution(around=64))
    leaf = m.face_segment == 1
    assert np.allclose(m.normals()[leaf], [0, 0, 1])
    assert m.face_areas()[leaf].sum() == pytest.approx(0.2 * 0.01, rel=1e-12)
    assert m.face_areas()[~leaf].sum() == pytest.approx(2 * np.pi * 0.002 * 0.1, rel=1e-12)
    # Leaf spans y ∈ [-w/2, w/2]
    v = m.vertices[np.unique(m.faces[leaf])]
    assert v[:, 1].min() == pytest.approx(-0.005) and v[:, 1].max() == pytest.approx(0.005)


def test_field_grid_and_ids():
    fld = Field(
        boundary="finite", n_plants=10, buffer_rows=2, row_spacing_m=0.2, plant_spacing_m=0.05, row_direction_deg=90
    )
    assert fld.n_rows == fld.n_along == 4 and fld.m == fld.m_along == 8  # next larger square
    p = fld.plants()
    assert len(p) == 64 and p["measured"].sum() == 16
    assert p["plant_id"].is_unique and p["seed"].is_unique
    # Rows run east–west: neighbours in a row differ in x by the plant spacing, rows in y by the row spacing.
    at = p.set_index(["row", "col"])
    a, b, c = at.loc[(0, 0)], at.loc[(0, 1)], at.loc[(1, 0)]
    assert b.x_m - a.x_m == pytest.approx(0.05) and b.y_m == pytest.approx(a.y_m)
    assert c.y_m - a.y_m == pytest.approx(0.2)
    meas = p[p["measured"]]
    assert meas["r"].min() == 0 and meas["r"].max() == fld.n_rows - 1
    assert meas["x_m"].mean() == pytest.approx(0.0, abs=1e-12) and meas["y_m"].mean() == pytest.approx(0.0, abs=1e-12)
    # The plant at (r, c) is named and seeded as the field module says, by hand: id (r + 1000)·10⁴ +
    # (c + 1000), seed plant_seed(seed, r + 1000, c + 1000) (a mutation audit: seeds drawn with r and c
    # swapped survived; every plant then stood where its transpose should, another layout of the
    # same seed than the one results files and caches were made with).
    for q in p.itertuples():
        assert q.plant_id == (q.r + 1000) * 10_000 + (q.c + 1000)
        assert q.seed == plant_seed(fld.seed, q.r + 1000, q.c + 1000)


@pytest.mark.parametrize("n_tiles", [1, 2, 3, 4, 6])
def test_tiles_partition_and_buffer_neighbourhood(n_tiles):
    fld = Field(boundary="finite", n_plants=36, buffer_rows=2)
    plants = fld.plants()
    tiles = fld.tiles(n_tiles)
    assert len(tiles) == n_tiles
    measured = np.concatenate([t.measured for t in tiles])
    assert sorted(measured) == sorted(plants.index[plants["measured"]])  # each measured plant in exactly one tile
    for t in tiles:
        own = plants.loc[t.measured]
        # Independent brute force: every grid plant within Chebyshev distance ≤ B of the block.
        r0, r1, c0, c1 = own["row"].min(), own["row"].max(), own["col"].min(), own["col"].max()
        near = plants[(plants["row"].between(r0 - 2, r1 + 2)) & (plants["col"].between(c0 - 2, c1 + 2))]
        assert sorted(near.index) == sorted(t.plant_ids)
        assert len(own) == (r1 - r0 + 1) * (c1 - c0 + 1)  # contiguous block


def test_measured_plants_do_not_depend_on_buffer_rows():
    a = Field(boundary="finite", n_plants=9, buffer_rows=0, seed=4).plants()
    b = Field(boundary="finite", n_plants=9, buffer_rows=3, seed=4).plants()
    cols = ["plant_id", "seed", "x_m", "y_m"]
    assert a[cols].equals(b.loc[b["measured"], cols])


def test_buffer_along_rows_widens_only_the_row_ends():
    sq = Field(boundary="finite", n_plants=9, buffer_rows=1, seed=4)
    wide = Field(boundary="finite", n_plants=9, buffer_rows=1, buffer_along=4, seed=4)
    p = wide.plants()
    assert len(p) == (3 + 2) * (3 + 8) and p["measured"].sum() == 9
    assert p["r"].min() == -1 and p["c"].min() == -4 and p["c"].max() == 3 + 3
    cols = ["plant_id", "seed", "x_m", "y_m"]
    assert sq.plants().loc[sq.plants()["measured"], cols].equals(p.loc[p["measured"], cols])
    # Rows run east-west (x): the extra buffer lies along x, 4 plants × 3 cm beyond the measured plants.
    meas = p[p["measured"]]
    assert p["x_m"].max() - meas["x_m"].max() == pytest.approx(4 * 0.03)
    assert p["y_m"].max() - meas["y_m"].max() == pytest.approx(1 * 0.125)
    # Each tile's plants are, by brute force, every plant within 1 row and 4 plants along of its block
    # (a mutation audit: tiles padded along the rows by buffer_rows, not buffer_along, survived; their
    # rows' ends then let in the edge light buffer_along is there to keep out).
    for n_tiles in (2, 3):
        for t in wide.tiles(n_tiles):
            own = p.loc[t.measured]
            near = p[
                p["r"].between(own["r"].min() - 1, own["r"].max() + 1)
                & p["c"].between(own["c"].min() - 4, own["c"].max() + 4)
            ]
            np.testing.assert_array_equal(t.plant_ids, np.sort(near.index))
    for t in wide.tiles(2):
        ring = p.loc[t.buffer]
        own = p.loc[t.measured]
        assert ring["c"].min() >= own["c"].min() - 4 and ring["r"].min() >= own["r"].min() - 1
        assert (
            (ring["c"] < own["c"].min())
            | (ring["c"] > own["c"].max())
            | (ring["r"] < own["r"].min())
            | (ring["r"] > own["r"].max())
        ).all()
    with pytest.raises(InputError, match="buffer_along"):
        Field(boundary="finite", buffer_along=-2)


def test_plant_is_identical_in_its_tile_and_as_a_neighbours_buffer(tmp_path):
    fld = Field(boundary="finite", n_plants=16, buffer_rows=1, seed=9)
    a, b = fld.tiles(2)
    shared = np.intersect1d(a.measured, b.buffer)
    assert len(shared) > 0
    ga = build(fld, tile=a, cache_dir=tmp_path / "A")
    gb = build(fld, tile=b, cache_dir=tmp_path / "B")  # separate caches: each grows its own copy
    pid = int(shared[0])
    sa = ga.segments[ga.segments.plant_id == pid].reset_index(drop=True)
    sb = gb.segments[gb.segments.plant_id == pid].reset_index(drop=True)
    assert sa["measured"].all() and not sb["measured"].any()
    assert sa.drop(columns="measured").equals(sb.drop(columns="measured"))


def test_build_whole_field(small_field):
    fld, g = small_field
    assert len(g.plants) == (3 + 2) ** 2
    assert g.segments["segment_id"].is_unique
    assert set(np.unique(g.mesh.face_segment)) <= set(g.segments["segment_id"])
    assert g.segments.loc[g.segments.measured, "plant_id"].nunique() == 9
    # Plants sit at their grid positions: each plant's stem base (its lowest stem point) is at its
    # (x, y). Measured: exactly (CPlantBox grows each plant at the origin; turning about the origin
    # keeps it there); 1 cm before, a third of the 3 cm spacing along the row, passed a plant 5 mm off.
    stem = g.segments[g.segments.organ_type == "stem"]
    base = stem.loc[stem.groupby("plant_id")["z0"].idxmin()].set_index("plant_id")[["x0", "y0"]]
    pos = g.plants.set_index("plant_id").loc[base.index, ["x_m", "y_m"]]
    assert len(base) == len(g.plants)
    np.testing.assert_allclose(base.to_numpy(), pos.to_numpy(), rtol=0, atol=1e-12)


def test_cache_hit_corrupt_and_stale_entries(tmp_path, caplog):
    g = GrowthConfig()
    a, hit = load_or_grow(g, 42, 1, directory=tmp_path)
    assert not hit
    b, hit = load_or_grow(g, 42, 1, directory=tmp_path)
    assert hit and a.equals(b)
    path = tmp_path / f"{cache_key(g, 42)}.npz"
    raw = bytearray(path.read_bytes())
    raw[len(raw) // 2] ^= 0xFF  # flip a byte in the middle
    path.write_bytes(bytes(raw))
    with caplog.at_level(logging.WARNING):
        c, hit = load_or_grow(g, 42, 1, directory=tmp_path)
    assert not hit and c.equals(a) and "corrupt or stale" in caplog.text
    path.write_bytes(b"")  # truncated write
    d, hit = load_or_grow(g, 42, 1, directory=tmp_path)
    assert not hit and d.equals(a)
    # A stale entry (another key's content under this name) is not used.
    other = tmp_path / f"{cache_key(g, 43)}.npz"
    load_or_grow(g, 43, 1, directory=tmp_path)
    path.write_bytes(other.read_bytes())
    e, hit = load_or_grow(g, 42, 1, directory=tmp_path)
    assert not hit and e.equals(a)
    # A different date is a different key.
    assert cache_key(GrowthConfig(target_date="2016-04-21"), 42) != cache_key(g, 42)


def read_legacy_vtk(path) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
    """Points, triangles and cell arrays of a legacy VTK polydata file, read as VTK's
    vtkDataReader does (the file-format spec, independent of lightfit's writer): BINARY data big-endian
    after the keyword's line, ASCII numbers as C++ ``>>`` reads them (no ``nan`` or ``inf``: VTK's
    reader stops there with "Error reading ascii data")."""
    data = Path(path).read_bytes()
    pos = 0

    def line():
        nonlocal pos
        end = data.index(b"\n", pos)
        text, pos = data[pos:end].decode("ascii"), end + 1
        return text

    def numbers(n, dtype):
        nonlocal pos
        if binary:
            size = np.dtype(dtype).itemsize * n
            out, pos = np.frombuffer(data, dtype, n, pos), pos + size
            return out
        words = []
        while len(words) < n:
            words += line().split()
        for w in words:
            if not re.fullmatch(r"[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?", w):
                raise ValueError(f"VTK's ASCII reader cannot read {w!r}")
        return np.array(words, dtype=float)

    assert line().startswith("# vtk DataFile Version")
    line()  # title
    binary = line() == "BINARY"
    assert line() == "DATASET POLYDATA"
    _, n, kind = line().split()
    assert kind == "double"
    points = numbers(3 * int(n), ">f8").reshape(-1, 3)
    arrays, tri = {}, None
    while pos < len(data):
        words = line().split()
        if not words:
            continue
        if words[0] == "POLYGONS":
            cells = numbers(int(words[2]), ">i4").astype(np.int64).reshape(-1, 4)
            assert (cells[:, 0] == 3).all()
            tri = cells[:, 1:]
        elif words[0] == "SCALARS":
            assert line() == "LOOKUP_TABLE default" and words[2] == "double"
            arrays[words[1]] = numbers(len(tri), ">f8")
    return points, tri, arrays


def test_exports_read_back_with_segment_ids(small_field, tmp_path):
    _, g = small_field
    m = g.mesh
    seg = g.segments.set_index("segment_id")
    values = {"measured": seg["measured"].astype(float), "blade_area_m2": seg["blade_area_m2"]}
    # PLY through trimesh, an independent reader.
    ply = trimesh.load(export(m, tmp_path / "f.ply", values), process=False)
    raw = ply.metadata["_ply_raw"]["face"]["data"]
    assert np.array_equal(raw["segment_id"].ravel(), m.face_segment)  # exact as doubles
    # Only types of the PLY format (VTK's reader, ParaView's, knows no int64; a review).
    head = (tmp_path / "f.ply").read_bytes().split(b"end_header")[0].decode()
    types = {line.split()[1] for line in head.splitlines() if line.startswith("property") and "list" not in line}
    assert types <= {"char", "uchar", "short", "ushort", "int", "uint", "float", "double"}, types
    assert np.allclose(raw["blade_area_m2"].ravel(), seg.loc[m.face_segment, "blade_area_m2"])
    assert np.allclose(ply.vertices, m.vertices) and np.array_equal(ply.faces, m.faces)
    # VTK legacy: parse the points, triangles and cell data back.
    pts, tri, cell = read_legacy_vtk(export(m, tmp_path / "f.vtk", values))
    assert np.array_equal(pts, m.vertices) and np.array_equal(tri, m.faces)
    assert np.array_equal(cell["segment_id"], m.face_segment)  # double, as in the PLY (VTK long: 32 bits on Windows)
    # OBJ: groups name the segments; face count per group matches.
    obj = export(m, tmp_path / "f.obj", values).read_text().splitlines()
    counts, current = {}, None
    for line in obj:
        if line.startswith("g seg_"):
            current = int(line[6:])
        elif line.startswith("f "):
            counts[current] = counts.get(current, 0) + 1
    assert counts == pd.Series(m.face_segment).value_counts().to_dict()
    side = pd.read_csv(tmp_path / "f.segments.csv")
    assert set(side["segment_id"]) == set(np.unique(m.face_segment))
    # a flag reads back as an integer (it was written 1.0), an area to 12 digits
    assert side["measured"].dtype.kind == "i"
    by_id = side.set_index("segment_id")
    np.testing.assert_allclose(by_id["blade_area_m2"], seg.loc[by_id.index, "blade_area_m2"], rtol=1e-11)
    with pytest.raises(InputError, match="unknown mesh format"):
        export(m, tmp_path / "f.stl")
    with pytest.raises(InputError, match="no entry for segment"):
        export(m, tmp_path / "g.ply", {"x": seg["measured"].iloc[:3]})


def test_a_plant_file_s_misspelled_name_or_word_for_a_number_is_named(tmp_path):
    """CPlantBox reads an unknown parameter name and a word where a number belongs without a word:
    a misspelled ``lmax`` ended in a C++ ``vector::_M_range_check`` traceback, ``theta="abc"`` grew
    a different plant (blades at 15° instead of 45°), ``lmax="nan"`` said the plant had no blade.
    Each is now refused naming the file, the organ and the parameter, with the closest known name;
    every plant file CPlantBox ships (112, wheat and others) still passes."""
    from lightfit.plant.growth import parameter_dir, resolve_parameter_file

    text = GrowthConfig().path.read_text()
    cases = {
        (
            'name="lmax" value="43"',
            'name="lmaxx" value="43"',
        ): r"<leaf subType=1>: CPlantBox knows no parameter 'lmaxx' \(did you mean 'lmax'\?\)",
        ('name="theta" value="0.2"', 'name="theta" value="abc"'): r"<leaf subType=1> parameter 'theta': value='abc'",
        ('name="lmax" value="43"', 'name="lmax" value="nan"'): r"parameter 'lmax': value='nan'.*a finite number",
    }
    for (old, new), message in cases.items():
        assert text.count(old) == 1
        bad = tmp_path / "bad.xml"
        bad.write_text(text.replace(old, new))
        with pytest.raises(InputError, match=message) as e:
            GrowthConfig(parameter_file=str(bad))
        assert e.value.file == bad
    shipped = sorted(parameter_dir().glob("*.xml"))
    assert len(shipped) > 100
    for f in shipped:
        resolve_parameter_file(f)


def test_bad_inputs_are_clear_errors(tmp_path):
    with pytest.raises(InputError, match="not found.*Triticum_aestivum"):
        GrowthConfig(parameter_file="Triticum_nonexistent.xml")
    bad = tmp_path / "bad.xml"
    bad.write_text("<notaplant/>")
    with pytest.raises(InputError, match="no <plant> element"):
        GrowthConfig(parameter_file=str(bad))
    with pytest.raises(InputError, match="not after season_start"):
        GrowthConfig(season_start="2016-04-20", target_date="2016-03-05")
    with pytest.raises(InputError, match="not a date"):
        GrowthConfig(target_date="April")
    with pytest.raises(InputError, match="row_spacing_m"):
        Field(boundary="finite", row_spacing_m=-0.1)
    with pytest.raises(InputError, match="plant_spacing_m"):
        Field(boundary="finite", plant_spacing_m=0.0)
    # centimetres given as metres (a newcomer's review: 12.5 m rows were grown without a word)
    with pytest.raises(InputError, match=r"row_spacing_m=12.5.*at most 2 m \(centimetres given as metres"):
        Field(row_spacing_m=12.5)
    with pytest.raises(InputError, match="plant_spacing_m=3"):
        Field(plant_spacing_m=3)
    assert Field(row_spacing_m=2.0, plant_spacing_m=0.75).row_spacing_m == 2.0  # maize's rows and wider pass
    with pytest.raises(InputError, match="buffer_rows"):
        Field(boundary="finite", buffer_rows=-1)
    for d in (float("nan"), float("inf"), "90"):  # NaN built a mesh of NaN vertices
        with pytest.raises(InputError, match="row_direction_deg"):
            Field(boundary="finite", row_direction_deg=d)
    for kw in ({"buffer_rows": True}, {"buffer_along": False}, {"n_plants": True}, {"n_plants": 4.0}):
        with pytest.raises(InputError, match=next(iter(kw))):  # errors.check_integer: bools are not counts
            Field(boundary="finite", **kw)
    assert Field(boundary="finite", n_plants=np.int64(4), buffer_rows=np.int64(1)).m == 4  # numpy integers count
    with pytest.raises(InputError, match="do not fit"):
        Field(boundary="finite", n_plants=4).tiles(9)
    with pytest.raises(InputError, match="along"):
        MeshResolution(along=0)


def test_a_field_s_growth_must_be_a_growth_config():
    """``Field(growth="Triticum_aestivum_adapted_2023.xml")``, the file where its GrowthConfig belongs,
    was taken and failed later, in build() or attrs(), on an AttributeError ('str' object has no
    attribute 'fingerprint'; a review)."""
    with pytest.raises(InputError, match="growth='Triticum_aestivum_adapted_2023.xml'.*GrowthConfig") as e:
        Field(growth="Triticum_aestivum_adapted_2023.xml")
    assert e.value.parameter == "growth"


def test_a_tile_of_another_field_is_named(tmp_path):
    """build(fld, tile=t) with t a tile of another, larger field (plants ``fld`` has no row for)
    stopped on a pandas KeyError listing every plant id (a review)."""
    other = Field(boundary="finite", n_plants=16).tiles(2)[1]
    with pytest.raises(InputError, match="tile 1 holds plants that 2 rows × 2 plants") as e:
        build(Field(n_plants=4, seed=1), tile=other, cache_dir=tmp_path)
    assert e.value.parameter == "tile"


def test_blade_inclination_against_analytic_and_trimesh(plant_table):
    """A flat and a 30°-tilted blade give 0° and 30°; on a grown plant the area-weighted mean equals
    trimesh's face normals and areas (an independent geometry library)."""
    verts = np.array([[0.0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]])
    quad = np.array([[0, 1, 2], [0, 2, 3]])
    flat = Mesh(verts, quad, np.array([1, 1]), np.array([True, True]))
    assert flat.blade_inclination_deg() == pytest.approx(0.0)
    c, s = np.cos(np.radians(30)), np.sin(np.radians(30))
    tilted = Mesh(verts @ np.array([[1, 0, 0], [0, c, s], [0, -s, c]]), quad, np.array([1, 1]), np.array([True, True]))
    assert tilted.blade_inclination_deg() == pytest.approx(30.0)
    m = shoot_mesh(plant_table, MeshResolution())
    tm = m.to_trimesh()
    blade = m.face_is_blade
    tilt = np.degrees(np.arccos(np.abs(tm.face_normals[blade, 2])))
    assert m.blade_inclination_deg() == pytest.approx(np.average(tilt, weights=tm.area_faces[blade]), rel=1e-9)


def _projected_blade_share(geom, zenith_deg: float, azimuth_deg: float) -> float:
    """G(Ω): the blades' area projected towards a sun at (zenith, compass azimuth) per blade area."""
    m = geom.mesh
    blade = np.asarray(m.face_is_blade)
    v, f = np.asarray(m.vertices), np.asarray(m.faces)[blade]
    cross = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])  # 2 × area × unit normal
    th, ph = np.radians(zenith_deg), np.radians(azimuth_deg)
    sun = np.array([np.sin(th) * np.sin(ph), np.sin(th) * np.cos(ph), np.cos(th)])  # x east, y north
    return float(np.abs(cross @ sun).sum() / np.linalg.norm(cross, axis=1).sum())


def test_plants_face_their_own_ways_unless_aligned():
    """Field plants stand at random headings: CPlantBox grows every plant facing the same way (its
    first leaf at one azimuth), which gave the canopy a preferred leaf azimuth, so the blades'
    projection towards a sun 57.5° from the zenith differed by ≈ 40 % (max − min over the mean of
    the four compass directions; 0.38–0.57) between compass directions (a review). Turned by their
    own headings, the 100-plant cell's blades project within a few per cent of each other from every
    side (2.6 %); the turn moves nothing but x and y."""
    from lightfit.plant.field import plant_heading_deg, turned

    random, aligned = Field(n_plants=100), Field(n_plants=100, headings="aligned")
    h = random.plants()["heading_deg"].to_numpy()
    assert (aligned.plants()["heading_deg"] == 0).all() and h.min() >= 0 and h.max() < 360
    assert np.abs(np.exp(1j * np.radians(h)).mean()) < 0.2  # no preferred heading
    assert plant_heading_deg(123) == plant_heading_deg(123) != plant_heading_deg(124)
    spread, built = {}, {}
    for name, fld in (("random", random), ("aligned", aligned)):
        g = built[name] = build(fld)
        share = [_projected_blade_share(g, 57.5, az) for az in (0, 90, 180, 270)]
        spread[name] = (max(share) - min(share)) / np.mean(share)
    assert spread["aligned"] > 0.2 and spread["random"] < 0.08, spread
    # Each built plant is the aligned one turned about its base by the heading the plants table
    # records, counter-clockwise (a rotation written out here; a mutation audit: building every plant
    # turned by minus its heading survived, the geometry then disagreeing with the recorded headings
    # and the layout fingerprint made of them): every segment's vector, and the stems' and sheaths'
    # points. (A blade's start is left out: a collar on a joint of the stem's polyline takes either
    # segment's tangent by round-off, which turn and placement change, and the blade then leaves its
    # tube up to some 30 µm round from where the other build puts it.)
    ra, al = built["random"].segments, built["aligned"].segments
    np.testing.assert_array_equal(ra["segment_id"], al["segment_id"])
    at = built["random"].plants.set_index("plant_id").loc[ra["plant_id"]]
    h, x, y = np.radians(at["heading_deg"].to_numpy()), at["x_m"].to_numpy(), at["y_m"].to_numpy()
    c, s = np.cos(h), np.sin(h)
    dx, dy = al["x1"] - al["x0"], al["y1"] - al["y0"]
    np.testing.assert_allclose(ra["x1"] - ra["x0"], c * dx - s * dy, rtol=0, atol=1e-12)
    np.testing.assert_allclose(ra["y1"] - ra["y0"], s * dx + c * dy, rtol=0, atol=1e-12)
    np.testing.assert_allclose(ra["z1"] - ra["z0"], al["z1"] - al["z0"], rtol=0, atol=1e-12)
    tube = organ_class(ra) != "blade"
    assert tube.sum() > 1000
    for end in "01":
        dx, dy = al[f"x{end}"] - x, al[f"y{end}"] - y
        np.testing.assert_allclose(ra[f"x{end}"][tube], (x + c * dx - s * dy)[tube], rtol=0, atol=1e-12)
        np.testing.assert_allclose(ra[f"y{end}"][tube], (y + s * dx + c * dy)[tube], rtol=0, atol=1e-12)
    seg = build(Field(n_plants=1, headings="aligned")).segments
    t = turned(seg, 90.0)  # a quarter turn counter-clockwise: (x, y) → (−y, x)
    np.testing.assert_allclose(t["x1"], -seg["y1"], atol=1e-15)
    np.testing.assert_allclose(t["y1"], seg["x1"], atol=1e-15)
    np.testing.assert_allclose(np.hypot(t["bx"], t["by"]), np.hypot(seg["bx"], seg["by"]), atol=1e-15)
    for c in ("z0", "z1", "length_m", "blade_area_m2", "radius_m"):
        assert (t[c] == seg[c]).all(), c
    # the whole plant turns, blades with it: the mesh of the turned table is the mesh turned by the
    # same angle about the base, vertex for vertex (a blade's width follows its branching direction;
    # leaving that direction unturned twisted every blade and survived a mutation audit)
    from lightfit.plant.mesh import shoot_mesh

    c, s37 = np.cos(np.radians(37.0)), np.sin(np.radians(37.0))
    m0, m1 = shoot_mesh(seg), shoot_mesh(turned(seg, 37.0))
    on_blade = np.unique(m0.faces[np.asarray(m0.face_is_blade)])  # (prisms turn by their plant's own angle)
    v0, v1 = m0.vertices[on_blade], m1.vertices[on_blade]
    assert len(v0) > 100
    np.testing.assert_allclose(v1[:, 0], c * v0[:, 0] - s37 * v0[:, 1], atol=1e-12)
    np.testing.assert_allclose(v1[:, 1], s37 * v0[:, 0] + c * v0[:, 1], atol=1e-12)
    np.testing.assert_allclose(v1[:, 2], v0[:, 2], atol=1e-12)


def test_a_broken_parameter_file_is_named_not_a_cplantbox_traceback(tmp_path):
    """A parameter file cut short (well-formed up to a point) made CPlantBox say it could not open
    the file and then fail on a missing root parameter: a ValueError traceback, exit 1. A folder,
    a file that is not XML and a plant CPlantBox cannot grow are refused naming the file; plants
    without a leaf blade (CPlantBox's bundled 0.xml: every leaf a sheath, LAI 0) are refused
    before anything is rendered (a review)."""
    from lightfit.plant.growth import parameter_dir

    default = GrowthConfig().path
    cut = tmp_path / "cut.xml"
    cut.write_bytes(default.read_bytes()[:3000])
    with pytest.raises(InputError, match="not well-formed XML") as e:
        GrowthConfig(parameter_file=str(cut))
    assert e.value.file == cut
    with pytest.raises(InputError, match="a folder, not a file"):
        GrowthConfig(parameter_file=str(tmp_path))
    empty = tmp_path / "empty.xml"
    empty.write_text("<plant></plant>")
    with pytest.raises(InputError, match="CPlantBox cannot grow a plant from it") as e:
        grow_plant(GrowthConfig(parameter_file=str(empty)), seed=1)
    assert e.value.file == empty
    assert (parameter_dir() / "0.xml").is_file()
    no_blades = Field(n_plants=1, growth=GrowthConfig(parameter_file="0.xml"))
    with pytest.raises(InputError, match="no leaf blade") as e:
        build(no_blades, cache_dir=tmp_path / "cache")
    assert e.value.file == parameter_dir() / "0.xml"


def test_segment_end_points_are_the_nodes_cplantbox_s_segments_join(tmp_path):
    """A segment's end points are the mapped nodes its CPlantBox segment joins (``plant.nodes``, which
    ``plant.segments``, radii and organ types index). ``getNodes()``, read before, can be one node
    short: CPlantBox's bundled maize of Leitner 2014 (a pea as well) stopped on an IndexError in
    the segment table instead of the file's named refusal (no leaf blade; a review)."""
    import plantbox as pb

    from lightfit.plant.growth import parameter_dir, segment_table

    path = parameter_dir() / "Zea_mays_4_Leitner_2014.xml"
    plant = pb.MappedPlant(1)
    plant.readParameters(str(path))
    plant.initialize(False)
    plant.simulate(10.0, False)
    assert len(plant.getNodes()) == len(plant.nodes) - 1  # the case: getNodes() misses one
    nodes = np.array([[v.x, v.y, v.z] for v in plant.nodes]) / 100  # cm → m
    ends = np.array([[s.x, s.y] for s in plant.segments])
    table = segment_table(plant)
    np.testing.assert_allclose(table[["x0", "y0", "z0"]].to_numpy(), nodes[ends[:, 0]], rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(table[["x1", "y1", "z1"]].to_numpy(), nodes[ends[:, 1]], rtol=1e-12, atol=1e-15)
    growth = GrowthConfig(parameter_file=path.name, target_date="2016-03-15")
    with pytest.raises(InputError, match="no leaf blade") as e:
        build(Field(n_plants=1, growth=growth), cache_dir=tmp_path)
    assert e.value.file == path


def test_a_plant_with_more_segments_than_its_id_stride_is_refused(monkeypatch):
    """Segment ids are plant_id · SEGMENT_ID_STRIDE + index: a plant with as many segments as the
    stride (10⁶; CPlantBox counts the roots in the index) would take its neighbour's ids, silently.
    Shown with the stride lowered to fewer than the plant's segments; the roots flag takes booleans
    only ("no" is true in Python: the roots were kept)."""
    import plantbox as pb

    from lightfit.plant import growth as G

    plant = pb.MappedPlant(1)
    plant.readParameters(str(G.parameter_dir() / GrowthConfig().path.name))
    plant.initialize(False)
    plant.simulate(10.0, False)
    n = len(plant.segments)
    assert len(G.segment_table(plant)) == n
    monkeypatch.setattr(G, "SEGMENT_ID_STRIDE", n)
    with pytest.raises(InputError, match=f"a plant of {n} segments.*fewer than {n:,} segments"):
        G.segment_table(plant)
    with pytest.raises(InputError, match="include_roots='no'.*True or False"):
        GrowthConfig(include_roots="no")


def test_growth_dates_and_spacings_are_read_as_values():
    """A date typed another way grows the same plants under the same key; spacings are numbers,
    numpy's too, and not booleans (True was taken as 1 m)."""
    assert GrowthConfig(target_date="20160420").fingerprint() == GrowthConfig().fingerprint()
    f = Field(boundary="finite", row_spacing_m=np.float32(0.125), plant_spacing_m=np.int64(1))
    assert f.plant_spacing_m == 1 and type(f.row_spacing_m) is float and f.row_spacing_m == 0.125
    assert repr(f) == repr(Field(boundary="finite", row_spacing_m=0.125, plant_spacing_m=1.0))  # one key
    with pytest.raises(InputError, match="row_spacing_m=True"):
        Field(boundary="finite", row_spacing_m=True)


def test_counts_and_seed_given_as_numpy_integers_are_the_same_field_under_the_same_key():
    """n_plants, seed and the buffers from numpy (a sweep over np.arange) were kept as numpy
    integers: the repr, a cache and resume key (Scenario.digest), read np.int64(16) where the
    same field typed by hand reads 16."""
    given = Field(
        n_plants=np.int64(16), seed=np.int32(3), boundary="finite", buffer_rows=np.int64(1), buffer_along=np.uint8(4)
    )
    typed = Field(n_plants=16, seed=3, boundary="finite", buffer_rows=1, buffer_along=4)
    assert repr(given) == repr(typed)
    assert [type(getattr(given, k)) for k in ("n_plants", "seed", "buffer_rows", "buffer_along")] == [int] * 4
    assert repr(Field(n_plants=np.int64(9))) == repr(Field(n_plants=9))  # periodic: buffer_rows set to 0


def test_a_parameter_file_given_as_a_path_is_kept_as_text_and_goes_into_results_files(tmp_path):
    """GrowthConfig kept a pathlib.Path as given: the field's attrs held it, and xarray refuses a
    Path as a netCDF attribute (a TypeError when the results file was written, after the run), and
    the repr (a cache and resume key) differed from the same file named as text. None was a
    TypeError from pathlib."""
    import xarray as xr

    from lightfit.plant.growth import resolve_parameter_file

    path = resolve_parameter_file("Triticum_aestivum_adapted_2023.xml")
    g = GrowthConfig(parameter_file=path)
    assert g.parameter_file == str(path) and repr(g) == repr(GrowthConfig(parameter_file=str(path)))
    assert GrowthConfig(parameter_file=Path("Triticum_aestivum_adapted_2023.xml")) == GrowthConfig()
    ds = xr.Dataset(attrs=Field(growth=g).attrs())
    ds.to_netcdf(tmp_path / "r.nc", engine="h5netcdf")
    assert xr.open_dataset(tmp_path / "r.nc", engine="h5netcdf").attrs["parameter_file"] == str(path)
    for bad in (None, 3):
        with pytest.raises(InputError, match="parameter 'parameter_file'.*a file name or path"):
            GrowthConfig(parameter_file=bad)


def test_dates_given_as_date_objects_are_the_same_growth_and_go_into_results_files(tmp_path):
    """``parse_date`` takes a ``datetime.date`` (or datetime), so GrowthConfig did; it kept the object:
    the repr (a cache and resume key) differed from the same day as text, and the field's attrs,
    which go into a results file, held a date that netCDF cannot store (xarray: "Invalid value for
    attr 'target_date'", at the end of a run; a review)."""
    import datetime as dt

    import xarray as xr

    given = GrowthConfig(season_start=dt.date(2016, 3, 5), target_date=dt.datetime(2016, 4, 20, 13, 30))
    assert given == GrowthConfig() and repr(given) == repr(GrowthConfig())
    assert GrowthConfig(target_date="20160420").target_date == "2016-04-20"
    fld = Field(n_plants=4, seed=1, growth=given)
    path = tmp_path / "attrs.nc"
    xr.Dataset(attrs=fld.attrs()).to_netcdf(path)
    with xr.open_dataset(path) as ds:
        assert Field.from_attrs(ds.attrs, path) == Field(n_plants=4, seed=1)


def test_a_field_is_rebuilt_from_its_attributes():
    """Field.from_attrs(field.attrs()) is the field a results file was made with: every layout setting
    off its default (buffer rows and plants along apart, spacings, row direction, seed, sheaths,
    headings) and the periodic default, compared setting by setting and by the layout fingerprint of
    every plant's id, position and heading. A mutation audit: buffer_along dropped on the way back
    survived (a rebuilt 1-row, 3-along field got 1 buffer plant along the rows, not 3)."""
    finite = Field(
        boundary="finite",
        n_plants=7,
        buffer_rows=1,
        buffer_along=3,
        row_spacing_m=0.2,
        plant_spacing_m=0.05,
        row_direction_deg=30.0,
        seed=5,
        sheaths="rods",
        headings="aligned",
    )
    rows = Field(n_plants=7, plants_per_row=4, seed=3)
    for fld in (finite, Field(n_plants=5, seed=2), rows):
        back = Field.from_attrs(fld.attrs())
        assert back == fld and back.attrs() == fld.attrs()
        assert (back.m, back.m_along) == (fld.m, fld.m_along)
    # a square area writes no plants_per_row (files written before it existed read the same)
    assert "plants_per_row" not in finite.attrs() and rows.attrs()["plants_per_row"] == 4


def test_a_measurement_area_of_whole_rows():
    """``plants_per_row`` makes the measurement area ⌈n_plants / plants_per_row⌉ rows of that many
    plants (500 as 20 × 25, which no square holds), counted and placed by hand: plants a plant spacing
    apart along a row, rows a row spacing apart, the area centred on the origin; a periodic cell
    exactly that area (its copies repeat at N_along × plant spacing along the rows and N_rows × row
    spacing across); buffers around it as around a square."""
    fld = Field(n_plants=500, plants_per_row=25)
    assert (fld.n_rows, fld.n_along, fld.n_measured) == (20, 25, 500) and fld.area_label == "20 rows × 25 plants"
    assert Field(n_plants=501, plants_per_row=25).n_measured == 525  # rounded up to whole rows
    assert Field(n_plants=5, plants_per_row=5).area_label == "1 row × 5 plants"
    with pytest.raises(InputError, match="plants_per_row=100"):  # a row longer than the plants asked for
        Field(n_plants=5, plants_per_row=100)
    small = Field(n_plants=6, plants_per_row=3, row_spacing_m=0.2, plant_spacing_m=0.05, row_direction_deg=90)
    p = small.plants()
    assert len(p) == 6 and p["measured"].all()
    assert sorted(p["r"].unique()) == [0, 1] and sorted(p["c"].unique()) == [0, 1, 2]
    # rows east–west (90°): along a row x grows by the plant spacing, across the rows y by the row spacing
    assert sorted(np.round(p["x_m"], 12).unique()) == pytest.approx([-0.05, 0.0, 0.05])
    assert sorted(np.round(p["y_m"], 12).unique()) == pytest.approx([-0.1, 0.1])
    cell = small.cell
    assert (cell.along_m, cell.across_m) == pytest.approx((0.15, 0.4))
    assert cell.area_m2 == pytest.approx(small.ground_area_m2)
    # each plant in the middle of its own spacing × spacing patch: the spacings continue across the seam
    assert np.abs(p["x_m"]).max() == pytest.approx(cell.along_m / 2 - 0.025)
    assert np.abs(p["y_m"]).max() == pytest.approx(cell.across_m / 2 - 0.1)
    finite = Field(boundary="finite", n_plants=6, plants_per_row=3, buffer_rows=1, buffer_along=2)
    q = finite.plants()
    assert (finite.m, finite.m_along, len(q), int(q["measured"].sum())) == (4, 7, 28, 6)
    assert q.loc[q["measured"], "r"].max() == 1 and q.loc[q["measured"], "c"].max() == 2
    # A square given as rows is the square: the same plants, ids, seeds, places and headings.
    sq, as_rows = Field(n_plants=9, seed=4), Field(n_plants=9, plants_per_row=3, seed=4)
    pd.testing.assert_frame_equal(sq.plants(), as_rows.plants())
    assert sq.layout_fingerprint() == as_rows.layout_fingerprint() and sq.cell == as_rows.cell


def test_tiles_of_a_measurement_area_of_whole_rows():
    """Tiles partition a rectangular area: every measured plant in exactly one tile, the larger count of
    blocks along the longer side (2 rows × 6 plants in 3 tiles: three blocks of 2 × 2 along the rows;
    6 rows × 2 plants: three blocks across them); too many tiles for a side is refused, naming both sides."""
    for fld, blocks in (
        (Field(boundary="finite", n_plants=12, plants_per_row=6, buffer_rows=1), (2, 2)),
        (Field(boundary="finite", n_plants=12, plants_per_row=2, buffer_rows=1), (2, 2)),
    ):
        tiles = fld.tiles(3)
        measured = np.concatenate([t.measured for t in tiles])
        assert len(measured) == len(np.unique(measured)) == 12
        np.testing.assert_array_equal(np.sort(measured), np.sort(fld.plants().query("measured").index.to_numpy()))
        for t in tiles:
            rc = fld.plants().loc[t.measured]
            assert (rc["r"].nunique(), rc["c"].nunique()) == blocks
    with pytest.raises(InputError, match="do not fit a 2×6 measurement area"):
        Field(n_plants=12, plants_per_row=6).tiles(9)
    # the most nearly square tiling that fits, not only the most nearly square one (a review: refused)
    for fld, n_tiles, blocks in (
        (Field(n_plants=4, plants_per_row=4, boundary="finite"), 4, (1, 4)),
        (Field(n_plants=20, plants_per_row=1), 4, (4, 1)),
        (Field(n_plants=300, plants_per_row=100), 16, (2, 8)),
        (Field(n_plants=12, plants_per_row=2), 2, (2, 1)),  # both fit: two blocks across the 6 rows
        (Field(n_plants=60, plants_per_row=3), 6, (2, 3)),  # 2 × 3 blocks of 10, not 3 × 2 of 14 and 7
    ):
        r, c = (fld.plants().loc[np.concatenate([t.measured for t in fld.tiles(n_tiles)])][k] for k in ("r", "c"))
        firsts = {(r[t.measured].min(), c[t.measured].min()) for t in fld.tiles(n_tiles)}
        assert (len({a for a, _ in firsts}), len({b for _, b in firsts})) == blocks


def test_a_square_keeps_its_key_and_ids_their_room():
    """The repr keys caches and resumes (Scenario.digest, the emulator, field-run's tasks): a square's is
    what it was before whole rows existed, and a square given as rows is the square (a review: both
    changed, so a stored calibration refused to resume with the same settings). Plant ids hold
    c + 1000 < 10⁴: a longer row is refused, not given ids that collide (a review: 10 001 per row did)."""
    square = Field(n_plants=9, seed=2)
    assert "plants_per_row" not in repr(square) and repr(square).startswith("Field(n_plants=9, row_spacing_m=0.125")
    as_rows = Field(n_plants=9, plants_per_row=3, seed=2)
    assert as_rows == square and repr(as_rows) == repr(square) and as_rows.plants_per_row is None
    assert repr(Field(n_plants=6, plants_per_row=3)).endswith("headings='random', plants_per_row=3)")
    from lightfit.distributed.tiles import HaloField

    assert repr(HaloField.of(square)).endswith("headings='random', halo_rows=None)")
    assert Field(n_plants=18000, plants_per_row=9000).plants()["plant_id"].is_unique  # two rows of the most
    with pytest.raises(InputError, match="plants per row") as err:
        Field(n_plants=9001, plants_per_row=9001)
    assert err.value.parameter == "plants_per_row"
    with pytest.raises(InputError, match="buffer"):
        Field(n_plants=4, boundary="finite", buffer_rows=1, buffer_along=1001)
    with pytest.raises(InputError, match="buffer_rows"):
        Field(n_plants=4, boundary="finite", buffer_rows=1001)


@pytest.mark.parametrize("bad", [0, -2, True, 2.5, "25"])
def test_plants_per_row_must_be_a_whole_number_of_plants(bad):
    with pytest.raises(InputError, match="plants_per_row") as err:
        Field(n_plants=10, plants_per_row=bad)
    assert err.value.parameter == "plants_per_row"
    assert Field(n_plants=10, plants_per_row=np.int64(5)).plants_per_row.__class__ is int


def test_the_preview_says_what_it_draws(tmp_path, monkeypatch):
    """The top view said "pale: buffer plants" on a periodic field, which has none, and did not draw
    its cell (a newcomer's review): a periodic field's cell is drawn dashed and named, buffer plants
    are named only where there are some."""
    import matplotlib.figure

    from lightfit.plant.preview import plot_field

    seen = []
    save = matplotlib.figure.Figure.savefig
    monkeypatch.setattr(
        matplotlib.figure.Figure,
        "savefig",
        lambda fig, *a, **k: (
            seen.append((fig.axes[0].get_title(), len(fig.axes[0].lines), fig._suptitle.get_text()))
            or save(fig, *a, **k)
        ),
    )
    cache = tmp_path / "cache"
    plot_field(build(Field(n_plants=4), cache_dir=cache), tmp_path / "p.png")
    plot_field(build(Field(n_plants=4, boundary="finite", buffer_rows=1), cache_dir=cache), tmp_path / "f.png")
    assert [s[:2] for s in seen] == [
        ("top view (dashed: the periodic cell, repeated without end)", 1),
        ("top view (pale: buffer plants)", 0),
    ]
    # the title's count: --n-plants 4 with one buffer row all round is 4 measured among 4 × 4; the
    # title said "16 plants" alone, another field than the one asked for at a glance
    assert seen[0][2].startswith("4 plants, ") and seen[1][2].startswith("16 plants (4 measured, 12 buffer), ")


def test_a_valid_archive_whose_payload_does_not_match_its_checksum_is_rebuilt(tmp_path, monkeypatch):
    """An entry that unzips cleanly under the right key but with an altered segment table (bit rot
    inside an array, not in the zip framing) fails its SHA-256 and is regrown, never used. A stand-in
    grower keeps it fast; the entry is rewritten with numpy's own writer, its metadata untouched."""
    import lightfit.plant.cache as pc

    table = pd.DataFrame(
        {
            "segment_index": np.arange(3, dtype=np.int64),
            "organ_type": pd.Categorical(["stem", "leaf", "leaf"], categories=["root", "stem", "leaf", "other"]),
            "length_m": np.array([0.1, 0.2, 0.3]),
        }
    )
    grown = []
    monkeypatch.setattr(pc, "grow_plant", lambda config, seed, plant_id=0: grown.append(seed) or table.copy())
    g = GrowthConfig()
    first, hit = pc.load_or_grow(g, 5, directory=tmp_path)
    assert not hit and grown == [5]
    path = tmp_path / f"{cache_key(g, 5)}.npz"
    with np.load(path) as z:
        entry = {k: z[k] for k in z.files}
    entry["length_m"] = entry["length_m"] * 2  # same key, digest and columns: only the payload differs
    np.savez(path, **entry)
    again, hit = pc.load_or_grow(g, 5, directory=tmp_path)
    assert not hit and grown == [5, 5]
    np.testing.assert_array_equal(again["length_m"], [0.1, 0.2, 0.3])
    third, hit = pc.load_or_grow(g, 5, directory=tmp_path)  # the rebuilt entry is good
    assert hit and third.equals(first)


def test_a_schema_bump_makes_every_entry_stale(monkeypatch):
    """Documented: bump SCHEMA when the segment table's layout changes and older entries become stale."""
    import lightfit.plant.cache as pc

    g = GrowthConfig()
    before = cache_key(g, 42)
    monkeypatch.setattr(pc, "SCHEMA", pc.SCHEMA + 1)
    assert cache_key(g, 42) != before


def test_exports_of_a_hand_built_mesh_read_back_by_face(tmp_path):
    """Two triangles of segments 7 and 3 (given in that order), a value per segment: the OBJ's faces
    read back by trimesh (1-based indices in the file) and the VTK cell values in face order."""
    mesh = Mesh(
        vertices=np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0.5]]),
        faces=np.array([[0, 1, 2], [1, 3, 2]]),
        face_segment=np.array([7, 3]),
        face_is_blade=np.array([True, True]),
    )
    values = {"an": pd.Series({3: -1.25, 7: 4.5})}
    obj = export(mesh, tmp_path / "m.obj", values)
    text = obj.read_text().splitlines()
    faces = [tuple(int(i) for i in line.split()[1:]) for line in text if line.startswith("f ")]
    assert sorted(faces) == sorted([(1, 2, 3), (2, 4, 3)])  # OBJ indices count from 1
    tm = trimesh.load(obj, process=False, force="mesh")
    assert np.allclose(tm.vertices, mesh.vertices)
    assert {tuple(f) for f in tm.faces} == {(0, 1, 2), (1, 3, 2)}
    _, tri, cell = read_legacy_vtk(export(mesh, tmp_path / "m.vtk", values))
    assert cell["an"].tolist() == [4.5, -1.25]  # face 0 is segment 7, face 1 segment 3
    assert tri.tolist() == [[0, 1, 2], [1, 3, 2]]
    # a value named segment_id replaced the ids in the OBJ sidecar (and doubled PLY's property); refused
    for fmt in ("obj", "ply", "vtk"):
        with pytest.raises(InputError, match="'segment_id' is the id column's own name"):
            export(mesh, tmp_path / f"id.{fmt}", {"segment_id": pd.Series({3: 0.0, 7: 1.0})})


def test_the_obj_sidecar_reads_back_exactly_large_ids_full_precision_and_nan(tmp_path):
    """The OBJ's sidecar CSV wrote every value with 12 significant digits: a parent id of plant
    10⁷·10⁶ (14 digits) read back as 10001000007300 and An lost its last digits. Integer-valued
    columns now read back as the same integers, the others as the same doubles, NaN as an empty cell."""
    big = 10_001_000_007_295
    mesh = Mesh(
        vertices=np.array([[0.0, 0, 0], [0.1, 0, 0], [0, 0.1, 0], [0.1, 0.1, 0.05]]),
        faces=np.array([[0, 1, 2], [1, 3, 2]]),
        face_segment=np.array([big, 3]),
        face_is_blade=np.array([True, False]),
    )
    an = 0.1 + 2.0**-40  # needs 17 significant digits
    values = {
        "an": pd.Series({big: an, 3: np.nan}),
        "parent": pd.Series({big: float(big - 1), 3: -1.0}),
        "tiller": pd.Series({big: np.nan, 3: 2.0}),
    }
    obj = export(mesh, tmp_path / "m.obj", values)
    text = (tmp_path / "m.segments.csv").read_text().splitlines()
    assert text[0] == "segment_id,an,parent,tiller"
    assert text[1:] == ["3,,-1,2", f"{big},{an!r},{big - 1},"]  # NaN: an empty cell
    side = pd.read_csv(obj.with_suffix(".segments.csv"))
    assert side["segment_id"].tolist() == [3, big]
    assert side["parent"].tolist() == [-1, big - 1] and side["parent"].dtype == np.int64
    assert np.isnan(side["an"][0]) and side["an"][1] == an  # exact, not to 12 digits
    assert np.isnan(side["tiller"][1]) and side["tiller"][0] == 2.0


def test_a_nan_value_and_a_large_id_read_back_from_vtk_as_paraview_reads_it(tmp_path):
    """Leaf An is NaN on stems (docs/dataset.md), so every dataset's field_values.vtk held NaN: the
    ASCII file said ``nan``, which VTK's reader (C++ ``>>``, so ParaView's) cannot read, and the
    file did not open. Written binary, NaN and a segment id of plant 10⁷·10⁶ read back exactly."""
    big = 10_001_000_007_295  # plant_id·10⁶ + index, 14 digits: past float32 and %.9g
    mesh = Mesh(
        vertices=np.array([[0.0, 0, 0], [0.1, 0, 0], [0, 0.1, 0], [0.1, 0.1, 0.05]]),
        faces=np.array([[0, 1, 2], [1, 3, 2]]),
        face_segment=np.array([big, 3]),
        face_is_blade=np.array([True, False]),
    )
    values = {"an": pd.Series({big: 4.5, 3: np.nan}), "parent": pd.Series({big: float(big - 1), 3: -1.0})}
    pts, tri, cell = read_legacy_vtk(export(mesh, tmp_path / "m.vtk", values))
    assert np.array_equal(pts, mesh.vertices) and tri.tolist() == [[0, 1, 2], [1, 3, 2]]
    assert cell["segment_id"].tolist() == [big, 3]
    assert cell["an"][0] == 4.5 and np.isnan(cell["an"][1])  # NaN, not 0 or a missing file
    assert cell["parent"].tolist() == [big - 1, -1]


def test_exports_say_what_their_values_are_in_the_header(tmp_path):
    """``notes`` (units, time, provenance) go where each format keeps text: PLY comments (trimesh
    still reads the file), OBJ ``#`` lines, the VTK title; a note that cannot be a header line is refused."""
    mesh = Mesh(np.eye(3), np.array([[0, 1, 2]]), np.array([5]), np.array([True]))
    values, notes = (
        {"an": pd.Series({5: 2.0})},
        {"units of an": "umol m-2 s-1", "time_utc": "2016-04-20T10:00:00+00:00"},
    )
    ply = export(mesh, tmp_path / "m.ply", values, notes)
    head = ply.read_bytes().split(b"end_header")[0].decode("ascii").splitlines()
    assert "comment units of an: umol m-2 s-1" in head and "comment time_utc: 2016-04-20T10:00:00+00:00" in head
    assert trimesh.load(ply, process=False).metadata["_ply_raw"]["face"]["data"]["an"].ravel().tolist() == [2.0]
    assert "# units of an: umol m-2 s-1" in export(mesh, tmp_path / "m.obj", values, notes).read_text().splitlines()
    title = export(mesh, tmp_path / "m.vtk", values, notes).read_bytes().split(b"\n")[1].decode("ascii")
    assert title == "lightfit shoot mesh (m); units of an: umol m-2 s-1; time_utc: 2016-04-20T10:00:00+00:00"
    assert read_legacy_vtk(tmp_path / "m.vtk")[2]["an"].tolist() == [2.0]
    with pytest.raises(InputError, match="printable ASCII on one line"):
        export(mesh, tmp_path / "n.ply", values, {"units of an": "µmol m⁻² s⁻¹"})


def test_a_value_with_two_entries_for_a_segment_is_refused_by_name(tmp_path):
    """A value series of a long table (two time steps, so each segment id twice) stopped in pandas'
    reindex with "cannot reindex on an axis with duplicate labels", naming neither the value nor the ids."""
    mesh = Mesh(np.eye(3), np.array([[0, 1, 2]]), np.array([5]), np.array([True]))
    two_steps = pd.Series([1.0, 2.0], index=[5, 5])
    for fmt in ("obj", "ply", "vtk"):
        with pytest.raises(InputError, match=r"parameter 'an'.*more than one entry for segment id\(s\) \[5\]"):
            export(mesh, tmp_path / f"m.{fmt}", {"an": two_steps})


def test_a_text_value_is_refused_by_name(tmp_path):
    """A text column (``organ_type``) stopped in numpy with "could not convert string to float: 'leaf'"."""
    mesh = Mesh(np.eye(3), np.array([[0, 1, 2]]), np.array([5]), np.array([True]))
    for fmt in ("obj", "ply", "vtk"):
        with pytest.raises(InputError, match=r"parameter 'organ_type'.*is not numeric.*integer code"):
            export(mesh, tmp_path / f"m.{fmt}", {"organ_type": pd.Series(["leaf"], index=[5])})


def test_a_refused_value_leaves_an_earlier_obj_and_its_sidecar_as_they_were(tmp_path):
    """write_obj checked the values only after writing the OBJ: a refused value (here a text column)
    replaced the OBJ but not its sidecar CSV, so the new geometry sat beside the old values. The
    values are now checked before anything is written."""
    mesh = Mesh(np.eye(3), np.array([[0, 1, 2]]), np.array([5]), np.array([True]))
    obj = export(mesh, tmp_path / "m.obj", {"an": pd.Series([1.5], index=[5])})
    before = obj.read_bytes(), (tmp_path / "m.segments.csv").read_bytes()
    moved = Mesh(np.eye(3) * 2, np.array([[0, 1, 2]]), np.array([5]), np.array([True]))
    with pytest.raises(InputError, match=r"parameter 'organ_type'.*is not numeric"):
        export(moved, obj, {"organ_type": pd.Series(["leaf"], index=[5])})
    assert (obj.read_bytes(), (tmp_path / "m.segments.csv").read_bytes()) == before
    assert "v 1 0 0" in obj.read_text().splitlines()  # the first mesh's vertices, not the refused one's


def test_a_mesh_without_faces_exports_in_every_format(tmp_path):
    """A mesh of no faces (a plant with no shoot yet) was written as PLY and VTK, but the OBJ writer
    stopped on an IndexError (it named the first segment's group)."""
    empty = Mesh.concatenate([])
    for suffix in ("obj", "ply", "vtk"):
        assert export(empty, tmp_path / f"e.{suffix}", {"an": pd.Series(dtype=float)}).exists()
    text = (tmp_path / "e.obj").read_text().splitlines()
    assert not [line for line in text if line.startswith(("v ", "f ", "g "))]
    assert pd.read_csv(tmp_path / "e.segments.csv").empty


def test_a_vtk_of_points_without_faces_ends_after_its_points_as_vtk_writes_it(tmp_path):
    """VTK's legacy reader (9.7, so ParaView) stops on "POLYGONS 0 0" with "Error reading
    polygons": a mesh without faces was written with that line and an empty CELL_DATA. VTK's own
    writer (vtkPolyDataWriter, binary) ends such a file after the points; so does write_vtk now.
    Checked on the bytes as the legacy format lays them out: header lines, then 3 big-endian doubles
    per point."""
    points = np.array([[0.0, 0.1, 0.2], [1.5, -2.0, 0.25]])
    mesh = Mesh(points, np.zeros((0, 3), dtype=int), np.zeros(0, dtype=int), np.zeros(0, dtype=bool))
    data = export(mesh, tmp_path / "p.vtk", {"an": pd.Series(dtype=float)}).read_bytes()
    head = b"# vtk DataFile Version 3.0\nlightfit shoot mesh (m)\nBINARY\nDATASET POLYDATA\nPOINTS 2 double\n"
    assert data.startswith(head)
    body = data[len(head) :]
    assert body[48:] == b"\n"  # nothing after the points: no POLYGONS, no CELL_DATA
    assert np.frombuffer(body[:48], dtype=">f8").reshape(2, 3).tolist() == points.tolist()
    empty = export(Mesh.concatenate([]), tmp_path / "e.vtk").read_bytes()
    assert empty == head.replace(b"POINTS 2", b"POINTS 0") + b"\n"


def test_a_value_name_that_is_not_ascii_is_refused_by_name(tmp_path):
    """``An_µmol`` is a Python identifier (µ is a letter) but the PLY and VTK headers are ASCII: the
    export stopped on a UnicodeEncodeError (and left an empty .vtk). Refused in every format, as the
    other names that cannot be a file attribute are, before the file is opened."""
    mesh = Mesh(np.eye(3), np.array([[0, 1, 2]]), np.array([5]), np.array([True]))
    for fmt in ("obj", "ply", "vtk"):
        with pytest.raises(InputError, match=r"parameter 'An_µmol'.*not a plain identifier.*ASCII letters"):
            export(mesh, tmp_path / f"m.{fmt}", {"An_µmol": pd.Series([1.0], index=[5])})
    assert not (tmp_path / "m.ply").exists() and not (tmp_path / "m.vtk").exists()


def test_a_blade_along_its_branching_direction_lies_across_horizontally():
    """Where a blade segment runs along its branching direction (t × s = 0) the width falls back to
    the horizontal direction square to the segment (mesh module): a segment rising at 45° towards +y
    gives a ribbon across x, its upper side up, normal (0, −1, 1)/√2, area w·L (by hand)."""
    a = np.array([0.0, 0.0, 0.1])
    t = np.array([0.0, 1.0, 1.0]) / np.sqrt(2)
    b = a + 0.1 * t
    seg = pd.DataFrame(
        {
            "plant_id": [0],
            "segment_index": [0],
            "segment_id": [7],
            "organ_type": pd.Categorical(["leaf"], categories=["root", "stem", "leaf", "other"]),
            "organ_id": [2],
            "x0": [a[0]],
            "y0": [a[1]],
            "z0": [a[2]],
            "x1": [b[0]],
            "y1": [b[1]],
            "z1": [b[2]],
            "length_m": [0.1],
            "radius_m": [0.0003],
            "blade_width_m": [0.01],
            "blade_area_m2": [0.001],
            "creation_time_d": [1.0],
            "bx": [t[0]],
            "by": [t[1]],
            "bz": [t[2]],
        }
    )
    m = shoot_mesh(seg)
    assert m.face_is_blade.all() and (m.face_segment == 7).all()
    np.testing.assert_allclose(m.normals(), np.tile([0.0, -1.0, 1.0], (m.n_faces, 1)) / np.sqrt(2), atol=1e-12)
    assert m.face_areas().sum() == pytest.approx(0.01 * 0.1, rel=1e-12)
    half = np.array([0.005, 0.0, 0.0])  # half the width, along x
    corners = np.array(sorted(map(tuple, [a - half, a + half, b - half, b + half])))
    used = np.array(sorted(map(tuple, m.vertices[np.unique(m.faces)])))
    np.testing.assert_allclose(used, corners, atol=1e-15)


def test_growth_runs_from_after_its_season_start_to_at_most_the_models_range():
    """The target date must come after the season start (the same day is no growth) and at most
    MAX_GROWTH_DAYS = 150 days after it: 5 March + 150 days is 2 August 2016 (26 + 30 + 31 + 30 + 31
    + 2 days, by hand), taken; 3 August is refused."""
    with pytest.raises(InputError, match="not after season_start"):
        GrowthConfig(season_start="2016-04-20", target_date="2016-04-20")
    assert GrowthConfig(season_start="2016-04-20", target_date="2016-04-21").days == 1.0
    assert GrowthConfig(season_start="2016-03-05", target_date="2016-08-02").days == 150.0
    with pytest.raises(InputError, match="151 days after season_start"):
        GrowthConfig(season_start="2016-03-05", target_date="2016-08-03")


def test_the_preview_shows_the_whole_cell_of_a_wide_row_field(tmp_path, monkeypatch):
    """The top view's limits came from the plants alone: with rows 0.75 m apart the cell (2 rows ×
    1 plant: 1.5 m across the east–west rows, y from −0.75 to +0.75 m; 0.03 m along them) reaches
    past the leaves (≈ 0.3 m from each plant), and its dashed north and south sides were cut off,
    leaving two lines. The view now holds the whole cell."""
    import matplotlib.figure

    from lightfit.plant.preview import plot_field

    seen = []
    save = matplotlib.figure.Figure.savefig
    monkeypatch.setattr(
        matplotlib.figure.Figure,
        "savefig",
        lambda fig, *a, **k: seen.append((fig.axes[0].get_xlim(), fig.axes[0].get_ylim())) or save(fig, *a, **k),
    )
    fld = Field(n_plants=2, plants_per_row=1, row_spacing_m=0.75)
    plot_field(build(fld, cache_dir=tmp_path / "cache"), tmp_path / "p.png")
    (x0, x1), (y0, y1) = seen[0]
    assert y0 < -0.75 and y1 > 0.75  # the cell's south and north sides are inside the view
    assert x0 < -0.015 and x1 > 0.015
