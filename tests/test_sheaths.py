"""Leaf sheaths wrapped around the stem (``Field.sheaths``): geometry checked against its definition
(lightfit.plant.sheaths): on the stem's axis, nested by age, blades moved rigidly to the collar."""

import numpy as np
import pandas as pd
import pytest

from lightfit.errors import InputError
from lightfit.plant import Field, GrowthConfig, build, expected_area, grow_plant, organ_class, plant_seed, shoot_mesh
from lightfit.plant.sheaths import SHEATHS, lay_sheaths, wrap_sheaths

P0, P1 = ["x0", "y0", "z0"], ["x1", "y1", "z1"]


@pytest.fixture(scope="module")
def plants():
    """Two plants as CPlantBox grows them, the second placed elsewhere (plants are independent)."""
    a = grow_plant(GrowthConfig(), plant_seed(7, 3, 4), plant_id=11)
    b = grow_plant(GrowthConfig(), plant_seed(7, 5, 6), plant_id=12)
    for c0, c1, off in (("x0", "x1", 0.4), ("y0", "y1", -0.2)):
        b[c0] += off
        b[c1] += off
    return pd.concat([a, b], ignore_index=True)


@pytest.fixture(scope="module")
def wrapped(plants):
    return wrap_sheaths(plants)


def _leaves(t):
    """Each leaf's segments in order, with their organ classes."""
    organ = pd.Series(organ_class(t), index=t.index)
    for _, leaf in t[t["organ_type"] == "leaf"].groupby(["plant_id", "organ_id"]):
        leaf = leaf.sort_values("segment_index")
        yield leaf, organ[leaf.index].to_numpy()


def test_rods_are_cplantbox_unchanged_and_bad_layouts_refused(plants):
    assert lay_sheaths(plants, "rods") is plants
    assert SHEATHS[0] == "wrapped" and Field().sheaths == "wrapped"
    for bad in ("tubes", None, ""):
        with pytest.raises(InputError, match="sheaths"):
            Field(sheaths=bad)


def _stem_chain(plant):
    """The plant's stem axis as (start, end) points of its segments, continued 1 m straight
    beyond the tip, as the wrapped layout's definition says."""
    stem = plant[organ_class(plant) == "stem"].sort_values("segment_index")
    a, b = stem[P0].to_numpy(), stem[P1].to_numpy()
    tip = b[-1] + (b[-1] - a[-1]) / np.linalg.norm(b[-1] - a[-1])
    return np.vstack([a, b[-1:]]), np.vstack([b, tip[None]])


def _nearest_on_chain(points, a, b):
    """Each point's nearest point on the chain of segments a → b, its distance and the direction there."""
    d = b - a
    L = np.linalg.norm(d, axis=1)
    u = d / L[:, None]
    t = np.clip(np.einsum("pkj,kj->pk", points[:, None, :] - a[None], u), 0, L)
    q = a[None] + t[..., None] * u[None]
    dist = np.linalg.norm(q - points[:, None, :], axis=2)
    i = dist.argmin(1)
    return q[np.arange(len(points)), i], dist[np.arange(len(points)), i], u[i]


def test_sheaths_follow_the_stem_axis_from_the_node_with_their_lengths(plants, wrapped):
    n_sheaths = 0
    for leaf, organ in _leaves(wrapped):
        s = leaf[organ == "sheath"]
        if s.empty:
            continue
        n_sheaths += 1
        a, b = _stem_chain(wrapped[wrapped["plant_id"] == leaf["plant_id"].iloc[0]])
        old = plants.loc[s.index]
        start, _, _ = _nearest_on_chain(old[P0].to_numpy()[:1], a, b)
        np.testing.assert_allclose(s[P0].to_numpy()[0], start[0], atol=1e-12)  # the axis point at the node
        for cols in (P0, P1):  # every end point on the stem's axis
            assert _nearest_on_chain(s[cols].to_numpy(), a, b)[1].max() < 1e-12
        np.testing.assert_allclose(s[P1].to_numpy()[:-1], s[P0].to_numpy()[1:], atol=1e-15)  # contiguous
        chord = np.linalg.norm(s[P1].to_numpy() - s[P0].to_numpy(), axis=1)
        np.testing.assert_allclose(chord, s["length_m"], rtol=1e-12)  # the table says the geometry
        np.testing.assert_allclose(chord, old["length_m"], rtol=1e-3)  # CPlantBox's lengths, up to the bends
    assert n_sheaths >= 8


