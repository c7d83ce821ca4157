"""Plant: CPlantBox growth (G1 segment table), shoot mesh (G3) and field geometry.

from lightfit import plant
cell = plant.build(plant.Field(n_plants=100, seed=1))  # one periodic cell of an infinite field (default)
fld = plant.Field(boundary="finite", n_plants=100, buffer_rows=2, seed=1)  # the paper's: 2 buffer rows
geom = plant.build(fld)                         # whole field; or tile=fld.tiles(4)[0]
plant.export(geom.mesh, "field.ply")
"""

from lightfit.plant.cache import cache_dir, load_or_grow
from lightfit.plant.export import export
from lightfit.plant.field import HEADINGS, Field, FieldGeometry, Tile, build
from lightfit.plant.growth import (
    GrowthConfig,
    centre_height_m,
    grow_plant,
    is_shoot,
    one_sided_area_m2,
    organ_class,
    plant_seed,
    resolve_parameter_file,
)
from lightfit.plant.mesh import Mesh, MeshResolution, expected_area, shoot_mesh
from lightfit.plant.periodic import PeriodicCell
from lightfit.plant.sheaths import SHEATHS

__all__ = [
    "Field",
    "FieldGeometry",
    "HEADINGS",
    "GrowthConfig",
    "Mesh",
    "MeshResolution",
    "PeriodicCell",
    "SHEATHS",
    "Tile",
    "build",
    "cache_dir",
    "centre_height_m",
    "expected_area",
    "export",
    "grow_plant",
    "load_or_grow",
    "one_sided_area_m2",
    "organ_class",
    "plant_seed",
    "resolve_parameter_file",
    "is_shoot",
    "shoot_mesh",
]
