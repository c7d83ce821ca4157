r"""Gradient calibration of leaf surface (and optionally light and Vcmax) parameters.

Loss: the calibration loss of :class:`~lightfit.inference.likelihood.GaussianLikelihood`,

.. math:: \mathcal L(\theta) = \tfrac12 \sum_{k \in obs} \frac{(y_k - m_k(\theta))^2}{\sigma_k^2 + s_k^2}

(measurement SD σ_k, the model's Monte Carlo SD s_k taken at the start θ₀ and held: a plug-in, so that
the optimisers' gradient is the derivative of the loss they evaluate; see
:mod:`lightfit.inference.likelihood`, "Plug-in Monte Carlo variance"), or
with ``mc_correlation`` the correlated form ½ rᵀΣ⁻¹r with the model's Monte Carlo correlation
across steps and series (:mod:`lightfit.inference.likelihood`; ``lightfit calibrate``'s default).
Gradients by reverse mode through the Mitsuba bridge and the implicit photosynthesis solve. Two
optimisers, chosen by ``method``:

- ``"lbfgsb"`` (the command line's and the surrogate calibration's default): jaxopt's
  box-constrained L-BFGS-B on the natural parameters within
  :data:`lightfit.model.parameters.BOUNDS` (an infinite upper bound stays infinite). Both keep a
  margin of 1e-6 from finite bounds (the logit cannot reach them either; at roughness 0 the GGX
  lobe is a mirror and the estimator's variance is unbounded);
- ``"bfgs"`` (this function's default): optimistix BFGS on unconstrained coordinates z — logit for parameters in
  [0, 1], log for positive ones (:func:`to_unconstrained`). Its first step is the raw gradient in
  z, which can leave the region where the loss is finite when the loss is steep (a light factor
  fitted to PAR records of ~1500 µmol m⁻² s⁻¹: a first step of −1.3e4 in log f); it also stalls
  near specular → 1 from poor starts. Directly on full renders from a good start it converges
  where L-BFGS-B can end on a failed line search a little short of the optimum (a loss 7e-4
  above BFGS's on the short twin).

Both are driven step by step, so that every accepted step is shown in a progress display and
appended to a JSON-lines history. After every trial the optimiser's whole state (iterate,
quasi-Newton matrix, line-search state, counters) is written atomically next to the history
(``<history>.state.npz``), so a calibration killed at any moment and rerun with the same
arguments continues exactly: same steps, same history, same optimum as an uninterrupted run
(history lines written after the last saved state are dropped and redone). Without a matching
state (a history written before states were saved, or a state that cannot be read)
``resume=True`` restarts from the best point of the history and says so; a state saved with other
settings (method, start, fixed values, tolerances, series, likelihood form, observation matching)
or a history made with other observations or another model (the state records a hash of both) is
refused with :class:`~lightfit.errors.InputError`: its losses belong to another loss, and
continuing would replace the state with which that run finishes exactly. The result counts
accepted steps, loss evaluations and gradient evaluations separately, and says why the optimiser
stopped (``stopped_by`` and the sentence ``reason``); the history ends with a record of the same.
"""

from __future__ import annotations

import dataclasses
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

from lightfit.errors import InputError, check_integer, check_real, is_real
from lightfit.files import UNREADABLE_NPZ, load_npz, replace_text, replaced
from lightfit.inference.likelihood import (
    USES,
    GaussianLikelihood,
    MCCorrelation,
    check_informed,
    likelihood_form,
    observations_digest,
    plug_in,
    run_settings,
)
from lightfit.inference.likelihood import mc_correlation as mc_correlation_of
from lightfit.inference.observations import matched_as_by_stamp, observation_matching
from lightfit.killpoint import kill_point
from lightfit.light.bsdf import LEAF_PARAMETERS
from lightfit.model.coupled import CoupledModel
from lightfit.model.parameters import BOUNDS, Theta, as_theta, check_names
from lightfit.model.scenario import DIGEST_WHEN_ABSENT, Scenario, digest_of, settings_digest
from lightfit.progress import progress_bar

#: Distance kept from finite bounds (see the module docstring).
MARGIN = 1e-6
METHODS = ("bfgs", "lbfgsb")


def to_unconstrained(value: float, name: str, bounds: Mapping[str, tuple[float, float]] | None = None) -> float:
    """z of a natural value: log(x − lo) when unbounded above, else logit((x − lo)/(hi − lo)).
    ``bounds``: (lo, hi) per name replacing :data:`BOUNDS` (e.g. an emulator's box)."""
    lo, hi = (bounds or {}).get(name, BOUNDS[name])
    if math.isinf(hi):
        return math.log(max(value - lo, MARGIN))
    u = min(max((value - lo) / (hi - lo), MARGIN), 1 - MARGIN)
    return math.log(u / (1 - u))


def from_unconstrained(z, name: str, bounds: Mapping[str, tuple[float, float]] | None = None) -> jax.Array:
    """Inverse of :func:`to_unconstrained` (JAX-traceable)."""
    lo, hi = (bounds or {}).get(name, BOUNDS[name])
    return lo + (jnp.exp(z) if math.isinf(hi) else (hi - lo) * jax.nn.sigmoid(z))


