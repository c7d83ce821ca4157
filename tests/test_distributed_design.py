"""Emulator design renders on a Dask cluster (lightfit.distributed.design).

Tiny field (2×2 measured plants, one buffer row, K=8, 2 bounces), a model restricted to 2 of 3 steps
with one sun position rendered (so the step masks travel), on a LocalCluster of 2 single-threaded
worker processes.
"""

from functools import partial

import numpy as np
import pytest
from typer.testing import CliRunner

from lightfit.cache import ENV_CACHE
from lightfit.distributed import connect
from lightfit.distributed.design import design_renderer, missing_points, render_design, step_masks
from lightfit.errors import InputError
from lightfit.model import emulator as E
from lightfit.model.coupled import CoupledModel
from lightfit.model.scenario import Scenario
from lightfit.plant import Field
from lightfit.precision import use_float64
from lightfit.replication import forcing

LO, HI = (0.1, 0.1, 0.1), (0.9, 0.9, 0.9)


@pytest.fixture(scope="module")
def model(tmp_path_factory):
    use_float64()  # as the command line and the workers do
    sc = Scenario(
        weather=forcing().iloc[[1, 5, 14]],  # 05:30 local (night), 07:30, 12:00
        field=Field(boundary="finite", n_plants=4, buffer_rows=1, seed=1),
        samples=8,
        bounces=2,
        par_kind="absorbed",
    )
    # Kept: 07:30 and 12:00; rendered: 12:00 only (as observed_model cuts a calibration's model).
    return E.restrict(CoupledModel(sc), [False, True, True], [False, False, True])


@pytest.fixture(scope="module")
def client():
    with connect(workers=2, threads_per_worker=1, timeout_s=60) as cl:
        yield cl


def test_step_masks_rebuild_the_restricted_model(model):
    """The masks shipped to the workers give back the client's model (same render key)."""
    keep, rendered = step_masks(model)
    assert keep.tolist() == [False, True, True] and rendered.tolist() == [False, False, True]
    again = E.restrict(CoupledModel(model.scenario), keep, rendered)
    assert E.render_key(again) == E.render_key(model)


def test_cluster_renders_equal_local_renders_and_only_missing_points_are_sent(model, client, tmp_path):
    """Points rendered by the workers into the cache are bitwise the local renders; a point already in
    the cache is not sent; the emulator then fits from the cache without rendering here."""
    cache = tmp_path / "renders"
    key = E.render_key(model)
    pts = E.sobol_design(3, LO, HI, seed=0)
    E.render_parts(model, pts[:1], cache=cache, key=key)  # one point pre-populated locally
    assert len(missing_points(pts, cache, key)) == 2  # render_file names the file render_parts wrote
    info = render_design(client, model, pts, cache, key, progress=False)
    assert sum(i["points"] for i in info) == 2 and sum(i["rendered"] for i in info) == 2
    assert len(missing_points(pts, cache, key)) == 0
    assert render_design(client, model, pts, cache, key, progress=False) == []  # nothing left to send
    local_v, local_s = E.render_parts(model, pts[1:])  # in this process, no cache
    for x, v, s in zip(pts[1:], local_v, local_s):
        with np.load(E.render_file(cache, key, x)) as z:
            np.testing.assert_array_equal(z["values"], v)
            np.testing.assert_array_equal(z["se"], s)
            np.testing.assert_array_equal(z["leaf"], x)


def test_a_design_resumed_from_the_cache_says_so(model, tmp_path, capsys):
    """A rerun after an interruption rendered the rest and said only "rendering design: 3/3" (a
    review): the line now counts the renders read from the cache, and a fresh design says nothing."""
    key, pts = E.render_key(model), E.sobol_design(3, LO, HI, seed=1)
    E.render_parts(model, pts[:1], cache=tmp_path, key=key, progress=True)
    assert "rendering design: 1/1" in capsys.readouterr().out
    E.render_parts(model, pts, cache=tmp_path, key=key, progress=True)
    assert "rendering design (1 of 3 from the cache): 3/3" in capsys.readouterr().out
    # a point repeated in a fresh design is rendered once, not "from the cache"
    E.render_parts(model, np.concatenate([pts[2:], pts[2:]]), cache=tmp_path / "new", key=key, progress=True)
    assert "rendering design: 2/2" in capsys.readouterr().out


