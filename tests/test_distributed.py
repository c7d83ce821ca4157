"""Scale-out on Dask: partition independence, layout, metadata, fault tolerance, errors, CLI.

Tiny fields (2×2 measured plants, one buffer row, K=8, 2 bounces, 2 time steps) on a
LocalCluster of 2 single-threaded worker processes.
"""

import contextlib
import dataclasses
import json
import os
import signal
import socket
import threading
import time

import numpy as np
import pytest

from lightfit.distributed import FieldRun, HaloField, connect, default_workers, gather, run_field, run_single, submit
from lightfit.errors import InputError
from lightfit.model.scenario import Scenario
from lightfit.plant import Field
from lightfit.replication import forcing

FIELD = Field(boundary="finite", n_plants=4, buffer_rows=1, seed=1)
SEGMENT_VARS = [
    "incident_par_umol_m2_s",
    "absorbed_par_umol_m2_s",
    "incident_par_mc_sd_umol_m2_s",
    "absorbed_par_mc_sd_umol_m2_s",
    "leaf_an_umol_m2_s",
    "leaf_an_mc_sd_umol_m2_s",
    "leaf_gs_mol_m2_s",
    "leaf_ci_umol_mol",
    "leaf_vc_umol_m2_s",
    "leaf_vj_umol_m2_s",
    "limitation",
    "converged",
]
AGGREGATES = [
    "plant_par_umol_m2_s",
    "plant_par_spread_umol_m2_s",
    "plant_par_mc_sd_umol_m2_s",
    "canopy_an_umol_m2_s",
    "canopy_an_mc_sd_umol_m2_s",
]


@pytest.fixture(scope="module")
def weather():
    return forcing().iloc[[1, 5, 14]]  # 05:30 local (night), 07:30 (low sun), 12:00


def make_run(weather, fld=FIELD, samples=8, **kw):
    """A FieldRun of the test scenario; ``kw``: how to split it (tiles, halo_rows, time_chunks)."""
    return FieldRun(Scenario(weather=weather, field=fld, samples=samples, bounces=2, par_kind="absorbed"), **kw)


@pytest.fixture(scope="module")
def reference(weather):
    return run_single(make_run(weather))


@pytest.fixture(scope="module")
def client():
    with connect(workers=2, threads_per_worker=1, timeout_s=60) as cl:
        cl.wait_for_workers(2, timeout=60)
        yield cl


def assert_same(ds, ref):
    assert list(ds.data_vars) == list(ref.data_vars)
    assert list(ds.coords) == list(ref.coords)
    assert dict(ds.sizes) == dict(ref.sizes)
    for name in list(ref.coords):
        np.testing.assert_array_equal(ds[name].values, ref[name].values)
    for v in ref.data_vars:
        assert ds[v].dims == ref[v].dims and ds[v].dtype == ref[v].dtype, v
    for v in SEGMENT_VARS + ["sun_elevation_deg", "dni_w_m2", "tair_c"]:
        assert ds[v].attrs.keys() == ref[v].attrs.keys(), v  # arrays (flag_values) by value
        assert all(np.array_equal(ds[v].attrs[k], ref[v].attrs[k]) for k in ref[v].attrs), v
        np.testing.assert_array_equal(ds[v].values, ref[v].values, err_msg=v)  # bitwise (NaN == NaN)
    for v in AGGREGATES:  # recomputed sums: equal up to summation order
        assert ds[v].attrs["units"] == ref[v].attrs["units"] == "umol m-2 s-1", v
        np.testing.assert_allclose(ds[v].values, ref[v].values, rtol=1e-12, atol=1e-12, err_msg=v)


@pytest.mark.parametrize("tiles,time_chunks", [(2, 1), (4, 2)])
def test_exact_halo_is_bitwise_partition_independent(client, weather, reference, tiles, time_chunks):
    ds = run_field(
        make_run(weather, tiles=tiles, time_chunks=time_chunks), client=client, timeout_s=240, progress=tiles == 4
    )
    assert_same(ds, reference)
    assert ds.attrs["n_tiles"] == tiles and ds.attrs["tile"] == -1 and ds.attrs["halo_rows"] == -1
    assert ds.attrs["tasks"] == tiles * time_chunks and ds.attrs["distributed_workers"] == 2
    timing = json.loads(ds.attrs["tile_timing_json"])
    assert sorted((t["tile"], t["chunk"]) for t in timing) == [(k, c) for k in range(tiles) for c in range(time_chunks)]
    assert all(t["total_s"] > 0 and t["triangles"] >= t["triangles_measured"] > 0 for t in timing)
    # Exact halo: every tile renders the whole field.
    assert len({t["triangles"] for t in timing}) == 1
    assert ds.attrs["buffer_overhead"] == pytest.approx(tiles * timing[0]["triangles"] / ds.attrs["triangles_measured"])


def test_paper_halo_equals_per_tile_runs(client, weather):
    """halo_rows=H reproduces the single-process per-tile runs of ``Field.tiles`` exactly (H = buffer rows)."""
    from lightfit.model.coupled import CoupledModel

    run = make_run(weather, tiles=2, halo_rows=FIELD.buffer_rows)
    ds = run_field(run, client=client, timeout_s=240)
    for k in range(2):
        part = CoupledModel(dataclasses.replace(run.scenario, n_tiles=2, tile=k)).simulate()  # plain Field.tiles
        sub = ds.sel(segment=part["segment"].values)
        for v in SEGMENT_VARS:
            np.testing.assert_array_equal(sub[v].values, part[v].values, err_msg=v)
    timing = json.loads(ds.attrs["tile_timing_json"])
    assert all(t["triangles"] < 36 * 650 for t in timing)  # smaller scenes than the 4×4 whole grid
    assert 1 < ds.attrs["buffer_overhead"] < 2 * 16 / 4


def test_a_halo_without_the_whole_field_leaves_the_ceptometer_unrendered(client, weather, reference):
    """The ceptometer spans the whole measurement area and gather takes tile 0's reading: under tile
    0's block + halo it saw bare soil where the other tile's plants were left out (a review: fAPAR
    0.055 against the whole field's 0.26). With a halo that holds the whole field it is the single
    process's; with less, NaN (not rendered) and said so in the attributes."""
    from lightfit.model.schema import SENSOR_OBSERVABLES

    run = make_run(weather, tiles=2, halo_rows=0)
    ds = run_field(run, client=client, timeout_s=240)
    day = ds["sun_elevation_deg"].values > 0
    for v in ("transmitted_par_umol_m2_s", "ceptometer_transmittance"):
        assert np.isnan(ds[v].values[day]).all(), v  # was tile 0's reading under half a canopy
    assert ds.attrs["ceptometer"] == "none (not rendered)"
    assert run.partial_scenes and run.sensors == ()
    # a task kept by a partial-halo run before (it rendered the ceptometer) is not taken over; the keys
    # of runs whose scenes hold the whole field stay as they were (their kept tasks resume)
    from dataclasses import replace

    from lightfit.distributed.run import task_key, task_specs

    before = replace(run)
    before.partial_scenes = False  # the key as computed before partial runs said so
    assert {task_key(s) for s in task_specs(run)}.isdisjoint({task_key(s) for s in task_specs(before)})
    whole = make_run(weather, tiles=2, halo_rows=HaloField.of(FIELD).exact_halo_rows(2))
    assert not whole.partial_scenes and whole.sensors is None
    ds = run_field(whole, client=client, timeout_s=240)
    for v in SENSOR_OBSERVABLES:
        np.testing.assert_array_equal(ds[v].values, reference[v].values, err_msg=v)
    assert ds.attrs["ceptometer"] == reference.attrs["ceptometer"]


