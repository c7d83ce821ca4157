"""Benchmark: periodic boundary vs a wide finite field and vs the 2-buffer-row default (issue 13).

    python benchmarks/bench_periodic.py [--sizes 4,10,23] [--wide-sizes 4,10,23] [--samples 64]
        [--seeds 2] [--main-job | --no-main-job] [--main-job-options "--quick"] [--no-equal-cost] [--out JSON]

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

With ``--equal-cost`` (default) the periodic cell is rendered once more with the K at which its
render costs as much CPU time as the 2-buffer-row default's at ``--samples``: its edge bias and
Monte Carlo SD at the default's cost.

Part 2, the main job end to end: ``lightfit replicate`` (100 plants, the main job's K: 32 with the
projected direct light, 64 with the paths; the 29 steps of the day) for each of
:data:`MAIN_JOBS`: today's default (periodic, PROSPECT-D leaf, 2 bounces) and the same in the
finite field; the old default's settings (grey leaf, 3 bounces) in the periodic
cell and the old default itself (finite, 2 buffer rows). Each runs first cold (an empty
temporary plant cache, ``LIGHTFIT_CACHE``, and an empty Dr.Jit kernel cache: the first run
after installing), then warm; wall time covers growing the plants, compiling kernels, rendering
every daytime step and the photosynthesis. CPU time (user + system of the child) is reported
next to wall time: on a shared machine it is the steadier measure.

Part 3, ``--step-costs``: where a main-job render step's CPU time goes, for the ``default`` and
``old_default`` jobs in one process, taking turns step by step: the first daytime step (paths
traced and kept) and the later ones split into the sun's shadow rays, the path weights, the
values and the per-segment summary (each evaluated and synchronised on its own), with the rays
each step casts per kind. Written to the results' ``step_costs`` section.

Writes benchmarks/results/periodic.json (or ``--out``; ``--step-costs`` and ``--main-job-only`` update a
section of it, which records its own run) and prints a table (Markdown, as in docs/light.md).
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

if str(Path(__file__).resolve().parent) not in sys.path:  # the --case children run with -P: no script folder
    sys.path.insert(0, str(Path(__file__).resolve().parent))
from provenance import out_option, record, write_result  # noqa: E402  (same script folder)

from lightfit.precision import use_float64  # noqa: E402

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
    """The sun and the direct-normal and diffuse PAR of experiments/periodic_vs_wide.py (the coupled
    model's: :meth:`lightfit.model.scenario.Forcing.of`)."""
    return _experiment().light()


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
    fs = FieldScene(g.mesh, Optics.preset("paper"), cell=g.cell)
    fs.set_sun(*sun)
    scene_s = time.perf_counter() - t
    ids = g.segments.loc[g.segments["measured"], "segment_id"].to_numpy()
    values, variances, render_s, render_cpu_s, meta = [], [], [], [], None
    for seed in range(seeds):
        t, c = time.perf_counter(), time.process_time()
        r = SegmentEstimator(fs, ids, samples=samples, bounces=3, seed=seed).render()
        render_s.append(time.perf_counter() - t)
        render_cpu_s.append(time.process_time() - c)
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
                "render_cpu_s": render_cpu_s,
                "canopy_absorbed_umol_s": float(v @ area),
                "canopy_absorbed_sd": float(math.sqrt(var @ area**2)),
                "baseline_rss_mb": baseline,
                "periodic": meta,
            },
            default=float,
        )
    )


def _child(args: list[str], env: dict | None = None, cpu: bool = False) -> tuple:
    """Run ``python args…``; (wall s, the child's peak RSS MB, exit status[, its CPU s: user + system])."""
    t = time.perf_counter()
    # -P: the working directory is not put first on sys.path, so the child imports lightfit from
    # PYTHONPATH (another checkout, for a baseline commit) and not from wherever it was started.
    p = subprocess.Popen([sys.executable, "-P", *args], env=env)
    _, status, usage = os.wait4(p.pid, 0)
    res = (time.perf_counter() - t, usage.ru_maxrss / 1024, os.waitstatus_to_exitcode(status))
    return (*res, usage.ru_utime + usage.ru_stime) if cpu else res


EQUAL_COST = "periodic, equal cost"


