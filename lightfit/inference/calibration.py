r"""Gradient calibration of leaf surface (and optionally light and Vcmax) parameters.

Loss: Gaussian negative log-likelihood over the observed steps,

.. math:: \mathcal L(\theta) = \tfrac12 \sum_{k \in obs} \frac{(y_k - m_k(\theta))^2}{\sigma_k^2 + s_k^2}

with the measurement SD σ_k and the model's Monte Carlo SD s_k (treated as a constant in the
gradient). Parameters are optimised unconstrained: logit for those in [0, 1], log for positive
ones. Optimiser: optimistix BFGS (gradient by reverse mode through the Mitsuba bridge and the
implicit photosynthesis solve), driven step by step so that every accepted step is shown in a
progress display and appended to a JSON-lines history; ``resume=True`` restarts from the best
point of an existing history (finished work is never lost; the BFGS Hessian approximation is
rebuilt).
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from lightfit.errors import InputError
from lightfit.inference.observations import align
from lightfit.model.coupled import DEFAULT_THETA, PARAMETERS, CoupledModel


def to_unconstrained(value: float, name: str) -> float:
    lo, hi = PARAMETERS[name]
    if hi is None:
        return math.log(value)
    v = min(max(value, 1e-6), 1 - 1e-6)
    return math.log(v / (1 - v))


def from_unconstrained(z, name: str):
    lo, hi = PARAMETERS[name]
    return jnp.exp(z) if hi is None else jax.nn.sigmoid(z)


def make_loss(model: CoupledModel, obs, names: tuple[str, ...], fixed: dict | None = None):
    """``loss(z) -> (value, aux)`` over the unconstrained parameters ``z`` (one per name)."""
    unknown = [n for n in names if n not in PARAMETERS]
    if unknown:
        raise InputError(f"unknown parameter(s) {unknown}", column="parameters", expected=", ".join(PARAMETERS))
    target = align(obs, model.times)
    have = {k: ~np.isnan(v) for k, v in target.items()}
    if not (have["par_umol_m2_s"].any() or have["an_umol_m2_s"].any()):
        raise InputError(
            "no observation falls on a simulated step",
            file=obs.attrs.get("source"),
            expected="PAR or net CO2 observations within the run",
        )
    y = {k: jnp.asarray(np.nan_to_num(v)) for k, v in target.items()}
    mask = {k: jnp.asarray(v) for k, v in have.items()}
    base = {**DEFAULT_THETA, **(fixed or {})}

    def theta_of(z):
        return {**base, **{n: from_unconstrained(z[i], n) for i, n in enumerate(names)}}

    def loss(z, args=None):
        m = model.observe(theta_of(z))
        total = 0.0
        for v, sd, mc in (
            ("par_umol_m2_s", "par_sd_umol_m2_s", "par_mc_var"),
            ("an_umol_m2_s", "an_sd_umol_m2_s", "an_mc_var"),
        ):
            var = y[sd] ** 2 + m[mc]
            r2 = jnp.where(mask[v], (y[v] - m[v]) ** 2 / jnp.where(mask[v], var, 1.0), 0.0)
            total = total + 0.5 * jnp.sum(r2)
        return total, None

    loss.theta_of = theta_of
    loss.n_observations = int(have["par_umol_m2_s"].sum() + have["an_umol_m2_s"].sum())
    return loss


@dataclass
class CalibrationResult:
    """Outcome: best parameters, loss, steps taken, convergence flag, history file."""

    theta: dict
    loss: float
    steps: int
    converged: bool
    history: Path | None
    seconds: float


def _read_history(path: Path) -> list[dict]:
    if not path.exists():
        return []
    out = []
    for line in path.read_text(encoding="utf-8").splitlines():
        try:
            out.append(json.loads(line))
        except json.JSONDecodeError:
            break  # a line cut by an interruption; everything before it is intact
    return out


def calibrate(
    model: CoupledModel,
    obs,
    *,
    names=("specular", "roughness", "subsurface"),
    start: dict | None = None,
    fixed: dict | None = None,
    max_steps: int = 30,
    rtol: float = 1e-4,
    atol: float = 1e-4,
    history: str | Path | None = None,
    resume: bool = True,
    progress: bool = True,
) -> CalibrationResult:
    """Minimise the loss over ``names`` with optimistix BFGS; see the module docstring.

    Args:
        start: starting values (defaults: :data:`DEFAULT_THETA`).
        fixed: values of the parameters not calibrated.
        history: JSON-lines file; one line per accepted step (step, loss, theta, gradient, time).
        resume: continue from the best point in ``history`` if it exists.
    """
    names = tuple(names)
    loss = make_loss(model, obs, names, fixed)
    th0 = {**DEFAULT_THETA, **(fixed or {}), **(start or {})}
    past: list[dict] = []
    hist = Path(history) if history else None
    if hist and resume:
        past = _read_history(hist)
        if past:
            best = min(past, key=lambda r: r["loss"])
            th0 = {**th0, **{n: best["theta"][n] for n in names}}
    elif hist and hist.exists():
        hist.unlink()
    z0 = jnp.asarray([to_unconstrained(float(th0[n]), n) for n in names], jnp.float64)
    solver = optx.BFGS(rtol=rtol, atol=atol)
    fn = jax.jit(loss)
    f_struct = jax.ShapeDtypeStruct((), jnp.float64)
    options: dict = {"autodiff_mode": "bwd"}
    state = solver.init(fn, z0, None, options, f_struct, None, frozenset())
    z = z0
    t0 = time.perf_counter()
    step0 = len(past)
    best_loss, best_z = math.inf, z0
    converged = False
    bar = None
    if progress:
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

        bar = Progress(
            TextColumn("calibrating"),
            BarColumn(),
            MofNCompleteColumn(),
            TimeElapsedColumn(),
            TextColumn("{task.fields[info]}"),
        )
        task = bar.add_task("cal", total=max_steps, info="")
        bar.start()
    try:
        accepted = int(state.num_accepted_steps)
        for k in range(max_steps):
            z, state, _ = solver.step(fn, z, None, options, state, frozenset())
            done, result = solver.terminate(fn, z, None, options, state, frozenset())
            if int(state.num_accepted_steps) == accepted and not bool(done):
                continue  # a rejected line-search trial: nothing new to record
            accepted = int(state.num_accepted_steps)
            # f_info holds the loss and gradient at the accepted point z.
            f, g = float(state.f_info.f), state.f_info.grad
            theta = {n: float(from_unconstrained(z[i], n)) for i, n in enumerate(names)}
            if f < best_loss:
                best_loss, best_z = f, z
            if hist:
                hist.parent.mkdir(parents=True, exist_ok=True)
                with open(hist, "a", encoding="utf-8") as fh:
                    fh.write(
                        json.dumps(
                            {
                                "step": step0 + k + 1,
                                "loss": f,
                                "theta": theta,
                                "grad_unconstrained": [float(x) for x in np.asarray(g)],
                                "seconds": time.perf_counter() - t0,
                            }
                        )
                        + "\n"
                    )
            if bar:
                bar.update(
                    task,
                    completed=k + 1,
                    info=f"loss {f:.4g}  " + " ".join(f"{n[:4]}={v:.3f}" for n, v in theta.items()),
                )
            if bool(done):
                converged = bool(result == optx.RESULTS.successful)
                break
    finally:
        if bar:
            bar.stop()
    theta = {
        **DEFAULT_THETA,
        **(fixed or {}),
        **{n: float(from_unconstrained(best_z[i], n)) for i, n in enumerate(names)},
    }
    if past and min(r["loss"] for r in past) < best_loss:
        b = min(past, key=lambda r: r["loss"])
        theta = {**theta, **b["theta"]}
        best_loss = b["loss"]
    return CalibrationResult(theta, best_loss, len(past) + k + 1, converged, hist, time.perf_counter() - t0)
