"""Benchmark: could the projected sky's rays be importance-sampled over ray space from a pilot? (issue 16)

    python benchmarks/bench_sky_importance.py [--n-plants 500] [--rays 2e7] [--out JSON]

The sky seen directly is ≈ 0.6 of a median segment's variance in the projection
(bench_projection_split.py), and its rays land on segments in proportion to their visible area:
most of them on the sunlit upper blades, which need few, few on the shaded blades that set the
all-segment median (docs/light-sampling.md, "Which blades"). This measures the best that moving rays
towards the median's segments could buy, before anything is built into the estimator.

Ray space (the cell's ground × the unit square of cosine-weighted directions, measure 1) is cut
into C cells: square tiles of the ground of side ``tile`` × ``bins`` × ``bins`` bins of the
direction square. n rays with density q_c per cell (Σ q_c = 1, uniform inside a cell) count a
segment's first hits with weights 1 / (n C q_c); with independent rays (Poisson; the layout's
stratification is left out of both sides) the relative variance of segment s is

    V_s(q) = Σ_c h_cs / (C q_c) / H_s²,

h_cs the first hits of s in cell c among n uniform rays and H_s = Σ_c h_cs (uniform q: 1 / H_s).
Minimising Σ_{s ∈ T} V_s over q (Lagrange) gives q_c ∝ √(Σ_{s ∈ T} h_cs / H_s²); T is the band
of segments between the 30th and 70th percentile of uniform variance (those around the median),
and q is mixed with the uniform density, α / C + (1 − α) q (defensive: a cell the pilot saw
empty keeps rays).

Two independent sets of uniform rays are cast (the projection's sky layout: jittered grid, R₂
directions in tiled Z-order, two seeds). The *design* takes h from set A (the pilot), the
*evaluation* V_s from set B, so the gain is what a pilot of A's size would buy, the pilot's own
rays not charged (an upper bound). "in-sample" designs and evaluates on B: an optimistic bound
that knows where B's rays landed. Reported: median V over all segments and over blades,
uniform ÷ designed (above 1: the design pays), and the all-segment median's gain with the other
parts' variance held at 0.4 / 0.6 of the sky's (the measured split).

Writes benchmarks/results/sky_importance.json (or ``--out``; with the commit and the load average) and
prints a table (2 shared cores).
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import numpy as np
from bench_ray_layouts import cosine_directions, jittered_grid, r2_point  # same script folder
from provenance import out_option, wide_console, write_result
from rich.table import Table

import lightfit  # noqa: F401
from lightfit.light import backend
from lightfit.light.periodic import LEAF
from lightfit.light.scene import FieldScene, Optics
from lightfit.plant import Field, build, organ_class
from lightfit.precision import use_float64

use_float64()  # lightfit's precision policy (lightfit.precision), before any JAX array exists

OUT = Path(__file__).resolve().parent / "results" / "sky_importance.json"
#: (tile side in m, direction bins per axis): from cells coarser than a blade to finer than one.
CELLS = [(0.05, 4), (0.02, 8), (0.01, 8), (0.005, 16)]
ALPHAS = [0.1, 0.3, 0.5]
BAND = (30, 70)  # percentiles of the uniform variance: the segments around the median
SKY_SHARE = 0.6  # the sky seen directly's share of a median segment's variance


def cast_hits(fs, row_of_face, m: int, seed: int, chunk: int = 4_000_000) -> dict[str, np.ndarray]:
    """First hits of m sky rays in the projection's layout: the ray's cell-frame ground point
    (a, b from the cell's corner, m), its direction square (u1, u2) and the segment row it met."""
    mi = backend.mitsuba()
    import drjit as dr

    cell, tr = fs.cell, fs.tracer
    A, B = (float(v) for v in cell.size_m)
    (ex, ey), (fx, fy) = cell.axes
    cx, cy = cell.center_xy
    rng = np.random.default_rng(seed)
    shift = rng.random(2)
    a, b, j = jittered_grid(rng, cell, m)
    out = {k: [] for k in ("a", "b", "u1", "u2", "row")}
    for s in range(0, len(a), chunk):
        aa, bb, jj = a[s : s + chunk], b[s : s + chunk], j[s : s + chunk]
        u1, u2 = r2_point(shift, jj)
        w = cosine_directions(u1, u2)
        o = [cx + aa * ex + bb * fx, cy + aa * ey + bb * fy, np.full(len(aa), tr.z_top + 1e-3)]
        origin = mi.Point3f(*(mi.Float(x.astype(np.float32)) for x in o))
        direction = mi.Vector3f(*(mi.Float(-w[:, i].astype(np.float32)) for i in range(3)))
        status, _, _, _, pi = tr.walk(origin, direction, mi.Bool(True), cap=tr.cap, soil=True, test=False)
        dr.eval(status, pi.prim_index)
        hit = np.asarray(status) == LEAF
        prim = np.asarray(pi.prim_index)[hit]
        for k, v in (("a", aa + A / 2), ("b", bb + B / 2), ("u1", u1), ("u2", u2)):
            out[k].append(v[hit].astype(np.float32))
        out["row"].append(row_of_face[prim].astype(np.int32))
    return {k: np.concatenate(v) for k, v in out.items()}


def cell_counts(hits: dict, size_m, tile: float, bins: int, S: int):
    """(C, cell, row, h): the ray-space cells and each (cell, segment) pair's count of first hits."""
    A, B = (float(v) for v in size_m)
    nta, ntb = math.ceil(A / tile), math.ceil(B / tile)
    ta = np.minimum((hits["a"] / tile).astype(np.int64), nta - 1)
    tb = np.minimum((hits["b"] / tile).astype(np.int64), ntb - 1)
    d1 = np.minimum((hits["u1"] * bins).astype(np.int64), bins - 1)
    d2 = np.minimum((hits["u2"] * bins).astype(np.int64), bins - 1)
    c = ((ta * ntb + tb) * bins + d1) * bins + d2
    key, h = np.unique(c * S + hits["row"], return_counts=True)
    return nta * ntb * bins * bins, key // S, key % S, h.astype(np.float64)


def variances(C: int, design, evaluation, S: int, alpha: float) -> tuple[np.ndarray, np.ndarray]:
    """Relative variance of each segment's count: uniform rays and the design's density, both
    evaluated on ``evaluation``'s hits (the module docstring's V_s)."""
    cd, sd, hd = design
    ce, se, he = evaluation
    Hd = np.bincount(sd, hd, minlength=S)
    He = np.bincount(se, he, minlength=S)
    seen = (Hd > 0) & (He > 0)
    v_design = np.where(Hd > 0, 1 / np.maximum(Hd, 1), np.inf)
    lo, hi = np.percentile(v_design, BAND)
    band = (v_design >= lo) & (v_design <= hi)
    g = np.bincount(cd, hd * np.where(band, 1 / np.maximum(Hd, 1) ** 2, 0.0)[sd], minlength=C)
    q = alpha / C + (1 - alpha) * np.sqrt(g) / np.sqrt(g).sum()
    v_uniform = np.where(seen, 1 / np.maximum(He, 1), np.inf)
    v_q = np.where(seen, np.bincount(se, he / (C * q[ce]), minlength=S) / np.maximum(He, 1) ** 2, np.inf)
    return v_uniform, v_q


def gains(v_uniform, v_q, blade) -> dict[str, float]:
    other = (1 - SKY_SHARE) / SKY_SHARE * v_uniform
    return {
        "sky_median_all": float(np.median(v_uniform) / np.median(v_q)),
        "sky_median_blades": float(np.median(v_uniform[blade]) / np.median(v_q[blade])),
        "all_segment_median": float(np.median(v_uniform + other) / np.median(v_q + other)),
    }


def main(n_plants: int = 500, rays: float = 2e7) -> dict:
    geom = build(Field(n_plants=n_plants, seed=1, boundary="periodic"), progress=True)
    fs = FieldScene(geom.mesh, Optics.preset("prospect"), cell=geom.cell)
    seg_id = np.unique(fs.scene_mesh.face_segment)
    S = len(seg_id)
    row_of_face = np.searchsorted(seg_id, fs.scene_mesh.face_segment)
    blade = np.asarray(organ_class(geom.segments.set_index("segment_id").loc[seg_id]) == "blade")
    m = round(rays * fs.cell.area_m2)
    t = time.perf_counter()
    sets = [cast_hits(fs, row_of_face, m, seed) for seed in (1, 2)]
    cast_s = time.perf_counter() - t
    rows = []
    for tile, bins in CELLS:
        C, *pilot = cell_counts(sets[0], fs.cell.size_m, tile, bins, S)
        _, *evaluation = cell_counts(sets[1], fs.cell.size_m, tile, bins, S)
        for alpha in ALPHAS:
            out_of_sample = gains(*variances(C, pilot, evaluation, S, alpha), blade)
            in_sample = gains(*variances(C, evaluation, evaluation, S, alpha), blade)
            rows.append(
                {
                    "tile_m": tile,
                    "direction_bins": bins * bins,
                    "cells": C,
                    "rays_per_cell": m / C,
                    "alpha": alpha,
                    "pilot": out_of_sample,
                    "in_sample": in_sample,
                }
            )
    res = {
        "segments_in_cell": S,
        "sky_rays_per_m2": rays,
        "rays_per_set": m,
        "cast_s_two_sets": cast_s,
        "band_percentiles": BAND,
        "sky_share_of_variance": SKY_SHARE,
        "rows": rows,
    }
    write_result(OUT, res, indent=2)
    table = Table(title=f"sky rays importance-sampled from a pilot: {n_plants} plants, {rays:.0e} rays/m² per set")
    for c in ("tile", "bins", "rays/cell", "α", "pilot: sky all", "blades", "all-seg. median", "in-sample: sky all"):
        table.add_column(c, justify="right")
    for r in rows:
        table.add_row(
            f"{r['tile_m'] * 100:g} cm",
            str(r["direction_bins"]),
            f"{r['rays_per_cell']:.0f}",
            f"{r['alpha']:g}",
            f"{r['pilot']['sky_median_all']:.2f}×",
            f"{r['pilot']['sky_median_blades']:.2f}×",
            f"{r['pilot']['all_segment_median']:.2f}×",
            f"{r['in_sample']['sky_median_all']:.2f}×",
        )
    wide_console().print(table)
    return res


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n-plants", type=int, default=500)
    ap.add_argument("--rays", type=float, default=2e7, help="sky rays per m² of ground in each of the two sets")
    out_option(ap, OUT)
    a = ap.parse_args()
    OUT = a.out
    main(a.n_plants, a.rays)
