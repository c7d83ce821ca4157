"""Run (or resume) an emcee ensemble into a resumable HDF5 file, with a stop rule.

Sampler: :class:`emcee.EnsembleSampler` with differential evolution and stretch moves (:func:`default_moves`),
vectorised over the walkers (one call of the log-probability per half-ensemble), storing every step through
:class:`~lightfit.inference.mcmc.backend.ResumableHDFBackend`; the stop rule is
:class:`~lightfit.inference.mcmc.diagnostics.StopRule`.
"""

from __future__ import annotations

import dataclasses
import hashlib
import inspect
import json
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

import emcee
import numpy as np

from lightfit.errors import InputError, check_integer
from lightfit.inference.mcmc.backend import ResumableHDFBackend, describe, jsonable, open_h5, stored_run, writer_lock
from lightfit.inference.mcmc.diagnostics import StopRule
from lightfit.killpoint import kill_point
from lightfit.progress import progress_bar

#: Walkers and total steps of a run unless given (the stop rule usually ends a run earlier).
WALKERS = 32
MAX_STEPS = 4000


@dataclass
class SamplerResult:
    """What :func:`sample` returns. ``chain``: (n_steps, n_walkers, ndim); ``stopped_by``:
    ``"rule"`` (stop rule met), ``"max_steps"``, ``"max_seconds"`` or ``"interrupted"`` (the last two
    are resumable; the file also keeps ``stopped_by`` and ``stopped_at``, the step count at the end).
    ``refused``: proposals inside the priors that the log-probability refused (−inf: the leaf
    photosynthesis did not converge, :meth:`LogPosterior.log_prob_refused`), over all calls on the
    file (its ``refused`` attribute)."""

    names: tuple
    chain: np.ndarray
    log_prob: np.ndarray
    diagnostics: dict
    path: Path
    stopped_by: str
    seconds: float
    steps_this_call: int
    refused: int = 0


def check_run_size(ndim: int, nwalkers: int, max_steps: int, seed: int = 0, seed_name: str = "seed") -> None:
    """emcee's red-blue moves (stretch, differential evolution) need an even number of walkers, at
    least two per parameter, and differential evolution a pair of walkers in the other half (four
    at least); a run needs a step, and numpy's RandomState a ``seed`` ≥ 0 (``seed_name``: how the
    caller names it). :class:`InputError` naming the value otherwise (before anything is rendered)."""
    if ndim == 0:
        raise InputError("no parameters to sample", parameter="names", expected="at least one parameter")
    least = max(2 * ndim, 4)
    if nwalkers < least or nwalkers % 2:
        raise InputError(
            f"nwalkers={nwalkers}", parameter="nwalkers", expected=f"an even number ≥ max(2·ndim, 4) = {least}"
        )
    check_integer(max_steps, "max_steps", 1)
    check_integer(seed, seed_name, 0, why="numpy's RandomState takes seeds 0 … 2³² − 1")


def check_max_steps(stored_steps: int, max_steps: int, path: str | Path | None = None) -> None:
    """Refuse resuming a chain of ``stored_steps`` with a ``max_steps`` below it: ``max_steps`` is
    the total (stored steps included), so such a resume samples nothing, and the status read e.g.
    "120/60 steps". :class:`InputError` naming ``--max-steps`` and the stored length."""
    if max_steps < stored_steps:
        raise InputError(
            f"max_steps={max_steps}, below the {stored_steps} steps the stored chain already has (max_steps counts "
            "them: nothing would be sampled)",
            file=path,
            parameter="max-steps",
            expected=f"--max-steps ≥ {stored_steps} (the total; {stored_steps} re-analyses the chain as it is), or "
            "--no-resume (resume=False) to start again",
        )


