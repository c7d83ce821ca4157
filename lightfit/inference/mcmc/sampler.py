"""Run (or resume) an emcee ensemble into a resumable HDF5 file, with a stop rule.

Sampler: :class:`emcee.EnsembleSampler` (affine-invariant stretch move), vectorised over the
walkers (one call of the log-probability per half-ensemble), storing every step through
:class:`~lightfit.inference.mcmc.backend.ResumableHDFBackend`; the stop rule is
:class:`~lightfit.inference.mcmc.diagnostics.StopRule`.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import emcee
import h5py
import numpy as np

from lightfit.errors import InputError
from lightfit.inference.mcmc.backend import ResumableHDFBackend, jsonable, stored_run
from lightfit.inference.mcmc.diagnostics import StopRule, diagnostics
from lightfit.inference.progress import progress_bar


@dataclass
class SamplerResult:
    """What :func:`sample` returns. ``chain``: (n_steps, n_walkers, ndim); ``stopped_by``:
    ``"rule"`` (stop rule met), ``"max_steps"``, ``"max_seconds"`` or ``"interrupted"``."""

    names: tuple
    chain: np.ndarray
    log_prob: np.ndarray
    diagnostics: dict
    path: Path
    stopped_by: str
    seconds: float
    steps_this_call: int


def sample(
    log_prob: Callable[[np.ndarray], np.ndarray],
    names: Sequence[str],
    path: str | Path,
    *,
    nwalkers: int = 32,
    max_steps: int = 5000,
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
        nwalkers: even, ≥ 2·ndim. ``seed``: seeds the sampler's RandomState (and the initial
            positions when ``initial`` is None and ``log_prob`` has ``.initial``).
        max_steps: total steps (including those already stored).
        resume: continue an existing run in ``path`` (same names/walkers required); False starts over.
        stop: :class:`StopRule` (None: run to ``max_steps``).
        attrs: JSON-serialisable metadata stored with the run.
        max_seconds: stop (resumably) after this much wall time in this call.
    """
    names = tuple(names)
    ndim = len(names)
    if ndim == 0:
        raise InputError("no parameters to sample", column="names", expected="at least one parameter")
    if nwalkers < 2 * ndim or nwalkers % 2:
        raise InputError(f"nwalkers={nwalkers}", column="nwalkers", expected=f"an even number ≥ 2·ndim = {2 * ndim}")
    if max_steps < 1:
        raise InputError(f"max_steps={max_steps}", column="max_steps", expected="≥ 1")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    backend = ResumableHDFBackend(str(path), name=group)
    stored = stored_run(path, group) if resume else None
    if stored is not None and stored != (names, nwalkers):
        raise InputError(
            f"{path} holds a run over {list(stored[0])} with {stored[1]} walkers",
            file=path,
            column="names",
            expected=f"the same names {list(names)} and nwalkers={nwalkers}, or resume=False",
        )
    if stored is None:
        state = _start(backend, path, group, log_prob, names, nwalkers, seed, initial, attrs)
    else:
        state = backend.get_last_sample()
    sampler = emcee.EnsembleSampler(nwalkers, ndim, log_prob, vectorize=True, backend=backend, moves=moves)
    sampler.random_state = np.random.RandomState(seed).get_state()  # overwritten by state.random_state
    done = backend.iteration
    todo = max_steps - done
    t0 = time.perf_counter()
    stopped_by = "max_steps"
    tau_prev = None
    k = 0
    with progress_bar("sampling", max_steps, completed=done, show=progress and todo > 0) as bar:
        try:
            steps = sampler.sample(state, iterations=todo, store=True, progress=False) if todo > 0 else ()
            for _ in steps:
                k += 1
                it = backend.iteration
                bar.update(completed=it)
                if stop is not None and it % stop.check_every == 0:
                    d = diagnostics(
                        backend.get_chain(), backend.accepted, burn_fraction=stop.burn_fraction, names=names
                    )
                    bar.update(
                        info=f"τ max {np.nanmax(d['tau']):.1f}  ESS min {np.nanmin(d['ess']):.0f}  "
                        f"acc {d['acceptance_mean']:.2f}"
                    )
                    if stop.check(d, tau_prev):
                        stopped_by = "rule"
                        break
                    tau_prev = d["tau"]
                if max_seconds is not None and time.perf_counter() - t0 > max_seconds:
                    stopped_by = "max_seconds"
                    break
        except KeyboardInterrupt:
            stopped_by = "interrupted"
    chain = backend.get_chain()
    d = diagnostics(chain, backend.accepted, burn_fraction=(stop or StopRule()).burn_fraction, names=names)
    d["rule_met"] = stopped_by == "rule"
    with h5py.File(path, "a") as f:
        f[group].attrs["diagnostics"] = json.dumps(jsonable(d))
        f[group].attrs["stopped_by"] = stopped_by
    return SamplerResult(names, chain, backend.get_log_prob(), d, path, stopped_by, time.perf_counter() - t0, k)


def _start(backend, path, group, log_prob, names, nwalkers, seed, initial, attrs) -> emcee.State:
    """Reset ``backend`` for a new run, store its metadata, return the initial state."""
    backend.reset(nwalkers, len(names))
    with h5py.File(path, "a") as f:
        g = f[group]
        g.attrs["names"] = json.dumps(list(names))
        g.attrs["seed"] = seed
        for k, v in (attrs or {}).items():
            g.attrs[k] = json.dumps(v)
    if initial is None:
        if not hasattr(log_prob, "initial"):
            raise InputError("no initial positions", column="initial", expected="an (nwalkers, ndim) array")
        initial = log_prob.initial(nwalkers, seed)
    initial = np.asarray(initial, float)
    if initial.shape != (nwalkers, len(names)):
        raise InputError(f"initial shape {initial.shape}", column="initial", expected=f"({nwalkers}, {len(names)})")
    return emcee.State(initial, random_state=np.random.RandomState(seed).get_state())


__all__ = ["SamplerResult", "sample"]
