"""Benchmark: the direct sun on its own points (``SegmentEstimator(sun_points=m)``) against the
estimator before the split, side by side in one session.

    python benchmarks/bench_sun_points.py [--base-commit f8e2a52] [--sun-points 1 2 4 8]
        [--n-plants 16] [--target 0.05] [--rounds 2] [--adaptive 4]

Each variant runs ``benchmarks/bench_variance.py`` in its own process (same field, sun, seed
and K; ``--repeat`` timed renders): ``base`` is the package of ``--base-commit`` (``git
archive``, the unchanged estimator, direct sun from the path points), ``m=…`` this tree at that
many direct-sun points per path point. Variants take turns, ``--rounds`` times (fixed K only:
the time is the fastest round, the errors are deterministic; CPU time of the process, all
threads, is the measure: wall time on the shared cores varies 2× with other load); then
``--adaptive`` variants (base and the given m) run the adaptive render to ``--target`` once
each, also in turns. Relative SE at equal time is rse × √(CPU ÷ CPU_base) (Monte Carlo error
∝ 1/√time). Writes benchmarks/results/sun_points.json and prints tables.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

from rich.console import Console
from rich.table import Table

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "benchmarks" / "results" / "sun_points.json"
CLASSES = ("blades", "stems")


def _run(tree: Path, args: list[str], out: Path) -> dict:
    env = {**os.environ, "PYTHONPATH": str(tree)}
    cmd = [sys.executable, str(ROOT / "benchmarks" / "bench_variance.py"), *args, "--out", str(out)]
    subprocess.run(cmd, env=env, check=True, stdout=subprocess.DEVNULL)
    return json.loads(out.read_text())


def main(
    base_commit: str,
    sun_points: list[int],
    n_plants: int,
    target: float,
    rounds: int,
    adaptive: int | None,
    repeat: int = 3,
):
    console = Console()
    tmp = Path(tempfile.mkdtemp(prefix="bench_sun_points_"))
    base_tree = tmp / "base"
    base_tree.mkdir()
    git = ["git", "-C", str(ROOT), "archive", base_commit, "lightfit"]
    archive = subprocess.run(git, check=True, capture_output=True)
    subprocess.run(["tar", "-x", "-C", str(base_tree)], input=archive.stdout, check=True)
    common = ["--n-plants", str(n_plants), "--target", str(target)]
    variants = {"base": (base_tree, [])} | {f"m={m}": (ROOT, ["--sun-points", str(m)]) for m in sun_points}
    fixed: dict[str, dict] = {}
    for rnd in range(rounds):
        for name, (tree, extra) in variants.items():
            r = _run(tree, [*common, *extra, "--no-adaptive", "--repeat", str(repeat)], tmp / f"{name}_{rnd}.json")
            r = r["fixed"]
            prev = fixed.get(name, {})
            walls, cpus = prev.get("times_s", []) + r["times_s"], prev.get("cpu_times_s", []) + r["cpu_times_s"]
            fixed[name] = r | {"time_s": min(walls), "cpu_s": min(cpus), "times_s": walls, "cpu_times_s": cpus}
    t0 = fixed["base"]["cpu_s"]
    res = {"base_commit": base_commit, "n_plants": n_plants, "target_rse": target, "fixed": fixed}
    tab = Table(title=f"K = 64 fixed, {n_plants} plants (at equal time: rse·√(CPU/CPU_base))")
    heads = [f"{k} {q}" for k in CLASSES for q in ("median", "p90")]
    for c in ("variant", "wall s", "CPU s", "CPU/base", *heads, *(f"{h} at t_base" for h in heads)):
        tab.add_column(c)
    for name, r in fixed.items():
        f = (r["cpu_s"] / t0) ** 0.5
        r["rse_equal_time"] = {k: {q: r["rse"][k][q] * f for q in ("median", "p90")} for k in (*CLASSES, "all")}
        tab.add_row(
            name,
            f"{r['time_s']:.2f}",
            f"{r['cpu_s']:.2f}",
            f"{r['cpu_s'] / t0:.2f}",
            *(f"{r['rse'][k][q]:.1%}" for k in CLASSES for q in ("median", "p90")),
            *(f"{r['rse_equal_time'][k][q]:.1%}" for k in CLASSES for q in ("median", "p90")),
        )
    console.print(tab)
    if adaptive is not None:
        res["adaptive"] = {}
        for name in ("base", f"m={adaptive}"):
            tree, extra = variants.get(name, (ROOT, ["--sun-points", str(adaptive)]))
            r = _run(tree, [*common, *extra], tmp / f"{name}_adaptive.json")
            res["adaptive"][name] = {k: r[k] for k in ("adaptive", "kept_allocation", "load_average_end")}
        tab = Table(title=f"adaptive to {target:.0%}")
        heads = [f"{k} {q}" for k in CLASSES for q in ("median", "p90")]
        for c in ("variant", "time s", "mean K", *heads, "grad/primal"):
            tab.add_column(c)
        for name, r in res["adaptive"].items():
            a = r["adaptive"]
            tab.add_row(
                name,
                f"{a['time_s']:.1f}",
                f"{a['samples_mean']:.0f}",
                *(f"{a['rse'][k][q]:.1%}" for k in CLASSES for q in ("median", "p90")),
                f"{r['kept_allocation']['gradient_over_primal']:.2f}",
            )
        console.print(tab)
    res["load_average_end"] = os.getloadavg()
    OUT.parent.mkdir(parents=True, exist_ok=True)
    OUT.write_text(json.dumps(res, indent=1))
    return res


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("--base-commit", default="f8e2a52")
    ap.add_argument("--sun-points", type=int, nargs="+", default=[1, 2, 4, 8])
    ap.add_argument("--n-plants", type=int, default=16)
    ap.add_argument("--target", type=float, default=0.05)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--adaptive", type=int, default=None, help="m of the adaptive comparison (default: none)")
    ap.add_argument("--repeat", type=int, default=3, help="fixed-K renders timed per round")
    a = ap.parse_args()
    main(a.base_commit, a.sun_points, a.n_plants, a.target, a.rounds, a.adaptive, a.repeat)
