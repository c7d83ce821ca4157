"""Run a field's tiles (and time chunks) as Dask tasks and gather one Dataset.

Each task is one (tile, time chunk): the worker rebuilds the tile's plants from their seeds
(the plant cache on a shared disk makes this a load; no geometry is shipped), renders only the
tile's measured segments at the chunk's sun positions, runs the photosynthesis and returns the
per-segment Dataset of :meth:`lightfit.model.coupled.CoupledModel.simulate`. The client
concatenates the parts along ``segment`` and ``time`` (sorted by segment id and time, the order
of a single-process run) and recomputes the canopy aggregates from the per-segment values, so
the result has the layout of a single-process run.

What "partition-independent" means here (see :mod:`lightfit.distributed.tiles`):

- ``halo_rows=None`` (default): per-segment values are bitwise identical to a single-process
  run for any tiling and time chunking; canopy aggregates agree to floating-point summation
  order (relative differences ~1e-15).
- ``halo_rows=H``: each tile renders only H rows of plants around its block; segments near tile
  boundaries see less far geometry than in the single-process scene, a bias that shrinks as H
  grows (numbers in ``docs/distributed.md``).

Fault tolerance is Dask's: tasks are pure functions of their spec, so a task whose worker dies
is re-run elsewhere (up to ``distributed.scheduler.allowed-failures`` times, default 3) and
gives the same values.

Resume: with ``parts=`` (the command line's default, ``results.nc.parts`` beside the results) each
finished task is kept on disk as it arrives, under a hash of everything its result depends on
(:func:`task_key`: its scenario and growth file, θ, the code's versions). A run killed or timed out and started
again with the same settings takes those tasks from disk and submits only the rest; a kept task
of other settings is computed again. The key holds the forcing's values, not its file's name or
declared provenance: the results' forcing attributes (``weather_source``, ``weather_provenance``, …)
are always the current run's. The command removes the folder once the results are written.

Worker processes: the task function imports lightfit (which points Dr.Jit at libLLVM before
Mitsuba loads), sets the Dr.Jit CPU thread count to ``LIGHTFIT_WORKER_THREADS`` (set by the
embedded cluster) and applies lightfit's precision policy *in the worker process*
(:func:`lightfit.precision.use_float64`), so that workers compute in the same precision as a
single-process run. Library imports never change JAX's configuration.
"""

from __future__ import annotations

import contextlib
import json
import logging
import math
import multiprocessing.resource_tracker
import os
import pickle
import signal
import threading
import time
import uuid
import warnings
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from lightfit.distributed.tiles import HaloField, check_tiles
from lightfit.errors import InputError, check_integer, check_real
from lightfit.files import replaced
from lightfit.killpoint import INTERRUPT_HANDLED_BY, kill_point
from lightfit.model import schema
from lightfit.model.parameters import Theta, as_theta
from lightfit.model.scenario import DAYTIME_RULE, Forcing, Scenario, daytime, sun_positions_deg
from lightfit.progress import progress_bar

#: Per-time canopy aggregates recomputed on the gathered Dataset (the observation operator's outputs).
#: Observables recomputed from the gathered segments. The virtual sensors' (ceptometer) are not
#: per segment: every tile renders them with the same layout, and gather takes tile 0's — exact
#: when the tiles render the whole field (``halo_rows=None``, periodic, or a halo that holds it);
#: with a smaller halo no task renders them (:attr:`FieldRun.sensors`) and they are NaN.
AGGREGATES = tuple(k for k in schema.OBSERVABLES if k not in schema.SENSOR_OBSERVABLES)
#: Per-time variables recomputed from the gathered per-segment values: the observables and the
#: canopy's Monte Carlo bias (a sum over blades, like canopy An).
RECOMPUTED = (*AGGREGATES, "canopy_an_mc_bias_umol_m2_s")
ENV_THREADS = "LIGHTFIT_WORKER_THREADS"


