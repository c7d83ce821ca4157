"""Sample points on segments (lightfit.light.placement, in Dr.Jit) against numpy and geometry.

References: a numpy transcription of the area-uniform placement (inverse CDF over the faces'
cumulative areas, the √u₁ warp on the triangle; the estimator's implementation before it moved
into Dr.Jit), which the Dr.Jit version must reproduce bit for bit; and geometry: every point lies
on a face of its own segment, faces are chosen in proportion to their area (χ² test), and
barycentric coordinates are uniform on the triangle (mean at the centroid).
"""

from __future__ import annotations

import numpy as np
import pytest

from lightfit.errors import InputError
from lightfit.light.backend import mitsuba
from lightfit.light.placement import FacePlacement
from lightfit.plant.mesh import Mesh


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
    pl = FacePlacement(mi, mesh)
    area, ranges = pl.ranges(seg)
    S, K = pos.shape[:2]
    si = mi.UInt32(np.repeat(np.arange(S), K).astype(np.uint32))
    u = [mi.Float64(np.ascontiguousarray(pos[..., d].reshape(-1))) for d in range(3)]
    x, n, blade = pl.place(ranges, si, u)
    face = pl.face(ranges, si, u[0])
    to_np = lambda cols: np.stack([np.asarray(c) for c in cols], -1).reshape(S, K, 3)  # noqa: E731
    return to_np(x), to_np(n), np.asarray(blade).reshape(S, K), np.asarray(face).reshape(S, K), area


def test_placement_is_bitwise_the_numpy_reference():
    mesh = _mesh()
    seg = np.array([3, 7, 11])
    pos = np.random.default_rng(1).random((3, 500, 3))
    pos[0, :3, 0] = [0.0, 1 - 2**-53, 0.5]  # both ends of the inverse CDF
    got, ref = _place(mesh, seg, pos), _numpy_place(mesh, seg, pos)
    for g, r in zip(got, (ref[0], ref[1], ref[2].reshape(3, 500), ref[3], ref[4])):
        assert np.array_equal(g, r)


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
        FacePlacement(mi, _mesh()).ranges(np.array([3, 99]))
