"""Benchmark: what a projected sky ray costs and how its layout moves the per-segment noise (issue 16).

    python benchmarks/bench_ray_layouts.py [--n-plants 500] [--rays 2e7] [--replicates 8]
        [--vector-width N] [--layouts NAME,NAME] [--out JSON]

The sky seen directly is ≈ 0.56 of a median segment's variance in the projection
(bench_projection_split.py); this measures, outside the estimator, whether another layout of the
same number of sky rays would lower variance × time. On the defaults' field (the measured plants as
one periodic cell) R replicates of m rays each are cast down from the canopy top and walked
through the cell (:meth:`PeriodicTracer.walk`, as the projection's first rays), in these layouts:

* ``per-ray R2``: a jittered grid over the cell, each ray its own cosine-weighted direction (an R₂
  sequence over the grid cells in the projection's tiled Z-order, ``projection.SKY_TILE``, shifted
  per replicate): the projection's sky today;
* ``tiles x bins``: the same rays traced in another order (5 cm tiles of the cell, then 8 × 8 bins
  of the direction's unit square): the values would be bitwise the same, only the order of the
  walk changes (what a sort would buy);
* ``D directions``: each replicate D directions (R₂ over the direction index, shifted per
  replicate), each lighting the whole cell from its own jittered grid of m/D rays: parallel,
  sun-like rays, coherent for the tracer, but only R·D directions in all;
* ``sun``: one direction (the sun's layout, for the rate it reaches);
* ``strata``: directions stratified per 16 × 16-cell block of the grid instead of the R₂
  sequence: the direction square cut into 16 × 16 strata, each block's cells taking every stratum
  once (cell (x, y) of a block the stratum :data:`STRATA_MAP` · (x, y) mod 16, so that neighbouring
  cells take distant strata), jittered within the stratum and shifted per replicate; traced in
  the order a projection could draw them without a sort: 64 × 64-cell tiles, and within a tile
  stratum by stratum, each stratum's 16 rays (one per block) a packet;
* ``strata rows``: the same rays traced row by row (its rate against ``strata`` is what the
  drawing order buys; its SE is the layout's, the same rays).

Per layout: rays per second of the walk (the median over the R replicates' walks, after a
warm-up), and the relative standard error of each segment's count of first hits (the sky seen
directly of an isotropic sky, unit weights; the spread of the R replicates / √R), median over
blades and over all segments. ``variance × time`` is the blades' median relative SE squared times
the walk time, relative to ``per-ray R2`` (below 1: the layout pays). ``--vector-width`` sets
Dr.Jit's LLVM packet width before anything is compiled (default: the CPU's, 16 with AVX-512) through
``backend.set_llvm_target`` (drjit-core's ``jit_llvm_set_target``), to measure
whether narrower packets trace incoherent rays faster.

Writes benchmarks/results/ray_layouts.json (or ray_layouts_width<W>.json, or ``--out``; with the commit
and the load average) and prints a table (2 shared cores: compare rows of one run).
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import numpy as np
from provenance import wide_console, write_result  # same script folder
from rich.table import Table

import lightfit  # noqa: F401
from lightfit.light import backend
from lightfit.light.periodic import LEAF
from lightfit.light.projection import _R2, SKY_TILE, _sky_order
from lightfit.light.scene import FieldScene, Optics
from lightfit.plant import Field, build, organ_class
from lightfit.precision import use_float64

use_float64()  # lightfit's precision policy (lightfit.precision), before any JAX array exists

RESULTS = Path(__file__).resolve().parent / "results"


def set_vector_width(width: int) -> int:
    """Dr.Jit's LLVM packet width for every kernel compiled from now on (this CPU and its features
    kept); returns the width in force."""
    cpu, features, _ = backend.llvm_target()
    backend.set_llvm_target(cpu, features, width)
    return backend.llvm_target()[2]


def cosine_directions(u1: np.ndarray, u2: np.ndarray) -> np.ndarray:
    """Unit vectors towards the sky, cosine-weighted about the zenith, from the unit square."""
    r, phi = np.sqrt(u1), 2 * np.pi * u2
    return np.stack([r * np.cos(phi), r * np.sin(phi), np.sqrt(np.maximum(0.0, 1.0 - u1))], 1)


def r2_point(shift, j):
    """The j-th point of the projection's R₂ sequence (generators 1/g, 1/g², g the plastic number),
    shifted by ``shift`` on the unit square: the sky's direction square (u1, u2)."""
    return (shift[0] + j / _R2) % 1, (shift[1] + j / _R2**2) % 1


