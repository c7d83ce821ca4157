r"""Leaf sheaths: where a wheat leaf's basal zone goes (``Field.sheaths``).

CPlantBox gives each wheat leaf's first 8 cm (its basal zone: no blade width) the leaf's radius,
0.3 mm, and the leaf's insertion angle, so taken as it comes a sheath is a 0.6 mm rod leaning
13–24° from the vertical whose top, where the blade begins, lies 1.6–3.9 cm across from the stem
(docs/plant.md, "Leaf sheaths"). A grass leaf sheath is a tube wrapped around the culm from its
node up to the collar (ligule), older sheaths outside younger ones, and the blade leaves the
pseudostem at the collar (e.g. Kirby & Appleyard 1987, *Cereal Development Guide*, 2nd ed.).
Two layouts:

``"wrapped"`` (default)
    Each leaf's sheath segments are re-laid, lengths kept, along its stem's axis from the leaf's
    node up (beyond the stem's tip, straight on), as a tube of radius

    .. math:: r_k = w_k + \max\bigl(r_\mathrm{stem},\ \max_{j \in E_k} r_j\bigr),

    :math:`w_k` the leaf radius CPlantBox gives the sheath, taken as its wall thickness,
    :math:`r_\mathrm{stem}` the stem's radius and :math:`E_k` the younger sheaths that start
    within sheath k's span (they are inside it): each sheath fits what it encloses, older outside
    younger. The sheath follows the stem where it bends, so the culm stays inside it. The blade is
    moved, shape and orientation unchanged, to start at the collar on that tube's surface, on the
    side its collar lay. A sheath's one-sided area is its tube's 2πrL. The culm inside its sheaths
    gets almost no light (a tube's top is open: a 0.3 mm gap between culm and innermost sheath).
``"rods"``
    CPlantBox's layout, unchanged: the reference paper's geometry (its preset).

What the wrapped layout changes on the main job's cell is measured by
``experiments/wrapped_sheaths.py`` (docs/plant.md).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from lightfit.defaults import SHEATHS
from lightfit.errors import InputError
from lightfit.plant.growth import organ_class

_P0, _P1 = ["x0", "y0", "z0"], ["x1", "y1", "z1"]


def check_sheaths(value) -> str:
    """A sheath layout of :data:`SHEATHS`, else :class:`InputError` naming ``sheaths``."""
    if value not in SHEATHS:
        raise InputError(f"sheaths={value!r}", parameter="sheaths", expected=" or ".join(map(repr, SHEATHS)))
    return value


def lay_sheaths(segments: pd.DataFrame, sheaths: str) -> pd.DataFrame:
    """The segment table with its sheaths laid out as ``sheaths`` says (module doc); ``"rods"``
    returns ``segments`` itself."""
    if check_sheaths(sheaths) == "rods":
        return segments
    return wrap_sheaths(segments)


def _unit(*candidates: np.ndarray) -> np.ndarray:
    """The first of ``candidates`` that is not (nearly) zero, normalised."""
    for v in candidates:
        n = np.linalg.norm(v)
        if n > 1e-12:
            return v / n
    raise ValueError("no direction")  # the last candidate is a unit vector: not reached


def _tube_radii(spans: list[tuple[float, float, float]], r_stem: float) -> list[float]:
    """Outer radius of each sheath, from ``(start, end, wall)`` along the stem, oldest first: its
    wall around whatever it encloses, the culm or the younger sheaths that start within its span
    (whose own radii come first)."""
    radii = [0.0] * len(spans)
    for k in range(len(spans) - 1, -1, -1):
        start, end, wall = spans[k]
        inside = [radii[j] for j in range(k + 1, len(spans)) if spans[j][0] < end]
        radii[k] = max([r_stem, *inside]) + wall
    return radii


class _Axis:
    """A stem's axis: the polyline through its segments' end points, by arc length (m), continued
    straight beyond either end."""

    def __init__(self, points: np.ndarray):
        self.points = points
        d = np.diff(points, axis=0)
        self.lengths = np.linalg.norm(d, axis=1)
        self.units = np.divide(d, self.lengths[:, None], out=np.zeros_like(d), where=self.lengths[:, None] > 0)
        self.arc = np.concatenate([[0.0], np.cumsum(self.lengths)])
        valid = np.flatnonzero(self.lengths > 0)
        self.first, self.last = self.units[valid[0]], self.units[valid[-1]]

    def locate(self, q: np.ndarray) -> tuple[float, float]:
        """Arc length (m) of the axis point nearest ``q`` (a point, m) and the distance (m) to it."""
        t = np.clip(np.einsum("ij,ij->i", q - self.points[:-1], self.units), 0.0, self.lengths)
        dist = np.linalg.norm(self.points[:-1] + t[:, None] * self.units - q, axis=1)
        i = int(np.argmin(dist))
        return float(self.arc[i] + t[i]), float(dist[i])

    def at(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Points and unit tangents at arc lengths ``s``."""
        s = np.asarray(s, float)
        i = np.clip(np.searchsorted(self.arc, s, side="right") - 1, 0, len(self.lengths) - 1)
        tangent = self.units[i]
        base, offset = self.points[i], s - self.arc[i]
        before, beyond = s < 0, s > self.arc[-1]
        tangent = np.where(before[:, None], self.first, np.where(beyond[:, None], self.last, tangent))
        base = np.where(before[:, None], self.points[0], np.where(beyond[:, None], self.points[-1], base))
        offset = np.where(before, s, np.where(beyond, s - self.arc[-1], offset))
        return base + offset[:, None] * tangent, tangent