def check_bounds(
    bounds: Mapping[str, tuple[float, float]] | None, names: Sequence[str]
) -> dict[str, tuple[float, float]]:
    """(lo, hi) per calibrated name in ``names``, in the parameter's own units: ``bounds``' pair where
    given, else the domain's (:data:`BOUNDS`). A given pair must be two real numbers, lo finite,
    lo < hi (the logit divides by hi − lo), inside the domain (hi may be infinite only where the
    domain is unbounded above: outside it the model is undefined, e.g. a negative specular); and
    only calibrated names may have bounds (others would be ignored). Anything else raises
    :class:`InputError` naming ``bounds``, the parameter and what was expected."""
    names = tuple(names)
    given = dict(bounds or {})
    check_names(given, what="bounds")
    extra = [n for n in given if n not in names]
    if extra:
        raise InputError(
            f"bounds for {', '.join(extra)}, which {'is' if len(extra) == 1 else 'are'} not calibrated",
            parameter="bounds",
            expected=f"bounds only for the calibrated parameters ({', '.join(names)})",
        )
    out = {}
    for n in names:
        lo_d, hi_d = BOUNDS[n]
        if n not in given:
            out[n] = (float(lo_d), float(hi_d))
            continue
        pair = given[n]
        try:
            lo, hi = pair
        except (TypeError, ValueError):
            lo = hi = None
        ok = is_real(lo) and is_real(hi) and math.isfinite(lo) and not math.isnan(hi)
        if not (ok and lo_d <= lo < hi <= hi_d):
            raise InputError(
                f"bounds {n}={pair!r}",
                parameter="bounds",
                expected=f"(lo, hi) with {lo_d:g} ≤ lo < hi ≤ {hi_d:g} ({n}'s domain), lo finite",
            )
        out[n] = (float(lo), float(hi))
    return out


class Loss:
    """The calibration loss over the parameters ``names`` (the others from ``base``).

    ``loss(z)`` → ``(value, None)`` over unconstrained z (optimistix's signature);
    ``loss.natural(x)`` → value over the natural parameters; ``loss.theta(x)`` the model parameters.
    ``bounds``: (lo, hi) per name narrowing :data:`BOUNDS` (both optimisers stay inside), checked by
    :func:`check_bounds`. ``mc``: the plug-in Monte Carlo SDs that build Σ at every θ
    (:func:`~lightfit.inference.likelihood.plug_in` at a reference θ; ``None``: each point's own,
    whose gradient is stopped, so that value and gradient then disagree where they matter).
    """

    def __init__(
        self,
        forward: Callable[[Theta], Mapping],
        likelihood: GaussianLikelihood,
        names,
        base: Theta,
        bounds: Mapping[str, tuple[float, float]] | None = None,
        mc: Mapping | None = None,
    ):
        self.forward, self.likelihood, self.names, self.base = forward, likelihood, tuple(names), base
        self.n_observations = likelihood.n_observations
        self.bounds = check_bounds(bounds, self.names)
        self.mc = mc

    def theta(self, x) -> Theta:
        return self.base.with_vector(self.names, x)

    def natural(self, x) -> jax.Array:
        """The loss at natural parameters ``x``; +inf where a blade's photosynthesis did not converge
        (:meth:`GaussianLikelihood.loss`: the line searches reject the trial)."""
        return self.likelihood.loss(self.forward(self.theta(x)), self.mc)

    def to_natural(self, z) -> jax.Array:
        return jnp.stack([from_unconstrained(z[i], n, self.bounds) for i, n in enumerate(self.names)])

    def to_unconstrained(self, x) -> jax.Array:
        return jnp.asarray([to_unconstrained(float(v), n, self.bounds) for v, n in zip(x, self.names)], jnp.float64)

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
    bounds: Mapping[str, tuple[float, float]] | None = None,
    mc_correlation: MCCorrelation | str | None = None,
    mc_scale: float = 1.0,
    at: Theta | Mapping[str, float] | None = None,
) -> Loss:
    """The calibration :class:`Loss` of ``model`` (or ``forward``, e.g. an emulator, on the model's
    time steps) against ``obs``. Unknown names, observations outside the run or none of the used
    series on a simulated step raise :class:`InputError`.

    ``mc_correlation``: the likelihood's Monte Carlo correlation across steps and series
    (:class:`~lightfit.inference.likelihood.GaussianLikelihood`): ``None`` (independent steps),
    an :class:`~lightfit.inference.likelihood.MCCorrelation`, or ``"model"`` — computed once here by
    :func:`~lightfit.inference.likelihood.mc_correlation` from ``model``'s light parts at ``at``
    (default: the fixed values; one render and one reverse pass per series unless the model's light
    is injected, e.g. ``model.with_light(emulator)``). ``mc_scale``: c of the likelihood (1 for
    measured data, 2 for twins rendered at the model's samples). ``model`` may be a
    :class:`~lightfit.inference.multiday.MultiDayModel` (several days, one likelihood).

    The loss's Monte Carlo SDs are taken at ``at`` too and held (:attr:`Loss.mc`; one evaluation of
    ``forward`` here, a render on full renders): the loss's gradient is then its derivative."""
    names = check_names(names, fitted=True)
    base = model.theta(fixed)
    lik = GaussianLikelihood.of_model(model, obs, use, mc_scale=mc_scale)
    check_informed(names, lik.use, **run_settings(model))  # before the "model" correlation renders
    if isinstance(mc_correlation, str) and likelihood_form(mc_correlation)["mc_correlation"] == "model":
        mc_correlation = mc_correlation_of(model, as_theta(at, base=base), lik.use)
    elif isinstance(mc_correlation, str):
        mc_correlation = None
    if mc_correlation is not None:
        lik = GaussianLikelihood.of_model(model, obs, lik.use, mc_correlation=mc_correlation, mc_scale=mc_scale)
    check_bounds(bounds, names)  # before the plug-in's evaluation (a render on full renders)
    forward = forward or model.observe
    mc = plug_in(lik, forward(as_theta(at, base=base)))
    # non-finite SDs (a start whose photosynthesis did not converge): the point's own, whose loss is
    # +inf there, so that the optimisers report the start as unconverged rather than a NaN loss
    finite = all(np.isfinite(v).all() for v in mc.values())
    return Loss(forward, lik, names, base, bounds, mc if finite else None)