def test_periodic_field_is_bitwise_partition_independent(client, weather):
    """A periodic Field (one cell of an infinite field) reaches every task: each tile renders the whole cell."""
    run = make_run(weather, Field(n_plants=4, seed=1, boundary="periodic"), tiles=2)
    ds = run_field(run, client=client, timeout_s=240)
    ref = run_single(run)
    assert ds.attrs["boundary"] == ref.attrs["boundary"] == "periodic"
    for v in SEGMENT_VARS:
        np.testing.assert_array_equal(ds[v].values, ref[v].values, err_msg=v)
    with pytest.raises(InputError, match="halo_rows.*periodic"):
        make_run(weather, run.scenario.field, tiles=2, halo_rows=1)


def test_task_scenarios_are_the_run_scenario_split(weather):
    """Each task's Scenario is the run's, with only its tile, halo field and weather rows changed."""
    run = make_run(weather, tiles=4, halo_rows=1, time_chunks=2)
    split = {"weather", "field", "n_tiles", "tile"}
    for rows in run.chunk_index():
        for k in range(run.tiles):
            sc = run.task_scenario(k, rows)
            for f in dataclasses.fields(Scenario):
                if f.name not in split:
                    assert getattr(sc, f.name) == getattr(run.scenario, f.name), f.name
            assert (sc.n_tiles, sc.tile) == (4, k) and isinstance(sc.field, HaloField) and sc.field.halo_rows == 1
            assert sc.field.base() == FIELD
            assert sc.weather.index.equals(weather.index[rows])
            assert sc.measured_tile.measured.tolist() == run.tile_list[k].measured.tolist()
    assert run.task_scenario(0).weather is run.scenario.weather


def test_halo_tiles_match_field_tiles_and_cover_field():
    for fld in (
        Field(boundary="finite", n_plants=16, buffer_rows=2, seed=0),
        Field(boundary="finite", n_plants=25, buffer_rows=1, seed=3),
        Field(boundary="finite", n_plants=12, plants_per_row=6, buffer_rows=1, seed=4),
    ):
        for w in (1, 2, 4, 6):
            for a, b in zip(HaloField.of(fld, fld.buffer_rows).tiles(w), fld.tiles(w)):
                np.testing.assert_array_equal(a.measured, b.measured)
                np.testing.assert_array_equal(a.buffer, b.buffer)
            every = np.sort(fld.plants().index.to_numpy())
            for big in (None, max(fld.m, fld.m_along)):  # halo covering the field = whole field
                for t in HaloField.of(fld, big).tiles(w):
                    np.testing.assert_array_equal(t.plant_ids, every)
            measured = np.sort(np.concatenate([t.measured for t in fld.tiles(w)]))
            np.testing.assert_array_equal(measured, np.sort(fld.plants().query("measured").index.to_numpy()))


def test_worker_killed_mid_run_result_complete_and_equal(weather, reference):
    """SIGKILL a worker process while it runs a task: Dask re-runs its tasks elsewhere; same result."""
    run = make_run(weather, tiles=4, time_chunks=2)
    with connect(workers=2, threads_per_worker=1, timeout_s=60) as cl:
        cl.wait_for_workers(2, timeout=60)
        pids = cl.run(os.getpid)  # {worker address: pid}
        futures = submit(cl, run)
        victim = None
        deadline = time.monotonic() + 60
        while victim is None and time.monotonic() < deadline:  # cold workers: first task takes seconds
            busy = [a for a, keys in cl.processing().items() if keys and a in pids]
            if busy:
                victim = busy[0]
            else:
                time.sleep(0.01)
        assert victim is not None, "no task started within 60 s"
        os.kill(pids[victim], signal.SIGKILL)
        results = cl.gather(futures, errors="raise")
        ds = gather(results, run)
    infos = [i for _, i in results]
    assert len(infos) == 8
    assert pids[victim] not in {i["pid"] for i in infos}  # the killed process delivered nothing
    assert_same(ds, reference)


def test_bad_input_names_the_parameter(weather):
    with pytest.raises(InputError, match="tiles"):
        make_run(weather, tiles=0)
    with pytest.raises(InputError, match="tiles.*do not fit"):
        make_run(weather, tiles=9)  # 3×3 blocks on a 2×2 area
    with pytest.raises(InputError, match="time_chunks"):
        make_run(weather, time_chunks=3)
    with pytest.raises(InputError, match="halo_rows"):
        make_run(weather, halo_rows=-1)
    with pytest.raises(InputError, match="samples"):
        make_run(weather, samples=0)
    with pytest.raises(InputError, match="parameter 'steps': all 1 steps of the run are at night"):
        make_run(weather.iloc[[0]])  # 05:30 local
    with pytest.raises(InputError, match="scenario"):  # FieldRun makes the tiles
        FieldRun(dataclasses.replace(make_run(weather).scenario, n_tiles=2, tile=0))
    with pytest.raises(InputError, match="workers"):
        with connect(workers=0):
            pass
    t0 = time.monotonic()
    with pytest.raises(InputError, match="scheduler"):
        with connect("tcp://127.0.0.1:9", timeout_s=3):
            pass
    assert time.monotonic() - t0 < 30
    # A port that accepts but never speaks Dask (the handshake hung forever), and one that answers
    # in another protocol (a traceback from an absurd allocation): both refused within the timeout.
    for reply in (None, b"HTTP/1.1 400 Bad Request\r\nContent-Length: 0\r\n\r\n" * 3):
        server = socket.create_server(("127.0.0.1", 0))
        port = server.getsockname()[1]

        def serve(server=server, reply=reply):
            conn, _ = server.accept()
            if reply:
                conn.recv(100)
                conn.sendall(reply)
            time.sleep(10)

        threading.Thread(target=serve, daemon=True).start()
        t0 = time.monotonic()
        with pytest.raises(InputError, match="scheduler") as refused:
            with connect(f"tcp://127.0.0.1:{port}", timeout_s=2):
                pass
        assert time.monotonic() - t0 < 15
        assert ": )" not in str(refused.value), refused.value  # a silent port's TimeoutError has no text
        server.close()
    n, t = default_workers()
    assert n >= 1 and t == 1


def test_joining_a_scheduler_from_inside_an_event_loop(client):
    """The scheduler probe runs its own loop in a thread: connecting from async code (a notebook)
    works as it did before the probe existed."""
    import asyncio

    async def main():
        with connect(client.scheduler.address, timeout_s=20) as cl:
            return cl.scheduler.address

    assert asyncio.run(main()) == client.scheduler.address


