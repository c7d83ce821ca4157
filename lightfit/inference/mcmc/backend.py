"""Resumable HDF5 storage of an emcee run, and reading/writing runs and their analysis groups.

:class:`ResumableHDFBackend` stores, per step, the chain, log-probabilities, acceptance flags
*and the generator state after that step*, and writes the step counter last, so a run killed at
any moment resumes from the last complete step and continues exactly as an uninterrupted run with
the same seed would (tested bit for bit). A partly written step is overwritten. (HDF5 itself has
no journal: a kill in the middle of a metadata write can in principle corrupt the file;
h5py/HDF5 give no stronger guarantee.)

Reading while a run is written: the writer opens the file once per step and closes it again, and
opens it *without* HDF5's file lock (:func:`open_h5`), so a reader that holds the file open — e.g.
``h5py.File(path)`` with h5py's default locking in a notebook — never makes the sampler fail
(emcee's own backend locks and dies with ``BlockingIOError``). Two writers on one file are kept
apart by a separate lock file instead (:func:`writer_lock`). A reader sees the file as of the last
step closed before it opened it (reopen to refresh; a read that coincides with a step's write can
fail and is simply retried, :func:`load_run` does so).
"""

from __future__ import annotations

import contextlib
import dataclasses
import fcntl
import json
import os
import time
from collections.abc import Iterator
from pathlib import Path

import emcee
import h5py
import numpy as np

from lightfit.errors import InputError
from lightfit.files import jsonable
from lightfit.inference.mcmc.diagnostics import StopRule


def open_h5(path: str | Path, mode: str = "r") -> h5py.File:
    """``h5py.File`` without HDF5's file lock: the run file's writer and lightfit's readers use it, so
    that neither blocks on (nor is blocked by) a reader holding the file open (see the module doc)."""
    return h5py.File(path, mode, locking=False)


@contextlib.contextmanager
def writer_lock(path: str | Path) -> Iterator[None]:
    """Hold an exclusive lock on ``<path>.lock`` while a run is written: a second writer of the same
    run file gets an :class:`InputError` instead of interleaving its steps (the HDF5 file itself is
    opened unlocked, :func:`open_h5`). The lock dies with its process (SIGKILL included). The empty
    lock file is left in place: unlinking it would race a writer that has it open but not yet locked."""
    lock = Path(f"{path}.lock")
    lock.parent.mkdir(parents=True, exist_ok=True)
    fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise InputError(
                "another process is writing this run", file=path, expected="one writer per run file (or another --out)"
            ) from None
        yield
    finally:
        os.close(fd)  # releases the lock


#: Reads of a run file :func:`_retry` makes, and the wait between them (s).
_READ_ATTEMPTS, _READ_WAIT_S = 20, 0.1


def _retry(read):
    """``read()``, retried (:data:`_READ_ATTEMPTS` times, :data:`_READ_WAIT_S` apart) when it
    coincides with the writer's step (OSError/KeyError from a half-written file, seen by a reader
    that opened it mid-step)."""
    for i in range(_READ_ATTEMPTS):
        try:
            return read()
        except (OSError, KeyError):
            if i == _READ_ATTEMPTS - 1:
                raise
            time.sleep(_READ_WAIT_S)


#: ``units`` and ``long_name`` of a run file's datasets, by their name in their group; datasets named
#: as a results variable (the predictive group's observables) take the results schema's instead. The
#: sampled parameters are all dimensionless (lightfit.model.parameters).
DESCRIPTIONS = {
    "chain": ("1", "walker positions (step, walker, parameter); the parameters are the group's 'names'"),
    "log_prob": ("1", "natural log of the unnormalised posterior density (step, walker)"),
    "accepted": ("1", "accepted moves per walker over the run"),
    "accepted_step": ("1", "whether each walker's move was accepted (step, walker)"),
    "rng_key": ("1", "the sampler's Mersenne Twister state after each step (resume)"),
    "rng_meta": ("1", "the sampler's generator position, has-Gaussian flag and cached Gaussian (resume)"),
    "check_step": ("1", "steps at which the stop rule checked"),
    "check_tau": ("1", "integrated autocorrelation time per parameter at each check, in steps"),
    "check_ess": ("1", "effective sample size per parameter at each check"),
    "matrix": ("1", "Fisher information of the log-likelihood in log-parameter space (d log theta)"),
    "eigenvalues": ("1", "the Fisher matrix's eigenvalues (stiff: large; sloppy: small)"),
    "eigenvectors": ("1", "the Fisher matrix's eigenvectors (columns), in log-parameter space"),
    "direction": ("1", "the profiled combination's direction in log-parameter space"),
    "t": ("1", "distance along the profiled direction in log-parameter space"),
    "profile_nll": ("1", "negative log-likelihood minimised over the other parameters at each t"),
    "slice_nll": ("1", "negative log-likelihood with the other parameters held at the MAP at each t"),
    "in_prior_box": ("1", "whether the point at t lies inside the priors' supports"),
    "x_map": ("1", "maximum a posteriori parameters (the run's 'names')"),
    "mean": ("1", "posterior mean per parameter"),
    "sd": ("1", "posterior standard deviation per parameter"),
    "q05": ("1", "posterior 5 % quantile per parameter"),
    "q50": ("1", "posterior median per parameter"),
    "q95": ("1", "posterior 95 % quantile per parameter"),
    "corr": ("1", "posterior correlation matrix of the parameters"),
}