def sample(
    log_prob: Callable[[np.ndarray], np.ndarray],
    names: Sequence[str],
    path: str | Path,
    *,
    nwalkers: int = WALKERS,
    max_steps: int = MAX_STEPS,
    seed: int = 0,
    initial: np.ndarray | None = None,
    resume: bool = True,
    stop: StopRule | None = None,
    progress: bool = True,
    group: str = "mcmc",
    attrs: dict | None = None,
    max_seconds: float | None = None,
    moves=None,
) -> SamplerResult:
    """Run (or resume) an emcee ensemble over ``names`` with the vectorised ``log_prob`` into HDF5 ``path``.

    Args:
        log_prob: ``f(xs: (n, ndim)) -> (n,)`` (e.g. :class:`LogPosterior`).
        nwalkers: even, ≥ max(2·ndim, 4). ``seed``: seeds the sampler's RandomState (and the initial
            positions when ``initial`` is None and ``log_prob`` has ``.initial``); a resumed run
            continues the generator state stored with its last step, so ``seed`` is not consulted
            then (:func:`lightfit.inference.posterior.run` refuses another seed).
        initial: (nwalkers, ndim) starting positions of a new run (their SHA-256 is stored as
            ``initial_sha256``); a resumed run continues from its last stored step, and one given
            other positions than it started from is refused.
        max_steps: total steps (including those already stored).
        resume: continue an existing run in ``path`` (same names/walkers required); False starts over.
        stop: :class:`StopRule` (None: run to ``max_steps``).
        attrs: JSON-serialisable metadata stored with the run when it starts (not rewritten on resume).
        max_seconds: stop (resumably) after this much wall time in this call.
        moves: emcee moves (None: :func:`default_moves` for a new run, and a resumed run's own
            where it was sampled with emcee's stretch move, the default before); described in the
            ``moves`` attribute (class, weight, parameters), and a resume with other moves is
            refused. Callables inside a move are described by name only.
    """
    names = tuple(names)
    check_run_size(len(names), nwalkers, max_steps, seed)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with writer_lock(path):
        return _sample(
            log_prob,
            names,
            path,
            nwalkers,
            max_steps,
            seed,
            initial,
            resume,
            stop,
            progress,
            group,
            attrs,
            max_seconds,
            moves,
        )


def _sample(
    log_prob, names, path, nwalkers, max_steps, seed, initial, resume, stop, progress, group, attrs, max_seconds, moves
) -> SamplerResult:
    ndim = len(names)
    backend = ResumableHDFBackend(str(path), name=group)
    stored = stored_run(path, group) if resume else None
    if stored is not None and stored != (names, nwalkers):
        raise InputError(
            f"{path} holds a run over {list(stored[0])} with {stored[1]} walkers",
            file=path,
            parameter="names",
            expected=(
                f"the same names {list(names)} and nwalkers={nwalkers}, or --no-resume (resume=False) to start again"
            ),
        )
    if moves is None:
        moves = default_moves() if stored is None else _own_moves(path, group)
    if stored is None:
        state = _start(backend, path, group, log_prob, names, nwalkers, seed, initial, attrs, moves)
    else:
        _check_resumed(path, group, initial, moves)
        check_max_steps(backend.iteration, max_steps, path)
        state = backend.get_last_sample()
    refused_stored = 0  # refusals of the steps stored so far: a resumed run goes on counting
    if stored is not None:
        with open_h5(path) as f:
            refused_stored = int(f[group].attrs.get("refused", 0))
    refused_before = getattr(log_prob, "refused", 0)
    backend.refused = lambda: refused_stored + getattr(log_prob, "refused", 0) - refused_before
    sampler = emcee.EnsembleSampler(nwalkers, ndim, log_prob, vectorize=True, backend=backend, moves=moves)
    # emcee's wrapper (for args/kwargs, which this call has none of) prints its own traceback for any
    # exception, a user's Ctrl-C included, before lightfit's "interrupted" line: called directly.
    sampler.log_prob_fn = log_prob
    sampler.random_state = np.random.RandomState(seed).get_state()  # overwritten by state.random_state
    done = backend.iteration
    with open_h5(path, "a") as f:  # what `lightfit posterior-status` shows while this call runs
        f[group].attrs["max_steps"] = max_steps
        f[group].attrs["stopped_by"] = "running"
    checks = _Checks(backend, stop, names)
    t0 = time.perf_counter()
    stopped_by = "max_steps"
    k = 0
    # A run stopped by the rule (or killed between its last step and that step's check) is not extended:
    # the check at the last stored step is made (again) first; it is a pure function of the chain.
    if checks.due(done) and checks.met(done):
        stopped_by = "rule"
    todo = 0 if stopped_by == "rule" else max_steps - done
    with progress_bar("sampling", max_steps, completed=done, show=progress and todo > 0) as bar:
        try:
            steps = sampler.sample(state, iterations=todo, store=True, progress=False) if todo > 0 else ()
            for _ in steps:
                k += 1
                it = backend.iteration
                bar.update(completed=it)
                kill_point("sample", it)
                if checks.due(it):
                    met = checks.met(it)
                    d = checks.last
                    bar.update(info=_bar_info(d))
                    if met:
                        stopped_by = "rule"
                        break
                if max_seconds is not None and time.perf_counter() - t0 > max_seconds:
                    stopped_by = "max_seconds"
                    break
        except KeyboardInterrupt:
            if backend.iteration == 0:  # nothing stored to report (Ctrl-C in the first step's compile)
                raise
            stopped_by = "interrupted"
    chain = backend.get_chain()
    d = (stop or StopRule()).diagnostics(chain, backend.get_accepted_steps(), names=names)
    d["rule_met"] = stopped_by == "rule"
    with open_h5(path, "a") as f:
        # strict JSON (jq and JavaScript refuse NaN): τ, ESS and R̂ of a chain too short for them are null
        f[group].attrs["diagnostics"] = json.dumps(jsonable(d, strict=True), allow_nan=False)
        f[group].attrs["stopped_by"] = stopped_by
        f[group].attrs["stopped_at"] = len(chain)
        refused = int(f[group].attrs.get("refused", 0))
    return SamplerResult(
        names, chain, backend.get_log_prob(), d, path, stopped_by, time.perf_counter() - t0, k, refused
    )