def test_a_damaged_render_in_the_cache_is_rendered_again(model, tmp_path):
    """A render file cut or damaged outside lightfit (a cut copy, a full disk) stopped every rerun
    with a BadZipFile or EOFError traceback (a review): it is rendered again and replaced, never read
    as data, as the plant cache's and a fitted emulator's are."""
    key, pts = E.render_key(model), E.sobol_design(2, LO, HI, seed=2)
    v, s = E.render_parts(model, pts, cache=tmp_path, key=key)
    file = E.render_file(tmp_path, key, pts[1])
    whole = file.read_bytes()
    for damaged in (whole[:200], b"", whole[:-30] + bytes(30)):
        file.write_bytes(damaged)
        before = dict(E.COUNTS)
        v2, s2 = E.render_parts(model, pts, cache=tmp_path, key=key)
        np.testing.assert_array_equal(v2, v)
        np.testing.assert_array_equal(s2, s)
        assert E.COUNTS["rendered"] - before["rendered"] == 1 and E.COUNTS["cached"] - before["cached"] == 1
        with np.load(file) as z:
            np.testing.assert_array_equal(z["values"], v[1])


def test_build_emulator_with_the_hook_renders_nothing_locally(model, client, tmp_path):
    """build_emulator(render_points=...) sends the design to the cluster and fits from the cache: the
    same emulator as a local build of the same design."""
    before = dict(E.COUNTS)
    hook = partial(render_design, client, progress=False)
    emu = E.build_emulator(model, LO, HI, n_design=5, degrees=(1,), cache=tmp_path / "a", render_points=hook)
    # counted as 5 new renders (made on the workers), none read from an earlier cache
    assert E.COUNTS["rendered"] - before["rendered"] == 5 and E.COUNTS["cached"] == before["cached"]
    local = E.build_emulator(model, LO, HI, n_design=5, degrees=(1,), cache=tmp_path / "b")
    np.testing.assert_array_equal(emu.coef_values, local.coef_values)
    np.testing.assert_array_equal(emu.coef_se, local.coef_se)
    with pytest.raises(InputError, match="cache"):
        E.build_emulator(model, LO, HI, n_design=5, render_points=hook)


def test_worker_with_another_render_key_fails_loudly(model, client, tmp_path):
    """A worker whose model is not the client's (here: the client claims K=9) refuses to fill the cache."""
    key = {**E.render_key(model), "samples": 9}
    with pytest.raises(InputError, match="samples: 9 → 8"):
        render_design(client, model, E.sobol_design(1, LO, HI, seed=0), tmp_path, key, progress=False)
    assert not list(tmp_path.glob("*.npz"))


def test_design_renderer_without_options_is_local():
    with design_renderer() as hook:
        assert hook is None


OBS = (
    "# provenance: synthetic\n# note: dask design test\ntime,plant_par_umol_m2_s,plant_par_sd_umol_m2_s\n"
    "2016-04-20T09:00:00Z,300,20\n2016-04-20T10:00:00Z,400,20\n"
)


def test_posterior_cli_workers_renders_the_design_on_the_cluster(tmp_path, monkeypatch):
    """``lightfit posterior --workers 1``: the design is rendered by the embedded cluster's worker,
    reported as this run's new renders."""
    from lightfit.cli import app

    monkeypatch.setenv(ENV_CACHE, str(tmp_path / "cache"))
    obs = tmp_path / "obs.csv"
    obs.write_text(OBS, encoding="utf-8")
    args = ["posterior", str(obs), "--quick", "--steps", "12:15", "--n-design", "6", "--parameters", "specular"]
    args += ["--walkers", "4", "--max-steps", "10", "--n-test", "0", "--no-analysis", "--workers", "1"]
    before = dict(E.COUNTS)
    r = CliRunner().invoke(app, [*args, "--out", str(tmp_path / "post")])
    assert r.exit_code == 0, r.output
    assert "design: 6 new renders, 0 from the cache (2 sun positions" in r.output.replace("\n", "")
    (d,) = (tmp_path / "cache" / "designs").iterdir()
    files = sorted((d / "renders").glob("*.npz"))
    assert len(files) == 6
    assert E.COUNTS["rendered"] - before["rendered"] == 6


