"""Does adaptive sampling's light floor bias the dark segments it stops? Against an independent reference.

    python experiments/dark_floor_bias.py [--seeds 10] [--floors 0 0.005] [--target 0.05]
        [--out experiments/results/dark_floor_bias.json]

A segment stopped by the floor (``render_adaptive(dark_floor=)``) stops when its *absolute* SE
is small, and a segment's SE is small when its estimate happens to be low, so the floor can
select low estimates (a sequential design's selection effect). This measures it where it can
show: the 16-plant default cell (periodic, wrapped sheaths, PROSPECT-D leaf and its 2 bounces; the
light benchmarks' ``periodic_cell``), the sun at 50°, absorbed PAR at DNI 1
and DHI 0.3, target ``--target``, with the direct light from the paths and projected. The
segments judged are fixed in advance, not by any run's data: those whose reference light is
below the floor ("dark", mostly culms inside their sheaths) and, apart, the blades. The reference
is the mean of 4 seeds at K = 2 048 with the paths' direct light (seeds 100–103, independent of the
runs' seeds 0 …). Per floor and mode: the area-weighted total of each class over ``--seeds``
seeds' adaptive renders ÷ the reference's − 1, with its SE over the seeds (the reference's own
noise is in the last column).

Writes experiments/results/dark_floor_bias.json and prints a table.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np
from rich.table import Table

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

from bench_light import periodic_cell  # noqa: E402
from provenance import wide_console, write_result  # noqa: E402

from lightfit.light.estimator import DARK_FLOOR, SegmentEstimator, render_adaptive  # noqa: E402
from lightfit.plant.sheaths import SHEATHS  # noqa: E402
from lightfit.precision import use_float64  # noqa: E402

use_float64()  # lightfit's precision policy (lightfit.precision), before any JAX array exists

OUT = ROOT / "experiments" / "results" / "dark_floor_bias.json"
DNI, DHI = 1.0, 0.3
REF_K, REF_SEEDS = 2048, (100, 101, 102, 103)
#: The adaptive renders' cap, well above the 3 / f = 600 points a floor of 0.5 % waits for.
MAX_SAMPLES = 4096


def main(seeds: int, floors: list[float], target: float, out: Path) -> dict:
    console = wide_console()
    g, fs, ids, bounces = periodic_cell(16)
    refs = [
        SegmentEstimator(fs, ids, samples=REF_K, bounces=bounces, seed=s).render().total("absorbed", DNI, DHI)
        for s in REF_SEEDS
    ]
    ref = np.mean(refs, 0)
    first = render_adaptive(fs, ids, target, bounces=bounces, seed=0, max_samples=32, dark_floor=max(floors))
    area, blade = first.meta["area_m2"], first.meta["is_blade"]
    floor_light = max(floors) * (DNI * float(fs.sun[2]) + DHI)
    classes = {"dark (reference below the floor)": (ref < floor_light) & (ref > 0), "blades": blade}
    ref_tot = {c: float(np.sum(area[m] * ref[m])) for c, m in classes.items()}
    ref_se = {
        c: float(np.std([np.sum(area[m] * x[m]) for x in refs], ddof=1) / math.sqrt(len(refs)) / ref_tot[c])
        for c, m in classes.items()
    }
    rows = []
    for direct in ("paths", "projection"):
        for f in floors:
            rel = {c: [] for c in classes}
            evals, flagged = [], []
            for seed in range(seeds):
                r = render_adaptive(
                    fs, ids, target, bounces=bounces, seed=seed, max_samples=MAX_SAMPLES, direct=direct, dark_floor=f
                )
                v = r.total("absorbed", DNI, DHI)
                for c, m in classes.items():
                    rel[c].append(float(np.sum(area[m] * v[m])) / ref_tot[c] - 1.0)
                evals.append(r.meta["n_evaluations"])
                flagged.append(int(r.meta["stopped_on_floor"].sum()))
            row = {
                "direct": direct,
                "dark_floor": f,
                "evaluations_mean": float(np.mean(evals)),
                "flagged_mean": float(np.mean(flagged)),
            }
            for c, x in rel.items():
                row[c] = {"bias": float(np.mean(x)), "bias_se": float(np.std(x, ddof=1) / math.sqrt(len(x)))}
            rows.append(row)
            console.print(f"{direct}, floor {f:g} done")
    res = {
        "n_plants": 16,
        "sheaths": SHEATHS[0],
        "target_rse": target,
        "seeds": seeds,
        "reference_samples": REF_K,
        "reference_seeds": list(REF_SEEDS),
        "max_samples": MAX_SAMPLES,
        "segments": {c: int(m.sum()) for c, m in classes.items()},
        "reference_share_of_canopy": {c: ref_tot[c] / float(np.sum(area * ref)) for c in classes},
        "reference_relative_se": ref_se,
        "rows": rows,
    }
    out.parent.mkdir(parents=True, exist_ok=True)
    write_result(out, res, indent=1)
    t = Table(title=f"adaptive sampling to {target:.0%}: class totals ÷ the reference − 1 ({seeds} seeds)")
    for c in ("direct", "floor", "evaluations", "segments done by the floor", *classes):
        t.add_column(c, justify="right")
    for r in rows:
        t.add_row(
            r["direct"],
            f"{r['dark_floor']:g}",
            f"{r['evaluations_mean']:.3g}",
            f"{r['flagged_mean']:.0f}",
            *(f"{r[c]['bias']:+.1%} ± {r[c]['bias_se']:.1%}" for c in classes),
        )
    t.add_row("reference", "", "", "", *(f"± {ref_se[c]:.1%}" for c in classes))
    console.print(t)
    console.print(
        "segments: "
        + ", ".join(
            f"{c} {res['segments'][c]} ({res['reference_share_of_canopy'][c]:.2%} of the light)" for c in classes
        )
    )
    return res


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--floors", type=float, nargs="+", default=[0.0, DARK_FLOOR])
    ap.add_argument("--target", type=float, default=0.05)
    ap.add_argument("--out", type=Path, default=OUT)
    a = ap.parse_args()
    main(a.seeds, a.floors, a.target, a.out)
