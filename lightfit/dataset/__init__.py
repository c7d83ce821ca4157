"""Data scene: synthetic labelled images with functional maps from a coupled-model run.

    from lightfit import dataset
    meta = dataset.make_dataset("results.nc", "out/", dataset.DatasetSpec(
        cameras=[dataset.Camera(name="east", position_m=(1.0, 0.0, 0.6), width_px=512, height_px=512)],
        times=["2016-04-20T11:00"]))

Per image: HDR EXR, tone-mapped PNG and dense labels (segment id, plant id, organ, depth,
absorbed PAR, An, Vc, Vj, gs, limitation class, limitation margin); a metadata JSON, a gallery
figure and a PLY/VTK of the coloured field. The data scene is kept apart from the model scene
(visual materials, a camera, the day's sun and sky), as in the reference paper.
"""

from lightfit.dataset.camera import EXPOSURE_MODES, Camera, Sweep, camera_sweep, load_cameras
from lightfit.dataset.dataset import DEFAULT_QUANTITIES, DatasetSpec, export_field, make_dataset
from lightfit.dataset.exposure import Exposure, clipped_fraction, luminance, meter, tone_map
from lightfit.dataset.labels import geometric_labels, quantity_map
from lightfit.dataset.render import RenderOutput, RenderSettings, render
from lightfit.dataset.results import MARGIN, QUANTITIES, Results, build_geometry, lighting, open_results, select_times
from lightfit.dataset.scene import (
    ORGAN_CODES,
    Lighting,
    SceneArrays,
    VisualMaterials,
    periodic_canopy,
    scene_arrays,
    view_reach_m,
)
from lightfit.dataset.synthetic import synthetic_results

__all__ = [
    "Camera",
    "DEFAULT_QUANTITIES",
    "DatasetSpec",
    "EXPOSURE_MODES",
    "Exposure",
    "Lighting",
    "MARGIN",
    "ORGAN_CODES",
    "QUANTITIES",
    "RenderOutput",
    "RenderSettings",
    "Results",
    "SceneArrays",
    "Sweep",
    "VisualMaterials",
    "build_geometry",
    "camera_sweep",
    "clipped_fraction",
    "export_field",
    "geometric_labels",
    "lighting",
    "load_cameras",
    "luminance",
    "make_dataset",
    "meter",
    "open_results",
    "periodic_canopy",
    "quantity_map",
    "render",
    "scene_arrays",
    "select_times",
    "synthetic_results",
    "tone_map",
    "view_reach_m",
]
