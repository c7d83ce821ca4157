"""Benchmark: render time of the periodic cell vs the finite 2-buffer-row field (issue 13).

    python benchmarks/bench_periodic_render.py [--plants 16 100] [--samples 64] [--repeat 2] [--day] [--walk]
        [--out JSON]

Side by side in one run, for the same measured plants (N × N, seed 1) at two sun positions
(the 2016-04-20 10:00 UTC sun of the main job, and a low sun at 15° elevation, same azimuth),
K samples, 3 bounces, all measured segments:

- ``finite``: the measured plants inside 2 buffer rows (the default when this was written; it
  grows and meshes the buffer plants too, ≈ 2× the plants for 10 × 10);
- ``periodic``: the measured plants as one periodic cell (ray wrapping,
  :class:`lightfit.light.periodic.PeriodicTracer`).

For each: primal render time and reverse-mode gradient (vjp) time, best of ``--repeat`` after
one warm-up call (compiled kernels cached), and for periodic the rays / side crossings per kind
of ray from ``Irradiance.meta["periodic"]`` plus a profile of where the periodic time goes (each
walk timed with ``dr.sync_thread`` around it, per kind of ray: ``path``, ``sun``, ``nee``). The
ratios periodic ÷ finite are what counts: absolute times on the shared 2-core machine are noisy.
With ``--day`` the main job's pipeline is timed end to end as well: build the 10 × 10
geometry from the plant cache, make the scene and render every daytime step of the replication
forcing (2016-04-20, primal, K samples), finite and periodic taking turns at each step.

With ``--walk`` the ray walk itself is measured on the first (cosine-sampled) rays of all
10 × 10 segments, best of 5, taking turns: one clipped intersection per ray (crossings
disabled, ``cap=0``), the full walk, the walk through a super-cell of (r_a, r_b) neighbour cells
held as geometry (explicit copies in the BVH: fewer crossings, a larger BVH), and a plain
intersection of the same rays in the finite 2-buffer-row field.

Writes benchmarks/results/periodic_render.json (or ``--out``) and prints a table.
"""

from __future__ import annotations

import argparse
import math
import time
from collections import defaultdict
from pathlib import Path

import numpy as np
import pandas as pd
from provenance import out_option, write_result

import lightfit  # noqa: F401
from lightfit import weather
from lightfit.light.estimator import SegmentEstimator
from lightfit.light.scene import FieldScene, Optics
from lightfit.plant import Field, build
from lightfit.precision import use_float64

use_float64()  # lightfit's precision policy (lightfit.precision), before any JAX array exists

OUT = Path(__file__).resolve().parent / "results" / "periodic_render.json"
LOW_SUN_DEG = 15.0


def _sync():
    import drjit as dr

    dr.sync_thread()


def profile(est: SegmentEstimator) -> dict:
    """Seconds spent in the periodic walks of one primal render, per kind of ray (synchronised).

    Each walk is timed as its own kernel (``fuse=False``); an ordinary render fuses them into
    one kernel, so ``render_s`` here is that of the unfused render."""
    import drjit as dr

    tracer = est.fs.tracer
    spent: dict = defaultdict(float)
    kind = ["path"]
    walk, occluded = tracer.walk, est._occluded

    def timed_walk(o, d, active, **kw):
        dr.eval(o, d, active)
        _sync()
        t = time.perf_counter()
        out = walk(o, d, active, **(kw | {"fuse": False}))  # its own kernel, to be timed
        _sync()
        spent[kind[0]] += time.perf_counter() - t
        kind[0] = "path"
        return out

    def timed_occluded(k, o, d, active):
        kind[0] = k
        return occluded(k, o, d, active)

    tracer.walk, est._occluded = timed_walk, timed_occluded
    try:
        est.render()  # warm with the wrappers
        spent.clear()
        est._kept = None  # trace the paths again (a render keeps them for the next sun)
        _sync()
        t = time.perf_counter()
        est.render()
        _sync()
        total = time.perf_counter() - t
    finally:
        del tracer.walk, est._occluded
    return {"render_s": total, **{f"walk_{k}_s": v for k, v in spent.items()}}


