"""The data scene: the model scene's geometry with *visual* materials, and the day's light.

The reference paper keeps two scenes apart: the model scene's materials are tuned for measuring
PAR, not for pictures. Here the same plant mesh gets visible-band colours (linear sRGB
reflectances), leaves transmit part of their diffuse light (backlit leaves glow), and the soil
is a large finite plane so that the horizon and sky appear in oblique views.

A periodic field (``Field(boundary="periodic")``) is one cell of an endless canopy, so its
picture must not be a block on bare soil: :func:`periodic_canopy` repeats the cell's mesh by the
lattice vectors (explicit shifted copies, as VPL and Eradiate build periodic scenes) out to the
distance at which the cameras' rays reach the ground (:func:`view_reach_m`), within
``VisualMaterials.periodic_max_reach_m`` and :data:`MAX_PERIODIC_FACES`. Every copy keeps its
segment ids: a pixel on a copy is labelled with the plant it is an image of.

Everything in this module is plain numpy: the arrays travel unchanged to whichever process
renders them (see :mod:`lightfit.dataset.render`).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace

import numpy as np
import pandas as pd

from lightfit.defaults import SKY_MODELS
from lightfit.errors import InputError, check_fraction
from lightfit.light.scene import check_sky
from lightfit.plant.mesh import Mesh
from lightfit.plant.periodic import PeriodicCell

#: Organ codes of the ``organ`` label array.
ORGAN_CODES = {"sky": 0, "soil": 1, "stem": 2, "leaf": 3}
#: Most plant triangles the copies of a periodic cell may put in the data scene (≈ 0.5 GB of
#: float32 vertices and attributes); the nearest copies are kept when the reach needs more.
MAX_PERIODIC_FACES = 4_000_000


@dataclass(frozen=True)
class VisualMaterials:
    """Visible-band appearance of the data scene (linear sRGB reflectances in [0, 1]).

    Attributes:
        leaf_rgb: leaf blade/sheath albedo, the diffuse light reflected and transmitted together:
            a leaf reflects (1 − leaf_transmission)·leaf_rgb and transmits leaf_transmission·leaf_rgb.
            The defaults reflect ≈ 5 % red, 12 % green, 3 % blue, as green leaves do, and transmit
            two thirds of that.
        stem_rgb: stem albedo (paler green).
        soil_rgb: soil albedo (moist loam, brownish).
        leaf_transmission: share of a leaf's diffuse light transmitted to its other side.
        roughness: microfacet roughness of all surfaces (gloss of the cuticle).
        colour_variation: relative spread (uniform ±) of each organ's albedo, drawn from the
            scene seed, so that leaves are told apart by eye as in real images.
        soil_half_size_m: half side of the square soil plane centred on the field, m.
        periodic_max_reach_m: periodic fields: the copies of the cell reach at most this far
            from its centre, m (beyond, oblique views see bare soil towards the horizon).
    """

    # the reflectance above ÷ (1 − leaf_transmission) (the images reflected 0.8 × (0.05, 0.12, 0.03)
    # while principledthin's diff_trans was given τ instead of 2τ)
    leaf_rgb: tuple[float, float, float] = (0.05 / 0.6, 0.12 / 0.6, 0.03 / 0.6)
    stem_rgb: tuple[float, float, float] = (0.09, 0.15, 0.05)
    soil_rgb: tuple[float, float, float] = (0.13, 0.09, 0.06)
    leaf_transmission: float = 0.4
    roughness: float = 0.5
    colour_variation: float = 0.15
    soil_half_size_m: float = 200.0
    periodic_max_reach_m: float = 5.0

    def __post_init__(self):
        for k in ("leaf_rgb", "stem_rgb", "soil_rgb"):
            a = np.asarray(getattr(self, k), dtype=float)
            if a.shape != (3,) or not np.isfinite(a).all() or (a < 0).any() or (a > 1).any():
                raise InputError(f"{k}={getattr(self, k)!r}", parameter=k, expected="three reflectances in [0, 1]")
        for k in ("leaf_transmission", "roughness", "colour_variation"):
            check_fraction(getattr(self, k), k)
        for k in ("soil_half_size_m", "periodic_max_reach_m"):
            v = getattr(self, k)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise InputError(f"{k}={v!r}", parameter=k, expected="a positive distance in metres")


@dataclass(frozen=True)
class Lighting:
    """Sun and sky of one time step.

    Attributes:
        sun_elevation_deg, sun_azimuth_deg: sun position (azimuth clockwise from north), degrees.
        dni_w_m2: direct normal irradiance, W m⁻² (0 below the horizon).
        dhi_w_m2: diffuse horizontal irradiance, W m⁻²; the sky's radiance is DHI/π W m⁻² sr⁻¹
            everywhere (``sky="isotropic"``) or the CIE standard overcast sky's with the same DHI
            (``"overcast"``; :func:`~lightfit.light.scene.overcast_radiance_per_dhi`), the run's own.
            Sun and sky are white: each image channel carries the broadband radiance times the
            surface's channel reflectance.
    """

    sun_elevation_deg: float
    sun_azimuth_deg: float
    dni_w_m2: float
    dhi_w_m2: float
    sky: str = SKY_MODELS[0]

    def __post_init__(self):
        check_sky(self.sky)
        for k, v in asdict(self).items():
            if k != "sky" and not math.isfinite(v):
                raise InputError(f"{k}={v!r}", parameter=k, expected="a finite number")
        if self.dni_w_m2 < 0 or self.dhi_w_m2 < 0:
            raise InputError(
                f"irradiance DNI={self.dni_w_m2}, DHI={self.dhi_w_m2}",
                parameter="dni_w_m2/dhi_w_m2",
                expected="non-negative W m⁻²",
            )

    def to_dict(self) -> dict:
        d = asdict(self)
        return d if self.sky != SKY_MODELS[0] else {k: v for k, v in d.items() if k != "sky"}  # keys as before


@dataclass
class SceneArrays:
    """Triangles of the data scene, ready to render (plants first, then the two soil triangles).

    Attributes:
        vertices: (V, 3) float32, m.
        faces: (F, 3) uint32.
        face_rgb: (F, 3) float32 linear albedo per face.
        face_transmission: (F,) float32 diffuse transmission share per face.
        n_plant_faces: faces ``< n_plant_faces`` are plant faces (index into the plant mesh);
            the rest are soil.
    """

    vertices: np.ndarray
    faces: np.ndarray
    face_rgb: np.ndarray
    face_transmission: np.ndarray
    n_plant_faces: int


def organ_colour_factor(segments: pd.DataFrame, spread: float, seed: int) -> pd.Series:
    """Multiplicative albedo factor per segment, constant over an organ, indexed by segment id.

    Drawn uniformly in [1 − spread, 1 + spread] from ``seed`` and the organ's (plant, organ) id,
    so an organ keeps its colour whichever cameras or tiles render it.
    """
    organ = segments["organ_id"].to_numpy() if "organ_id" in segments else np.zeros(len(segments), dtype=np.int64)
    keys = pd.MultiIndex.from_arrays([segments["plant_id"].to_numpy(), organ])
    uniq = keys.unique()
    draw = {k: np.random.default_rng([int(seed), int(k[0]), int(k[1]) + 1]).uniform(-1.0, 1.0) for k in uniq}
    factor = 1.0 + spread * np.array([draw[k] for k in keys])
    return pd.Series(factor, index=segments["segment_id"].to_numpy())


def scene_arrays(
    mesh: Mesh,
    segments: pd.DataFrame,
    materials: VisualMaterials = VisualMaterials(),
    seed: int = 0,
    centre_m=(0.0, 0.0),
) -> SceneArrays:
    """Colour the plant mesh by organ and append a square soil plane at z = 0."""
    seg = segments.set_index("segment_id")
    organ = seg["organ_type"].astype(str).reindex(mesh.face_segment).to_numpy()
    if pd.isna(organ).any():
        raise InputError(
            "the mesh has faces whose segment id is not in the segment table",
            column="segment_id",
            expected="the mesh and segments of one FieldGeometry",
        )
    factor = organ_colour_factor(segments, materials.colour_variation, seed).reindex(mesh.face_segment).to_numpy()
    is_leaf = organ == "leaf"
    rgb = np.where(is_leaf[:, None], materials.leaf_rgb, materials.stem_rgb) * factor[:, None]
    trans = np.where(is_leaf, materials.leaf_transmission, 0.0)
    h, (cx, cy) = materials.soil_half_size_m, centre_m
    nv = len(mesh.vertices)
    soil_v = np.array([[cx - h, cy - h, 0.0], [cx + h, cy - h, 0.0], [cx + h, cy + h, 0.0], [cx - h, cy + h, 0.0]])
    soil_f = np.array([[nv, nv + 1, nv + 2], [nv, nv + 2, nv + 3]])
    return SceneArrays(
        vertices=np.vstack([mesh.vertices, soil_v]).astype(np.float32),
        faces=np.vstack([mesh.faces, soil_f]).astype(np.uint32),
        face_rgb=np.clip(np.vstack([rgb, [materials.soil_rgb] * 2]), 0.0, 1.0).astype(np.float32),
        face_transmission=np.r_[trans, 0.0, 0.0].astype(np.float32),
        n_plant_faces=int(mesh.n_faces),
    )


def view_reach_m(cameras, centre_xy=(0.0, 0.0), max_reach_m: float = 5.0, rays_per_side: int = 33) -> float:
    """Farthest horizontal distance from ``centre_xy`` at which the cameras' rays reach the ground, m.

    A grid of ``rays_per_side``² rays spanning each camera's image (corners and edges included)
    is intersected with the plane z = 0; rays that never reach it (sky) are ignored, and the
    answer is capped at ``max_reach_m`` (grazing rays reach the ground very far away).
    """
    reach = 0.0
    for cam in cameras:
        probe = replace(cam, width_px=rays_per_side, height_px=rays_per_side)
        # Pixel centres of a coarse image, plus its exact corners (jitter 0 and 1 at the borders).
        j = np.full((rays_per_side, rays_per_side, 2), 0.5)
        j[:, 0, 0], j[:, -1, 0], j[0, :, 1], j[-1, :, 1] = 0.0, 1.0, 0.0, 1.0
        d = probe.directions(j)
        down = d[:, 2] < -1e-9
        if not down.any():
            continue
        t = -cam.position_m[2] / d[down, 2]
        xy = np.asarray(cam.position_m[:2]) + t[:, None] * d[down, :2]
        reach = max(reach, float(np.linalg.norm(xy - np.asarray(centre_xy, dtype=float), axis=1).max()))
        if reach >= max_reach_m:
            return float(max_reach_m)
    return min(reach, float(max_reach_m))


def periodic_canopy(
    mesh: Mesh, cell: PeriodicCell, reach_m: float, max_faces: int = MAX_PERIODIC_FACES
) -> tuple[Mesh, dict]:
    """The cell's mesh and its copies shifted by lattice vectors, covering a disc of ``reach_m``.

    Copy (i, j) is the mesh moved by ``cell.lattice_shift(i, j)``; it is kept when the copy's
    cell comes within ``reach_m`` of the cell centre, nearest first, at most ``max_faces`` faces
    in all. The original comes first (its faces keep their indices), every copy keeps the
    segment ids and blade flags. Returns the mesh and a summary for the dataset's metadata
    (``reach_m``: the radius fully covered, less than requested when ``max_faces`` capped it).
    """
    a, b = cell.size_m
    half_diag = 0.5 * math.hypot(a, b)
    ni, nj = (int(math.ceil((reach_m + half_diag) / p)) for p in (a, b))
    i, j = (g.ravel() for g in np.meshgrid(np.arange(-ni, ni + 1), np.arange(-nj, nj + 1), indexing="ij"))
    dist = np.linalg.norm(cell.lattice_shift(i, j), axis=-1)
    keep = dist - half_diag <= reach_m
    i, j, dist = i[keep], j[keep], dist[keep]
    order = np.lexsort((j, i, dist))  # nearest first, (0, 0) first; ties in a fixed order
    n_max = max(1, int(max_faces // max(mesh.n_faces, 1)))
    capped = len(order) > n_max
    # Fully covered out to the nearest copy left out (less its half-diagonal).
    covered = max(0.0, float(dist[order[n_max]] - half_diag)) if capped else float(reach_m)  # ≥ 0: the cell itself
    order = order[:n_max]
    parts = []
    for k in order:
        v = mesh.vertices.copy()
        v[:, :2] += cell.lattice_shift(i[k], j[k])
        parts.append(Mesh(v, mesh.faces, mesh.face_segment, mesh.face_is_blade))
    out = Mesh.concatenate(parts)
    return out, {
        "cell_m": [float(a), float(b)],
        "copies": len(order),
        "reach_m": covered,
        "requested_reach_m": float(reach_m),
        "capped_by_max_faces": bool(capped),
        "plant_faces": int(out.n_faces),
    }