def describe(dataset, scale: str = "log") -> None:
    """Set a dataset's ``units`` and ``long_name`` from :data:`DESCRIPTIONS` or the results schema;
    ``scale``: the coordinates of an identifiability group (``"natural"``: the parameters themselves,
    where the MAP sits on a zero bound, :func:`lightfit.inference.posterior.identifiability`)."""
    from lightfit.model import schema

    name = dataset.name.rsplit("/", 1)[-1]
    if name in schema.VARIABLES:
        units, long_name = schema.units(name), schema.variable(name).attrs().get("long_name", name)
    elif name in DESCRIPTIONS:
        units, long_name = DESCRIPTIONS[name]
    else:
        return
    if scale == "natural":
        long_name = long_name.replace("log-parameter space (d log theta)", "parameter space (d theta)")
        long_name = long_name.replace("log-parameter space", "parameter space")
    dataset.attrs["units"], dataset.attrs["long_name"] = units, long_name


class ResumableHDFBackend(emcee.backends.HDFBackend):
    """HDFBackend whose generator state and acceptance flags are stored per step (see module doc),
    opened without HDF5's file lock (readers never disturb it). ``refused``: a callable giving the
    run's count of refused proposals so far, stored with each step (attribute ``refused``)."""

    refused = None

    def open(self, mode="r"):
        if self.read_only and mode != "r":
            raise RuntimeError("the backend is read-only")
        f = open_h5(self.filename, mode)
        if not self.dtype_set and self.name in f and "chain" in f[self.name]:
            self.dtype, self.dtype_set = f[self.name]["chain"].dtype, True
        return f

    def reset(self, nwalkers, ndim):
        super().reset(nwalkers, ndim)
        with self.open("a") as f:
            g = f[self.name]
            g.create_dataset("rng_key", (0, 624), maxshape=(None, 624), dtype=np.uint32)
            g.create_dataset("rng_meta", (0, 3), maxshape=(None, 3), dtype=np.float64)
            g.create_dataset("accepted_step", (0, nwalkers), maxshape=(None, nwalkers), dtype=bool)
            for d in g.values():
                if isinstance(d, h5py.Dataset):
                    describe(d)

    def grow(self, ngrow, blobs):
        super().grow(ngrow, blobs)
        with self.open("a") as f:
            g = f[self.name]
            n = g["chain"].shape[0]
            for k in ("rng_key", "rng_meta", "accepted_step"):
                g[k].resize(n, axis=0)

    def save_step(self, state, accepted):
        self._check(state, accepted)
        with self.open("a") as f:
            g = f[self.name]
            i = int(g.attrs["iteration"])
            g["chain"][i, :, :] = state.coords
            g["log_prob"][i, :] = state.log_prob
            if state.blobs is not None:
                g["blobs"][i, :] = state.blobs
            _, key, pos, has_gauss, cached = state.random_state
            g["rng_key"][i, :] = np.asarray(key, np.uint32)
            g["rng_meta"][i, :] = (pos, has_gauss, cached)
            g["accepted_step"][i, :] = accepted
            g["accepted"][:] = g["accepted_step"][: i + 1].sum(axis=0)
            if self.refused is not None:
                g.attrs["refused"] = int(self.refused())
            g.attrs["iteration"] = i + 1  # last: commits the step

    def get_accepted_steps(self) -> np.ndarray:
        """Each stored step's acceptance flags, (iteration, nwalkers) booleans (a run stored before
        they were: each walker's count over the run, (nwalkers,))."""
        with self.open() as f:
            g = f[self.name]
            return g["accepted_step"][: int(g.attrs["iteration"])] if "accepted_step" in g else g["accepted"][:]

    @property
    def random_state(self):
        with self.open() as f:
            g = f[self.name]
            i = int(g.attrs["iteration"])
            if i == 0 or "rng_key" not in g:
                return None
            pos, has_gauss, cached = g["rng_meta"][i - 1]
            return ("MT19937", np.asarray(g["rng_key"][i - 1], np.uint32), int(pos), int(has_gauss), float(cached))


