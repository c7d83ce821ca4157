"""Benchmark: per-segment light at every step of a day, to a 2 % median (issue 16).

    python benchmarks/bench_day.py [--n-plants 500] [--steps 29] [--sheaths wrapped|rods] [--out JSON]

A day renders one estimator at every step's sun. The paths' geometry and the projected sky are
kept, so only the first render casts the sky's rays and traces the paths; every later step casts
the sun's rays alone. A day can therefore afford more sky rays than one render. For each setting
(K, projection rays per m² for sun and sky) on the defaults' periodic cell (PROSPECT-D leaf, the
bounces for 1 % truncation; ``--sheaths`` the leaf sheaths' layout, default the model's default,
recorded as ``sheaths``; runs stored before it was recorded had ``rods``), one fresh estimator
renders the first step (sun 50° / 180°) and then the later steps' suns in :data:`STEP_SUNS_DEG`.
Reported: the first render's time, a later step's time (mean over the later suns), the later
steps' median relative SE of absorbed PAR (sun + 0.3·sky; R-corrected: divided by
``bench_light.median_se_factor``), and the time for a 2 % median, per later step and for a whole
day of ``--steps`` steps. Both scale every part (the sky's single cast included) by
(median / 2 %)²: each part's variance falls as 1/rays and 1/K.

The later steps share the sky's rays, so their sky errors are correlated from step to step: a
day's sum does not average them down. The per-step median is what each step's photosynthesis
sees.

Before the settings, one render of the first setting at another seed compiles the kernels and
lets Dr.Jit's allocator hold the memory the renders reuse (memory touched for the first time costs
4–6 s per GiB here: docs/light-sampling.md, "A process's first render"). Writes benchmarks/results/day.json
(or ``--out``) and prints a table, with the commit and the load average (the 2 cores are shared).
"""

from __future__ import annotations

import argparse
import gc
import json
import time
from pathlib import Path

import numpy as np
from bench_light import finite_median, median_se_factor  # same script folder
from bench_variance import _stats
from provenance import out_option, wide_console, write_result
from rich.table import Table

import lightfit  # noqa: F401
from lightfit.light import backend
from lightfit.light.estimator import SegmentEstimator, bounces_for_tolerance
from lightfit.light.scene import FieldScene, Optics
from lightfit.plant import SHEATHS, Field, build
from lightfit.precision import use_float64

use_float64()  # lightfit's precision policy (lightfit.precision), before any JAX array exists

OUT = Path(__file__).resolve().parent / "results" / "day.json"

#: The first step's sun and two later steps' (elevation, azimuth), degrees.
FIRST_SUN_DEG = (50.0, 180.0)
STEP_SUNS_DEG = ((45.0, 200.0), (30.0, 240.0))

#: (K, (sun, sky) rays per m²): the single render's setting first (``bench_light.py``), then more
#: sky rays and fewer sun rays.
SETTINGS = (
    (16, (1.5e7, 2e7)),
    (16, (1.5e7, 6e7)),
    (16, (1e7, 6e7)),
    (16, (7.5e6, 6e7)),
    (32, (1.5e7, 6e7)),
    (16, (1e7, 1e8)),
)


def day(fs: FieldScene, ids: np.ndarray, bounces: int, samples: int, rays, steps: int, seed: int = 2) -> dict:
    """One setting: the first render and the later steps of one estimator."""
    est = SegmentEstimator(
        fs, ids, samples=samples, bounces=bounces, seed=seed, direct="projection", direct_rays_per_m2=rays
    )
    fs.set_sun(*FIRST_SUN_DEG)
    t = time.perf_counter()
    est.render()
    t_first = time.perf_counter() - t
    t_steps, meds, stats = [], [], []
    for el, az in STEP_SUNS_DEG:
        fs.set_sun(el, az)
        t = time.perf_counter()
        r = est.render()
        t_steps.append(time.perf_counter() - t)
        rse = r.relative_se()
        meds.append(finite_median(rse) / median_se_factor(rse, est.replicates - 1))
        stats.append(_stats(rse, np.asarray(r.meta["is_blade"], bool)))
    fs.set_sun(*FIRST_SUN_DEG)
    del est
    gc.collect()
    t_step, med = float(np.mean(t_steps)), float(np.mean(meds))
    f = (med / 0.02) ** 2
    return {
        "samples": samples,
        "rays_per_m2": list(rays),
        "first_render_s": t_first,
        "step_s": t_steps,
        "step_rse_absorbed": stats,
        "step_median_rse_r_corrected": meds,
        "step_s_at_2pct": t_step * f,
        "day_s_at_2pct": (t_first + (steps - 1) * t_step) * f,
    }


