"""Benchmark: periodic boundary vs a wide finite field and vs the 2-buffer-row default (issue 13).

    python benchmarks/bench_periodic.py [--sizes 4,10,23] [--wide-sizes 4,10,23] [--samples 64]
        [--seeds 2] [--main-job | --no-main-job] [--main-job-options "--quick"]

Part 1, edge bias and cost, at 2016-04-20 10:00 UTC (reconstructed forcing; the sun and weather
of ``experiments/periodic_vs_wide.py``, whose field setups this imports), K samples, 3 bounces,
for N × N measured plants (N = 4, 10, 23):

- ``periodic``: the measured plants as one periodic cell (no buffer plants);
- ``default``: the reference paper's finite field, 2 buffer rows (2 plants along);
- ``wide``: the measured plants inside 8 buffer rows and 32 buffer plants along the rows
  (≈ 1 m of buffer both ways), the reference of the edge bias.

Each field is built and rendered in its own child process, so that its peak memory is its own:
**memory is the child's peak resident set size** (``ru_maxrss`` from ``os.wait4``; it includes
the ≈ 0.5 GB of Python, JAX and Mitsuba loaded before any plant, reported as ``baseline_rss_mb``
from ``resource.getrusage`` just before the build). Per field: canopy absorbed PAR of the
measured plants (µmol s⁻¹, sun + sky, mean over ``--seeds`` render seeds) with its Monte Carlo
SD (from the per-segment standard errors, segments being independent), its relative difference
from the wide field with the SD of that difference, the per-segment error against the wide
field (area-weighted RMS over the measured segments of the difference in absorbed PAR, divided
by the wide field's mean, next to the same RMS that Monte Carlo noise alone would give), render time per seed (the first
includes kernel compilation), build time, plants grown and triangles. Plants come from the
user's plant cache (grown once if absent; ``grow_or_load_s`` says how long that took).

Part 2, the main job end to end: ``lightfit replicate`` (100 plants, K = 64, 3 bounces, the 29
steps of the day) with its default periodic boundary and with ``--boundary finite``, one after
the other in this run, each in a child process with an empty temporary plant cache
(``LIGHTFIT_CACHE``, :mod:`lightfit.plant.cache`), so its wall time covers growing the plants,
rendering every daytime step and the photosynthesis.

Writes benchmarks/results/periodic.json and prints a table (Markdown, as in docs/light.md).
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import math
import os
import platform
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from lightfit.precision import use_float64

use_float64()  # lightfit's precision policy (lightfit.precision), before any JAX array exists

ROOT = Path(__file__).resolve().parents[1]
OUT = Path(__file__).resolve().parent / "results" / "periodic.json"


def _experiment():
    """experiments/periodic_vs_wide.py as a module (its field setups and sun)."""
    spec = importlib.util.spec_from_file_location("periodic_vs_wide", ROOT / "experiments" / "periodic_vs_wide.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _sun():
    import pandas as pd

    from lightfit import weather
    from lightfit.weather.units import par_from_ghi

    row = weather.load("2016-04-20").loc[pd.Timestamp("2016-04-20 10:00", tz="UTC")]
    sun = (float(row["sun_elevation_deg"]), float(row["sun_azimuth_deg"]))
    return sun, float(par_from_ghi(row["dni_w_m2"])), float(par_from_ghi(row["dhi_w_m2"]))


def case(n: int, setup: str, samples: int, seeds: int, out: Path) -> None:
    """Child process: build and render one field, write its numbers (json) and per-segment values (npz)."""
    from lightfit.light.estimator import SegmentEstimator
    from lightfit.light.scene import FieldScene, Optics
    from lightfit.plant import Field, build

    kw = _experiment().SETUPS[setup]
    sun, dni, dhi = _sun()
    baseline = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    t = time.perf_counter()
    g = build(Field(n_plants=n * n, seed=1, **kw), progress=False)
    grow_s = time.perf_counter() - t
    t = time.perf_counter()
    fs = FieldScene(g.mesh, Optics(), cell=g.cell)
    fs.set_sun(*sun)
    scene_s = time.perf_counter() - t
    ids = g.segments.loc[g.segments["measured"], "segment_id"].to_numpy()
    values, variances, render_s, meta = [], [], [], None
    for seed in range(seeds):
        t = time.perf_counter()
        r = SegmentEstimator(fs, ids, samples=samples, bounces=3, seed=seed).render()
        render_s.append(time.perf_counter() - t)
        values.append(r.total("absorbed", dni, dhi))
        variances.append((dni * r.se["absorbed_sun"]) ** 2 + (dhi * r.se["absorbed_sky"]) ** 2)
        area, meta = r.meta["area_m2"], r.meta.get("periodic")
    v = np.mean(values, 0)
    var = np.sum(variances, 0) / seeds**2  # of the mean over seeds
    np.savez(out.with_suffix(".npz"), segment_id=r.segment_id, absorbed=v, var=var, area=area)
    out.write_text(
        json.dumps(
            {
                "n": n,
                "setup": setup,
                **kw,
                "plants_grown": len(g.plants),
                "cache_hits": int(g.cache_hits),
                "mesh_faces": int(g.mesh.n_faces),
                "scene_faces": int(fs.n_scene_faces),
                "measured_segments": len(ids),
                "grow_or_load_s": grow_s,
                "scene_s": scene_s,
                "render_s": render_s,
                "canopy_absorbed_umol_s": float(v @ area),
                "canopy_absorbed_sd": float(math.sqrt(var @ area**2)),
                "baseline_rss_mb": baseline,
                "periodic": meta,
            },
            default=float,
        )
    )


def _child(args: list[str], env: dict | None = None) -> tuple[float, float, int]:
    """Run ``python args…``; (wall s, the child's peak RSS MB, exit status)."""
    t = time.perf_counter()
    p = subprocess.Popen([sys.executable, *args], env=env)
    _, status, usage = os.wait4(p.pid, 0)
    return time.perf_counter() - t, usage.ru_maxrss / 1024, os.waitstatus_to_exitcode(status)


def edge_bias(sizes, wide_sizes, samples, seeds, tmp: Path) -> list[dict]:
    rows = []
    for n in sizes:
        per = {}
        for setup in ("periodic", "default", "wide"):
            if setup == "wide" and n not in wide_sizes:
                continue
            out = tmp / f"{n}_{setup}.json"
            argv = [__file__, "--case", str(n), setup, "--samples", str(samples), "--seeds", str(seeds)]
            wall, rss, rc = _child([*argv, "--case-out", str(out)])
            if rc != 0:
                raise RuntimeError(f"case {n} {setup} failed with exit status {rc}")
            res = json.loads(out.read_text()) | {"wall_s": wall, "peak_rss_mb": rss}
            with np.load(out.with_suffix(".npz")) as z:
                per[setup] = {k: z[k] for k in z.files}
            print(f"{n}×{n} {setup}: {res['canopy_absorbed_umol_s']:.2f} ± {res['canopy_absorbed_sd']:.2f} µmol/s")
            rows.append(res)
        if "wide" not in per:
            continue
        ref = per["wide"]
        wide_row = next(r for r in rows if r["n"] == n and r["setup"] == "wide")
        for r in rows:
            if r["n"] != n or r["setup"] == "wide":
                continue
            p = per[r["setup"]]
            assert np.array_equal(p["segment_id"], ref["segment_id"])
            ratio = r["canopy_absorbed_umol_s"] / wide_row["canopy_absorbed_umol_s"]
            r["vs_wide"] = ratio - 1
            r["vs_wide_sd"] = ratio * math.hypot(
                r["canopy_absorbed_sd"] / r["canopy_absorbed_umol_s"],
                wide_row["canopy_absorbed_sd"] / wide_row["canopy_absorbed_umol_s"],
            )
            # Per segment: area-weighted RMS of the difference from the wide field's absorbed PAR
            # (µmol m⁻² s⁻¹), relative to the wide field's area-weighted mean, next to the same RMS
            # that Monte Carlo noise alone would give (segments in shade make a per-segment ratio
            # meaningless, so the RMS is normalised by the mean).
            w = ref["area"] / ref["area"].sum()
            mean = float(w @ ref["absorbed"])
            r["segment_rms_error_vs_wide"] = float(math.sqrt(w @ (p["absorbed"] - ref["absorbed"]) ** 2)) / mean
            r["segment_rms_noise"] = float(math.sqrt(w @ (p["var"] + ref["var"]))) / mean
    return rows


def main_job(tmp: Path, options: tuple[str, ...] = ()) -> dict:
    """``lightfit replicate`` default (periodic) and ``--boundary finite``, each from an empty plant cache."""
    out = {}
    for name, extra in (("periodic", [*options]), ("finite", [*options, "--boundary", "finite"])):
        cache = tmp / f"cache_{name}"
        env = dict(os.environ, LIGHTFIT_CACHE=str(cache))
        argv = ["-m", "lightfit.cli", "replicate", "--out", str(tmp / f"main_{name}"), *extra]
        wall, rss, rc = _child(argv, env)
        if rc != 0:
            raise RuntimeError(f"lightfit replicate {' '.join(extra)} failed with exit status {rc}")
        import xarray as xr

        with xr.open_dataset(tmp / f"main_{name}" / "results.nc", engine="h5netcdf") as ds:
            a = dict(ds.attrs)
            par = ds["plant_par_umol_m2_s"].values
            an = ds["canopy_an_umol_m2_s"].values
        out[name] = {
            "command": "lightfit replicate --out DIR " + " ".join(extra),
            "boundary": a["boundary"],
            "buffer_rows": int(a["buffer_rows"]),
            "plants_grown": len(list((cache / "plants").glob("*.npz"))),
            "wall_s": wall,
            "peak_rss_mb": rss,
            "daily_max_plant_par_umol_m2_s": float(np.nanmax(par)),
            "daily_max_canopy_an_umol_m2_s": float(np.nanmax(an)),
        }
        print(f"main job {name}: {wall:.0f} s, {out[name]['plants_grown']} plants grown, {rss:.0f} MB")
    return out


def _code_state() -> dict:
    """The commit measured and whether lightfit/ had uncommitted changes (they would be measured too)."""

    def git(*args):
        r = subprocess.run(["git", "-C", str(ROOT), *args], capture_output=True, text=True)
        return r.stdout.strip() if r.returncode == 0 else None

    status = git("status", "--porcelain", "--", "lightfit")
    return {"commit": git("rev-parse", "HEAD"), "lightfit_uncommitted": None if status is None else status.splitlines()}


def table(res: dict) -> str:
    lines = [
        "| N × N | field | plants grown | triangles | render (s) | peak RSS (MB) | canopy absorbed PAR (µmol s⁻¹) "
        "| vs wide field | per-segment RMS difference from wide ÷ mean (MC noise alone) |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in res["fields"]:
        vs = f"{100 * r['vs_wide']:+.2f} % ± {100 * r['vs_wide_sd']:.2f} %" if "vs_wide" in r else "–"
        seg = (
            f"{100 * r['segment_rms_error_vs_wide']:.1f} % ({100 * r['segment_rms_noise']:.1f} %)"
            if "segment_rms_error_vs_wide" in r
            else "–"
        )
        lines.append(
            f"| {r['n']} × {r['n']} | {r['setup']} | {r['plants_grown']} | {r['scene_faces']} | "
            f"{min(r['render_s']):.1f} | {r['peak_rss_mb']:.0f} | "
            f"{r['canopy_absorbed_umol_s']:.2f} ± {r['canopy_absorbed_sd']:.2f} | {vs} | {seg} |"
        )
    if res.get("main_job"):
        lines += ["", "| main job | plants grown | wall time (s) | peak RSS (MB) |", "|---|---:|---:|---:|"]
        for v in res["main_job"].values():
            lines.append(f"| `{v['command']}` | {v['plants_grown']} | {v['wall_s']:.0f} | {v['peak_rss_mb']:.0f} |")
    return "\n".join(lines)


def main(
    sizes=(4, 10, 23), wide_sizes=(4, 10, 23), samples=64, seeds=2, with_main_job=True, main_job_options=()
) -> dict:
    (sun_el, sun_az), dni, dhi = _sun()
    with tempfile.TemporaryDirectory(prefix="lightfit-bench-periodic-") as d:
        tmp = Path(d)
        t0 = time.perf_counter()
        fields = edge_bias(sizes, wide_sizes, samples, seeds, tmp)
        mj = main_job(tmp, main_job_options) if with_main_job else None
        wall = time.perf_counter() - t0
    res = {
        "command": "python benchmarks/bench_periodic.py " + " ".join(sys.argv[1:]),
        "time": "2016-04-20 10:00 UTC",
        "sun_deg": [sun_el, sun_az],
        "dni_par_umol_m2_s": dni,
        "dhi_par_umol_m2_s": dhi,
        "samples": samples,
        "bounces": 3,
        "seeds": seeds,
        "sizes": list(sizes),
        "wide_sizes": list(wide_sizes),
        "wide_note": None
        if set(sizes) <= set(wide_sizes)
        else f"wide finite field only for N in {list(wide_sizes)} (growing it for the others was left out)",
        "memory": "peak resident set size of the child process that built and rendered the field "
        "(ru_maxrss via os.wait4), including the baseline_rss_mb of Python, JAX and Mitsuba",
        "render_s": "per render seed; the first includes kernel compilation, the table shows the fastest",
        "fields": fields,
        "main_job": mj,
        "bench_wall_s": wall,
        "machine": f"{platform.machine()}, {os.cpu_count()} cores (shared; timings are indicative)",
        "code": _code_state(),
    }
    OUT.parent.mkdir(parents=True, exist_ok=True)
    OUT.write_text(json.dumps(res, indent=1, default=float))
    print(table(res))
    print(f"wrote {OUT}")
    return res


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="4,10,23")
    ap.add_argument("--wide-sizes", default="4,10,23")
    ap.add_argument("--samples", type=int, default=64)
    ap.add_argument("--seeds", type=int, default=2)
    ap.add_argument("--main-job", action=argparse.BooleanOptionalAction, default=True)
    ap.add_argument("--main-job-options", default="", help="extra options of both main jobs, e.g. '--quick'")
    ap.add_argument("--case", nargs=2, metavar=("N", "SETUP"), help=argparse.SUPPRESS)
    ap.add_argument("--case-out", type=Path, help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.case:
        case(int(a.case[0]), a.case[1], a.samples, a.seeds, a.case_out)
    else:
        ints = lambda s: tuple(int(x) for x in s.split(",") if x)  # noqa: E731
        main(ints(a.sizes), ints(a.wide_sizes), a.samples, a.seeds, a.main_job, tuple(a.main_job_options.split()))
