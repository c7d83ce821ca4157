r"""Gradient calibration of leaf surface (and optionally light and Vcmax) parameters.

Loss: the calibration loss of :class:`~lightfit.inference.likelihood.GaussianLikelihood`,

.. math:: \mathcal L(\theta) = \tfrac12 \sum_{k \in obs} \frac{(y_k - m_k(\theta))^2}{\sigma_k^2 + s_k^2}

(measurement SD σ_k, the model's Monte Carlo SD s_k, treated as a constant in the gradient).
Gradients by reverse mode through the Mitsuba bridge and the implicit photosynthesis solve. Two
optimisers, chosen by ``method``:

- ``"bfgs"`` (default): optimistix BFGS on unconstrained coordinates z — logit for parameters in
  [0, 1], log for positive ones (:func:`to_unconstrained`);
- ``"lbfgsb"``: jaxopt's box-constrained L-BFGS-B on the natural parameters within
  :data:`lightfit.model.parameters.BOUNDS` (an infinite upper bound stays infinite). Both keep a
  margin of 1e-6 from finite bounds (the logit cannot reach them either; at roughness 0 the GGX
  lobe is a mirror and the estimator's variance is unbounded).

Both are driven step by step, so that every accepted step is shown in a progress display and
appended to a JSON-lines history; ``resume=True`` restarts from the best point of an existing
history (finished work is never lost; the quasi-Newton Hessian approximation is rebuilt). The
result counts accepted steps, loss evaluations and gradient evaluations separately, and says why
the optimiser stopped.
"""

from __future__ import annotations

import json
import math
import time
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
import pandas as pd

from lightfit.errors import InputError
from lightfit.inference.likelihood import USES, GaussianLikelihood
from lightfit.inference.progress import progress_bar
from lightfit.model.coupled import CoupledModel
from lightfit.model.parameters import BOUNDS, Theta, as_theta, check_names

#: Distance kept from finite bounds (see the module docstring).
MARGIN = 1e-6
METHODS = ("bfgs", "lbfgsb")


def to_unconstrained(value: float, name: str) -> float:
    """z of a natural value: log(x − lo) when unbounded above, else logit((x − lo)/(hi − lo))."""
    lo, hi = BOUNDS[name]
    if math.isinf(hi):
        return math.log(max(value - lo, MARGIN))
    u = min(max((value - lo) / (hi - lo), MARGIN), 1 - MARGIN)
    return math.log(u / (1 - u))


def from_unconstrained(z, name: str) -> jax.Array:
    """Inverse of :func:`to_unconstrained` (JAX-traceable)."""
    lo, hi = BOUNDS[name]
    return lo + (jnp.exp(z) if math.isinf(hi) else (hi - lo) * jax.nn.sigmoid(z))


class Loss:
    """The calibration loss over the parameters ``names`` (the others from ``base``).

    ``loss(z)`` → ``(value, None)`` over unconstrained z (optimistix's signature);
    ``loss.natural(x)`` → value over the natural parameters; ``loss.theta(x)`` the model parameters.
    """

    def __init__(self, forward: Callable[[Theta], Mapping], likelihood: GaussianLikelihood, names, base: Theta):
        self.forward, self.likelihood, self.names, self.base = forward, likelihood, tuple(names), base
        self.n_observations = likelihood.n_observations

    def theta(self, x) -> Theta:
        return self.base.with_vector(self.names, x)

    def natural(self, x) -> jax.Array:
        return self.likelihood.loss(self.forward(self.theta(x)))

    def to_natural(self, z) -> jax.Array:
        return jnp.stack([from_unconstrained(z[i], n) for i, n in enumerate(self.names)])

    def to_unconstrained(self, x) -> jax.Array:
        return jnp.asarray([to_unconstrained(float(v), n) for v, n in zip(x, self.names)], jnp.float64)

    def __call__(self, z, args=None) -> tuple[jax.Array, None]:
        return self.natural(self.to_natural(z)), None


def make_loss(
    model: CoupledModel,
    obs: pd.DataFrame,
    names: Sequence[str],
    fixed: Theta | Mapping[str, float] | None = None,
    *,
    use: Sequence[str] = USES,
    forward: Callable[[Theta], Mapping] | None = None,
) -> Loss:
    """The calibration :class:`Loss` of ``model`` (or ``forward``, e.g. an emulator, on the model's
    time steps) against ``obs``. Unknown names, observations outside the run or none of the used
    series on a simulated step raise :class:`InputError`."""
    names = check_names(names)
    return Loss(forward or model.observe, GaussianLikelihood(obs, model.times, use), names, as_theta(fixed))