@dataclass
class CalibrationResult:
    """Outcome of :func:`calibrate`.

    Attributes:
        theta: all model parameters at the best point (plain floats).
        loss: calibration loss there, with that point's own Monte Carlo SDs (the optimiser held
            its start's, and the history's losses are those: the answer's loss and χ² do not
            depend on where the search began).
        steps: accepted optimiser steps (L-BFGS-B: iterations, the last one possibly a failed line
            search), including those of a resumed history.
        evaluations, gradients: loss and gradient evaluations (line-search trials included; BFGS
            computes the gradient only at accepted points), including those before an exact resume.
        stopped_by: ``"converged"`` (the method's tolerances met), ``"max_steps"`` (step limit),
            ``"stalled"`` (10·max_steps trials without reaching the step limit: the line search keeps
            rejecting), ``"failed: <reason>"`` (e.g. ``"failed: line search"``), ``"unconverged: θ"``
            (the leaf photosynthesis did not converge at the start) or ``"against unconverged: θ"``
            (BFGS's steps shrank against a region where it does not converge, the gradient not small).
        reason: the same as a sentence with the numbers (tolerances, counts).
        seconds: wall time of the calibration, s, summed over the calls of a resumed run (the
            history's ``seconds`` likewise: each step's time since the run began).
        n_observations: the likelihood's entries (readings in one model step are one entry, their
            inverse-variance mean): the n of χ²/(n − k).
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
    reason: str = ""
    n_observations: int = 0

    @property
    def converged(self) -> bool:
        return self.stopped_by == "converged"


def _read_history(path: Path) -> list[dict]:
    """The step records of a history (the final ``stopped_by`` record and a cut last line skipped).
    An unreadable line before the last (not an interruption's cut: the history is appended to) raises
    :class:`InputError` naming the file and line: the steps after it were dropped unsaid."""
    if not path.exists():
        return []
    out = []
    lines = path.read_text(encoding="utf-8").splitlines()
    for i, line in enumerate(lines):
        try:
            r = json.loads(line)
        except json.JSONDecodeError:
            r = None
        if not isinstance(r, dict):
            if any(rest.strip() for rest in lines[i + 1 :]):
                raise InputError(
                    "not a JSON object of a calibration step, and lines follow it (an interruption cuts only "
                    "the last line)",
                    file=path,
                    row=i + 1,
                    expected="the history lightfit wrote, --no-resume (resume=False) to start again, or another "
                    "--out (history)",
                )
            break  # a line cut by an interruption; everything before it is intact
        if "loss" in r:
            out.append(r)
    return out


def _save_state(path: Path, opt, counters: dict, key: dict) -> None:
    """Write the optimiser's state pytree and the loop's counters (:func:`lightfit.files.replaced`)."""
    leaves = jax.tree_util.tree_leaves(opt.state)
    arrays = {f"leaf{i}": np.asarray(v) for i, v in enumerate(leaves)}
    with replaced(path) as tmp:
        np.savez(tmp, point=np.asarray(opt.current), meta=json.dumps({"key": key, **counters}), **arrays)


def _load_state(path: Path) -> dict | None:
    try:
        with load_npz(path) as z:
            meta = json.loads(str(z["meta"]))
            n = sum(1 for k in z.files if k.startswith("leaf"))
            return {**meta, "point": z["point"], "leaves": [z[f"leaf{i}"] for i in range(n)]}
    except UNREADABLE_NPZ:
        # unreadable (an empty file: EOFError, which click turned into a bare "Aborted."; a cut one:
        # BadZipFile, a traceback): start from the history's best point instead
        return None


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

    @property
    def current(self):
        return self.z

    def restore(self, point, leaves, evaluations: int) -> None:
        self.z, self.state = jnp.asarray(point), _unflatten(self.state, leaves)
        self.evaluations = evaluations


class _LBFGSB:
    """jaxopt L-BFGS-B on natural parameters in the box; every update is an accepted step."""

    coordinates = "natural"

    def __init__(self, loss: Loss, x0, gtol: float, **_):
        with warnings.catch_warnings():
            # jaxopt announces on import that it is no longer maintained; see calibrate()'s docstring.
            warnings.filterwarnings("ignore", "JAXopt is no longer maintained", DeprecationWarning)
            from jaxopt import LBFGSB

        lo, hi = np.array([loss.bounds[n] for n in loss.names]).T
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
        return True, "converged" if float(self.state.error) <= self.solver.tol and not self._short_of_bound() else None

    def _short_of_bound(self) -> bool:
        """Whether a parameter stands off a bound that its projected gradient step reaches: jaxopt's
        error is then the distance to the bound, not the gradient, so it met ``gtol`` up to gtol short
        of a bound the loss still falls towards (0.999 for a bound at 1 and gtol 1e-2: the loss above
        the bound's, and the optimum not reported on its edge). One more update steps onto it."""
        x, g = np.asarray(self.x, float), np.asarray(self.state.grad, float)
        lo, hi = (np.asarray(b, float) for b in self.bounds)
        return bool(np.any(((x - g < lo) & (x > lo)) | ((x - g > hi) & (x < hi))))

    @property
    def evaluations(self) -> int:
        return int(self.state.num_fun_eval)

    @property
    def gradients(self) -> int:
        return int(self.state.num_grad_eval)

    def point(self):
        return self.x, float(self.state.value), np.asarray(self.state.grad)

    @property
    def current(self):
        return self.x

    def restore(self, point, leaves, evaluations: int) -> None:
        self.x, self.state = jnp.asarray(point), _unflatten(self.state, leaves)


def _unflatten(template, leaves):
    """A state pytree like ``template`` with the stored ``leaves`` (same types and dtypes as the template's)."""
    old, tree = jax.tree_util.tree_flatten(template)
    if len(old) != len(leaves):
        raise ValueError("stored optimiser state does not fit")
    new = [
        np.asarray(v, o.dtype) if isinstance(o, np.ndarray) else jnp.asarray(v, o.dtype) for o, v in zip(old, leaves)
    ]
    return jax.tree_util.tree_unflatten(tree, new)


#: Most accepted optimiser steps of a calibration by default (on full renders or on the surrogate,
#: whose optimiser stopped at 200 while the command line passed 30).
MAX_STEPS = 30


def check_max_steps(max_steps) -> int:
    """The optimiser's accepted steps at most: an integer ≥ 1 (with 0 the start would be returned
    as if it were a calibration)."""
    return check_integer(max_steps, "max_steps", 1)


def check_start_names(start, names: Sequence[str], base: Theta) -> None:
    """Refuse a start value of a parameter not in ``names`` that differs from the value the run holds
    it at (``base``: the fixed values or the run leaf's defaults): it would be ignored, the parameter
    held at ``base``'s value while the result listed it as fixed there (a review: ``--parameters
    light_factor --start specular=0.2`` fitted at specular 0.5 unsaid). Equal values pass (a start
    read from a calibration.json of the same run lists every parameter). A :class:`Theta` start
    (every value given) is not checked here."""
    if start is None or isinstance(start, Theta):
        return
    names = tuple(names)
    held = {
        n: float(v)
        for n, v in start.items()
        if n not in names and not math.isclose(float(v), float(getattr(base, n)), rel_tol=1e-12, abs_tol=0.0)
    }
    if held:
        said = ", ".join(f"{n}={v:g} (held at {float(getattr(base, n)):g})" for n, v in held.items())
        raise InputError(
            f"start values of parameters not calibrated: {said}",
            parameter="start",
            expected=f"start values only for the calibrated parameters ({', '.join(names)}), or those "
            "parameters calibrated too",
        )


def _check_start(th0: Theta, start, box: Mapping, narrowed: Mapping) -> None:
    """Refuse a start value outside its ``bounds`` (``box``: the checked (lo, hi) per calibrated name;
    ``narrowed``: the names given bounds) instead of letting the optimisers move it to the edge
    silently. Also a value not named in ``start`` (``fixed``'s or the default): no caller relies on
    that move (the surrogate calibration checks its start against its box before rendering)."""
    for n in narrowed:
        v, (lo, hi) = float(getattr(th0, n)), box[n]
        if not lo <= v <= hi:
            named = isinstance(start, Theta) or n in (start or {})
            source = "" if named else " (fixed or default, no start given)"
            raise InputError(
                f"{n}={v!r}{source} outside its bounds [{lo:g}, {hi:g}]",
                parameter="start",
                expected=f"a start inside the bounds ({lo:g} ≤ {n} ≤ {hi:g}), or bounds that hold it",
            )


def _model_digest(model) -> dict[str, str] | None:
    """:meth:`~lightfit.model.scenario.Scenario.digest` of the model's scenario (a multi-day
    model's per day): what its outputs depend on besides θ. ``None`` for a model without a
    Scenario dataclass (a test double). Light injected into the model (``with_light``) or a
    ``forward`` are not covered: the surrogate calibration that uses them does not resume."""
    days = getattr(model, "day_models", None)
    if days is not None:
        return {f"{d}: {k}": v for d, m in days.items() for k, v in (_model_digest(m) or {}).items()}
    sc = getattr(model, "scenario", None)
    if isinstance(sc, Scenario):
        return sc.digest()
    return settings_digest(sc) if dataclasses.is_dataclass(sc) and not isinstance(sc, type) else None


def _check_same_data(saved: dict | None, data: dict, hist: Path, say: Callable[[str], None]) -> None:
    """Refuse to resume a history made with other observations or another model: its losses and
    optimiser state belong to another loss, so neither an exact resume nor a restart from its best
    point would be a calibration against these data. A state saved before the data were recorded
    cannot be checked: it resumes as before, with a notice."""
    if saved is None:
        return
    before = saved.get("key", {}).get("data")
    if before is None:
        say(f"{hist}: saved before the observations and model were recorded; they are not checked")
        return
    changed = []
    if before.get("observations") != data["observations"]:
        changed.append("observations")
    old, new = before.get("model"), data["model"]
    if (old is None) != (new is None):
        changed.append("model")
    elif old is not None:
        old = dict(old)
        for k in new:  # settings stored before they existed, where that meant another value
            field = k.rsplit(": ", 1)[-1]  # a multi-day digest's keys are "day: field"
            if k not in old and field in DIGEST_WHEN_ABSENT:
                old[k] = digest_of(DIGEST_WHEN_ABSENT[field])
        settings = [k for k in old if k in new and old[k] != new[k]]
        if settings:
            changed.append(f"model settings ({', '.join(settings)})")
    if changed:
        raise InputError(
            f"the calibration history there was made with other {' and '.join(changed)}",
            file=hist,
            expected="the same observations and model as that run, --no-resume (resume=False) to start again, "
            "or another --out (history)",
        )


def calibrate(
    model: CoupledModel,
    obs: pd.DataFrame,
    *,
    names: Sequence[str] = LEAF_PARAMETERS,
    start: Theta | Mapping[str, float] | None = None,
    fixed: Theta | Mapping[str, float] | None = None,
    method: str = "bfgs",
    max_steps: int = MAX_STEPS,
    rtol: float = 1e-4,
    atol: float = 1e-4,
    gtol: float = 1e-2,
    use: Sequence[str] = USES,
    forward: Callable[[Theta], Mapping] | None = None,
    bounds: Mapping[str, tuple[float, float]] | None = None,
    history: str | Path | None = None,
    resume: bool = True,
    progress: bool = True,
    say: Callable[[str], None] = print,
    mc_correlation: MCCorrelation | str | None = None,
    mc_scale: float = 1.0,
) -> CalibrationResult:
    """Minimise the calibration loss over ``names``; see the module docstring.

    Args:
        start: starting values of (some of) ``names`` (others: ``fixed``, then the defaults), each
            inside its domain and its ``bounds`` (a value taken from ``fixed`` or the defaults too).
        fixed: values of the parameters not calibrated (default: ``Theta()``), inside their domains
            (a mapping or a :class:`Theta`, whose concrete values are checked as a mapping's).
        method: ``"bfgs"`` (rtol/atol: optimistix's Cauchy termination on parameters and loss) or
            ``"lbfgsb"`` (gtol: ∞-norm of the projected gradient step, loss per natural unit; it
            converges when that norm is ≤ gtol and no parameter stands short of a bound its
            projected gradient step reaches, where the norm is only the distance to the bound). On
            rendered losses L-BFGS-B usually ends with ``"failed: line search"`` at the optimum: loss
            and gradient disagree below ≈ 1e-4 in the parameters (float32 renders; on the twin
            benchmark the gradient is ≈ −0.05 where the loss is lowest), so no Wolfe step exists.
            jaxopt, which provides L-BFGS-B, is no longer maintained upstream (it says so on import);
            it works with the pinned JAX and is kept for this bounded option.
        max_steps: most accepted steps in all, resumed ones included (and at most 10·max_steps
            loss evaluations: beyond that the run counts as ``"stalled"``).
        use: which observed series enter the loss (``"par"``, ``"an"``).
        forward: model outputs of a ``Theta`` (default ``model.observe``; e.g. an emulator).
        bounds: (lo, hi) per calibrated name narrowing :data:`~lightfit.model.parameters.BOUNDS`
            (an emulator is only valid in its box), in the parameter's units; checked by
            :func:`check_bounds` (finite lo < hi inside the domain, calibrated names only).
        history: JSON-lines file; one line per accepted step (step, loss, theta, gradient in the
            optimiser's coordinates, evaluations and gradients so far, time), then one line
            ``{"stopped_by", "reason", "steps", "evaluations", "gradients"}``; the optimiser state
            is kept next to it (``<history>.state.npz``).
        resume: continue exactly from the saved state (or from the best point in ``history``). The
            state records a hash of the aligned observations (values, SDs, mask, steps) and of the
            model's scenario settings; a history made with other ones, or a state saved with another
            method, start, tolerances, series or likelihood form, raises :class:`InputError`.
        say: where a one-line notice goes (a history without a readable state, resumed from its
            best point).
        mc_correlation, mc_scale: the likelihood's Monte Carlo form (:func:`make_loss`; ``"model"``
            computes the correlation at ``start``); both enter the resume key.
    """
    if method not in METHODS:
        raise InputError(f"method={method!r}", parameter="method", expected=" or ".join(METHODS))
    check_max_steps(max_steps)
    for name, tol in (("rtol", rtol), ("atol", atol), ("gtol", gtol)):  # NaN never stops, < 0 means nothing
        check_real(tol, name, 0, expected="a finite tolerance ≥ 0")
    if method == "bfgs" and rtol == atol == 0:  # the Cauchy test needs one of them (atol=0: relative only)
        raise InputError("rtol=0 and atol=0", parameter="rtol", expected="rtol > 0 or atol > 0 for method bfgs")
    if method == "lbfgsb" and gtol == 0:
        raise InputError("gtol=0", parameter="gtol", expected="gtol > 0 for method lbfgsb")
    form = likelihood_form(mc_correlation, mc_scale)  # checked before any render
    for what, given in (("fixed", fixed), ("start", start)):
        if given is not None:
            as_theta(given, what=what)  # domains, named; a Theta is built unchecked
    base = model.theta(fixed)
    th0 = as_theta(start, base=base, what="start")
    names = check_names(names, fitted=True)
    check_start_names(start, names, base)
    _check_start(th0, start, check_bounds(bounds, names), bounds or {})
    hist = Path(history) if history else None
    state_file = hist.with_name(hist.name + ".state.npz") if hist else None
    saved = _load_state(state_file) if hist and resume and state_file.exists() else None
    data = None
    if hist:
        # The observations as the loss sees them (cheap: no render), so that a history of other
        # data is refused before the "model" correlation below renders.
        aligned = GaussianLikelihood.of_model(model, obs, use, mc_scale=mc_scale)
        data = {"observations": observations_digest(aligned, model.times), "model": _model_digest(model)}
        _check_same_data(saved, data, hist, say)
    loss = make_loss(
        model,
        obs,
        names,
        base,
        use=use,
        forward=forward,
        bounds=bounds,
        mc_correlation=mc_correlation,
        mc_scale=mc_scale,
        at=th0,
    )
    names = loss.names
    key = {
        "method": method,
        "names": list(names),
        "start": [float(v) for v in np.asarray(th0.vector(names))],
        "base": loss.base.to_dict(),
        "tolerances": [rtol, atol, gtol],
        "use": list(loss.likelihood.use),
        # the plug-in SDs' point enters the form: a state saved with each point's own SDs optimised
        # another loss (refused as "likelihood (mc_sd_at: None → 'start')")
        "likelihood": {**form, "mc_sd_at": "start"},
    }
    if bounds:  # absent without: states saved before bounds existed still resume exactly
        key["bounds"] = {n: list(loss.bounds[n]) for n in names}
    how = (model.times, model.timestamps, model.step, loss.likelihood.use)
    if not matched_as_by_stamp(obs, *how):  # else absent: states saved before still resume exactly
        key["observation_matching"] = observation_matching(obs, *how)
    if data is not None:
        key["data"] = data
    # states saved before the likelihood's form was recorded used independent steps
    old = {"likelihood": likelihood_form(None), **(saved or {}).get("key", {})}
    if data is not None:  # _check_same_data passed: the same data (a setting unknown to one key aside)
        old["data"] = data
    if saved is not None and old != key:
        changed = [k for k in {**old, **key} if old.get(k) != key.get(k)]
        before = old["likelihood"]
        what = [
            "likelihood ("
            + "; ".join(f"{k}: {before.get(k)!r} → {v!r}" for k, v in key["likelihood"].items() if before.get(k) != v)
            + ")"
            if k == "likelihood"
            else k
            for k in changed
        ]
        # Refused, as other data are: continuing from the history's best point mixed two runs (a
        # history and counts of one method, the optimum of another) and deleted the state with
        # which the first command would have finished exactly.
        raise InputError(
            f"the calibration there was run with other {', '.join(what)}",
            file=state_file,
            expected="the same settings as that run, --no-resume (resume=False) to start again, or another --out "
            "(history)",
        )
    past: list[dict] = []
    if saved is None and hist and resume and hist.exists():
        past = _read_history(hist)
        if any("mc_sd_at" not in r for r in past):
            raise InputError(
                "the history there was written before the loss held its start's Monte Carlo SDs: its losses "
                "are of another function",
                file=hist,
                expected="--no-resume (resume=False) to start again, or another --out (history)",
            )
        # drop a line cut by an interruption, so that the steps appended below stay readable
        replace_text(hist, "".join(json.dumps(r) + "\n" for r in past))
        if past:
            best_past = min(past, key=lambda r: r["loss"])
            th0 = th0.replace(**{n: best_past["theta"][n] for n in names})
            say(f"resuming {hist} without a saved state: {len(past)} steps kept, restarted from their best point")
    elif saved is None and hist:
        hist.unlink(missing_ok=True)
    if saved is None and state_file is not None:
        state_file.unlink(missing_ok=True)
    opt = (_BFGS if method == "bfgs" else _LBFGSB)(loss, np.asarray(th0.vector(names)), rtol=rtol, atol=atol, gtol=gtol)
    t0 = time.perf_counter()
    # seconds: of every call's work on this run, so that a resumed run's reads as the run's (it read
    # the last call's alone); a history resumed without its state goes on from its last step's
    spent = float(past[-1].get("seconds", 0.0)) if past else 0.0
    c = {"accepted": len(past), "trials": 0, "best_loss": math.inf, "best_x": None, "stopped_by": None}
    c |= {"seconds": spent}
    c["best_x"] = [float(v) for v in np.asarray(th0.vector(names))]
    if saved is not None:
        opt.restore(saved["point"], saved["leaves"], saved["evaluations"])
        c = {k: saved[k] if k != "seconds" else saved.get(k, 0.0) for k in c}  # "seconds": absent before
        if c["stopped_by"] in ("max_steps", "stalled"):
            c["stopped_by"] = None  # limits, not the optimiser's verdict: a rerun with a larger max_steps goes on
        # lines appended after the saved state (a kill in between) are redone identically below
        kept = _read_history(hist)
        if len(kept) < c["accepted"]:  # written before the state, so lost since: the steps would skip them
            raise InputError(
                f"{len(kept)} readable steps, where its saved optimiser state ({state_file.name}) has {c['accepted']}",
                file=hist,
                expected="the history written with that state, --no-resume (resume=False) to start again, or "
                "another --out (history)",
            )
        replace_text(hist, "".join(json.dumps(r) + "\n" for r in kept[: c["accepted"]]))
        say(f"resuming {hist}: {c['accepted']} accepted steps kept, continued exactly from the saved state")
    if past and best_past["loss"] < c["best_loss"]:
        c["best_loss"], c["best_x"] = best_past["loss"], [best_past["theta"][n] for n in names]

    def elapsed() -> float:
        return c["seconds"] + time.perf_counter() - t0

    def counts() -> str:
        return f"{c['accepted']} steps, {opt.evaluations} evaluations, {opt.gradients} gradients"

    def at(x) -> str:
        return ", ".join(f"{n}={float(v):.6g}" for n, v in zip(names, np.asarray(x)))

    if saved is None and method == "lbfgsb" and not math.isfinite(opt.point()[1]):
        c["stopped_by"] = "unconverged: " + at(opt.point()[0])  # its first update would take a NaN gradient

    with progress_bar("calibrating", max_steps, completed=c["accepted"], show=progress) as bar:
        while c["stopped_by"] is None:
            if c["accepted"] >= max_steps:
                c["stopped_by"] = "max_steps"
                break
            if c["trials"] >= 10 * max_steps:
                c["stopped_by"] = "stalled"
                break
            new, reason = opt.step()
            c["trials"] += 1
            if new:
                c["accepted"] += 1
                x, f, g = opt.point()
                values = {n: float(v) for n, v in zip(names, np.asarray(x))}
                if not math.isfinite(f):  # an accepted point with no loss: BFGS's start was one
                    c["stopped_by"] = "unconverged: " + at(x)
                    break
                if f < c["best_loss"]:
                    c["best_loss"], c["best_x"] = f, [float(v) for v in np.asarray(x)]
                if hist:
                    record = {
                        "step": c["accepted"],
                        "loss": f,
                        "mc_sd_at": "start",  # the loss held its start's SDs (a history without it did not)
                        "theta": values,
                        "grad": [float(v) for v in g],
                        "coordinates": opt.coordinates,
                        "evaluations": opt.evaluations,
                        "gradients": opt.gradients,
                        "seconds": elapsed(),
                    }
                    hist.parent.mkdir(parents=True, exist_ok=True)
                    with open(hist, "a", encoding="utf-8") as fh:
                        fh.write(json.dumps(record) + "\n")
                    kill_point("calibrate", c["accepted"])
                info = f"loss {f:.4g}  {opt.evaluations} evals  " + " ".join(
                    f"{n[:4]}={v:.3f}" for n, v in values.items()
                )
                bar.update(completed=c["accepted"], info=info)
            if reason is not None:
                c["stopped_by"] = reason
            if state_file is not None:
                _save_state(state_file, opt, {**c, "seconds": elapsed(), "evaluations": opt.evaluations}, key)
        if method == "bfgs" and c["stopped_by"] == "converged" and _against_unconverged(opt, rtol, atol, gtol):
            c["stopped_by"] = "against unconverged: " + at(opt.point()[0])
        why = _reason(c["stopped_by"], method, rtol, atol, gtol, max_steps, c["trials"], c["accepted"])
        bar.update(info=f"{why}; {counts()}")
    if state_file is not None:
        _save_state(state_file, opt, {**c, "seconds": elapsed(), "evaluations": opt.evaluations}, key)
    if hist:
        steps = _read_history(hist)
        final = {
            "stopped_by": c["stopped_by"],
            "reason": why,
            "steps": c["accepted"],
            "evaluations": opt.evaluations,
            "gradients": opt.gradients,
        }
        replace_text(hist, "".join(json.dumps(r) + "\n" for r in [*steps, final]))
    theta = loss.theta(jnp.asarray(c["best_x"]))
    # The answer's loss with its own SDs: one more evaluation (a render on full renders), so that
    # the reported loss and the χ² caution do not move with the start.
    own = float(loss.likelihood.loss(loss.forward(theta))) if math.isfinite(c["best_loss"]) else c["best_loss"]
    return CalibrationResult(
        theta.to_dict(),
        own,
        c["accepted"],
        opt.evaluations,
        opt.gradients,
        c["stopped_by"],
        method,
        hist,
        elapsed(),
        why,
        loss.n_observations,
    )


def _against_unconverged(opt: _BFGS, rtol: float, atol: float, gtol: float) -> bool:
    """Whether BFGS's "converged" is its steps shrinking against a region where the photosynthesis
    does not converge (the loss +inf there, every trial into it rejected) rather than an optimum: the
    gradient is not small (∞-norm > ``gtol``) and a short step down it, 10 × the step tolerance,
    has no finite loss. One loss evaluation, only when the gradient is not small."""
    _, _, g = opt.point()
    g = np.asarray(g, float)
    if not np.abs(g).max() > gtol:
        return False
    z = np.asarray(opt.current, float)
    step = 10 * (atol + rtol * np.abs(z).max())
    return not math.isfinite(float(opt.fn(jnp.asarray(z - step * g / np.linalg.norm(g)))[0]))


def _reason(
    stopped_by: str, method: str, rtol, atol, gtol, max_steps: int, trials: int, accepted: int | None = None
) -> str:
    """``stopped_by`` as a sentence with the numbers (``accepted``: the steps taken, resumed ones included)."""
    if stopped_by == "converged":
        if method == "bfgs":
            return f"converged: parameter and loss changes within rtol {rtol:g}, atol {atol:g}"
        return (
            f"converged: projected gradient ∞-norm ≤ gtol {gtol:g}, "
            "no parameter short of a bound its projected gradient step reaches"
        )
    if stopped_by == "max_steps":
        limit = f"step limit: {max_steps} accepted step{'s' * (max_steps != 1)}"
        # a resume with a smaller max_steps than the steps already taken: it took none, and said it stopped at max_steps
        return limit + (f" ({accepted} already taken)" if accepted is not None and accepted > max_steps else "")
    if stopped_by == "stalled":
        return f"stalled: {trials} trials (limit 10 × max_steps) without reaching {max_steps} accepted steps"
    if stopped_by.startswith("unconverged: "):
        return (
            f"failed: the leaf photosynthesis did not converge at {stopped_by.split(': ', 1)[1]} "
            "(a start outside the model's range; SolverConfig sets the solver's limits)"
        )
    if stopped_by.startswith("against unconverged: "):
        return (
            f"stopped at {stopped_by.split(': ', 1)[1]} against a region where the leaf photosynthesis does "
            "not converge: the loss still falls towards it (the gradient is not small), so this is not an optimum"
        )
    return stopped_by


#: χ² tail probability below which a fit is said not to reproduce its data within their SDs.
MISFIT_P = 1e-3
#: Share of a finite search range within which a calibrated value counts as on its edge.
EDGE_SHARE = 1e-3


def on_edge(v: float, lo: float, hi: float) -> bool:
    """Whether ``v`` lies within :data:`EDGE_SHARE` of a finite end of [lo, hi] (of the range's width,
    or of max(|v|, 1) where it is unbounded above)."""
    width = (hi - lo) if math.isfinite(hi) else max(abs(v), 1.0)
    return any(math.isfinite(e) and abs(v - e) <= EDGE_SHARE * width for e in (lo, hi))


def misfit(chi2_value: float, n_values: int, k: int, what: str = "the fit") -> list[str]:
    """A sentence where χ² over ``n_values`` observed values and ``k`` fitted parameters exceeds the χ²
    distribution with n − k degrees of freedom at tail probability :data:`MISFIT_P` (the model does
    not reproduce the data within their SDs), else nothing. ``what`` left that χ² (a calibration's
    fit, a posterior's MAP)."""
    from scipy.stats import chi2

    dof = n_values - k
    if dof > 0 and math.isfinite(chi2_value) and chi2.sf(chi2_value, dof) < MISFIT_P:
        return [
            f"{what} leaves χ² = {chi2_value:.4g} for {n_values} values and {k} parameter{'s' * (k != 1)} "
            f"(χ²/(n − k) = {chi2_value / dof:.3g}, tail probability < {MISFIT_P:g}): the model does not "
            "reproduce the data within their SDs"
        ]
    return []


#: The closing line of fit cautions that a unit slip, SDs too small or a missing process explain.
CHECK_UNITS = "check the observations' units and SDs, and what the model leaves out, before using these values"
#: The closing line where the only caution is a parameter on its box's edge and the fit is good.
EDGE_WITH_GOOD_FIT = (
    "the fit is good (χ² within the data's SDs): an edge can mean the data barely inform that parameter "
    "(lightfit posterior shows its "
    "spread) as well as that they pull it beyond (then check the observations' units and SDs)"
)


def fit_cautions(
    theta: Mapping[str, float],
    names: Sequence[str],
    loss: float,
    n_values: int,
    box: Mapping[str, tuple[float, float]],
    support: Mapping[str, tuple[float, float]],
) -> list[str]:
    r"""What a calibration's result ``theta`` (``names`` calibrated, ``loss`` = ½ rᵀΣ⁻¹r over
    ``n_values`` observed values) warns of, as sentences:

    * a value on the edge of its search ``box`` (within :data:`EDGE_SHARE` of a finite range): the
      data pull it out of the box, so the optimum found is the box's, not the data's;
    * a value outside ``support``, the range its prior gives (e.g. the light factor's 0.25–4): a
      value no posterior would reach;
    * a fit whose χ² = 2·loss exceeds the χ² distribution with n − k degrees of freedom (k = len
      ``names``) at tail probability :data:`MISFIT_P`: the model does not reproduce the data within
      their SDs.

    Each is what a unit slip in the observations (PAR in mmol), SDs too small, or a process the
    model leaves out produce; the numbers of a calibration with a caution are not a fit to trust.
    """
    edges, others = [], []
    for n in names:
        v, (lo, hi) = float(theta[n]), box[n]
        if on_edge(v, lo, hi):
            edges.append(f"{n} = {v:.4g} is on the edge of its search range [{lo:g}, {hi:g}]")
        if n in support and not support[n][0] <= v <= support[n][1]:
            lo, hi = support[n]
            others.append(f"{n} = {v:.4g} lies outside its prior's range [{lo:g}, {hi:g}]")
    others += misfit(2.0 * loss, n_values, len(names))
    # "good" only where χ² could say otherwise: a finite loss and more values than parameters
    judged = math.isfinite(loss) and n_values > len(names)
    if others or (edges and not judged):
        return [*edges, *others, CHECK_UNITS]
    if edges:  # a good fit: a flat direction lets the optimum wander to the box's edge too
        return [*edges, EDGE_WITH_GOOD_FIT]
    return []


__all__ = [
    "CHECK_UNITS",
    "EDGE_WITH_GOOD_FIT",
    "MAX_STEPS",
    "CalibrationResult",
    "Loss",
    "calibrate",
    "check_bounds",
    "check_max_steps",
    "check_start_names",
    "fit_cautions",
    "from_unconstrained",
    "make_loss",
    "misfit",
    "on_edge",
    "to_unconstrained",
]
