"""The data scene: the model scene's geometry with *visual* materials, and the day's light.

The reference paper keeps two scenes apart: the model scene's materials are tuned for measuring
PAR, not for pictures. Here the same plant mesh gets visible-band colours (linear sRGB
reflectances), leaves transmit part of their diffuse light (backlit leaves glow), and the soil
is a large finite plane so that the horizon and sky appear in oblique views.

Everything in this module is plain numpy: the arrays travel unchanged to whichever process
renders them (see :mod:`lightfit.dataset.render`).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np
import pandas as pd

from lightfit.errors import InputError
from lightfit.plant.mesh import Mesh

#: Organ codes of the ``organ`` label array.
ORGAN_CODES = {"sky": 0, "soil": 1, "stem": 2, "leaf": 3}


@dataclass(frozen=True)
class VisualMaterials:
    """Visible-band appearance of the data scene (linear sRGB reflectances in [0, 1]).

    Attributes:
        leaf_rgb: leaf blade/sheath albedo; green leaves reflect ~5 % red, ~12 % green, ~3 % blue.
        stem_rgb: stem albedo (paler green).
        soil_rgb: soil albedo (moist loam, brownish).
        leaf_transmission: share of a leaf's diffuse light transmitted to its other side.
        roughness: microfacet roughness of all surfaces (gloss of the cuticle).
        colour_variation: relative spread (uniform ±) of each organ's albedo, drawn from the
            scene seed, so that leaves are told apart by eye as in real images.
        soil_half_size_m: half side of the square soil plane centred on the field, m.
    """

    leaf_rgb: tuple[float, float, float] = (0.05, 0.12, 0.03)
    stem_rgb: tuple[float, float, float] = (0.09, 0.15, 0.05)
    soil_rgb: tuple[float, float, float] = (0.13, 0.09, 0.06)
    leaf_transmission: float = 0.4
    roughness: float = 0.5
    colour_variation: float = 0.15
    soil_half_size_m: float = 200.0

    def __post_init__(self):
        for k in ("leaf_rgb", "stem_rgb", "soil_rgb"):
            a = np.asarray(getattr(self, k), dtype=float)
            if a.shape != (3,) or not np.isfinite(a).all() or (a < 0).any() or (a > 1).any():
                raise InputError(f"{k}={getattr(self, k)!r}", column=k, expected="three reflectances in [0, 1]")
        for k in ("leaf_transmission", "roughness", "colour_variation"):
            v = getattr(self, k)
            if not (math.isfinite(v) and 0.0 <= v <= 1.0):
                raise InputError(f"{k}={v!r}", column=k, expected="a number in [0, 1]")
        if not (math.isfinite(self.soil_half_size_m) and self.soil_half_size_m > 0):
            raise InputError(
                f"soil_half_size_m={self.soil_half_size_m!r}",
                column="soil_half_size_m",
                expected="a positive distance in metres",
            )


@dataclass(frozen=True)
class Lighting:
    """Sun and sky of one time step.

    Attributes:
        sun_elevation_deg, sun_azimuth_deg: sun position (azimuth clockwise from north), degrees.
        dni_w_m2: direct normal irradiance, W m⁻² (0 below the horizon).
        dhi_w_m2: diffuse horizontal irradiance, W m⁻²; the sky is isotropic with radiance
            DHI/π W m⁻² sr⁻¹. Sun and sky are white: each image channel carries the broadband
            radiance times the surface's channel reflectance.
    """

    sun_elevation_deg: float
    sun_azimuth_deg: float
    dni_w_m2: float
    dhi_w_m2: float

    def __post_init__(self):
        for k, v in asdict(self).items():
            if not math.isfinite(v):
                raise InputError(f"{k}={v!r}", column=k, expected="a finite number")
        if self.dni_w_m2 < 0 or self.dhi_w_m2 < 0:
            raise InputError(
                f"irradiance DNI={self.dni_w_m2}, DHI={self.dhi_w_m2}",
                column="dni_w_m2/dhi_w_m2",
                expected="non-negative W m⁻²",
            )

    def to_dict(self) -> dict:
        return asdict(self)


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
