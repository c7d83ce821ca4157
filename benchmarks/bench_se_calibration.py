"""Benchmark: are the reported per-segment standard errors right? Seed-to-seed spread against them (issue 16).

    python benchmarks/bench_se_calibration.py [--n-plants 100] [--seeds 12] [--samples 16]
        [--rays 1.5e7 2e7] [--tea-rounds 16 4] [--out JSON]

Every render reports a standard error per segment from its R replicates. Here N renders with seeds
1 … N of the defaults' periodic cell (PROSPECT-D leaf, the bounces for 1 % truncation, the
projection at ``--rays`` per m² for sun and sky, sun 50°) give each segment of absorbed PAR (sun +
0.3·sky) two independent estimates of the same variance: the seeds' spread s² (N − 1 degrees of
freedom) and the mean of the reported SE² (N·(R − 1)). Their ratio has an F(N − 1, N(R − 1))
distribution when the SEs are right, so its mean over segments should be d₂/(d₂ − 2) and its median
F's median; a ratio above that means the reported SEs are too small (what the seed-difference |z|
of ``bench_light.py`` hinted at, with a Student's t that skewed sparse counts only approximate).
Also the ratio of sums Σ s² / Σ SE² (1 when unbiased; the noisiest segments weigh most) and the
same by quartile of relative SE and for blades and stems. Each ``--tea-rounds`` value
(:data:`lightfit.light.keyed_random.TEA_ROUNDS`, the hash behind the projection's random numbers; 4
was the value before: Mitsuba's default) is measured in turn in the same process, with its mean
render time. Writes
benchmarks/results/se_calibration.json (or ``--out``) and prints a table, with the commit and the load average.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
from bench_light import periodic_cell  # same script folder
from provenance import out_option, wide_console, write_result
from rich.progress import track
from rich.table import Table
from scipy.stats import f as fisher

import lightfit  # noqa: F401
from lightfit.light import keyed_random
from lightfit.light.estimator import SegmentEstimator
from lightfit.plant import Field
from lightfit.precision import use_float64

use_float64()  # lightfit's precision policy (lightfit.precision), before any JAX array exists

OUT = Path(__file__).resolve().parent / "results" / "se_calibration.json"


def _ratios(spread: np.ndarray, se2: np.ndarray) -> dict:
    r = spread / se2
    return {
        "n": int(r.size),
        "mean": float(r.mean()),
        "median": float(np.median(r)),
        "ratio_of_sums": float(spread.sum() / se2.sum()),
    }


def expected_ratio(d1: int, d2: int) -> tuple[float | None, float]:
    """Mean and median of F(d1, d2), the ratio's distribution when the SEs are right. The mean is
    d2 / (d2 − 2) only for d2 > 2; with fewer degrees of freedom (2 seeds at R = 2) it is infinite:
    ``None``, not a division by zero after the renders."""
    return (d2 / (d2 - 2) if d2 > 2 else None), float(fisher.median(d1, d2))


def calibration(fs, ids, bounces: int, seeds: int, samples: int, rays, console) -> dict:
    """The seeds' spread against the reported SE² at the current :data:`keyed_random.TEA_ROUNDS`."""
    values, se2, times = [], [], []
    for seed in track(range(1, seeds + 1), description=f"{keyed_random.TEA_ROUNDS} rounds", console=console):
        t = time.perf_counter()
        est = SegmentEstimator(
            fs, ids, samples=samples, bounces=bounces, seed=seed, direct="projection", direct_rays_per_m2=rays
        )
        r = est.render()
        times.append(time.perf_counter() - t)
        v = r.total("absorbed", 1.0, 0.3)
        se2.append(r.total_se() ** 2)  # unlit segments: 0, left out below
        values.append(v)
        R, blade = est.replicates, np.asarray(r.meta["is_blade"], bool)
        del est
    values, se2 = np.array(values), np.array(se2)
    ok = np.all(np.isfinite(se2) & (se2 > 0), axis=0)
    spread, mse2 = values.var(0, ddof=1)[ok], se2.mean(0)[ok]
    d1, d2 = seeds - 1, seeds * (R - 1)
    expected_mean, expected_median = expected_ratio(d1, d2)
    rse = np.sqrt(mse2) / values.mean(0)[ok]
    edges = np.quantile(rse, [0, 0.25, 0.5, 0.75, 1])
    groups = {"all": np.ones(rse.size, bool), "blades": blade[ok], "stems": ~blade[ok]}
    for i, (lo, hi) in enumerate(zip(edges[:-1], edges[1:])):
        groups[f"relative SE quartile {i + 1} ({lo:.1%}–{hi:.1%})"] = (rse >= lo) & (rse <= hi)
    return {
        "tea_rounds": keyed_random.TEA_ROUNDS,
        "replicates": R,
        "segments_compared": int(ok.sum()),
        # One render's median relative SE: from the reported SEs (pooled over the seeds, so hardly
        # biased by the replicates' few degrees of freedom) and from the seeds' spread.
        "median_rse_reported": float(np.median(rse)),
        "median_rse_seed_spread": float(np.median(np.sqrt(spread) / values.mean(0)[ok])),
        "render_s_mean": float(np.mean(times[1:])),  # the first compiles the kernels
        "expected_mean": expected_mean,  # None: infinite (d2 ≤ 2)
        "expected_median": expected_median,
        "groups": {k: _ratios(spread[m], mse2[m]) for k, m in groups.items()},
    }