def test_a_cluster_joined_by_address_keeps_its_workers_after_the_block(client):
    """connect() kills the workers of the cluster it started when its block ends (at once, whichever
    way it ends); a scheduler given by address is another's cluster: the block closes only its own
    client, and the cluster's workers, the same processes, take the next task."""
    pids = client.run(os.getpid)
    with connect(client.scheduler.address, timeout_s=20) as cl:
        assert cl.submit(os.getpid, pure=False).result() in pids.values()
    assert client.run(os.getpid) == pids
    assert client.submit(lambda: 42, pure=False).result(timeout=30) == 42


def test_cli_joins_existing_scheduler(client, tmp_path):
    import xarray as xr
    from typer.testing import CliRunner

    from lightfit.cli import app

    out = tmp_path / "r.nc"
    args = [
        "field-run",
        "--scheduler",
        client.scheduler.address,
        "--n-plants",
        "4",
        "--boundary",
        "finite",
        "--buffer-rows",
        "1",
        "--tiles",
        "2",
        "--samples",
        "8",
        "--bounces",
        "2",
        "--steps",
        "14:15",
        "--out",
        str(out),
        "--no-progress",
    ]
    r = CliRunner().invoke(app, args)
    assert r.exit_code == 0, r.output
    with xr.open_dataset(out, engine="h5netcdf") as ds:
        assert ds.sizes["time"] == 1 and ds.attrs["n_tiles"] == 2
        # Computed in the worker processes, which get float64 from _worker_setup (not from this test process).
        assert ds.attrs["precision"] == "float64" and ds["plant_par_umol_m2_s"].dtype == np.float64
        assert np.isfinite(ds["plant_par_umol_m2_s"].values).all()
    bad = CliRunner().invoke(app, args[:9] + ["--tiles", "9"] + args[11:])
    assert bad.exit_code == 2 and "tiles" in bad.stderr
    late = CliRunner().invoke(app, [*args[:-3], "--timeout", "0.001", "--out", str(tmp_path / "late.nc")])
    assert late.exit_code == 2 and "option --timeout" in late.stderr and not (tmp_path / "late.nc").exists()
    bad = CliRunner().invoke(
        app,
        [
            "field-run",
            "--scheduler",
            "tcp://127.0.0.1:9",
            "--n-plants",
            "4",
            "--steps",
            "14:15",
            "--connect-timeout",
            "3",
        ],
    )
    assert bad.exit_code == 2 and "scheduler" in bad.stderr


def _unreachable_cluster(monkeypatch, made: list | None = None) -> None:
    """Stand in for dask's LocalCluster (its keywords appended to ``made``) and a Client that cannot
    reach it (distributed's "Timed out trying to connect", an OSError)."""
    import distributed

    class Cluster:
        def __init__(self, **kw):
            if made is not None:
                made.append(kw)

        def close(self):
            pass

    def unreachable(*a, **k):
        raise OSError("Timed out trying to connect to tcp://127.0.0.1:1 after 0.001 s")

    monkeypatch.setattr(distributed, "LocalCluster", Cluster)
    monkeypatch.setattr(distributed, "Client", unreachable)


def test_cli_embedded_cluster_that_does_not_answer_is_the_options_error(tmp_path, monkeypatch):
    """A client that cannot reach the embedded cluster in time (distributed's "Timed out trying to
    connect", an OSError; seen with --connect-timeout 0.001, which a fast machine may still meet, so
    the cluster is stood in for here) is --connect-timeout's error, not ~90 lines of traceback (a
    review); nothing is written."""
    from typer.testing import CliRunner

    from lightfit.cli import app

    _unreachable_cluster(monkeypatch)
    slow = CliRunner().invoke(
        app,
        ["field-run", "--n-plants", "4", "--steps", "14:15", "--workers", "1", "--connect-timeout", "0.001"]
        + ["--out", str(tmp_path / "slow.nc")],
    )
    err = " ".join(slow.stderr.split())
    assert slow.exit_code == 2 and "option --connect-timeout" in err and "did not answer within 0.001 s" in err, err
    assert not (tmp_path / "slow.nc").exists()


def test_adaptive_time_chunks_allocate_at_the_whole_runs_point(weather, monkeypatch):
    """With adaptive sampling every task allocates at the whole run's point (its highest sun), not
    at its time chunk's, so the tasks' samples per segment agree: tiles and time chunks give the
    single process's result (each chunk allocated at its own sun before, and gather failed with
    conflicting samples_per_segment). Tasks run in this process (no cluster needed)."""
    import lightfit.model.scenario as scenario
    from lightfit.distributed.run import TaskSpec, run_task
    from lightfit.model.coupled import CoupledModel

    monkeypatch.setattr(scenario, "MAX_ADAPTIVE_SAMPLES", 256)  # seconds, not minutes
    sc = Scenario(weather=weather, field=FIELD, samples=32, bounces=2, par_kind="absorbed", target_rse=0.1)
    ref = run_single(FieldRun(sc))
    run = FieldRun(sc, tiles=2, time_chunks=2)
    whole = CoupledModel(sc, sensors=()).allocation_point
    chunks = run.chunk_index()
    for rows in chunks:
        leaf, sun, dni, dhi = run.task_scenario(0, rows).allocate_at
        np.testing.assert_array_equal(sun, whole[1])
        assert (leaf, dni, dhi) == (tuple(whole[0]), whole[2], whole[3])
    tasks = [TaskSpec(run=run, tile=k, chunk=c, rows=rows) for c, rows in enumerate(chunks) for k in range(2)]
    results = [run_task(t) for t in tasks]
    ds = gather(results, run)
    for v in ("samples_per_segment", "reached_rse", "stopped_on_floor", "absorbed_par_umol_m2_s"):
        np.testing.assert_array_equal(ds[v].values, ref[v].values)
    assert len(np.unique(ds["samples_per_segment"].values)) >= 2