@dataclass
class FieldRun:
    """A coupled run of a field, to be split into tiles and time chunks.

    What to run is one :class:`~lightfit.model.scenario.Scenario` (field, weather, irradiance
    estimator, photosynthesis, optics, sky: one home for those options); the run adds only how
    to split it. Each task runs the scenario of its tile and time chunk (:meth:`task_scenario`).

    Attributes:
        scenario: the whole run, as a single process would run it (``scenario.tile`` is None).
        tiles: number of tiles W (blocks of the measurement area, ``Field.tiles``).
        halo_rows: geometry around each tile: ``None`` = the whole field (exact, bitwise
            partition-independent), an integer H = H plant rows/columns (the reference
            paper's approach: smaller scenes, a boundary bias; finite fields only).
        time_chunks: split the time steps into this many tasks per tile (strided, so each
            chunk gets a similar share of daytime steps).
        theta: model parameters (a :class:`~lightfit.model.parameters.Theta`, or a mapping of
            some names; the rest the scenario's own, :attr:`Scenario.theta`: its leaf's defaults).
    """

    scenario: Scenario
    tiles: int = 1
    halo_rows: int | None = None
    time_chunks: int = 1
    theta: Theta | dict = field(default_factory=dict)  # {}: the scenario's own leaf (the grey leaf's subsurface 0.3)

    def __post_init__(self):
        sc = self.scenario
        if sc.tile is not None:
            raise InputError(
                f"scenario.tile={sc.tile!r}",
                parameter="scenario",
                expected="the whole field (tile=None): FieldRun makes the tiles",
            )
        self.halo_field = HaloField.of(sc.field, self.halo_rows)  # validates halo_rows
        self.tile_list = check_tiles(self.halo_field, self.tiles)
        #: Whether some tile's scene lacks plants of the field (``halo_rows`` below
        #: :meth:`HaloField.exact_halo_rows`): its virtual sensors would read the light under a
        #: partial canopy, so the tasks render none (:attr:`sensors`).
        self.partial_scenes = self.halo_rows is not None and self.halo_rows < self.halo_field.exact_halo_rows(
            self.tiles
        )
        tc = check_integer(self.time_chunks, "time_chunks", 1)
        n_day = int(daytime(sc.weather).sum())
        if n_day == 0:
            raise InputError(
                f"all {len(sc.weather)} steps of the run are at night: nothing to distribute",
                parameter="steps",
                expected=f"at least one step that is rendered ({DAYTIME_RULE}; --steps, the window)",
            )
        if tc > n_day:
            raise InputError(
                f"time_chunks={tc} > {n_day} daytime steps",
                parameter="time_chunks",
                expected=f"at most {n_day} (every chunk needs a daytime step)",
            )

    @property
    def sensors(self) -> tuple | None:
        """The virtual sensors each task renders (``CoupledModel``'s ``sensors``): ``None``, the run's
        default ceptometer over the whole measurement area, where every tile's scene is the whole
        field; ``()`` where it is not (:attr:`partial_scenes`). The ceptometer spans the whole area,
        and under a tile's block + halo it saw bare soil where the other tiles' plants were left out
        (ceptometer fAPAR 0.055 against the whole field's 0.26 with ``halo_rows=0`` on 2 × 3 plants
        in 3 tiles, a review); its observables are then NaN, as in a run that renders no sensor."""
        return () if self.partial_scenes else None

    def chunk_index(self) -> list[np.ndarray]:
        """Row positions of the weather in each time chunk: daytime and night steps dealt out
        in turn, so every chunk has a similar share of the rendering (and at least one daytime
        step, which the coupled model needs)."""
        day = daytime(self.scenario.weather)
        d, n = np.flatnonzero(day), np.flatnonzero(~day)
        c = self.time_chunks
        return [np.sort(np.concatenate([d[i::c], n[i::c]])) for i in range(c)]

    def task_scenario(self, tile: int, rows=None) -> Scenario:
        """The :attr:`scenario` of one tile (its halo field) and time chunk (weather ``rows``; ``None``: all).

        With adaptive sampling every task allocates at the whole run's point
        (:func:`~lightfit.model.coupled.allocation_point` of all its steps), not at its chunk's
        highest sun, so the tasks' samples per segment agree and merge."""
        from lightfit.model.coupled import allocation_point

        sc, w = self.scenario, self.scenario.weather
        at = sc.allocate_at
        if sc.target_rse is not None and at is None:
            at = allocation_point(Forcing.of(w), sun_positions_deg(w), np.asarray(sc.theta.leaf, np.float64))
        return replace(
            sc,
            weather=w if rows is None else w.iloc[rows],
            field=self.halo_field,
            n_tiles=self.tiles,
            tile=tile,
            allocate_at=at,
        )


@dataclass
class TaskSpec:
    """What a worker needs for one task: small (a field spec, a few weather rows), no geometry."""

    run: FieldRun
    tile: int
    chunk: int
    rows: np.ndarray


class _QuietCancel(logging.Filter):
    """Drops a worker's warning that a task ended with ``CancelledError``: lightfit cancels its
    tasks itself on --timeout or Ctrl-C and says so in one line (the warning came first, a line of
    Dask internals; a review)."""

    def filter(self, record: logging.LogRecord) -> bool:
        return "ended with CancelledError" not in record.getMessage()


def _worker_setup() -> None:
    """Prepare a worker process: libLLVM for Dr.Jit, its CPU threads, lightfit's float64 policy, and
    no warning for the tasks lightfit cancels (:class:`_QuietCancel`)."""
    import lightfit  # noqa: F401  (sets DRJIT_LIBLLVM_PATH before Mitsuba loads)
    from lightfit.precision import use_compilation_cache, use_float64

    log = logging.getLogger("distributed.worker.state_machine")
    if not any(isinstance(f, _QuietCancel) for f in log.filters):
        log.addFilter(_QuietCancel())

    # Workers are separate processes: the client's JAX configuration does not reach them.
    use_float64()
    use_compilation_cache()

    threads = os.environ.get(ENV_THREADS)
    if threads:
        from lightfit.light.backend import mitsuba

        mi = mitsuba()
        if mi.variant().startswith("llvm"):
            import drjit as dr

            if dr.thread_count() != int(threads):
                dr.set_thread_count(int(threads))


