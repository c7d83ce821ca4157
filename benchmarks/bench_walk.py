"""Benchmark: what one projected sky ray costs, and how much of it is the periodic walk (issue 16).

    python benchmarks/bench_walk.py [--n-plants 500] [--rays 4e6] [--rounds 5] [--out JSON]

The sky's first walk is the largest part of a render of the 500-plant cell (docs/light-sampling.md, "Where
the time goes"). This bench takes ``--rays`` rays as the sky's first walk casts them (origins
uniform over the cell just above the canopy top, cosine-weighted downward directions; numpy,
seed 1) and times, alternating round by round in one process (the median of ``--rounds``):

* ``walk``: :meth:`PeriodicTracer.walk` in the default mesh's scene (the cell's faces and their
  overhanging images), as the projection casts them;
* ``one segment``: one Mitsuba intersection per ray in the same scene, bounded by the soil and not
  by the cell's sides: what the rays cost with no periodic loop (the ones that cross a side are
  cut short, so this is a lower bound of the loop's overhead);
* ``3 × 3 tiles``: one intersection in a scene of the cell's mesh and its eight neighbours (9× the
  faces): the alternative to wrapping, for rays that stay within one cell of where they start;
* the walk in meshes whose stem and sheath prisms (three quarters of the faces: long, thin
  triangles) are cut in two or four along each segment, or have four sides instead of six, and
  in a mesh of the blades alone: what the thin prisms cost the traversal.

It also counts the walk's side crossings and, for Dr.Jit's 16-wide packets of consecutive rays,
the loop's iterations per packet (a symbolic loop runs a packet until its last lane is done).

Writes benchmarks/results/walk.json (or ``--out``) and prints a table with the commit and load average
(2 shared cores: compare the rows of one run, not absolute times across runs).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
from provenance import out_option, wide_console, write_result  # same script folder
from rich.table import Table

import lightfit  # noqa: F401  (sets Dr.Jit's libLLVM before drjit is imported)
from lightfit.light.periodic import LEAF, SOIL
from lightfit.light.scene import FieldScene, Optics
from lightfit.plant import Field, build, organ_class
from lightfit.plant.mesh import Mesh, MeshResolution, blade_mesh, prism_mesh, shoot_mesh
from lightfit.precision import use_float64

use_float64()  # lightfit's precision policy (lightfit.precision), before any JAX array exists

OUT = Path(__file__).resolve().parent / "results" / "walk.json"
PACKET = 16  # Dr.Jit's LLVM vector width on this machine (AVX-512)


def sky_rays(cell, z_top: float, n: int, seed: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Origins uniform over the cell at ``z_top`` + 1 mm and cosine-weighted downward directions,
    both (3, n) float32."""
    rng = np.random.default_rng(seed)
    A, B = cell.size_m
    (ex, ey), (fx, fy) = cell.axes
    cx, cy = cell.center_xy
    a, b = (rng.random(n) - 0.5) * A, (rng.random(n) - 0.5) * B
    o = np.stack([cx + a * ex + b * fx, cy + a * ey + b * fy, np.full(n, z_top + 1e-3)])
    u1, u2 = rng.random(n), rng.random(n)
    r, phi = np.sqrt(u1), 2 * np.pi * u2
    d = np.stack([r * np.cos(phi), r * np.sin(phi), -np.sqrt(1 - u1)])
    return o.astype(np.float32), d.astype(np.float32)


def tiled(mesh: Mesh, cell) -> Mesh:
    """The cell's faces (with their images) and their eight neighbouring copies."""
    A, B = cell.size_m
    (ex, ey), (fx, fy) = cell.axes
    copies = []
    for i in (-1, 0, 1):
        for j in (-1, 0, 1):
            shift = np.array([i * A * ex + j * B * fx, i * A * ey + j * B * fy, 0.0])
            copies.append(Mesh(mesh.vertices + shift, mesh.faces, mesh.face_segment, mesh.face_is_blade))
    return Mesh.concatenate(copies)