def test_finished_tasks_are_kept_and_taken_again_only_for_the_same_settings(client, weather, reference, tmp_path):
    """A field-run keeps each finished task in its parts folder; a second run of the same settings
    takes every task from there (no task runs: the tasks' timings are the first run's) and gives the
    single process's values bitwise. A part missing, unreadable or made for another task is run again;
    so is every part for another θ."""
    from lightfit.distributed.run import task_key, task_specs

    run = make_run(weather, tiles=2, time_chunks=2)
    parts = tmp_path / "results.nc.parts"
    first = run_field(run, client=client, timeout_s=240, parts=parts)
    assert_same(first, reference)
    files = sorted(p.name for p in parts.iterdir())
    assert files == ["tile0-chunk0.pkl", "tile0-chunk1.pkl", "tile1-chunk0.pkl", "tile1-chunk1.pkl"]
    assert first.attrs["tasks_resumed"] == 0 and first.attrs["tasks_discarded"] == 0
    again = run_field(run, client=client, timeout_s=240, parts=parts)
    assert again.attrs["tasks_resumed"] == 4 and again.attrs["tile_timing_json"] == first.attrs["tile_timing_json"]
    assert_same(again, reference)
    (parts / "tile0-chunk0.pkl").unlink()
    (parts / "tile0-chunk1.pkl").write_bytes(b"not a pickle")
    (parts / "tile1-chunk0.pkl").write_bytes((parts / "tile1-chunk1.pkl").read_bytes())  # another task's
    mixed = run_field(run, client=client, timeout_s=240, parts=parts)
    assert mixed.attrs["tasks_resumed"] == 1
    assert mixed.attrs["tasks_discarded"] == 2  # the unreadable and the other task's: counted, not silent
    assert_same(mixed, reference)
    # Keys: per task, and they change with θ.
    specs = task_specs(run)
    assert len({task_key(s) for s in specs}) == 4
    other = dataclasses.replace(run, theta={"light_factor": 1.1})
    assert {task_key(s) for s in task_specs(other)}.isdisjoint({task_key(s) for s in specs})
    other_ds = run_field(other, client=client, timeout_s=240, parts=parts)
    assert other_ds.attrs["tasks_resumed"] == 0 and other_ds.attrs["tasks_discarded"] == 4
    # The growth file's contents, not its name only: an edited XML is another field.
    from lightfit.plant.growth import GrowthConfig

    xml = tmp_path / "wheat.xml"
    xml.write_bytes(run.scenario.field.growth.path.read_bytes())
    same = dataclasses.replace(run.scenario.field, growth=GrowthConfig(parameter_file=str(xml)))
    edited_run = dataclasses.replace(run, scenario=dataclasses.replace(run.scenario, field=same))
    key = task_key(task_specs(edited_run)[0])
    xml.write_bytes(xml.read_bytes() + b"<!-- edited -->")
    assert task_key(task_specs(edited_run)[0]) != key


def test_cli_field_run_interrupted_resumes_to_the_same_results(client, tmp_path):
    """Ctrl-C after the first finished task (a kill point in the client): exit 130 and a line saying
    what was kept; the same command then runs only the other task, says so, writes the results of an
    uninterrupted run (per-segment values bitwise) and removes the parts folder."""
    import subprocess
    import sys

    import xarray as xr

    args = ["field-run", "--scheduler", client.scheduler.address, "--n-plants", "4", "--boundary", "finite"]
    args += ["--buffer-rows", "1", "--tiles", "2", "--samples", "8", "--bounces", "2", "--steps", "14:15"]
    args += ["--no-progress"]

    def lightfit(out, kill_after=None):
        env = {**os.environ, "JAX_PLATFORMS": "cpu", "COLUMNS": "200"}
        env.pop("LIGHTFIT_TEST_KILL_AFTER", None)
        if kill_after:
            env["LIGHTFIT_TEST_KILL_AFTER"] = kill_after
        cmd = [sys.executable, "-m", "lightfit.cli", *args, "--out", str(out)]
        p = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=600)
        return p.returncode, p.stdout + p.stderr

    rc, output = lightfit(tmp_path / "ref.nc")
    assert rc == 0, output
    out = tmp_path / "run.nc"
    rc, output = lightfit(out, kill_after="field-task:1:INT")
    assert rc == 130 and "every finished task is kept beside --out" in output, output
    assert not out.exists() and len(list((tmp_path / "run.nc.parts").glob("*.pkl"))) == 1
    rc, output = lightfit(out)
    assert rc == 0 and "resumed: 1 of 2 tasks were kept from the run before" in output, output
    assert not (tmp_path / "run.nc.parts").exists()
    with xr.open_dataset(tmp_path / "ref.nc", engine="h5netcdf") as ref, xr.open_dataset(out, engine="h5netcdf") as ds:
        for v in SEGMENT_VARS:
            np.testing.assert_array_equal(ds[v].values, ref[v].values, err_msg=v)
        assert ds.attrs["tasks_resumed"] == 1 and ref.attrs["tasks_resumed"] == 0


def _ctrl_c_in_a_terminal(tmp_path, kill_after=None):
    """Run an embedded-cluster field-run in its own process group and send SIGINT to the whole group,
    as a terminal's Ctrl-C does: at the kill point ``kill_after``, or (None) as soon as the worker
    process exists, while it still imports Dask. Returns (exit status, stderr, whether any process of
    the group was left running)."""
    import subprocess
    import sys

    import psutil

    args = ["field-run", "--workers", "1", "--n-plants", "4", "--boundary", "finite", "--buffer-rows", "1"]
    args += ["--tiles", "2", "--samples", "8", "--bounces", "2", "--steps", "14:15", "--no-progress"]
    env = {**os.environ, "JAX_PLATFORMS": "cpu", "COLUMNS": "200"}
    env.pop("LIGHTFIT_TEST_KILL_AFTER", None)
    if kill_after:
        env["LIGHTFIT_TEST_KILL_AFTER"] = kill_after
    cmd = [sys.executable, "-m", "lightfit.cli", *args, "--out", str(tmp_path / "r.nc")]
    p = subprocess.Popen(
        cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True
    )
    try:
        if kill_after is None:
            waited, worker = 0.0, False
            while not worker and p.poll() is None and waited < 300:
                for child in psutil.Process(p.pid).children(recursive=True):
                    with contextlib.suppress(psutil.Error):  # a child that ended meanwhile
                        line = " ".join(child.cmdline())
                        worker = worker or ("spawn_main" in line and "resource_tracker" not in line)
                time.sleep(0.02)
                waited += 0.02
            assert worker, "no worker process started"
            os.killpg(p.pid, signal.SIGINT)
        _, err = p.communicate(timeout=600)
        for _ in range(100):  # the workers and multiprocessing's resource tracker exit after the command
            try:
                os.killpg(p.pid, 0)
            except ProcessLookupError:
                break
            time.sleep(0.1)
    finally:
        try:
            os.killpg(p.pid, signal.SIGKILL)  # nothing may be left of the group
            left = True
        except ProcessLookupError:
            left = False
    return p.returncode, err, left


INTERRUPTED_LINE = (
    "interrupted: every finished task is kept beside --out (OUT.parts/); rerun the same command to resume"
)


def test_a_terminal_ctrl_c_reaches_the_embedded_workers_and_prints_one_line(tmp_path):
    """A terminal's Ctrl-C goes to the whole process group, the embedded cluster's worker processes
    too: they printed 30–70 lines of tracebacks (an interrupted import, a cancelled event loop, a
    broken pipe) above lightfit's one line. The workers leave Ctrl-C to the command, which closes
    them: exit 130, one line on stderr, no worker left running. The SIGINT goes to the group after
    the first of two tasks is kept (a kill point), while the worker runs the second."""
    rc, err, left = _ctrl_c_in_a_terminal(tmp_path, kill_after="field-task:1:INT-GROUP")
    assert rc == 130, err
    assert err.splitlines() == [INTERRUPTED_LINE], err
    assert not left


def test_a_terminal_ctrl_c_while_the_workers_start_prints_one_line(tmp_path):
    """The same Ctrl-C in the first second of the worker's life, while it still imports Dask and
    before lightfit's import there ignores SIGINT: the worker printed a 33–36-line traceback of the
    interrupted import. Workers now start with SIGINT blocked (``_interrupt_deferred``)."""
    rc, err, left = _ctrl_c_in_a_terminal(tmp_path)
    assert rc == 130, err
    assert err.splitlines() == [INTERRUPTED_LINE], err
    assert not left