def edge_bias(sizes, wide_sizes, samples, seeds, tmp: Path, equal_cost: bool = True) -> list[dict]:
    """Part 1 (module doc). With ``equal_cost``, the periodic cell is rendered once more with the
    K that makes its render as cheap as the 2-buffer-row default's at ``samples`` (K scaled by the
    ratio of the two renders' least CPU times, rounded down to whole replicates): its edge bias
    and Monte Carlo error at the default's cost."""
    from lightfit.light.estimator import replicates_for

    rows = []
    for n in sizes:
        per = {}
        jobs = [("periodic", "periodic", samples), ("default", "default", samples), ("wide", "wide", samples)]
        if equal_cost:
            jobs.append((EQUAL_COST, "periodic", None))
        for label, setup, k in jobs:
            if setup == "wide" and n not in wide_sizes:
                continue
            if k is None:  # equal cost: from the two renders just made
                t = {r["setup"]: min(r["render_cpu_s"]) for r in rows if r["n"] == n}
                rep = replicates_for(samples)
                k = max(2 * rep, rep * math.floor(samples * t["default"] / t["periodic"] / rep))
            out = tmp / f"{n}_{label.replace(' ', '_').replace(',', '')}.json"
            argv = [__file__, "--case", str(n), setup, "--samples", str(k), "--seeds", str(seeds)]
            wall, rss, rc = _child([*argv, "--case-out", str(out)])
            if rc != 0:
                raise RuntimeError(f"case {n} {label} failed with exit status {rc}")
            res = json.loads(out.read_text()) | {"wall_s": wall, "peak_rss_mb": rss, "setup": label, "samples": k}
            with np.load(out.with_suffix(".npz")) as z:
                per[label] = {k: z[k] for k in z.files}
            print(
                f"{n}×{n} {label} (K={k}): {res['canopy_absorbed_umol_s']:.2f} ± {res['canopy_absorbed_sd']:.2f} µmol/s"
            )
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


#: The main jobs timed: (name, ``lightfit replicate`` options, what it is). Pairs at the same leaf,
#: samples and bounces: default / default_finite and paper_periodic / old_default; the goal
#: (issue 13) compares default with old_default.
MAIN_JOBS = (
    ("default", (), "today's default: periodic cell, PROSPECT-D leaf, bounces for 1 % (2), winter_wheat"),
    ("default_finite", ("--boundary", "finite"), "the same settings in the finite field (2 buffer rows)"),
    (
        "paper_periodic",
        ("--preset", "paper", "--bounces", "3", "--boundary", "periodic"),
        "the old default's settings (grey leaf, 3 bounces, giraud2023) in the periodic cell",
    ),
    (
        "old_default",
        ("--preset", "paper", "--bounces", "3"),
        "the default before the periodic boundary: finite, 2 buffer rows, grey leaf, 3 bounces, giraud2023",
    ),
)


def _attr(attrs: dict, key: str, kind=str):
    """A results.nc attribute, or None where the file lacks it (an older commit's, a baseline)."""
    return None if key not in attrs else kind(attrs[key])