def stored_run(path: Path, group: str) -> tuple[tuple[str, ...], int] | None:
    """(names, nwalkers) of a run with at least one step stored in ``path``/``group``, else None."""
    if not path.exists():
        return None
    with open_h5(path) as f:
        if group not in f or int(f[group].attrs.get("iteration", 0)) == 0:
            return None
        g = f[group]
        return tuple(json.loads(g.attrs.get("names", "[]"))), int(g.attrs["nwalkers"])


def load_run(path: str | Path, group: str = "mcmc") -> dict:
    """Read a stored run: ``names``, ``chain`` (n, walkers, ndim), ``log_prob``, ``accepted``, ``attrs``
    (JSON-decoded), ``diagnostics`` (recomputed with the run's own ``stop_rule``, a
    :class:`~lightfit.inference.mcmc.diagnostics.StopRule`), the stop rule's ``checks`` (step, τ, ESS
    per check) and any analysis groups written next to it (the Fisher eigenvectors and the profile's
    direction oriented as their combination strings read, :func:`oriented_analysis`: older runs stored
    some mirrored). Safe while the run is being written (see the module doc)."""
    path = Path(path)
    if not path.exists():
        raise InputError("file not found", file=path, expected="an HDF5 file written by lightfit.inference.mcmc")
    return _retry(lambda: _load_run(path, group))


def run_attrs(path: str | Path, group: str = "mcmc") -> dict:
    """A stored run's attributes (JSON-decoded, as :func:`load_run`'s ``attrs``) without reading its
    chain or computing its diagnostics: what the resume checks compare."""
    path = Path(path)
    if not path.exists():
        raise InputError("file not found", file=path, expected="an HDF5 file written by lightfit.inference.mcmc")

    def read():
        with open_h5(path) as f:
            if group not in f:
                raise InputError(f"no group {group!r}", file=path, expected="a posterior run")
            return _decoded_attrs(f[group])

    return _retry(read)


def _decoded_attrs(g) -> dict:
    out = {}
    for k, v in g.attrs.items():
        try:
            out[k] = json.loads(v) if isinstance(v, str) else (v.item() if hasattr(v, "item") else v)
        except (json.JSONDecodeError, TypeError):
            out[k] = v
    return out


def _load_run(path: Path, group: str) -> dict:
    with open_h5(path) as f:
        if group not in f:
            raise InputError(f"no group {group!r}", file=path, expected="a posterior run")
        g = f[group]
        n = int(g.attrs["iteration"])
        out = {
            "names": tuple(json.loads(g.attrs["names"])),
            "chain": g["chain"][:n],
            "log_prob": g["log_prob"][:n],
            "accepted": g["accepted_step"][:n].sum(axis=0) if "accepted_step" in g else g["accepted"][:],
            # each step's flags (runs stored before them: None, and the acceptance is over all steps)
            "accepted_step": g["accepted_step"][:n] if "accepted_step" in g else None,
            "checks": {k: g[f"check_{k}"][:] for k in ("step", "tau", "ess") if f"check_{k}" in g},
            "attrs": _decoded_attrs(g),
        }
        if "analysis" in f:
            out["analysis"] = oriented_analysis(_read_group(f["analysis"]))
    # With the run's own stop rule (its burn-in and τ multiple), as the sampler judged the run.
    rule = out["attrs"].get("stop_rule")
    known = {f.name for f in dataclasses.fields(StopRule)}
    stop = StopRule(**{k: v for k, v in rule.items() if k in known}) if isinstance(rule, dict) else StopRule()
    flags = out["accepted"] if out["accepted_step"] is None else out["accepted_step"]
    out["diagnostics"] = stop.diagnostics(out["chain"], flags, names=out["names"])
    out["stop_rule"] = stop  # the rule the run was sampled under (thresholds to judge it by)
    return out


def writer_running(path: str | Path) -> bool:
    """Whether a process holds the run's writer lock (:func:`writer_lock`) now. Probed with a shared
    non-blocking lock taken and released at once (a writer starting in that instant would be refused)."""
    lock = Path(f"{path}.lock")
    if not lock.exists():
        return False
    fd = os.open(lock, os.O_RDONLY)
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        return False
    except BlockingIOError:
        return True
    finally:
        os.close(fd)