def test_holding_ctrl_c_while_a_cluster_starts_leaves_the_callers_signal_state_as_it_was(monkeypatch):
    """``_interrupt_deferred`` blocks SIGINT while a cluster starts and starts multiprocessing's
    resource tracker first, whose first start unblocks SIGINT in the calling thread: a caller that
    had SIGINT blocked got it back unblocked, and a setup that failed left lightfit's holding handler
    installed for good, every later Ctrl-C swallowed (a review)."""
    from lightfit.distributed import run

    handler = signal.getsignal(signal.SIGINT)
    signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        with run._interrupt_deferred():
            assert signal.getsignal(signal.SIGINT) is not handler
        assert signal.SIGINT in signal.pthread_sigmask(signal.SIG_BLOCK, set())
    finally:
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
    assert signal.getsignal(signal.SIGINT) is handler

    def fails(*_):
        raise OSError("no more processes")

    monkeypatch.setattr(signal, "pthread_sigmask", fails)
    with pytest.raises(OSError, match="no more processes"):
        with run._interrupt_deferred():
            pass
    monkeypatch.undo()
    assert signal.getsignal(signal.SIGINT) is handler
    assert signal.SIGINT not in signal.pthread_sigmask(signal.SIG_BLOCK, set())


def test_an_interrupt_while_a_worker_is_busy_stops_it_at_once_and_quietly(capfd):
    """A worker busy in a task that holds the interpreter (a render in C) cannot answer the cluster's
    close: on Ctrl-C the nanny waited 4 s to kill it and both logged heartbeat tracebacks (30–60
    lines, a review of interrupted runs). The embedded cluster's workers are now killed at once."""
    import logging

    from lightfit.distributed.run import connect

    def busy(seconds):  # holds the GIL, as Dr.Jit's and JAX's C calls do: the worker's event loop stalls
        import sys
        import time

        sys.setswitchinterval(60.0)
        end = time.time() + seconds
        while time.time() < end:
            pass

    with pytest.raises(KeyboardInterrupt):
        with connect(workers=1, threads_per_worker=1) as client:
            client.submit(busy, 30.0, pure=False)
            time.sleep(2.0)  # the task is running
            t0 = time.perf_counter()
            raise KeyboardInterrupt
    closed_in = time.perf_counter() - t0
    err = capfd.readouterr().err
    # the nanny's own wait is 4 s; killed at once, the close takes ≈ 0.01 s
    assert closed_in < 2.0 and "still alive" not in err and "Traceback" not in err, (closed_in, err)
    assert logging.getLogger("distributed").level != logging.CRITICAL  # muted for the close only


def test_a_finished_run_closes_its_workers_at_once_and_quietly(capfd):
    """A worker's own exit after a finished run (Dr.Jit's and JAX's teardown) outlasted the nanny's
    4 s on a loaded 2-core machine: every field-run ended with two "Worker process still alive after
    4.0 seconds, killing" lines and 4 s more. Here a worker's exit takes 30 s; the embedded
    cluster's workers are killed at once after a finished block, its results already returned."""
    import logging

    from lightfit.distributed.run import connect

    def slow_to_exit():
        import atexit
        import time

        atexit.register(time.sleep, 30.0)
        return 42

    with connect(workers=1, threads_per_worker=1) as client:
        assert client.submit(slow_to_exit, pure=False).result() == 42
        t0 = time.perf_counter()
    closed_in = time.perf_counter() - t0
    err = capfd.readouterr().err
    assert closed_in < 2.0 and "still alive" not in err and "Traceback" not in err, (closed_in, err)
    assert logging.getLogger("distributed").level != logging.CRITICAL  # muted for the close only


def test_an_error_in_the_block_leaves_a_task_about_to_finish_its_grace(tmp_path):
    """Only Ctrl-C and a finished block kill the workers at once: on another error (a --timeout, a
    task's failure) the nanny's grace lets a task that is about to finish write its render to the
    design cache, as before (a review: killed, it left an orphan partial file instead)."""
    from lightfit.distributed.run import connect

    def write_soon(path):
        import time

        time.sleep(1.5)
        with open(path, "w") as f:
            f.write("render")
        return path

    done = tmp_path / "render.npz"
    with pytest.raises(RuntimeError, match="the block failed"):
        with connect(workers=1, threads_per_worker=1) as client:
            client.submit(write_soon, str(done), pure=False)
            time.sleep(0.5)  # the task is running
            raise RuntimeError("the block failed")
    assert done.read_text() == "render"


def test_workers_drop_the_warning_of_a_task_lightfit_cancelled(caplog):
    """On --timeout or Ctrl-C lightfit cancels its tasks and says so in one line; a worker logged
    "Async instruction … ended with CancelledError" above it. Worker setup drops that record, and
    only that one."""
    import logging

    from lightfit.distributed.run import _worker_setup

    _worker_setup()
    _worker_setup()  # a second task on the worker: one filter, not two
    log = logging.getLogger("distributed.worker.state_machine")
    assert sum(type(f).__name__ == "_QuietCancel" for f in log.filters) == 1
    with caplog.at_level(logging.WARNING, logger="distributed.worker.state_machine"):
        log.warning("Async instruction for <Task cancelled name='execute(x)'> ended with CancelledError")
        log.warning("Async instruction for <Task name='execute(x)'> ended with OSError")
    assert [r.getMessage() for r in caplog.records] == [
        "Async instruction for <Task name='execute(x)'> ended with OSError"
    ]


def test_plant_rc_inverts_plant_id():
    """plant_rc is the inverse of plant_id: rows and columns not swapped, buffer plants (negative r, c) too."""
    from lightfit.distributed.tiles import plant_rc
    from lightfit.plant.field import plant_id

    assert int(plant_id(2, -1)) == 10020999  # (2 + 1000) × 10 000 + (−1 + 1000)
    r, c = plant_rc([10020999, 9991003, 10001000])
    assert r.tolist() == [2, -1, 0] and c.tolist() == [-1, 3, 0]


def test_halo_of_zero_rows_renders_only_the_block_and_one_row_its_ring():
    """halo_rows=0 is allowed (an integer ≥ 0) and a tile's scene is then its own block; halo_rows=1 adds
    the ring one plant deep, clipped to the field. 4×4 area, 2 buffer rows, 4 tiles of 2×2 (by hand)."""
    from lightfit.plant.field import plant_id

    fld = Field(boundary="finite", n_plants=16, buffer_rows=2, seed=0)
    for t, ref in zip(HaloField.of(fld, 0).tiles(4), fld.tiles(4)):
        np.testing.assert_array_equal(t.measured, ref.measured)
        assert t.buffer.size == 0
    t0 = HaloField.of(fld, 1).tiles(4)[0]  # measures r, c ∈ {0, 1}; ring r, c ∈ {−1 … 2}
    R, C = np.meshgrid(np.arange(-1, 3), np.arange(-1, 3), indexing="ij")
    np.testing.assert_array_equal(t0.plant_ids, np.sort(plant_id(R, C).ravel()))
    assert len(t0.measured) == 4 and len(t0.buffer) == 12


