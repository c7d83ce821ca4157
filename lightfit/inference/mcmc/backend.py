"""Resumable HDF5 storage of an emcee run, and reading/writing runs and their analysis groups.

:class:`ResumableHDFBackend` stores, per step, the chain, log-probabilities, acceptance flags
*and the generator state after that step*, and writes the step counter last, so a run killed at
any moment resumes from the last complete step and continues exactly as an uninterrupted run with
the same seed would (tested bit for bit). A partly written step is overwritten. (HDF5 itself has
no journal: a kill in the middle of a metadata write can in principle corrupt the file;
h5py/HDF5 give no stronger guarantee.)
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import emcee
import h5py
import numpy as np

from lightfit.errors import InputError
from lightfit.inference.mcmc.diagnostics import diagnostics


class ResumableHDFBackend(emcee.backends.HDFBackend):
    """HDFBackend whose generator state and acceptance flags are stored per step (see module doc)."""

    def reset(self, nwalkers, ndim):
        super().reset(nwalkers, ndim)
        with self.open("a") as f:
            g = f[self.name]
            g.create_dataset("rng_key", (0, 624), maxshape=(None, 624), dtype=np.uint32)
            g.create_dataset("rng_meta", (0, 3), maxshape=(None, 3), dtype=np.float64)
            g.create_dataset("accepted_step", (0, nwalkers), maxshape=(None, nwalkers), dtype=bool)

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
            g.attrs["iteration"] = i + 1  # last: commits the step

    @property
    def random_state(self):
        with self.open() as f:
            g = f[self.name]
            i = int(g.attrs["iteration"])
            if i == 0 or "rng_key" not in g:
                return None
            pos, has_gauss, cached = g["rng_meta"][i - 1]
            return ("MT19937", np.asarray(g["rng_key"][i - 1], np.uint32), int(pos), int(has_gauss), float(cached))


def jsonable(d: Any) -> Any:
    """``d`` with numpy arrays and scalars turned into lists and Python numbers (for ``json.dumps``)."""
    if isinstance(d, dict):
        return {k: jsonable(v) for k, v in d.items()}
    if isinstance(d, (list, tuple)):
        return [jsonable(v) for v in d]
    if isinstance(d, np.ndarray):
        return d.tolist()
    if isinstance(d, (np.floating, np.integer, np.bool_)):
        return d.item()
    return d


def stored_run(path: Path, group: str) -> tuple[tuple[str, ...], int] | None:
    """(names, nwalkers) of a run with at least one step stored in ``path``/``group``, else None."""
    if not path.exists():
        return None
    with h5py.File(path, "r") as f:
        if group not in f or int(f[group].attrs.get("iteration", 0)) == 0:
            return None
        g = f[group]
        return tuple(json.loads(g.attrs.get("names", "[]"))), int(g.attrs["nwalkers"])


def load_run(path: str | Path, group: str = "mcmc") -> dict:
    """Read a stored run: ``names``, ``chain`` (n, walkers, ndim), ``log_prob``, ``accepted``, ``attrs``
    (JSON-decoded), ``diagnostics`` (recomputed) and any analysis groups written next to it."""
    path = Path(path)
    if not path.exists():
        raise InputError("file not found", file=path, expected="an HDF5 file written by lightfit.inference.mcmc")
    with h5py.File(path, "r") as f:
        if group not in f:
            raise InputError(f"no group {group!r}", file=path, expected="a posterior run")
        g = f[group]
        n = int(g.attrs["iteration"])
        out = {
            "names": tuple(json.loads(g.attrs["names"])),
            "chain": g["chain"][:n],
            "log_prob": g["log_prob"][:n],
            "accepted": g["accepted"][:],
            "attrs": {},
        }
        for k, v in g.attrs.items():
            try:
                out["attrs"][k] = json.loads(v) if isinstance(v, str) else (v.item() if hasattr(v, "item") else v)
            except (json.JSONDecodeError, TypeError):
                out["attrs"][k] = v
        if "analysis" in f:
            out["analysis"] = _read_group(f["analysis"])
    out["diagnostics"] = diagnostics(out["chain"], out["accepted"], names=out["names"])
    return out


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
    with h5py.File(path, "a") as f:
        if name in f:
            del f[name]
        _write(f.create_group(name), data)


def _write(g, data: dict):
    for k, v in data.items():
        if isinstance(v, dict):
            _write(g.create_group(k), v)
        elif isinstance(v, np.ndarray) and v.dtype.kind in "fiub":
            g.create_dataset(k, data=v)
        else:
            g.attrs[k] = json.dumps(jsonable(v))


__all__ = ["ResumableHDFBackend", "jsonable", "load_run", "stored_run", "write_group"]