@dataclass
class CalibrationResult:
    """Outcome of :func:`calibrate`.

    Attributes:
        theta: all model parameters at the best point (plain floats).
        loss: calibration loss there.
        steps: accepted optimiser steps (L-BFGS-B: iterations, the last one possibly a failed line
            search), including those of a resumed history.
        evaluations, gradients: loss and gradient evaluations in this call (line-search trials
            included; BFGS computes the gradient only at accepted points).
        stopped_by: ``"converged"``, ``"max_steps"`` or ``"failed: <reason>"``.
    """

    theta: dict[str, float]
    loss: float
    steps: int
    evaluations: int
    gradients: int
    stopped_by: str
    method: str
    history: Path | None
    seconds: float

    @property
    def converged(self) -> bool:
        return self.stopped_by == "converged"


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


class _BFGS:
    """optimistix BFGS in unconstrained coordinates, one ``solver.step`` (one loss evaluation) at a time."""

    coordinates = "unconstrained"

    def __init__(self, loss: Loss, x0, rtol: float, atol: float, **_):
        self.loss = loss
        self.solver = optx.BFGS(rtol=rtol, atol=atol)
        self.options = {"autodiff_mode": "bwd"}
        self.fn = jax.jit(loss)
        self.z = loss.to_unconstrained(x0)
        f_struct = jax.ShapeDtypeStruct((), jnp.float64)
        self.state = self.solver.init(self.fn, self.z, None, self.options, f_struct, None, frozenset())
        self._step = jax.jit(lambda z, s: self.solver.step(self.fn, z, None, self.options, s, frozenset())[:2])
        self._done = jax.jit(lambda z, s: self.solver.terminate(self.fn, z, None, self.options, s, frozenset()))
        self.evaluations = 0

    def step(self) -> tuple[bool, str | None]:
        """One trial; returns (new accepted point?, stop reason or None)."""
        before = int(self.state.num_accepted_steps)
        self.z, self.state = self._step(self.z, self.state)
        self.evaluations += 1
        done, result = self._done(self.z, self.state)
        reason = None
        if bool(done):
            reason = "converged" if result == optx.RESULTS.successful else f"failed: {optx.RESULTS[result]}"
        return int(self.state.num_accepted_steps) > before, reason

    @property
    def gradients(self) -> int:
        return int(self.state.num_accepted_steps)

    def point(self):
        """Accepted point: natural x, loss, gradient (in the optimiser's coordinates)."""
        return self.loss.to_natural(self.z), float(self.state.f_info.f), np.asarray(self.state.f_info.grad)


class _LBFGSB:
    """jaxopt L-BFGS-B on natural parameters in the box; every update is an accepted step."""

    coordinates = "natural"

    def __init__(self, loss: Loss, x0, gtol: float, **_):
        with warnings.catch_warnings():
            # jaxopt announces on import that it is no longer maintained; see calibrate()'s docstring.
            warnings.filterwarnings("ignore", "JAXopt is no longer maintained", DeprecationWarning)
            from jaxopt import LBFGSB

        lo, hi = np.array([BOUNDS[n] for n in loss.names]).T
        span = np.where(np.isinf(hi), 1.0, hi - lo)
        self.bounds = (jnp.asarray(lo + MARGIN * span), jnp.asarray(np.where(np.isinf(hi), hi, hi - MARGIN * span)))
        self.loss = loss
        self.solver = LBFGSB(fun=loss.natural, tol=gtol, maxiter=10**6)
        self.x = jnp.clip(jnp.asarray(x0, jnp.float64), *self.bounds)
        self.state = jax.jit(self.solver.init_state)(self.x, bounds=self.bounds)
        self._update = jax.jit(self.solver.update)

    def step(self) -> tuple[bool, str | None]:
        self.x, self.state = self._update(self.x, self.state, bounds=self.bounds)
        if bool(self.state.failed_linesearch):
            return True, "failed: line search"
        return True, "converged" if float(self.state.error) <= self.solver.tol else None

    @property
    def evaluations(self) -> int:
        return int(self.state.num_fun_eval)

    @property
    def gradients(self) -> int:
        return int(self.state.num_grad_eval)

    def point(self):
        return self.x, float(self.state.value), np.asarray(self.state.grad)


