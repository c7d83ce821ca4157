"""Benchmark: build a 500-plant field (the reference paper's per-node size) at default resolution.

    python benchmarks/bench_field.py [--n-plants 500] [--buffer-rows 2] [--out JSON]

Measures, in one run: growing every plant with CPlantBox (empty cache), building again from
a warm cache, meshing alone; peak traced memory of the build; segments and triangles per plant.
Writes benchmarks/results/field.json (or ``--out``) and prints a table.
"""

from __future__ import annotations

import argparse
import platform
import resource
import tempfile
import time
import tracemalloc
from pathlib import Path

from provenance import out_option, wide_console, write_result
from rich.table import Table

from lightfit.plant import Field, MeshResolution, build, shoot_mesh
from lightfit.precision import use_float64

use_float64()  # lightfit's precision policy (lightfit.precision), before any JAX array exists

OUT = Path(__file__).resolve().parent / "results" / "field.json"


def main(n_plants: int = 500, buffer_rows: int = 2) -> dict:
    fld = Field(boundary="finite", n_plants=n_plants, buffer_rows=buffer_rows, seed=1)
    with tempfile.TemporaryDirectory() as cache:
        t0 = time.perf_counter()
        cold = build(fld, cache_dir=cache, progress=True)
        t_cold = time.perf_counter() - t0
        t0 = time.perf_counter()
        warm = build(fld, cache_dir=cache)
        t_warm = time.perf_counter() - t0
        # Memory traced separately: tracemalloc slows CPlantBox's many small allocations ~4×.
        tracemalloc.start()
        build(fld, cache_dir=cache)
        _, peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
    t0 = time.perf_counter()
    mesh = shoot_mesh(warm.segments, MeshResolution())
    t_mesh = time.perf_counter() - t0
    n_built = len(cold.plants)
    res = {
        "n_plants_measured": int(fld.n_measured),
        "n_plants_built": n_built,
        "buffer_rows": buffer_rows,
        "segments": len(cold.segments),
        "triangles": int(cold.mesh.n_faces),
        "segments_per_plant": len(cold.segments) / n_built,
        "triangles_per_plant": cold.mesh.n_faces / n_built,
        "build_cold_s": t_cold,
        "build_warm_cache_s": t_warm,
        "mesh_only_s": t_mesh,
        "cold_over_warm": t_cold / t_warm,
        "peak_traced_memory_warm_build_mb": peak / 2**20,
        "max_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
        "cache_hits_warm": warm.cache_hits,
        "mesh_vertices": len(mesh.vertices),
        "machine": f"{platform.machine()} {platform.processor() or ''}".strip(),
    }
    write_result(OUT, res, indent=2)
    t = Table(title=f"field build: {fld.area_label} measured + {buffer_rows} buffer rows = {n_built} plants")
    t.add_column("quantity")
    t.add_column("value", justify="right")
    for k, v in res.items():
        t.add_row(k, f"{v:.3g}" if isinstance(v, float) else str(v))
    wide_console().print(t)
    return res


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n-plants", type=int, default=500)
    ap.add_argument("--buffer-rows", type=int, default=2)
    out_option(ap, OUT)
    a = ap.parse_args()
    OUT = a.out
    main(a.n_plants, a.buffer_rows)
