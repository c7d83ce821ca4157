"""Benchmark: where the projection's time and variance go (issue 16).

    python benchmarks/bench_projection_split.py [--n-plants 500] [--samples 32] [--rays 2e7] [--out JSON]

The defaults' field (the measured plants as one periodic cell, the PROSPECT-D leaf, the bounces
that leaf needs for 1 % truncation) at the sun of bench_light (50°), one estimator with the
direct light projected (``direct_rays_per_m2`` = ``--rays`` for sun and sky), after a small render
that compiles the kernels:

* the time of each kind's cast (first rays, the continued share, the deposits: ``hits``), of
  taking the projected values, and of the rest of the render (the paths, light scattered twice
  and more);
* near the median (segments between the 40th and 60th percentile of relative SE of absorbed PAR,
  DNI 1, DHI 0.3), each part's share of the light and the median of its share of the variance:
  the replicate values of each part's hits (direct, scattered once by a leaf or by the soil, per
  kind) taken apart, the paths as the rest; shares of the variance ignore the parts' covariances.

Writes benchmarks/results/projection_split.json (or ``--out``; with the commit and load average) and
prints a table (2 shared cores: compare parts of one run, not absolute times across runs).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
from bench_light import periodic_cell  # same script folder
from provenance import out_option, wide_console, write_result
from rich.table import Table

import lightfit  # noqa: F401
from lightfit.light.estimator import SegmentEstimator
from lightfit.plant import Field
from lightfit.precision import use_float64

use_float64()  # lightfit's precision policy (lightfit.precision), before any JAX array exists

OUT = Path(__file__).resolve().parent / "results" / "projection_split.json"
SKY_WEIGHT = 0.3  # DHI per unit DNI in the relative SE, as bench_light


def main(n_plants: int = 500, samples: int = 32, rays: float = 2e7) -> dict:
    import drjit as dr

    geom, fs, ids, bounces = periodic_cell(n_plants)
    kw = dict(samples=samples, bounces=bounces, direct="projection", direct_rays_per_m2=rays)
    SegmentEstimator(fs, ids[:2000], seed=0, **kw).render()  # compile kernels
    est = SegmentEstimator(fs, ids, seed=1, **kw)
    proj = est._direct
    times = {}
    for kind in ("sun", "sky"):
        t = time.perf_counter()
        proj.hits(kind)
        dr.sync_thread()
        times[f"{kind}_cast_s"] = time.perf_counter() - t
    t = time.perf_counter()
    for kind in ("sun", "sky"):
        proj.values(kind)
    times["values_s"] = time.perf_counter() - t
    t = time.perf_counter()
    r = est.render()  # the hits are kept: the paths, the values once more, the bookkeeping
    times["rest_of_render_s"] = time.perf_counter() - t - times["values_s"]

    parts = {}
    for kind, weight in (("sun", 1.0), ("sky", SKY_WEIGHT)):
        store = proj._kept[kind]  # the one sun rendered, or the sky
        key = next(iter(store))
        kept = store[key]
        try:
            for part in ("direct", "via_leaf", "via_soil"):
                store[key] = [h for h in kept if h.part == part]
                parts[f"{kind}_{part}"] = weight * proj.values(kind)["absorbed"]
        finally:
            store[key] = kept
    reps = r.meta["replicate_means"]
    total = reps["absorbed_sun"] + SKY_WEIGHT * reps["absorbed_sky"]
    parts["paths"] = total - sum(parts.values())
    rse = r.relative_se("absorbed", 1.0, SKY_WEIGHT)
    order = np.argsort(np.where(np.isfinite(rse), rse, np.inf))
    n_ok = int(np.isfinite(rse).sum())
    near = order[int(0.4 * n_ok) : int(0.6 * n_ok)]
    var_total = total[near].var(1, ddof=1)
    split = {
        name: {
            "light_share": float(v[near].mean(1).sum() / total[near].mean(1).sum()),
            "median_variance_share": float(np.median(v[near].var(1, ddof=1) / var_total)),
        }
        for name, v in parts.items()
    }
    res = {
        "n_plants_measured": int(Field(n_plants=n_plants).n_measured),
        "segments": len(ids),
        "samples": est.samples,
        "bounces": bounces,
        "rays_per_m2": rays,
        "projection": proj.summary(),
        "median_rse_absorbed": float(np.nanmedian(rse)),
        **times,
        "near_median_split": split,
    }
    write_result(OUT, res, indent=2)
    t = Table(title=f"projection split: {len(ids)} segments, K={est.samples}, {rays:.1e} rays/m², 2 CPU cores")
    t.add_column("quantity")
    t.add_column("value", justify="right")
    for k, v in times.items():
        t.add_row(k, f"{v:.2f}")
    t.add_row("median rse (absorbed)", f"{res['median_rse_absorbed']:.2%}")
    for name, q in split.items():
        shares = f"{q['light_share']:.3f} / {q['median_variance_share']:.3f}"
        t.add_row(f"{name}: light / median variance share", shares)
    wide_console().print(t)
    return res


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n-plants", type=int, default=500)
    ap.add_argument("--samples", type=int, default=32)
    ap.add_argument("--rays", type=float, default=2e7)
    out_option(ap, OUT)
    a = ap.parse_args()
    OUT = a.out
    main(a.n_plants, a.samples, a.rays)