def test_impossible_tiling_is_the_error_of_fieldrun_tiles(weather):
    """FieldRun's attribute is ``tiles``: the error names that parameter, not Field.tiles' ``n_tiles``."""
    for bad in (0, 9):
        with pytest.raises(InputError) as err:
            make_run(weather, tiles=bad)
        assert err.value.parameter == "tiles", (bad, err.value.parameter)


def test_time_chunks_deal_daytime_and_night_steps_in_turn_in_time_order(weather):
    """Rows 03:00–04:30 UTC are night, 05:00, 07:30 and 10:00 UTC day (05:00–12:00 local). Two chunks:
    day rows 4, 6 and night rows 0, 2 to the first; day 5, night 1, 3 to the second; each in time
    order (the task's weather rows as in the run)."""
    from lightfit.model.scenario import daytime

    w = forcing().iloc[[0, 1, 2, 3, 4, 9, 14]]
    assert daytime(w).tolist() == [False] * 4 + [True] * 3
    run = make_run(w, time_chunks=2)
    assert [c.tolist() for c in run.chunk_index()] == [[0, 2, 4, 6], [1, 3, 5]]
    for rows in run.chunk_index():
        assert run.task_scenario(0, rows).weather.index.is_monotonic_increasing
    assert [c.tolist() for c in make_run(w, time_chunks=3).chunk_index()] == [[0, 3, 4], [1, 5], [2, 6]]


def test_time_chunks_dealt_out_of_time_order_gather_in_time_order():
    """A mutation audit: gather concatenates the chunks in chunk order, which is time order only where
    each chunk's steps follow the previous chunk's. Three daytime steps in two chunks are dealt as
    rows 0, 2 and row 1: concatenated, the times read 0, 2, 1 (the other tests' chunks, night rows
    first, happened to be in time order, so dropping gather's sort by time passed them). Tasks run
    here (no cluster); the reference is the untiled single-process run of the same scenario."""
    from lightfit.distributed.run import run_task, task_specs

    w = forcing().iloc[[4, 9, 14]]
    run = make_run(w, time_chunks=2, samples=4)
    assert [c.tolist() for c in run.chunk_index()] == [[0, 2], [1]]  # chunk order ≠ time order
    ds = gather([run_task(s) for s in task_specs(run)], run)
    np.testing.assert_array_equal(ds["time"].values, w.index.tz_convert(None).to_numpy())
    assert_same(ds, run_single(run))


def test_task_keys_tell_the_splits_apart():
    """A mutation audit: a kept task is taken again only for the same task (module doc, "Resume"). Keyed
    by the whole run's scenario and (tile, chunk) alone, tile 0 of a 2-tile run had the key of tile 0 of
    a 4-tile run, and of a run with another halo or other time chunks: a run resumed with another
    --tiles, --halo-rows or --time-chunks took parts measuring other plants or other steps (a segment
    twice, or silently missing plants). Every task of every split has its own key; the same run, the
    same keys."""
    from lightfit.distributed.run import task_key, task_specs

    w = forcing().iloc[[1, 5, 14]]
    splits = [{}, {"tiles": 2}, {"tiles": 4}, {"tiles": 2, "halo_rows": 1}, {"tiles": 2, "time_chunks": 2}]
    keys = [[task_key(s) for s in task_specs(make_run(w, **kw))] for kw in splits]
    flat = [k for ks in keys for k in ks]
    assert len(flat) == 1 + 2 + 4 + 2 + 4 and len(set(flat)) == len(flat)
    assert [task_key(s) for s in task_specs(make_run(w, tiles=2, time_chunks=2))] == keys[-1]


def test_a_resume_with_a_renamed_copy_of_the_forcing_says_which_forcing_it_ran(tmp_path):
    """Two forcing files of the same values, one the bundled reconstruction, the other a copy under
    another name that declares itself synthetic: their tasks have the same key (the scenario's digest
    hashes the rows, not the file's name or provenance), so a resume with the copy takes the first
    run's kept tasks — the values, rightly — but the results' forcing attributes must be the copy's.
    They were the kept task's (``gather`` took the attributes from ``results[0]``): a results file
    calling its forcing reconstructed, from a.csv, for a run of b.csv. Tasks run here (no cluster)."""
    import shutil

    from lightfit.distributed.run import run_task, task_key, task_specs
    from lightfit.weather.bundled import DATA_DIR

    src = DATA_DIR / "weather" / "selhausen_2016-04-20_reconstructed.csv"
    a, b = tmp_path / "a.csv", tmp_path / "b.csv"
    shutil.copy(src, a)
    text = src.read_text()
    assert "# provenance: reconstructed\n" in text
    b.write_text(text.replace("# provenance: reconstructed\n", "# provenance: synthetic\n"))
    run_a, run_b = (make_run(forcing(f).iloc[[14]], samples=4) for f in (a, b))
    specs_a, specs_b = task_specs(run_a), task_specs(run_b)
    assert [task_key(s) for s in specs_a] == [task_key(s) for s in specs_b]  # b's resume takes a's tasks
    kept = [run_task(s) for s in specs_a]
    ds = gather(kept, run_b)
    assert ds.attrs["weather_source"] == str(b) and ds.attrs["weather_provenance"] == "synthetic"
    assert gather(kept, run_a).attrs["weather_source"] == str(a)
    assert list(ds.attrs) == list(kept[0][0].attrs) + [k for k in ds.attrs if k not in kept[0][0].attrs]


def test_gather_refuses_a_missing_or_repeated_task_and_records_the_split(weather):
    """Two tiles with a one-row halo, run here (no cluster). A result set without tile 1 is refused (it
    would have half the segments); tile 0 given twice is refused (its segments twice). The merged
    Dataset has each tile's segments once and records the split it was made with."""
    from lightfit.distributed.run import run_task, task_specs

    run = make_run(weather.iloc[[2]], tiles=2, halo_rows=1)
    results = [run_task(s) for s in task_specs(run)]
    with pytest.raises(InputError, match="task results cover"):
        gather(results[:1], run)
    with pytest.raises(InputError, match="segment id occurs in two tiles"):
        gather([*results, results[0]], run)
    ds = gather(results, run)
    seg = np.concatenate([d["segment"].values for d, _ in results])
    np.testing.assert_array_equal(ds["segment"].values, np.sort(seg))
    assert len(np.unique(seg)) == len(seg)
    a = ds.attrs
    assert (a["n_tiles"], a["time_chunks"], a["tasks"], a["halo_rows"]) == (2, 1, 2, 1)
    assert a["halo"] == "1 plant rows/columns around each tile"
    tri = sum(i["triangles"] for _, i in results)
    assert a["triangles_rendered"] == tri and a["buffer_overhead"] == tri / a["triangles_measured"]
    # An unconverged solve in a task is warned of by gather, for the whole run, as a single process
    # warns (the worker's warning went to its log, or nowhere on a joined cluster or when resumed).
    import warnings

    from lightfit.model.coupled import NonConvergenceWarning

    flagged = results[1][0].copy(deep=True)
    blade = np.flatnonzero(flagged["is_blade"].values.astype(bool))[0]
    flagged["converged"][0, blade] = 0
    n_bad = sum(
        int((d["converged"].values[:, d["is_blade"].values.astype(bool)] == 0).sum()) for d in (results[0][0], flagged)
    )
    with pytest.warns(NonConvergenceWarning, match=f"did not converge for {n_bad} blade-step"):
        gather([results[0], (flagged, results[1][1])], run)
    if n_bad == 1:  # the task's own results converged: gathering them says nothing
        with warnings.catch_warnings():
            warnings.simplefilter("error", NonConvergenceWarning)
            gather(results, run)


