"""Render emulator design points on a Dask cluster, straight into the design cache.

The emulator's design renders (:mod:`lightfit.model.emulator`) are independent full renders of one
configuration at different leaf parameters: embarrassingly parallel. :func:`render_design` sends the
points that are not in the cache yet, one task per chunk of points; each worker rebuilds the model
from what is shipped (the :class:`~lightfit.model.scenario.Scenario` and the step masks of
:func:`~lightfit.model.emulator.restrict`: no geometry), checks that its
:func:`~lightfit.model.emulator.render_key` is the client's (another lightfit / Mitsuba version, or
plants grown differently, would otherwise fill the cache with renders of another configuration under
this one's name) and calls :func:`~lightfit.model.emulator.render_parts` with the design's render
cache. That writes one file per finished point, atomically, so:

- the client afterwards fits the emulator from the cache with nothing left to render (the usual
  ``build_emulator`` path, which reads every point from the cache);
- a run killed at any moment keeps every finished point, and a rerun sends only the rest;
- a worker that dies mid-chunk loses only its unfinished point; Dask re-runs the task elsewhere and
  the rerun skips the points the dead worker had finished.

The cache directory must be visible to the workers at the same path (always true for the embedded
``LocalCluster``; a shared file system on a real cluster).

Values are those of a local render: the estimator's random numbers are keyed by (render seed,
segment, sample), not by process or thread (``docs/distributed.md``), and
``tests/test_distributed_design.py`` checks bitwise equality.

Use :func:`design_renderer` to get the ``render_points`` hook that ``build_emulator``,
``cached_emulator``, ``shared_emulator`` and ``surrogate_calibrate`` accept.
"""

from __future__ import annotations

import json
import math
import os
import time
import uuid
from collections.abc import Callable, Iterator
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lightfit.distributed.run import _worker_setup, check_cluster_options, connect
from lightfit.errors import InputError
from lightfit.model import emulator as E
from lightfit.model.scenario import Scenario
from lightfit.progress import progress_bar

#: The worker's last model, keyed by its render key (JSON): chunks of one design that land on the
#: same worker build the plants and the scene once.
_MODEL: dict[str, object] = {}


@dataclass
class DesignChunk:
    """What a worker needs for one chunk of design points (small: no geometry).

    Attributes:
        scenario: the configuration (as for ``CoupledModel(scenario)``).
        keep, rendered: the step masks of :func:`~lightfit.model.emulator.restrict` over the
            scenario's weather rows (``keep`` all true and ``rendered`` the daytime: no restriction).
        leaf: (n, 3) points (specular, roughness, subsurface) to render.
        cache: the design's render directory (``design_dir(model)/renders``).
        key: the client's :func:`~lightfit.model.emulator.render_key` of the model.
    """

    scenario: Scenario
    keep: np.ndarray
    rendered: np.ndarray
    leaf: np.ndarray
    cache: Path
    key: dict


def step_masks(model) -> tuple[np.ndarray, np.ndarray]:
    """``(keep, rendered)`` over ``model.scenario.weather`` such that ``restrict(CoupledModel(model.scenario),
    keep, rendered)`` is ``model`` (whose steps are a subset of its scenario's, in order)."""
    times = model.scenario.weather.index
    keep = np.asarray(times.isin(model.times), bool)
    rendered = keep & np.asarray(times.isin(model.times[np.asarray(model.day, bool)]), bool)
    if int(keep.sum()) != len(model.times):
        raise InputError(
            f"{len(model.times)} model steps, {int(keep.sum())} of them in its scenario's weather",
            parameter="model",
            expected="a CoupledModel whose steps are rows of its scenario's weather (restrict() of one)",
        )
    return keep, rendered


def render_chunk(chunk: DesignChunk) -> dict:
    """Worker side: rebuild the model, check its render key, render the chunk into the cache."""
    t0 = time.perf_counter()
    _worker_setup()
    from lightfit.model.coupled import CoupledModel

    tag = json.dumps(chunk.key, sort_keys=True)
    model = _MODEL.get(tag)
    if model is None:
        model = E.restrict(CoupledModel(chunk.scenario), chunk.keep, chunk.rendered)
        mine = E.render_key(model)
        if mine != chunk.key:
            raise InputError(
                "the worker's model is not the client's ("
                + "; ".join(E.key_changes(chunk.key, mine))
                + f") on {os.uname().nodename}, pid {os.getpid()}",
                parameter="render_key",
                expected="workers with the client's lightfit, Mitsuba and Dr.Jit versions and plant growth",
            )
        _MODEL.clear()
        _MODEL[tag] = model
    t1 = time.perf_counter()
    before = E.COUNTS["rendered"]
    E.render_parts(model, chunk.leaf, cache=chunk.cache, key=chunk.key)
    t2 = time.perf_counter()
    point_s = []
    for x in chunk.leaf:  # each render's own seconds, as stored with it (the first carries the warm-up)
        with np.load(E.render_file(chunk.cache, chunk.key, x)) as z:
            point_s.append(float(z["seconds"]))
    return {
        "points": len(chunk.leaf),
        "rendered": E.COUNTS["rendered"] - before,
        "pid": os.getpid(),
        "build_s": t1 - t0,
        "render_s": t2 - t1,
        "point_s": point_s,
    }