def test_the_culm_never_crosses_its_sheaths(wrapped, plants):
    """Every point of the stem within a sheath's span lies inside that sheath's tube, culm radius
    included: the sheath follows the stem where it bends (a straight sheath along the node's
    direction crossed it on 16 % of such points). CPlantBox's rods cross it everywhere."""
    for table, crossing in ((wrapped, False), (plants, True)):
        inside_points = crossed = 0
        for _, plant in table.groupby("plant_id"):
            organ = organ_class(plant)
            stem = plant[organ == "stem"].sort_values("segment_index")
            r_stem = stem["radius_m"].max()
            p0, p1 = stem[P0].to_numpy(), stem[P1].to_numpy()
            culm = (p0[:, None, :] + np.linspace(0, 1, 10)[None, :, None] * (p1 - p0)[:, None, :]).reshape(-1, 3)
            for leaf, lorgan in _leaves(plant):
                s = leaf[lorgan == "sheath"]
                if s.empty:
                    continue
                a, b = s[P0].to_numpy(), s[P1].to_numpy()
                u0, u1 = (b[0] - a[0]) / np.linalg.norm(b[0] - a[0]), (b[-1] - a[-1]) / np.linalg.norm(b[-1] - a[-1])
                inside = ((culm - a[0]) @ u0 > 1e-9) & ((culm - b[-1]) @ u1 < -1e-9)
                if inside.any():
                    _, d, _ = _nearest_on_chain(culm[inside], a, b)
                    inside_points += int(inside.sum())
                    crossed += int(np.sum(d + r_stem > s["radius_m"].iloc[0]))
        assert inside_points > 100
        assert (crossed > 0.5 * inside_points) if crossing else crossed == 0, (crossed, inside_points)


def test_sheath_tubes_fit_what_they_enclose_oldest_outside(plants, wrapped):
    """A sheath's radius is its wall (CPlantBox's sheath radius) around what it encloses: the culm,
    or the younger sheaths starting within its span, whichever is wider."""
    checked = 0
    for _, plant in wrapped.groupby("plant_id"):
        organ = organ_class(plant)
        r_stem = plant.loc[organ == "stem", "radius_m"].max()
        tubes = []  # (node height, top height, radius, wall), oldest first
        for leaf, lorgan in _leaves(plant):
            s = leaf[lorgan == "sheath"]
            if len(s):
                assert (s["radius_m"] == s["radius_m"].iloc[0]).all()
                wall = plants.loc[s.index, "radius_m"].max()
                tubes.append((s["z0"].iloc[0], s["z1"].iloc[-1], s["radius_m"].iloc[0], wall))
        tubes.sort()
        for k, (_, top, r, wall) in enumerate(tubes):
            inside = [t[2] for t in tubes[k + 1 :] if t[0] < top]
            np.testing.assert_allclose(r, max([r_stem, *inside]) + wall, rtol=1e-12)
            assert all(r >= x + wall - 1e-15 for x in inside) and r > r_stem  # nested, the culm inside
            checked += 1
    assert checked >= 8


