"""Benchmark: the order in which the sky's rays take their directions, over a scan of ray densities (issue 16).

    python benchmarks/bench_sky_order.py [--n-plants 100 500] [--rays 1e7 2e7 5e7 8e7 1e8] [--out JSON]

The projection's sky rays take consecutive points of an R₂ sequence as their directions, in an
order over the grid cells (:data:`lightfit.light.projection.SKY_TILE`): tiles of 16 × 16 cells in
Z-order (default) or the whole grid row-major (``SKY_TILE = 0``, the order before). For each
field (the defaults' periodic cell of ``--n-plants`` plants, PROSPECT-D leaf, sun 50° at 10⁶ rays
per m², ``bounces=0``: the sky part is then the sky seen directly), each order and each sky ray
density, one render at K = 16 gives the blades' median relative SE of the sky part times
√(rays / 10⁷ per m²): constant when the SE falls as 1/√rays, so a row that rises marks an order
whose directions cluster on the rays that meet a segment at that grid. Writes
benchmarks/results/sky_order.json (or ``--out``) and prints a table, with the commit and the load average.
"""

from __future__ import annotations

import argparse
import gc
import math
from pathlib import Path

import numpy as np
from provenance import out_option, wide_console, write_result  # same script folder
from rich.table import Table

import lightfit  # noqa: F401
from lightfit.light import projection
from lightfit.light.estimator import SegmentEstimator
from lightfit.light.scene import FieldScene, Optics
from lightfit.plant import Field, build, organ_class
from lightfit.precision import use_float64

use_float64()  # lightfit's precision policy (lightfit.precision), before any JAX array exists

OUT = Path(__file__).resolve().parent / "results" / "sky_order.json"
ORDERS = {"tiled Z-order (16)": 16, "row-major (before)": 0}


def main(n_plants=(100, 500), rays=(1e7, 2e7, 5e7, 8e7, 1e8)) -> dict:
    rows = []
    default = projection.SKY_TILE
    try:
        for n in n_plants:
            geom = build(Field(n_plants=n, seed=1, boundary="periodic"), progress=True)
            fs = FieldScene(geom.mesh, Optics.preset("prospect"), cell=geom.cell)
            fs.set_sun(50.0, 180.0)
            ids = geom.segments.loc[geom.segments["measured"], "segment_id"].to_numpy()
            blade = organ_class(geom.segments.set_index("segment_id").loc[ids]) == "blade"
            for rho in rays:
                for name, tile in ORDERS.items():
                    projection.SKY_TILE = tile
                    est = SegmentEstimator(
                        fs, ids, samples=16, bounces=0, seed=2, direct="projection", direct_rays_per_m2=(1e6, rho)
                    )
                    r = est.render()
                    with np.errstate(divide="ignore", invalid="ignore"):
                        rse = r.se["absorbed_sky"] / np.abs(r.absorbed_sky)
                    med = float(np.nanmedian(np.where(np.isfinite(rse[blade]), rse[blade], np.nan)))
                    rows.append(
                        {
                            "n_plants": n,
                            "sky_rays_per_m2": rho,
                            "order": name,
                            "blades_median_rse_sky": med,
                            "normalised_to_1e7_per_m2": med * math.sqrt(rho / 1e7),
                        }
                    )
                    del est
                    gc.collect()
    finally:
        projection.SKY_TILE = default
    res = {"rows": rows}
    write_result(OUT, res, indent=2)
    t = Table(title="Sky directions' order: blades' median relative SE of the sky part × √(rays / 10⁷ per m²)")
    t.add_column("plants")
    t.add_column("sky rays per m²")
    for name in ORDERS:
        t.add_column(name)
    for n in n_plants:
        for rho in rays:
            vals = {
                q["order"]: q["normalised_to_1e7_per_m2"]
                for q in rows
                if q["n_plants"] == n and q["sky_rays_per_m2"] == rho
            }
            t.add_row(str(n), f"{rho:.1e}", *(f"{vals[k]:.2%}" for k in ORDERS))
    wide_console().print(t)
    return res


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n-plants", type=int, nargs="+", default=[100, 500])
    ap.add_argument("--rays", type=float, nargs="+", default=[1e7, 2e7, 5e7, 8e7, 1e8])
    out_option(ap, OUT)
    a = ap.parse_args()
    OUT = a.out
    main(tuple(a.n_plants), tuple(a.rays))