def main_job(tmp: Path, options: tuple[str, ...] = (), jobs=MAIN_JOBS, warm_repeats: int = 1) -> dict:
    """``lightfit replicate`` for each of ``jobs``, first cold, then warm (``warm_repeats`` rounds).

    Cold: an empty plant cache (``LIGHTFIT_CACHE``) and an empty Dr.Jit kernel cache (``HOME``
    of the child is a fresh directory; ``MPLCONFIGDIR`` stays the user's, so matplotlib's font
    cache is not rebuilt): the first run after installing. Warm: the same command again with both
    caches as the cold run left them. Cold runs take turns first, then warm ones, so drifting load
    on the shared machine touches every job alike. Per run: wall time, the child's CPU time
    (user + system, all threads: steadier than wall time while other processes compete for the
    cores) and peak RSS (``os.wait4``).
    """
    import matplotlib
    import xarray as xr

    jobs = [(*j, None)[:4] for j in jobs]  # (name, options, what, source tree or None: this checkout)
    out = {
        name: {"command": "lightfit replicate --out DIR " + " ".join(extra), "what": what}
        | ({} if tree is None else {"source": str(tree)})
        for name, extra, what, tree in jobs
    }
    for state in ("cold",) + ("warm",) * warm_repeats:
        for name, extra, _, tree in jobs:
            cache, home = tmp / f"cache_{name}", tmp / f"home_{name}"
            home.mkdir(exist_ok=True)
            env = dict(os.environ, LIGHTFIT_CACHE=str(cache), HOME=str(home), MPLCONFIGDIR=matplotlib.get_configdir())
            if tree is not None:  # lightfit imported from that checkout (the venv's install points here)
                env["PYTHONPATH"] = str(tree)
                where = subprocess.run(
                    [sys.executable, "-P", "-c", "import lightfit; print(lightfit.__file__)"],
                    env=env,
                    capture_output=True,
                    text=True,
                    check=True,
                ).stdout.strip()
                if not Path(where).resolve().is_relative_to(Path(tree).resolve()):
                    raise RuntimeError(f"job {name} should import lightfit from {tree}, but imports {where}")
            argv = ["-m", "lightfit.cli", "replicate", "--out", str(tmp / f"main_{name}"), *options, *extra]
            wall, rss, rc, cpu = _child(argv, env, cpu=True)
            if rc != 0:
                raise RuntimeError(f"lightfit replicate {' '.join([*options, *extra])} failed with exit status {rc}")
            with xr.open_dataset(tmp / f"main_{name}" / "results.nc", engine="h5netcdf") as ds:
                a = dict(ds.attrs)
                par = ds["plant_par_umol_m2_s"].values
                an = ds["canopy_an_umol_m2_s"].values
            r = out[name]
            r |= {
                "boundary": _attr(a, "boundary"),
                "buffer_rows": _attr(a, "buffer_rows", int),
                "samples": _attr(a, "samples", int),
                "bounces": _attr(a, "bounces", int),
                "base_color": _attr(a, "base_color", float),
                "photosynthesis": _attr(a, "photosynthesis"),
                "plants_grown": len(list((cache / "plants").glob("*.npz"))),
                "daily_max_plant_par_umol_m2_s": float(np.nanmax(par)),
                "daily_max_canopy_an_umol_m2_s": float(np.nanmax(an)),
            }
            run = {"wall_s": wall, "cpu_s": cpu, "peak_rss_mb": rss}
            if state == "cold":
                r["cold"] = run
            else:  # the warm entry is the mean over the rounds, which take turns between the jobs
                r.setdefault("warm_runs", []).append(run)
                r["warm"] = {k: float(np.mean([x[k] for x in r["warm_runs"]])) for k in run}
            print(f"main job {name} ({state}): {wall:.0f} s wall, {cpu:.0f} s CPU, {rss:.0f} MB")
    ref = out.get("old_default")
    base = next((r for r in out.values() if "source" in r), None)
    for r in out.values():
        for state in ("cold", "warm"):
            if ref is not None:
                r[state]["cpu_vs_old_default"] = r[state]["cpu_s"] / ref[state]["cpu_s"]
                r[state]["wall_vs_old_default"] = r[state]["wall_s"] / ref[state]["wall_s"]
            if base is not None:
                r[state]["cpu_vs_baseline"] = r[state]["cpu_s"] / base[state]["cpu_s"]
    return out


