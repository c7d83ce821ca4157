"""The LESS 3 peer scripts (benchmarks/bench_less.py, less_runner.py, experiments/less_*.py) without
LESS: they stop at once and say how to get it and on what terms (its licence allows non-commercial
research only), and refuse settings that would end their run in NaN or a traceback.

LESS itself is never installed for the tests (docs/light.md, "Peer: LESS 3")."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: What every "LESS not installed" message must tell: how to get it, and its licence.
MUST_SAY = ("pip install less3d==3.0.7", "Academic and Non-Commercial Research License", "non-commercial")


@pytest.fixture(scope="module")
def bench_less(script_module):
    return script_module("bench_less")


def _said(capsys) -> str:
    return " ".join(capsys.readouterr().out.split())  # rich wraps long lines


def _never(*args, **kwargs):
    raise AssertionError("the benchmark ran without LESS")


@pytest.mark.parametrize("python", ["missing", "without_less"])
def test_bench_less_without_less_says_how_to_get_it_and_its_licence(bench_less, monkeypatch, capsys, tmp_path, python):
    """An interpreter without less3d (a .venv-less whose install failed, LIGHTFIT_LESS_PYTHON set
    to another Python) was taken for LESS: the benchmark grew the field and rendered for minutes,
    then stopped on less_runner's failure; and the message for a missing one named no licence."""
    exe = tmp_path / "no-such-python" if python == "missing" else Path(sys.executable)
    monkeypatch.setattr(bench_less, "LESS_PYTHON", exe)
    monkeypatch.setattr(bench_less, "run_boundary", _never)
    out = tmp_path / "less.json"
    assert bench_less.main(4, ["finite"], [16, 64], [64, 256], 2, 0.02, out=out) is None
    said = _said(capsys)
    assert "LESS 3 is not installed" in said and str(exe) in said
    assert ("missing" in said) == (python == "missing") and ("has no LESS 3" in said) == (python != "missing")
    for text in MUST_SAY:
        assert text in said, (text, said)
    assert not out.exists()


@pytest.mark.parametrize("script", ["less_soil_edge", "less_scaled_scene"])
def test_less_experiments_without_less_say_how_to_get_it_and_its_licence(
    bench_less, script_module, monkeypatch, capsys, tmp_path, script
):
    """The experiments pointed to the README only, and took any existing interpreter for LESS."""
    module = script_module(ROOT / "experiments" / f"{script}.py")
    monkeypatch.setattr(module.bl, "LESS_PYTHON", Path(sys.executable))
    monkeypatch.setattr(module, "build", _never)
    out = tmp_path / "x.json"
    args = ([5.0, 50.0], 2) if script == "less_soil_edge" else ([1.0, 10.0], 200.0, 2)
    assert module.main(*args, out=out) is None
    said = _said(capsys)
    assert "Nothing run" in said
    for text in MUST_SAY:
        assert text in said, (text, said)
    assert not out.exists()


def test_less_runner_without_less_says_how_to_get_it_and_its_licence(tmp_path):
    p = subprocess.run(
        [sys.executable, str(ROOT / "benchmarks" / "less_runner.py"), str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert p.returncode == 1 and "Traceback" not in p.stderr, p.stderr
    for text in MUST_SAY:
        assert text in p.stderr, (text, p.stderr)


@pytest.mark.parametrize(
    ("script", "args", "option"),
    [
        # one replicate: every SE, noise and |z| was NaN in the JSON (a spread over one value)
        ("benchmarks/bench_less.py", ["--replicates", "1"], "--replicates"),
        # two equal counts: a ZeroDivisionError or ValueError traceback after the whole run
        ("benchmarks/bench_less.py", ["--less-samples", "64", "64"], "--less-samples"),
        ("benchmarks/bench_less.py", ["--lightfit-samples", "0", "256"], "--lightfit-samples"),
        ("benchmarks/bench_less.py", ["--target", "0"], "--target"),
        ("experiments/less_soil_edge.py", ["--replicates", "1"], "--replicates"),
        # one width: the c₀ + c₁/W fit's covariance is singular (a LinAlgError after the LESS runs)
        ("experiments/less_soil_edge.py", ["--half-widths", "50"], "--half-widths"),
        ("experiments/less_scaled_scene.py", ["--replicates", "1"], "--replicates"),
    ],
)
def test_settings_that_end_in_nan_or_a_traceback_are_refused_when_read(tmp_path, script, args, option):
    p = subprocess.run(
        [sys.executable, str(ROOT / script), *args, "--out", str(tmp_path / "x.json")],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert p.returncode == 2 and "Traceback" not in p.stderr, (p.stdout, p.stderr)
    assert f"error: {option} " in p.stderr, p.stderr
    assert not (tmp_path / "x.json").exists()


@pytest.mark.parametrize("script", ["less_soil_edge", "less_scaled_scene"])
def test_less_experiments_refuse_an_unwritable_out_when_read(tmp_path, script):
    """Their --out was a plain path: one that cannot be written ended the run on a traceback after
    all its LESS and lightfit runs (provenance.out_option, which the benchmarks use, checks it first)."""
    (tmp_path / "a_file").write_text("")
    p = subprocess.run(
        [sys.executable, str(ROOT / "experiments" / f"{script}.py"), "--out", str(tmp_path / "a_file" / "x.json")],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert p.returncode == 2 and "argument --out" in p.stderr and "Traceback" not in p.stderr, p.stderr