def test_blades_move_rigidly_to_the_collar_on_the_tube(plants, wrapped):
    for leaf, organ in _leaves(wrapped):
        s, b = leaf[organ == "sheath"], leaf[organ == "blade"]
        if s.empty or b.empty:
            continue
        old = plants.loc[b.index]
        # Shape and orientation kept: every segment's vector, and every point moved by one shift.
        np.testing.assert_allclose(
            b[P1].to_numpy() - b[P0].to_numpy(), old[P1].to_numpy() - old[P0].to_numpy(), atol=1e-15
        )
        shift = b[P0].to_numpy() - old[P0].to_numpy()
        np.testing.assert_allclose(shift, np.broadcast_to(shift[0], shift.shape), atol=1e-15)
        # The blade starts at the collar: at the sheath's top, on its tube's surface, square to the stem.
        base, collar = b[P0].to_numpy()[0], s[P1].to_numpy()[-1]
        chain = _stem_chain(wrapped[wrapped["plant_id"] == leaf["plant_id"].iloc[0]])
        _, _, tangent = _nearest_on_chain(collar[None], *chain)
        d = base - collar
        assert abs(d @ tangent[0]) < 1e-12
        np.testing.assert_allclose(np.linalg.norm(d), s["radius_m"].iloc[0], rtol=1e-9)
        # ... on the side where CPlantBox's collar lay (seen from the stem's axis at the collar).
        before = plants.loc[s.index[-1], P1].to_numpy(float) - collar
        before -= (before @ tangent[0]) * tangent[0]
        np.testing.assert_allclose(d / np.linalg.norm(d), before / np.linalg.norm(before), atol=1e-9)
    stems = organ_class(plants) == "stem"
    cols = [*P0, *P1, "radius_m"]
    np.testing.assert_array_equal(wrapped.loc[stems, cols].to_numpy(), plants.loc[stems, cols].to_numpy())


def test_wrapped_field_mesh_has_the_tube_areas(tmp_path):
    """A built field lays its sheaths as its ``sheaths`` says; the mesh's areas are the new 2πrL."""
    rods = build(Field(n_plants=4, seed=2, sheaths="rods"), cache_dir=tmp_path)
    wrapped = build(Field(n_plants=4, seed=2), cache_dir=tmp_path)
    np.testing.assert_array_equal(wrapped.segments.to_numpy(), wrap_sheaths(rods.segments).to_numpy())
    exp = expected_area(wrapped.segments)
    got = wrapped.mesh.area_per_segment().reindex(exp.index).fillna(0.0)
    np.testing.assert_allclose(got, exp, rtol=1e-9, atol=1e-15)
    sheath = organ_class(wrapped.segments) == "sheath"
    seg = wrapped.segments[sheath]
    np.testing.assert_allclose(exp[seg["segment_id"]], 2 * np.pi * seg["radius_m"] * seg["length_m"], rtol=1e-12)
    assert shoot_mesh(rods.segments).n_faces == wrapped.mesh.n_faces


def test_the_knob_reaches_the_field_and_runs_stored_before_it_had_rods():
    """``sheaths`` is a model setting: the default field wraps them, the paper preset keeps
    CPlantBox's rods, ``--sheaths`` chooses, and a run stored before the setting existed (rods)
    differs from today's default by exactly that."""
    from lightfit.cli.options import ModelOptions, changed_settings, resolve
    from lightfit.replication import ReplicationConfig

    assert ReplicationConfig().field().sheaths == "wrapped"
    assert ReplicationConfig.paper().field().sheaths == "rods" and ReplicationConfig.paper().preset == "paper"
    assert ReplicationConfig(sheaths="rods").preset is None  # neither preset's whole setup
    default = resolve(ModelOptions(quick=True))
    assert default.sheaths == "wrapped" and resolve(ModelOptions(quick=True, preset="paper")).sheaths == "rods"
    chosen = resolve(ModelOptions(quick=True, sheaths="rods"))
    assert chosen.replication_config().field().sheaths == "rods"
    with pytest.raises(InputError, match="sheaths"):
        resolve(ModelOptions(quick=True, sheaths="tubes"))
    stored_before = {k: v for k, v in default.as_dict().items() if k != "sheaths"}
    assert changed_settings(stored_before, default) == ["sheaths: 'rods' → 'wrapped'"]
    assert changed_settings(stored_before, chosen) == []


def test_cli_refuses_an_unknown_layout_before_growing():
    from typer.testing import CliRunner

    from lightfit.cli import app

    for cmd in (["replicate", "--quick"], ["field", "--n-plants", "1"]):
        r = CliRunner().invoke(app, [*cmd, "--sheaths", "tubes"])
        assert r.exit_code == 2 and "sheaths" in r.output and "wrapped" in r.output, r.output
        assert "growing" not in r.output


