"""Benchmark: the two calibration optimisers side by side; loss-and-gradient cost, AD vs finite differences.

    python benchmarks/bench_calibration.py [--json JSON]        # optimisers (1.5–2.5 min on 2 cores)
    python benchmarks/bench_calibration.py --gradients quick,default [--calibrate quick] [--json JSON]

Every mode writes its tracked file under benchmarks/results/ (named below), or ``--json``.

**Optimisers** (default; writes benchmarks/results/calibration_optimisers.json): optimistix BFGS
on logit/log-transformed parameters (``method="bfgs"``) against jaxopt's box-constrained L-BFGS-B
on the natural parameters (``method="lbfgsb"``): same model, same twin observations (rendered
with another seed, 101, at specular 0.7, roughness 0.4, subsurface 0.6, plus noise), same start,
same step limit. Two problems, because full renders of the quick field cost ≈ 1–3 s per loss
evaluation on 2 shared cores:

1. ``emulated``: the quick configuration's whole day (25 daytime steps), renders replaced by a
   polynomial emulator fitted to full renders (``FastObservables``, exact photosynthesis), four
   parameters (specular, subsurface, light_factor, vcmax_scale; roughness fixed at its true 0.4:
   the emulator box starts at 0.3);
2. ``renders``: the quick field with full renders on a 3-hour window (7 daytime steps), specular
   alone from 0.3.

Reported per run: loss reached, accepted steps, loss and gradient evaluations, why it stopped,
wall time (including JIT compilation), and per problem the time ratio L-BFGS-B / BFGS.

**Gradients** (``--gradients``; writes benchmarks/results/calibration.json, the configurations under
``rows``): for each configuration
of the 20 April replication (quick: 4 plants, K=16, 2 bounces;
default: 100 plants, K=64, 3 bounces) on twin observations: time of one jitted loss evaluation,
of one loss + reverse-mode gradient over the three leaf parameters, and of a central
finite-difference gradient with the same fixed random numbers (equal accuracy: with frozen
sampling both differentiate the same smooth estimate). A full three-parameter calibration is
timed for the configurations given in ``--calibrate`` (others: estimated as measured time per
evaluation × the evaluations the quick calibration needed).

**Surrogate commands** (``--cli quick`` or ``--cli default [--max-minutes 14] [--posterior-after]
[--no-posterior] [--json PATH]``; writes benchmarks/results/calibration_cli_<config>.json or PATH):
the real ``lightfit calibrate`` and ``lightfit posterior`` commands as subprocesses on one
configuration, observations = the bundled chamber record (above-canopy sensor: informs only the
light factor) merged with the synthetic twin series (plant PAR + canopy An at the 25 daytime steps),
parameters specular, roughness, subsurface, light_factor. Timed in order, with a fresh
``LIGHTFIT_CACHE`` (so plants and design are cold): (1) calibrate cold, (2) the same calibrate again
into a new OUT (design cached), (3) posterior with another fresh cache (cold), stop rule with
``--target-ess 50`` and ``--max-minutes`` of sampling; with ``--posterior-after`` also the posterior
on the first cache after the calibration (design cached). Reported per stage: wall and CPU time,
load average before and after, new/cached renders and the full-render check (calibrate); for the
posterior the wall time at which a stop-rule check first had ESS ≥ 50 for every parameter, as
estimated and with τ reliable (n_kept ≥ 20 τ, the stop rule's length condition) (``run.h5`` polled
every 10 s), the stop reason, steps and ESS per parameter at the end.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import h5py
import jax
import jax.numpy as jnp
import numpy as np
from provenance import wide_console, write_result
from rich.table import Table

import lightfit  # noqa: F401
from lightfit import replication as rep
from lightfit.inference import mcmc as P
from lightfit.inference.calibration import METHODS, calibrate, make_loss, to_unconstrained
from lightfit.inference.twin import twin_observations
from lightfit.model import emulator as E
from lightfit.precision import use_float64

use_float64()  # lightfit's precision policy (lightfit.precision), before any JAX array exists

OUT = Path(__file__).resolve().parent / "results" / "calibration.json"
OUT_OPTIMISERS = OUT.with_name("calibration_optimisers.json")
NAMES = ("specular", "roughness", "subsurface")
TRUTH = {"specular": 0.7, "roughness": 0.4, "subsurface": 0.6}


def _best(f, n=2):
    f()
    ts = []
    for _ in range(n):
        t = time.perf_counter()
        f()
        ts.append(time.perf_counter() - t)
    return min(ts)


def bench(name: str, cfg, do_calibrate: bool, evals_per_calibration: int | None) -> dict:
    model = rep.model_for(cfg, rep.forcing())
    obs = twin_observations(
        model, {"specular": 0.7, "roughness": 0.4, "subsurface": 0.6}, render_seed=101, noise_seed=7
    )
    loss = make_loss(model, obs, NAMES)
    z = jnp.asarray([to_unconstrained(v, n) for v, n in zip((0.4, 0.6, 0.3), NAMES)])
    f = jax.jit(lambda z: loss(z)[0])
    vg = jax.jit(jax.value_and_grad(lambda z: loss(z)[0]))
    t_f = _best(lambda: float(f(z)))
    t_vg = _best(lambda: float(vg(z)[0]))
    h = 1e-3

    def fd():
        return [(float(f(z.at[i].add(h))) - float(f(z.at[i].add(-h)))) / (2 * h) for i in range(len(NAMES))]

    t_fd = _best(fd, 1)
    g_ad, g_fd = np.asarray(vg(z)[1]), np.asarray(fd())
    res = {
        "config": name,
        "segments": len(model.segment_id),
        "daytime_steps": int(model.day.sum()),
        "loss_s": t_f,
        "loss_and_grad_s": t_vg,
        "fd_grad_s": t_fd,
        "fd_over_ad": t_fd / t_vg,
        "grad_ad": g_ad.tolist(),
        "grad_fd": g_fd.tolist(),
    }
    if do_calibrate:
        r = calibrate(
            model,
            obs,
            names=NAMES,
            start={"specular": 0.4, "roughness": 0.6, "subsurface": 0.3},
            max_steps=30,
            progress=True,
        )
        res |= {
            "calibration_s": r.seconds,
            "calibration_steps": r.steps,
            "calibration_loss": r.loss,
            "calibration_theta": {k: r.theta[k] for k in NAMES},
        }
    elif evals_per_calibration:
        res["calibration_s_estimated"] = evals_per_calibration * t_vg
    return res


def compare(label: str, model, obs, names, start: dict, fixed: dict, forward=None, max_steps: int = 100) -> list[dict]:
    """Both optimisers on one problem; rows with the counts and times, the second with the time ratio."""
    rows = []
    for method in METHODS:
        r = calibrate(
            model,
            obs,
            names=names,
            start=start,
            fixed=fixed,
            method=method,
            forward=forward,
            max_steps=max_steps,
            progress=False,
        )
        rows.append(
            {
                "problem": label,
                "method": method,
                "parameters": list(names),
                "start": start,
                "theta": {n: r.theta[n] for n in names},
                "loss": r.loss,
                "accepted_steps": r.steps,
                "loss_evaluations": r.evaluations,
                "gradient_evaluations": r.gradients,
                "stopped_by": r.stopped_by,
                "seconds": r.seconds,
            }
        )
        wide_console().print(rows[-1])
    rows[1]["time_ratio_vs_bfgs"] = rows[1]["seconds"] / rows[0]["seconds"]
    rows[1]["loss_minus_bfgs"] = rows[1]["loss"] - rows[0]["loss"]
    return rows


def optimisers(n_design: int = 24) -> dict:
    """The side-by-side comparison described in the module docstring."""
    t0 = time.perf_counter()
    cfg = rep.ReplicationConfig.quick()
    day = rep.model_for(cfg, rep.forcing())
    obs = twin_observations(day, TRUTH, render_seed=101, noise_seed=7)
    t = time.perf_counter()
    emu = E.build_emulator(day, (0.0, 0.3, 0.0), (1.0, 1.0, 1.0), n_design=n_design, degrees=(2, 3, 4), seed=0)
    t_emu = time.perf_counter() - t
    fast = E.FastObservables(day, emu, n_grid=None)
    names = ("specular", "subsurface", "light_factor", "vcmax_scale")
    start = {"specular": 0.4, "subsurface": 0.3, "light_factor": 0.8, "vcmax_scale": 1.2}
    rows = compare("emulated", day, obs, names, start, {"roughness": TRUTH["roughness"]}, forward=fast)
    w = rep.forcing().loc["2016-04-20 09:00+00:00":"2016-04-20 12:00+00:00"]
    short = rep.model_for(cfg, w)
    obs_short = twin_observations(short, TRUTH, render_seed=101, noise_seed=7)
    fixed = {k: TRUTH[k] for k in ("roughness", "subsurface")}
    rows += compare("renders", short, obs_short, ("specular",), {"specular": 0.3}, fixed, max_steps=30)
    return {
        "machine": "2 CPU cores shared with other jobs; one run",
        "problems": {
            "emulated": f"quick field (4 plants, K=16, 2 bounces), 25 daytime steps; emulator degree {emu.degree} "
            f"from {n_design} full renders over specular [0,1], roughness [0.3,1], subsurface [0,1] "
            f"({t_emu:.0f} s to build); exact photosynthesis",
            "renders": "quick field, full renders, 09:00-12:00 UTC (7 daytime steps)",
        },
        "observations": "twin: render seed 101 (model: 0), truth specular 0.7, roughness 0.4, subsurface 0.6, "
        "light_factor 1, vcmax_scale 1; PAR SD 3 % (≥ 1), CO2 SD 1 µmol m-2 s-1, noise seed 7",
        "runs": rows,
        "seconds_total": time.perf_counter() - t0,
    }


def print_optimisers(res: dict) -> None:
    t = Table(title="calibration optimisers: BFGS (logit/log) vs L-BFGS-B (box), " + res["machine"])
    cols = ("problem", "method", "loss", "accepted_steps", "loss_evaluations", "gradient_evaluations")
    for c in (*cols, "stopped_by", "seconds", "time_ratio_vs_bfgs", "theta"):
        t.add_column(c.replace("_", " "), justify="right")
    for r in res["runs"]:
        t.add_row(
            *(f"{r[c]:.6g}" if isinstance(r[c], float) else str(r[c]) for c in cols),
            r["stopped_by"],
            f"{r['seconds']:.1f}",
            f"{r['time_ratio_vs_bfgs']:.2f}" if "time_ratio_vs_bfgs" in r else "–",
            " ".join(f"{k[:4]}={v:.4f}" for k, v in r["theta"].items()),
        )
    wide_console().print(t)


def main(configs=("quick", "default"), calibrate_in=("quick",), out: Path | None = None) -> list[dict]:
    cfgs = {"quick": rep.ReplicationConfig.quick(), "default": rep.ReplicationConfig()}
    rows = []
    for name in configs:
        evals = rows[0].get("calibration_steps") if rows else None
        rows.append(bench(name, cfgs[name], name in calibrate_in, evals))
        wide_console().print(rows[-1])
    write_result(out or OUT, {"rows": rows}, indent=2)
    t = Table(title="calibration cost (2 CPU cores, one run)")
    columns = (
        "config",
        "segments",
        "daytime_steps",
        "loss_s",
        "loss_and_grad_s",
        "fd_grad_s",
        "fd_over_ad",
        "calibration_s",
        "calibration_s_estimated",
    )
    for c in columns:
        t.add_column(c, justify="right")
    for r in rows:
        t.add_row(*(f"{r[c]:.3g}" if isinstance(r.get(c), float) else str(r.get(c, "–")) for c in columns))
    wide_console().print(t)
    return rows


def ess_checks(run_h5: Path, rule: P.StopRule = P.StopRule(target_ess=50.0)) -> dict:
    """The first stop-rule checks (step, ESS per parameter) at which every parameter had ESS ≥ 50:
    ``estimate`` whatever the chain's length; ``reliable`` also with n_kept ≥ 20 τ (the stop rule's
    length condition: early on τ is underestimated and ESS with it). Missing: not reached yet."""
    try:
        with h5py.File(run_h5, "r") as f:
            g = f["mcmc"]
            step, tau, ess = g["check_step"][:], g["check_tau"][:], g["check_ess"][:]
    except (OSError, KeyError):  # not written yet, or read while a step is written: try again later
        return {}
    kept = step - np.floor(rule.burn_fraction * step)
    ok = ess.min(axis=1) >= rule.target_ess
    reliable = ok & np.all(kept[:, None] >= rule.tau_multiple * tau, axis=1)
    return {
        k: {"step": int(step[i[0]]), "ess": ess[i[0]].tolist()}
        for k, i in (("estimate", np.flatnonzero(ok)), ("reliable", np.flatnonzero(reliable)))
        if len(i)
    }


def git_state() -> dict:
    """The commit measured and the tracked files changed in the working tree (another session's edit
    counts: the commands import lightfit from this checkout)."""
    import subprocess

    def git(*args):
        return subprocess.run(["git", *args], capture_output=True, text=True, cwd=OUT.parents[2]).stdout.strip()

    return {"commit": git("rev-parse", "HEAD"), "modified": git("diff", "--name-only", "HEAD").splitlines()}


def cli(
    config: str,
    n_design: int | None = None,
    max_minutes: float = 14.0,
    posterior_after: bool = False,
    posterior: bool = True,
    out: Path | None = None,
    calibrate: bool = True,
) -> dict:
    """The surrogate commands benchmark (see the module docstring)."""
    import os
    import resource
    import shutil
    import subprocess
    import sys
    import tempfile

    import pandas as pd

    from lightfit.inference.observations import read_observations

    work = Path(tempfile.mkdtemp(prefix="bench-cli-"))
    data = Path(rep.OBSERVATIONS).parent
    a, b = read_observations(rep.OBSERVATIONS), read_observations(data / "twin_2016-04-20_synthetic.csv")
    both = pd.concat([a, b]).sort_index()
    both.index = both.index.tz_convert("UTC").strftime("%Y-%m-%dT%H:%M:%SZ")
    obs = work / "chamber_plus_twin.csv"
    with open(obs, "w", encoding="utf-8") as fh:
        fh.write("# provenance: synthetic\n# note: bundled chamber record (measured) + synthetic twin series\n")
        both.to_csv(fh, index_label="time")
    size = ["--quick"] if config == "quick" else []
    names = "specular,roughness,subsurface,light_factor"
    design = [] if n_design is None else ["--n-design", str(n_design)]

    def run(args, cache, watch: Path | None = None) -> dict:
        """One command as a subprocess: wall and CPU seconds, load average before/after, its stdout; with
        ``watch`` (a run.h5) also the wall time when a stop-rule check first had ESS ≥ 50 per parameter."""
        env = {**os.environ, "LIGHTFIT_CACHE": str(cache), "COLUMNS": "200"}
        cpu0 = resource.getrusage(resource.RUSAGE_CHILDREN)
        load0 = os.getloadavg()
        t0 = time.perf_counter()
        p = subprocess.Popen(
            [sys.executable, "-m", "lightfit.cli", *args], env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE
        )
        first: dict = {}  # "estimate"/"reliable" → the check and the wall time it was first seen
        while watch is not None and p.poll() is None and len(first) < 2:
            time.sleep(10)
            for k, hit in ess_checks(watch).items():
                first.setdefault(k, hit | {"seconds": time.perf_counter() - t0})
        out, err = (s.decode() for s in p.communicate())
        dt = time.perf_counter() - t0
        cpu1 = resource.getrusage(resource.RUSAGE_CHILDREN)
        if p.returncode != 0:
            raise RuntimeError(out[-3000:] + err[-3000:])
        wide_console().print(out[-2500:])
        cpu = cpu1.ru_utime + cpu1.ru_stime - cpu0.ru_utime - cpu0.ru_stime
        rec = {"wall_s": dt, "cpu_s": cpu, "loadavg_before": load0, "loadavg_after": os.getloadavg()}
        if watch is not None:  # the posterior prints "design: N new renders, M from the cache (...)"
            line = next((x for x in out.splitlines() if x.startswith("design:")), "")
            rec["design_line"] = line
            rec["first_check_ess_ge_50"] = ess_checks(watch) | first  # those seen after the end: no time
        return rec

    # L-BFGS-B: BFGS's first step on log(light_factor) with an identity Hessian jumps by the raw gradient
    # (≈ 1e4 here, loss ≈ 7e3 at the start) to an infinite light factor and its linear solve gets NaN
    cal = ["calibrate", str(obs), *size, *design, "--parameters", names, "--method", "lbfgsb"]
    post = ["posterior", str(obs), *size, *design, "--parameters", names, "--target-ess", "50"]
    post += ["--max-minutes", str(max_minutes)]
    res = {
        "command": f"python benchmarks/bench_calibration.py --cli {config}"
        + ("" if n_design is None else f" --design {n_design}")
        + f" --max-minutes {max_minutes:g}"
        + (" --posterior-after" if posterior_after else "")
        + ("" if posterior else " --no-posterior")
        + ("" if calibrate else " --no-calibrate")
        + ("" if out is None else f" --json {out}"),
        "config": config,
        "machine": f"{os.cpu_count()} CPU cores; load average recorded before/after each stage; one run",
        "observations": "chamber record + synthetic twin (plant_par, canopy_an)",
        "parameters": names.split(","),
        "goals": "issue 15: calibrate <= 15 min cold, <= 5 min cached, full-render check passed; "
        "posterior >= 50 effective samples per parameter in <= 20 min cold",
        "git": git_state(),
    }
    if calibrate:
        res["calibrate_cold"] = run([*cal, "--out", str(work / "cal1")], work / "cache")
        res["calibrate_cached"] = run([*cal, "--out", str(work / "cal2")], work / "cache")
        c = json.loads((work / "cal1" / "calibration.json").read_text())
        c2 = json.loads((work / "cal2" / "calibration.json").read_text())
        for key, rec in (("calibrate_cold", c), ("calibrate_cached", c2)):
            s = rec["surrogate"]
            res[key] |= {
                "renders_new": s["renders_new"],
                "renders_cached": s["renders_cached"],
                "check_passed": s["passed"],
                "rounds": len(s["rounds"]),
            }
        res["calibration"] = {k: c[k] for k in ("theta", "loss", "steps", "stopped_by")} | {
            "check": {k: v for k, v in c["surrogate"].items() if k != "rounds"},
            "rounds": c["surrogate"]["rounds"],
        }
    else:
        res["calibrate_cold"] = res["calibrate_cached"] = "not run (--no-calibrate)"
    stages = [("posterior_cold", work / "cache_cold", "post_cold")] if posterior else []
    if not posterior:
        res["posterior_cold"] = "not run (--no-posterior)"
    if posterior_after:
        stages.insert(0, ("posterior_after_calibrate", work / "cache", "post_after"))
    for key, cache, tag in stages:
        res[key] = run([*post, "--out", str(work / tag)], cache, watch=work / tag / "run.h5")
        sm = json.loads((work / tag / "summary.json").read_text())
        res[key] |= {k: sm.get(k) for k in ("names", "stopped_by", "n_steps", "ess", "tau", "seconds_sampling")}
        res[key]["min_ess"] = float(np.min(sm["ess"]))
    out = out or OUT.with_name(f"calibration_cli_{config}.json")
    write_result(out, res, indent=2, default=str)
    print_cli(res)
    shutil.rmtree(work)  # caches and outputs: ≈ 4 GB on the default configuration, summarised in the JSON
    return res


def print_cli(res: dict) -> None:
    """The table of ``cli``'s stages (wall and CPU minutes, renders, check / ESS, load average)."""
    t = Table(title=f"lightfit calibrate / posterior on the emulator ({res['config']}; {res['machine']})")
    for col in ("stage", "wall min", "CPU min", "load before→after", "notes"):
        t.add_column(col)
    for key, label in (
        ("calibrate_cold", "calibrate, cold cache"),
        ("calibrate_cached", "calibrate, design cached"),
        ("posterior_after_calibrate", "posterior after calibrate"),
        ("posterior_cold", "posterior, cold cache"),
    ):
        r = res.get(key)
        if r is None:
            continue
        if isinstance(r, str):
            t.add_row(label, "–", "–", "–", r)
            continue
        if key.startswith("calibrate"):
            note = f"{r['renders_new']} new + {r['renders_cached']} cached renders, {r['rounds']} rounds; check "
            note += "passed" if r["check_passed"] else "NOT passed"
        else:
            first = r.get("first_check_ess_ge_50", {})
            when = "; ".join(
                f"ESS ≥ 50 ({k}) at step {c['step']}" + (f", {c['seconds'] / 60:.1f} min" if "seconds" in c else "")
                for k, c in first.items()
            )
            when = when or "ESS < 50"
            note = f"{r['design_line'][8:].split(' (')[0]}; {when}; stopped: {r['stopped_by']} at step "
            note += f"{r['n_steps']}, ESS " + ", ".join(f"{n[:4]} {e:.0f}" for n, e in zip(r["names"], r["ess"]))
        load = f"{r['loadavg_before'][0]:.1f}→{r['loadavg_after'][0]:.1f}"
        t.add_row(label, f"{r['wall_s'] / 60:.1f}", f"{r['cpu_s'] / 60:.1f}", load, note)
    wide_console().print(t)


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--gradients", default=None, help="configurations for the gradient-cost benchmark, e.g. quick")
    ap.add_argument("--calibrate", default="quick", help="with --gradients: also time a BFGS calibration here")
    ap.add_argument("--n-design", type=int, default=24, help="full renders for the emulator (optimisers)")
    ap.add_argument("--cli", default=None, help="time the surrogate calibrate/posterior commands: quick or default")
    ap.add_argument("--design", type=int, default=None, help="with --cli: --n-design (default: the shared size)")
    ap.add_argument("--max-minutes", type=float, default=14.0, help="with --cli: posterior's sampling budget")
    ap.add_argument("--posterior-after", action="store_true", help="with --cli: also the posterior after calibrate")
    ap.add_argument("--no-posterior", action="store_true", help="with --cli: calibrate cold and cached only")
    ap.add_argument("--no-calibrate", action="store_true", help="with --cli: the cold posterior only")
    ap.add_argument(
        "--json",
        type=Path,
        default=None,
        help="JSON to write (default the mode's tracked result the docs cite, in benchmarks/results/: "
        "calibration_optimisers.json, with --gradients calibration.json, with --cli calibration_cli_<config>.json)",
    )
    a = ap.parse_args()
    if a.cli:
        cli(a.cli, a.design, a.max_minutes, a.posterior_after, not a.no_posterior, a.json, not a.no_calibrate)
    elif a.gradients:
        main(tuple(a.gradients.split(",")), tuple(x for x in a.calibrate.split(",") if x), a.json)
    else:
        res = optimisers(a.n_design)
        write_result(a.json or OUT_OPTIMISERS, res, indent=2)
        print_optimisers(res)
