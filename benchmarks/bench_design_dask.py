"""Emulator design renders in this process vs on an embedded Dask cluster (issue 15 item 2).

Run:  .venv/bin/python benchmarks/bench_design_dask.py [--points 8] [--workers 2] [--out JSON]
Writes benchmarks/results/design_dask.json (``--samples K``: design_dask_k<K>.json; or ``--out``) and prints a
table.

The quick configuration's whole 20 April day (4 plants, K=16, 2 bounces, periodic, 25 daytime
steps), ``--points`` Sobol design points over the informed prior box, each into its own empty render
cache (plants from the shared plant cache):

- ``local``: :func:`lightfit.model.emulator.render_parts` in this process (Dr.Jit's thread pool: all
  cores), and the same with one Dr.Jit thread (what each worker has);
- ``dask``: :func:`lightfit.distributed.design.render_design` on ``connect(workers=N)`` (single-threaded
  worker processes); timed with and without starting the cluster, and split into the workers'
  model rebuild (imports, plants, scene) and render seconds.

All in one run, alternated ``--repeats`` times (medians), with the load average after each repeat
(the machine is shared); the caches are compared bitwise. CPU-bound renders on C cores cannot gain more than C×.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from dataclasses import replace
from pathlib import Path

os.environ.setdefault("JAX_PLATFORMS", "cpu")

from lightfit.precision import use_float64  # noqa: E402

use_float64()  # lightfit's precision policy, as the command line and the workers

import numpy as np  # noqa: E402
from provenance import write_result  # noqa: E402  (same script folder)

from lightfit import replication as rep  # noqa: E402
from lightfit.distributed import connect  # noqa: E402
from lightfit.distributed.design import render_design  # noqa: E402
from lightfit.inference.posterior import prior_set  # noqa: E402
from lightfit.model import emulator as E  # noqa: E402

RESULTS = Path(__file__).parent / "results"


def _same(a: Path, b: Path, key: dict, pts) -> bool:
    """Whether two render caches hold bitwise the same values and SEs at ``pts``."""
    for x in pts:
        with np.load(E.render_file(a, key, x)) as u, np.load(E.render_file(b, key, x)) as v:
            if not (np.array_equal(u["values"], v["values"]) and np.array_equal(u["se"], v["se"])):
                return False
    return True


def main(
    points: int = 8, workers: int = 2, repeats: int = 2, samples: int | None = None, out: Path | None = None
) -> dict:
    import drjit as dr

    cfg = rep.ReplicationConfig.quick()
    if samples is not None:  # a heavier render per point, same field
        cfg = replace(cfg, samples=samples)
    model = rep.model_for(cfg, rep.forcing())
    box = prior_set("informed", model.scenario.optics)
    lo = [box[n].support[0] for n in E.LEAF_PARAMETERS]
    hi = [box[n].support[1] for n in E.LEAF_PARAMETERS]
    pts = E.sobol_design(points, lo, hi, seed=0)
    key = E.render_key(model)
    threads = dr.thread_count()
    E.render_parts(model, pts[:1])  # warm-up: kernels traced and compiled in this process
    rows: dict[str, list[float]] = {"local": [], "local_1_thread": [], "dask_render": [], "dask_total": []}
    starts, infos, load, same = [], [], [os.getloadavg()], True
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(repeats):  # alternated, so that a change of the machine's load hits every row
            for name, n_threads in (("local", threads), ("local_1_thread", 1)):
                dr.set_thread_count(n_threads)
                t0 = time.perf_counter()
                E.render_parts(model, pts, cache=Path(tmp) / f"{name}{r}", key=key)
                rows[name].append(time.perf_counter() - t0)
            dr.set_thread_count(threads)
            t0 = time.perf_counter()
            with connect(workers=workers, threads_per_worker=1, timeout_s=120) as client:
                starts.append(time.perf_counter() - t0)
                t1 = time.perf_counter()
                infos.append(render_design(client, model, pts, Path(tmp) / f"dask{r}", key, progress=False))
                rows["dask_render"].append(time.perf_counter() - t1)
            rows["dask_total"].append(time.perf_counter() - t0)
            load.append(os.getloadavg())
            same &= _same(Path(tmp) / f"local{r}", Path(tmp) / f"dask{r}", key, pts)
            same &= _same(Path(tmp) / f"local{r}", Path(tmp) / f"local_1_thread{r}", key, pts)
    med = {k: float(np.median(v)) for k, v in rows.items()}
    res = {
        "command": f"python benchmarks/bench_design_dask.py --points {points} --workers {workers} --repeats {repeats}"
        + ("" if samples is None else f" --samples {samples}")
        + ("" if out is None else f" --out {out}"),
        "configuration": f"quick field ({cfg.n_plants} plants, K={model.scenario.samples}, {model.scenario.bounces} "
        f"bounces, {cfg.boundary}), {int(np.asarray(model.day).sum())} daytime steps, {points} design points",
        "machine": f"{os.cpu_count()} CPU cores shared with other jobs; {repeats} alternated repeats, medians",
        "load_average_1_5_15": load,
        "local_threads": threads,
        "seconds": rows,
        "median_s": med,
        "dask_workers": workers,
        "dask_cluster_start_s": starts,
        "speedup_over_local": {k: med["local"] / v for k, v in med.items()},
        "worker_tasks": infos,
        "bitwise_equal": same,
    }
    out = out or RESULTS / ("design_dask.json" if samples is None else f"design_dask_k{samples}.json")
    write_result(out, res, indent=2)
    print(f"{res['configuration']}; load average (1 min) {', '.join(f'{x[0]:.1f}' for x in load)}")
    print(f"{'':36s}{'median s':>10s}{'local ÷ this':>14s}")
    labels = {
        "local": f"this process, {threads} Dr.Jit threads",
        "local_1_thread": "this process, 1 Dr.Jit thread",
        "dask_render": f"dask {workers} workers × 1 thread",
        "dask_total": "  incl. starting the cluster",
    }
    for k, lab in labels.items():
        print(f"{lab:36s}{med[k]:10.1f}{med['local'] / med[k]:14.2f}")
    for i in infos[-1]:
        each = ", ".join(f"{x:.1f}" for x in i["point_s"])
        print(f"  worker pid {i['pid']}: rebuild {i['build_s']:.1f} s, {i['points']} points rendered in {each} s")
    print(f"bitwise equal: {same}; wrote {out}")
    return res


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=8, help="design points")
    ap.add_argument("--workers", type=int, default=2, help="Dask worker processes")
    ap.add_argument("--repeats", type=int, default=2, help="alternated repeats (medians reported)")
    ap.add_argument("--samples", type=int, default=None, help="samples per segment K (default: the quick size's)")
    ap.add_argument(
        "--out",
        type=Path,
        default=None,
        help="JSON to write (default benchmarks/results/design_dask.json, with --samples K design_dask_k<K>.json: "
        "the tracked results the docs cite)",
    )
    a = ap.parse_args()
    main(a.points, a.workers, a.repeats, a.samples, a.out)
