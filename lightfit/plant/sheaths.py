r"""Leaf sheaths: where a wheat leaf's basal zone goes (``Field.sheaths``).

CPlantBox gives each wheat leaf's first 8 cm (its basal zone: no blade width) the leaf's radius,
0.3 mm, and the leaf's insertion angle, so taken as it comes a sheath is a 0.6 mm rod leaning
13–24° from the vertical whose top, where the blade begins, lies 1.6–3.9 cm across from the stem
(docs/plant.md, "Leaf sheaths"). A grass leaf sheath is a tube wrapped around the culm from its
node up to the collar (ligule), older sheaths outside younger ones, and the blade leaves the
pseudostem at the collar (e.g. Kirby & Appleyard 1987, *Cereal Development Guide*, 2nd ed.).
Two layouts:

``"wrapped"`` (default)
    Each leaf's sheath segments are re-laid, lengths kept, along the branching direction CPlantBox
    records at the leaf's node (the stem's axis there), from the node up, as a tube of radius

    .. math:: r = r_\mathrm{stem} + (n - k)\,w,

    :math:`r_\mathrm{stem}` the plant's stem radius, :math:`n` the plant's leaves, :math:`k` the
    leaf's rank by node height (0 the lowest: the oldest, outermost sheath) and :math:`w` the leaf
    radius CPlantBox gives the sheath, taken as its wall thickness. The blade is moved, shape and
    orientation unchanged, to start at the collar on that tube's surface, on the side its collar
    lay. A sheath's one-sided area is its tube's 2πrL. The culm inside its sheaths gets no light.
``"rods"``
    CPlantBox's layout, unchanged: the reference paper's geometry (its preset).

What the wrapped layout changes on the main job's cell is measured by
``experiments/wrapped_sheaths.py`` (docs/plant.md).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from lightfit.errors import InputError
from lightfit.plant.growth import organ_class

#: Sheath layouts of :attr:`lightfit.plant.Field.sheaths`; the first is the default.
SHEATHS = ("wrapped", "rods")

_P0, _P1 = ["x0", "y0", "z0"], ["x1", "y1", "z1"]


def check_sheaths(value) -> str:
    """A sheath layout of :data:`SHEATHS`, else :class:`InputError` naming ``sheaths``."""
    if value not in SHEATHS:
        raise InputError(f"sheaths={value!r}", column="sheaths", expected=" or ".join(map(repr, SHEATHS)))
    return value


def lay_sheaths(segments: pd.DataFrame, sheaths: str) -> pd.DataFrame:
    """The segment table with its sheaths laid out as ``sheaths`` says (module doc); ``"rods"``
    returns ``segments`` itself."""
    if check_sheaths(sheaths) == "rods":
        return segments
    return wrap_sheaths(segments)


def wrap_sheaths(segments: pd.DataFrame) -> pd.DataFrame:
    """A copy of the segment table with every leaf's sheath wrapped around its plant's stem and
    its blade moved to the collar (the ``"wrapped"`` layout of the module doc). Coordinates in
    metres; plants are independent (``plant_id``), so a placed field gives the placed result."""
    out = segments.copy()
    organ = organ_class(segments)
    xyz0, xyz1 = segments[_P0].to_numpy(float), segments[_P1].to_numpy(float)
    new0, new1 = xyz0.copy(), xyz1.copy()
    radius = segments["radius_m"].to_numpy(float).copy()
    axes = segments[["bx", "by", "bz"]].to_numpy(float)
    lengths = segments["length_m"].to_numpy(float)
    plant, organ_id = segments["plant_id"].to_numpy(), segments["organ_id"].to_numpy()
    leaf = segments["organ_type"].to_numpy(str) == "leaf"
    order = np.lexsort((segments["segment_index"].to_numpy(), organ_id, plant))
    for p in np.unique(plant):
        rows = order[plant[order] == p]
        stem = rows[organ[rows] == "stem"]
        r_stem = float(radius[stem].max()) if len(stem) else 0.0
        leaves = [rows[organ_id[rows] == o] for o in np.unique(organ_id[rows[leaf[rows]]])]
        leaves.sort(key=lambda r: (xyz0[r[0], 2], organ_id[r[0]]))  # by node height: the oldest first
        n = len(leaves)
        for k, r in enumerate(leaves):
            sheath, blade = r[organ[r] == "sheath"], r[organ[r] == "blade"]
            if not len(sheath):
                continue
            node = xyz0[sheath[0]]
            axis = axes[sheath[0]] / np.linalg.norm(axes[sheath[0]])
            s = np.concatenate([[0.0], np.cumsum(lengths[sheath])])
            points = node + s[:, None] * axis
            new0[sheath], new1[sheath] = points[:-1], points[1:]
            r_tube = r_stem + (n - k) * float(radius[sheath].max())
            radius[sheath] = r_tube
            if not len(blade):
                continue
            old_collar = xyz1[sheath[-1]]
            side = (old_collar - node) - np.dot(old_collar - node, axis) * axis
            norm = np.linalg.norm(side)
            side = side / norm if norm > 0 else np.array([1.0, 0.0, 0.0])
            shift = points[-1] + r_tube * side - old_collar
            new0[blade], new1[blade] = xyz0[blade] + shift, xyz1[blade] + shift
    out[_P0], out[_P1] = new0, new1
    out["radius_m"] = radius
    return out


__all__ = ["SHEATHS", "check_sheaths", "lay_sheaths", "wrap_sheaths"]
