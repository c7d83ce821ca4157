"""Long runs killed at any moment and rerun with the same command end exactly as uninterrupted runs (issue 17).

``lightfit posterior`` and ``lightfit calibrate`` run as subprocesses on the CI-sized field (3 daytime
steps). Kill points: SIGKILL at chosen moments — sent by the process to itself at a chosen render, step or
accepted calibration step (``lightfit.killpoint``, ``LIGHTFIT_TEST_KILL_AFTER``; deterministic) and
once from outside during sampling. The
reference is the same command run without interruption; the comparison is bit for bit.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import h5py
import numpy as np
import pytest

from lightfit.inference import mcmc as P

MODEL = ["--quick", "--steps", "12:15"]
POSTERIOR = [
    "posterior",
    *MODEL,
    "--parameters",
    "light_factor",
    "--walkers",
    "8",
    "--max-steps",
    "1000",
    "--n-design",
    "6",
    "--n-test",
    "0",
    "--no-analysis",
    "--target-ess",  # the rule stops at step 250 (τ ≈ 2–3 steps): checks at 50 … 200 to kill around
    "300",
]
# PAR at the plants on the three steps: the posterior renders them (the bundled chamber record alone
# is the above-canopy sensor, which needs no render at all)
OBS_HEADER = "# provenance: synthetic\n# note: resume test\ntime,plant_par_umol_m2_s,plant_par_sd_umol_m2_s\n"
OBS_ROWS = "2016-04-20T09:00:00Z,300,20\n2016-04-20T09:30:00Z,350,20\n2016-04-20T10:00:00Z,400,20\n"


#: Return code of a subprocess ended by SIGKILL.
KILLED = -signal.SIGKILL


def lightfit(args, out: Path | None, kill_after: str | None = None, wait: bool = True):
    env = {**os.environ, "JAX_PLATFORMS": "cpu", "COLUMNS": "200"}  # rich: no wrapped lines
    env.pop("LIGHTFIT_TEST_KILL_AFTER", None)
    if out is not None:  # each run its own design cache, so that a rerun finds only its own renders
        env["LIGHTFIT_CACHE"] = str(out / "cache")
    if args and args[0] == "posterior":
        obs = Path(os.environ.get("TMPDIR", "/tmp")) / f"lightfit-resume-obs-{os.getpid()}.csv"
        obs.write_text(OBS_HEADER + OBS_ROWS, encoding="utf-8")
        args = [args[0], str(obs), *args[1:]]
    if kill_after:
        env["LIGHTFIT_TEST_KILL_AFTER"] = kill_after
    cmd = [sys.executable, "-m", "lightfit.cli", *args, *([] if out is None else ["--out", str(out)])]
    p = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    if not wait:
        return p
    output, _ = p.communicate(timeout=600)
    return p.returncode, output


def renders(out: Path) -> list[Path]:
    """Design renders kept in the run's design cache."""
    return list((out / "cache" / "designs").glob("*/renders/*.npz"))


def iteration(path: Path) -> int:
    """Steps stored, read with h5py's *default* file locking while the writer may be running."""
    try:
        with h5py.File(path, "r") as f:
            return int(f["mcmc"].attrs["iteration"])
    except (OSError, KeyError):
        return -1  # not created yet, or opened in the middle of a step's write


def h5_contents(path: Path) -> dict:
    """Every dataset of the run group (raw, unsliced) and the attributes that are not wall times."""
    out = {}
    with h5py.File(path, "r") as f:
        g = f["mcmc"]
        for k, v in g.items():
            out[k] = v[()]
        for k in ("iteration", "stopped_by", "stopped_at", "diagnostics", "stop_rule", "max_steps"):
            out["attr:" + k] = g.attrs[k]
    return out


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """The uninterrupted run, read (default locking) every 0.1 s while it samples."""
    out = tmp_path_factory.mktemp("ref")
    p = lightfit(POSTERIOR, out, wait=False)
    seen = set()
    while p.poll() is None:
        seen.add(iteration(out / "run.h5"))
        time.sleep(0.1)
    output = p.stdout.read()
    assert p.returncode == 0, output
    return out, seen, output


def test_reading_the_run_file_while_sampling_does_not_disturb_the_sampler(reference):
    out, seen, output = reference
    run = P.load_run(out / "run.h5")
    assert run["attrs"]["stopped_by"] == "rule"
    # the reader saw the run in progress (several intermediate step counts), and the sampler finished
    assert len({n for n in seen if 0 < n < len(run["chain"])}) >= 3, sorted(seen)
    assert "stopped: rule" in output