def run_task(spec: TaskSpec):
    """Worker side: build the tile, render, photosynthesis. Returns (Dataset, timing/size info)."""
    t0 = time.perf_counter()
    _worker_setup()
    from lightfit.model.coupled import CoupledModel, NonConvergenceWarning

    t1 = time.perf_counter()
    sc = spec.run.task_scenario(spec.tile, spec.rows)
    model = CoupledModel(sc, sensors=spec.run.sensors)
    t2 = time.perf_counter()
    with warnings.catch_warnings():  # said once for the whole run by gather, in the client
        warnings.simplefilter("ignore", NonConvergenceWarning)
        ds = model.simulate(spec.run.theta)
    t3 = time.perf_counter()
    mesh = model.geometry.mesh
    tile = spec.run.tile_list[spec.tile]
    try:
        from distributed import get_worker

        worker = get_worker().address
    except (ImportError, ValueError):
        worker = "local"
    info = {
        "tile": int(spec.tile),
        "chunk": int(spec.chunk),
        "time_steps": int(len(spec.rows)),
        "worker": worker,
        "pid": os.getpid(),
        "host": os.uname().nodename,
        "setup_s": t1 - t0,
        "build_s": t2 - t1,
        "simulate_s": t3 - t2,
        "total_s": t3 - t0,
        "plants_measured": int(len(tile.measured)),
        "plants_rendered": int(len(tile.plant_ids)),
        "segments": int(len(model.segment_id)),
        "triangles": int(mesh.n_faces),
        "triangles_measured": int(np.isin(mesh.face_segment, model.segment_id).sum()),
        "ground_area_m2": model.ground_area_m2,
    }
    return ds, info


def _aggregates(out) -> dict:
    """The observables of the gathered per-segment values (:func:`lightfit.model.observe.observables`, numpy)."""
    from lightfit.model.observe import above_canopy_par, an_denominator, area_total, observables, soil_respiration
    from lightfit.weather.solar import par_direct_diffuse

    area = out["area_m2"].values.astype(np.float64)
    blade = out["is_blade"].values.astype(bool)
    kind = out.attrs["par_kind"]
    par = out[f"{kind}_par_umol_m2_s"].values
    par_sd = out[f"{kind}_par_mc_sd_umol_m2_s"].values
    an = out["leaf_an_umol_m2_s"].values[:, blade]
    an_sd = out["leaf_an_mc_sd_umol_m2_s"].values[:, blade]
    ground = float(out.attrs["ground_area_m2"])
    denom = an_denominator(area[blade], out.attrs["an_per"], ground)
    sun = out["sun_elevation_deg"].values
    measured = out["weather_par_umol_m2_s"].values if "weather_par_umol_m2_s" in out else None
    above = above_canopy_par(
        *par_direct_diffuse(out["dni_w_m2"].values, out["dhi_w_m2"].values, sun, measured),
        sun,
        float(out.attrs["theta_light_factor"]),
    )
    bias = {}
    if "leaf_an_mc_bias_umol_m2_s" in out:
        b = out["leaf_an_mc_bias_umol_m2_s"].values[:, blade]
        bias["canopy_an_mc_bias_umol_m2_s"] = area_total(b, np.zeros_like(b), area[blade], denom)[0]
    return bias | observables(
        par,
        par_sd,
        area,
        an,
        an_sd,
        area[blade],
        denom,
        absorbed=out["absorbed_par_umol_m2_s"].values,
        absorbed_mc_sd=out["absorbed_par_mc_sd_umol_m2_s"].values,
        ground_area_m2=ground,
        above_par=above,
        soil_respiration_umol_m2_s=soil_respiration(
            float(out.attrs.get("soil_respiration_umol_m2_s", 0.0)),
            float(out.attrs.get("soil_respiration_q10", 1.0)),  # files without it: a constant
            out["tair_c"].values,
        ),
    )


