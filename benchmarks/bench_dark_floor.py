"""Benchmark: adaptive sampling with and without its light floor (``render_adaptive(dark_floor=)``).

    python benchmarks/bench_dark_floor.py [--n-plants 100] [--targets 0.1 0.05] [--floors 0 0.005]
        [--out JSON]

The default field (periodic cell, wrapped sheaths, PROSPECT-D leaf, its 2 bounces; the light
benchmarks' ``periodic_cell``), the sun at 50° elevation, absorbed PAR at
DNI 1 and DHI 0.3, the projected direct light at its default rays, a pilot of 32 points and the
coupled model's cap (``MAX_ADAPTIVE_SAMPLES``). For each target the floors are run in turn, in
one process (a warm-up render first), so their times are side by side. Reported per run: wall
time, evaluations (points × sides rendered), segments at the cap and stopped by the floor,
reached relative SE (median and 90th percentile over the segments above the largest floor, by
each run's own estimate, and over all segments with light), and the canopy's absorbed PAR
(Σ area × value) against the first floor's, in units of its Monte Carlo SE (the floor must not
move it beyond noise).

Writes benchmarks/results/dark_floor.json (or ``--out``) and prints a table.
"""

from __future__ import annotations

import argparse
import math
import os
import time
from pathlib import Path

import numpy as np
from bench_light import periodic_cell
from provenance import out_option, wide_console, write_result
from rich.table import Table

import lightfit  # noqa: F401
from lightfit.light.estimator import DARK_FLOOR, SegmentEstimator, render_adaptive
from lightfit.model.scenario import MAX_ADAPTIVE_SAMPLES
from lightfit.plant.sheaths import SHEATHS
from lightfit.precision import use_float64

use_float64()  # lightfit's precision policy (lightfit.precision), before any JAX array exists

OUT = Path(__file__).resolve().parent / "results" / "dark_floor.json"
DNI, DHI = 1.0, 0.3


def _quantiles(x: np.ndarray) -> dict:
    return {"median": float(np.median(x)), "p90": float(np.quantile(x, 0.9))}


def run(fs, ids, target: float, floor: float, compare_floor: float, bounces: int) -> tuple[dict, object]:
    """One adaptive render; its SEs summarised over the segments above ``compare_floor`` (the
    largest floor of the bench, by this run's estimate) and over all with light."""
    t = time.perf_counter()
    r = render_adaptive(
        fs,
        ids,
        target,
        bounces=bounces,
        seed=1,
        max_samples=MAX_ADAPTIVE_SAMPLES,
        direct="projection",
        dark_floor=floor,
    )
    wall = time.perf_counter() - t
    K, rse, on_floor = r.meta["samples_per_segment"], r.meta["reached_rse"], r.meta["stopped_on_floor"]
    value = r.total("absorbed", DNI, DHI)
    above = value >= compare_floor * (DNI * float(fs.sun[2]) + DHI)
    lit = np.isfinite(rse)
    area = r.meta["area_m2"]
    se = np.multiply(rse, value, out=np.zeros_like(value), where=lit)
    return {
        "target_rse": target,
        "dark_floor": floor,
        "time_s": wall,
        "evaluations": int(r.meta["n_evaluations"]),
        "segments_at_cap": int((K == MAX_ADAPTIVE_SAMPLES).sum()),
        "segments_stopped_on_floor": int(on_floor.sum()),
        "segments_below_floor": int((~above).sum()),
        "segments_without_light": int((~lit).sum()),
        "rse_above_floor": _quantiles(rse[above & lit]),
        "rse_all_lit": _quantiles(rse[lit]),
        "canopy_absorbed": float(np.sum(area * value)),
        "canopy_absorbed_se": float(math.sqrt(np.sum((area * se) ** 2))),
    }, r


def main(n_plants: int, targets: list[float], floors: list[float], out: Path) -> dict:
    console = wide_console()
    g, fs, ids, bounces = periodic_cell(n_plants)
    res = {
        "n_plants": n_plants,
        "segments": len(ids),
        "sheaths": SHEATHS[0],
        "bounces": bounces,
        "max_samples": MAX_ADAPTIVE_SAMPLES,
        "load_average_start": os.getloadavg()[0],  # the field built: the start of the timed renders
        "runs": [],
    }
    SegmentEstimator(fs, ids[:200], samples=32, bounces=bounces, seed=9, direct="projection").render()  # warm-up
    for target in targets:
        first = None
        for floor in floors:
            row, _ = run(fs, ids, target, floor, max(floors), bounces)
            first = first or row
            d = row["canopy_absorbed"] - first["canopy_absorbed"]
            row["canopy_difference_z"] = d / math.hypot(row["canopy_absorbed_se"], first["canopy_absorbed_se"])
            row["time_over_first"] = row["time_s"] / first["time_s"]
            res["runs"].append(row)
            console.print(f"target {target:.0%}, floor {floor:g}: {row['time_s']:.1f} s")
    write_result(out, res, indent=1)
    t = Table(title=f"adaptive sampling, {n_plants}-plant cell, {len(ids)} segments, cap {MAX_ADAPTIVE_SAMPLES}")
    for c in (
        "target",
        "floor",
        "time s (÷ no floor)",
        "evaluations",
        "at cap",
        "stopped on floor",
        "median / p90 above floor",
        "median / p90 all lit",
        "canopy Δ / SE",
    ):
        t.add_column(c, justify="right")
    for r in res["runs"]:
        t.add_row(
            f"{r['target_rse']:.0%}",
            f"{r['dark_floor']:g}",
            f"{r['time_s']:.1f} ({r['time_over_first']:.2f})",
            f"{r['evaluations']:.3g}",
            str(r["segments_at_cap"]),
            str(r["segments_stopped_on_floor"]),
            f"{r['rse_above_floor']['median']:.1%} / {r['rse_above_floor']['p90']:.1%}",
            f"{r['rse_all_lit']['median']:.1%} / {r['rse_all_lit']['p90']:.1%}",
            f"{r['canopy_difference_z']:+.2f}",
        )
    console.print(t)
    return res


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n-plants", type=int, default=100)
    ap.add_argument("--targets", type=float, nargs="+", default=[0.1, 0.05])
    ap.add_argument("--floors", type=float, nargs="+", default=[0.0, DARK_FLOOR])
    out_option(ap, OUT)
    a = ap.parse_args()
    main(a.n_plants, a.targets, a.floors, a.out)