def run_status(path: str | Path, group: str = "mcmc") -> dict:
    """Progress of a run being written or finished: ``steps``, ``max_steps``, ``state`` (``"running"``,
    ``"stopped"`` with ``stopped_by``, or ``"killed"`` — a call that ended without recording why, e.g.
    SIGKILL; resumable), per-parameter τ, ESS (:func:`diagnostics` on the stored chain), acceptance,
    the stop rule's last check (step, τ, ESS) and ``refused`` (proposals refused so far: the leaf
    photosynthesis did not converge or the likelihood was not finite). Reads without locking."""
    run = load_run(path, group)
    a = run["attrs"]
    stopped_by = a.get("stopped_by")
    if writer_running(path):
        state = "running"
    elif stopped_by in (None, "running"):
        state = "killed"
    else:
        state = "stopped"
    checks = run["checks"]
    last = None
    if len(checks.get("step", [])):
        last = {"step": int(checks["step"][-1]), "tau": checks["tau"][-1], "ess": checks["ess"][-1]}
    return {
        "path": str(path),
        "names": run["names"],
        "steps": len(run["chain"]),
        "max_steps": a.get("max_steps"),
        "state": state,
        "stopped_by": None if stopped_by == "running" else stopped_by,
        "diagnostics": run["diagnostics"],
        "last_check": last,
        "analysis": "analysis" in run,
        "map_search": run.get("analysis", {}).get("map_search"),
        "emulator_error": run.get("analysis", {}).get("emulator_error"),
        "fit": run.get("analysis", {}).get("fit"),  # the MAP's χ² and the priors' say (absent in older runs)
        "refused": int(a.get("refused", 0)),
    }


#: The stored profile's per-point arrays, one value per offset ``t``.
PROFILE_POINTS = ("t", "profile_nll", "slice_nll", "in_prior_box")


def oriented_analysis(an: dict) -> dict:
    """A stored ``analysis`` group with its Fisher eigenvectors (columns) and profile ``direction``
    oriented as the combination strings beside them read (largest entry positive,
    :func:`lightfit.inference.identifiability.combination`). Runs written before the eigenvectors
    were oriented kept eigh's arbitrary sign: a profile stored along ``-d`` read against the
    combination of ``d`` was mirrored. A mirrored direction is flipped with its offsets ``t`` (and the
    profile's points reordered so that ``t`` still ascends); an oriented run is returned as stored."""
    from lightfit.inference.identifiability import oriented

    fisher, profile = an.get("fisher"), an.get("profile")
    if isinstance(fisher, dict) and np.ndim(fisher.get("eigenvectors")) == 2:
        fisher["eigenvectors"] = oriented(fisher["eigenvectors"])
    if isinstance(profile, dict) and np.ndim(profile.get("direction")) == 1 and "t" in profile:
        d = np.asarray(profile["direction"], float)
        if np.dot(oriented(d), d) < 0:  # stored along the opposite of its combination
            profile["direction"] = -d
            profile["t"] = -np.asarray(profile["t"])
            for k in PROFILE_POINTS:  # t ascending again
                if k in profile:
                    profile[k] = np.asarray(profile[k])[::-1]
    return an


def _read_group(g) -> dict:
    out = {}
    for k, v in g.items():
        out[k] = _read_group(v) if isinstance(v, h5py.Group) else v[()]
    for k, v in g.attrs.items():
        out[k] = json.loads(v) if isinstance(v, str) else v
    return out


def write_group(path: str | Path, name: str, data: dict) -> None:
    """Write (replace) HDF5 group ``name``: numeric arrays as datasets, dicts as subgroups, anything
    else as JSON attributes."""
    with open_h5(path, "a") as f:
        if name in f:
            del f[name]
        _write(f.create_group(name), data)


def drop_group(path: str | Path, name: str) -> None:
    """Remove HDF5 group ``name`` if the file has it (e.g. an analysis of a chain since extended)."""
    with open_h5(path, "a") as f:
        if name in f:
            del f[name]


def _write(g, data: dict):
    for k, v in data.items():
        if isinstance(v, dict):
            _write(g.create_group(k), v)
        elif isinstance(v, np.ndarray) and v.dtype.kind in "fiub":
            describe(g.create_dataset(k, data=v), data.get("scale", "log"))
        else:
            g.attrs[k] = json.dumps(jsonable(v))


__all__ = [
    "DESCRIPTIONS",
    "ResumableHDFBackend",
    "describe",
    "drop_group",
    "jsonable",
    "load_run",
    "open_h5",
    "run_status",
    "stored_run",
    "write_group",
    "writer_lock",
    "writer_running",
]