def gather(results: list, run: FieldRun, extra_attrs: dict | None = None):
    """Merge task results ``[(Dataset, info), …]`` into the single-process layout.

    Per-segment variables (dimensions from :mod:`lightfit.model.schema`) are concatenated
    (sorted by segment id, then time); per-time weather/sun variables are taken from the parts;
    the observables are recomputed from the per-segment values by the observation operator
    (:func:`lightfit.model.observe.observables`): segments are independent, so canopy sums and
    Monte Carlo variances add over tiles. Unconverged photosynthesis solves are warned of here,
    once for the whole run (:func:`~lightfit.model.coupled.warn_unconverged`), as by a single process.
    """
    import xarray as xr

    from lightfit.model.coupled import WEATHER_ATTRS, warn_unconverged, weather_attrs

    if not results:
        raise InputError("no task results to gather", parameter="results", expected="one result per task")
    infos = [i for _, i in results]
    expected = {(t, c) for t in range(run.tiles) for c in range(run.time_chunks)}
    got = {(i["tile"], i["chunk"]) for i in infos}
    if got != expected:
        raise InputError(
            f"task results cover {sorted(got)}", parameter="results", expected=f"all of {sorted(expected)}"
        )
    ds0 = results[0][0]
    seg_vars = [v for v in ds0.data_vars if "segment" in schema.variable(v).dims]
    time_vars = [v for v in ds0.data_vars if "segment" not in schema.variable(v).dims and v not in RECOMPUTED]
    chunks = []
    for c in range(run.time_chunks):
        part = sorted((r for r in results if r[1]["chunk"] == c), key=lambda r: r[1]["tile"])
        seg = xr.concat([d[seg_vars] for d, _ in part], dim="segment", join="exact").sortby("segment")
        for v in time_vars:
            seg[v] = part[0][0][v]
        chunks.append(seg)
    out = (
        chunks[0]
        if len(chunks) == 1
        else xr.concat(chunks, dim="time", data_vars="minimal", coords="minimal", compat="equals", join="exact")
    )
    out = out.sortby("time")
    if len(np.unique(out["segment"].values)) != out.sizes["segment"]:
        raise InputError("a segment id occurs in two tiles", parameter="results", expected="disjoint tiles")
    # The forcing's description from this run's forcing, not from a task's: a kept task (a resume) is
    # keyed by the forcing's rows, and may come from a copy of it under another name or provenance.
    # (in the place a single-process run puts them).
    forcing_attrs = weather_attrs(run.scenario.weather)
    attrs = {}
    for k, v in ds0.attrs.items():
        if k == WEATHER_ATTRS[0]:
            attrs |= forcing_attrs
        elif k not in WEATHER_ATTRS:
            attrs[k] = v
    out.attrs = attrs | forcing_attrs | {"ground_area_m2": run.scenario.ground_area_m2}
    for k, v in _aggregates(out).items():
        if k in RECOMPUTED:
            out[k] = ("time", v)
    out = schema.annotate(out[list(ds0.data_vars)])
    by_tile = {}
    for i in infos:
        by_tile.setdefault(i["tile"], i)
    rendered = sum(i["triangles"] for i in by_tile.values())
    measured = sum(i["triangles_measured"] for i in by_tile.values())
    out.attrs.update(
        {
            "n_tiles": run.tiles,
            "tile": -1,
            "halo_rows": -1 if run.halo_rows is None else run.halo_rows,
            "halo": "whole field (exact)"
            if run.halo_rows is None
            else f"{run.halo_rows} plant rows/columns around each tile",
            "time_chunks": run.time_chunks,
            "tasks": len(results),
            "triangles_rendered": rendered,
            "triangles_measured": measured,
            "buffer_overhead": rendered / measured if measured else math.nan,
            "tile_timing_json": json.dumps(sorted(infos, key=lambda i: (i["tile"], i["chunk"]))),
            **(extra_attrs or {}),
        }
    )
    # As a single-process run warns: the workers' own warnings went to their logs (or nowhere, on a
    # joined cluster) and a task taken from the parts folder gave none.
    warn_unconverged(out)
    return out


# -- clusters ------------------------------------------------------------------------------


def gpu_count() -> int:
    """CUDA devices visible to this process (``CUDA_VISIBLE_DEVICES`` or ``nvidia-smi -L``); 0 without."""
    vis = os.environ.get("CUDA_VISIBLE_DEVICES")
    if vis is not None:
        return len([d for d in vis.split(",") if d.strip() and d.strip() != "-1"])
    import shutil
    import subprocess

    if not shutil.which("nvidia-smi"):
        return 0
    try:
        out = subprocess.run(["nvidia-smi", "-L"], capture_output=True, text=True, timeout=10)
    except (OSError, subprocess.SubprocessError):
        return 0
    return sum(1 for line in out.stdout.splitlines() if line.startswith("GPU "))