def test_results_rebuild_their_sheaths_and_older_files_had_rods(tmp_path):
    from lightfit.dataset.results import field_of, open_results
    from lightfit.dataset.synthetic import synthetic_results

    ds = synthetic_results(Field(n_plants=1, seed=4), ["2016-04-20T11:00"], cache_dir=tmp_path)
    assert ds.attrs["sheaths"] == "wrapped" and field_of(open_results(ds)).sheaths == "wrapped"
    del ds.attrs["sheaths"]  # written before the setting: CPlantBox's rods
    assert field_of(open_results(ds)).sheaths == "rods"
    ds.attrs["sheaths"] = "tubes"
    with pytest.raises(InputError, match="tubes"):
        field_of(open_results(ds))


def test_young_leaves_without_blades_are_wrapped_too():
    """Early in the season (6 March) a leaf may be all sheath: it is wrapped like the others."""
    young = grow_plant(GrowthConfig(target_date="2016-03-06"), plant_seed(7, 3, 4), plant_id=5)
    organ = pd.Series(organ_class(young), index=young.index)
    leaves = [(leaf, organ[leaf.index].to_numpy()) for leaf, _ in _leaves(young)]
    assert any(not (o == "blade").any() for _, o in leaves)  # the case this test is for
    wrapped = wrap_sheaths(young)
    a, b = _stem_chain(young)
    for leaf, o in leaves:
        s = wrapped.loc[leaf.index[o == "sheath"]]
        assert _nearest_on_chain(s[P1].to_numpy(), a, b)[1].max() < 1e-12
        assert (s["radius_m"] > young.loc[organ == "stem", "radius_m"].max()).all()
    assert np.isfinite(wrapped[[*P0, *P1, "radius_m", "length_m"]].to_numpy()).all()


def _three_sheath_plant() -> pd.DataFrame:
    """A made-up plant, sheaths wrapped: a vertical stem (organ 9, radius 1 mm) and three one-sheath
    leaves (organs 3 and 1 at 2 cm, organ 2 at the base; wall 0.2 mm) whose rods start off the axis,
    as CPlantBox's do (wrapping moves them)."""
    rows = [(9, "stem", 0.0), (3, "leaf", 0.02), (1, "leaf", 0.02), (2, "leaf", 0.0)]  # organ id, organ, node (m)
    recs = []
    for i, (oid, kind, z) in enumerate(rows):
        top = 0.1 if kind == "stem" else z + 0.05
        recs.append(
            {
                "plant_id": 1,
                "segment_index": i,
                "segment_id": 1_000_000 + i,
                "organ_type": kind,
                "organ_id": oid,
                "x0": 0.01 * (kind == "leaf"),
                "y0": 0.0,
                "z0": z,
                "x1": 0.03 * (kind == "leaf"),
                "y1": 0.0,
                "z1": top,
                "length_m": 0.1 if kind == "stem" else float(np.hypot(0.02, 0.05)),
                "radius_m": 1e-3 if kind == "stem" else 2e-4,
                "blade_width_m": 0.0,
                "blade_area_m2": 0.0,
                "creation_time_d": 1.0,
                "bx": 0.0,
                "by": 0.0,
                "bz": 1.0,
            }
        )
    return wrap_sheaths(pd.DataFrame(recs))


def test_ties_and_order_of_organ_ids_do_not_change_the_nesting():
    """Leaves are ranked by their node on the stem whatever CPlantBox numbered them; two leaves at
    one node are ranked by organ id (the made-up plant of _three_sheath_plant)."""
    wrapped = _three_sheath_plant().set_index("organ_id")
    # By node: organ 2 (z = 0) is the oldest, then organs 1 and 3 at z = 0.02 in organ-id order.
    np.testing.assert_allclose(wrapped.loc[[2, 1, 3], "radius_m"], [1e-3 + 3 * 2e-4, 1e-3 + 2 * 2e-4, 1e-3 + 2e-4])
    np.testing.assert_allclose(wrapped.loc[[1, 2, 3], ["x0", "x1"]].to_numpy(), 0.0, atol=1e-15)  # on the stem axis