def _bar_info(d: dict) -> str:
    """The progress bar's τ, ESS and acceptance; "–" where no τ is finite (a chain too short, or a
    walker that never moved: emcee's τ is NaN then, and numpy warned of an all-NaN slice)."""
    tau, ess = np.asarray(d["tau"], float), np.asarray(d["ess"], float)
    if not np.isfinite(tau).any():
        return f"τ max –  ESS min –  acc {d['acceptance_mean']:.2f}"
    return f"τ max {np.nanmax(tau):.1f}  ESS min {np.nanmin(ess):.0f}  acc {d['acceptance_mean']:.2f}"


class _Checks:
    """The stop rule's checks of a run, kept in the run file (``check_step``, ``check_tau``, ``check_ess``,
    one row per check) so that a resumed run decides exactly as an uninterrupted one: the check at step
    n compares τ with the check at n − check_every, which a resumed process did not see. Rows missing
    after a kill (between a step and its check) are recomputed from the stored chain, as are all rows
    when the stored ones were made with another rule (``stop_rule`` attribute)."""

    def __init__(self, backend: ResumableHDFBackend, stop: StopRule | None, names):
        self.backend, self.stop, self.names = backend, stop, names
        self.rows: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # step → (τ, ESS)
        self.last: dict = {}
        if stop is None:
            return
        rule = json.dumps(dataclasses.asdict(stop))
        done = backend.iteration
        with backend.open("a") as f:
            g = f[backend.name]
            for k in ("step", "tau", "ess"):
                if f"check_{k}" not in g:
                    shape = (0,) if k == "step" else (0, len(names))
                    describe(g.create_dataset(f"check_{k}", shape, maxshape=(None, *shape[1:]), dtype=float))
            if g.attrs.get("stop_rule") == rule:
                for s, tau, ess in zip(g["check_step"][:], g["check_tau"][:], g["check_ess"][:]):
                    if s <= done:
                        self.rows[int(s)] = (tau, ess)
            g.attrs["stop_rule"] = rule
        missing = [s for s in range(stop.check_every, done + 1, stop.check_every) if s not in self.rows]
        if missing:
            chain = backend.get_chain()
            for s in missing:
                d = self._diagnostics(chain[:s], None)
                self.rows[s] = (d["tau"], d["ess"])
        self._write()

    def due(self, step: int) -> bool:
        return self.stop is not None and step > 0 and step % self.stop.check_every == 0

    def _diagnostics(self, chain, accepted) -> dict:
        return self.stop.diagnostics(chain, accepted, names=self.names)

    def met(self, step: int) -> bool:
        """Check the rule at ``step`` (the last stored step), record τ and ESS, return whether it is met."""
        d = self._diagnostics(self.backend.get_chain(), self.backend.get_accepted_steps())
        self.last = d
        self.rows[step] = (d["tau"], d["ess"])
        self._write()
        prev = self.rows.get(step - self.stop.check_every)
        return self.stop.check(d, None if prev is None else prev[0])

    def _write(self) -> None:
        steps = sorted(self.rows)
        shape = (len(steps), len(self.names))
        data = {
            "step": np.asarray(steps, float),
            "tau": np.array([self.rows[s][0] for s in steps]).reshape(shape),
            "ess": np.array([self.rows[s][1] for s in steps]).reshape(shape),
        }
        with self.backend.open("a") as f:
            g = f[self.backend.name]
            for k, v in data.items():
                g[f"check_{k}"].resize(len(steps), axis=0)
                g[f"check_{k}"][...] = v


