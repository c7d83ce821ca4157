"""Benchmark: issue 16's single-render goal alone, at the recommended setting.

    python benchmarks/bench_single_render.py [--n-plants 500] [--plants-per-row square[,25]]
        [--samples 16[,32]] [--rays 1.5e7,2e7] [--sheaths wrapped[,rods]] [--headings random[,aligned]]
        [--seeds 4] [--out JSON]

The goal: on the defaults' periodic cell of ``--n-plants`` plants (PROSPECT-D leaf, the bounces
for 1 % truncation, sun 50° / 180°), a median per-segment relative SE of absorbed PAR (sun +
0.3·sky) of 2 % over all segments in ≤ 60 s on 2 cores. ``bench_light.py`` measures this setting
among others after a much longer run; this script measures it alone, with the same function
(``bench_light.direct_projection_comparison``: fresh estimators, the second's render as the
steady state, the median raw, corrected for R's downward bias, and pooled over the seeds), so a
machine's speed can be checked against the goal in a few minutes. Times scale to a 2 % median by
(median / 2 %)²: every part's variance falls as 1/rays and 1/K.

``--samples``: the paths per segment K (which also sets the replicates R, 8 from K = 32 on);
``--sheaths``: the leaf sheaths' layout (``Field.sheaths``, default the model's default). Several
values of either, comma-separated, are measured one after the other in one process (a
side-by-side ratio), and the JSON then holds one result per setting under ``runs``;
``--headings`` (``Field.headings``) and ``--plants-per-row`` (``Field.plants_per_row``; ``square``:
N × N, N = ⌈√n_plants⌉, so that 500 builds 23² = 529 plants; ``25``: 20 rows × 25, exactly 500) the
same. ``--sky-continued-share``: the share q of the sky's
rays continued after their first hit (``projection.CONTINUED_SHARE["sky"]``, 0.25 in the
library: a day casts the sky once and its continuation serves every step); several values are
measured in turn the same way. The value is set for this process only, as an experiment.
``--seeds N`` (default 4) pools N fresh estimators' SEs (N·(R − 1) degrees of freedom) for the
pooled median, whose correction for the few degrees of freedom then shrinks (≈ 0.96 at N = 4,
R = 4): the goal is judged on that row. Its time is the second estimator's render; the last row
takes the median of the N − 1 steady renders instead (one render moves by ± 5 % on this
machine). At the 2 % setting one render's R-corrected median (3 degrees of freedom) read 2.02 %
where 4 seeds pooled read 2.15 %, 13 % less time to a 2 % median (docs/light-sampling.md, "The single
render judged on four seeds").

Writes benchmarks/results/single_render.json (or ``--out``) and prints a table, with the commit and
the load average (the 2 cores are shared: absolute times move with the machine, see docs/light-sampling.md).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time
from pathlib import Path

from bench_light import direct_projection_comparison, periodic_cell  # same script folder
from provenance import out_option, wide_console, write_result
from rich.table import Table

import lightfit  # noqa: F401
from lightfit.light.estimator import SegmentEstimator
from lightfit.plant import SHEATHS, organ_class
from lightfit.plant.field import HEADINGS, Field, check_headings
from lightfit.plant.sheaths import check_sheaths
from lightfit.precision import use_float64

use_float64()  # lightfit's precision policy (lightfit.precision), before any JAX array exists

OUT = Path(__file__).resolve().parent / "results" / "single_render.json"
#: Issue 16's goal for one render at a 2 % median on 2 cores, s.
GOAL_S = 60.0


def main(
    n_plants: int,
    samples: int,
    rays: tuple[float, float],
    sheaths: str = SHEATHS[0],
    q_sky: float | None = None,
    headings: str = HEADINGS[0],
    seeds: int = 4,
    plants_per_row: int | None = None,
) -> dict:
    from lightfit.light import projection

    if q_sky is not None:
        projection.CONTINUED_SHARE["sky"] = q_sky
    load_start = os.getloadavg()[0]  # this run's (several are measured in turn)
    t = time.perf_counter()
    geom, fs, ids, bounces = periodic_cell(n_plants, sheaths, headings, plants_per_row)
    area = Field(n_plants=n_plants, plants_per_row=plants_per_row)  # the cell's layout, as built
    t_build = time.perf_counter() - t
    SegmentEstimator(fs, ids[:2000], samples=samples, bounces=bounces, seed=0).render()  # compile kernels
    organ = organ_class(geom.segments.set_index("segment_id").loc[ids])
    row = direct_projection_comparison(fs, ids, bounces, [(samples, rays)], organ, seeds)["settings"][0]
    return {
        "n_plants": n_plants,
        "plants_per_row": plants_per_row,
        "n_plants_measured": area.n_measured,
        "measurement_area": area.area_label,
        "cell_m": [geom.cell.along_m, geom.cell.across_m],
        "sheaths": sheaths,
        "headings": headings,
        "sky_continued_share": projection.CONTINUED_SHARE["sky"],
        "segments": len(ids),
        "bounces": bounces,
        "build_s": t_build,
        "goal_s_at_2pct": GOAL_S,
        "load_average_start": load_start,
        "load_average_end": os.getloadavg()[0],
        **row,
    }


def int_list(text: str) -> list[int]:
    """``"16,64"`` → ``[16, 64]`` (argparse names the option when this raises)."""
    return [int(k) for k in text.split(",")]


def rays_pair(text: str) -> tuple[float, float]:
    """``"1.5e7,2e7"`` → ``(1.5e7, 2e7)``, sun and sky rays per m², both > 0 (argparse names the
    option when this raises)."""
    sun, sky = (float(x) for x in text.split(","))
    if not (sun > 0 and sky > 0):
        raise ValueError(text)
    return sun, sky


def table(res: dict) -> Table:
    t = Table(
        title=f"one render, {res.get('measurement_area', str(res['n_plants']) + ' plants')} "
        f"({res['segments']} segments), "
        f"K = {res['samples']}, "
        f"{res['sheaths']} sheaths, {res.get('headings', 'aligned')} headings, sky continued share "
        f"{res['sky_continued_share']:g}"
    )
    t.add_column("median SE is", justify="left")
    t.add_column("median", justify="right")
    t.add_column("time to a 2 % median", justify="right")
    t.add_column("÷ goal (60 s)", justify="right")
    rows = (
        ("as reported (R replicates)", res["rse_absorbed"]["all"]["median"], res["extrapolated_s_at_2pct"]),
        ("R-corrected", res["median_rse_r_corrected"], res["extrapolated_s_at_2pct_r_corrected"]),
        (
            f"pooled over {res.get('seeds', 2)} seeds",
            res["median_rse_pooled_seeds"],
            res["extrapolated_s_at_2pct_pooled_seeds"],
        ),
    )
    steady = [res["render_s"], *res.get("later_renders_s", [])]
    if len(steady) > 1:  # one render moves ± 5 % on this machine: the steady renders' median beside it
        med = res["median_rse_pooled_seeds"]
        at_2pct = statistics.median(steady) * (med / 0.02) ** 2
        rows += ((f"pooled, median of {len(steady)} steady renders", med, at_2pct),)
    for name, med, s in rows:
        t.add_row(name, f"{100 * med:.2f} %", f"{s:.0f} s", f"{s / GOAL_S:.2f}")
    return t


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n-plants", type=int, default=500)
    ap.add_argument(
        "--plants-per-row",
        default="square",
        help="plants per row of the cell, comma-separated; square: N × N (500 builds 23² = 529)",
    )
    ap.add_argument("--samples", default="16", type=int_list, help="paths per segment K, comma-separated")
    ap.add_argument("--rays", default="1.5e7,2e7", type=rays_pair, help="projection rays per m², sun,sky")
    ap.add_argument(
        "--sheaths", default=SHEATHS[0], help="leaf sheath layout(s), comma-separated: " + ", ".join(SHEATHS)
    )
    ap.add_argument("--headings", default=HEADINGS[0], help="plant headings, comma-separated: " + ", ".join(HEADINGS))
    ap.add_argument(
        "--seeds", type=int, default=4, help="fresh estimators whose SEs are pooled (≥ 2; more: a smaller correction)"
    )
    ap.add_argument("--sky-continued-share", default=None, help="q of the sky's continued rays, comma-separated")
    out_option(ap, OUT)
    a = ap.parse_args()
    if a.seeds < 2:
        ap.error(f"--seeds {a.seeds}: at least 2 (the steady-state time is the second estimator's)")
    sun, sky = a.rays
    layouts = a.sheaths.split(",")
    for x in layouts:
        check_sheaths(x)
    shares = [None] if a.sky_continued_share is None else [float(q) for q in a.sky_continued_share.split(",")]
    headings = a.headings.split(",")
    for h in headings:
        check_headings(h)
    per_row = [None if v == "square" else int(v) for v in a.plants_per_row.split(",")]
    runs = [
        main(a.n_plants, k, (sun, sky), x, q, h, a.seeds, r)
        for r in per_row
        for k in a.samples
        for x in layouts
        for q in shares
        for h in headings
    ]
    written = write_result(a.out, runs[0] if len(runs) == 1 else {"runs": runs}, indent=1, default=float)
    commit = json.loads(written.read_text())["lightfit_commit"]
    console = wide_console()
    for res in runs:
        console.print(table(res))
        by = res["rse_absorbed"]
        console.print(
            f"render {res['render_s']:.1f} s (first {res['first_render_s']:.1f} s; system CPU "
            f"{res['render_cpu_user_sys_s'][1][1]:.1f} s, first {res['render_cpu_user_sys_s'][0][1]:.1f} s); "
            f"p90 {100 * by['all']['p90']:.1f} %; "
            f"blades {100 * by['blades']['median']:.2f} %, stems and sheaths {100 * by['stems']['median']:.2f} %; "
            f"load {res['load_average_start']:.1f}–{res['load_average_end']:.1f}; commit {commit}"
        )
    console.print(f"wrote {a.out}")