def main(n_plants: int = 100, seeds: int = 12, samples: int = 16, rays=(1.5e7, 2e7), rounds=(16, 4)) -> dict:
    console = wide_console()
    geom, fs, ids, bounces = periodic_cell(n_plants)
    runs = []
    default = keyed_random.TEA_ROUNDS
    try:
        for n in rounds:
            keyed_random.TEA_ROUNDS = n
            runs.append(calibration(fs, ids, bounces, seeds, samples, rays, console))
    finally:
        keyed_random.TEA_ROUNDS = default
    res = {
        "n_plants_measured": int(Field(n_plants=n_plants).n_measured),
        "segments": len(ids),
        "samples": samples,
        "rays_per_m2": list(rays),
        "bounces": bounces,
        "seeds": seeds,
        "runs": runs,
    }
    res = json.loads(write_result(OUT, res, indent=2).read_text())  # with the provenance, for the table
    for run in runs:
        t = Table(
            title=f"seeds' spread ÷ reported SE², TEA {run['tea_rounds']} rounds ({seeds} seeds, K = {samples}, "
            f"R = {run['replicates']}, render {run['render_s_mean']:.2f} s, median relative SE reported "
            f"{run['median_rse_reported']:.2%}, from the seeds' spread {run['median_rse_seed_spread']:.2%})"
        )
        for c in ("segments", "n", "mean", "median", "Σ spread / Σ SE²"):
            t.add_column(c, justify="right")
        mean = "∞ (d₂ ≤ 2)" if run["expected_mean"] is None else f"{run['expected_mean']:.3f}"
        t.add_row("expected if the SEs are right", "", mean, f"{run['expected_median']:.3f}", "1")
        for k, q in run["groups"].items():
            t.add_row(k, str(q["n"]), f"{q['mean']:.3f}", f"{q['median']:.3f}", f"{q['ratio_of_sums']:.3f}")
        console.print(t)
    console.print(
        f"commit {res['lightfit_commit']}, load {res['load_average_start']:.1f} → {res['load_average_end']:.1f}"
    )
    return res


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n-plants", type=int, default=100)
    ap.add_argument("--seeds", type=int, default=12)
    ap.add_argument("--samples", type=int, default=16)
    ap.add_argument("--rays", type=float, nargs=2, default=(1.5e7, 2e7), metavar=("SUN", "SKY"))
    ap.add_argument("--tea-rounds", type=int, nargs="+", default=(16, 4), help="TEA rounds measured in turn")
    out_option(ap, OUT)
    a = ap.parse_args()
    OUT = a.out
    main(a.n_plants, a.seeds, a.samples, tuple(a.rays), tuple(a.tea_rounds))
