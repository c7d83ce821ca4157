"""Sample points on segments (lightfit.light.face_sampling, in Dr.Jit) against numpy and geometry.

References: a numpy transcription of the area-uniform placement (inverse CDF over the faces'
cumulative areas, the √u₁ warp on the triangle) and of the estimator's evaluation layout (every
point's front side, then the back side of each point on a blade face) and periodic wrapping — the
implementation before the set-up moved into Dr.Jit — which the Dr.Jit version must reproduce bit
for bit on the CPU (LLVM: no fused multiply-adds; CUDA may fuse them, so there only to rounding);
and geometry: every point lies on a face of its own segment, faces are chosen in proportion to
their area (χ² test), and barycentric coordinates are uniform on the triangle (mean at the
centroid).
"""

from __future__ import annotations

import numpy as np
import pytest

from lightfit.errors import InputError
from lightfit.light.backend import mitsuba
from lightfit.light.estimator import SegmentEstimator
from lightfit.light.face_sampling import FaceSampler
from lightfit.light.scene import FieldScene, Optics
from lightfit.plant.mesh import Mesh
from lightfit.plant.periodic import PeriodicCell


def _same(got, ref):
    """Bitwise on the CPU; to rounding where the backend may fuse multiply-adds (CUDA)."""
    if mitsuba().variant().startswith("llvm"):
        return np.array_equal(got, ref)
    return np.allclose(got, ref, rtol=1e-12, atol=1e-15)


def _numpy_place(mesh: Mesh, seg: np.ndarray, pos: np.ndarray):
    """The numpy reference: ``pos`` (S, K, 3) → points, normals, blade flags, faces."""
    order = np.argsort(mesh.face_segment, kind="stable")
    fseg = mesh.face_segment[order]
    start, end = np.searchsorted(fseg, seg, "left"), np.searchsorted(fseg, seg, "right")
    area = mesh.face_areas()[order]
    cum = np.cumsum(area)
    cum0 = cum - area
    seg_area = cum[end - 1] - cum0[start]
    target = cum0[start][:, None] + pos[..., 0] * seg_area[:, None]
    idx = np.clip(np.searchsorted(cum, target, "right"), start[:, None], (end - 1)[:, None])
    face = order[idx]
    v0, v1, v2 = (mesh.vertices[mesh.faces[face, i]] for i in range(3))
    su = np.sqrt(pos[..., 1])
    b0, b1 = 1 - su, pos[..., 2] * su
    x = v0 * b0[..., None] + v1 * b1[..., None] + v2 * (1 - b0 - b1)[..., None]
    return x, mesh.normals()[face], mesh.face_is_blade[face], face, seg_area


