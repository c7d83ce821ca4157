r"""Sample points on mesh segments, in Dr.Jit: where a :class:`~lightfit.light.estimator.SegmentEstimator` measures.

A point of segment s from coordinates :math:`(u_0, u_1, u_2) \in [0, 1)^3`: :math:`u_0` picks
one of the segment's faces with probability proportional to its area (the inverse of the
cumulative face areas, faces sorted by segment), :math:`(u_1, u_2)` a uniform point on that
triangle (Turk 1990; Pharr, Jakob & Humphreys, *PBR* 4th ed., §6.5.1):

.. math::

    x = (1 - \sqrt{u_1})\,v_0 + u_2\sqrt{u_1}\,v_1 + \bigl(1 - (1 - \sqrt{u_1}) - u_2\sqrt{u_1}\bigr)\,v_2

Everything runs in float64 inside Dr.Jit kernels, one lane per point, without the
per-point temporaries a numpy version allocates (≈ 400 bytes per point; on a machine with slow
page faults they cost seconds for a few million points). On the CPU (LLVM) Dr.Jit does not fuse
multiplies and adds, so the arithmetic is IEEE-identical to the numpy version it replaced
(tested bitwise against a numpy transcription in ``tests/test_light_face_sampling.py``). The
CUDA backend may contract them into fused multiply-adds: points then differ in the last bit, and
very rarely a point on the border of two faces changes face.

The face search runs within each segment's own faces (a binary search of as many steps as the
largest segment needs), so the compiled kernel depends on the mesh only through that count and
is reused, and cached on disk, across scenes.
"""

from __future__ import annotations

import numpy as np

from lightfit.errors import InputError
from lightfit.light.backend import owned


class FaceSampler:
    """Area-uniform points on the segments of one mesh (Dr.Jit arrays, built once per scene).

    Memory: ≈ 110 bytes per face in Dr.Jit (corners, normals and cumulative areas in float64, the
    sort order and blade flags; on a GPU, device memory) and 24 in numpy, for the scene's life.

    Args:
        mi: the Mitsuba module (variant set).
        mesh: the shoot mesh (``lightfit.plant.Mesh``), faces labelled by ``face_segment``.
    """

    def __init__(self, mi, mesh):
        self.mi = mi
        order = np.argsort(mesh.face_segment, kind="stable")
        self._fseg = mesh.face_segment[order]
        area = mesh.face_areas()[order]
        self._cum_np = np.cumsum(area)
        self._cum0_np = self._cum_np - area
        # Binary-search steps for the segment with the most faces (n faces: bit length of n − 1).
        self._search_steps = int(np.unique(self._fseg, return_counts=True)[1].max() - 1).bit_length()
        F64 = mi.Float64
        self._cum = owned(self._cum_np, F64)
        self._order = owned(order, mi.UInt32)
        self._corners = [[owned(mesh.vertices[mesh.faces[:, i], c], F64) for c in range(3)] for i in range(3)]
        normals = mesh.normals()
        self._normal = [owned(normals[:, c], F64) for c in range(3)]
        self._blade = owned(mesh.face_is_blade, mi.Bool)

    def ranges(self, seg: np.ndarray):
        """Per requested segment: ``(area_m2, ranges)``, its one-sided area (numpy, m²) and the Dr.Jit
        arrays :meth:`place` reads (first and last face in the sorted order, the cumulative area
        before its first face, its area)."""
        start = np.searchsorted(self._fseg, seg, "left")
        end = np.searchsorted(self._fseg, seg, "right")
        if (start == end).any():
            raise InputError(
                f"segment id(s) {seg[start == end][:5].tolist()} have no faces in the mesh",
                parameter="segment_ids",
                expected="ids of stem or leaf segments with non-zero length",
            )
        seg_area = self._cum_np[end - 1] - self._cum0_np[start]
        mi = self.mi
        first, last = owned(start, mi.UInt32), owned(end - 1, mi.UInt32)
        return seg_area, (first, last, owned(self._cum0_np[start], mi.Float64), owned(seg_area, mi.Float64))

    def face(self, ranges, si, u0):
        """Index of the face (original mesh order) chosen by ``u0`` (Float64) in segment ``si`` (UInt32)."""
        import drjit as dr

        mi = self.mi
        first, last, cum0, area = ranges
        target = dr.gather(type(u0), cum0, si) + u0 * dr.gather(type(u0), area, si)
        # The first of the segment's faces whose cumulative area exceeds the target, else its last
        # (numpy's searchsorted "right" clipped to the segment: rounding at its ends).
        lo, hi = dr.gather(mi.UInt32, first, si), dr.gather(mi.UInt32, last, si)
        for _ in range(self._search_steps):
            mid = (lo + hi) >> 1
            below = dr.gather(type(u0), self._cum, mid) <= target
            lo, hi = dr.select(below, dr.minimum(mid + 1, hi), lo), dr.select(below, hi, mid)
        return dr.gather(mi.UInt32, self._order, lo)

    def is_blade(self, face):
        """Whether each face (UInt32 indices) is a leaf-blade face."""
        import drjit as dr

        return dr.gather(self.mi.Bool, self._blade, face)

    def place(self, ranges, si, u):
        """Points ``x`` and unit normals ``n`` (three Float64 arrays each, m) and the blade flag of
        the faces chosen by ``u = (u0, u1, u2)`` (Float64 in [0, 1)) in segments ``si``."""
        import drjit as dr

        F64 = type(u[0])
        face = self.face(ranges, si, u[0])
        su = dr.sqrt(u[1])
        b0 = 1.0 - su
        b1 = u[2] * su
        b2 = 1.0 - b0 - b1
        v0, v1, v2 = ([dr.gather(F64, c, face) for c in corner] for corner in self._corners)
        x = [v0[c] * b0 + v1[c] * b1 + v2[c] * b2 for c in range(3)]
        n = [dr.gather(F64, c, face) for c in self._normal]
        return x, n, self.is_blade(face)