def estimators(geom, fs, sun, samples, bounces):
    fs.set_sun(*sun)
    ids = geom.segments.loc[geom.segments["measured"], "segment_id"].to_numpy()
    est = SegmentEstimator(fs, ids, samples=samples, bounces=bounces, seed=1)
    ct = {"absorbed_sun": np.ones(len(ids)), "absorbed_sky": np.full(len(ids), 0.3)}
    return est, ct


def summary(est, r) -> dict:
    a = r.meta["area_m2"]
    res = {
        "segments": len(est.segment_id),
        "evaluations": est.n_evaluations,
        "canopy_absorbed_sun": float(r.absorbed_sun @ a),
        "canopy_absorbed_sky": float(r.absorbed_sky @ a),
        "canopy_absorbed_sun_sd": float(np.sqrt(((a * r.se["absorbed_sun"]) ** 2).sum())),
        "canopy_absorbed_sky_sd": float(np.sqrt(((a * r.se["absorbed_sky"]) ** 2).sum())),
    }
    if "periodic" in r.meta:
        res["periodic"] = r.meta["periodic"]
    return res


def timed_interleaved(setups: dict, repeat: int) -> dict:
    """Best of ``repeat`` primal and vjp times per setup, the setups taking turns in each round
    (so that load from other processes on the shared machine hits them alike). Each primal is a
    whole render (its paths traced, not kept from the previous call: ``--day`` times the kept
    paths of a day's steps)."""
    best = {k: {"primal_s": math.inf, "vjp_s": math.inf} for k in setups}
    results = {}
    for k, (est, ct) in setups.items():  # warm up: compile or load kernels
        est.fs.set_sun(*est._sun)
        results[k] = est.render()
        est.vjp(ct)
    for _ in range(repeat):
        for what in ("primal_s", "vjp_s"):
            for k, (est, ct) in setups.items():
                est.fs.set_sun(*est._sun)
                est._kept = None  # a whole render: paths traced again, not kept from the last one
                _sync()
                t = time.perf_counter()
                est.render() if what == "primal_s" else est.vjp(ct)
                _sync()
                best[k][what] = min(best[k][what], time.perf_counter() - t)
    return {k: {**best[k], **summary(setups[k][0], results[k])} for k in setups}


def main(
    plants=(16, 100), samples: int = 64, bounces: int = 3, repeat: int = 2, day: bool = False, walk: bool = False
) -> dict:
    row = weather.load("2016-04-20").loc[pd.Timestamp("2016-04-20 10:00", tz="UTC")]
    main_sun = (float(row["sun_elevation_deg"]), float(row["sun_azimuth_deg"]))
    suns = {"2016-04-20 10:00 UTC": main_sun, f"low {LOW_SUN_DEG:g}°": (LOW_SUN_DEG, main_sun[1])}
    res = {"samples": samples, "bounces": bounces, "repeat": repeat, "suns": suns, "cases": []}
    for n in plants:
        geoms = {}
        for name, kw in (("finite", dict(boundary="finite", buffer_rows=2)), ("periodic", dict(boundary="periodic"))):
            g = build(Field(n_plants=n, seed=1, **kw))
            t = time.perf_counter()
            fs = FieldScene(g.mesh, Optics.preset("paper"), cell=g.cell)
            geoms[name] = (g, fs, time.perf_counter() - t)
        for sun_name, sun in suns.items():
            case = {"n_plants": n, "sun": sun_name, "sun_deg": sun}
            setups = {}
            for name, (g, fs, _) in geoms.items():
                est, ct = estimators(g, fs, sun, samples, bounces)
                est._sun = sun
                setups[name] = (est, ct)
            timed = timed_interleaved(setups, repeat)
            for name, (g, fs, t_scene) in geoms.items():
                case[name] = {
                    "plants_built": len(g.plants),
                    "mesh_faces": int(g.mesh.n_faces),
                    "scene_faces": int(fs.n_scene_faces),
                    "scene_s": t_scene,
                    **timed[name],
                }
            fs = geoms["periodic"][1]
            fs.set_sun(*sun)
            case["periodic"]["profile"] = profile(setups["periodic"][0])
            f, p = case["finite"], case["periodic"]
            p["primal_ratio"], p["vjp_ratio"] = p["primal_s"] / f["primal_s"], p["vjp_s"] / f["vjp_s"]
            res["cases"].append(case)
            print(_row(case), flush=True)
    if day:
        res["day"] = main_job_day(samples, bounces)
    if walk:
        res["walk"] = walk_costs()
    write_result(OUT, res, indent=2, default=float)
    print()
    print(f"K = {samples}, {bounces} bounces, best of {repeat}; ratio = periodic ÷ finite (2 buffer rows)")
    print(_header())
    for case in res["cases"]:
        print(_row(case))
    if day:
        d = res["day"]
        print(f"\nmain job's day ({d['steps']} daytime steps, 10 × 10 plants, K = {samples}):")
        print(
            "| field | plants built | build s | scene s | render s (all steps) | total s |\n|---|---|---|---|---|---|"
        )
        for k in ("finite", "periodic"):
            v = d[k]
            print(
                f"| {k} | {v['plants_built']} | {v['build_s']:.2f} | {v['scene_s']:.2f} | {v['render_s']:.2f} | "
                f"{v['total_s']:.2f} |"
            )
        print(f"periodic ÷ finite: render {d['render_ratio']:.2f}, total {d['total_ratio']:.2f}")
    if walk:
        w = res["walk"]
        print(f"\nwalk of the first rays of 10 × 10 ({w['rays']} rays), best of 5:")
        print("| what | scene faces | s | ÷ one clipped intersection | crossings / ray |\n|---|---|---|---|---|")
        for k, v in w["seconds"].items():
            cr = w["crossings_per_ray"].get(k)
            print(
                f"| {k} | {w['scene_faces'].get(k, '')} | {v:.3f} | {w['over_one_clipped_intersection'][k]:.2f} | "
                f"{'' if cr is None else f'{cr:.3f}'} |"
            )
    return res