def test_nested_prisms_stay_inside_one_another():
    """The wrapped tubes' hexagons: the culm inside the youngest sheath, each sheath inside the next
    older one, for every vertex where their spans overlap (the made-up plant of _three_sheath_plant:
    radii 1.0, 1.2, 1.4, 1.6 mm). Reference: a point is inside a convex prism when it lies behind
    each face's plane. A hexagon of circumradius R holds another of R' turned against it only if R' ≤
    R·cos 30°, and 1.4 / 1.6 = 0.875 is more: prisms turned organ by organ pushed the middle sheath's
    edges through the oldest one's faces. One turn per plant keeps each nest's hexagons aligned."""
    from lightfit.plant.mesh import shoot_mesh

    wrapped = _three_sheath_plant()
    mesh = shoot_mesh(wrapped)
    by_segment = wrapped.set_index("segment_id")
    normals = mesh.normals()
    checked = 0
    for outer, o in by_segment.iterrows():
        for inner, i in by_segment.iterrows():
            if i["radius_m"] >= o["radius_m"]:
                continue
            faces = mesh.face_segment == outer
            p, n = mesh.vertices[mesh.faces[faces, 0]], normals[faces]
            v = mesh.vertices[np.unique(mesh.faces[mesh.face_segment == inner])]
            v = v[(v[:, 2] >= o["z0"]) & (v[:, 2] <= o["z1"])]
            # behind every face plane of the outer prism (outward normals)
            assert (np.einsum("vk,fk->vf", v, n) - np.einsum("fk,fk->f", p, n) <= 1e-12).all(), (inner, outer)
            checked += len(v)
    assert checked > 0


def test_grown_plants_wrapped_prisms_stay_inside_one_another(wrapped):
    """On two grown plants' wrapped sheaths (stem radius 1.5 mm, walls 0.3 mm: tubes up to 3 mm),
    every vertex of a thinner prism of the same plant (stem or younger sheath) lying within a sheath
    segment's span is behind each face plane of that sheath's prism (outward normals), as for
    _three_sheath_plant above but on CPlantBox's plants, whose deeper nests (2.1 mm inside 2.4 mm:
    0.875 > cos 30°) need their hexagons aligned. A mutation audit: prisms turned segment by segment
    (by segment id, not plant id) survived the made-up plant, whose four ids happened to turn its
    hexagons within the margin; here they push through by 0.1 mm (and 0.06 mm turned organ by organ)."""
    mesh = shoot_mesh(wrapped)
    normals, tube = mesh.normals(), ~mesh.face_is_blade
    checked = 0
    for _, plant in wrapped.groupby("plant_id"):
        organ = organ_class(plant)
        prisms, sheaths = plant[organ != "blade"], plant[organ == "sheath"]
        for _, s in sheaths.iterrows():
            a, b = s[P0].to_numpy(float), s[P1].to_numpy(float)
            length = np.linalg.norm(b - a)
            faces = mesh.face_segment == s["segment_id"]
            p, n = mesh.vertices[mesh.faces[faces, 0]], normals[faces]
            thinner = prisms.loc[prisms["radius_m"] < s["radius_m"], "segment_id"].to_numpy()
            v = mesh.vertices[np.unique(mesh.faces[np.isin(mesh.face_segment, thinner) & tube])]
            h = (v - a) @ ((b - a) / length)
            v = v[(h > 1e-6) & (h < length - 1e-6)]
            assert (v @ n.T - np.einsum("fk,fk->f", p, n) < 0).all(), s["segment_id"]
            checked += len(v)
    assert checked > 500


def _made_up(segments):
    """A segment table from ``(plant, organ id, kind, start, end, radius, branching)`` rows (m; kind
    "stem" or "leaf", leaves without blade width: all sheath)."""
    recs = []
    for i, (plant, oid, kind, p0, p1, r, branch) in enumerate(segments):
        p0, p1 = np.asarray(p0, float), np.asarray(p1, float)
        recs.append(
            {
                "plant_id": plant,
                "segment_index": i,
                "segment_id": plant * 1_000_000 + i,
                "organ_type": kind,
                "organ_id": oid,
                **dict(zip(P0, p0)),
                **dict(zip(P1, p1)),
                "length_m": float(np.linalg.norm(p1 - p0)),
                "radius_m": r,
                "blade_width_m": 0.0,
                "blade_area_m2": 0.0,
                "creation_time_d": 1.0,
                **dict(zip(["bx", "by", "bz"], branch)),
            }
        )
    return pd.DataFrame(recs)


