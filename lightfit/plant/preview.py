"""Top and side view of a built field, as an image a person can look at (PNG, PDF, SVG, …)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.collections import PolyCollection  # noqa: E402

from lightfit.figure import figure_format  # noqa: E402
from lightfit.plant.field import FieldGeometry  # noqa: E402

# Buffer plants first so the measured plants are drawn on top.
COLOURS = {
    ("tube", False): "#cdb98f",
    ("blade", False): "#b9dcbf",
    ("tube", True): "#8b6d2e",
    ("blade", True): "#1f7a31",
}


def plot_field(geom: FieldGeometry, path: str | Path, title: str = "") -> Path:
    """Top view (x–y) and side view (x–z) of the mesh; buffer plants drawn pale, a periodic field's
    cell dashed. The format
    comes from the suffix of ``path`` (:func:`lightfit.figure.figure_format`)."""
    path = Path(path)
    figure_format(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    m = geom.mesh
    measured_ids = set(geom.segments.loc[geom.segments["measured"], "segment_id"].to_numpy().tolist())
    measured = np.fromiter((s in measured_ids for s in m.face_segment), bool, m.n_faces)
    tri = m.vertices[m.faces]
    fig, ax = plt.subplots(1, 2, figsize=(13, 6), constrained_layout=True, gridspec_kw={"width_ratios": [1, 1.3]})
    for (kind, meas), colour in COLOURS.items():
        sel = (m.face_is_blade == (kind == "blade")) & (measured == meas)
        if not sel.any():
            continue
        order = np.argsort(tri[sel][:, :, 2].mean(1))  # draw low faces first in the top view
        ax[0].add_collection(PolyCollection(tri[sel][order][:, :, :2], facecolors=colour, edgecolors="none"))
        order = np.argsort(-tri[sel][:, :, 1].mean(1))  # far (north) faces first in the side view
        ax[1].add_collection(PolyCollection(tri[sel][order][:, :, [0, 2]], facecolors=colour, edgecolors="none"))
    for a, (i, j), lab in ((ax[0], (0, 1), ("x east (m)", "y north (m)")), (ax[1], (0, 2), ("x east (m)", "z up (m)"))):
        pts = m.vertices[:, [i, j]]
        if a is ax[0] and geom.cell is not None:  # the dashed cell whole, also where it is wider than the plants
            pts = np.vstack([pts, geom.cell.corners_xy])
        lo, hi = pts.min(0), pts.max(0)
        pad = 0.03 * (hi - lo).max()
        a.set_xlim(lo[0] - pad, hi[0] + pad)
        a.set_ylim(lo[1] - pad, hi[1] + pad)
        a.set_aspect("equal")
        a.set_xlabel(lab[0])
        a.set_ylabel(lab[1])
    notes = ["pale: buffer plants"] if not measured.all() else []
    if geom.cell is not None:  # a periodic field: its cell, the plants repeated around it (none drawn)
        xy = np.vstack([geom.cell.corners_xy, geom.cell.corners_xy[:1]])  # closed
        ax[0].plot(xy[:, 0], xy[:, 1], "k--", lw=1)
        notes.append("dashed: the periodic cell, repeated without end")
    ax[0].set_title("top view" + (f" ({'; '.join(notes)})" if notes else ""))
    ax[1].set_title("side view from the south")
    # --n-plants counts the measured plants: a finite field's total alone read as a different field
    n_meas = int(geom.plants["measured"].sum())
    plants = f"{len(geom.plants)} plants" + (
        f" ({n_meas} measured, {len(geom.plants) - n_meas} buffer)" if n_meas < len(geom.plants) else ""
    )
    fig.suptitle(title or f"{plants}, {len(geom.segments)} shoot segments, {m.n_faces} triangles")
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
