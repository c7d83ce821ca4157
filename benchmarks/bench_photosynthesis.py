"""Benchmark of lightfit.photosynthesis: segments per second (forward and gradient),
cost of the robust solver over plain fixed-point iteration, and speed against CPlantBox's
C++ photosynthesis at matched accuracy. All ratios come from one run of this script.

    python benchmarks/bench_photosynthesis.py [--max-segments 1000000] [--repeats 3] [--out JSON]

Writes benchmarks/results/photosynthesis.json (or ``--out``) and prints a Markdown table.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from pathlib import Path

os.environ.setdefault("JAX_PLATFORMS", "cpu")

import jax  # noqa: E402

# float64 is lightfit's precision; the float32 timings pass float32 arrays explicitly.
from lightfit.precision import use_float64  # noqa: E402

use_float64()  # lightfit's precision policy (lightfit.precision), before any JAX array exists

import equinox as eqx  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
from provenance import out_option, write_result  # noqa: E402  (same script folder)

import lightfit.photosynthesis as ps  # noqa: E402
from lightfit.photosynthesis import model as psm  # noqa: E402

RESULTS = Path(__file__).parent / "results" / "photosynthesis.json"


def inputs(n, dtype, seed=0):
    rng = np.random.default_rng(seed)
    par = rng.uniform(0, 2000, n)
    t = rng.uniform(5, 35, n)
    co2 = rng.uniform(250, 800, n)
    rh = rng.uniform(0.3, 0.9, n)
    return tuple(x.astype(dtype) for x in (par, t, co2, rh))


def best_time(fn, repeats):
    jax.block_until_ready(fn())  # compile + warm up
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(fn())
        times.append(time.perf_counter() - t0)
    return min(times)


def bench_solve(n, dtype, params, gb, repeats):
    par, t, co2, rh = inputs(n, dtype)
    env, q = psm.prepare_environment(par, t, co2, rh, 101.325, params, gb_mol_m2_s=gb)
    cfg = ps.SolverConfig.for_dtype(dtype)
    fwd = jax.jit(lambda e, p: psm._solve_impl(e, p, cfg))
    plain = jax.jit(lambda e, p: psm._plain_impl(e, p, cfg))

    def loss(par_, vcmax, e, p):
        e = e._replace(par_abs_umol_m2_s=par_)
        p = eqx.tree_at(lambda r: r.fvcb.vcmax_ref_umol_m2_s, p, vcmax)
        return jnp.sum(psm._solve_impl(e, p, cfg).an_umol_m2_s)

    grad = jax.jit(jax.grad(loss, argnums=(0, 1)))
    vc = q.fvcb.vcmax_ref_umol_m2_s
    out = fwd(env, q)
    row = {
        "segments": n,
        "dtype": np.dtype(dtype).name,
        "closure": params.stomata.model,
        "forward_s": best_time(lambda: fwd(env, q), repeats),
        "gradient_s": best_time(lambda: grad(env.par_abs_umol_m2_s, vc, env, q), repeats),
        "converged_fraction": float(np.mean(np.asarray(out.converged))),
        "mean_iterations": float(np.mean(np.asarray(out.iterations))),
        "max_iterations": int(np.max(np.asarray(out.iterations))),
    }
    if params.stomata.model != "cplantbox":
        pl = plain(env, q)
        row["plain_s"] = best_time(lambda: plain(env, q), repeats)
        row["plain_converged_fraction"] = float(np.mean(np.asarray(pl.converged)))
        row["robust_over_plain"] = row["forward_s"] / row["plain_s"]
    row["forward_segments_per_s"] = n / row["forward_s"]
    row["gradient_segments_per_s"] = n / row["gradient_s"]
    return row


def bench_peer(n_points, repeats):
    from lightfit.photosynthesis.cplantbox_peer import run_cplantbox

    params = ps.parameter_set("cplantbox")
    par, t, co2, _ = inputs(n_points, np.float64, seed=1)
    peer = run_cplantbox(par, t, co2, params)
    res = ps.solve(par, t, co2, 0.6, 101.325, params, fw=peer.fw)
    err = np.abs(np.asarray(res.an_umol_m2_s) - peer.an_umol_m2_s)
    rel = err / np.maximum(np.abs(peer.an_umol_m2_s), 0.05)
    cpb_per_seg = peer.solve_seconds / n_points
    rows = {}
    for dtype in (np.float64, np.float32):
        env, q = psm.prepare_environment(
            *(x.astype(dtype) for x in (par, t, co2)), 0.6, 101.325, params, fw=peer.fw.astype(dtype)
        )
        cfg = ps.SolverConfig.for_dtype(dtype)
        fwd = jax.jit(lambda e, p: psm._solve_impl(e, p, cfg))
        r = fwd(env, q)
        e = np.abs(np.asarray(r.an_umol_m2_s, float) - peer.an_umol_m2_s)
        s = best_time(lambda: fwd(env, q), repeats)
        rows[np.dtype(dtype).name] = {
            "jax_s_per_segment": s / n_points,
            "speed_ratio_vs_cplantbox": cpb_per_seg / (s / n_points),
            "max_abs_err_umol_m2_s": float(e.max()),
            "max_rel_err_above_0p05": float((e / np.maximum(np.abs(peer.an_umol_m2_s), 0.05)).max()),
        }
    # Same number of segments in one big JAX call: CPlantBox's per-solve size is fixed by
    # its plant, JAX amortises over many segments.
    big = 100_000
    bp, bt, bc, _ = inputs(big, np.float64, seed=2)
    env, q = psm.prepare_environment(bp, bt, bc, 0.6, 101.325, params)
    cfg = ps.SolverConfig.for_dtype(np.float64)
    fwd = jax.jit(lambda e, p: psm._solve_impl(e, p, cfg))
    s_big = best_time(lambda: fwd(env, q), repeats) / big
    return {
        "points": n_points,
        "cplantbox_solves": peer.n_solves,
        "cplantbox_blade_segments_per_solve": peer.blade_segments,
        "cplantbox_s_per_segment": cpb_per_seg,
        "max_abs_err_umol_m2_s": float(err.max()),
        "max_rel_err_above_0p05": float(rel.max()),
        "same_points": rows,
        "jax_float64_s_per_segment_at_1e5": s_big,
        "speed_ratio_vs_cplantbox_at_1e5": cpb_per_seg / s_big,
    }


def progress(r: dict) -> str:
    """One finished row as a line (the table comes at the end)."""
    return (
        f"{r['closure']} {r['dtype']}, {r['segments']:,} segments: forward {r['forward_segments_per_s']:.3g} seg/s, "
        f"gradient {r['gradient_segments_per_s']:.3g} seg/s, {r['converged_fraction']:.1%} converged"
    )


def table(rows, peer):
    lines = [
        "| closure | dtype | segments | forward seg/s | gradient seg/s | mean / max iters "
        "| robust ÷ plain time | plain converged |",
        "|---|---|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        # The closed form (cplantbox) has no plain iteration to compare with.
        plain = (
            f"{r['robust_over_plain']:.2f} | {r['plain_converged_fraction']:.3f}"
            if "plain_s" in r
            else "— (closed form) | —"
        )
        lines.append(
            f"| {r['closure']} | {r['dtype']} | {r['segments']:.0e} | {r['forward_segments_per_s']:.3g} | "
            f"{r['gradient_segments_per_s']:.3g} | {r['mean_iterations']:.1f} / {r['max_iterations']} | {plain} |"
        )
    lines.append("")
    lines.append(
        f"CPlantBox C++ (`Photosynthesis.solve_photosynthesis`, incl. its xylem solve): "
        f"{peer['cplantbox_s_per_segment'] * 1e6:.1f} µs per leaf-blade segment "
        f"({peer['cplantbox_blade_segments_per_solve']} blade segments per solve, {peer['points']} points)."
    )
    for dt, r in peer["same_points"].items():
        lines.append(
            f"lightfit {dt} on the same {peer['points']} points: {r['jax_s_per_segment'] * 1e6:.3f} µs/segment, "
            f"{r['speed_ratio_vs_cplantbox']:.0f}× faster; max |ΔAn| = {r['max_abs_err_umol_m2_s']:.2g} µmol m⁻² s⁻¹, "
            f"max rel = {r['max_rel_err_above_0p05']:.2g}."
        )
    lines.append(
        f"lightfit float64 at 1e5 segments per call: {peer['jax_float64_s_per_segment_at_1e5'] * 1e6:.3f} µs/segment, "
        f"{peer['speed_ratio_vs_cplantbox_at_1e5']:.0f}× CPlantBox per segment."
    )
    return "\n".join(lines)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--max-segments", type=int, default=1_000_000)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--peer-points", type=int, default=2200)
    out_option(ap, RESULTS)
    args = ap.parse_args(argv)

    sizes = [n for n in (1_000, 10_000, 100_000, 1_000_000) if n <= args.max_segments]
    coupled = ps.parameter_set("giraud2023_coupled")
    cpb = ps.parameter_set("cplantbox")
    rows = []
    for n in sizes:
        for dtype in (np.float64, np.float32):
            rows.append(bench_solve(n, dtype, coupled, 1.0, args.repeats))
            print(progress(rows[-1]), file=sys.stderr)
        rows.append(bench_solve(n, np.float64, cpb, None, args.repeats))
        print(progress(rows[-1]), file=sys.stderr)
    peer = bench_peer(args.peer_points, args.repeats)
    result = {
        "command": "python benchmarks/bench_photosynthesis.py " + " ".join(argv if argv is not None else sys.argv[1:]),
        "machine": {
            "platform": platform.platform(),
            "cpus": os.cpu_count(),
            "jax": jax.__version__,
            "backend": jax.default_backend(),
        },
        "inputs": "uniform PAR 0-2000 µmol m-2 s-1, T 5-35 °C, CO2 250-800 ppm, RH 0.3-0.9; "
        "coupled rows: giraud2023_coupled with gb = 1 mol m-2 s-1; cplantbox rows: closed form",
        "rows": rows,
        "peer": peer,
    }
    write_result(args.out, result, indent=2)
    print(table(rows, peer))


if __name__ == "__main__":
    main()