def test_a_sheath_encloses_every_younger_sheath_starting_within_its_whole_length():
    """A vertical culm (radius 1 mm) and four sheaths (wall 0.2 mm) by node height: A from 0 m, two
    segments of 5 cm (to 0.10 m); B 0.01–0.02; C 0.07–0.17; D 0.08–0.10. By hand, youngest first:
    D = 1 + 0.2 = 1.2 mm; C encloses D: 1.4 mm; B encloses none (C and D start above its top):
    1.2 mm; A encloses B, C (starting at 0.07 m, within its second segment) and D: 1.4 + 0.2 = 1.6 mm,
    not the 1.4 mm of its next-younger sheath B alone."""
    up = (0.0, 0.0, 1.0)
    rod = lambda z0, z1: ((0.005, 0.0, z0), (0.005, 0.0, z1))  # noqa: E731  CPlantBox's rod, off the axis
    rows = [(1, 9, "stem", (0, 0, 0.0), (0, 0, 0.15), 1e-3, up), (1, 9, "stem", (0, 0, 0.15), (0, 0, 0.3), 1e-3, up)]
    rows += [
        (1, 1, "leaf", *rod(0.0, 0.05), 2e-4, up),
        (1, 1, "leaf", *rod(0.05, 0.10), 2e-4, up),
        (1, 2, "leaf", *rod(0.01, 0.02), 2e-4, up),
        (1, 3, "leaf", *rod(0.07, 0.17), 2e-4, up),
        (1, 4, "leaf", *rod(0.08, 0.10), 2e-4, up),
    ]
    wrapped = wrap_sheaths(_made_up(rows))
    radius = wrapped[wrapped["organ_type"] == "leaf"].groupby("organ_id")["radius_m"]
    assert (radius.nunique() == 1).all()
    np.testing.assert_allclose(radius.first().loc[[1, 2, 3, 4]], [1.6e-3, 1.2e-3, 1.4e-3, 1.2e-3], rtol=1e-12)


def test_a_leaf_wraps_the_nearest_stem_or_without_one_goes_along_its_branching_direction():
    """Plant 1 has two culms, at x = 0 (organ 1, radius 1 mm) and x = 5 cm (organ 2, 1.5 mm); a leaf
    whose node is 2 mm from the second is wrapped on it, from the node's height with its length.
    Plant 2 has no stem: its two-segment sheath goes straight from its node along the branching
    direction (0, 0.6, 0.8), not along CPlantBox's tilted rod (module doc); its radius is its wall."""
    up, b = (0.0, 0.0, 1.0), np.array([0.0, 0.6, 0.8])
    rows = [
        (1, 1, "stem", (0, 0, 0.0), (0, 0, 0.2), 1e-3, up),
        (1, 2, "stem", (0.05, 0, 0.0), (0.05, 0, 0.2), 1.5e-3, up),
        (1, 3, "leaf", (0.052, 0, 0.03), (0.06, 0, 0.08), 2e-4, up),
        (2, 1, "leaf", (0.3, 0, 0.01), (0.32, 0, 0.05), 3e-4, tuple(b)),
        (2, 1, "leaf", (0.32, 0, 0.05), (0.34, 0, 0.09), 3e-4, tuple(b)),
    ]
    table = _made_up(rows)
    wrapped = wrap_sheaths(table)
    leaf = wrapped.iloc[2]
    L = np.hypot(0.008, 0.05)
    np.testing.assert_allclose(leaf[P0].to_numpy(float), [0.05, 0.0, 0.03], atol=1e-15)
    np.testing.assert_allclose(leaf[P1].to_numpy(float), [0.05, 0.0, 0.03 + L], atol=1e-15)
    assert leaf["radius_m"] == pytest.approx(1.5e-3 + 2e-4, rel=1e-12)
    lone = wrapped.iloc[3:]
    L = np.hypot(0.02, 0.04)
    node = np.array([0.3, 0.0, 0.01])
    np.testing.assert_allclose(lone[P0].to_numpy(float), [node, node + L * b], atol=1e-15)
    np.testing.assert_allclose(lone[P1].to_numpy(float), [node + L * b, node + 2 * L * b], atol=1e-15)
    np.testing.assert_allclose(lone["length_m"], [L, L], rtol=1e-12)
    np.testing.assert_allclose(lone["radius_m"], [3e-4, 3e-4], rtol=1e-12)
