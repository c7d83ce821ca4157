"""Triangle mesh (G3) of the shoot, with every face labelled by its plant segment.

Leaf blades are flat ribbons along the leaf centreline: each blade segment from node a to node b
becomes a rectangle of CPlantBox's blade width w, spanned by the segment direction t and the
width direction

.. math:: \\hat w = \\frac{t \\times s}{\\lVert t \\times s \\rVert}

where s is the branching direction (the parent stem's axis where the leaf emerges). The blade is
thus perpendicular to the branching direction and contains each successive vertex difference,
the convention of the reference paper's visualiser (Baker et al. 2023). Per-segment rectangles are
planar, so a segment's mesh area equals its one-sided blade area w·L exactly (to round-off).

Stems and leaf sheaths (leaf segments with no blade area) are open n-sided prisms whose
circumradius is enlarged to r·π / (n·sin(π/n)) so that the prism's lateral area equals the
cylinder's 2πrL exactly. A prism's width seen from the side depends on where one looks from
(a hexagon's from √3 R to 2R, −9 % to +5 % of the cylinder's 2r), so each plant's prisms are turned
about their axes by the plant's own angle (:func:`prism_turn`): a common angle gave every upright
stem and sheath of the field the same facets, and their direct sun a shared pattern in the sun's
azimuth with a period of 2π/n. One angle per plant, not per organ, keeps the hexagons of a stem and
the sheaths wrapped round it aligned, so that each stays inside the next (a hexagon of circumradius
R holds one turned against it only if that one's is at most R·cos(π/n)).

Normals of blade faces point to the upper (adaxial) side: the side whose normal has a
non-negative vertical component; prism normals point outwards.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

from lightfit.defaults import MESH_ACROSS, MESH_ALONG, MESH_AROUND
from lightfit.errors import InputError
from lightfit.plant.growth import is_shoot, one_sided_area_m2, organ_class

if TYPE_CHECKING:
    import trimesh


@dataclass(frozen=True)
class MeshResolution:
    """Resolution knobs of the mesh.

    Attributes:
        along: subdivisions along each segment (≥ 1).
        across: subdivisions across each leaf blade (≥ 1).
        around: sides of the prism for stems and sheaths (≥ 3).
    """

    along: int = MESH_ALONG
    across: int = MESH_ACROSS
    around: int = MESH_AROUND

    def __post_init__(self):
        for name, lo in (("along", 1), ("across", 1), ("around", 3)):
            v = getattr(self, name)
            if not isinstance(v, (int, np.integer)) or v < lo:
                raise InputError(f"mesh resolution {name}={v!r}", parameter=name, expected=f"an integer ≥ {lo}")


@dataclass
class Mesh:
    """A labelled triangle mesh.

    Attributes:
        vertices: (V, 3) float64, m.
        faces: (F, 3) int64 vertex indices, counter-clockwise around ``normals``.
        face_segment: (F,) int64 segment id of every face.
        face_is_blade: (F,) bool, True for leaf-blade faces (thin, two-sided), False for
            stem/sheath prisms (closed solids seen from outside).
    """

    vertices: np.ndarray
    faces: np.ndarray
    face_segment: np.ndarray
    face_is_blade: np.ndarray

    @property
    def n_faces(self) -> int:
        return len(self.faces)

    def face_areas(self) -> np.ndarray:
        """Area of each face, m²."""
        v = self.vertices[self.faces]
        return 0.5 * np.linalg.norm(np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]), axis=1)

    def normals(self) -> np.ndarray:
        """Unit normal of each face (zero for degenerate faces)."""
        v = self.vertices[self.faces]
        n = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
        norm = np.linalg.norm(n, axis=1, keepdims=True)
        return np.divide(n, norm, out=np.zeros_like(n), where=norm > 0)

    def blade_inclination_deg(self) -> float:
        """Area-weighted mean inclination of the leaf blades from the horizontal, degrees (0: flat,
        90: upright): the angle of each blade face's normal from the vertical. Wheat canopies lie
        near 55–65° (erectophile to spherical; a spherical distribution has 57.3°)."""
        blade = self.face_is_blade
        if not blade.any():
            return float("nan")
        tilt = np.degrees(np.arccos(np.clip(np.abs(self.normals()[blade, 2]), 0.0, 1.0)))
        return float(np.average(tilt, weights=self.face_areas()[blade]))

    def of_faces(self, keep: np.ndarray) -> Mesh:
        """The mesh of the faces ``keep`` marks ((F,) bool), its vertices shared (unused ones kept)."""
        return Mesh(self.vertices, self.faces[keep], self.face_segment[keep], self.face_is_blade[keep])

    def area_per_segment(self) -> pd.Series:
        """Mesh area per segment id, m²."""
        return pd.Series(self.face_areas()).groupby(self.face_segment).sum()

    def to_trimesh(self) -> trimesh.Trimesh:
        """A ``trimesh.Trimesh`` with ``face_attributes['segment_id']`` (vertices not merged)."""
        import trimesh

        return trimesh.Trimesh(
            self.vertices, self.faces, process=False, face_attributes={"segment_id": self.face_segment}
        )

    @staticmethod
    def concatenate(meshes: list[Mesh]) -> Mesh:
        offsets = np.cumsum([0] + [len(m.vertices) for m in meshes[:-1]])
        return Mesh(
            np.concatenate([m.vertices for m in meshes]) if meshes else np.zeros((0, 3)),
            np.concatenate([m.faces + o for m, o in zip(meshes, offsets)]) if meshes else np.zeros((0, 3), np.int64),
            np.concatenate([m.face_segment for m in meshes]) if meshes else np.zeros(0, np.int64),
            np.concatenate([m.face_is_blade for m in meshes]) if meshes else np.zeros(0, bool),
        )


def _unit(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return np.divide(v, n, out=np.zeros_like(v), where=n > 0), n[..., 0]


def _grid_faces(n_seg: int, nu: int, nv: int) -> np.ndarray:
    """Faces of n_seg independent (nu+1)×(nv+1) vertex grids, two triangles per cell."""
    i, j = np.meshgrid(np.arange(nu), np.arange(nv), indexing="ij")
    v00 = i * (nv + 1) + j
    v10, v01, v11 = v00 + (nv + 1), v00 + 1, v00 + nv + 2
    cell = np.stack([np.stack([v00, v10, v11], -1), np.stack([v00, v11, v01], -1)], axis=2).reshape(-1, 3)
    per = (nu + 1) * (nv + 1)
    return (cell[None, :, :] + (np.arange(n_seg) * per)[:, None, None]).reshape(-1, 3)


def blade_mesh(seg: pd.DataFrame, res: MeshResolution) -> Mesh:
    """Ribbons for leaf segments with a blade (``blade_width_m > 0``)."""
    a = seg[["x0", "y0", "z0"]].to_numpy()
    b = seg[["x1", "y1", "z1"]].to_numpy()
    t, length = _unit(b - a)
    s = seg[["bx", "by", "bz"]].to_numpy()
    w, wn = _unit(np.cross(t, s))
    # Where the segment runs along the branching direction the cross product vanishes:
    # fall back to a horizontal width direction (perpendicular to t and vertical).
    bad = wn < 1e-6
    if bad.any():
        alt, altn = _unit(np.cross(t[bad], np.array([0.0, 0.0, 1.0])))
        alt[altn < 1e-6] = [1.0, 0.0, 0.0]
        w[bad] = alt
    normal = np.cross(t, w)
    flip = normal[:, 2] < 0  # orient the upper side up
    w[flip] *= -1
    width = seg["blade_width_m"].to_numpy()
    u = np.linspace(0.0, 1.0, res.along + 1)
    v = np.linspace(-0.5, 0.5, res.across + 1)
    pts = (
        a[:, None, None, :]
        + u[None, :, None, None] * (b - a)[:, None, None, :]
        + v[None, None, :, None] * (width[:, None] * w)[:, None, None, :]
    )
    faces = _grid_faces(len(seg), res.along, res.across)
    n_per = 2 * res.along * res.across
    ids = np.repeat(seg["segment_id"].to_numpy(), n_per)
    return Mesh(pts.reshape(-1, 3), faces, ids, np.ones(len(faces), bool))


#: Generator of :func:`prism_turn`: 1/g, g the plastic number (the R₂ sequence's first), whose
#: multiples spread the plant ids evenly over the unit interval.
_TURN = 0.7548776662466927


def prism_turn(plant_id, around: int) -> np.ndarray:
    """Angle (radians, in [0, 2π/n)) by which a plant's n-sided prisms are turned about their axes,
    from its id alone: {plant_id · a} · 2π/n with a :data:`_TURN`. The plants' facets then face every
    way in equal measure (a prism repeats itself every 2π/n)."""
    return (np.asarray(plant_id, dtype=float) * _TURN % 1.0) * (2 * np.pi / around)


def prism_mesh(seg: pd.DataFrame, res: MeshResolution) -> Mesh:
    """Open n-sided prisms for stems and sheaths, lateral area equal to 2πrL, each plant's turned
    about their axes by :func:`prism_turn` (so ``seg`` needs its ``plant_id`` column)."""
    a = seg[["x0", "y0", "z0"]].to_numpy()
    b = seg[["x1", "y1", "z1"]].to_numpy()
    t, _ = _unit(b - a)
    helper = np.where(np.abs(t[:, 2:3]) < 0.9, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]])
    e1, _ = _unit(np.cross(t, helper))
    e2 = np.cross(t, e1)
    n = res.around
    r = seg["radius_m"].to_numpy() * np.pi / (n * np.sin(np.pi / n))
    # closing column repeats the first angle
    theta = prism_turn(seg["plant_id"], n)[:, None] + np.linspace(0.0, 2 * np.pi, n + 1)
    ring = np.cos(theta)[:, :, None] * e1[:, None, :] + np.sin(theta)[:, :, None] * e2[:, None, :]
    u = np.linspace(0.0, 1.0, res.along + 1)
    pts = (
        a[:, None, None, :]
        + u[None, :, None, None] * (b - a)[:, None, None, :]
        + (r[:, None, None] * ring)[:, None, :, :]
    )
    # Reverse the grid winding so that prism normals point away from the axis.
    faces = _grid_faces(len(seg), res.along, n)[:, [0, 2, 1]]
    ids = np.repeat(seg["segment_id"].to_numpy(), 2 * res.along * n)
    return Mesh(pts.reshape(-1, 3), faces, ids, np.zeros(len(faces), bool))


def shoot_mesh(segments: pd.DataFrame, res: MeshResolution = MeshResolution()) -> Mesh:
    """Mesh of the stems and leaves in a segment table (roots and zero-length segments skipped)."""
    seg = segments[is_shoot(segments) & (segments["length_m"] > 0).to_numpy()]
    blade = organ_class(seg) == "blade"
    tube = ~blade & (seg["radius_m"].to_numpy() > 0)
    return Mesh.concatenate([blade_mesh(seg[blade], res), prism_mesh(seg[tube], res)])


def expected_area(segments: pd.DataFrame) -> pd.Series:
    """Area each segment's mesh should have, m²: blade area (one side) or 2πrL, by segment id."""
    area = one_sided_area_m2(segments)
    keep = is_shoot(segments)
    return pd.Series(area[keep], index=segments["segment_id"].to_numpy()[keep])
