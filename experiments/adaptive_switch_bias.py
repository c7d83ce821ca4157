"""Does adaptive sampling's switch from the projected to a segment's own direct light bias it?

    python experiments/adaptive_switch_bias.py [--n-plants 4] [--seeds 16] [--target 0.1]
        [--rays 0 1e6 3e5 1e5] [--out experiments/results/adaptive_switch_bias.json]

``render_adaptive(direct="projection")`` switches a segment still above the target to the paths'
direct light when its *projected* part's own relative SE is above the target, or no projected ray
met it (``own_rse = inf``). The switch is decided on the realised values of the estimator it then
discards: a segment that the projection missed (0) or under-counted (a large relative SE) is
replaced by an unbiased estimate, so the kept values are biased upward, by about E[paths] ×
P(switch | low draw). The bias grows as the projected rays per m² fall (more segments switch on a
noisy projection) and vanishes when every segment's projection is resolved (none switch on noise)
or when every segment switches (a paths render, unbiased).

Scene: the light benchmarks' ``periodic_cell`` (``--n-plants``, periodic, wrapped sheaths, the
PROSPECT-D leaf and its bounces for 1 % truncation, sun 50°), absorbed PAR at DNI 1, DHI 0.3,
target ``--target``, pilot 32, cap ``--max-samples``, the default light floor. Reference: the mean
of ``--ref-seeds`` fixed-K renders (K = ``--ref-samples``) with the projected direct light at 10 × the
default rays per m², for the thin stems (seeds 1000 …, independent of the runs' seeds 0 …; the
projection is an unbiased estimator whatever its rays). Per projected rays per m² (``--rays``,
0 = the default (sun, sky) = (2.5e6, 1e7); one number sets both): per organ class (blade, stem, sheath) and the
canopy, the area-weighted absorbed PAR of each seed's adaptive render ÷ the reference's − 1, mean
and SE over the seeds; the same for a *control*, the fixed-K render (K = 256) with the projection
at those rays and the same seeds (unbiased: it must come out within its SE); how many
segments switched; and the adaptive render with the paths' direct light (no switch: its own
sequential-stopping bias, which the switched segments share).

Writes experiments/results/adaptive_switch_bias.json and prints a table.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np
from rich.table import Table

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

from bench_light import periodic_cell  # noqa: E402
from provenance import wide_console, write_result  # noqa: E402

from lightfit.defaults import DEFAULT_RAYS_PER_M2  # noqa: E402
from lightfit.light.estimator import SegmentEstimator, render_adaptive  # noqa: E402
from lightfit.plant import organ_class  # noqa: E402
from lightfit.plant.sheaths import SHEATHS  # noqa: E402
from lightfit.precision import use_float64  # noqa: E402

use_float64()  # lightfit's precision policy (lightfit.precision), before any JAX array exists

OUT = ROOT / "experiments" / "results" / "adaptive_switch_bias.json"
DNI, DHI = 1.0, 0.3
CONTROL_K = 256
#: The reference's projected rays per m² (sun, sky): 10 × the default, for the thin stems.
REF_RAYS = tuple(10 * x for x in DEFAULT_RAYS_PER_M2)
CLASSES = ("blade", "stem", "sheath", "canopy")


def main(
    n_plants: int,
    seeds: int,
    target: float,
    rays: list[float],
    max_samples: int,
    ref_samples: int,
    ref_seeds: int,
    out: Path,
) -> dict:
    console = wide_console()
    g, fs, ids, bounces = periodic_cell(n_plants)
    seg = g.segments.set_index("segment_id").loc[ids].reset_index()
    oc = organ_class(seg)
    masks = {c: (oc == c) if c != "canopy" else np.ones(len(ids), bool) for c in CLASSES}

    def totals(r):
        v = r.total("absorbed", DNI, DHI) * r.meta["area_m2"]
        return {c: float(v[m].sum()) for c, m in masks.items()}

    ref_runs = [
        totals(
            SegmentEstimator(
                fs,
                ids,
                samples=ref_samples,
                bounces=bounces,
                seed=1000 + s,
                direct="projection",
                direct_rays_per_m2=REF_RAYS,
            ).render()
        )
        for s in range(ref_seeds)
    ]
    ref = {c: float(np.mean([x[c] for x in ref_runs])) for c in CLASSES}
    ref_se = {c: float(np.std([x[c] for x in ref_runs], ddof=1) / math.sqrt(ref_seeds) / ref[c]) for c in CLASSES}
    console.print("reference done")

    def summary(xs):
        rel = {c: np.array([x[c] / ref[c] - 1.0 for x in xs]) for c in CLASSES}
        return {
            c: {"bias": float(r.mean()), "bias_se": float(r.std(ddof=1) / math.sqrt(len(r)))} for c, r in rel.items()
        }

    # The same adaptive rule with the paths' direct light (no projection, no switch): its own
    # sequential-stopping bias, which the switched segments carry too.
    paths = [
        totals(render_adaptive(fs, ids, target, bounces=bounces, seed=seed, max_samples=max_samples, direct="paths"))
        for seed in range(seeds)
    ]
    rows = []
    for rpm in rays:
        kw = {} if rpm == 0 else {"direct_rays_per_m2": rpm}
        adaptive, control, switched, evals = [], [], {c: [] for c in CLASSES}, []
        for seed in range(seeds):
            r = render_adaptive(
                fs, ids, target, bounces=bounces, seed=seed, max_samples=max_samples, direct="projection", **kw
            )
            adaptive.append(totals(r))
            for c, m in masks.items():
                switched[c].append(int((~r.meta["projected"][m]).sum()))
            evals.append(r.meta["n_evaluations"])
            c0 = SegmentEstimator(fs, ids, samples=CONTROL_K, bounces=bounces, seed=seed, direct="projection", **kw)
            control.append(totals(c0.render()))
        rows.append(
            {
                "rays_per_m2": list(DEFAULT_RAYS_PER_M2) if rpm == 0 else [rpm, rpm],
                "evaluations_mean": float(np.mean(evals)),
                "switched_mean": {c: float(np.mean(x)) for c, x in switched.items()},
                "adaptive": summary(adaptive),
                "control_fixed_k": summary(control),
            }
        )
        console.print(f"rays {rpm:g} done")
    res = {
        "n_plants": n_plants,
        "sheaths": SHEATHS[0],
        "target_rse": target,
        "max_samples": max_samples,
        "seeds": seeds,
        "control_samples": CONTROL_K,
        "reference_samples": ref_samples,
        "reference_seeds": list(range(1000, 1000 + ref_seeds)),
        "reference_rays_per_m2": list(REF_RAYS),
        "segments": {c: int(m.sum()) for c, m in masks.items()},
        "reference_absorbed_w": ref,
        "reference_relative_se": ref_se,
        "adaptive_paths": summary(paths),
        "rows": rows,
    }
    write_result(out, res, indent=1)
    t = Table(title=f"{n_plants}-plant cell, target {target:.0%}: class totals ÷ the reference − 1 ({seeds} seeds)")
    for c in ("rays per m² (sun, sky)", "run", "segments switched", *CLASSES):
        t.add_column(c, justify="right")
    for r in rows:
        sw = r["switched_mean"]
        for run in ("adaptive", "control_fixed_k"):
            t.add_row(
                "{:.3g}, {:.3g}".format(*r["rays_per_m2"]),
                run if run == "adaptive" else f"fixed K = {CONTROL_K}",
                " / ".join(f"{sw[c]:.0f}" for c in CLASSES) if run == "adaptive" else "",
                *(f"{r[run][c]['bias']:+.2%} ± {r[run][c]['bias_se']:.2%}" for c in CLASSES),
            )
    t.add_row(
        "—",
        "adaptive, paths",
        "",
        *(f"{res['adaptive_paths'][c]['bias']:+.2%} ± {res['adaptive_paths'][c]['bias_se']:.2%}" for c in CLASSES),
    )
    t.add_row("reference", "", "", *(f"± {ref_se[c]:.2%}" for c in CLASSES))
    console.print(t)
    console.print("segments (blade / stem / sheath / all): " + " / ".join(str(res["segments"][c]) for c in CLASSES))
    return res


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n-plants", type=int, default=4)
    ap.add_argument("--seeds", type=int, default=16)
    ap.add_argument("--target", type=float, default=0.1)
    ap.add_argument("--rays", type=float, nargs="+", default=[0, 1e6, 3e5, 1e5])
    ap.add_argument("--max-samples", type=int, default=1024)
    ap.add_argument("--ref-samples", type=int, default=1024)
    ap.add_argument("--ref-seeds", type=int, default=16)
    ap.add_argument("--out", type=Path, default=OUT)
    a = ap.parse_args()
    main(a.n_plants, a.seeds, a.target, a.rays, a.max_samples, a.ref_samples, a.ref_seeds, a.out)