def calibrate(
    model: CoupledModel,
    obs: pd.DataFrame,
    *,
    names: Sequence[str] = ("specular", "roughness", "subsurface"),
    start: Theta | Mapping[str, float] | None = None,
    fixed: Theta | Mapping[str, float] | None = None,
    method: str = "bfgs",
    max_steps: int = 30,
    rtol: float = 1e-4,
    atol: float = 1e-4,
    gtol: float = 1e-2,
    use: Sequence[str] = USES,
    forward: Callable[[Theta], Mapping] | None = None,
    history: str | Path | None = None,
    resume: bool = True,
    progress: bool = True,
) -> CalibrationResult:
    """Minimise the calibration loss over ``names``; see the module docstring.

    Args:
        start: starting values of (some of) ``names`` (others: ``fixed``, then the defaults).
        fixed: values of the parameters not calibrated (default: ``Theta()``).
        method: ``"bfgs"`` (rtol/atol: optimistix's Cauchy termination on parameters and loss) or
            ``"lbfgsb"`` (gtol: ∞-norm of the projected gradient step, loss per natural unit). On
            rendered losses L-BFGS-B usually ends with ``"failed: line search"`` at the optimum: loss
            and gradient disagree below ≈ 1e-4 in the parameters (float32 renders; on the twin
            benchmark the gradient is ≈ −0.05 where the loss is lowest), so no Wolfe step exists.
            jaxopt, which provides L-BFGS-B, is no longer maintained upstream (it says so on import);
            it works with the pinned JAX and is kept for this bounded option.
        max_steps: most accepted steps in this call (BFGS also stops after 10·max_steps trials).
        use: which observed series enter the loss (``"par"``, ``"an"``).
        forward: model outputs of a ``Theta`` (default ``model.observe``; e.g. an emulator).
        history: JSON-lines file; one line per accepted step (step, loss, theta, gradient in the
            optimiser's coordinates, evaluations so far, time).
        resume: continue from the best point in ``history`` if it exists.
    """
    if method not in METHODS:
        raise InputError(f"method={method!r}", column="method", expected=" or ".join(METHODS))
    loss = make_loss(model, obs, names, fixed, use=use, forward=forward)
    names = loss.names
    th0 = as_theta(start, base=loss.base)
    past: list[dict] = []
    hist = Path(history) if history else None
    if hist and resume and hist.exists():
        past = _read_history(hist)
        # drop a line cut by an interruption, so that the steps appended below stay readable
        hist.write_text("".join(json.dumps(r) + "\n" for r in past), encoding="utf-8")
        if past:
            best_past = min(past, key=lambda r: r["loss"])
            th0 = th0.replace(**{n: best_past["theta"][n] for n in names})
    elif hist and hist.exists():
        hist.unlink()
    opt = (_BFGS if method == "bfgs" else _LBFGSB)(loss, np.asarray(th0.vector(names)), rtol=rtol, atol=atol, gtol=gtol)
    t0 = time.perf_counter()
    best_loss, best_x = math.inf, np.asarray(th0.vector(names))
    accepted, stopped_by = 0, "max_steps"
    with progress_bar("calibrating", max_steps, show=progress) as bar:
        for _ in range(10 * max_steps):
            new, reason = opt.step()
            if new:
                accepted += 1
                x, f, g = opt.point()
                values = {n: float(v) for n, v in zip(names, np.asarray(x))}
                if f < best_loss:
                    best_loss, best_x = f, np.asarray(x)
                if hist:
                    record = {
                        "step": len(past) + accepted,
                        "loss": f,
                        "theta": values,
                        "grad": [float(v) for v in g],
                        "coordinates": opt.coordinates,
                        "evaluations": opt.evaluations,
                        "seconds": time.perf_counter() - t0,
                    }
                    hist.parent.mkdir(parents=True, exist_ok=True)
                    with open(hist, "a", encoding="utf-8") as fh:
                        fh.write(json.dumps(record) + "\n")
                info = f"loss {f:.4g}  " + " ".join(f"{n[:4]}={v:.3f}" for n, v in values.items())
                bar.update(completed=accepted, info=info)
            if reason is not None:
                stopped_by = reason
                break
            if accepted >= max_steps:
                break
    theta = loss.theta(jnp.asarray(best_x))
    if past and best_past["loss"] < best_loss:
        theta, best_loss = theta.replace(**best_past["theta"]), best_past["loss"]
    return CalibrationResult(
        theta.to_dict(),
        best_loss,
        len(past) + accepted,
        opt.evaluations,
        opt.gradients,
        stopped_by,
        method,
        hist,
        time.perf_counter() - t0,
    )


__all__ = ["CalibrationResult", "Loss", "calibrate", "from_unconstrained", "make_loss", "to_unconstrained"]