def wrap_sheaths(segments: pd.DataFrame) -> pd.DataFrame:
    """A copy of the segment table with every leaf's sheath wrapped around its stem and its blade
    moved to the collar (the ``"wrapped"`` layout of the module doc). Coordinates in metres;
    plants are independent (``plant_id``), so a placed field gives the placed result.

    A sheath follows its stem's axis (the polyline of the stem's segments, continued straight
    beyond the stem's tip) from the point nearest the leaf's node, so the culm stays inside it
    where it bends; each sheath segment is the chord between two points of that axis, its
    ``length_m`` the chord's (CPlantBox's length to within 10⁻³, tested). A
    leaf goes with the nearest of its plant's stems (tillers), ranked among that stem's leaves by
    node position. Without a stem the sheath goes straight along CPlantBox's branching direction.
    """
    out = segments.copy()
    organ = organ_class(segments)
    xyz0, xyz1 = segments[_P0].to_numpy(float), segments[_P1].to_numpy(float)
    new0, new1 = xyz0.copy(), xyz1.copy()
    radius = segments["radius_m"].to_numpy(float).copy()
    lengths = segments["length_m"].to_numpy(float).copy()
    axes = segments[["bx", "by", "bz"]].to_numpy(float)
    plant, organ_id = segments["plant_id"].to_numpy(), segments["organ_id"].to_numpy()
    order = np.lexsort((segments["segment_index"].to_numpy(), organ_id, plant))
    for p in np.unique(plant):
        rows = order[plant[order] == p]
        organs = {o: rows[organ_id[rows] == o] for o in np.unique(organ_id[rows])}
        stems = [
            (_Axis(np.vstack([xyz0[r[:1]], xyz1[r]])), float(radius[r].max()))
            for r in organs.values()
            if organ[r[0]] == "stem" and np.linalg.norm(xyz1[r[-1]] - xyz0[r[0]]) > 0
        ]
        on_stem: dict[int, list] = {}  # stem index (-1: none) → [(node arc length, organ id, sheath, blade)]
        for o, r in organs.items():
            sheath, blade = r[organ[r] == "sheath"], r[organ[r] == "blade"]
            if not len(sheath):
                continue
            node = xyz0[sheath[0]]
            where = [ax.locate(node) for ax, _ in stems]
            j = int(np.argmin([d for _, d in where])) if stems else -1
            on_stem.setdefault(j, []).append((where[j][0] if stems else node[2], o, sheath, blade))
        for j, leaves in on_stem.items():
            leaves.sort(key=lambda x: (x[0], x[1]))  # by node: the oldest first
            tubes = _tube_radii(
                [(s0, s0 + lengths[sheath].sum(), float(radius[sheath].max())) for s0, _, sheath, _ in leaves],
                stems[j][1] if j >= 0 else 0.0,
            )
            for (s0, _, sheath, blade), r_tube in zip(leaves, tubes):
                s = np.concatenate([[0.0], np.cumsum(lengths[sheath])])
                if j >= 0:
                    points, tangents = stems[j][0].at(s0 + s)
                else:
                    axis = _unit(axes[sheath[0]], xyz1[sheath[0]] - xyz0[sheath[0]], np.array([0.0, 0.0, 1.0]))
                    points, tangents = xyz0[sheath[0]] + s[:, None] * axis, np.broadcast_to(axis, (len(s), 3))
                new0[sheath], new1[sheath] = points[:-1], points[1:]
                lengths[sheath] = np.linalg.norm(points[1:] - points[:-1], axis=1)
                radius[sheath] = r_tube
                if not len(blade):
                    continue
                old_collar, collar, axis = xyz1[sheath[-1]], points[-1], tangents[-1]
                # Towards where the collar lay, square to the stem (else towards the blade's first step).
                step = xyz1[blade[0]] - xyz0[blade[0]]
                side = _unit(
                    *(
                        v - np.dot(v, axis) * axis
                        for v in (old_collar - collar, step, np.eye(3)[np.argmin(np.abs(axis))])
                    )
                )
                shift = collar + r_tube * side - old_collar
                new0[blade], new1[blade] = xyz0[blade] + shift, xyz1[blade] + shift
    out[_P0], out[_P1] = new0, new1
    out["radius_m"], out["length_m"] = radius, lengths
    return out


__all__ = ["SHEATHS", "check_sheaths", "lay_sheaths", "wrap_sheaths"]
