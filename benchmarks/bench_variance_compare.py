"""Benchmark: per-segment error at equal time, this tree's estimator against another commit's,
side by side in one session (issue 16: keep a variance reduction only if it wins).

    python benchmarks/bench_variance_compare.py [--base-commit f8e2a52] [--n-plants 16]
        [--target 0.05] [--rounds 2] [--repeat 3] [--adaptive] [--out benchmarks/results/variance_compare.json]

Each variant runs ``benchmarks/bench_variance.py`` (this tree's script) in its own process with
``PYTHONPATH`` at its package: ``base`` is ``lightfit/`` of ``--base-commit`` (``git archive``),
``new`` this tree's. Same field, sun, seed and K. Fixed K: the variants take turns ``--rounds``
times, ``--repeat`` timed renders each; the time is the fastest CPU time of the process (all
threads; wall time on the shared cores varies 2× with other load), the errors are deterministic.
The relative SE at the base's time is rse × √(CPU ÷ CPU_base) (Monte Carlo error ∝ 1/√time).
``--adaptive``: then each variant's adaptive render to ``--target`` (and its gradient at the
kept allocation), once, in turns. Writes benchmarks/results/variance_compare.json (or
``--out``) and prints tables.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

from provenance import out_option, wide_console, write_result
from rich.table import Table

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "benchmarks" / "results" / "variance_compare.json"
CLASSES = ("blades", "stems")
HEADS = [(k, q) for k in CLASSES for q in ("median", "p90")]


def _run(tree: Path, args: list[str], out: Path) -> dict:
    env = {**os.environ, "PYTHONPATH": str(tree)}
    cmd = [sys.executable, str(ROOT / "benchmarks" / "bench_variance.py"), *args, "--out", str(out)]
    subprocess.run(cmd, env=env, check=True, stdout=subprocess.DEVNULL)
    return json.loads(out.read_text())


def main(
    base_commit: str, n_plants: int, target: float, rounds: int, repeat: int, adaptive: bool, out: Path = OUT
) -> dict:
    console = wide_console()
    tmp = Path(tempfile.mkdtemp(prefix="bench_variance_compare_"))
    base_tree = tmp / "base"
    base_tree.mkdir()
    git = ["git", "-C", str(ROOT), "archive", base_commit, "lightfit"]
    archive = subprocess.run(git, check=True, capture_output=True)
    subprocess.run(["tar", "-x", "-C", str(base_tree)], input=archive.stdout, check=True)
    head = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"], capture_output=True, text=True)
    common = ["--n-plants", str(n_plants), "--target", str(target)]
    variants = {"base": base_tree, "new": ROOT}
    fixed: dict[str, dict] = {}
    for rnd in range(rounds):
        for name, tree in variants.items():
            r = _run(tree, [*common, "--no-adaptive", "--repeat", str(repeat)], tmp / f"{name}_{rnd}.json")["fixed"]
            prev = fixed.get(name, {})
            walls, cpus = prev.get("times_s", []) + r["times_s"], prev.get("cpu_times_s", []) + r["cpu_times_s"]
            fixed[name] = r | {"time_s": min(walls), "cpu_s": min(cpus), "times_s": walls, "cpu_times_s": cpus}
    t0 = fixed["base"]["cpu_s"]
    res = {
        "base_commit": base_commit,
        "new_commit": head.stdout.strip() + " (+ working tree)",
        "n_plants": n_plants,
        "target_rse": target,
        "fixed": fixed,
    }
    tab = Table(title=f"K = 64 fixed, {n_plants} plants; 'at base time' = rse·√(CPU/CPU_base)")
    for c in ("variant", "wall s", "CPU s", "CPU/base", *(f"{k} {q}" for k, q in HEADS), "at base time"):
        tab.add_column(c)
    for name, r in fixed.items():
        f = (r["cpu_s"] / t0) ** 0.5
        r["rse_at_base_time"] = {k: {q: r["rse"][k][q] * f for q in ("median", "p90")} for k in (*CLASSES, "all")}
        tab.add_row(
            name,
            f"{r['time_s']:.2f}",
            f"{r['cpu_s']:.2f}",
            f"{r['cpu_s'] / t0:.2f}",
            *(f"{r['rse'][k][q]:.1%}" for k, q in HEADS),
            " ".join(f"{r['rse_at_base_time'][k][q]:.1%}" for k, q in HEADS),
        )
    console.print(tab)
    if adaptive:
        res["adaptive"] = {}
        for name, tree in variants.items():
            r = _run(tree, common, tmp / f"{name}_adaptive.json")
            res["adaptive"][name] = {k: r[k] for k in ("adaptive", "kept_allocation", "load_average_end")}
        tab = Table(title=f"adaptive to {target:.0%} (wall time)")
        for c in ("variant", "time s", "mean K blades", "mean K stems", *(f"{k} {q}" for k, q in HEADS), "grad/primal"):
            tab.add_column(c)
        for name, r in res["adaptive"].items():
            a = r["adaptive"]
            tab.add_row(
                name,
                f"{a['time_s']:.1f}",
                f"{a['samples_mean_blades']:.0f}",
                f"{a['samples_mean_stems']:.0f}",
                *(f"{a['rse'][k][q]:.1%}" for k, q in HEADS),
                f"{r['kept_allocation']['gradient_over_primal']:.2f}",
            )
        console.print(tab)
    res["load_average_end"] = os.getloadavg()
    write_result(out, res, indent=1)
    return res


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base-commit", default="f8e2a52")
    ap.add_argument("--n-plants", type=int, default=16)
    ap.add_argument("--target", type=float, default=0.05)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--repeat", type=int, default=3, help="fixed-K renders timed per round")
    ap.add_argument("--adaptive", action="store_true", help="also compare the adaptive render")
    out_option(ap, OUT)
    a = ap.parse_args()
    main(a.base_commit, a.n_plants, a.target, a.rounds, a.repeat, a.adaptive, a.out)