def test_posterior_killed_three_times_ends_as_the_uninterrupted_run(reference, tmp_path):
    ref, _, _ = reference
    out = tmp_path / "killed"
    # 1. during the emulator design, after 3 of its 6 renders
    rc, output = lightfit(POSTERIOR, out, kill_after="render:3")
    assert rc == KILLED and not (out / "emulator.npz").exists() and len(renders(out)) == 3
    # 2. a real SIGKILL from outside while sampling (after at least one stop-rule check at step 50)
    p = lightfit(POSTERIOR, out, wait=False)
    deadline = time.time() + 300
    while iteration(out / "run.h5") < 60 and p.poll() is None and time.time() < deadline:
        time.sleep(0.05)
    p.send_signal(signal.SIGKILL)
    p.wait()
    killed_at = iteration(out / "run.h5")
    assert 60 <= killed_at, killed_at
    # rendering resumed: the design has all 6 renders now (3 kept from the first attempt)
    assert len(renders(out)) == 6
    # 3. right after the last check step before the reference's stop is stored, before its stop-rule check
    # (the check a resumed run must not skip)
    n_kill = 50 * ((int(P.load_run(ref / "run.h5")["attrs"]["stopped_at"]) - 1) // 50)
    assert n_kill > killed_at, (n_kill, killed_at)
    rc, output = lightfit(POSTERIOR, out, kill_after=f"sample:{n_kill}")
    assert rc == KILLED, output
    assert iteration(out / "run.h5") == n_kill
    rc, output = lightfit(POSTERIOR, out)
    assert rc == 0, output
    assert f"resuming {out / 'run.h5'}: {n_kill} steps kept" in " ".join(output.split()), output
    a, b = h5_contents(ref / "run.h5"), h5_contents(out / "run.h5")
    assert a.keys() == b.keys()
    for k in a:
        np.testing.assert_array_equal(b[k], a[k], err_msg=k)
    assert a["attr:stopped_by"] == "rule" and a["attr:stopped_at"] > n_kill
    with np.load(ref / "emulator.npz") as x, np.load(out / "emulator.npz") as y:
        np.testing.assert_array_equal(x["coef_values"], y["coef_values"])
    # A finished run rerun is not extended: the rule is met at its last step.
    rc, output = lightfit(POSTERIOR, out)
    assert rc == 0 and "stopped: rule" in output
    assert h5_contents(out / "run.h5")["attr:iteration"] == a["attr:iteration"]
    # status of the finished run
    rc, output = lightfit(["posterior-status", str(out)], None)
    assert rc == 0 and "stopped: rule" in output and "light_factor" in output


def test_n_design_change_rebuilds_the_emulator(reference, tmp_path):
    ref, _, _ = reference
    out = tmp_path / "n7"
    shutil.copytree(ref / "cache", out / "cache")
    shutil.copy(ref / "emulator.npz", out / "emulator.npz")
    args = [*POSTERIOR, "--n-design", "7", "--max-steps", "5"]
    rc, output = lightfit(args, out)
    assert rc == 0, output
    assert "was built for other settings (n_design: 6 → 7" in output.replace("\n", "")
    assert len(P.load_run(out / "run.h5")["chain"]) == 5
    assert len(renders(out)) == 7  # the 6 renders of the old design reused
    with np.load(out / "emulator.npz") as z:
        assert len(z["design"]) == 7
    # resuming that chain on an emulator of another design is refused with one line
    rc, output = lightfit([*POSTERIOR, "--n-design", "8", "--max-steps", "10"], out)
    assert rc == 2 and "another emulator (n_design: 7 → 8" in output.replace("\n", "") and "Traceback" not in output


def test_n_test_negative_is_refused(tmp_path):
    rc, output = lightfit([*POSTERIOR, "--n-test", "-1"], tmp_path)
    assert rc == 2 and "n_test=-1" in output and "Traceback" not in output


CALIBRATE = ["calibrate", None, *MODEL, "--parameters", "specular", "--max-steps", "4", "--no-surrogate"]


def _observations(path: Path) -> Path:
    path.write_text(OBS_HEADER + OBS_ROWS, encoding="utf-8")
    return path


def _history(out: Path) -> list[dict]:
    rows = [json.loads(x) for x in (out / "history.jsonl").read_text().splitlines()]
    return [{k: v for k, v in r.items() if k != "seconds"} for r in rows]


def test_calibrate_killed_and_rerun_reaches_the_same_optimum_and_history(tmp_path):
    # BFGS (the command line's default before 413eed7): L-BFGS-B takes specular to its bound in one
    # step on these three made-up PAR values, so a kill after step 2 would never come.
    args = [*CALIBRATE, "--method", "bfgs"]
    args[1] = str(_observations(tmp_path / "obs.csv"))
    rc, output = lightfit(args, tmp_path / "ref")
    assert rc == 0, output
    rc, output = lightfit(args, tmp_path / "killed", kill_after="calibrate:2")
    assert rc == KILLED, output
    rc, output = lightfit(args, tmp_path / "killed")
    assert rc == 0, output
    assert "accepted steps kept, continued exactly from the saved state" in " ".join(output.split()), output
    assert _history(tmp_path / "killed") == _history(tmp_path / "ref")
    a, b = (json.loads((tmp_path / d / "calibration.json").read_text()) for d in ("ref", "killed"))
    for k in ("theta", "loss", "steps", "evaluations", "gradients", "stopped_by", "reason"):
        assert a[k] == b[k], k
    assert "accepted steps" in output and "stopped:" in output
    # Another method (or start) into the finished --out: refused, the run's state kept (it continued
    # from the best point, wrote the other method's counts and deleted the state).
    state = (tmp_path / "killed" / "history.jsonl.state.npz").read_bytes()
    rc, output = lightfit([*args[:-1], "lbfgsb"], tmp_path / "killed")
    assert rc == 2 and "run with other method" in " ".join(output.split()) and "--no-resume" in output, output
    assert (tmp_path / "killed" / "history.jsonl.state.npz").read_bytes() == state
    # --no-resume with other parameters, killed after its first step: the finished run's result went
    # with it (it stayed, a result of roughness beside this run's history), so the rerun the message
    # asks for (without --no-resume) resumes this run's steps instead of being refused by it.
    other = [*args[:6], "specular,roughness", *args[7:]]
    rc, output = lightfit([*other, "--no-resume"], tmp_path / "killed", kill_after="calibrate:1")
    assert rc == KILLED and not (tmp_path / "killed" / "calibration.json").exists(), output
    rc, output = lightfit(other, tmp_path / "killed")
    assert rc == 0 and "resuming" in output and "steps kept" in " ".join(output.split()), output


def test_surrogate_calibrate_killed_during_its_design_ends_as_the_uninterrupted_run(tmp_path):
    """The surrogate calibration (default) keeps every render in the design cache: killed after its third
    design render and rerun, it renders only the rest and ends with the uninterrupted run's rounds and optimum."""
    args = [*CALIBRATE[:-1], "--n-design", "6"]
    args[1] = str(_observations(tmp_path / "obs.csv"))
    rc, output = lightfit(args, tmp_path / "ref")
    assert rc == 0, output
    assert "full-render check" in output and "passed" in output
    # A rerun with other observations or priors into the finished --out is refused, naming what changed:
    # it re-optimised from the cached renders and replaced the result unsaid (a review).
    edited = tmp_path / "edited.csv"
    edited.write_text((tmp_path / "obs.csv").read_text().replace(OBS_ROWS, OBS_ROWS.replace(",300,", ",310,")))
    assert edited.read_text() != (tmp_path / "obs.csv").read_text()
    before = (tmp_path / "ref" / "calibration.json").read_text()
    for other, said in (
        ([*args[:1], str(edited), *args[2:]], "observations (another table"),
        ([*args, "--priors", "wide"], "priors ('informed' → 'wide')"),
    ):
        rc, output = lightfit(other, tmp_path / "ref")
        assert rc == 2 and "the calibration there was run with other" in output and said in output, output
    assert (tmp_path / "ref" / "calibration.json").read_text() == before
    rc, output = lightfit(args, tmp_path / "killed", kill_after="render:3")
    assert rc == KILLED and len(renders(tmp_path / "killed")) == 3, output
    rc, output = lightfit(args, tmp_path / "killed")
    assert rc == 0, output
    a, b = (json.loads((tmp_path / d / "calibration.json").read_text()) for d in ("ref", "killed"))
    assert a["theta"] == b["theta"] and a["loss"] == b["loss"]
    strip = [{k: v for k, v in r.items() if k != "seconds"} for r in a["surrogate"]["rounds"]]
    assert strip == [{k: v for k, v in r.items() if k != "seconds"} for r in b["surrogate"]["rounds"]]
    assert a["surrogate"]["passed"] and a["surrogate"]["renders_new"] == 6 + len(strip)
    # Ctrl-C (SIGINT) after the third design render: exit 130 and a line that says what was kept and
    # how to go on (it used to end in click's bare "Aborted!"); the same command then ends as above.
    rc, output = lightfit(args, tmp_path / "ctrl-c", kill_after="render:3:INT")
    flat = " ".join(output.split())
    assert rc == 130 and len(renders(tmp_path / "ctrl-c")) == 3, output
    assert "interrupted: every finished design render is kept" in flat and "rerun the same command to resume" in flat
    assert "Traceback" not in output
    rc, output = lightfit(args, tmp_path / "ctrl-c")
    assert rc == 0, output
    c = json.loads((tmp_path / "ctrl-c" / "calibration.json").read_text())
    assert c["theta"] == a["theta"] and c["loss"] == a["loss"]
    assert b["surrogate"]["renders_cached"] == 3 and b["surrogate"]["renders_new"] == 3 + len(strip)


def test_replicate_interrupted_twice_ends_as_the_uninterrupted_run(tmp_path):
    """replicate keeps each rendered step in --out's .kept-steps folder: stopped by Ctrl-C after its
    first daytime step (exit 130, the line saying what is kept; again with --no-resume, which first
    discards what the folder held), then killed after its second, and rerun,
    it renders only the last step and ends with the uninterrupted run's results bit for bit (every
    variable and attribute of results.nc, the summary's rows); the folder is gone once the results are
    written."""
    import xarray as xr

    args = ["replicate", *MODEL]
    rc, output = lightfit(args, tmp_path / "ref")
    assert rc == 0, output
    out = tmp_path / "run"
    rc, output = lightfit(args, out, kill_after="step:1:INT")
    assert rc == 130, output
    said = " ".join(output.split())
    assert "interrupted: every rendered step is kept in --out (its .kept-steps folder); rerun the same command" in said
    assert len(list((out / ".kept-steps").glob("*.npz"))) == 1 and not (out / "results.nc").exists()
    stale = out / ".kept-steps" / "stale.npz"  # another run's step: --no-resume discards what is kept
    stale.write_bytes(b"")
    rc, output = lightfit([*args, "--no-resume"], out, kill_after="step:1:INT")
    assert rc == 130 and " ".join(output.split()).endswith("rerun without --no-resume to resume"), output
    assert not stale.exists() and len(list((out / ".kept-steps").glob("*.npz"))) == 1
    rc, output = lightfit(args, out, kill_after="step:2")
    assert rc == KILLED, output  # (a killed run's progress line is never printed)
    rc, output = lightfit(args, out)
    assert rc == 0, output
    assert "rendering steps (2 of 3 kept by an interrupted run)" in " ".join(output.split()), output
    assert not (out / ".kept-steps").exists()
    with xr.open_dataset(tmp_path / "ref" / "results.nc") as a, xr.open_dataset(out / "results.nc") as b:
        assert set(a.variables) == set(b.variables) and set(a.attrs) == set(b.attrs)
        for k in a.variables:
            np.testing.assert_array_equal(a[k].values, b[k].values, err_msg=k)
        for k in a.attrs:
            np.testing.assert_array_equal(np.asarray(a.attrs[k]), np.asarray(b.attrs[k]), err_msg=k)
    rows = [
        [x for x in (d / "summary.csv").read_text().splitlines() if not x.startswith("#")]
        for d in (tmp_path / "ref", out)
    ]
    assert rows[0] == rows[1]


def test_step_files_are_named_by_the_backend_that_renders_them(tmp_path, monkeypatch):
    """A step kept by a run on another Mitsuba variant or CPU target (another machine, another
    LIGHTFIT_LLVM_TARGET) is not read: its kernels round otherwise, so a resumed run mixed two
    backends' steps, the results those of neither run (every light variable differed; a review)."""
    import dataclasses

    from lightfit import replication as rep
    from lightfit.light import backend

    w = rep.forcing().loc["2016-04-20 10:00+00:00":"2016-04-20 10:00+00:00"]
    model = rep.model_for(rep.ReplicationConfig.quick(), w, keep_steps=tmp_path)
    leaf, steps = model.theta().leaf, np.flatnonzero(model.day)[:1]
    here = model.step_files(leaf, steps)
    assert model.step_files(leaf, steps) == here  # the same run: the same file
    for other in ({"llvm_target": "x86-64-v3, 8 lanes (LIGHTFIT_LLVM_TARGET=avx2)"}, {"variant": "cuda_ad_mono"}):
        monkeypatch.setitem(backend._STATE, "info", dataclasses.replace(backend.info(), **other))
        assert model.step_files(leaf, steps) != here, other
        monkeypatch.undo()