def main(n_plants: int = 500, steps: int = 29, sheaths: str = SHEATHS[0], out: Path = OUT) -> dict:
    console = wide_console()
    optics = Optics.preset("prospect")
    bounces = bounces_for_tolerance(0.01, optics)
    geom = build(Field(n_plants=n_plants, seed=1, boundary="periodic", sheaths=sheaths), progress=True)
    fs = FieldScene(geom.mesh, optics, cell=geom.cell)
    ids = geom.segments.loc[geom.segments["measured"], "segment_id"].to_numpy()
    fs.set_sun(*FIRST_SUN_DEG)
    k0, rays0 = SETTINGS[0]
    SegmentEstimator(
        fs, ids, samples=k0, bounces=bounces, seed=0, direct="projection", direct_rays_per_m2=rays0
    ).render()  # compile, and let the allocator hold the memory
    gc.collect()
    rows = []
    for samples, rays in SETTINGS:
        rows.append(day(fs, ids, bounces, samples, rays, steps))
        q = rows[-1]
        console.print(
            f"K={samples}, {rays[0]:.1e} / {rays[1]:.1e}: first {q['first_render_s']:.1f} s, "
            f"step {np.mean(q['step_s']):.1f} s, ≈ {q['day_s_at_2pct'] / 60:.1f} min a day at 2 %"
        )
    res = {
        "mitsuba_variant": backend.info().variant,
        "n_plants_measured": int(Field(n_plants=n_plants).n_measured),
        "sheaths": sheaths,
        "segments": len(ids),
        "bounces": bounces,
        "steps": steps,
        "first_sun_deg": FIRST_SUN_DEG,
        "step_suns_deg": STEP_SUNS_DEG,
        "settings": rows,
    }
    res = json.loads(write_result(out, res, indent=2).read_text())  # with the provenance, for the table
    t = Table(title=f"a day at a 2 % median per step: {len(ids)} segments, {steps} steps, 2 CPU cores")
    for c in (
        "K, sun / sky rays per m²",
        "first render",
        "later step",
        "median (R-corr.)",
        "per step at 2 %",
        f"{steps}-step day at 2 %",
    ):
        t.add_column(c, justify="right")
    for q in rows:
        t.add_row(
            f"{q['samples']}, {q['rays_per_m2'][0]:.1e} / {q['rays_per_m2'][1]:.1e}",
            f"{q['first_render_s']:.1f} s",
            f"{np.mean(q['step_s']):.1f} s",
            f"{np.mean(q['step_median_rse_r_corrected']):.2%}",
            f"{q['step_s_at_2pct']:.0f} s",
            f"{q['day_s_at_2pct'] / 60:.1f} min",
        )
    console.print(t)
    console.print(
        f"commit {res['lightfit_commit']}, load {res['load_average_start']:.1f} → {res['load_average_end']:.1f}"
    )
    return res


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n-plants", type=int, default=500)
    ap.add_argument("--steps", type=int, default=29, help="steps in the day (the main job's 20 April: 29)")
    ap.add_argument("--sheaths", choices=SHEATHS, default=SHEATHS[0], help="leaf sheath layout (lightfit.plant.Field)")
    out_option(ap, OUT)
    a = ap.parse_args()
    main(a.n_plants, a.steps, a.sheaths, a.out)