def main(n_plants: int = 500, n_rays: int = 4_000_000, rounds: int = 5) -> dict:
    import drjit as dr

    optics = Optics.preset("prospect")
    geom = build(Field(n_plants=n_plants, seed=1, boundary="periodic"), progress=True)
    cell = geom.cell
    seg = geom.segments[geom.segments["organ_type"].isin(["stem", "leaf"]) & (geom.segments["length_m"] > 0)]
    blade = organ_class(seg) == "blade"
    blades = blade_mesh(seg[blade], MeshResolution())
    meshes = {
        "default mesh": shoot_mesh(geom.segments),
        "prisms cut in 2 along": Mesh.concatenate([blades, prism_mesh(seg[~blade], MeshResolution(along=2))]),
        "prisms cut in 4 along": Mesh.concatenate([blades, prism_mesh(seg[~blade], MeshResolution(along=4))]),
        "prisms with 4 sides": Mesh.concatenate([blades, prism_mesh(seg[~blade], MeshResolution(around=4))]),
        "blades alone": blades,
    }
    scenes = {k: FieldScene(m, optics, cell=cell) for k, m in meshes.items()}
    fs = scenes["default mesh"]
    mi, tracer = fs.mi, fs.tracer
    o_np, d_np = sky_rays(cell, tracer.z_top, n_rays)
    o, d = mi.Point3f(o_np), mi.Vector3f(d_np)
    bounded = mi.Ray3f(o, d)
    bounded.maxt = mi.Float((o_np[2] / -d_np[2]).astype(np.float32))  # to the soil plane
    dr.eval(o, d, bounded)
    big = tiled(fs.scene_mesh, cell)
    tiles_scene = FieldScene(big, optics).scene  # a finite scene: no periodic images, no tracer

    def walk(s):
        def run():
            t = s.tracer
            status, _, _, k, pi = t.walk(o, d, mi.Bool(True), cap=t.cap, soil=True, test=False)
            dr.eval(status, k, pi.prim_index)
            dr.sync_thread()
            return np.asarray(status), np.asarray(k)

        return run

    def one_segment(scene):
        def run():
            pi = scene.ray_intersect_preliminary(bounded, False, True)
            dr.eval(pi.prim_index, pi.t)
            dr.sync_thread()

        return run

    cases = {f"walk, {k}": walk(s) for k, s in scenes.items()}
    cases["one segment, no loop (default mesh)"] = one_segment(fs.scene)
    cases["3 × 3 tiles, no loop"] = one_segment(tiles_scene)
    faces = {f"walk, {k}": s.n_scene_faces for k, s in scenes.items()}
    faces["one segment, no loop (default mesh)"] = fs.n_scene_faces
    faces["3 × 3 tiles, no loop"] = big.n_faces
    for f in cases.values():  # compile, first touch
        f()
    times = {k: [] for k in cases}
    for _ in range(rounds):
        for k, f in cases.items():
            t = time.perf_counter()
            f()
            times[k].append(time.perf_counter() - t)
    status, k = cases["walk, default mesh"]()
    packets = k[: len(k) // PACKET * PACKET].reshape(-1, PACKET)
    base = float(np.median(times["walk, default mesh"]))
    rows = [
        {
            "case": name,
            "faces": int(faces[name]),
            "median_s": float(np.median(ts)),
            "times_s": ts,
            "m_rays_per_s": n_rays / float(np.median(ts)) / 1e6,
            "time_over_walk": float(np.median(ts)) / base,
        }
        for name, ts in times.items()
    ]
    res = {
        "n_plants_measured": int(Field(n_plants=n_plants).n_measured),
        "cell_m": list(cell.size_m),
        "z_top_m": float(tracer.z_top),
        "rays": n_rays,
        "rounds": rounds,
        "crossings_mean": float(k.mean()),
        "crossing_share": float(np.mean(k >= 1)),
        "two_or_more_crossings_share": float(np.mean(k >= 2)),
        "lane_iterations_mean": float(k.mean() + 1),
        "packet_iterations_mean": float(packets.max(axis=1).mean() + 1),
        "status_share": {name: float(np.mean(status == v)) for name, v in (("leaf", LEAF), ("soil", SOIL))},
        "rows": rows,
    }
    res = json.loads(write_result(OUT, res, indent=2).read_text())  # with the provenance, for the summary
    console = wide_console()
    t = Table(title=f"sky rays' first walk: {n_rays:.0e} rays, {res['n_plants_measured']} plants, 2 CPU cores")
    for c in ("case", "faces", "time", "M rays/s", "÷ walk"):
        t.add_column(c, justify="right")
    for q in rows:
        t.add_row(
            q["case"],
            f"{q['faces']:,}",
            f"{q['median_s']:.2f} s",
            f"{q['m_rays_per_s']:.2f}",
            f"{q['time_over_walk']:.2f}",
        )
    console.print(t)
    console.print(
        f"side crossings per ray {res['crossings_mean']:.2f} ({res['crossing_share']:.0%} cross at least once); "
        f"loop iterations per ray {res['lane_iterations_mean']:.2f}, per {PACKET}-wide packet "
        f"{res['packet_iterations_mean']:.2f}"
    )
    console.print(
        f"commit {res['lightfit_commit']}, load {res['load_average_start']:.1f} → {res['load_average_end']:.1f}"
    )
    return res


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n-plants", type=int, default=500)
    ap.add_argument("--rays", type=float, default=4e6)
    ap.add_argument("--rounds", type=int, default=5)
    out_option(ap, OUT)
    a = ap.parse_args()
    OUT = a.out
    main(a.n_plants, int(a.rays), a.rounds)
