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
