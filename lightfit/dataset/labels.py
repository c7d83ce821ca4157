"""Dense per-pixel labels: segment, plant, organ, and per-segment quantities through the segment id.

Sentinels (documented in every dataset's metadata):

=====================  ========  ===============================================================
array                  dtype     background / no value
=====================  ========  ===============================================================
``segment_id``         int64     −1 for soil and sky pixels
``plant_id``           int64     −1 for soil and sky pixels
``organ``              uint8     codes :data:`~lightfit.dataset.scene.ORGAN_CODES`: 0 sky, 1 soil,
                                 2 stem, 3 leaf
``depth_m``            float32   NaN for sky (distance along the optical axis, m)
``valid``              bool      True where the pixel's segment has a value in the results
``<quantity>``         float32   NaN where ``valid`` is False (background, unmeasured buffer
                                 plants) or where the results store NaN
``limitation``         int8      1 electron-transport limited (Fj < Fc), 0 Rubisco limited,
                                 −1 no value
=====================  ========  ===============================================================
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from lightfit.dataset.scene import ORGAN_CODES
from lightfit.plant.mesh import Mesh

NO_SEGMENT = -1
NO_CLASS = -1


def geometric_labels(
    face: np.ndarray, depth_m: np.ndarray, mesh: Mesh, segments: pd.DataFrame
) -> dict[str, np.ndarray]:
    """Segment id, plant id and organ code per pixel from the face index under its centre.

    Args:
        face: (H, W) face index into the data scene (plant faces first, then soil), −1 = sky.
        depth_m: (H, W) depth along the optical axis, m.
        mesh: the plant mesh the scene was built from (its face count separates plant from soil).
    """
    plant = (face >= 0) & (face < mesh.n_faces)
    seg = np.full(face.shape, NO_SEGMENT, dtype=np.int64)
    seg[plant] = mesh.face_segment[face[plant]]
    table = segments.set_index("segment_id")
    organ_code = table["organ_type"].astype(str).map({"stem": ORGAN_CODES["stem"], "leaf": ORGAN_CODES["leaf"]})
    organ = np.where(face < 0, ORGAN_CODES["sky"], ORGAN_CODES["soil"]).astype(np.uint8)
    organ[plant] = organ_code.reindex(seg[plant]).to_numpy(dtype=np.uint8)
    pid = np.full(face.shape, NO_SEGMENT, dtype=np.int64)
    pid[plant] = table["plant_id"].reindex(seg[plant]).to_numpy(dtype=np.int64)
    return {"segment_id": seg, "plant_id": pid, "organ": organ, "depth_m": depth_m.astype(np.float32)}


def quantity_map(segment_id: np.ndarray, values: pd.Series) -> tuple[np.ndarray, np.ndarray]:
    """Map per-segment values (indexed by segment id) onto pixels.

    Returns (float32 map with NaN where there is no value, bool mask of pixels whose segment is
    in ``values``).
    """
    fg = segment_id != NO_SEGMENT
    known = np.zeros(segment_id.shape, dtype=bool)
    known[fg] = np.isin(segment_id[fg], values.index.to_numpy())
    out = np.full(segment_id.shape, np.nan, dtype=np.float32)
    out[known] = values.reindex(segment_id[known]).to_numpy(dtype=np.float32)
    return out, known


def class_map(values_map: np.ndarray) -> np.ndarray:
    """Integer class map (int8) from a float map of per-segment classes, −1 where NaN (no value)."""
    out = np.full(values_map.shape, NO_CLASS, dtype=np.int8)
    ok = np.isfinite(values_map)
    out[ok] = values_map[ok].astype(np.int8)
    return out