@pytest.mark.parametrize(
    "name, value",
    [
        ("timeout_s", 0),
        ("timeout_s", float("nan")),
        ("connect_timeout_s", 0.0),
        ("timeout_s", float("inf")),
        ("connect_timeout_s", float("inf")),
    ],
)
def test_run_field_refuses_a_timeout_not_above_zero_before_any_cluster(weather, monkeypatch, name, value):
    """--timeout / --connect-timeout must be finite and > 0 (0 timed out at once, NaN never; inf was
    Dask's KeyError "Invalid time unit: inf" as a traceback, or with --scheduler an error blaming the
    address), refused before a cluster starts."""
    import lightfit.distributed.run as R

    def no_cluster(*a, **k):
        raise AssertionError("a cluster was started")

    monkeypatch.setattr(R, "connect", no_cluster)
    with pytest.raises(InputError) as err:
        run_field(make_run(weather), **{name: value})
    assert err.value.parameter == name.removesuffix("_s")


def test_default_workers_gpu_count_and_gpu_pinning(monkeypatch):
    """By hand: 64 cores and 8 GiB → 4 workers (one per 2 GiB); 3 cores and 64 GiB → 3; GPUs visible
    → one worker per GPU. CUDA_VISIBLE_DEVICES counts listed devices ("-1" and blanks are none);
    worker i of an embedded cluster is pinned to GPU i mod n."""
    import types

    import lightfit.distributed.run as R

    def machine(cores, gib):
        monkeypatch.setattr(os, "sched_getaffinity", lambda pid: set(range(cores)), raising=False)
        pages = {"SC_PAGE_SIZE": 4096, "SC_PHYS_PAGES": gib * 2**30 // 4096}
        monkeypatch.setattr(os, "sysconf", lambda name: pages[name])

    monkeypatch.setenv("CUDA_VISIBLE_DEVICES", "")
    machine(64, 8)
    assert default_workers() == (4, 1)
    machine(3, 64)
    assert default_workers() == (3, 1)
    machine(64, 1)
    assert default_workers() == (1, 1)  # at least one
    for vis, n in (("0,1", 2), ("-1", 0), ("", 0), ("2, 3,", 2)):
        monkeypatch.setenv("CUDA_VISIBLE_DEVICES", vis)
        assert R.gpu_count() == n, vis
    monkeypatch.setenv("CUDA_VISIBLE_DEVICES", "0,1,2")
    assert default_workers() == (3, 1)
    pin = R.PinGPU(3)
    for name, want in ((4, "1"), ("2", "2"), ("tcp://127.0.0.1:1", "2")):  # a name that is no index: left alone
        pin.setup(types.SimpleNamespace(name=name))
        assert os.environ["CUDA_VISIBLE_DEVICES"] == want, name


def test_cli_embedded_cluster_gets_the_workers_and_threads_asked_for(tmp_path, monkeypatch):
    """--workers and --threads-per-worker size the embedded LocalCluster (not each other), the workers'
    Dr.Jit/OpenMP threads follow --threads-per-worker, and XLA's own threading is turned off only for
    single-threaded workers. The cluster is stood in for; the client then fails to connect."""
    from typer.testing import CliRunner

    from lightfit.cli import app

    made = []
    _unreachable_cluster(monkeypatch, made)
    monkeypatch.delenv("XLA_FLAGS", raising=False)
    base = ["field-run", "--n-plants", "4", "--steps", "14:15", "--out", str(tmp_path / "r.nc")]
    for workers, threads in ((3, 2), (2, 1)):
        r = CliRunner().invoke(app, [*base, "--workers", str(workers), "--threads-per-worker", str(threads)])
        assert r.exit_code == 2 and "option --connect-timeout" in " ".join(r.stderr.split()), r.output
        kw = made.pop()
        assert (kw["n_workers"], kw["threads_per_worker"], kw["processes"]) == (workers, threads, True)
        assert kw["env"]["LIGHTFIT_WORKER_THREADS"] == kw["env"]["OMP_NUM_THREADS"] == str(threads)
        assert ("--xla_cpu_multi_thread_eigen=false" in kw["env"].get("XLA_FLAGS", "")) == (threads == 1)


def test_cli_field_run_options_reach_the_run(tmp_path, monkeypatch):
    """Each field-run option reaches its FieldRun / run_field parameter, and the parts folder is
    OUT.parts: kept by default, emptied first with --no-resume. run_field is stood in for (it times out)."""
    from typer.testing import CliRunner

    import lightfit.distributed.run as R
    from lightfit.cli import app

    seen = []

    def fake_run_field(run, **kw):
        parts = kw["parts"]
        seen.append((run, kw, sorted(p.name for p in parts.iterdir()) if parts.exists() else None))
        raise TimeoutError

    monkeypatch.setattr(R, "run_field", fake_run_field)
    out = tmp_path / "r.nc"
    parts = tmp_path / "r.nc.parts"
    parts.mkdir()
    (parts / "tile0-chunk0.pkl").write_bytes(b"kept")
    args = ["field-run", "--n-plants", "4", "--boundary", "finite", "--buffer-rows", "1", "--steps", "12:15"]
    args += ["--tiles", "2", "--halo-rows", "1", "--time-chunks", "3", "--workers", "3", "--threads-per-worker", "2"]
    args += ["--timeout", "5", "--connect-timeout", "7", "--out", str(out)]
    for extra, kept, again in (([], ["tile0-chunk0.pkl"], "the same command"), (["--no-resume"], None, "without")):
        r = CliRunner().invoke(app, [*args, *extra])
        err = " ".join(r.stderr.split())
        assert r.exit_code == 2 and "option --timeout" in err and "within 5 s" in err, r.output
        assert str(parts) in err and again in err, err
        run, kw, listing = seen.pop()
        assert (run.tiles, run.halo_rows, run.time_chunks) == (2, 1, 3)
        assert (kw["scheduler"], kw["workers"], kw["threads_per_worker"]) == (None, 3, 2)
        assert (kw["timeout_s"], kw["connect_timeout_s"], kw["parts"]) == (5, 7, parts)
        assert listing == kept
    assert not out.exists()


def test_cli_field_run_no_resume_discards_nothing_when_an_option_is_refused(tmp_path):
    """--no-resume emptied OUT.parts before --theta, the weather and the tiles were checked, so a
    typo in a later option cost every finished task of the run before (a review). Refused first."""
    from typer.testing import CliRunner

    from lightfit.cli import app

    out, parts = tmp_path / "r.nc", tmp_path / "r.nc.parts"
    parts.mkdir()
    (parts / "tile0-chunk0.pkl").write_bytes(b"kept")
    args = ["field-run", "--quick", "--no-resume", "--out", str(out)]
    for bad in (["--theta", "specular=2"], ["--tiles", "0"], ["--time-chunks", "999"]):
        r = CliRunner().invoke(app, [*args, *bad])
        assert r.exit_code == 2, (bad, r.output)
        assert (parts / "tile0-chunk0.pkl").read_bytes() == b"kept", bad


def test_cli_field_run_refuses_threads_per_worker_with_a_scheduler(tmp_path):
    """--threads-per-worker sizes only the embedded cluster: with --scheduler it was silently dropped
    (the joined cluster's workers keep their own threads) while --workers was refused. Now refused
    too, naming the option, before any plant grows or the scheduler is contacted."""
    from typer.testing import CliRunner

    from lightfit.cli import app
    from lightfit.distributed.run import check_cluster_options

    with pytest.raises(InputError) as err:
        check_cluster_options("tcp://127.0.0.1:8786", threads_per_worker=4)
    assert err.value.parameter == "threads_per_worker"
    check_cluster_options(None, threads_per_worker=4)  # the embedded cluster's option
    args = ["field-run", "--quick", "--out", str(tmp_path / "r.nc"), "--scheduler", "tcp://127.0.0.1:9"]
    r = CliRunner().invoke(app, [*args, "--threads-per-worker", "4"])
    assert r.exit_code == 2 and "--threads-per-worker" in r.output and "cannot connect" not in r.output, r.output


@pytest.mark.parametrize(
    "fld",
    [
        FIELD,
        Field(boundary="finite", n_plants=9, buffer_rows=1, buffer_along=3, seed=1),
        Field(boundary="finite", n_plants=8, plants_per_row=4, buffer_rows=1, seed=1),
    ],
)
def test_exact_halo_rows_is_the_fewest_that_give_every_tile_the_whole_field(fld):
    """At ``exact_halo_rows`` every tile's scene holds every plant of the field, so it renders what one
    process renders; one row fewer leaves some tile without some plant (field-run cautions below it).
    Counted on the tiles' plant sets, no render; never more than the docs' bound, side + buffer."""
    all_plants = set(fld.plants().index)
    for tiles in (2, 4) if fld.n_along % 2 == 0 else (3,):
        h = HaloField.of(fld).exact_halo_rows(tiles)
        assert 0 < h <= max(fld.n_rows, fld.n_along) + max(fld.buffer_rows, fld.buffer_along or 0)
        full = HaloField.of(fld, halo_rows=h).tiles(tiles)
        assert all(set(t.measured) | set(t.buffer) == all_plants for t in full)
        short = HaloField.of(fld, halo_rows=h - 1).tiles(tiles)
        assert any(set(t.measured) | set(t.buffer) != all_plants for t in short)


def test_a_field_run_without_theta_takes_its_scenarios_own_leaf(weather):
    """FieldRun's default theta was Theta(), the default leaf's values: a field-run with the paper's
    grey leaf rendered it with the PROSPECT leaf's subsurface (0.596 against its own 0.3), unlike
    replicate. Now {} (the scenario's own leaf), and the tasks' key hashes the values a task runs
    with, so a task kept by the old default is not taken for one of the new (a review)."""
    from lightfit.distributed.run import task_key, task_specs
    from lightfit.light.scene import Optics
    from lightfit.model.parameters import Theta

    grey = Optics.preset("paper")
    sc = Scenario(weather=weather.iloc[[2]], field=FIELD, samples=8, bounces=2, optics=grey)
    ds = run_single(FieldRun(sc))
    assert ds.attrs["theta_subsurface"] == grey.subsurface == sc.theta.subsurface != Theta().subsurface
    (own,), (old,) = (task_specs(FieldRun(sc, theta=t)) for t in ({}, Theta()))
    assert task_key(own) != task_key(old)
    assert task_key(own) == task_key(task_specs(FieldRun(sc, theta=sc.theta))[0])  # the same values, one key


def test_a_task_taken_by_the_client_is_no_longer_held_by_the_workers(client, weather, monkeypatch, tmp_path):
    """Once run_field has a task's result, the cluster forgets it: a worker killed later made Dask
    compute again every finished task it still held ("lose already computed task(s), which will be
    recomputed elsewhere"), results the client had already taken and kept beside --out."""
    import lightfit.distributed.run as dr

    def held():
        return client.run_on_scheduler(
            lambda dask_scheduler: [
                k for k, t in dask_scheduler.tasks.items() if str(k).startswith("lightfit-tile") and t.state == "memory"
            ]
        )

    seen = []

    def hook(kind, n):  # after the n-th result is taken and kept
        if n == 2:  # both taken: none held (the release reaches the scheduler within moments)
            deadline = time.monotonic() + 10
            while held() and time.monotonic() < deadline:
                time.sleep(0.05)
            seen.append(len(held()))

    monkeypatch.setattr(dr, "kill_point", hook)
    ds = run_field(make_run(weather, tiles=2), client=client, timeout_s=240, parts=tmp_path / "results.nc.parts")
    assert ds.attrs["tasks"] == 2 and seen == [0]


def test_cli_a_scheduler_without_workers_is_named_not_the_timeout(client, tmp_path):
    """Joined to a scheduler with no workers, no task runs however long the command waits: --timeout
    ran out with "expected a longer --timeout". The error names --scheduler and its lack of workers;
    with workers, a timeout says how many tasks finished on how many."""
    from distributed import LocalCluster
    from typer.testing import CliRunner

    from lightfit.cli import app

    args = ["field-run", "--n-plants", "4", "--boundary", "finite", "--buffer-rows", "1", "--samples", "8"]
    args += ["--bounces", "2", "--steps", "14:15", "--no-progress", "--out", str(tmp_path / "r.nc")]
    with LocalCluster(n_workers=0, processes=False, dashboard_address=":0") as empty:
        r = CliRunner().invoke(app, [*args, "--scheduler", empty.scheduler_address, "--timeout", "2"])
    err = " ".join(r.stderr.split())
    assert r.exit_code == 2 and "option --scheduler" in err and "has no workers" in err, r.output
    assert "longer --timeout" not in err and not (tmp_path / "r.nc").exists()
    late = CliRunner().invoke(app, [*args, "--scheduler", client.scheduler.address, "--timeout", "0.001"])
    err = " ".join(late.stderr.split())
    assert late.exit_code == 2 and "option --timeout" in err and "0 of 1 tasks finished" in err, late.output
    assert "on 2 worker(s)" in err


def test_a_local_cluster_that_does_not_start_names_the_workers_not_the_connect_timeout(monkeypatch):
    """--connect-timeout bounds the client's connection, not the workers' start (a review started
    workers with 0.3 s): a cluster that fails to start was blamed on it ("a longer one")."""
    import distributed

    def fail(*args, **kwargs):
        raise RuntimeError("Nanny failed to start")

    monkeypatch.setattr(distributed, "LocalCluster", fail)
    with pytest.raises(InputError, match="did not start") as refused:
        with connect(workers=1, threads_per_worker=1, timeout_s=5):
            pass
    assert refused.value.parameter == "workers" and "connect" not in str(refused.value), refused.value
