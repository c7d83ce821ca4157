"""Benchmark: a full-render calibration loss and its gradient with each sun's rays kept.

    python benchmarks/bench_kept_suns.py [--start 09:00] [--end 11:00] [--repeat 3] [--out JSON]

The main job's default model (the measured plants as one periodic cell, the PROSPECT-D leaf, the
direct light projected, K = 32) on a window of 20 April 2016 (reconstructed forcing; 09:00–11:00
UTC: 5 steps), twin observations, and the calibration loss of specular and subsurface
(:func:`lightfit.inference.calibration.make_loss`). Every loss evaluation renders each step at its
sun; the projected sun hits and the paths' shadow rays depend on the sun and the seed, not on the
leaf parameters, so with :data:`lightfit.light.projection.SUN_HITS_BUDGET_BYTES` (2 GiB) an
estimator casts each sun's rays once and later evaluations only weigh them, where with a budget of
0 (the behaviour before) each render dropped the other suns and cast its own again. For both
budgets, in one process (budget 0 first, then the default after one warm-up evaluation at another
point): the median time of a loss evaluation and of a loss-and-gradient evaluation
(``jax.jit(jax.grad)``), at points moved slightly each time, that the values are bitwise the
same, and the bytes of sun hits and shadow rays kept after the loss evaluations.

Writes benchmarks/results/kept_suns.json (or ``--out``; with the commit and load average) and prints a table.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from provenance import out_option, wide_console, write_result  # same script folder
from rich.table import Table

from lightfit import replication as rep
from lightfit.inference.calibration import make_loss, to_unconstrained
from lightfit.inference.twin import twin_observations
from lightfit.light import projection
from lightfit.model.parameters import Theta
from lightfit.precision import use_float64

use_float64()  # lightfit's precision policy (lightfit.precision), before any JAX array exists

OUT = Path(__file__).resolve().parent / "results" / "kept_suns.json"
NAMES = ("specular", "subsurface")


def main(start: str = "09:00", end: str = "11:00", repeat: int = 3) -> dict:
    w = rep.forcing().loc[f"2016-04-20 {start}+00:00" : f"2016-04-20 {end}+00:00"]
    model = rep.model_for(rep.ReplicationConfig(), w)
    obs = twin_observations(model, Theta().replace(subsurface=0.5), render_seed=3, noise_seed=1)
    loss = make_loss(model, obs, NAMES)
    grad = jax.jit(jax.grad(lambda z: loss(z)[0]))
    z0 = jnp.asarray([to_unconstrained(v, n) for v, n in zip((0.45, 0.35), NAMES)])
    points = [z0 + 0.01 * i for i in range(repeat)]
    loss(z0 + 1.0)  # build the estimator, compile every kernel and the photosynthesis
    grad(z0 + 1.0)
    rows, values = {}, {}
    default = projection.SUN_HITS_BUDGET_BYTES
    for label, budget in (("budget 0: cast at every render", 0), ("kept within the budget", default)):
        projection.SUN_HITS_BUDGET_BYTES = budget
        loss(z0 - 1.0)  # one evaluation at another point: fills the kept suns (or not)
        t_loss, t_grad, vals = [], [], []
        for z in points:
            t = time.perf_counter()
            vals.append(float(loss(z)[0]))
            t_loss.append(time.perf_counter() - t)
        kept = _kept_bytes(model.scenario.seed)  # after the losses (a gradient's reverse passes cast without trimming)
        for z in points[:2]:
            t = time.perf_counter()
            vals.extend(np.asarray(grad(z)).tolist())
            t_grad.append(time.perf_counter() - t)
        values[label] = vals
        rows[label] = {
            "budget_bytes": projection.SUN_HITS_BUDGET_BYTES,
            "loss_s": float(np.median(t_loss)),
            "loss_and_gradient_s": float(np.median(t_grad)),
            "kept_sun_bytes": kept,
        }
    a, b = rows.values()
    res = {
        "window_utc": [start, end],
        "steps": len(w),
        "calibrated": list(NAMES),
        "rows": rows,
        "loss_speedup": a["loss_s"] / b["loss_s"],
        "loss_and_gradient_speedup": a["loss_and_gradient_s"] / b["loss_and_gradient_s"],
        "values_bitwise_equal": values[next(iter(values))] == values[list(values)[1]],
    }
    write_result(OUT, res, indent=2)
    t = Table(title=f"full-render calibration loss, default model, {len(w)} steps, 2 CPU cores")
    for c in ("each sun's rays", "loss", "loss + gradient", "kept after the losses"):
        t.add_column(c, justify="right")
    for label, r in rows.items():
        mib = r["kept_sun_bytes"] / 2**20
        t.add_row(label, f"{r['loss_s']:.2f} s", f"{r['loss_and_gradient_s']:.2f} s", f"{mib:.0f} MiB")
    wide_console().print(t)
    wide_console().print(
        f"speed-up: loss {res['loss_speedup']:.2f}×, loss + gradient {res['loss_and_gradient_speedup']:.2f}×; "
        f"values bitwise equal: {res['values_bitwise_equal']}"
    )
    return res


def _kept_bytes(seed: int) -> int:
    """Bytes of sun hits and shadow rays kept by the live estimators of ``seed`` (the model's; the
    twin observations' renders used another seed)."""
    import gc

    from lightfit.light.estimator import SegmentEstimator

    gc.collect()
    live = [x for x in gc.get_objects() if isinstance(x, (projection.DirectProjection, SegmentEstimator))]
    live = [x for x in live if x.seed == seed]
    hits = sum(sum(x.kept_sun_bytes().values()) for x in live if isinstance(x, projection.DirectProjection))
    rays = sum(len(x._suns_kept) * x.n_evaluations * (4 + x.bounces) for x in live if isinstance(x, SegmentEstimator))
    return hits + rays


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--start", default="09:00", help="window start, UTC")
    ap.add_argument("--end", default="11:00", help="window end, UTC")
    ap.add_argument("--repeat", type=int, default=3)
    out_option(ap, OUT)
    a = ap.parse_args()
    OUT = a.out
    main(a.start, a.end, a.repeat)
