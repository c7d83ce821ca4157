"""Benchmark: reverse-mode gradient (three leaf parameters) against the primal render it follows.

    python benchmarks/bench_gradient.py [--n-plants 36] [--samples 64] [--bounces 3] [--repeats 3] [--out JSON]

Finite field with 2 buffer rows, sun 50°, every measured segment. In one process, taking turns,
CPU time (all threads) per call, medians of ``repeats``:

- ``traced_primal``: ``render()`` tracing its paths (the first render of an estimator);
- ``primal``: ``render()`` with the paths kept (every later render: a day's later steps, other
  leaf parameters);
- ``vjp_after_render``: ``vjp()`` right after a render at the same sun (how the JAX bridge calls
  it: backward after forward), reusing that render's shadow rays;
- ``vjp_alone``: ``vjp()`` with no render's shadow rays to reuse.

Issue 16's goal: gradient ≤ 2.5 × the primal. Writes benchmarks/results/gradient.json (or
``--out``) and prints a table.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
from provenance import out_option, wide_console, write_result
from rich.table import Table

import lightfit  # noqa: F401
from lightfit.light.estimator import SegmentEstimator
from lightfit.light.scene import FieldScene, Optics
from lightfit.plant import Field, build
from lightfit.precision import use_float64

use_float64()
OUT = Path(__file__).parent / "results" / "gradient.json"


def _cpu(f) -> float:
    t = time.process_time()
    f()
    return time.process_time() - t


def main(n_plants: int = 36, samples: int = 64, bounces: int = 3, repeats: int = 3) -> dict:
    g = build(Field(boundary="finite", n_plants=n_plants, buffer_rows=2, seed=1))
    fs = FieldScene(g.mesh, Optics.preset("paper"))
    fs.set_sun(50.0, 180.0)
    ids = g.segments.loc[g.segments["measured"], "segment_id"].to_numpy()
    est = SegmentEstimator(fs, ids, samples=samples, bounces=bounces, seed=1)
    ct = {"absorbed_sun": np.ones(len(ids)), "absorbed_sky": np.full(len(ids), 0.3)}
    est.render()  # compile every kernel once
    est.vjp(ct)
    est._suns_kept.clear()
    est.vjp(ct)
    runs: dict[str, list[float]] = {k: [] for k in ("traced_primal", "primal", "vjp_after_render", "vjp_alone")}
    for _ in range(repeats):
        est._kept = None  # drop the kept paths: this render traces them
        runs["traced_primal"].append(_cpu(est.render))
        est._suns_kept.clear()  # the kept paths, this sun's shadow rays cast again (a new step's)
        runs["primal"].append(_cpu(est.render))
        runs["vjp_after_render"].append(_cpu(lambda: est.vjp(ct)))
        est._suns_kept.clear()  # nothing to reuse
        runs["vjp_alone"].append(_cpu(lambda: est.vjp(ct)))
    med = {k: float(np.median(v)) for k, v in runs.items()}
    res = {
        "command": f"python benchmarks/bench_gradient.py --n-plants {n_plants} --samples {samples} "
        f"--bounces {bounces} --repeats {repeats}",
        "segments": int(len(ids)),
        "evaluations": int(est.n_evaluations),
        "cpu_s": runs,
        "cpu_s_median": med,
        "vjp_after_render_over_primal": med["vjp_after_render"] / med["primal"],
        "vjp_after_render_over_traced_primal": med["vjp_after_render"] / med["traced_primal"],
        "vjp_alone_over_primal": med["vjp_alone"] / med["primal"],
    }
    write_result(OUT, res, indent=1)
    t = Table(title=f"gradient vs primal ({len(ids)} segments, K = {samples}, {bounces} bounces; CPU s, medians)")
    for c in ("call", "CPU s", "÷ primal (kept paths)"):
        t.add_column(c)
    for k, v in med.items():
        t.add_row(k, f"{v:.2f}", f"{v / med['primal']:.2f}")
    wide_console().print(t)
    print(f"wrote {OUT}")
    return res


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n-plants", type=int, default=36)
    ap.add_argument("--samples", type=int, default=64)
    ap.add_argument("--bounces", type=int, default=3)
    ap.add_argument("--repeats", type=int, default=3)
    out_option(ap, OUT)
    a = ap.parse_args()
    OUT = a.out
    main(a.n_plants, a.samples, a.bounces, a.repeats)
