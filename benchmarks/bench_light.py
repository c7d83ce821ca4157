"""Benchmark: per-segment irradiance on a 500-plant field, gradient cost, ray throughput, irradiancemeter.

    python benchmarks/bench_light.py [--n-plants 500] [--samples 64] [--boundary periodic|finite]
        [--optics prospect|paper] [--bounces B] [--sheaths wrapped|rods] [--out JSON]

The field is the defaults' (issue 16): the measured plants as one periodic cell, the PROSPECT-D
leaf, the bounces that leaf needs for 1 % truncation (2); ``--boundary finite --optics paper
--bounces 3`` is the earlier setup (2 buffer rows, the grey leaf); ``--sheaths`` the leaf sheaths'
layout (``Field.sheaths``, default the model's default; recorded as ``sheaths``, and runs stored
before it was recorded had ``rods``). All ratios come from one run on one machine. Writes
benchmarks/results/light.json (or ``--out``; the last run of another setup is kept under
``earlier_runs``) and prints a table, with the commit and the load average (the 2 cores are
shared). Measured:
1. Wall time of one primal pass over all measured shoot segments at K samples, twice: with the
   paths traced (a fresh estimator, kernels compiled) and with them kept (the same estimator
   again, as every later time step of a day: only the sun's rays are cast), its median
   relative standard error of absorbed PAR (sun + 0.3·sky; median and 90th percentile over
   all segments, blades and stems), and the K (and time, ∝ K) that a median of 2 % needs.
2. Estimator throughput (path samples/s) ÷ raw ``scene.ray_test`` throughput (rays/s) on random
   rays through the same scene; each path sample casts about 1 + 3·(bounces + 1) rays.
3. Reverse-mode gradient (three leaf parameters) time ÷ primal time (warm kernels).
4. Our estimator vs one Mitsuba ``irradiancemeter`` render per segment, at equal standard error
   of the front-side diffuse + scattered irradiance, on a small field.
5. Periodic fields: the direct light from the paths against the projection
   (``direct="projection"``, :func:`direct_projection_comparison`), steady-state time, median and
   90th percentile, and the time a 2 % median needs.

The Mitsuba variant is the package's choice (``cuda_ad_mono`` where a CUDA device is usable,
``LIGHTFIT_VARIANT`` to force one) and is recorded as ``mitsuba_variant``: run unchanged on a
machine with a GPU, this measures issue 16's item 4 (time to a 2 % median in ``cuda_ad_mono``).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import resource
import time
from pathlib import Path

import numpy as np
from bench_variance import _stats  # per-class median / p90 (same script folder)
from provenance import out_option, wide_console, write_result
from rich.table import Table

import lightfit  # noqa: F401
from lightfit.light import backend
from lightfit.light.estimator import SegmentEstimator, bounces_for_tolerance
from lightfit.light.scene import SOIL_ALBEDO, FieldScene, Optics
from lightfit.plant import HEADINGS, SHEATHS, Field, build, organ_class
from lightfit.precision import use_float64

use_float64()  # lightfit's precision policy (lightfit.precision), before any JAX array exists

OUT = Path(__file__).resolve().parent / "results" / "light.json"


#: The benchmarks' sun on their cell (elevation, azimuth), degrees.
BENCH_SUN_DEG = (50.0, 180.0)


def periodic_cell(
    n_plants: int, sheaths: str = SHEATHS[0], headings: str = HEADINGS[0], plants_per_row: int | None = None
):
    """The light benchmarks' scene: ``n_plants`` (seed 1) as one periodic cell with the default
    (or ``sheaths``) layout of the leaf sheaths and plant ``headings``, the default PROSPECT-D
    leaf, the sun at :data:`BENCH_SUN_DEG`; a square of N² plants (N = ⌈√n_plants⌉: 500 builds
    23² = 529) or whole rows of ``plants_per_row``. Returns ``(geometry, scene, measured segment
    ids, bounces for 1 % truncation)``."""
    optics = Optics.preset("prospect")
    fld = Field(
        n_plants=n_plants,
        seed=1,
        boundary="periodic",
        sheaths=sheaths,
        headings=headings,
        plants_per_row=plants_per_row,
    )
    geom = build(fld, progress=True)
    fs = FieldScene(geom.mesh, optics, cell=geom.cell)
    fs.set_sun(*BENCH_SUN_DEG)
    ids = geom.segments.loc[geom.segments["measured"], "segment_id"].to_numpy()
    return geom, fs, ids, bounces_for_tolerance(0.01, optics)


def _timed(f, repeat=2):
    f()  # compile / warm up
    best = math.inf
    for _ in range(repeat):
        t = time.perf_counter()
        out = f()
        best = min(best, time.perf_counter() - t)
    return best, out


def raw_ray_rate(fs: FieldScene, n: int) -> float:
    mi = backend.mitsuba()
    import drjit as dr

    v = fs.mesh.vertices
    lo, hi = v.min(0), v.max(0)
    rng = np.random.default_rng(0)
    o = rng.uniform(lo, hi, size=(n, 3)).astype(np.float32)
    d = rng.normal(size=(n, 3)).astype(np.float32)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    ray = mi.Ray3f(mi.Point3f(o.T), mi.Vector3f(d.T))
    dr.eval(ray)

    def run():
        hit = fs.scene.ray_test(ray)
        dr.eval(hit)
        dr.sync_thread()

    t, _ = _timed(run, 3)
    return n / t


def _cpu_s() -> tuple[float, float]:
    """This process's CPU time so far, (user, system) s. A process's first render takes longer
    than the next in system time: memory it touches for the first time is mapped by the kernel,
    which costs ≈ 4–6 s per GiB in this machine's virtual machine (a Firecracker guest whose freed
    memory goes back to the host within seconds) against ≈ 0.07 s per GiB for memory mapped
    before; docs/light-sampling.md, "A process's first render"."""
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime, r.ru_stime


def median_se_factor(se: np.ndarray, dof: int, *, seed: int = 0, draws: int = 16) -> float:
    r"""By how much the median over segments of replicate SEs (``dof`` degrees of freedom each)
    falls short of the median of the true SEs, estimated from the SEs themselves.

    Each estimate is ŝ = σ·c with c = √(χ²_dof / dof). For segments that all share one σ the
    factor is the median of c (0.888 at dof = 3); for σ spread widely (this canopy: p90 ÷ median
    ≈ 6) the median of log ŝ is shifted by the *mean* of log c, exp(E log c) = 0.832 at dof = 3,
    and the median-of-c factor leaves the median ≈ 5 % low. The shift depends on how σ is spread
    around the median, so it is taken from the data: median(ŝ·c*) ÷ median(ŝ), c* fresh draws of
    c (seeded). In simulation (log-normal σ) this is within 0.5 % of the true factor once σ's
    log-SD is ≥ 1 (this canopy's is ≈ 1.4), 1.3–2 % low at 0.5, and ≤ 7 % low when every σ is the
    same (the estimates' own spread is taken for σ's): a low factor gives a higher, conservative
    corrected median. Only finite, positive SEs count.
    """
    s = np.asarray(se, dtype=np.float64)
    s = s[np.isfinite(s) & (s > 0)]
    c = np.sqrt(np.random.default_rng(seed).chisquare(dof, size=(draws, len(s))) / dof)
    return float(np.median(s * c) / np.median(s))


def finite_median(x: np.ndarray) -> float:
    """Median over the finite entries (a segment without light has relative SE inf)."""
    x = np.asarray(x, dtype=np.float64)
    return float(np.median(x[np.isfinite(x)]))


#: The sun of a later step of a day (elevation, azimuth), degrees, after the bench's 50° / 180°.
STEP_SUN_DEG = (45.0, 200.0)


def organ_stats(rse: np.ndarray, organ: np.ndarray) -> dict:
    """Per organ class: segments, median and p90 relative SE, and the share of the class above the
    all-segment median (who sets that median)."""
    ok = np.isfinite(rse)
    median = float(np.median(rse[ok]))
    out = {}
    for name in ("blade", "sheath", "stem"):
        v = rse[(organ == name) & ok]
        if v.size:
            out[name] = {
                "n": int(v.size),
                "median": float(np.median(v)),
                "p90": float(np.quantile(v, 0.9)),
                "share_above_all_median": float(np.mean(v > median)),
            }
    return out


def blade_light_deciles(r, organ: np.ndarray, dhi: float = 0.3) -> dict:
    r"""Which blades set the all-segment median: the blades by decile of absorbed PAR (DNI 1, DHI
    ``dhi`` per unit one-sided area) with, per decile, the median absorbed PAR, relative SE, share
    above the all-segment median and share of the variance from the sky part (the parts'
    covariance left out), and the slope p of a least-squares fit
    :math:`\log \mathrm{rse} = c - p \log v` over the blades (Poisson hits alone: p = ½)."""
    v = r.total("absorbed", 1.0, dhi)
    rse = r.relative_se("absorbed", 1.0, dhi)
    all_median = float(np.median(rse[np.isfinite(rse)]))
    b = (organ == "blade") & np.isfinite(rse) & (v > 0)
    vb, rb = v[b], rse[b]
    var_sun, var_sky = r.se["absorbed_sun"][b] ** 2, (dhi * r.se["absorbed_sky"][b]) ** 2
    sky_share = var_sky / (var_sun + var_sky)
    edges = np.quantile(vb, np.linspace(0, 1, 11))
    dec = np.clip(np.searchsorted(edges, vb, side="right") - 1, 0, 9)
    rows = [
        {
            "decile": int(i),
            "absorbed_median": float(np.median(vb[dec == i])),
            "rse_median": float(np.median(rb[dec == i])),
            "share_above_all_median": float(np.mean(rb[dec == i] > all_median)),
            "sky_variance_share_median": float(np.median(sky_share[dec == i])),
        }
        for i in range(10)
    ]
    slope = -float(np.polyfit(np.log(vb), np.log(rb), 1)[0])
    return {"all_median": all_median, "deciles": rows, "rse_light_exponent": slope}


def direct_projection_comparison(
    fs: FieldScene, ids: np.ndarray, bounces: int, settings, organ: np.ndarray | None = None, seeds: int = 2
) -> dict:
    r"""Direct light from the paths vs by projection (issue 16), side by side in one process.

    Each setting ``(samples, rays_per_m2)`` (``rays_per_m2`` 0: ``direct="paths"``) renders all
    ``ids`` with two fresh estimators in turn; the second's time is the steady state (Dr.Jit
    reuses the first's memory: on this machine memory touched for the first time costs 4–6 s per
    GiB of system time, which the first render pays; :func:`_cpu_s`). The time for a 2 % median
    scales K and the projection's rays together by (median / 2 %)²: both parts' variances fall as
    1/K and 1/rays.

    Settings with different replicate counts R (K < 32: R = K/4) are compared by the median SE
    divided by :func:`median_se_factor` too (``*_r_corrected``): the replicates' SE estimate is
    unbiased in variance, but the median over segments of its square root falls with fewer
    degrees of freedom (on this canopy's widely spread SEs by ≈ 0.93 at R = 8 and ≈ 0.83 at
    R = 4), which alone would make R = 4 look ≈ 11 % better. The two seeds' renders of a setting
    also give each segment a pooled variance (``*_pooled_seeds``: 2(R − 1) degrees of freedom, so
    a correction half as large) and, as a check of the reported SEs against something they did not compute, the median
    over segments of |z| = |v₁ − v₂| / √(SE₁² + SE₂²), which is Student's t median |t| with
    2(R − 1) degrees of freedom (0.72 at R = 4) when the SEs are right. ``seeds`` > 2 renders more
    fresh estimators (seeds 1, 2, …) and pools all of them (``seeds``·(R − 1) degrees of freedom: at
    4 seeds and R = 4 the correction is ≈ 0.96, so the pooled median rests little on how it is
    estimated); the timing and the |z| check stay those of seeds 1 and 2. With ``organ``
    (:func:`lightfit.plant.organ_class`) the second seed's SEs are summarised per organ class too.

    A day renders one estimator at every step's sun: the paths' geometry and the projected sky are
    kept, and only the sun's rays are cast again. So the second estimator then renders once more
    at :data:`STEP_SUN_DEG` (``day_step_*``): the time a later step of a day takes, its SE, and
    (R-corrected) that step's time for a 2 % median, the kept sky's single cast not included.
    """
    import gc

    from scipy.stats import t as student_t

    if seeds < 2:
        raise ValueError(f"seeds={seeds}: at least 2 (the steady state is the second estimator's render)")
    out = []
    sun = fs.sun.copy()
    for samples, rays in settings:
        kw = dict(direct="projection", direct_rays_per_m2=rays) if rays else {}
        times, cpu, renders = [], [], []
        for seed in range(1, seeds + 1):
            est = SegmentEstimator(fs, ids, samples=samples, bounces=bounces, seed=seed, **kw)
            t, c = time.perf_counter(), _cpu_s()
            r = est.render()
            times.append(time.perf_counter() - t)
            cpu.append(tuple(b - a for a, b in zip(c, _cpu_s())))
            renders.append(r)
            R = est.replicates
            if seed == 2:  # a later step of a day: another sun, the same estimator
                fs.set_sun(*STEP_SUN_DEG)
                t = time.perf_counter()
                r_step = est.render()
                t_step = time.perf_counter() - t
                fs.sun = sun
            del est
            gc.collect()
        r = renders[1]  # the steady state's render, whatever the seeds
        rse = r.relative_se()
        med = finite_median(rse)
        f = (med / 0.02) ** 2
        med_c = med / median_se_factor(rse, R - 1)
        # The two seeds together: their variance estimates pooled (2(R − 1) degrees of freedom,
        # so a smaller correction than R - 1's), and the seeds' difference in units of its reported
        # SE, whose median |z| is that of Student's t with 2(R − 1) degrees of freedom if the
        # reported SEs are right (an independent check of them).
        v = [x.total("absorbed", 1.0, 0.3) for x in renders]
        dof = seeds * (R - 1)
        with np.errstate(divide="ignore", invalid="ignore"):  # segments without light: nan, left out
            se = [x.total_se() for x in renders]
            pooled = np.sqrt(np.mean(np.square(se), axis=0)) / np.abs(np.mean(v, axis=0))
            z = np.abs(v[0] - v[1]) / np.sqrt(se[0] ** 2 + se[1] ** 2)
        med_p = finite_median(pooled) / median_se_factor(pooled, dof)
        rse_step = r_step.relative_se()
        med_step = finite_median(rse_step) / median_se_factor(rse_step, R - 1)
        out.append(
            {
                "direct": "projection" if rays else "paths",
                "samples": samples,
                "rays_per_m2": rays or None,
                "first_render_s": times[0],
                "render_s": times[1],
                # Process CPU seconds (user, system) of each seed's render: the first render's
                # system time is the kernel mapping fresh memory (see _cpu_s).
                "render_cpu_user_sys_s": cpu,
                "seeds": seeds,
                **({"later_renders_s": times[2:]} if seeds > 2 else {}),
                "rse_absorbed": _stats(rse, np.asarray(r.meta["is_blade"], bool)),
                **({"rse_absorbed_by_organ": organ_stats(rse, organ)} if organ is not None else {}),
                **({"blades_by_absorbed_decile": blade_light_deciles(r, organ)} if organ is not None else {}),
                "scale_for_2pct_median": f,
                "extrapolated_s_at_2pct": times[1] * f,
                "replicates": R,
                "median_rse_r_corrected": med_c,
                "extrapolated_s_at_2pct_r_corrected": times[1] * (med_c / 0.02) ** 2,
                "median_rse_pooled_seeds": med_p,
                "extrapolated_s_at_2pct_pooled_seeds": times[1] * (med_p / 0.02) ** 2,
                "seed_difference_median_abs_z": float(np.nanmedian(np.where(np.isfinite(z), z, np.nan))),
                "seed_difference_median_abs_z_expected": float(student_t.ppf(0.75, 2 * (R - 1))),
                "day_step_s": t_step,
                "day_step_rse_absorbed": _stats(rse_step, np.asarray(r_step.meta["is_blade"], bool)),
                "day_step_median_rse_r_corrected": med_step,
                "day_step_s_at_2pct_r_corrected": t_step * (med_step / 0.02) ** 2,
            }
        )
    return {"settings": out, "load_average": os.getloadavg()[0]}


def irradiancemeter_comparison(n_segments: int = 6, bounces: int = 3, sheaths: str = SHEATHS[0]) -> dict:
    """Per-segment time at equal SE: one irradiancemeter render per segment vs our batched pass."""
    mi = backend.mitsuba()
    geom = build(Field(boundary="finite", n_plants=4, buffer_rows=1, seed=2, sheaths=sheaths))
    fs = FieldScene(geom.mesh, Optics.preset("paper"))
    fs.set_sun(-10.0, 0.0)
    seg = geom.segments[geom.segments["measured"].to_numpy() & (organ_class(geom.segments) == "blade")]
    ids = seg["segment_id"].to_numpy()
    K = 256
    t_ours, r = _timed(lambda: SegmentEstimator(fs, ids, samples=K, bounces=bounces, seed=1).render(), 1)
    # Front-side SE from the front evaluations alone (rerun with front values as the target).
    ours_val = r.front("incident_sky")
    pick = np.linspace(0, len(ids) - 1, n_segments).astype(int)
    m = geom.mesh
    results = []
    for i in pick:
        sid = ids[i]
        sel = m.face_segment == sid
        # Reference value and SE for our estimator on this segment alone, front side.
        reps = [
            SegmentEstimator(fs, [sid], samples=K, bounces=bounces, seed=s).render().front("incident_sky")[0]
            for s in range(4)
        ]
        se_ours = float(np.std(reps, ddof=1))

        def shape(faces):
            sub = mi.Mesh(f"m{sid}{len(faces)}", len(m.vertices), len(faces), mi.Properties(), False, False)
            p = mi.traverse(sub)
            import drjit as dr

            p["vertex_positions"] = dr.ravel(mi.Point3f(np.ascontiguousarray(m.vertices.T, dtype=np.float32)))
            p["faces"] = dr.ravel(mi.Vector3u(np.ascontiguousarray(faces.T, dtype=np.uint32)))
            p.update()
            return sub

        target = shape(m.faces[sel])
        rest = shape(m.faces[~sel])
        sensor = mi.load_dict(
            {
                "type": "irradiancemeter",
                "sampler": {"type": "independent", "sample_count": 1},
                "film": {
                    "type": "hdrfilm",
                    "width": 1,
                    "height": 1,
                    "rfilter": {"type": "box"},
                    "pixel_format": "luminance",
                },
            }
        )
        props = mi.Properties()
        props["sensor"] = sensor
        props["bsdf"] = mi.load_dict({"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.0] * 3}})
        tgt = mi.Mesh(f"t{sid}", len(m.vertices), int(sel.sum()), props, False, False)
        pt = mi.traverse(tgt)
        import drjit as dr

        pt["vertex_positions"] = dr.ravel(mi.Point3f(np.ascontiguousarray(m.vertices.T, dtype=np.float32)))
        pt["faces"] = dr.ravel(mi.Vector3u(np.ascontiguousarray(m.faces[sel].T, dtype=np.uint32)))
        pt.update()
        del target
        scene = mi.load_dict(
            {
                "type": "scene",
                "integrator": {"type": "path", "max_depth": bounces + 2},
                "target": tgt,
                "rest": rest,
                "ground": {
                    "type": "rectangle",
                    "to_world": mi.ScalarTransform4f.scale([300, 300, 1]),
                    "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [SOIL_ALBEDO] * 3}},
                },
                "sky": {"type": "constant", "radiance": {"type": "rgb", "value": [1 / math.pi] * 3}},
            }
        )
        spp = 4096
        vals, times = [], []
        for s in range(4):
            t = time.perf_counter()
            img = mi.render(scene, spp=spp, seed=s + 1)
            vals.append(float(np.asarray(img).ravel()[0]))
            times.append(time.perf_counter() - t)
        se_meter = float(np.std(vals, ddof=1))
        # Time each needs for the same SE: t ∝ SE⁻².
        t_meter = float(np.median(times[1:]))
        t_ours_seg = t_ours / len(ids)
        t_meter_equal = t_meter * (se_meter / max(se_ours, 1e-12)) ** 2
        results.append(
            {
                "segment_id": int(sid),
                "ours": float(ours_val[i]),
                "meter": float(np.mean(vals)),
                "se_ours": se_ours,
                "se_meter": se_meter,
                "t_ours_per_segment_s": t_ours_seg,
                "t_meter_equal_se_s": t_meter_equal,
                "speedup": t_meter_equal / t_ours_seg,
            }
        )
        del scene, tgt, rest
    return {"segments": results, "median_speedup": float(np.median([r["speedup"] for r in results]))}


def main(
    n_plants: int = 500,
    samples: int = 64,
    bounces: int | None = None,
    boundary: str = "periodic",
    optics_name="prospect",
    sheaths: str = SHEATHS[0],
    out: Path = OUT,
) -> dict:
    console = wide_console()
    optics = Optics.preset(optics_name)
    if bounces is None:
        bounces = bounces_for_tolerance(0.01, optics)
    geom = build(Field(n_plants=n_plants, seed=1, boundary=boundary, sheaths=sheaths), progress=True)  # finite: 2 rows
    fs = FieldScene(geom.mesh, optics, cell=geom.cell)
    fs.set_sun(50.0, 180.0)
    ids = geom.segments.loc[geom.segments["measured"], "segment_id"].to_numpy()
    SegmentEstimator(fs, ids[:2000], samples=samples, bounces=bounces, seed=0).render()  # compile kernels
    t_setup = time.perf_counter()
    est = SegmentEstimator(fs, ids, samples=samples, bounces=bounces, seed=1)
    t_setup = time.perf_counter() - t_setup
    t = time.perf_counter()
    r = est.render()
    t_traced = time.perf_counter() - t
    # The kept paths with this sun's shadow rays cast again, as at a new step of a day.
    t_primal, r_kept = _timed(lambda: est._suns_kept.clear() or est.render(), 1)
    assert np.array_equal(r.absorbed_sun, r_kept.absorbed_sun)  # kept paths: the same values
    rse_all = r.relative_se()
    rse = float(np.nanmedian(rse_all))
    k2 = samples * (rse / 0.02) ** 2
    ct = {"absorbed_sun": np.ones(len(ids)), "absorbed_sky": np.full(len(ids), 0.3)}
    t_grad, _ = _timed(lambda: est.vjp(ct), 1)
    rays = raw_ray_rate(fs, 4_000_000)
    path_rate = est.n_evaluations / t_primal
    rays_per_sample = 1 + 3 * (bounces + 1)
    meter = irradiancemeter_comparison(sheaths=sheaths)
    # (K, projection rays per m² (sun, sky) or one for both; 0: paths). The last: the cost model's
    # reallocation (docs/light-sampling.md, "Where the time goes, and casting in passes").
    settings = [(64, 0), (64, 1e7), (32, 2e7), (16, (1.5e7, 2e7))]
    organ = organ_class(geom.segments.set_index("segment_id").loc[ids])
    direct = direct_projection_comparison(fs, ids, bounces, settings, organ) if fs.tracer is not None else None
    res = {
        # cuda_ad_mono where a CUDA device is usable (issue 16 item 4), else llvm_ad_mono.
        "mitsuba_variant": backend.info().variant,
        "boundary": boundary,
        "optics": optics_name,
        "sheaths": sheaths,
        "n_plants_measured": int(Field(n_plants=n_plants).n_measured),
        "segments": len(ids),
        "triangles": int(geom.mesh.n_faces),
        "samples": est.samples,
        "bounces": bounces,
        "evaluations": est.n_evaluations,
        "setup_s": t_setup,
        "primal_traced_s": t_traced,
        "primal_s": t_primal,
        "median_rse_absorbed": rse,
        "rse_absorbed": _stats(rse_all, np.asarray(r.meta["is_blade"], bool)),
        "samples_for_2pct_median": k2,
        "extrapolated_primal_s_at_2pct": t_primal * k2 / samples,
        "extrapolated_traced_s_at_2pct": (t_setup + t_traced) * k2 / samples,
        "goal_s_at_2pct": 60.0,
        "stretch_goal_s_at_2pct": 10.0,
        "path_samples_per_s": path_rate,
        "raw_ray_test_per_s": rays,
        "path_over_raw": path_rate / rays,
        "ray_equivalent_over_raw": path_rate * rays_per_sample / rays,
        "gradient_s": t_grad,
        "gradient_over_primal": t_grad / t_primal,
        "irradiancemeter_median_speedup_equal_se": meter["median_speedup"],
        "irradiancemeter": meter["segments"],
        "direct_projection": direct,
    }
    if out.exists():  # keep the last run of every other setup, with its own conditions
        old = json.loads(out.read_text())
        earlier = old.pop("earlier_runs", {})
        earlier[_setup_key(old)] = old
        earlier.pop(_setup_key(res), None)
        if earlier:
            res["earlier_runs"] = earlier
    res = json.loads(write_result(out, res, indent=2).read_text())  # with the provenance, for the table
    t = Table(
        title=f"irradiance benchmark: {res['segments']} segments, K={est.samples}, {bounces} bounces, 2 CPU cores"
    )
    t.add_column("quantity")
    t.add_column("value", justify="right")
    for k, v in res.items():
        if k == "rse_absorbed":
            for c, q in v.items():
                t.add_row(f"rse {c} median / p90", f"{q['median']:.2%} / {q['p90']:.2%}")
        elif k == "direct_projection" and v is not None:
            for q in v["settings"]:
                label = f"{q['direct']} K={q['samples']}"
                rays = q["rays_per_m2"]
                label += f", {' / '.join(f'{v:.1e}' for v in np.atleast_1d(rays))} rays/m²" if rays else ""
                a = q["rse_absorbed"]["all"]
                t.add_row(
                    label,
                    f"{q['render_s']:.1f} s (first {q['first_render_s']:.1f} s), median / p90 {a['median']:.2%} / "
                    f"{a['p90']:.2%}, 2 % median ≈ {q['extrapolated_s_at_2pct']:.0f} s (R = {q['replicates']}; "
                    f"R-corrected {q['median_rse_r_corrected']:.2%}, "
                    f"≈ {q['extrapolated_s_at_2pct_r_corrected']:.0f} s; two seeds pooled "
                    f"{q['median_rse_pooled_seeds']:.2%}, ≈ {q['extrapolated_s_at_2pct_pooled_seeds']:.0f} s; "
                    f"seeds' median |z| {q['seed_difference_median_abs_z']:.2f}, expected "
                    f"{q['seed_difference_median_abs_z_expected']:.2f}); a later step of a day "
                    f"{q['day_step_s']:.1f} s, {q['day_step_median_rse_r_corrected']:.2%} R-corrected, "
                    f"≈ {q['day_step_s_at_2pct_r_corrected']:.0f} s for 2 %",
                )
                for name, o in q.get("rse_absorbed_by_organ", {}).items():
                    t.add_row(
                        f"  {name}s ({o['n']})",
                        f"median / p90 {o['median']:.2%} / {o['p90']:.2%}, "
                        f"{o['share_above_all_median']:.0%} above the all-segment median",
                    )
                if "blades_by_absorbed_decile" in q:
                    bd = q["blades_by_absorbed_decile"]
                    t.add_row(
                        f"  blades by decile of absorbed PAR (rse ∝ v^-{bd['rse_light_exponent']:.2f})",
                        "; ".join(
                            f"{d['decile'] + 1}: v {d['absorbed_median']:.3f}, {d['rse_median']:.1%}, "
                            f"{d['share_above_all_median']:.0%} above, sky {d['sky_variance_share_median']:.2f}"
                            for d in bd["deciles"]
                        ),
                    )
        elif k not in ("irradiancemeter", "earlier_runs"):
            t.add_row(k, f"{v:.4g}" if isinstance(v, float) else str(v))
    console.print(t)
    return res


def _setup_key(res: dict) -> str:
    """A run's setup as ``earlier_runs`` keys it; runs stored before ``sheaths`` was recorded had
    rods, and the rods' key is the one those runs had."""
    key = f"{res.get('boundary', 'finite')}_{res.get('optics', 'paper')}_{res.get('bounces')}_bounces"
    sheaths = res.get("sheaths", "rods")
    return key if sheaths == "rods" else f"{key}_{sheaths}_sheaths"


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n-plants", type=int, default=500)
    ap.add_argument("--samples", type=int, default=64)
    ap.add_argument("--bounces", type=int, default=None, help="default: the leaf's bounces for 1 %% truncation")
    ap.add_argument("--boundary", default="periodic", choices=["periodic", "finite"])
    ap.add_argument("--optics", default="prospect", choices=["prospect", "paper"], help="leaf optics preset")
    ap.add_argument("--sheaths", choices=SHEATHS, default=SHEATHS[0], help="leaf sheath layout (lightfit.plant.Field)")
    out_option(ap, OUT)
    a = ap.parse_args()
    main(a.n_plants, a.samples, a.bounces, a.boundary, a.optics, a.sheaths, a.out)
