"""Benchmark: the projected direct light's rays against its error and a time step's cost (issue 16).

    python benchmarks/bench_projection.py [--n-plants 100] [--samples 64] [--out JSON]

The defaults' field (the measured plants as one periodic cell, the PROSPECT-D leaf, the bounces
that leaf needs for 1 % truncation) at the sun of bench_light (50°), K samples per segment. For
the direct light from the paths and for each (sun, sky) rays per m² of the projection
(``SegmentEstimator(direct="projection", direct_rays_per_m2=(sun, sky))``), one process and one
estimator each, in turn:

* the median and 90th percentile relative SE of absorbed PAR (DNI 1, DHI 0.3), all segments,
  blades and stems;
* the time of a render at a new sun with the paths kept — what every later time step of a day
  costs (the sun's shadow rays, and the sun's projection; the sky's projection is kept) — the
  median of four suns;
* the variance × step time relative to the paths' (efficiency: > 1 is better);
* the reverse-mode gradient of absorbed PAR (DNI 1, DHI 0.3) with respect to the three leaf
  parameters at the last sun, and its time ÷ a step's (issue 16: ≤ 2.5× the primal).

Writes benchmarks/results/projection.json (or ``--out``; with the commit and load average) and prints a
table (2 shared cores: compare the settings of one run, not absolute times across runs).
"""

from __future__ import annotations

import argparse
import gc
import time
from pathlib import Path

import numpy as np
from bench_variance import _stats  # per-class median / p90 (same script folder)
from provenance import out_option, wide_console, write_result
from rich.table import Table

import lightfit  # noqa: F401
from lightfit.defaults import DEFAULT_RAYS_PER_M2
from lightfit.light.estimator import SegmentEstimator, bounces_for_tolerance
from lightfit.light.scene import FieldScene, Optics
from lightfit.plant import Field, build
from lightfit.precision import use_float64

use_float64()  # lightfit's precision policy (lightfit.precision), before any JAX array exists

OUT = Path(__file__).resolve().parent / "results" / "projection.json"
SETTINGS = (None, (1e6, 1e7), DEFAULT_RAYS_PER_M2, (1e7, 1e7), (2.5e6, 3e6), (2.5e6, 3e7))
STEP_SUNS = ((30.0, 170.0), (40.0, 170.0), (45.0, 170.0), (55.0, 170.0))


def main(n_plants: int = 100, samples: int = 64) -> dict:
    console = wide_console()
    optics = Optics.preset("prospect")
    bounces = bounces_for_tolerance(0.01, optics)
    geom = build(Field(n_plants=n_plants, seed=1, boundary="periodic"), progress=True)
    fs = FieldScene(geom.mesh, optics, cell=geom.cell)
    ids = geom.segments.loc[geom.segments["measured"], "segment_id"].to_numpy()
    fs.set_sun(50.0, 180.0)
    # Compile both kinds of kernels before timing.
    SegmentEstimator(fs, ids[:300], samples=16, bounces=bounces, direct="projection", direct_rays_per_m2=1e5).render()
    rows = []
    for rays in SETTINGS:
        kw = {} if rays is None else dict(direct="projection", direct_rays_per_m2=rays)
        fs.set_sun(50.0, 180.0)
        est = SegmentEstimator(fs, ids, samples=samples, bounces=bounces, seed=1, **kw)
        t = time.perf_counter()
        r = est.render()
        first = time.perf_counter() - t
        steps = []
        for sun in STEP_SUNS:
            fs.set_sun(*sun)
            t = time.perf_counter()
            est.render()
            steps.append(time.perf_counter() - t)
        ct = {"absorbed_sun": np.ones(len(ids)), "absorbed_sky": np.full(len(ids), 0.3)}
        est.vjp(ct)  # compile
        t = time.perf_counter()
        est.vjp(ct)
        grad = time.perf_counter() - t
        rse = r.relative_se()
        rows.append(
            {
                "direct": "paths" if rays is None else "projection",
                "rays_per_m2_sun_sky": None if rays is None else list(rays),
                "first_render_s": first,
                "step_s": float(np.median(steps)),
                "gradient_s": grad,
                "gradient_over_step": grad / float(np.median(steps)),
                "rse_absorbed": _stats(rse, np.asarray(r.meta["is_blade"], bool)),
            }
        )
        del est, r
        gc.collect()
    base = rows[0]
    for q in rows:
        q["efficiency_vs_paths"] = (base["rse_absorbed"]["all"]["median"] ** 2 * base["step_s"]) / (
            q["rse_absorbed"]["all"]["median"] ** 2 * q["step_s"]
        )
    res = {
        "n_plants_measured": int(Field(n_plants=n_plants).n_measured),
        "segments": len(ids),
        "samples": samples,
        "bounces": bounces,
        "step_suns_deg": STEP_SUNS,
        "rows": rows,
    }
    write_result(OUT, res, indent=2)
    t = Table(title=f"projected direct light: {len(ids)} segments, K={samples}, {bounces} bounces, 2 CPU cores")
    heads = ("direct light", "first render", "time step", "gradient", "median / p90", "blades / stems", "efficiency")
    for c in heads:
        t.add_column(c, justify="right")
    for q in rows:
        a = q["rse_absorbed"]
        rays = q["rays_per_m2_sun_sky"]
        label = q["direct"] if rays is None else "rays {:.1e} / {:.1e}".format(*rays)
        t.add_row(
            label,
            f"{q['first_render_s']:.2f} s",
            f"{q['step_s']:.2f} s",
            f"{q['gradient_s']:.2f} s ({q['gradient_over_step']:.2f}×)",
            f"{a['all']['median']:.1%} / {a['all']['p90']:.1%}",
            f"{a['blades']['median']:.1%} / {a['stems']['median']:.1%}",
            f"{q['efficiency_vs_paths']:.1f}×",
        )
    console.print(t)
    return res


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n-plants", type=int, default=100)
    ap.add_argument("--samples", type=int, default=64)
    out_option(ap, OUT)
    a = ap.parse_args()
    OUT = a.out
    main(a.n_plants, a.samples)