def step_costs(rounds: int = 2) -> dict:
    """CPU seconds per render step of the main jobs ``default`` and ``old_default`` (module doc, part 3).

    Both estimators are built as the main job builds them (``lightfit.replication.model_for``:
    its field, optics, samples, bounces and seed), then take turns at every daytime step, ``rounds``
    times over the later steps. Rays per step: active lanes of each kind of shadow ray (direct
    sun from the points, next-event from path vertices) at the last step.
    """
    import dataclasses

    import drjit as dr

    from lightfit import replication
    from lightfit.light.estimator import SegmentEstimator
    from lightfit.light.scene import FieldScene

    cpu = time.process_time  # user + system CPU of this process, as part 1's render_cpu_s

    w = replication.forcing()
    configs = {
        "default": replication.ReplicationConfig(),
        "old_default": dataclasses.replace(replication.ReplicationConfig.paper(), bounces=3),
    }
    jobs = {}
    for name, cfg in configs.items():
        m = replication.model_for(cfg, w)
        sc = m.scenario
        fs = FieldScene(m.geometry.mesh, sc.optics, sky=sc.sky, cell=m.geometry.cell)
        est = SegmentEstimator(fs, m.segment_id, samples=sc.samples, bounces=sc.bounces, seed=sc.seed)
        jobs[name] = (est, m.sun_deg[m.day])
    parts = ("sun_rays", "weights", "values", "summary", "render")
    out = {
        n: {
            "boundary": "periodic" if e.fs.cell is not None else "finite",
            "evaluations": e.n_evaluations,
            "bounces": e.bounces,
            "samples": e.samples,
            "first_step_cpu_s": 0.0,
            "later": dict.fromkeys(parts, 0.0),
        }
        for n, (e, _) in jobs.items()
    }
    for name, (est, suns) in jobs.items():
        est.fs.set_sun(*suns[0])
        c = cpu()
        est.render()
        dr.sync_thread()
        out[name]["first_step_cpu_s"] = cpu() - c
    n_later = len(next(iter(jobs.values()))[1]) - 1
    for _ in range(rounds):
        for i in range(1, n_later + 1):
            for name, (est, suns) in jobs.items():
                est.fs.set_sun(*suns[i])
                acc = out[name]["later"]
                with dr.suspend_grad():
                    geo = est._geometry()
                    c = cpu()
                    rays = est._sun_rays(geo)
                    dr.eval(rays)
                    dr.sync_thread()
                    acc["sun_rays"] += cpu() - c
                    c = cpu()
                    weights = est._weigh(geo)
                    dr.eval(weights)
                    dr.sync_thread()
                    acc["weights"] += cpu() - c
                    c = cpu()
                    vals = est._values(geo, weights, rays)
                    dr.eval(vals)
                    dr.sync_thread()
                    acc["values"] += cpu() - c
                    c = cpu()
                    est._irradiance(vals, None)
                    acc["summary"] += cpu() - c
                est._suns_kept.clear()  # a later step at a new sun: its shadow rays cast, not kept ones
                c = cpu()
                est.render()
                dr.sync_thread()
                acc["render"] += cpu() - c
    for name, (est, _) in jobs.items():
        r = out[name]
        r["later"] = {k: v / (rounds * n_later) for k, v in r["later"].items()}
        # Shadow rays of the last step, per kind: direct sun where the side faces the sun, next-event
        # rays from every leaf or soil vertex.
        with dr.suspend_grad():
            o, nrm, *_ = est._arrays()
            geo = est._geometry()
            sun = np.asarray(est.fs.sun)
            r["rays_per_later_step"] = {
                "sun": int(
                    np.sum(np.asarray(nrm.x) * sun[0] + np.asarray(nrm.y) * sun[1] + np.asarray(nrm.z) * sun[2] > 0)
                ),
                **{
                    f"nee_order_{d}": int(np.sum(np.asarray(g["hit_leaf"]) | np.asarray(g["hit_soil"])))
                    for d, g in enumerate(geo[: est.bounces])
                },
            }
        r["later"]["shadow_rays_per_cpu_s"] = sum(r["rays_per_later_step"].values()) / r["later"]["sun_rays"]
    out["later_render_ratio_default_over_old"] = (
        out["default"]["later"]["render"] / out["old_default"]["later"]["render"]
    )
    out["first_step_ratio_default_over_old"] = (
        out["default"]["first_step_cpu_s"] / out["old_default"]["first_step_cpu_s"]
    )
    return out


def _code_state() -> dict:
    """The commit measured and whether lightfit/ had uncommitted changes (they would be measured too)."""

    def git(*args):
        r = subprocess.run(["git", "-C", str(ROOT), *args], capture_output=True, text=True)
        return r.stdout.strip() if r.returncode == 0 else None

    status = git("status", "--porcelain", "--", "lightfit")
    return {"commit": git("rev-parse", "HEAD"), "lightfit_uncommitted": None if status is None else status.splitlines()}


def _write_section(name: str, section: dict) -> None:
    """Write ``section`` (with its own run's record) into the results at OUT, keeping the rest. The
    file's top-level record is its main run's: fields that run did not record are left unknown (None)."""
    res = json.loads(OUT.read_text()) if OUT.exists() else {}
    if res:
        res = {**dict.fromkeys(record()), **res}
    res[name] = {**record(), **section}
    write_result(OUT, res, indent=1, default=float)


