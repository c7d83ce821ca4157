"""Scale-out on Dask: tiles on one worker, strong and weak scaling, halo bias.

Run:  .venv/bin/python benchmarks/bench_distributed.py [--quick] [--out-dir DIR]
Writes benchmarks/results/distributed.json and benchmarks/results/distributed_scaling.png (``--quick``:
distributed_quick.json and distributed_quick_scaling.png), into ``--out-dir`` when given.

Sections
- tiles: a fixed field run as 1, 2, 4, 8 tiles on ONE worker (1 thread), for the exact halo
  (whole field in every tile) and the reference paper's halo (H = buffer rows): wall time, sum
  of task times split into build/simulate, triangles rendered ÷ triangles measured.
- strong: the same field, W tiles, on 1 and 2 workers (1 thread each): speedup T(1)/T(2),
  efficiency speedup/N.
- weak: the field grows with the number of workers (measured plants ∝ workers, as nearly as
  square fields allow); efficiency normalised per measured plant.
- halo: per-segment and canopy differences of halo H = 1, 2, 4 tiles vs the single-process run
  (exact), against the Monte Carlo standard errors.
Each worker is warmed up (imports, kernels) before timing. One repetition per configuration.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from dataclasses import replace
from pathlib import Path

os.environ.setdefault("JAX_PLATFORMS", "cpu")

from lightfit.precision import use_float64  # noqa: E402

use_float64()  # lightfit's precision policy (lightfit.precision), before any JAX array exists

import numpy as np  # noqa: E402
from provenance import write_result  # noqa: E402  (same script folder)

from lightfit.distributed import FieldRun, connect, run_field, run_single  # noqa: E402
from lightfit.model.scenario import Scenario  # noqa: E402
from lightfit.plant import Field  # noqa: E402
from lightfit.replication import forcing  # noqa: E402

OUT = Path(__file__).parent / "results"


def _burn(_):
    t = time.perf_counter()
    s = 0
    for i in range(5_000_000):
        s += i
    return time.perf_counter() - t


def available_parallelism() -> dict:
    """How much of the machine this run actually gets: the same pure-Python loop in 1 and in 2
    processes (ratio ≈ 2 on 2 idle cores; ≈ 1 if other jobs hold a core), and the load average."""
    import multiprocessing as mp

    one = _burn(0)
    with mp.get_context("spawn").Pool(2) as p:
        two = p.map(_burn, [0, 1])
    return {
        "loop_1proc_s": one,
        "loop_2proc_s": two,
        "effective_parallelism_2": 2 * one / max(two),
        "loadavg_1min": os.getloadavg()[0],
    }


def warm(client, weather):
    """One tiny run on every worker: imports, Dr.Jit kernels, JAX compilation of common code."""
    n = len(client.nthreads())
    sc = Scenario(
        weather=weather, field=Field(boundary="finite", n_plants=4, buffer_rows=1, seed=1), samples=4, bounces=1
    )
    run_field(FieldRun(sc, tiles=min(n, 4)), client=client, timeout_s=600)


def timed(client, run):
    ds = run_field(run, client=client, timeout_s=1200)
    tasks = json.loads(ds.attrs["tile_timing_json"])
    return ds, {
        "wall_s": ds.attrs["distributed_wall_s"],
        "workers": ds.attrs["distributed_workers"],
        "tiles": run.tiles,
        "halo_rows": run.halo_rows,
        "n_plants": run.scenario.field.n_measured,
        "task_s": sum(t["total_s"] for t in tasks),
        "build_s": sum(t["build_s"] for t in tasks),
        "simulate_s": sum(t["simulate_s"] for t in tasks),
        "triangles_rendered": ds.attrs["triangles_rendered"],
        "triangles_measured": ds.attrs["triangles_measured"],
        "buffer_overhead": ds.attrs["buffer_overhead"],
        "max_tile_triangles": max(t["triangles"] for t in tasks),
        "tasks": [
            {
                k: t[k]
                for k in (
                    "tile",
                    "chunk",
                    "worker",
                    "build_s",
                    "simulate_s",
                    "total_s",
                    "triangles",
                    "triangles_measured",
                    "segments",
                )
            }
            for t in tasks
        ],
    }


def halo_bias(weather, n_plants, buffer_rows, samples, bounces, tiles, halos):
    """Differences of halo-H tiled runs from the exact (single-process) run, in-process."""
    from lightfit.model.coupled import CoupledModel
    from lightfit.model.observe import plant_par

    sc = Scenario(
        weather=weather,
        field=Field(boundary="finite", n_plants=n_plants, buffer_rows=buffer_rows, seed=1),
        samples=samples,
        bounces=bounces,
        par_kind="absorbed",
    )
    ref = run_single(FieldRun(sc))
    out = []
    for h in halos:
        run = FieldRun(sc, tiles=tiles, halo_rows=h)
        parts = [CoupledModel(run.task_scenario(k)).simulate() for k in range(tiles)]
        import xarray as xr

        seg = xr.concat([p[["absorbed_par_umol_m2_s"]] for p in parts], "segment").sortby("segment")
        day = ref["sun_elevation_deg"].values > 0  # sun above the horizon: relative differences are defined
        a = seg["absorbed_par_umol_m2_s"].values[day]
        b = ref["absorbed_par_umol_m2_s"].values[day]
        se = ref["absorbed_par_mc_sd_umol_m2_s"].values[day]
        area = ref["area_m2"].values
        canopy_a, canopy_b = (plant_par(x, np.zeros_like(x), area)[0] for x in (a, b))
        diff = a - b
        out.append(
            {
                "halo_rows": h,
                "tiles": tiles,
                "canopy_absorbed_par_rel_diff": ((canopy_a - canopy_b) / canopy_b).tolist(),
                "canopy_mc_sd_rel": (ref["plant_par_mc_sd_umol_m2_s"].values[day] / canopy_b).tolist(),
                "segments_changed_frac": float((diff != 0).mean()),
                "segment_rms_diff_over_rms_se": float(np.sqrt((diff**2).mean()) / np.sqrt((se**2).mean())),
                "segments_beyond_3se_frac": float((np.abs(diff) > 3 * np.sqrt(2) * np.maximum(se, 1e-12)).mean()),
                "sun_elevation_deg": ref["sun_elevation_deg"].values[day].tolist(),
            }
        )
        print(
            f"halo {h}: canopy rel diff {out[-1]['canopy_absorbed_par_rel_diff']}, "
            f"MC rel SD {out[-1]['canopy_mc_sd_rel']}, changed {out[-1]['segments_changed_frac']:.3f}"
        )
    return out


def plot(res, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 3, figsize=(15, 4.6), constrained_layout=True)
    for label, key, c in (
        ("exact halo (whole field)", "exact", "tab:blue"),
        ("paper halo (H = buffer rows)", "paper", "tab:orange"),
    ):
        rows = res["tiles"][key]
        w = [r["tiles"] for r in rows]
        ax[0].plot(w, [r["task_s"] for r in rows], "o-", color=c, label=f"{label}: Σ task time")
        ax[0].plot(w, [r["simulate_s"] for r in rows], "s--", color=c, alpha=0.6, label=f"{label}: Σ simulate")
        a2 = ax[0].twinx() if key == "exact" else a2  # noqa: F821
        a2.plot(w, [r["buffer_overhead"] for r in rows], "^:", color=c, alpha=0.8)
    a2.set_ylabel("triangles rendered ÷ measured (▲ dotted)")
    a2.set_yscale("log")
    ax[0].set_xscale("log", base=2)
    ax[0].set_xlabel("tiles on one worker")
    ax[0].set_ylabel("seconds")
    ax[0].set_title(f"one worker, {res['config']['n_plants']} plants + {res['config']['buffer_rows']} buffer rows")
    ax[0].legend(fontsize=7, loc="upper left")
    s = res["strong"]
    for key, c in (("exact", "tab:blue"), ("paper", "tab:orange")):
        n = [r["workers"] for r in s[key]]
        t1 = s[key][0]["wall_s"]
        ax[1].plot(n, [t1 / r["wall_s"] for r in s[key]], "o-", color=c, label=key)
    ax[1].plot([1, 2], [1, 2], "k:", label="ideal")
    ax[1].set_xlabel("workers (1 core each)")
    ax[1].set_ylabel("speedup T(1)/T(N)")
    ax[1].set_title(f"strong scaling, {s['tiles']} tiles")
    ax[1].legend(fontsize=8)
    wk = res["weak"]
    n = [r["workers"] for r in wk]
    ax[2].plot(n, [r["efficiency"] for r in wk], "o-", color="tab:green")
    ax[2].axhline(1, color="k", ls=":")
    ax[2].set_ylim(0, 1.2)
    ax[2].set_xlabel("workers")
    ax[2].set_ylabel("weak-scaling efficiency (per measured plant)")
    ax[2].set_title("weak scaling: " + ", ".join(f"{r['n_plants']} plants on {r['workers']}" for r in wk))
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="small field, few samples (a smoke run)")
    ap.add_argument(
        "--out-dir",
        type=Path,
        default=OUT,
        help="folder for the JSON and the plot (default benchmarks/results/, the tracked results the docs cite)",
    )
    args = ap.parse_args()
    out_dir = args.out_dir
    w_all = forcing()
    weather = w_all.iloc[[8, 14]]  # 09:00 and 12:00 local
    n_plants, buffer_rows, samples, bounces = (16, 1, 8, 2) if args.quick else (100, 2, 32, 3)
    cfg = {
        "n_plants": n_plants,
        "buffer_rows": buffer_rows,
        "samples": samples,
        "bounces": bounces,
        "time_steps_utc": [str(t) for t in weather.index],
        "machine": platform.node(),
        "cores": os.cpu_count(),
        "threads_per_worker": 1,
    }
    res = {"config": cfg, "tiles": {}, "strong": {}, "weak": [], "machine_load_before": available_parallelism()}
    print("machine load before:", res["machine_load_before"])
    field = Field(boundary="finite", n_plants=n_plants, buffer_rows=buffer_rows, seed=1)
    sc = Scenario(weather=weather, field=field, samples=samples, bounces=bounces, par_kind="absorbed")

    def mk(tiles, halo, fld=field):
        return FieldRun(replace(sc, field=fld), tiles=tiles, halo_rows=halo)

    t0 = time.time()
    with connect(workers=1, threads_per_worker=1, timeout_s=60) as client:
        warm(client, weather)
        for key, halo in (("exact", None), ("paper", buffer_rows)):
            res["tiles"][key] = []
            for tiles in (1, 2, 4, 8):
                _, r = timed(client, mk(tiles, halo))
                res["tiles"][key].append(r)
                print(
                    f"[tiles] {key} W={tiles}: wall {r['wall_s']:.1f} s, Σtask {r['task_s']:.1f} s "
                    f"(build {r['build_s']:.1f}, simulate {r['simulate_s']:.1f}), overhead {r['buffer_overhead']:.2f}"
                )
    strong_tiles = 4
    res["strong"] = {"tiles": strong_tiles, "exact": [], "paper": []}
    weak_sizes = {1: 36, 2: 64} if not args.quick else {1: 4, 2: 9}
    for n_workers in (1, 2):
        with connect(workers=n_workers, threads_per_worker=1, timeout_s=60) as client:
            client.wait_for_workers(n_workers, timeout=60)
            warm(client, weather)
            for key, halo in (("exact", None), ("paper", buffer_rows)):
                _, r = timed(client, mk(strong_tiles, halo))
                res["strong"][key].append(r)
                print(f"[strong] {key} N={n_workers}: wall {r['wall_s']:.1f} s")
            fld = Field(boundary="finite", n_plants=weak_sizes[n_workers], buffer_rows=buffer_rows, seed=1)
            _, r = timed(client, mk(2 * n_workers, buffer_rows, fld))
            res["weak"].append(r)
            print(f"[weak] N={n_workers}, {fld.n_measured} plants: wall {r['wall_s']:.1f} s")
    for key in ("exact", "paper"):
        t1 = res["strong"][key][0]["wall_s"]
        for r in res["strong"][key]:
            r["speedup"] = t1 / r["wall_s"]
            r["efficiency"] = r["speedup"] / r["workers"]
    w1 = res["weak"][0]
    for r in res["weak"]:
        # time per measured plant, relative: T1/n1 ÷ (T_N / (n_N / N))
        r["efficiency"] = (w1["wall_s"] / w1["n_plants"]) / (r["wall_s"] / (r["n_plants"] / r["workers"]))
    res["halo"] = halo_bias(
        w_all.iloc[[6, 14]],
        36 if not args.quick else 9,
        4 if not args.quick else 2,
        samples,
        bounces,
        4,
        [1, 2, 4] if not args.quick else [1, 2],
    )
    res["halo_config"] = {
        "n_plants": 36 if not args.quick else 9,
        "buffer_rows": 4 if not args.quick else 2,
        "tiles": 4,
        "time_steps_utc": [str(t) for t in w_all.index[[6, 14]]],
    }
    res["machine_load_after"] = available_parallelism()
    print("machine load after:", res["machine_load_after"])
    res["total_s"] = time.time() - t0
    name = "distributed_quick" if args.quick else "distributed"
    write_result(out_dir / f"{name}.json", res, indent=1)
    plot(res, out_dir / f"{name}_scaling.png")
    print(f"wrote {out_dir / f'{name}.json'} and {out_dir / f'{name}_scaling.png'} ({res['total_s']:.0f} s)")


if __name__ == "__main__":
    main()