def default_workers() -> tuple[int, int]:
    """(workers, threads per worker) of the embedded cluster: one worker per GPU if any, else
    one single-threaded worker per core, at most one per 2 GiB of memory."""
    g = gpu_count()
    if g:
        return g, 1
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    try:
        mem_gib = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**30
    except (ValueError, OSError, AttributeError):
        mem_gib = 2.0 * cores
    return max(1, min(cores, int(mem_gib // 2))), 1


class PinGPU:
    """Worker plugin: worker i of an embedded cluster sees only GPU ``i mod n`` (before Mitsuba loads)."""

    name = "lightfit-pin-gpu"

    def __init__(self, n_gpus: int):
        self.n_gpus = n_gpus

    def setup(self, worker):
        try:
            i = int(worker.name)
        except (TypeError, ValueError):
            return
        os.environ["CUDA_VISIBLE_DEVICES"] = str(i % self.n_gpus)


def _probe(address: str, timeout_s: float) -> None:
    """Ask the scheduler at ``address`` who it is, giving up after ``timeout_s`` (TimeoutError):
    a port that accepts but never speaks Dask would otherwise hang the handshake forever. Runs its
    own event loop in a thread (the caller may be inside one: a notebook) and connects as a client
    would (the dask configuration's TLS settings)."""
    import asyncio
    from concurrent.futures import ThreadPoolExecutor

    from distributed.core import rpc
    from distributed.security import Security

    async def identity():
        r = rpc(address, timeout=timeout_s, connection_args=Security().get_connection_args("client"))
        try:
            return await r.identity()
        finally:
            await r.close_rpc()

    async def bounded():
        return await asyncio.wait_for(identity(), timeout_s)

    with ThreadPoolExecutor(1) as pool:
        pool.submit(asyncio.run, bounded()).result()


#: The longest --timeout / --connect-timeout, s (about 116 days): Dask and Python turn a timeout into
#: a C timestamp, which overflows from about 9.2e9 s (threading.TIMEOUT_MAX).
MAX_TIMEOUT_S = 1e7


def check_cluster_options(
    scheduler: str | None = None,
    *,
    workers: int | None = None,
    threads_per_worker: int | None = None,
    timeout_s: float | None = None,
    connect_timeout_s: float = 30.0,
) -> None:
    """What can be told of the cluster options without a cluster, as :class:`InputError` naming the
    option: both timeouts finite, > 0 s and at most :data:`MAX_TIMEOUT_S`, workers and threads ≥ 1,
    no workers or threads with a scheduler, a scheduler address that parses (host and port for
    TCP/TLS). ``field-run`` checks them before any plant grows; :func:`run_field` and
    :func:`connect` again."""
    for name, value in (("timeout", timeout_s), ("connect_timeout", connect_timeout_s)):
        # finite too: Dask parses a timeout's number as a string, and "inf" was a KeyError traceback;
        # at most MAX_TIMEOUT_S: 1e15 s passed, ran, then Dask's close turned it into a C timestamp
        # (OverflowError traceback, exit 1, after the run; 2 × 1e308 parsed as inf the same)
        if value is not None:
            limit = " (no --timeout: no limit)" if name == "timeout" else ""
            most = f"at most {MAX_TIMEOUT_S:,.0f} ({MAX_TIMEOUT_S / 86400:.0f} days)"
            check_real(
                value,
                name,
                0.0,
                MAX_TIMEOUT_S,
                open_lo=True,
                expected=f"finite and > 0 seconds, {most}" + limit,
            )
    for name, v in (("workers", workers), ("threads_per_worker", threads_per_worker)):
        if v is not None:
            check_integer(v, name, 1)
    if scheduler:
        if workers is not None:
            raise InputError(
                f"workers={workers} with scheduler={scheduler!r}",
                parameter="workers",
                expected="no --workers when joining an existing cluster (its workers are given)",
            )
        if threads_per_worker is not None:  # connect() does not use it there: it was dropped unsaid
            raise InputError(
                f"threads_per_worker={threads_per_worker} with scheduler={scheduler!r}",
                parameter="threads_per_worker",
                expected="no --threads-per-worker when joining an existing cluster (its workers' threads are "
                "set where they were started: dask worker --nthreads)",
            )
        from distributed.comm.addressing import parse_address, parse_host_port

        try:
            protocol, location = parse_address(scheduler)
            if protocol in ("tcp", "tls"):
                parse_host_port(location)
        except ValueError as err:
            raise InputError(
                f"scheduler={scheduler!r}: {err}", parameter="scheduler", expected="an address such as tcp://host:8786"
            ) from None


@contextmanager
def connect(
    scheduler: str | None = None,
    *,
    workers: int | None = None,
    threads_per_worker: int | None = None,
    timeout_s: float = 30.0,
):
    """A Dask client: joins ``scheduler`` (address, e.g. ``tcp://host:8786``) or starts an
    embedded ``LocalCluster`` (processes, ``workers`` × ``threads_per_worker``; default sized to
    the machine, :func:`default_workers`). Closes what it started."""
    from distributed import Client, LocalCluster

    check_cluster_options(
        scheduler, workers=workers, threads_per_worker=threads_per_worker, connect_timeout_s=timeout_s
    )
    if scheduler:
        try:
            _probe(scheduler, timeout_s)  # Client's own timeout does not bound a handshake that never answers
            client = Client(scheduler, timeout=timeout_s)
        except Exception as err:  # noqa: BLE001 - whatever a wrong address does (bytes of another protocol: MemoryError)
            # a port that never answers: a TimeoutError without text (it read "TimeoutError: ")
            why = f"{type(err).__name__}: {str(err)[:200]}" if str(err) else type(err).__name__
            raise InputError(
                f"scheduler={scheduler!r}: cannot connect ({why})",
                parameter="scheduler",
                expected=f"the address of a running Dask scheduler answering within {timeout_s:g} s, e.g. tcp://host:8786",
            ) from None
        try:
            yield client
        finally:
            client.close()
        return
    n_def, t_def = default_workers()
    n = n_def if workers is None else workers
    t = t_def if threads_per_worker is None else threads_per_worker
    for name, v in (("workers", n), ("threads_per_worker", t)):
        check_integer(v, name, 1)
    # Workers inherit this process's environment, XLA_PYTHON_CLIENT_PREALLOCATE (backend.configure_jax_memory) too.
    env = {ENV_THREADS: str(t), "OMP_NUM_THREADS": str(t)}
    if t == 1:
        env["XLA_FLAGS"] = (
            os.environ.get("XLA_FLAGS", "") + " --xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1"
        ).strip()
    # dashboard_address ":0": a free port. None does not disable the scheduler's HTTP server: it
    # takes port 8787 and warns when another cluster (another lightfit run) holds it.
    muted = None  # the Dask logger's level while the cluster closes (_stop_workers)
    with _interrupts_handled_here(), _interrupt_deferred() as interrupted:
        try:
            cluster = LocalCluster(n_workers=n, threads_per_worker=t, processes=True, env=env, dashboard_address=":0")
        except Exception as err:  # noqa: BLE001 - whatever stops the workers starting (a ~90-line traceback)
            interrupted.restore()
            raise InputError(
                f"a local Dask cluster of {n} worker(s) × {t} thread(s) did not start ({type(err).__name__}: "
                f"{str(err)[:200]})",
                # not --connect-timeout's: it bounds the client's connection, not the workers' start
                parameter="workers",
                expected="fewer --workers, or the cause the error names (memory, ports, a worker's import)",
            ) from None
        try:
            interrupted.restore()  # a Ctrl-C while the cluster started is raised here, where it is closed
            try:
                client = Client(cluster, timeout=timeout_s)
            except (OSError, TimeoutError) as err:  # distributed's "Timed out trying to connect"
                raise InputError(
                    f"the local Dask cluster did not answer within {timeout_s:g} s "
                    f"({type(err).__name__}: {str(err)[:200]})",
                    parameter="connect_timeout",
                    expected="a longer --connect-timeout",
                ) from None
            try:
                g = gpu_count()
                if g:
                    client.register_plugin(PinGPU(g))
                yield client
            except KeyboardInterrupt:
                muted = _stop_workers(cluster)
                raise
            else:  # every result is in this process: nothing a worker still does is needed
                muted = _stop_workers(cluster)
            finally:
                client.close()
        finally:
            cluster.close()
            if muted is not None:  # a library caller's process goes on: its Dask logging as it was
                logging.getLogger("distributed").setLevel(muted)


def _stop_workers(cluster) -> int:
    """Kill the embedded cluster's worker processes and mute Dask's loggers for the close, on Ctrl-C
    and after a block that ended normally; another error (a timeout) leaves the nanny's 4 s grace,
    in which a task about to finish still writes its render to the cache. On Ctrl-C a worker busy
    in a task cannot answer the close, and printed 30–60 lines of heartbeat tracebacks while the
    nanny waited to kill it (a review of interrupted runs); after a finished run a worker's own exit
    (Dr.Jit's and JAX's teardown) outlasted those 4 s on a loaded 2-core machine, which added them
    to the run and printed "Worker process still alive after 4.0 seconds, killing" twice under its
    result. Every finished task's result is in this process by then (``parts``); on Ctrl-C a task
    still in a worker is lost either way. Returns the logger's level before."""
    for nanny in list(getattr(cluster, "workers", {}).values()):
        pid = getattr(getattr(nanny, "process", None), "pid", None)
        if pid:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
    log = logging.getLogger("distributed")
    level = log.level
    log.setLevel(logging.CRITICAL)
    return level


class _Deferred:
    """A Ctrl-C held while a cluster starts (:func:`_interrupt_deferred`)."""

    def __init__(self):
        self.previous, self.got, self.mask = None, False, None

    def restore(self) -> None:
        """Unblock SIGINT, put the previous handler back and raise the held Ctrl-C, if one came."""
        if self.mask is not None:
            signal.pthread_sigmask(signal.SIG_SETMASK, self.mask)  # a pending Ctrl-C reaches `hold` here
            self.mask = None
        if self.previous is not None:
            signal.signal(signal.SIGINT, self.previous)
            self.previous = None
            if self.got:
                raise KeyboardInterrupt


@contextmanager
def _interrupt_deferred():
    """Hold a Ctrl-C until :meth:`_Deferred.restore`: one during LocalCluster's start left a cluster
    no one closed, and distributed's own close at exit printed ≈ 28 lines (a review). Only in the
    main thread (elsewhere Python takes no handler and nothing is held).

    SIGINT is also blocked in this thread meanwhile. The threads Dask starts here inherit that mask,
    and so do the worker processes they spawn (a signal mask survives fork and exec, and Python
    leaves it as it finds it): a terminal's Ctrl-C while a worker still imports Dask waits in it
    unseen, where it printed a 36-line traceback of the interrupted import, until lightfit's import
    there sets SIGINT ignored (:func:`lightfit.killpoint.ignore_interrupt_in_workers`), which drops it.
    multiprocessing's resource tracker is started before the mask is set: its first start unblocks
    SIGINT in the thread that starts it (CPython's ``ResourceTracker.ensure_running``), which would
    otherwise be Dask's event loop, the parent of every worker."""
    held = _Deferred()
    try:
        if threading.current_thread() is threading.main_thread():

            def hold(*_):
                held.got = True

            held.previous = signal.signal(signal.SIGINT, hold)
            if hasattr(signal, "pthread_sigmask"):  # POSIX; elsewhere the workers' imports stay interruptible
                # The caller's mask, read before the tracker's first start unblocks SIGINT in this thread.
                held.mask = signal.pthread_sigmask(signal.SIG_BLOCK, set())
                with contextlib.suppress(OSError):  # a tracker that cannot start: Dask's own start says so
                    multiprocessing.resource_tracker.ensure_running()
                signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
        yield held
    finally:
        held.restore()


@contextmanager
def _interrupts_handled_here():
    """Within the block, worker processes this process starts ignore Ctrl-C and leave it to it
    (:func:`lightfit.killpoint.ignore_interrupt_in_workers`): it closes them and says so once."""
    before = os.environ.get(INTERRUPT_HANDLED_BY)
    os.environ[INTERRUPT_HANDLED_BY] = str(os.getpid())
    try:
        yield
    finally:
        if before is None:
            os.environ.pop(INTERRUPT_HANDLED_BY, None)
        else:
            os.environ[INTERRUPT_HANDLED_BY] = before


# -- the run ---------------------------------------------------------------------------------


def task_specs(run: FieldRun) -> list[TaskSpec]:
    """One task per (tile, time chunk), chunk by chunk."""
    return [
        TaskSpec(run=run, tile=k, chunk=c, rows=rows)
        for c, rows in enumerate(run.chunk_index())
        for k in range(run.tiles)
    ]


def submit(client, run: FieldRun, specs: list[TaskSpec] | None = None) -> list:
    """Submit ``specs`` (default: every task of ``run``); returns the futures."""
    token = uuid.uuid4().hex[:10]
    return [
        client.submit(run_task, s, key=f"lightfit-tile{s.tile}-chunk{s.chunk}-{token}", pure=False)
        for s in (task_specs(run) if specs is None else specs)
    ]


def task_key(spec: TaskSpec) -> str:
    """Hash of everything the task's result depends on: its scenario (tile, time rows, field and its
    growth file's contents, estimator, optics, photosynthesis, … :
    :meth:`~lightfit.model.scenario.Scenario.digest`, whose growth entry holds CPlantBox's version),
    θ, the versions of the code it ran (:func:`~lightfit.model.emulator.run_versions`), and, where a
    partial halo leaves the virtual sensors unrendered (:attr:`FieldRun.sensors`), that."""
    import hashlib

    from lightfit.model.emulator import run_versions

    versions = run_versions()
    what = {
        "scenario": spec.run.task_scenario(spec.tile, spec.rows).digest(),
        "theta": as_theta(spec.run.theta, spec.run.scenario.theta).to_dict(),  # as the task runs it
        "versions": versions,
        "task": [spec.tile, spec.chunk],
        # only where the tasks render no sensor (a partial halo): every other run keeps its keys, and a
        # task kept before (it rendered tile 0's ceptometer under part of the canopy) is not taken over
        **({"sensors": "none"} if spec.run.partial_scenes else {}),
    }
    return hashlib.sha256(json.dumps(what, sort_keys=True, default=str).encode()).hexdigest()


#: Suffix of the folder beside a field-run's results where its finished tasks are kept
#: (``results.nc`` → ``results.nc.parts``; module doc, "Resume").
PARTS_SUFFIX = ".parts"


def _part(parts: Path, tile: int, chunk: int) -> Path:
    return parts / f"tile{tile}-chunk{chunk}.pkl"


def _load_part(path: Path, key: str):
    """A kept task's ``(Dataset, info)`` if ``path`` holds one made under ``key``, else None (absent,
    other settings, or unreadable: computed again)."""
    try:
        with path.open("rb") as f:
            kept_key, ds, info = pickle.load(f)  # noqa: S301 (the run's own folder, written below)
    except Exception:  # noqa: BLE001 (any unreadable file is one more task to run, not an error)
        return None
    return (ds, info) if kept_key == key else None


def _keep_part(path: Path, key: str, result) -> None:
    """Through :func:`lightfit.files.replaced`: a killed write leaves no half file."""
    with replaced(path) as tmp, tmp.open("wb") as f:
        pickle.dump((key, *result), f, protocol=pickle.HIGHEST_PROTOCOL)


def run_field(
    run: FieldRun,
    *,
    client=None,
    scheduler: str | None = None,
    workers: int | None = None,
    threads_per_worker: int | None = None,
    progress: bool = False,
    timeout_s: float | None = None,
    connect_timeout_s: float = 30.0,
    parts: str | Path | None = None,
):
    """Run ``run`` on Dask and return the gathered Dataset (layout of a single-process run).

    Uses ``client`` if given, else joins ``scheduler``, else starts an embedded LocalCluster.
    ``timeout_s`` bounds the wait for all tasks (``None``: no bound; past it a ``TimeoutError`` says how
    many finished on how many workers, its ``workers`` attribute the latter); ``connect_timeout_s`` the
    wait for the scheduler; both must be > 0 (checked before a cluster is started or joined).
    ``parts``: a folder where each finished task is kept, and from which the tasks of the same
    settings are taken instead of run (module doc, "Resume"); the Dataset's ``tasks_resumed``
    attribute counts them, ``tasks_discarded`` the parts found there of other settings or unreadable
    (run again).
    """
    check_cluster_options(timeout_s=timeout_s, connect_timeout_s=connect_timeout_s)
    if client is None:
        with connect(
            scheduler, workers=workers, threads_per_worker=threads_per_worker, timeout_s=connect_timeout_s
        ) as cl:
            return run_field(run, client=cl, progress=progress, timeout_s=timeout_s, parts=parts)
    from distributed import as_completed

    t0 = time.perf_counter()
    specs = task_specs(run)
    keys = {}
    results = []
    discarded = 0
    if parts is not None:
        parts = Path(parts)
        parts.mkdir(parents=True, exist_ok=True)
        keys = {(s.tile, s.chunk): task_key(s) for s in specs}
        todo = []
        for s in specs:
            path = _part(parts, s.tile, s.chunk)
            kept = _load_part(path, keys[s.tile, s.chunk])
            if kept is None:
                todo.append(s)
                discarded += path.exists()  # another run's (other settings) or unreadable: said, not silent
            else:
                results.append(kept)
        specs = todo
    resumed = len(results)
    futures = submit(client, run, specs)
    total = len(futures) + resumed
    try:
        with progress_bar("tiles × time chunks", total, completed=resumed, show=progress) as bar:
            for n, fut in enumerate(as_completed(futures, timeout=timeout_s), 1):
                ds, info = fut.result()
                # Forgotten by the cluster once here: a worker that dies later made Dask compute again
                # every task it still held, results this process already had (and kept beside --out).
                fut.release()
                results.append((ds, info))
                if parts is not None:
                    _keep_part(_part(parts, info["tile"], info["chunk"]), keys[info["tile"], info["chunk"]], (ds, info))
                    kill_point("field-task", n)
                bar.update(
                    completed=resumed + n,
                    info=f"tile {info['tile']} chunk {info['chunk']}: {info['total_s']:.1f} s on {info['worker']}",
                )
    except TimeoutError:
        if timeout_s is None:  # a task's own TimeoutError, not the wait's: passed on as it is
            raise
        # The count of workers too: a joined scheduler without any runs nothing, however long it waits.
        n_workers = len(client.nthreads())  # asked of the scheduler once
        err = TimeoutError(
            f"{len(results) - resumed} of {len(futures)} tasks finished within {timeout_s:g} s on {n_workers} worker(s)"
        )
        err.workers = n_workers
        raise err from None
    finally:
        for f in futures:
            f.release()
    wall = time.perf_counter() - t0
    n_workers = len(client.nthreads())
    extra = {
        "distributed_wall_s": wall,
        "distributed_workers": n_workers,
        "tasks_resumed": resumed,
        "tasks_discarded": discarded,
    }
    return gather(results, run, extra)


def run_single(run: FieldRun):
    """The same run in this process without tiling (the reference for partition independence)."""
    from lightfit.model.coupled import CoupledModel

    return CoupledModel(run.scenario).simulate(run.theta)


__all__ = [
    "AGGREGATES",
    "PARTS_SUFFIX",
    "FieldRun",
    "PinGPU",
    "TaskSpec",
    "connect",
    "default_workers",
    "gather",
    "gpu_count",
    "run_field",
    "run_single",
    "run_task",
    "submit",
    "task_key",
    "task_specs",
]