def _mesh(seed: int = 0) -> Mesh:
    """Three segments of random triangles of very unequal areas (one with a zero-area face)."""
    rng = np.random.default_rng(seed)
    n_faces = 60
    vertices = rng.normal(size=(3 * n_faces, 3)) * rng.uniform(0.001, 0.2, size=(3 * n_faces, 1))
    vertices[3:6] = vertices[3]  # a degenerate face
    faces = np.arange(3 * n_faces).reshape(n_faces, 3)
    segment = rng.permutation(np.repeat([7, 3, 11], n_faces // 3))  # faces of a segment not contiguous
    return Mesh(vertices, faces, segment, segment == 3)


def _place(mesh: Mesh, seg: np.ndarray, pos: np.ndarray):
    mi = mitsuba()
    pl = FaceSampler(mi, mesh)
    area, ranges = pl.ranges(seg)
    S, K = pos.shape[:2]
    si = mi.UInt32(np.repeat(np.arange(S), K).astype(np.uint32))
    u = [mi.Float64(np.ascontiguousarray(pos[..., d].reshape(-1))) for d in range(3)]
    x, n, blade = pl.place(ranges, si, u)
    face = pl.face(ranges, si, u[0])
    to_np = lambda cols: np.stack([np.asarray(c) for c in cols], -1).reshape(S, K, 3)  # noqa: E731
    return to_np(x), to_np(n), np.asarray(blade).reshape(S, K), np.asarray(face).reshape(S, K), area


def test_sampling_is_bitwise_the_numpy_reference():
    mesh = _mesh()
    seg = np.array([3, 7, 11])
    pos = np.random.default_rng(1).random((3, 500, 3))
    pos[0, :3, 0] = [0.0, 1 - 2**-53, 0.5]  # both ends of the inverse CDF
    got, ref = _place(mesh, seg, pos), _numpy_place(mesh, seg, pos)
    for g, r in zip(got, (ref[0], ref[1], ref[2].reshape(3, 500), ref[3], ref[4])):
        assert _same(g, r)


def test_points_lie_on_faces_of_their_segment_with_area_weights():
    mesh = _mesh(2)
    seg = np.array([3, 7, 11])
    K = 20_000
    pos = np.random.default_rng(3).random((3, K, 3))
    x, n, blade, face, area = _place(mesh, seg, pos)
    areas = mesh.face_areas()
    for s, sid in enumerate(seg):
        assert (mesh.face_segment[face[s]] == sid).all()
        assert area[s] == pytest.approx(areas[mesh.face_segment == sid].sum(), rel=1e-12)
        assert (blade[s] == (sid == 3)).all()
        # χ² over the segment's faces with non-negligible expected counts: area-proportional choice.
        own = np.flatnonzero(mesh.face_segment == sid)
        expected = K * areas[own] / areas[own].sum()
        counts = np.bincount(np.searchsorted(own, face[s]), minlength=len(own))
        keep = expected > 5
        chi2 = ((counts[keep] - expected[keep]) ** 2 / expected[keep]).sum()
        dof = keep.sum() - 1
        assert chi2 < dof + 5 * np.sqrt(2 * dof)
        assert counts[~(areas[own] > 0)].sum() == 0  # the zero-area face is never chosen
    # On the plane of its face, inside the triangle; the mean point of one face is its centroid.
    v = mesh.vertices[mesh.faces[face]]  # (S, K, 3, 3)
    e1, e2, d = v[..., 1, :] - v[..., 0, :], v[..., 2, :] - v[..., 0, :], x - v[..., 0, :]
    assert np.abs(np.einsum("skc,skc->sk", d, n)).max() < 1e-12
    big = np.argmax(areas)
    on = face == big
    m = x[on].mean(0)
    centroid = mesh.vertices[mesh.faces[big]].mean(0)
    spread = np.linalg.norm(np.cross(e1[on][0], e2[on][0])) ** 0.5
    assert np.linalg.norm(m - centroid) < 4 * spread / np.sqrt(on.sum())


def test_unknown_segment_is_an_input_error():
    mi = mitsuba()
    with pytest.raises(InputError, match="segment id"):
        FaceSampler(mi, _mesh()).ranges(np.array([3, 99]))


def test_wrap64_is_the_cells_numpy_wrap():
    """Bitwise on points off the cell's sides; a point exactly on a side may land on either
    (numpy's matrix product may round the cell-frame coordinate differently): it must then
    still be moved by a whole lattice vector onto the closed cell."""
    mi = mitsuba()
    cell = PeriodicCell(along_m=0.31, across_m=0.52, row_direction_deg=37.0, center_xy=(0.4, -1.3))
    tracer = FieldScene(_mesh(), Optics.preset("paper"), cell=cell).tracer
    rng = np.random.default_rng(4)

    def wrap64(p):
        got = tracer.wrap64([mi.Float64(np.ascontiguousarray(p[:, i])) for i in range(3)])
        return np.stack([np.asarray(c) for c in got], -1)

    wide = rng.uniform(-3, 3, (20_000, 3))
    assert _same(wrap64(wide), cell.wrap(wide))
    ab = rng.uniform(-0.5, 0.5, (4_000, 2)) * cell.size_m
    ab[:2000, 0] = np.where(rng.random(2000) < 0.5, -0.5, 0.5) * cell.size_m[0]
    ab[2000:, 1] = np.where(rng.random(2000) < 0.5, -0.5, 0.5) * cell.size_m[1]
    edges = np.zeros((4_000, 3))
    edges[:, :2] = cell.to_world(ab)
    got = wrap64(edges)
    local = cell.to_local(got) / cell.size_m
    assert (np.abs(local) <= 0.5 + 1e-12).all()
    moved = cell.to_local(got) - cell.to_local(edges)
    assert np.abs(moved / cell.size_m - np.round(moved / cell.size_m)).max() < 1e-9


def _estimator_layout_reference(est: SegmentEstimator, mesh: Mesh, epsilon_m: float):
    """The numpy set-up the estimator had: points, front/back evaluations, origins (float32)."""
    S, K, M = len(est.segment_id), est.samples, est.per_replicate
    shift = est._shift[..., [est._column_of[d] for d in range(3)]]  # (S, R, 3)
    j = np.arange(M) + est.first
    pos = np.mod(shift[:, :, None, :] + j[None, None, :, None] * est._alpha[:3], 1.0).reshape(S, K, 3)
    x, n, blade, _, area = _numpy_place(mesh, est.segment_id, pos)
    x, n, blade = x.reshape(-1, 3), n.reshape(-1, 3), blade.reshape(-1)
    if est.fs.cell is not None:
        x = est.fs.cell.wrap(x)
    n_ev = np.concatenate([n, -n[blade]])
    valid = (n_ev != 0).any(axis=1)
    n_ev[~valid] = [0.0, 0.0, 1.0]
    o = np.concatenate([x, x[blade]]) + epsilon_m * n_ev
    return np.flatnonzero(blade), o.astype(np.float32), n_ev.astype(np.float32), valid, area


@pytest.mark.parametrize("periodic", [False, True])
def test_estimator_layout_is_the_numpy_set_up(periodic):
    """Mixed blade/stem segments, a single-face segment, zero-area faces, K not a multiple of
    the replicates, a continued sequence (``first``), periodic wrapping of overhanging faces."""
    mesh = _mesh(5)
    mesh.vertices[:, 2] = np.abs(mesh.vertices[:, 2])  # above the soil
    blade = mesh.face_is_blade.copy()
    blade[mesh.face_segment == 7] = np.arange((mesh.face_segment == 7).sum()) % 2 == 0  # mixed
    seg = mesh.face_segment.copy()
    seg[np.flatnonzero(seg == 11)[0]] = 5  # a segment of one face
    mesh = Mesh(mesh.vertices, mesh.faces, seg, blade)
    cell = PeriodicCell(along_m=0.3, across_m=0.25, row_direction_deg=20.0) if periodic else None
    fs = FieldScene(mesh, Optics.preset("paper"), cell=cell)
    eps = 1e-5
    for samples, first in ((10, 0), (16, 3)):
        est = SegmentEstimator(fs, np.array([3, 5, 7, 11]), samples=samples, bounces=1, seed=2, first=first)
        back_of, o, n, valid, area = _estimator_layout_reference(est, mesh, eps)
        assert np.array_equal(est._back_of, back_of)
        assert est.n_evaluations == len(est.segment_id) * est.samples + len(back_of)
        assert np.array_equal(est.is_blade, np.isin(np.arange(4), back_of // est.samples))
        assert np.array_equal(est.area_m2, area)
        o_dr, n_dr, _, _, _, valid_dr = est._arrays()
        assert _same(np.stack([np.asarray(c) for c in o_dr], -1), o)
        assert _same(np.stack([np.asarray(c) for c in n_dr], -1), n)
        assert np.array_equal(np.asarray(valid_dr), valid)


def test_first_beyond_float32_exact_indices_is_an_input_error():
    fs = FieldScene(_mesh(), Optics.preset("paper"))
    with pytest.raises(InputError, match="first"):
        SegmentEstimator(fs, np.array([3]), samples=16, first=2**24)


@pytest.mark.parametrize("first", [2**20, 2**24 - 8])
def test_first_directions_stay_uniform_far_along_the_sequence(first):
    """The first direction's coordinates {Δ + j·α} (front dims 3–4, a blade's back 11–12) at large
    j, over 100 seeds × 3 segments × 4 replicates × 4 points: uniform on [0, 1) by KS (p > 10⁻⁴),
    with thousands of distinct values. In float32 j·α rounded away the shift's bits: at
    first = 2²⁰ each coordinate took 16 values (its mean 0.469), at 2²⁴ − 8 one (0: every path
    started in the same direction)."""
    from scipy.stats import kstest

    fs = FieldScene(_mesh(), Optics.preset("paper"))
    cols = [[], []]
    for seed in range(100):
        est = SegmentEstimator(fs, np.array([3, 7, 11]), samples=16, bounces=0, seed=seed, first=first)
        u = est._arrays()[4]
        for c in range(2):
            cols[c].append(np.asarray(u[c]))
    for c in cols:
        v = np.concatenate(c)
        assert len(np.unique(v)) > 0.9 * v.size
        assert kstest(v, "uniform").pvalue > 1e-4
