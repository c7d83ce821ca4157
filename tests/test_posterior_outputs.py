"""Posterior runs: resuming with --max-steps, and what summary.json and the diagnostics report (reviews)."""

from __future__ import annotations

import numpy as np
import pytest
from typer.testing import CliRunner

from lightfit.errors import InputError
from lightfit.inference import mcmc as P

MU, SD = np.array([0.5, 1.0]), np.array([0.1, 0.2])


def gauss(xs):
    """Independent Gaussian log-density, vectorised over rows."""
    return -0.5 * (((np.atleast_2d(xs) - MU) / SD) ** 2).sum(1)


def _init(nw=8, seed=3):
    return MU + SD * np.random.default_rng(seed).normal(size=(nw, 2))


def test_a_resume_with_max_steps_below_the_stored_chain_is_refused(tmp_path, monkeypatch):
    """max_steps counts the stored steps: resuming a 12-step chain with max_steps 5 sampled nothing,
    stored max_steps 5 and reported "12/5 steps". Refused now, naming --max-steps and the stored
    length, before anything is written; the stored length itself re-analyses the chain as before."""
    names, path = ("specular", "light_factor"), tmp_path / "run.h5"
    kw = dict(nwalkers=8, seed=0, progress=False)
    form = {"mc_correlation": "model", "mc_scale": 1.0}  # the command line's defaults: resumable by it
    P.sample(gauss, names, path, max_steps=12, initial=_init(), attrs={"likelihood": form}, **kw)
    with pytest.raises(InputError, match="below the 12 steps the stored chain already has") as e:
        P.sample(gauss, names, path, max_steps=5, **kw)
    assert e.value.column == "max-steps" and "--max-steps ≥ 12" in str(e.value)
    run = P.load_run(path)
    assert len(run["chain"]) == 12 and run["attrs"]["max_steps"] == 12
    same = P.sample(gauss, names, path, max_steps=12, **kw)
    assert same.steps_this_call == 0 and len(same.chain) == 12
    # the command line refuses it before the plants grow (after what says the run is another one)
    from lightfit.cache import ENV_CACHE
    from lightfit.cli import app

    monkeypatch.setenv(ENV_CACHE, str(tmp_path / "cache"))
    args = ["posterior", "--quick", "--out", str(tmp_path), "--parameters", "specular,light_factor"]
    r = CliRunner().invoke(app, [*args, "--walkers", "8", "--max-steps", "5"])
    said = " ".join(r.stderr.split())
    assert r.exit_code == 2 and "--max-steps ≥ 12" in said and "resuming" not in r.output, r.output + said
    assert P.load_run(path)["attrs"]["max_steps"] == 12


def test_the_acceptance_is_over_the_kept_steps(tmp_path):
    """The diagnostics' acceptance (summary.json's acceptance_mean, posterior-status, the caution
    outside 0.1–0.8) counted the burn-in's steps, where τ, ESS and the samples do not. It is over the
    kept steps now, and says so (``acceptance_steps``). By hand: a walker's move was accepted at a step
    where its position changed (a continuous target: a proposal is never its start)."""
    names, path = ("a", "b"), tmp_path / "run.h5"
    far = MU + 100 * SD * np.random.default_rng(5).normal(size=(8, 2))  # spread wide: a burn-in that shows
    res = P.sample(gauss, names, path, nwalkers=8, max_steps=80, seed=2, initial=far, progress=False)
    chain = np.concatenate([far[None], res.chain])
    moved = (chain[1:] != chain[:-1]).any(-1)  # (steps, walkers)
    burn = int(0.25 * 80)  # the default stop rule's burn-in, 25 % (docs/posterior.md)
    kept, every = moved[burn:].mean(), moved.mean()
    assert abs(kept - every) > 0.02  # the burn-in's acceptance differs here
    for d in (res.diagnostics, P.load_run(path)["diagnostics"]):
        assert d["acceptance_steps"] == "kept" and d["acceptance_mean"] == pytest.approx(kept, abs=1e-12)
        np.testing.assert_allclose(d["acceptance"], moved[burn:].mean(0))


def test_status_of_a_run_without_a_recorded_max_steps(tmp_path):
    """posterior-status of a run stored before its max_steps was recorded (the notebook's fixture,
    150 steps) read "150/None steps"; it says the steps and that the limit was not recorded."""
    from pathlib import Path

    from lightfit.cli.common import console
    from lightfit.cli.posterior import _print_status
    from lightfit.inference.mcmc.backend import run_status

    st = run_status(Path(__file__).parent / "fixtures" / "posterior_tiny.h5")
    assert st["max_steps"] is None and st["steps"] == 150
    with console.capture() as cap:
        _print_status(st)
    text = " ".join(cap.get().split())
    assert "None" not in text and "150 steps (its --max-steps not recorded), stopped" in text, text
    path = tmp_path / "run.h5"
    P.sample(gauss, ("a", "b"), path, nwalkers=8, max_steps=6, initial=_init(), progress=False)
    with console.capture() as cap:
        _print_status(run_status(path))
    assert "6/6 steps, stopped" in " ".join(cap.get().split())


def test_a_run_stored_with_a_mirrored_profile_direction_is_read_as_its_combination_reads(tmp_path):
    """Runs written before the Fisher eigenvectors were oriented (largest entry positive) kept eigh's
    arbitrary sign: a profile stored along -d, with its offsets t along -d, was plotted against the
    combination string of +d (always written oriented), so the notebook's profile was mirrored. A
    hand-made mirror of the notebook's fixture (direction and an eigenvector negated, t negated and
    its points in ascending order of the mirrored t, as such a run stored them) reads back as the
    fixture: each entry of the direction as its combination string gives it, and every profile
    point at the same parameters."""
    import re
    import shutil
    from pathlib import Path

    import h5py

    fixture = Path(__file__).parent / "fixtures" / "posterior_tiny.h5"
    mirrored = shutil.copy(fixture, tmp_path / "run.h5")
    with h5py.File(mirrored, "a") as f:
        pr, fi = f["analysis/profile"], f["analysis/fisher"]
        pr["direction"][...] = -pr["direction"][()]
        pr["t"][...] = -pr["t"][()][::-1]
        for k in ("profile_nll", "slice_nll", "in_prior_box"):
            pr[k][...] = pr[k][()][::-1]
        vec = fi["eigenvectors"][()]
        vec[:, -1] *= -1
        fi["eigenvectors"][...] = vec
    want, got = (P.load_run(p)["analysis"] for p in (fixture, mirrored))
    pr = got["profile"]
    # the combination string's coefficients (|entry| ≥ 0.1), read independently of the stored vector
    said = {n: float(c) for c, n in re.findall(r"([+−-]\d\.\d\d) log (\w+)", pr["combination"].replace("−", "-"))}
    names = list(got["fisher"]["names"])
    assert said and all(abs(pr["direction"][names.index(n)] - c) <= 0.005 for n, c in said.items()), said
    assert np.all(np.diff(pr["t"]) > 0)
    for k in ("direction", "t", "profile_nll", "slice_nll", "in_prior_box"):
        np.testing.assert_array_equal(pr[k], want["profile"][k], err_msg=k)
    np.testing.assert_array_equal(got["fisher"]["eigenvectors"], want["fisher"]["eigenvectors"])
    # the fixture, written oriented, reads as stored
    with h5py.File(fixture, "r") as f:
        np.testing.assert_array_equal(want["profile"]["t"], f["analysis/profile/t"][()])
        np.testing.assert_array_equal(want["profile"]["direction"], f["analysis/profile/direction"][()])
