"""Benchmark: the emulator's design renders, point by point against one batch (trace once, weigh many).

    .venv/bin/python benchmarks/bench_design.py [--config quick|default] [--n-design 20] [--steps A:B] [--json JSON]

Renders the same Sobol design (``--n-design`` points over the informed prior box of specular,
roughness, subsurface; seed 0) of a 20 April 2016 configuration at its daytime steps (``--steps``:
a slice of them, e.g. ``0:5``), side by side in one process:

- ``per_point``: one :meth:`CoupledModel.render` per point with the paths traced anew for every
  point — the cost of the design before ``render_many`` (the estimator then kept its paths only
  while the leaf parameters stayed; emulated here by dropping the kept geometry whenever they
  change);
- ``batch``: :meth:`CoupledModel.render_many` — paths traced once, each sun's shadow rays cast
  once, every point only weighed.

Reports both times, their ratio, the batch's first point (tracing and shadow rays included) and
later points, and the largest difference between the two (absolute, and relative to the largest
value of each step and part). Writes/updates ``benchmarks/results/design.json`` (or ``--json``; one
entry per configuration, each with its run's commit and load) and prints a table.
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

from lightfit.precision import use_float64

use_float64()  # the command line's precision policy (lightfit.precision), before any JAX array exists

import numpy as np  # noqa: E402
from provenance import record, write_result  # noqa: E402  (same script folder)

from lightfit.inference import mcmc as P  # noqa: E402
from lightfit.light.bsdf import LEAF_PARAMETERS  # noqa: E402
from lightfit.light.estimator import SegmentEstimator  # noqa: E402
from lightfit.model import emulator as E  # noqa: E402
from lightfit.replication import ReplicationConfig, forcing, model_for  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def per_point_geometry():
    """Patch: drop the kept geometry whenever the leaf parameters change (the previous cost)."""
    traced = SegmentEstimator._geometry

    def geometry(self):
        leaf = tuple(float(getattr(self.fs.bsdf, k)[0]) for k in LEAF_PARAMETERS)
        if getattr(self, "_bench_leaf", None) != leaf:
            self._kept, self._bench_leaf = None, leaf
        return traced(self)

    return traced, geometry


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", choices=("quick", "default"), default="quick")
    ap.add_argument("--n-design", type=int, default=E.DESIGN_SIZE)
    ap.add_argument("--steps", default=None, help="slice of the daytime steps, e.g. 0:5 (default: all)")
    ap.add_argument(
        "--out",
        "--json",
        dest="json",
        type=Path,
        default=ROOT / "benchmarks" / "results" / "design.json",
        help="JSON to write/update (default benchmarks/results/design.json, the tracked result the docs cite)",
    )
    args = ap.parse_args(argv)
    cfg = ReplicationConfig.quick() if args.config == "quick" else ReplicationConfig()
    t = time.perf_counter()
    model = model_for(cfg, forcing())
    t_build = time.perf_counter() - t
    if args.steps:
        day = np.flatnonzero(model.day)
        a, b = (int(x) if x else None for x in args.steps.split(":"))
        keep = np.zeros(len(model.day), bool)
        keep[day[a:b]] = True
        model = E.restrict(model, keep)
    pri = P.PRIORS_INFORMED
    lo = [pri[n].support[0] for n in LEAF_PARAMETERS]
    hi = [pri[n].support[1] for n in LEAF_PARAMETERS]
    design = E.sobol_design(args.n_design, lo, hi, 0)
    thetas = [dict(zip(LEAF_PARAMETERS, x)) for x in design]
    n_steps = int(model.day.sum())
    print(f"{args.config}: {len(model.segment_id)} segments, {n_steps} daytime steps, {len(design)} points", flush=True)

    # Warm-up (kernels compiled and cached, scene built), not timed: one point each way.
    model.render(thetas[0])
    list(model.render_many(thetas[:1]))

    t = time.perf_counter()
    batch, per = [], []  # values per point; seconds per point (the first includes the tracing)
    for v, _ in model.render_many(thetas):
        per.append(time.perf_counter() - t - sum(per))
        batch.append(v)
    t_batch = time.perf_counter() - t
    first, later = per[0], per[1:]

    traced, patched = per_point_geometry()
    SegmentEstimator._geometry = patched
    try:
        t = time.perf_counter()
        single = [np.asarray(model.render(th)[0]) for th in thetas]
        t_single = time.perf_counter() - t
    finally:
        SegmentEstimator._geometry = traced

    b, s = np.stack(batch), np.stack(single)
    diff = np.abs(b - s)
    scale = np.abs(s).max(axis=(0, 3), keepdims=True)  # per step and part
    rel = float(np.max(np.divide(diff, scale, out=np.zeros_like(diff), where=scale > 0)))
    res = {
        **record(),  # this entry's own run (the file keeps one entry per configuration)
        "config": args.config,
        "segments": int(len(model.segment_id)),
        "columns": int(model.n_columns),
        "daytime_steps": n_steps,
        "n_design": len(design),
        "samples": int(model.scenario.samples),
        "bounces": int(model.scenario.bounces),
        "boundary": cfg.boundary,
        "model_build_s": t_build,
        "per_point_s": t_single,
        "batch_s": t_batch,
        "ratio_per_point_over_batch": t_single / t_batch,
        "batch_first_point_s": first,
        "batch_later_points_median_s": float(np.median(later)) if later else None,
        "max_abs_diff": float(diff.max()),
        "max_rel_diff_to_step_part_max": rel,
        "bitwise_equal": bool((b == s).all()),
        "platform": platform.platform(),
        "note": "2 cores shared with other jobs; ratio measured side by side in one process",
    }
    old = json.loads(args.json.read_text()) if args.json.exists() else {}
    out = {k: v for k, v in old.items() if isinstance(v, dict)}  # the entries; the last write's record is new
    out[args.config + ("" if not args.steps else f"[steps {args.steps}]")] = res
    write_result(args.json, out, indent=2)
    head = ("configuration", "points × steps", "per point (s)", "batch (s)", "ratio", "1st / later (s)", "max diff")
    print("| " + " | ".join(head) + " |")
    print("|---|---|---|---|---|---|---|")
    for k, r in out.items():
        lp = r["batch_later_points_median_s"]
        lp = "–" if lp is None else f"{lp:.2f}"
        print(
            f"| {k} ({r['segments']} segments, K={r['samples']}, {r['bounces']} bounces) | "
            f"{r['n_design']} × {r['daytime_steps']} | {r['per_point_s']:.1f} | {r['batch_s']:.1f} | "
            f"{r['ratio_per_point_over_batch']:.1f} | {r['batch_first_point_s']:.2f} / {lp} | "
            f"{r['max_abs_diff']:.1e}{' (bitwise)' if r['bitwise_equal'] else ''} |"
        )


if __name__ == "__main__":
    main()
