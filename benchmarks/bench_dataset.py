"""Benchmark: labelled images per second at 512² and 1024² on 2 CPU cores.

    python benchmarks/bench_dataset.py [--spp 16] [--images 2] [--n-plants 25] [--buffer-rows 2] [--out JSON]

A 5×5-plant field with 2 buffer rows (81 plants) and *synthetic* results; cameras from a sweep
around it. Per resolution it times (after one warm-up image that compiles the kernels):

- ``render``: the data-scene render alone (HDR radiance + pixel-centre hits), in this process
  with ``llvm_ad_rgb`` (the benchmark owns its process, so no child process is needed);
- ``end_to_end``: :func:`lightfit.dataset.make_dataset` without gallery/export — results
  read, geometry rebuilt from the cache, render, labels, metering, EXR + PNG + npz written.

Writes benchmarks/results/dataset.json (or ``--out``) and prints a table.
"""

from __future__ import annotations

import argparse
import os
import platform
import tempfile
import time
from pathlib import Path

from provenance import out_option, wide_console, write_result

import lightfit  # noqa: F401 - libLLVM before Dr.Jit
from lightfit.light.backend import mitsuba
from lightfit.precision import use_float64

use_float64()  # lightfit's precision policy (lightfit.precision), before any JAX array exists

OUT = Path(__file__).resolve().parent / "results" / "dataset.json"
CORES = 2


def _pin_cores() -> None:
    """Run on 2 CPU cores: pin the process and give Dr.Jit 2 worker threads."""
    if hasattr(os, "sched_setaffinity") and len(os.sched_getaffinity(0)) > CORES:
        os.sched_setaffinity(0, set(sorted(os.sched_getaffinity(0))[:CORES]))
    import drjit as dr

    dr.set_thread_count(CORES)


def main(spp: int = 16, n_images: int = 2, n_plants: int = 25, buffer_rows: int = 2, sizes=(512, 1024)) -> dict:
    mitsuba("llvm_ad_rgb")
    _pin_cores()
    from rich.table import Table

    from lightfit.dataset import (
        DatasetSpec,
        RenderSettings,
        Sweep,
        build_geometry,
        camera_sweep,
        lighting,
        make_dataset,
        open_results,
        render,
        scene_arrays,
        select_times,
        synthetic_results,
    )
    from lightfit.plant import Field

    fld = Field(boundary="finite", n_plants=n_plants, buffer_rows=buffer_rows, seed=1)
    tmp = Path(tempfile.mkdtemp(prefix="bench-dataset-"))
    results = tmp / "results.nc"
    synthetic_results(fld, ["2016-04-20T11:00"]).to_netcdf(results, engine="h5netcdf")
    res = open_results(results)
    geom = build_geometry(res)
    lights = lighting(res, select_times(res, None))
    arrays = scene_arrays(geom.mesh, geom.segments)
    settings = RenderSettings(spp=spp, colour="rgb", seed=0)
    rows = []
    for side in sizes:
        sweep = Sweep(n=n_images, distance_m=1.2, elevation_deg=40.0, camera={"width_px": side, "height_px": side})
        cams = camera_sweep(sweep, canopy_height_m=0.6)
        render(arrays, cams[:1], lights, settings)  # warm-up: compile (or load cached) kernels
        t0 = time.perf_counter()
        render(arrays, cams, lights, settings)
        t_render = time.perf_counter() - t0
        t0 = time.perf_counter()
        make_dataset(
            res, tmp / f"ds{side}", DatasetSpec(cameras=cams, settings=settings, gallery_images=0, export="none")
        )
        t_e2e = time.perf_counter() - t0
        rows.append(
            {
                "resolution_px": side,
                "images": n_images,
                "spp": spp,
                "render_images_per_s": n_images / t_render,
                "end_to_end_images_per_s": n_images / t_e2e,
                "render_s_per_image": t_render / n_images,
                "end_to_end_s_per_image": t_e2e / n_images,
                "paths_per_s": n_images * side * side * spp / t_render,
            }
        )
    out = {
        "field": {
            "n_plants_measured": fld.n_measured,
            "plants_built": len(geom.plants),
            "triangles": int(geom.mesh.n_faces),
        },
        "cores": CORES,
        "variant": "llvm_ad_rgb",
        "max_depth": settings.max_depth,
        "results": "synthetic",
        "machine": f"{platform.machine()} {platform.processor() or ''}".strip(),
        "rows": rows,
        "command": f"python benchmarks/bench_dataset.py --spp {spp} --images {n_images} --n-plants {n_plants} "
        f"--buffer-rows {buffer_rows}",
    }
    write_result(OUT, out, indent=2)
    t = Table(
        title=f"data scene on {CORES} cores: {out['field']['plants_built']} plants, "
        f"{out['field']['triangles']} triangles, {spp} spp, rgb"
    )
    for c in ("resolution", "render img/s", "end-to-end img/s", "render s/img", "Mpaths/s"):
        t.add_column(c, justify="right")
    for r in rows:
        t.add_row(
            f"{r['resolution_px']}²",
            f"{r['render_images_per_s']:.3f}",
            f"{r['end_to_end_images_per_s']:.3f}",
            f"{r['render_s_per_image']:.2f}",
            f"{r['paths_per_s'] / 1e6:.2f}",
        )
    wide_console().print(t)
    return out


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--images", type=int, default=2)
    ap.add_argument("--n-plants", type=int, default=25)
    ap.add_argument("--buffer-rows", type=int, default=2)
    out_option(ap, OUT)
    a = ap.parse_args()
    OUT = a.out
    main(a.spp, a.images, a.n_plants, a.buffer_rows)