def missing_points(leaf, cache: str | Path, key: dict) -> np.ndarray:
    """The rows of ``leaf`` (n, 3) without a render in ``cache`` (duplicates once), in order."""
    seen, out = set(), []
    for x in np.atleast_2d(np.asarray(leaf, float)):
        f = E.render_file(cache, key, x)
        if f not in seen and not f.exists():
            out.append(x)
        seen.add(f)
    return np.asarray(out, float).reshape(-1, 3)


def render_design(
    client,
    model,
    leaf,
    cache: str | Path,
    key: dict | None = None,
    *,
    chunk: int | None = None,
    progress: bool = True,
    timeout_s: float | None = None,
    label: str = E.DESIGN_LABEL,
) -> list[dict]:
    """Render the points of ``leaf`` (n, 3) that ``cache`` lacks on the workers of ``client``.

    Args:
        model: a :class:`~lightfit.model.coupled.CoupledModel` (or a :func:`~lightfit.model.emulator.restrict`
            of one) built from its ``scenario`` with the default sensors.
        cache: the render directory (``design_dir(model)/renders``), visible to the workers.
        key: ``render_key(model)`` if already computed.
        chunk: points per task (default: the missing points shared evenly over the workers).
        progress: a bar over finished points (files appearing in the cache).
        timeout_s: give up waiting after this many seconds (``None``: no bound).
        label: the progress line's (the posterior's held-out renders say so:
            :data:`~lightfit.model.emulator.HELD_OUT_LABEL`).

    Returns one dict per task (points, new renders, worker pid, build and render seconds, each point's
    render seconds); ``[]``
    when nothing was missing. A task's error (e.g. a worker whose render key differs) is raised here.
    """
    if not np.asarray(model.day).any():  # nothing to render at all (see restrict)
        return []
    key = key or E.render_key(model)
    cache = Path(cache)
    todo = missing_points(leaf, cache, key)
    if not len(todo):
        return []
    n_workers = max(1, len(client.nthreads()))
    size = math.ceil(len(todo) / n_workers) if chunk is None else int(chunk)
    if size < 1:
        raise InputError(f"chunk={chunk!r}", parameter="chunk", expected="an integer ≥ 1 (points per task)")
    keep, rendered = step_masks(model)
    token = uuid.uuid4().hex[:10]
    futures = [
        client.submit(
            render_chunk,
            DesignChunk(model.scenario, keep, rendered, todo[i : i + size], cache, key),
            key=f"lightfit-design-{i // size}-{token}",
            pure=False,
        )
        for i in range(0, len(todo), size)
    ]
    files = [E.render_file(cache, key, x) for x in todo]
    t0 = time.perf_counter()
    label = f"{label} on {n_workers} worker(s)"
    try:
        with progress_bar(label, len(files), show=progress) as bar:
            # Poll: a chunk's points land in the cache one by one, so the bar counts points, not tasks.
            while True:
                done = all(f.done() for f in futures)
                for f in futures:
                    if f.done() and f.status != "finished":
                        f.result()  # raises the task's error here
                bar.update(completed=sum(p.exists() for p in files))
                if done:
                    break
                if timeout_s is not None and time.perf_counter() - t0 > timeout_s:
                    raise TimeoutError(f"design renders not finished after {timeout_s} s")
                time.sleep(0.25)
        info = [f.result() for f in futures]
    finally:
        for f in futures:
            f.release()
    # The caller reads these points from the cache next (that is the hook's contract): count them as
    # this process's new renders, not as cache hits, so "n new renders, m from the cache" stays true.
    new = sum(i["rendered"] for i in info)
    E.COUNTS["rendered"] += new
    E.COUNTS["cached"] -= new
    return info


@contextmanager
def design_renderer(
    scheduler: str | None = None, workers: int | None = None, connect_timeout_s: float = 30.0
) -> Iterator[Callable | None]:
    """The ``render_points`` hook of the emulator for the command line's ``--scheduler`` / ``--workers``:
    ``None`` (render in this process) when neither is given, else :func:`render_design` on a client
    of :func:`~lightfit.distributed.run.connect`, started at the first call that has a point to
    render (a design already in the cache starts no cluster) and closed on exit. Options that
    contradict each other (``workers`` with ``scheduler``, ``workers < 1``, an address that does not
    parse, a timeout that is not finite and > 0) are refused on entry, whether or not a point is missing.
    ``connect_timeout_s``: :func:`~lightfit.distributed.run.connect`'s ``timeout_s`` (``--connect-timeout``)."""
    check_cluster_options(scheduler, workers=workers, connect_timeout_s=connect_timeout_s)
    if scheduler is None and workers is None:
        yield None
        return
    with ExitStack() as stack:
        client = None

        def render_points(model, leaf, cache, key=None, **kw):
            nonlocal client
            key = key or E.render_key(model)
            if not np.asarray(model.day).any() or not len(missing_points(leaf, cache, key)):
                return []
            if client is None:
                client = stack.enter_context(connect(scheduler, workers=workers, timeout_s=connect_timeout_s))
            return render_design(client, model, leaf, cache, key, **kw)

        yield render_points


__all__ = ["DesignChunk", "design_renderer", "missing_points", "render_chunk", "render_design", "step_masks"]