def walk_costs(n_plants: int = 100, rings=((1, 0), (2, 0), (1, 1)), repeat: int = 5) -> dict:
    """Seconds per walk of the same first rays (module doc, ``--walk``), and crossings per ray."""
    import drjit as dr

    from lightfit.light.periodic import PeriodicCell

    g = build(Field(n_plants=n_plants, seed=1, boundary="periodic"))
    gf = build(Field(boundary="finite", n_plants=n_plants, seed=1, buffer_rows=2))
    fs = FieldScene(g.mesh, Optics.preset("paper"), cell=g.cell)
    fin = FieldScene(gf.mesh, Optics.preset("paper"))
    est = SegmentEstimator(fs, g.segments["segment_id"].to_numpy(), samples=64, bounces=3, seed=1)
    o, _, _, d, _, _ = est._arrays()
    mi, cell = fs.mi, g.cell
    scenes = {"cell": fs}
    for ra, rb in rings:  # the super-cell (2r_a + 1)A × (2r_b + 1)B holding the cell's copies
        big = PeriodicCell(cell.along_m * (2 * ra + 1), cell.across_m * (2 * rb + 1), cell.row_direction_deg)
        copies = [g.mesh]
        for i in range(-ra, ra + 1):
            for j in range(-rb, rb + 1):
                if i or j:
                    v = g.mesh.vertices.copy()
                    v[:, :2] += cell.lattice_shift(i, j)
                    copies.append(type(g.mesh)(v, g.mesh.faces, g.mesh.face_segment, g.mesh.face_is_blade))
        scenes[f"ring {ra},{rb}"] = FieldScene(type(g.mesh).concatenate(copies), Optics.preset("paper"), cell=big)

    def walk(sc, cap=None):
        def f():
            out = sc.tracer.walk(o, d, True, cap=sc.tracer.cap if cap is None else cap, soil=True, test=False)
            dr.eval(out)
            return out

        return f

    def plain():
        si = fin.scene.ray_intersect(mi.Ray3f(o, d), True)
        dr.eval(si.t)

    fns = {"finite: plain intersection": plain, "periodic: one clipped intersection (cap 0)": walk(fs, 0)}
    fns |= {f"periodic walk, {k}": walk(sc) for k, sc in scenes.items()}
    crossings = {k: float(np.asarray(f()[3]).mean()) for k, f in fns.items() if k.startswith("periodic walk")}
    best = dict.fromkeys(fns, math.inf)
    for _ in range(repeat):
        for k, f in fns.items():
            _sync()
            t = time.perf_counter()
            f()
            _sync()
            best[k] = min(best[k], time.perf_counter() - t)
    faces = {f"periodic walk, {k}": sc.n_scene_faces for k, sc in scenes.items()}
    faces["finite: plain intersection"] = fin.n_scene_faces
    return {
        "rays": int(dr.width(o)),
        "seconds": best,
        "over_one_clipped_intersection": {
            k: v / best["periodic: one clipped intersection (cap 0)"] for k, v in best.items()
        },
        "crossings_per_ray": crossings,
        "scene_faces": faces,
    }


