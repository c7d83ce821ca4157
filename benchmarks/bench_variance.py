"""Benchmark: per-segment relative SE of absorbed PAR against time, fixed K vs adaptive sampling.

    python benchmarks/bench_variance.py [--n-plants 500] [--target 0.02] [--bounces 3]
        [--no-adaptive] [--repeat 1] [--out benchmarks/results/variance.json]

Periodic field of ``n_plants`` measured plants (every segment measured), sun 50° elevation,
absorbed PAR at DNI 1 and DHI 0.3. In one run, side by side on the same machine:

1. fixed K = 64 (the old recipe): wall time, median and 90th percentile per-segment relative SE,
   blades and stems apart, with the SE as it was computed before (sun and sky parts treated as
   independent) and with their covariance (``Irradiance.cov``); the K and time a 2 % median needs,
   extrapolated by K ∝ rse⁻² and time ∝ K; the sun and sky parts' own relative SE and the
   share of the total's variance from the sun part (where a variance reduction must act);
2. ``render_adaptive(target_rse=target)``: wall time, reached median/p90 per class, samples
   spent (evaluations), rounds;
3. ``AdaptiveEstimator``: a render at the kept allocation and the reverse-mode gradient (three
   leaf parameters) ÷ that render's time.

``--no-adaptive`` stops after 1; ``--repeat`` times that many fixed-K renders and keeps the
fastest (wall and CPU time of the process, all threads: CPU time is the steadier measure on
shared cores). ``benchmarks/bench_variance_compare.py`` runs this script against another
commit's estimator in turns. Writes benchmarks/results/variance.json (or ``--out``) and
prints a table. Times are wall clock on a machine
whose load is recorded (``load_average``).
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import time
from pathlib import Path

import numpy as np
from provenance import out_option, wide_console, write_result
from rich.table import Table

import lightfit  # noqa: F401
from lightfit.light.estimator import AdaptiveEstimator, SegmentEstimator, render_adaptive
from lightfit.light.scene import FieldScene, Optics
from lightfit.plant import Field, build
from lightfit.precision import use_float64

use_float64()

OUT = Path(__file__).resolve().parent / "results" / "variance.json"
DNI, DHI = 1.0, 0.3


def _stats(rse: np.ndarray, blade: np.ndarray) -> dict:
    out = {}
    for name, sel in (("all", np.ones_like(blade)), ("blades", blade), ("stems", ~blade)):
        v = rse[sel & np.isfinite(rse)]
        out[name] = {"median": float(np.median(v)), "p90": float(np.quantile(v, 0.9)), "n": int(sel.sum())}
    return out


def main(
    n_plants: int = 500,
    target: float = 0.02,
    bounces: int = 3,
    samples: int = 64,
    adaptive: bool = True,
    out: Path = OUT,
    repeat: int = 1,
) -> dict:
    console = wide_console()
    g = build(Field(n_plants=n_plants, seed=1, boundary="periodic"), progress=False)
    fs = FieldScene(g.mesh, Optics.preset("paper"), cell=g.cell)
    fs.set_sun(50.0, 180.0)
    ids = g.segments.loc[g.segments["measured"], "segment_id"].to_numpy()
    res = {
        "n_plants": n_plants,
        "segments": len(ids),
        "bounces": bounces,
        "target_rse": target,
        "load_average_start": os.getloadavg(),  # 1, 5, 15 min, the field built
    }
    # 1. fixed K (warm-up render first: kernels compiled outside the timing)
    SegmentEstimator(fs, ids[:200], samples=32, bounces=bounces, seed=9).render()
    walls, cpus = [], []
    for _ in range(repeat):  # the fastest of ``repeat`` renders (estimator built in each)
        t, c = time.perf_counter(), time.process_time()
        r = SegmentEstimator(fs, ids, samples=samples, bounces=bounces, seed=1).render()
        walls.append(time.perf_counter() - t)
        cpus.append(time.process_time() - c)
    t_fixed = min(walls)
    blade = r.meta["is_blade"]
    indep = dataclasses.replace(r, cov={}).relative_se("absorbed", DNI, DHI)  # the parts as independent
    cov = r.relative_se("absorbed", DNI, DHI)
    fixed = {
        "samples": r.samples,
        "time_s": t_fixed,
        "cpu_s": min(cpus),
        "times_s": walls,
        "cpu_times_s": cpus,
        "rse_independent": _stats(indep, blade),
        "rse": _stats(cov, blade),
    }
    # Where the noise is (what a variance reduction must target): each part's own relative SE,
    # and the share of the total's variance from the sun part (direct sun + scattered sun).
    for part in ("sun", "sky"):
        v, se = getattr(r, f"absorbed_{part}"), r.se[f"absorbed_{part}"]
        fixed[f"rse_{part}_part"] = _stats(np.divide(se, v, out=np.full_like(v, np.inf), where=v > 0), blade)
    vs, vk = (DNI * r.se["absorbed_sun"]) ** 2, (DHI * r.se["absorbed_sky"]) ** 2
    share = np.divide(vs, vs + vk, out=np.full_like(vs, np.nan), where=vs + vk > 0)
    fixed["sun_variance_share_median"] = {
        name: float(np.nanmedian(share[sel])) for name, sel in (("blades", blade), ("stems", ~blade))
    }
    for key in ("rse_independent", "rse"):
        m = fixed[key]["all"]["median"]
        fixed[key]["samples_for_target_median"] = samples * (m / target) ** 2
        fixed[key]["time_s_for_target_median"] = t_fixed * (m / target) ** 2
    res["fixed"] = fixed
    if not adaptive:
        res["load_average_end"] = os.getloadavg()
        write_result(out, res, indent=1)
        _print_table(res, n_plants, len(ids), bounces, target, samples, t_fixed)  # the rule: every bench prints one
        return res
    # 2. adaptive
    t = time.perf_counter()
    a = render_adaptive(fs, ids, target, bounces=bounces, seed=1, max_samples=4096)
    t_adapt = time.perf_counter() - t
    K = a.meta["samples_per_segment"]
    res["adaptive"] = {
        "time_s": t_adapt,
        "evaluations": int(a.meta["n_evaluations"]),
        "evaluations_fixed_k": int(r.meta["n_evaluations"]),
        "rounds": a.meta["rounds"],
        "rse": _stats(a.meta["reached_rse"], blade),
        "samples_median": float(np.median(K)),
        "samples_mean": float(K.mean()),
        "samples_mean_blades": float(K[blade].mean()),
        "samples_mean_stems": float(K[~blade].mean()),
        "at_max_samples": int((K == 4096).sum()),
    }
    # 3. kept allocation: render and gradient
    est = AdaptiveEstimator(fs, ids, target, bounces=bounces, seed=1, max_samples=4096)
    t = time.perf_counter()
    est.render()
    t_render = time.perf_counter() - t
    ct = {"absorbed_sun": np.ones(len(ids)), "absorbed_sky": np.full(len(ids), DHI)}
    t = time.perf_counter()
    est.vjp(ct)
    t_grad = time.perf_counter() - t
    res["kept_allocation"] = {"render_s": t_render, "gradient_s": t_grad, "gradient_over_primal": t_grad / t_render}
    res["load_average_end"] = os.getloadavg()
    write_result(out, res, indent=1)

    _print_table(res, n_plants, len(ids), bounces, target, samples, t_fixed)
    console.print(
        f"fixed K for a {target:.0%} median: {fixed['rse']['samples_for_target_median']:.0f} "
        f"({fixed['rse']['time_s_for_target_median']:.0f} s; independent-parts SE: "
        f"{fixed['rse_independent']['time_s_for_target_median']:.0f} s); adaptive {t_adapt:.1f} s, "
        f"mean K {K.mean():.0f} (blades {K[blade].mean():.0f}, stems {K[~blade].mean():.0f}); "
        f"gradient/primal at the kept allocation {t_grad / t_render:.2f}; load {res['load_average_end']}"
    )
    return res


def _print_table(res: dict, n_plants: int, n_segments: int, bounces: int, target: float, samples: int, t_fixed: float):
    """The fixed-K rows of ``res`` and, where it was run, the adaptive one."""
    fixed = res["fixed"]
    tab = Table(title=f"{n_plants}-plant periodic field, {n_segments} segments, {bounces} bounces, target {target:.0%}")
    for c in ("run", "time s", "median all", "p90 all", "median blades", "p90 blades", "median stems", "p90 stems"):
        tab.add_column(c)

    def row(name, secs, s):
        tab.add_row(
            name,
            f"{secs:.1f}",
            *(f"{s[k][q]:.1%}" for k in ("all", "blades", "stems") for q in ("median", "p90")),
        )

    row(f"K={samples}, independent-parts SE", t_fixed, fixed["rse_independent"])
    row(f"K={samples}, SE with covariance", t_fixed, fixed["rse"])
    row(f"K={samples}, sun part alone", t_fixed, fixed["rse_sun_part"])
    row(f"K={samples}, sky part alone", t_fixed, fixed["rse_sky_part"])
    if "adaptive" in res:
        row("adaptive", res["adaptive"]["time_s"], res["adaptive"]["rse"])
    wide_console().print(tab)


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n-plants", type=int, default=500)
    ap.add_argument("--target", type=float, default=0.02)
    ap.add_argument("--bounces", type=int, default=3)
    ap.add_argument("--samples", type=int, default=64)
    ap.add_argument("--no-adaptive", action="store_true")
    out_option(ap, OUT)
    ap.add_argument("--repeat", type=int, default=1, help="fixed-K renders timed (the fastest is kept)")
    a = ap.parse_args()
    main(a.n_plants, a.target, a.bounces, a.samples, not a.no_adaptive, a.out, a.repeat)