def _start(backend, path, group, log_prob, names, nwalkers, seed, initial, attrs, moves) -> emcee.State:
    """Reset ``backend`` for a new run, store its metadata, return the initial state."""
    # The positions are made and checked before the reset: a bad ``initial`` leaves the file as it was.
    if initial is None:
        if not hasattr(log_prob, "initial"):
            raise InputError("no initial positions", parameter="initial", expected="an (nwalkers, ndim) array")
        initial = log_prob.initial(nwalkers, seed)
    initial = np.asarray(initial, float)
    if initial.shape != (nwalkers, len(names)):
        raise InputError(f"initial shape {initial.shape}", parameter="initial", expected=f"({nwalkers}, {len(names)})")
    bad = np.argwhere(~np.isfinite(initial))
    if len(bad):  # emcee said "Initial state has a large condition number" of a NaN
        w, j = bad[0]
        raise InputError(
            f"initial[{w}, {j}] = {initial[w, j]} (walker {w}, {names[j]}; {len(bad)} non-finite values in all)",
            parameter="initial",
            expected="finite starting positions",
        )
    backend.reset(nwalkers, len(names))
    with open_h5(path, "a") as f:
        g = f[group]
        g.attrs["names"] = json.dumps(list(names))
        g.attrs["seed"] = seed
        g.attrs["initial_sha256"] = _digest(initial)
        g.attrs["moves"] = json.dumps(describe_moves(moves))
        for k, v in (attrs or {}).items():
            g.attrs[k] = json.dumps(v)
    return emcee.State(initial, random_state=np.random.RandomState(seed).get_state())


def _digest(initial: np.ndarray) -> str:
    return hashlib.sha256(np.ascontiguousarray(initial, np.float64).tobytes()).hexdigest()


def _check_resumed(path: Path, group: str, initial, moves) -> None:
    """Refuse to resume a run with other explicit starting positions or other moves than it was
    started with (both would be silently ignored or mix two samplers in one chain). Runs stored
    before these were recorded (no attribute) are resumed unchecked."""
    with open_h5(path) as f:
        a = f[group].attrs
        stored_initial, stored_moves = a.get("initial_sha256"), a.get("moves")
    if initial is not None and stored_initial is not None and _digest(np.asarray(initial, float)) != stored_initial:
        raise InputError(
            "the run there started from other initial positions; a resumed run continues from its last stored step",
            file=path,
            parameter="initial",
            expected="the run's own initial positions (or none), or --no-resume (resume=False) to start again",
        )
    if stored_moves is not None and json.loads(stored_moves) != describe_moves(moves):
        raise InputError(
            f"the run there was sampled with other moves ({json.loads(stored_moves)} → {describe_moves(moves)})",
            file=path,
            parameter="moves",
            expected="the run's own moves to resume, or --no-resume (resume=False) to start again",
        )