def test_the_render_key_names_only_the_rendered_steps(model):
    """A step kept but not rendered (night, or one observed only by the above-canopy sensor) is in
    no render: the same rendered steps with or without it are one design (a CO2 record with night
    readings made a second design of the same renders; a review). Their renders are bitwise equal;
    another rendered step is another key."""
    base = CoupledModel(model.scenario)
    with_night = E.restrict(base, [True, True, True], [False, False, True])
    alone = E.restrict(base, [False, False, True])
    assert E.render_key(with_night) == E.render_key(alone) == E.render_key(model)
    assert E.design_dir(with_night) == E.design_dir(alone)
    leaf = {"specular": 0.5, "roughness": 0.5, "subsurface": 0.5}
    for x, y in zip(with_night.render(leaf), alone.render(leaf)):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
    assert E.render_key(E.restrict(base, [False, True, True])) != E.render_key(model)


class _Done:
    """A finished future of :class:`_Client` (the task is not run: its result says how many points it had)."""

    status = "finished"

    def __init__(self, n):
        self.n = n

    def done(self):
        return True

    def result(self):
        return {"points": self.n, "rendered": self.n}

    def release(self):
        pass


class _Client:
    """Two workers; records the points of each submitted chunk."""

    def __init__(self):
        self.chunks = []

    def nthreads(self):
        return {"tcp://w1": 1, "tcp://w2": 1}

    def submit(self, fn, chunk, key, pure):
        self.chunks.append(chunk.leaf)
        return _Done(len(chunk.leaf))


def _fake_model():
    """What render_design reads of a model: its steps (one, daytime) and its scenario's weather."""
    from types import SimpleNamespace

    import pandas as pd

    times = pd.date_range("2016-04-20 10:00", periods=2, freq="30min", tz="UTC")
    return SimpleNamespace(
        day=np.array([True]), times=times[1:], scenario=SimpleNamespace(weather=pd.DataFrame(index=times))
    )


def test_missing_points_lists_a_repeated_point_once(tmp_path):
    """A point given twice is rendered once; a point whose render file exists is not missing."""
    key = {"design": "test"}
    a, b = [0.1, 0.2, 0.3], [0.4, 0.5, 0.6]
    np.testing.assert_array_equal(missing_points([a, a, b, a], tmp_path, key), [a, b])
    E.render_file(tmp_path, key, a).touch()
    np.testing.assert_array_equal(missing_points([a, b, b], tmp_path, key), [b])
    assert missing_points([a], tmp_path, key).shape == (0, 3)


def test_render_design_shares_the_missing_points_over_the_workers(tmp_path, monkeypatch):
    """Default chunk: the missing points shared evenly, rounded up (3 points on 2 workers: 2 + 1, in
    order); chunk=n: n per task; chunk=0 refused. The new renders count as this process's (3 rendered,
    3 fewer cache hits)."""
    monkeypatch.setattr(E, "COUNTS", {"rendered": 0, "cached": 10})
    pts = np.array([[0.1, 0.1, 0.1], [0.2, 0.2, 0.2], [0.3, 0.3, 0.3]])
    model, key = _fake_model(), {"design": "test"}
    client = _Client()
    info = render_design(client, model, pts, tmp_path, key, progress=False)
    assert [len(c) for c in client.chunks] == [2, 1] and [i["points"] for i in info] == [2, 1]
    np.testing.assert_array_equal(np.concatenate(client.chunks), pts)
    assert E.COUNTS == {"rendered": 3, "cached": 7}
    client = _Client()
    render_design(client, model, pts, tmp_path, key, chunk=3, progress=False)
    assert [len(c) for c in client.chunks] == [3]
    with pytest.raises(InputError, match="chunk"):
        render_design(_Client(), model, pts, tmp_path, key, chunk=0, progress=False)


def test_render_design_names_what_it_renders_in_its_progress_line(tmp_path, monkeypatch):
    """The posterior's held-out renders on workers read "rendering design on 2 worker(s)" beside a line
    saying the design needed no renders (a review): the line takes the caller's label."""
    import contextlib

    from lightfit.distributed import design

    said = []

    @contextlib.contextmanager
    def bar(label, total, show):
        said.append(label)
        yield type("Bar", (), {"update": lambda self, **kw: None})()

    monkeypatch.setattr(design, "progress_bar", bar)
    pts = np.array([[0.1, 0.1, 0.1]])
    render_design(_Client(), _fake_model(), pts, tmp_path, {"design": "test"}, progress=False)
    render_design(_Client(), _fake_model(), pts, tmp_path / "b", {"design": "test"}, label=E.HELD_OUT_LABEL)
    assert said == ["rendering design on 2 worker(s)", "rendering held-out check on 2 worker(s)"]