def table(res: dict) -> str:
    lines = [
        "| N × N | field | K | plants grown | triangles | render (s) | peak RSS (MB) | canopy absorbed PAR (µmol s⁻¹) "
        "| vs wide field | per-segment RMS difference from wide ÷ mean (MC noise alone) |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in res["fields"]:
        vs = f"{100 * r['vs_wide']:+.2f} % ± {100 * r['vs_wide_sd']:.2f} %" if "vs_wide" in r else "–"
        seg = (
            f"{100 * r['segment_rms_error_vs_wide']:.1f} % ({100 * r['segment_rms_noise']:.1f} %)"
            if "segment_rms_error_vs_wide" in r
            else "–"
        )
        lines.append(
            f"| {r['n']} × {r['n']} | {r['setup']} | {r.get('samples', res['samples'])} | {r['plants_grown']} "
            f"| {r['scene_faces']} | "
            f"{min(r['render_s']):.1f} | {r['peak_rss_mb']:.0f} | "
            f"{r['canopy_absorbed_umol_s']:.2f} ± {r['canopy_absorbed_sd']:.2f} | {vs} | {seg} |"
        )
    if res.get("main_job"):
        lines += [
            "",
            "| main job | boundary | leaf base colour | bounces | plants grown | cold: wall / CPU (s) "
            "| warm: wall / CPU (s) | CPU ÷ old default (cold / warm) | peak RSS (MB) |",
            "|---|---|---:|---:|---:|---:|---:|---:|---:|",
        ]
        for v in res["main_job"].values():
            c, w = v["cold"], v["warm"]
            ratio = (
                f"{c['cpu_vs_old_default']:.2f} / {w['cpu_vs_old_default']:.2f}" if "cpu_vs_old_default" in c else "–"
            )
            lines.append(
                f"| `{v['command']}` | {v['boundary']} | {v['base_color']:.2f} | {v['bounces']} | {v['plants_grown']} "
                f"| {c['wall_s']:.0f} / {c['cpu_s']:.0f} | {w['wall_s']:.0f} / {w['cpu_s']:.0f} | {ratio} "
                f"| {max(c['peak_rss_mb'], w['peak_rss_mb']):.0f} |"
            )
    return "\n".join(lines)


def main(
    sizes=(4, 10, 23),
    wide_sizes=(4, 10, 23),
    samples=64,
    seeds=2,
    with_main_job=True,
    main_job_options=(),
    equal_cost=True,
) -> dict:
    (sun_el, sun_az), dni, dhi = _sun()
    with tempfile.TemporaryDirectory(prefix="lightfit-bench-periodic-") as d:
        tmp = Path(d)
        t0 = time.perf_counter()
        fields = edge_bias(sizes, wide_sizes, samples, seeds, tmp, equal_cost)
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
        "render_cpu_s": "per render seed, CPU time of the child (all threads)",
        "main_job_note": "each job cold (empty plant cache and Dr.Jit kernel cache: the child's HOME is new) "
        "then warm (both caches as the cold run left them); cpu_s is the child's user + system time",
        "fields": fields,
        "main_job": mj,
        "bench_wall_s": wall,
        "machine": f"{platform.machine()}, {os.cpu_count()} cores (shared; timings are indicative)",
        "code": _code_state(),
    }
    write_result(OUT, res, indent=1, default=float)
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
    ap.add_argument("--equal-cost", action=argparse.BooleanOptionalAction, default=True)
    ap.add_argument("--main-job-options", default="", help="extra options of both main jobs, e.g. '--quick'")
    ap.add_argument("--case", nargs=2, metavar=("N", "SETUP"), help=argparse.SUPPRESS)
    ap.add_argument("--case-out", type=Path, help=argparse.SUPPRESS)
    ap.add_argument(
        "--main-job-only",
        metavar="JOBS",
        help="only the main jobs named (comma-separated, e.g. default,old_default), written to the results' "
        "main_job_rerun section; the rest of the results file is kept",
    )
    ap.add_argument("--warm-repeats", type=int, default=1, help="warm rounds of the main jobs (taking turns)")
    ap.add_argument(
        "--baseline-commit",
        metavar="REF",
        help="with --main-job-only: also time the default main job of this commit (checked out in a temporary "
        "git worktree), e.g. the commit before the periodic boundary, as the job 'default_at_REF'",
    )
    ap.add_argument(
        "--step-costs",
        action="store_true",
        help="only the CPU cost per render step of the default and old default main jobs (module doc, part 3), "
        "written to the results' step_costs section",
    )
    out_option(ap, OUT)
    a = ap.parse_args()
    OUT = a.out
    if a.step_costs:
        sc = step_costs()
        _write_section(
            "step_costs",
            {
                "command": "python benchmarks/bench_periodic.py " + " ".join(sys.argv[1:]),
                "note": "CPU s (user + system) per step; later steps averaged over 2 rounds; parts evaluated apart",
                "machine": f"{platform.machine()}, {os.cpu_count()} cores (shared; timings are indicative)",
                "code": _code_state(),
                **sc,
            },
        )
        print(
            "| job | boundary | bounces | evaluations | first step s | later step s | sun rays | weights | values "
            "| summary | shadow rays / step | shadow rays per CPU s |"
        )
        print("|" + "---|" * 12)
        for name in ("default", "old_default"):
            r = sc[name]
            L = r["later"]
            print(
                f"| {name} | {r['boundary']} | {r['bounces']} | {r['evaluations']} | {r['first_step_cpu_s']:.2f} | "
                f"{L['render']:.3f} | {L['sun_rays']:.3f} | {L['weights']:.3f} | {L['values']:.3f} | "
                f"{L['summary']:.3f} | {sum(r['rays_per_later_step'].values())} | {L['shadow_rays_per_cpu_s']:.3g} |"
            )
        print(f"wrote {OUT} (step_costs)")
    elif a.main_job_only:
        names = a.main_job_only.split(",")
        with tempfile.TemporaryDirectory(prefix="lightfit-bench-periodic-") as d:
            jobs = [j for j in MAIN_JOBS if j[0] in names]
            if a.baseline_commit:
                tree = Path(d) / "baseline"
                subprocess.run(
                    ["git", "-C", str(ROOT), "worktree", "add", "-q", "--detach", str(tree), a.baseline_commit],
                    check=True,
                )
                sha = subprocess.run(
                    ["git", "-C", str(tree), "rev-parse", "--short", "HEAD"], capture_output=True, text=True
                ).stdout.strip()
                jobs.append((f"default_at_{sha}", (), f"the default main job of commit {sha}", tree))
            try:
                mj = main_job(Path(d), tuple(a.main_job_options.split()), jobs, a.warm_repeats)
            finally:
                if a.baseline_commit:
                    subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(tree)], check=False)
        _write_section(
            "main_job_rerun",
            {
                "command": "python benchmarks/bench_periodic.py " + " ".join(sys.argv[1:]),
                "note": "cold once, then warm rounds taking turns; warm = mean of warm_runs; cpu_s = user + system",
                "machine": f"{platform.machine()}, {os.cpu_count()} cores (shared; timings are indicative)",
                "code": _code_state(),
                "jobs": mj,
            },
        )
        for name, r in mj.items():
            c, w = r["cold"], r["warm"]
            nan = float("nan")
            print(
                f"{name}: cold {c['cpu_s']:.1f} s CPU ({c.get('cpu_vs_old_default', nan):.2f}x old default, "
                f"{c.get('cpu_vs_baseline', nan):.2f}x baseline), warm {w['cpu_s']:.1f} s CPU "
                f"({w.get('cpu_vs_old_default', nan):.2f}x, {w.get('cpu_vs_baseline', nan):.2f}x), "
                f"warm runs {[round(x['cpu_s'], 1) for x in r['warm_runs']]}"
            )
        print(f"wrote {OUT} (main_job_rerun)")
    elif a.case:
        case(int(a.case[0]), a.case[1], a.samples, a.seeds, a.case_out)
    else:
        ints = lambda s: tuple(int(x) for x in s.split(",") if x)  # noqa: E731
        main(
            ints(a.sizes),
            ints(a.wide_sizes),
            a.samples,
            a.seeds,
            a.main_job,
            tuple(a.main_job_options.split()),
            a.equal_cost,
        )
