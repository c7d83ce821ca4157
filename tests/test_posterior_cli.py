"""``lightfit posterior`` on the CI-sized field, through the real app."""

from __future__ import annotations

import json

import numpy as np
from typer.testing import CliRunner

from lightfit.cli import app
from lightfit.inference.mcmc import load_run


def test_posterior_cli_quick(tmp_path):
    out = tmp_path / "post"
    args = [
        "posterior",
        "--quick",
        "--out",
        str(out),
        "--parameters",
        "specular,light_factor",
        "--walkers",
        "8",
        "--max-steps",
        "30",
        "--n-design",
        "6",
        "--n-test",
        "1",
    ]
    r = CliRunner().invoke(app, args)
    assert r.exit_code == 0, r.output
    s = json.loads((out / "summary.json").read_text())
    assert s["names"] == ["specular", "light_factor"] and s["n_steps"] == 30
    assert "emulator_error" in s and "sloppy" in s
    run = load_run(out / "run.h5")
    assert run["chain"].shape == (30, 8, 2) and "analysis" in run
    # resuming to more steps appends
    r = CliRunner().invoke(app, args[:-6] + ["--max-steps", "40", "--n-design", "6", "--n-test", "1"])
    assert r.exit_code == 0, r.output
    assert load_run(out / "run.h5")["chain"].shape == (40, 8, 2)
    with np.load(out / "emulator.npz") as z:  # the emulator's key names the field it was rendered on
        assert "boundary='periodic'" in json.loads(str(z["key"]))["field"]
    # The stored chain is the periodic field's: resuming it on another field is refused, before any plant grows.
    r = CliRunner().invoke(app, [*args, "--boundary", "finite"])
    assert r.exit_code == 2 and "posterior run" in r.stderr and "boundary: 'periodic' → 'finite'" in r.stderr


def test_posterior_cli_bad_parameter(tmp_path):
    r = CliRunner().invoke(app, ["posterior", "--quick", "--out", str(tmp_path), "--parameters", "specularity"])
    assert r.exit_code == 2 and "specularity" in r.stderr


def test_posterior_cli_n_test_zero(tmp_path):
    """--n-test 0: no held-out renders, no emulator-error report (it used to end in a ValueError traceback)."""
    args = ["posterior", "--quick", "--steps", "12:15", "--out", str(tmp_path), "--parameters", "light_factor"]
    r = CliRunner().invoke(app, [*args, "--walkers", "4", "--max-steps", "20", "--n-design", "6", "--n-test", "0"])
    assert r.exit_code == 0, r.output
    s = json.loads((tmp_path / "summary.json").read_text())
    assert s["n_steps"] == 20 and "emulator_error" not in s