def test_design_renderer_joins_the_scheduler_only_when_a_point_is_missing(tmp_path, monkeypatch):
    """A design already in the cache starts or joins no cluster; the first missing point joins the
    given --scheduler (once, reused for the next call)."""
    from contextlib import contextmanager

    import lightfit.distributed.design as D

    calls = []

    @contextmanager
    def fake_connect(scheduler=None, *, workers=None, timeout_s=None):
        calls.append((scheduler, workers, timeout_s))
        yield _Client()

    monkeypatch.setattr(D, "connect", fake_connect)
    monkeypatch.setattr(E, "COUNTS", {"rendered": 0, "cached": 0})
    model, key = _fake_model(), {"design": "test"}
    done, todo = [0.1, 0.2, 0.3], [0.4, 0.5, 0.6]
    E.render_file(tmp_path, key, done).touch()
    with design_renderer("tcp://scheduler:8786") as hook:
        assert hook(model, [done], tmp_path, key) == []
        assert calls == []
        assert len(hook(model, [done, todo], tmp_path, key, progress=False)) == 1
        hook(model, [todo], tmp_path, key, progress=False)
    assert calls == [("tcp://scheduler:8786", None, 30.0)]  # connect's default timeout (--connect-timeout)


@pytest.mark.parametrize(
    ("command", "options", "named"),
    [
        ("calibrate", ["--workers", "2", "--scheduler", "tcp://127.0.0.1:8786"], "--workers"),
        ("posterior", ["--workers", "2", "--scheduler", "tcp://127.0.0.1:8786"], "--workers"),
        ("posterior", ["--scheduler", "tcp://host-without-port"], "--scheduler"),
        ("calibrate", ["--no-surrogate", "--workers", "2"], "--workers"),
        ("calibrate", ["--no-surrogate", "--scheduler", "tcp://127.0.0.1:8786"], "--scheduler"),
    ],
)
def test_cluster_options_that_cannot_work_are_refused_before_the_plants_grow(tmp_path, command, options, named):
    """--workers with --scheduler was refused only when the first design point was sent (after the
    plants grew; never when the design was cached), and calibrate --no-surrogate --workers 2 ran in
    this process without a word (a review). They are refused first: here before the observations file,
    which does not exist, is read."""
    from lightfit.cli import app

    args = [command, str(tmp_path / "missing.csv"), "--quick", "--out", str(tmp_path / "out"), *options]
    r = CliRunner().invoke(app, args)
    assert r.exit_code == 2, r.output
    text = r.output.replace("\n", "")
    assert f"option {named}" in text and "missing.csv" not in text


def test_design_renderer_refuses_workers_with_a_scheduler_even_for_a_cached_design():
    """The library hook accepted workers=2 with a scheduler and ignored it while the design was cached."""
    with pytest.raises(InputError, match="workers"), design_renderer("tcp://127.0.0.1:8786", 2):
        pass


@pytest.mark.parametrize("command", ["calibrate", "posterior"])
def test_the_connect_timeout_the_cluster_error_advises_is_an_option_and_is_used(command, tmp_path, monkeypatch):
    """When the embedded cluster did not answer, calibrate and posterior advised "a longer
    --connect-timeout", an option only field-run had (a review): both take it now, and it is the
    client's timeout. The cluster is stood in for, with a client that cannot reach it (distributed's
    "Timed out trying to connect", an OSError)."""
    import distributed

    from lightfit.cli import app

    made = []

    class Cluster:
        def __init__(self, **kw):
            pass

        def close(self):
            pass

    def unreachable(*a, **k):
        made.append(k)
        raise OSError("Timed out trying to connect to tcp://127.0.0.1:1 after 7 s")

    monkeypatch.setattr(distributed, "LocalCluster", Cluster)
    monkeypatch.setattr(distributed, "Client", unreachable)
    monkeypatch.setenv(ENV_CACHE, str(tmp_path / "cache"))  # no design cached: a point to render
    obs = tmp_path / "obs.csv"
    obs.write_text(OBS, encoding="utf-8")
    args = [command, str(obs), "--quick", "--steps", "12:15", "--n-design", "6", "--parameters", "specular"]
    args += ["--workers", "1", "--connect-timeout", "7", "--out", str(tmp_path / "out")]
    r = CliRunner().invoke(app, args)
    err = " ".join(r.stderr.split())
    assert r.exit_code == 2 and "option --connect-timeout" in err and "did not answer within 7 s" in err, r.output
    assert made == [{"timeout": 7.0}]
