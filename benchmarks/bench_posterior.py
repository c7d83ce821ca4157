"""Benchmark: posterior sampling of the default 20 April 2016 configuration on the available cores.

    .venv/bin/python benchmarks/bench_posterior.py [--renders DIR] [--n-design 16] [--n-test 2]
        [--walkers 32] [--max-steps 20000] [--out H5] [--json JSON]

The main job's configuration (``ReplicationConfig()``: its field, K, bounces and observable; the
JSON's ``config`` records them), bundled chamber record, informed priors, sampled: specular,
roughness, subsurface, light_factor. Steps and what is timed:

1. full render passes (the daytime steps) at a Sobol design over the prior box and at held-out
   points — cached one file per render in DIR/designs/<hash of the render key>/bench_renders, so
   an interrupted benchmark loses no render and another configuration never reads them;
2. emulator fit (LOO-chosen degree) and its error at the held-out renders;
3. emcee (32 walkers) until the stop rule (ESS ≥ 50 per parameter, n_kept ≥ 20 τ, stable τ);
4. the analysis (optimum, Fisher, profile, predictive, emulator error vs posterior width).

Writes benchmarks/results/posterior.json (or ``--json``; the chain goes to ``--out``).
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from pathlib import Path

from lightfit.precision import use_float64

use_float64()  # lightfit's precision policy (lightfit.precision), before any JAX array exists

import numpy as np  # noqa: E402
from provenance import write_result  # noqa: E402  (same script folder)

from lightfit.inference import mcmc as P  # noqa: E402
from lightfit.inference import posterior as A  # noqa: E402
from lightfit.inference.observations import read_observations  # noqa: E402
from lightfit.light.bsdf import LEAF_PARAMETERS  # noqa: E402
from lightfit.model import emulator as E  # noqa: E402
from lightfit.replication import OBSERVATIONS, ReplicationConfig, forcing, model_for  # noqa: E402
from lightfit.report import field_label  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]

NAMES = ("specular", "roughness", "subsurface", "light_factor")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--renders", type=Path, default=ROOT / "results" / "posterior" / "default_renders")
    ap.add_argument("--n-design", type=int, default=16)
    ap.add_argument("--n-test", type=int, default=2)
    ap.add_argument("--walkers", type=int, default=32)
    ap.add_argument("--max-steps", type=int, default=20000, help="emcee steps at most (the stop rule may end sooner)")
    ap.add_argument(
        "--out", type=Path, default=ROOT / "results" / "posterior" / "bench_default.h5", help="the chain (HDF5)"
    )
    ap.add_argument(
        "--json",
        type=Path,
        default=ROOT / "benchmarks" / "results" / "posterior.json",
        help="JSON to write (default benchmarks/results/posterior.json, the tracked result the docs cite)",
    )
    args = ap.parse_args(argv)
    pri = P.PRIORS_INFORMED
    lo = [pri[n].support[0] for n in LEAF_PARAMETERS]
    hi = [pri[n].support[1] for n in LEAF_PARAMETERS]
    t = time.perf_counter()
    cfg = ReplicationConfig()
    model = model_for(cfg, forcing())
    t_build = time.perf_counter() - t
    d = E.design_dir(model, args.renders) / "bench_renders"  # keyed by everything a render depends on
    d.mkdir(parents=True, exist_ok=True)
    design = E.sobol_design(16, lo, hi, 0)
    test = E.sobol_design(4, lo, hi, 1)[:3]
    if args.n_design > 16:
        design = E.sobol_design(args.n_design, lo, hi, 0)
    seconds = []

    def get(name, i, x):
        f = d / f"{name}_{i:02d}.npz"
        if not f.exists():
            t0 = time.perf_counter()
            v, s = E.render_parts(model, x[None])
            np.savez(f, values=v[0], se=s[0], x=x, seconds=time.perf_counter() - t0)
        z = np.load(f)
        assert np.allclose(z["x"], x), f"{f} was rendered at another point"
        seconds.append(float(z["seconds"]))
        return z["values"], z["se"]

    dv = [get("design", i, x) for i, x in enumerate(design[: args.n_design])]
    tv = [get("test", i, x) for i, x in enumerate(test[: args.n_test])]
    t = time.perf_counter()
    emu = E.fit_emulator(
        design[: args.n_design],
        np.stack([v for v, _ in dv]),
        np.stack([s for _, s in dv]),
        lo,
        hi,
        degrees=(1, 2, 3),
        render_seconds=float(np.sum(seconds[: args.n_design])),
    )
    t_fit = time.perf_counter() - t
    obs = read_observations(OBSERVATIONS)
    fast = E.FastObservables(model, emu)
    lp = P.LogPosterior.of_model(fast, model, obs, NAMES, pri)
    xs = lp.initial(args.walkers // 2, 0)
    lp(xs)
    t = time.perf_counter()
    for _ in range(5):
        lp(xs)
    t_lp = (time.perf_counter() - t) / 5
    res = A.run(
        model,
        obs,
        emu,
        args.out,
        names=NAMES,
        priors=pri,
        nwalkers=args.walkers,
        max_steps=args.max_steps,
        seed=0,
        resume=False,
        stop=P.StopRule(target_ess=50),
        progress=True,
        validation_renders=(test[: args.n_test], (np.stack([v for v, _ in tv]), np.stack([s for _, s in tv]))),
    )
    out = {
        "command": " ".join(["bench_posterior.py", *(sys.argv[1:] if argv is None else argv)]),
        "machine": {"cpus": os.cpu_count(), "platform": platform.platform(), "processor": platform.processor()},
        "config": f"ReplicationConfig() default: {cfg.n_plants} plants, {field_label(cfg.field())}, "
        f"K={model.scenario.samples}, {model.scenario.bounces} bounces, {cfg.par_kind} PAR; "
        "bundled chamber record; informed priors",
        "render_key": E.render_key(model),
        "n_segments": int(len(model.segment_id)),
        "n_blades": int(model.is_blade.sum()),
        "daytime_steps": int(model.day.sum()),
        "model_build_s": t_build,
        "full_render_pass_s": {
            "median": float(np.median(seconds)),
            "min": float(np.min(seconds)),
            "max": float(np.max(seconds)),
            "n": len(seconds),
        },
        "emulator": {
            "n_design": args.n_design,
            "degree": emu.degree,
            "loo_rms": emu.loo_rms,
            "design_render_s": emu.render_seconds,
            "fit_s": t_fit,
        },
        "log_prob_half_ensemble_s": t_lp,
        "walkers": args.walkers,
        "sampling": {k: res[k] for k in ("stopped_by", "n_steps", "tau", "ess", "acceptance_mean", "seconds_sampling")},
        "min_ess_per_parameter": float(np.min(res["ess"])),
        "analysis_s": res["seconds_total"] - res["seconds_sampling"],
        "emulator_error": res.get("emulator_error"),
        "posterior": {"mean": res["mean"], "sd": res["sd"], "stiff": res["stiff"], "sloppy": res["sloppy"]},
        "note": "The full render passes are counted separately from sampling: the emulator is built once per "
        "configuration (and cached), then every posterior run (other data, priors, seeds) reuses it; "
        "their times are those of the first run that rendered them (stored with each render in DIR).",
    }
    print(write_result(args.json, P.jsonable(out), indent=2, default=str).read_text())


if __name__ == "__main__":
    main()