def jittered_grid(rng, cell, m: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cell-frame coordinates (a, b), m, of about m points, one per cell of a grid, row by row, and
    each point's place in the sky's direction sequence (the projection's tiled Z-order)."""
    A, B = (float(v) for v in cell.size_m)
    nx = max(1, round(math.sqrt(m * A / B)))
    ny = max(1, -(-m // nx))
    c = np.arange(nx * ny, dtype=np.uint64)
    ia, ib = c % np.uint64(nx), c // np.uint64(nx)
    j = _sky_order(ia, ib, SKY_TILE).astype(np.float64)
    return (ia + rng.random(c.size)) * A / nx - A / 2, (ib + rng.random(c.size)) * B / ny - B / 2, j


#: Stratum (s_x, s_y) = M · (x, y) mod 16 of cell (x, y) in its 16 × 16 block (``strata`` layouts):
#: odd determinant, so a bijection of the block's cells onto the strata; neighbours along x and y
#: differ by (7, 3) and (4, 9) sixteenths of the direction square.
STRATA_MAP = np.array([[7, 4], [3, 9]])


def strata_layout(rng, cell, m: int, shift: np.ndarray, coherent: bool):
    """One replicate's ``strata`` rays (module doc): cell-frame origins and directions."""
    A, B = (float(v) for v in cell.size_m)
    nx = max(1, round(math.sqrt(m * A / B)))
    ny = max(1, -(-m // nx))
    c = np.arange(nx * ny)
    ia, ib = c % nx, c // nx
    s = (STRATA_MAP @ np.stack([ia % 16, ib % 16])) % 16
    u1 = (shift[0] + (s[0] + rng.random(c.size)) / 16) % 1
    u2 = (shift[1] + (s[1] + rng.random(c.size)) / 16) % 1
    a, b = (ia + rng.random(c.size)) * A / nx - A / 2, (ib + rng.random(c.size)) * B / ny - B / 2
    w = cosine_directions(u1, u2)
    if coherent:  # tiles of 64 × 64 cells, then stratum (the shifted one), then block
        tile = (ib // 64) * (nx // 64 + 1) + ia // 64
        su = np.floor(u1 * 16) * 16 + np.floor(u2 * 16)
        order = np.lexsort(((ib // 16) * (nx // 16 + 1) + ia // 16, su, tile))
        a, b, w = a[order], b[order], w[order]
    return a, b, w


def layout(name: str, rng, cell, m: int, shift: np.ndarray, sun: np.ndarray):
    """One replicate's rays of a layout: cell-frame origins (a, b) and directions towards the sky."""
    if name.startswith("strata"):
        return strata_layout(rng, cell, m, shift, coherent=name == "strata")
    if name.startswith("D="):
        d = int(name[2:])
        parts = [jittered_grid(rng, cell, -(-m // d)) for _ in range(d)]
        j = np.arange(d)
        w = cosine_directions(*r2_point(shift, j))
        a = np.concatenate([p[0] for p in parts])
        b = np.concatenate([p[1] for p in parts])
        return a, b, np.repeat(w, [len(p[0]) for p in parts], axis=0)
    a, b, j = jittered_grid(rng, cell, m)
    if name == "sun":
        return a, b, np.repeat(sun[None, :], len(a), axis=0)
    c = np.arange(len(a))
    u1, u2 = r2_point(shift, j)
    w = cosine_directions(u1, u2)
    if name == "tiles x bins":
        A, B = (float(v) for v in cell.size_m)
        ta, tb = np.floor((a / A + 0.5) * A / 0.05), np.floor((b / B + 0.5) * B / 0.05)
        order = np.lexsort((c, np.floor(u2 * 8), np.floor(u1 * 8), tb, ta))
        a, b, w = a[order], b[order], w[order]
    return a, b, w


#: The layouts measured (the first is the reference of ``variance × time``).
LAYOUTS = ("per-ray R2", "tiles x bins", "D=16", "D=64", "D=256", "D=1024", "sun", "strata", "strata rows")


def main(
    n_plants: int = 500,
    rays: float = 2e7,
    replicates: int = 8,
    vector_width: int | None = None,
    out: Path | None = None,
    layouts: tuple[str, ...] | None = None,
) -> dict:
    mi = backend.mitsuba()  # the LLVM backend first: its target is then set before any kernel exists
    width = set_vector_width(vector_width) if vector_width else None
    import drjit as dr

    geom = build(Field(n_plants=n_plants, seed=1, boundary="periodic"), progress=True)
    fs = FieldScene(geom.mesh, Optics.preset("prospect"), cell=geom.cell)
    fs.set_sun(50.0, 180.0)
    cell, tr = fs.cell, fs.tracer
    segments = geom.segments.set_index("segment_id")
    seg_id = np.unique(fs.scene_mesh.face_segment)
    row_of_face = np.searchsorted(seg_id, fs.scene_mesh.face_segment)
    blade = organ_class(segments.loc[seg_id]) == "blade"
    m = round(rays * cell.area_m2 / replicates)
    (ex, ey), (fx, fy) = cell.axes
    cx, cy = cell.center_xy

    def walk(a, b, w):
        o = [cx + a * ex + b * fx, cy + a * ey + b * fy, np.full(len(a), tr.z_top + 1e-3)]
        origin = mi.Point3f(*(mi.Float(x.astype(np.float32)) for x in o))
        direction = mi.Vector3f(*(mi.Float(-w[:, i].astype(np.float32)) for i in range(3)))
        dr.eval(origin, direction)
        t = time.perf_counter()
        status, _, _, _, pi = tr.walk(origin, direction, mi.Bool(True), cap=tr.cap, soil=True, test=False)
        dr.sync_thread()
        return time.perf_counter() - t, np.asarray(status), np.asarray(pi.prim_index)

    names = list(layouts or LAYOUTS)
    rng = np.random.default_rng(12345)
    shifts = rng.random((replicates, 2))
    walk(*layout(names[0], rng, cell, m, shifts[0], fs.sun))  # compile the walk
    rows = {}
    for name in names:
        counts = np.zeros((len(seg_id), replicates))
        times = []
        for r in range(replicates):
            rays_r = layout(name, rng, cell, m, shifts[r], fs.sun)
            dt, status, prim = walk(*rays_r)
            times.append(dt)
            counts[:, r] = np.bincount(row_of_face[prim[status == LEAF]], minlength=len(seg_id))
        mean = counts.mean(1)
        with np.errstate(divide="ignore", invalid="ignore"):
            rse = np.where(mean > 0, counts.std(1, ddof=1) / np.sqrt(replicates) / mean, np.nan)
        t = float(np.median(times))
        rows[name] = {
            "rays_per_s": m / t,
            "walk_s_per_replicate": t,
            "median_rse_blades": float(np.nanmedian(rse[blade])),
            "median_rse_all": float(np.nanmedian(rse)),
            "mean_hits_per_segment": float(mean.mean()),
        }
    base = rows[names[0]]
    for row in rows.values():
        row["variance_x_time_blades"] = (row["median_rse_blades"] ** 2 * row["walk_s_per_replicate"]) / (
            base["median_rse_blades"] ** 2 * base["walk_s_per_replicate"]
        )
    res = {
        "llvm_vector_width": width,
        "n_plants_measured": int(Field(n_plants=n_plants).n_measured),
        "segments_in_cell": len(seg_id),
        "rays_per_m2": rays,
        "replicates": replicates,
        "rays_per_replicate": m,
        "layouts": rows,
    }
    out = out or RESULTS / ("ray_layouts.json" if width is None else f"ray_layouts_width{width}.json")
    write_result(out, res, indent=2)
    t = Table(
        title=f"sky ray layouts: {n_plants} plants, {rays:.1e} rays/m², R={replicates}, 2 CPU cores"
        + ("" if width is None else f", LLVM width {width}")
    )
    for c in ("layout", "M rays/s", "median rse blades", "median rse all", "variance × time (blades)"):
        t.add_column(c, justify="right")
    for name, r in rows.items():
        t.add_row(
            name,
            f"{r['rays_per_s'] / 1e6:.2f}",
            f"{r['median_rse_blades']:.2%}",
            f"{r['median_rse_all']:.2%}",
            f"{r['variance_x_time_blades']:.2f}",
        )
    wide_console().print(t)
    return res


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n-plants", type=int, default=500)
    ap.add_argument("--rays", type=float, default=2e7, help="sky rays per m² of ground, all replicates")
    ap.add_argument("--replicates", type=int, default=8)
    ap.add_argument("--vector-width", type=int, default=None, help="Dr.Jit LLVM packet width (default: the CPU's)")
    ap.add_argument(
        "--out",
        type=Path,
        default=None,
        help="JSON to write (default benchmarks/results/ray_layouts.json, with --vector-width W "
        "ray_layouts_width<W>.json: the tracked results the docs cite)",
    )
    ap.add_argument(
        "--layouts", default=None, help="layouts to measure, comma-separated (default all; the first is the reference)"
    )
    a = ap.parse_args()
    chosen = None if a.layouts is None else tuple(x.strip() for x in a.layouts.split(","))
    unknown = [x for x in chosen or () if x not in LAYOUTS]
    if unknown:
        ap.error(f"--layouts {unknown}: not among {', '.join(LAYOUTS)}")
    main(a.n_plants, a.rays, a.replicates, a.vector_width, a.out, chosen)
