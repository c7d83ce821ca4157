"""Benchmark: loss-and-gradient cost, AD vs finite differences, and calibration time.

    python benchmarks/bench_calibration.py [--configs quick,default] [--calibrate quick]

For each configuration of the 20 April replication (quick: 4 plants, K=16, 2 bounces;
default: 100 plants, K=64, 3 bounces) on twin observations: time of one jitted loss evaluation,
of one loss + reverse-mode gradient over the three leaf parameters, and of a central
finite-difference gradient with the same fixed random numbers (equal accuracy: with frozen
sampling both differentiate the same smooth estimate). A full three-parameter calibration is
timed for the configurations given in ``--calibrate`` (others: estimated as measured time per
evaluation × the evaluations the quick calibration needed). Writes benchmarks/results/calibration.json.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from rich.console import Console
from rich.table import Table

import lightfit  # noqa: F401
from lightfit import replication as rep
from lightfit.inference.calibration import calibrate, make_loss, to_unconstrained
from lightfit.inference.twin import twin_observations
from lightfit.precision import use_float64

use_float64()  # lightfit's precision policy (lightfit.precision), before any JAX array exists

OUT = Path(__file__).resolve().parent / "results" / "calibration.json"
NAMES = ("specular", "roughness", "subsurface")


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


def main(configs=("quick", "default"), calibrate_in=("quick",)) -> list[dict]:
    cfgs = {"quick": rep.ReplicationConfig.quick(), "default": rep.ReplicationConfig()}
    rows = []
    for name in configs:
        evals = rows[0].get("calibration_steps") if rows else None
        rows.append(bench(name, cfgs[name], name in calibrate_in, evals))
        Console().print(rows[-1])
    OUT.parent.mkdir(parents=True, exist_ok=True)
    OUT.write_text(json.dumps(rows, indent=2))
    t = Table(title="calibration cost (2 CPU cores, one run)")
    for c in (
        "config",
        "segments",
        "daytime_steps",
        "loss_s",
        "loss_and_grad_s",
        "fd_grad_s",
        "fd_over_ad",
        "calibration_s",
        "calibration_s_estimated",
    ):
        t.add_column(c, justify="right")
    for r in rows:
        t.add_row(
            *(
                f"{r[c]:.3g}" if isinstance(r.get(c), float) else str(r.get(c, "–"))
                for c in (
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
            )
        )
    Console().print(t)
    return rows


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--configs", default="quick,default")
    ap.add_argument("--calibrate", default="quick")
    a = ap.parse_args()
    main(tuple(a.configs.split(",")), tuple(x for x in a.calibrate.split(",") if x))