def main_job_day(samples: int, bounces: int, n_plants: int = 100) -> dict:
    """The main job's light, end to end: geometry from the plant cache, scene, every daytime step."""
    from lightfit import replication

    w = replication.forcing()
    suns = w.loc[w["sun_elevation_deg"] > 0, ["sun_elevation_deg", "sun_azimuth_deg"]].to_numpy(float)
    out, est = {}, {}
    for name, kw in (("finite", dict(boundary="finite", buffer_rows=2)), ("periodic", dict(boundary="periodic"))):
        t = time.perf_counter()
        g = build(Field(n_plants=n_plants, seed=1, **kw))
        t_build = time.perf_counter() - t
        t = time.perf_counter()
        fs = FieldScene(g.mesh, Optics.preset("paper"), cell=g.cell)
        ids = g.segments.loc[g.segments["measured"], "segment_id"].to_numpy()
        est[name] = SegmentEstimator(fs, ids, samples=samples, bounces=bounces, seed=1)
        _sync()
        out[name] = {"plants_built": len(g.plants), "build_s": t_build, "scene_s": time.perf_counter() - t}
        out[name]["render_s"] = 0.0
    for el, az in suns:  # the setups take turns at each step
        for name, e in est.items():
            e.fs.set_sun(el, az)
            _sync()
            t = time.perf_counter()
            e.render()
            _sync()
            out[name]["render_s"] += time.perf_counter() - t
    for v in out.values():
        v["total_s"] = v["build_s"] + v["scene_s"] + v["render_s"]
    return {
        "steps": len(suns),
        **out,
        "render_ratio": out["periodic"]["render_s"] / out["finite"]["render_s"],
        "total_ratio": out["periodic"]["total_s"] / out["finite"]["total_s"],
    }


def _header() -> str:
    cols = ["plants", "sun", "finite primal s", "periodic primal s", "primal ratio", "vjp ratio"]
    cols += ["crossings / ray (path, sun, nee)", "walk s (path, sun, nee) of render s"]
    return "| " + " | ".join(cols) + " |\n|" + "---|" * len(cols)


def _row(c: dict) -> str:
    p = c["periodic"]
    m = p["periodic"]
    cr = ", ".join(f"{m[k]['crossings'] / max(m[k]['rays'], 1):.2f}" for k in ("path", "sun", "nee"))
    pr = p.get("profile", {})
    walk = ", ".join(f"{pr.get(f'walk_{k}_s', float('nan')):.2f}" for k in ("path", "sun", "nee"))
    cols = [c["n_plants"], c["sun"], f"{c['finite']['primal_s']:.2f}", f"{p['primal_s']:.2f}"]
    cols += [f"{p['primal_ratio']:.2f}", f"{p['vjp_ratio']:.2f}"]
    cols += [cr, f"{walk} of {pr.get('render_s', float('nan')):.2f}"]
    return "| " + " | ".join(str(x) for x in cols) + " |"


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--plants", type=int, nargs="+", default=[16, 100])
    ap.add_argument("--samples", type=int, default=64)
    ap.add_argument("--bounces", type=int, default=3)
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--day", action="store_true", help="also time the main job's day end to end")
    ap.add_argument("--walk", action="store_true", help="also time the walk alone, and rings of copies")
    out_option(ap, OUT)
    a = ap.parse_args()
    OUT = a.out
    main(tuple(a.plants), a.samples, a.bounces, a.repeat, a.day, a.walk)
