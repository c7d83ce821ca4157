"""Benchmark: the sky seen directly, gathered from the segments that set the median, on top of the
projection (issue 16).

    python benchmarks/bench_sky_gather.py [--n-plants 500] [--samples 128] [--out JSON]

The sky seen directly is ≈ 0.55 of a median segment's variance in the projection and is
Poisson-limited there (docs/light-sampling.md, "Why the sky seen directly stays Poisson-limited"). Its rays
are shared by all segments, most of them landing on sunlit upper blades that need none. Rays
*gathered* from a segment's own points (cosine-weighted directions, a hit on the sky or not: the
paths' first rays with ``direct="paths"``, 0 bounces, the sun below the horizon) could be spent
on the segments near the median alone, and combined with the projection's estimate by inverse
variance. Near the 2 % threshold a segment needs only a little extra precision, so the cost of
moving the all-segment median grows slowly at first; this measures whether it pays before any
of it is built.

Measured on one cell (sun 50° / 180°, PROSPECT-D leaf, bounces for 1 %, seed 1):

1. the single render's recommended setting (K = 16, 1.5 × 10⁷ / 2 × 10⁷ rays per m²), a fresh
   estimator's render: its time T and each segment's variance of absorbed PAR (DNI 1, DHI 0.3);
2. the same projection with 0 bounces: the sky seen directly's variance alone (the same first
   rays: they are keyed by index, so its direct hits are those of step 1);
3. gathering on every blade with ``--samples`` points: its time per point and variance per point,
   and its mean against the projection's (an independent check of both: the two estimate the same
   sky).

Model: the projection scaled by a (every part's variance ÷ a, time × a) plus, for each blade still
above 2 %, the gathered points k that bring it to 2 %: var = (V − V_sky)/a + 1 / (a / V_sky +
k / c), c the gathering's variance × points. The cheapest blades are added until half of all
segments are at or below 2 %; the total time is minimised over a. Variances are averaged over 150
bins of blades by absorbed PAR (a segment's own 3-degree-of-freedom SE would let the model pick
segments that were lucky), and the projection alone is evaluated the same way, so the ratio
compares like with like. k is continuous (``best_s``) or rounded up to 8 × a power of 2 (as
rounds of adaptive sampling would give, ``best_rounded_s``).

Writes benchmarks/results/sky_gather.json (or ``--out``) and prints a table, with the commit and the load
average.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
from bench_light import BENCH_SUN_DEG, periodic_cell  # same script folder
from provenance import out_option, wide_console, write_result
from rich.table import Table

import lightfit  # noqa: F401
from lightfit.light.estimator import SegmentEstimator
from lightfit.plant import organ_class
from lightfit.precision import use_float64

use_float64()  # lightfit's precision policy (lightfit.precision), before any JAX array exists

OUT = Path(__file__).resolve().parent / "results" / "sky_gather.json"
RAYS = (1.5e7, 2e7)  # the single render's recommended setting, sun and sky rays per m²
DHI = 0.3  # absorbed PAR = sun part + DHI · sky part (per unit DNI), as bench_light.py
TARGET = 0.02
BINS = 150


def lit_median(num, den) -> float:
    """Median of num / den over the segments with den > 0: an unlit segment (no light, no variance)
    has no relative SE or share, and its 0 / 0 would make the median NaN (small cells have some)."""
    num, den = np.asarray(num, float), np.asarray(den, float)
    keep = den > 0
    return float(np.median(num[keep] / den[keep])) if keep.any() else float("nan")


def hybrid_time(a, T, var, var_sky, c_blade, t_point, x, blade, rounded):
    """Time for a 2 % all-segment median: the projection at a × its rays plus gathered points."""
    xb, vb, sb = x[blade], var[blade], var_sky[blade]
    rest = (vb - sb) / a
    need = (TARGET * xb) ** 2
    with np.errstate(divide="ignore", invalid="ignore"):
        k = np.where(need > rest, c_blade * (1.0 / (need - rest) - a / sb), np.inf)
    k = np.where(vb / a <= need, 0.0, np.maximum(k, 0.0))
    if rounded:
        fin = np.isfinite(k) & (k > 0)
        k[fin] = 8 * 2 ** np.ceil(np.log2(np.maximum(k[fin] / 8, 1)))
    cost = np.sort(k * t_point)
    others_below = int(np.sum(var[~blade] / a <= (TARGET * x[~blade]) ** 2))
    short = len(x) // 2 + 1 - others_below
    if short > np.isfinite(cost).sum():
        return np.inf, 0
    short = max(short, 0)
    return a * T + float(cost[:short].sum()), int(np.count_nonzero(cost[:short]))


def main(n_plants: int, samples: int) -> dict:
    geom, fs, ids, bounces = periodic_cell(n_plants)
    blade = np.asarray(organ_class(geom.segments.set_index("segment_id").loc[ids])) == "blade"
    kw = dict(direct="projection", direct_rays_per_m2=RAYS, seed=1)
    SegmentEstimator(fs, ids, samples=16, bounces=bounces, **kw).render()  # compile, hold memory
    est = SegmentEstimator(fs, ids, samples=16, bounces=bounces, **kw)
    t = time.perf_counter()
    r = est.render()
    T = time.perf_counter() - t
    x = r.total("absorbed", 1.0, DHI)
    var = r.total_se("absorbed", 1.0, DHI) ** 2
    sky_p = SegmentEstimator(fs, ids, samples=16, bounces=0, **kw).render()  # the sky seen directly
    var_sky = (DHI * sky_p.se["absorbed_sky"]) ** 2

    fs.set_sun(-10.0, 180.0)  # the sky alone
    bl = np.flatnonzero(blade)
    SegmentEstimator(fs, ids[bl[:500]], samples=16, bounces=0, seed=9).render()  # compile
    t = time.perf_counter()
    g = SegmentEstimator(fs, ids[bl], samples=samples, bounces=0, seed=7).render()
    T_gather = time.perf_counter() - t
    fs.set_sun(*BENCH_SUN_DEG)
    var_g = (DHI * g.se["absorbed_sky"]) ** 2
    sky_bl, sky_bl_se = sky_p.absorbed_sky[bl], sky_p.se["absorbed_sky"][bl]
    z = np.abs(g.absorbed_sky - sky_bl) / np.hypot(g.se["absorbed_sky"], sky_bl_se)

    # Variances averaged over bins of blades by absorbed PAR (see the module docstring).
    sm = {"var": var.copy(), "sky": var_sky.copy()}
    c_blade = np.empty(len(bl))
    for b in np.array_split(np.argsort(x[bl]), BINS):
        for k in sm:
            sm[k][bl[b]] = sm[k][bl[b]].mean()
        c_blade[b] = var_g[b].mean() * samples
    t_point = T_gather / (len(bl) * samples)
    grid = np.linspace(0.3, 5.0, 95)
    lit = x > 0  # a segment without light has no relative SE; the median counts the others
    alone = min((a * T for a in grid if np.median(np.sqrt(sm["var"][lit] / a) / x[lit]) <= TARGET), default=np.inf)
    res = {}
    for name, rounded in (("best", False), ("best_rounded", True)):
        best = min(
            (hybrid_time(a, T, sm["var"], sm["sky"], c_blade, t_point, x, blade, rounded) + (a,) for a in grid),
            key=lambda q: q[0],
        )
        res[name] = {"s": best[0], "gathered_blades": best[1], "projection_scale": best[2]}
    return {
        "n_plants": n_plants,
        "segments": len(ids),
        "blades": len(bl),
        "rays_per_m2": list(RAYS),
        "render_s": T,
        "median_rse_as_reported": lit_median(np.sqrt(var), x),
        "sky_direct_variance_share_median_blades": lit_median(var_sky[blade], var[blade]),
        "gather_samples": samples,
        "gather_s": T_gather,
        "gather_s_per_point": t_point,
        "gather_over_projection_sky_mean": float(g.absorbed_sky.mean() / sky_bl.mean()),
        "gather_vs_projection_median_abs_z": float(np.median(z[np.isfinite(z)])),
        "projection_alone_s_at_2pct_binned": alone,
        "hybrid_s_at_2pct_binned": res["best"]["s"],
        "hybrid_rounded_s_at_2pct_binned": res["best_rounded"]["s"],
        "hybrid": res,
        "gain": alone / res["best"]["s"],
        "gain_rounded": alone / res["best_rounded"]["s"],
    }


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n-plants", type=int, default=500)
    ap.add_argument("--samples", type=int, default=128, help="gathered points per blade")
    out_option(ap, OUT)
    args = ap.parse_args()
    OUT = args.out
    res = main(args.n_plants, args.samples)
    res = json.loads(write_result(OUT, res, indent=2).read_text())  # with the provenance, for the summary
    t = Table(title=f"the sky gathered on top of the projection, {res['n_plants']} plants")
    t.add_column("to a 2 % median (binned variances)")
    t.add_column("time", justify="right")
    t.add_column("÷ projection alone", justify="right")
    alone = res["projection_alone_s_at_2pct_binned"]
    for label, v, h in (
        ("projection alone", alone, None),
        ("+ gathered sky, continuous k", res["hybrid_s_at_2pct_binned"], res["hybrid"]["best"]),
        ("+ gathered sky, k in rounds", res["hybrid_rounded_s_at_2pct_binned"], res["hybrid"]["best_rounded"]),
    ):
        extra = "" if h is None else f" ({h['gathered_blades']} blades, projection × {h['projection_scale']:.2f})"
        t.add_row(label + extra, f"{v:.0f} s", f"{v / alone:.2f}")
    wide_console().print(t)
    print(
        f"render {res['render_s']:.1f} s; gathering {res['gather_s']:.1f} s for {res['blades']} blades × "
        f"{res['gather_samples']} points; gathered ÷ projected sky {res['gather_over_projection_sky_mean']:.4f}, "
        f"median |z| {res['gather_vs_projection_median_abs_z']:.3f}; load "
        f"{res['load_average_start']:.1f}–{res['load_average_end']:.1f}; commit {res['lightfit_commit']}"
    )
    print(f"wrote {OUT}")
