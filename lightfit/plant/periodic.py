r"""The periodic cell: the measurement area as one cell of an infinite, doubly periodic field.

A cell is a rectangle in the horizontal plane, aligned with the rows: ``along_m`` along the rows
(N plants × plant spacing) by ``across_m`` across them (N rows × row spacing), centred on
``center_xy``. The field is the cell's contents repeated by the lattice vectors
:math:`i\,A\,\hat e_a + j\,B\,\hat e_b` (i, j integers), so plant spacing and row spacing are
preserved across the seams. The rows may run in any compass direction: the cell is a rectangle
in the row-aligned frame (ê_a along the rows, ê_b 90° counter-clockwise from it, as in
:meth:`lightfit.plant.Field.plants`), and a rotated rectangle tiles the plane as well as an
axis-aligned one, so nothing is gained by restricting the row direction.

This module is pure geometry (numpy): local coordinates, wrapping points into the cell and the
periodic images of a mesh. Ray transport through the cell lives in
:mod:`lightfit.light.periodic`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from lightfit.defaults import DEFAULT_ROW_DIRECTION_DEG
from lightfit.errors import InputError
from lightfit.plant.mesh import Mesh

#: Triangles within this distance (m) of the cell are kept as images: a ray accepted inside the
#: cell up to float32 round-off must still find the triangle it touches.
IMAGE_MARGIN_M = 1e-6


def compass_vector(azimuth_deg: float) -> np.ndarray:
    """The horizontal unit vector (x = east, y = north) of a compass azimuth in degrees (clockwise
    from north, pvlib's convention): the rows' direction and the sun's bearing."""
    az = math.radians(azimuth_deg)
    return np.array([math.sin(az), math.cos(az)])


def row_axes(row_direction_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """Unit vectors (x = east, y = north) along rows of compass azimuth ``row_direction_deg``
    (degrees) and across them, 90° counter-clockwise: a field's and its cell's frame."""
    along = compass_vector(row_direction_deg)
    return along, np.array([-along[1], along[0]])


@dataclass(frozen=True)
class PeriodicCell:
    """One cell of a rectangular lattice of identical copies of the field.

    Attributes:
        along_m: cell length along the rows, m (lattice period along ê_a).
        across_m: cell width across the rows, m (lattice period along ê_b).
        row_direction_deg: compass azimuth of the rows (ê_a), degrees (90 = east–west).
        center_xy: cell centre (x east, y north), m.
    """

    along_m: float
    across_m: float
    row_direction_deg: float = DEFAULT_ROW_DIRECTION_DEG
    center_xy: tuple[float, float] = (0.0, 0.0)

    def __post_init__(self):
        for name in ("along_m", "across_m"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float, np.floating)) and math.isfinite(v) and v > 0):
                raise InputError(f"{name}={v!r}", parameter=name, expected="a positive cell size in metres")
        if not math.isfinite(self.row_direction_deg):
            raise InputError(
                f"row_direction_deg={self.row_direction_deg!r}", parameter="row_direction_deg", expected="degrees"
            )

    @property
    def axes(self) -> tuple[np.ndarray, np.ndarray]:
        """Unit vectors (x, y) of the cell frame: ê_a along the rows, ê_b across them."""
        return row_axes(self.row_direction_deg)

    @property
    def size_m(self) -> np.ndarray:
        """Periods (A, B) = (along_m, across_m), m."""
        return np.array([float(self.along_m), float(self.across_m)])

    @property
    def bounds_m(self) -> tuple[tuple[float, float], tuple[float, float]]:
        """Cell bounds in the row-aligned frame, m: ((−A/2, A/2) along, (−B/2, B/2) across)."""
        a, b = self.size_m / 2
        return (-a, a), (-b, b)

    @property
    def corners_xy(self) -> np.ndarray:
        """The four corners (x, y) in metres, counter-clockwise in the cell frame."""
        (a0, a1), (b0, b1) = self.bounds_m
        ab = np.array([[a0, b0], [a1, b0], [a1, b1], [a0, b1]])
        return self.to_world(ab)

    @property
    def area_m2(self) -> float:
        """Ground area of the cell, m²."""
        return float(self.along_m * self.across_m)

    def to_local(self, xy: ArrayLike) -> np.ndarray:
        """Cell-frame coordinates (a, b) of points (..., ≥2) given as (x, y[, z]), m."""
        p = np.asarray(xy, dtype=np.float64)[..., :2] - np.asarray(self.center_xy, dtype=np.float64)
        ea, eb = self.axes
        return np.stack([p @ ea, p @ eb], axis=-1)

    def to_world(self, ab: ArrayLike) -> np.ndarray:
        """World (x, y) of cell-frame coordinates (..., 2)."""
        ab = np.asarray(ab, dtype=np.float64)
        ea, eb = self.axes
        return np.asarray(self.center_xy) + ab[..., :1] * ea + ab[..., 1:2] * eb

    def lattice_shift(self, i: ArrayLike, j: ArrayLike) -> np.ndarray:
        """World (x, y) shift of the lattice vector i·A·ê_a + j·B·ê_b."""
        ea, eb = self.axes
        i, j = np.asarray(i, dtype=np.float64), np.asarray(j, dtype=np.float64)
        return (i * self.along_m)[..., None] * ea + (j * self.across_m)[..., None] * eb

    def wrap(self, points: ArrayLike) -> np.ndarray:
        """Points (..., 3) moved by whole lattice vectors into the cell [−A/2, A/2) × [−B/2, B/2)."""
        p = np.array(points, dtype=np.float64)
        a, b = np.moveaxis(self.to_local(p), -1, 0)
        i = -np.floor(a / self.along_m + 0.5)
        j = -np.floor(b / self.across_m + 0.5)
        out = (i != 0) | (j != 0)  # most points are inside already: a zero shift would change nothing
        p[out, :2] += self.lattice_shift(i[out], j[out])
        return p

    def images(self, mesh: Mesh, margin_m: float = IMAGE_MARGIN_M) -> Mesh:
        """Every periodic image of every face that reaches into the cell, as one mesh.

        A face is copied once for each lattice vector that moves its bounding box (in the cell
        frame, widened by ``margin_m``) to overlap the cell: the original where it overlaps, one
        copy per side it reaches over (shifted by ∓ the period), and the diagonal copy where it
        reaches over a corner; a leaf longer than the cell gets as many copies as it spans.
        Faces keep their segment id and blade flag. Inside the cell the images are exactly the
        infinite field's geometry, which is what a ray that is only allowed to hit inside the
        cell (:class:`lightfit.light.periodic.PeriodicTracer`) needs to see. Vertices are not
        shared between faces.
        """
        tri = mesh.vertices[mesh.faces]  # (F, 3, 3)
        ab = self.to_local(tri)  # (F, 3, 2)
        lo, hi = ab.min(1), ab.max(1)
        half, size = self.size_m / 2, self.size_m
        # Shift k overlaps when [lo + k·P, hi + k·P] meets [−P/2 − m, P/2 + m].
        k_lo = np.ceil((-half - margin_m - hi) / size).astype(np.int64)
        k_hi = np.floor((half + margin_m - lo) / size).astype(np.int64)
        parts = []
        if len(tri):
            for i in range(int(k_lo[:, 0].min()), int(k_hi[:, 0].max()) + 1):
                for j in range(int(k_lo[:, 1].min()), int(k_hi[:, 1].max()) + 1):
                    sel = (k_lo[:, 0] <= i) & (i <= k_hi[:, 0]) & (k_lo[:, 1] <= j) & (j <= k_hi[:, 1])
                    if not sel.any():
                        continue
                    v = tri[sel].copy()
                    v[..., :2] += self.lattice_shift(i, j)
                    n = int(sel.sum())
                    parts.append(
                        Mesh(
                            v.reshape(-1, 3),
                            np.arange(3 * n, dtype=np.int64).reshape(n, 3),
                            mesh.face_segment[sel],
                            mesh.face_is_blade[sel],
                        )
                    )
        return Mesh.concatenate(parts)