def default_moves() -> list:
    r"""The moves of a new run: differential evolution (ter Braak 2006, Stat. Comput. 16:239; emcee's
    :class:`~emcee.moves.DEMove`) with weight 0.8 and the stretch move (Goodman & Weare 2010; emcee's
    default) with 0.2. Differential evolution proposes x + γ (z₁ − z₂), z₁ ≠ z₂ two walkers of the
    other half, γ = 2.38/√(2d)·(1 + 10⁻⁵ ε): its jumps follow the ensemble's spread, so along
    lightfit's flat directions and ridges it mixes in fewer steps than the stretch move, and it
    carries walkers between separated modes. Alone it leaves a walker that starts far out in a
    prior's tail there for hundreds of steps (its jumps are the ensemble's small differences); the
    stretch move's share pulls such walkers in. Measured (``experiments/mcmc_moves.py``,
    docs/posterior.md "Moves"): 2–5× fewer steps to the stop rule, with posterior means about as close
    to the truth there. emcee's snooker move is not used: in emcee 3.1.6 it samples a
    Gaussian's variances 14–21 % low (the same experiment). New objects each call."""
    return [(emcee.moves.DEMove(), 0.8), (emcee.moves.StretchMove(), 0.2)]


def _own_moves(path: Path, group: str):
    """The moves to resume a run with when none are given: its own if they are emcee's stretch move
    (runs started before :func:`default_moves`, including those from before moves were recorded) or
    lightfit's default; otherwise the default, which :func:`_check_resumed` then refuses, naming both."""
    with open_h5(path) as f:
        stored = f[group].attrs.get("moves")
    stretch = emcee.moves.StretchMove()
    if stored is None or json.loads(stored) == describe_moves(stretch):
        return stretch
    return default_moves()


def describe_moves(moves) -> list[dict]:
    """emcee ``moves`` (as :class:`emcee.EnsembleSampler` takes them: None, a move, a list of moves or
    of (move, weight)) as JSON: per move its class, normalised weight and parameters (arrays as lists,
    nested objects by class and parameters, callables by name). None: :func:`default_moves`."""
    if moves is None:
        moves = default_moves()
    if not isinstance(moves, Iterable):  # one move (emcee's own test)
        pairs = [(moves, 1.0)]
    else:
        pairs = [tuple(m) if isinstance(m, (tuple, list)) else (m, 1.0) for m in moves]
    total = float(sum(w for _, w in pairs))
    return [{"move": _qualname(m), "weight": float(w) / total, **_params(m)} for m, w in pairs]


def _qualname(obj) -> str:
    return f"{type(obj).__module__}.{type(obj).__qualname__}"


def _params(obj, depth: int = 0) -> dict:
    # emcee's DEMove.setup stores its γ (from gamma0 and the run's dimension) as g0 at the first step:
    # a used move would describe otherwise than a new one with the same parameters.
    skip = {"g0"} if isinstance(obj, emcee.moves.DEMove) else set()
    return {k: _value(v, depth) for k, v in sorted(getattr(obj, "__dict__", {}).items()) if k not in skip}


def _value(v, depth: int):
    """One parameter of a move as JSON: numbers and text as they are, arrays as lists, functions by
    name (two lambdas look alike), other objects by class and (two levels deep) their parameters."""
    if v is None or isinstance(v, (bool, int, float, str)):
        return v
    if isinstance(v, (np.ndarray, np.generic)):
        return v.tolist()
    if isinstance(v, (list, tuple)):
        return [_value(x, depth) for x in v]
    if inspect.isroutine(v):
        return f"{getattr(v, '__module__', '')}.{getattr(v, '__qualname__', repr(v))}"
    if hasattr(v, "__dict__") and depth < 2:
        return {"class": _qualname(v), **_params(v, depth + 1)}
    return _qualname(v)


__all__ = ["SamplerResult", "check_run_size", "default_moves", "describe_moves", "sample"]
