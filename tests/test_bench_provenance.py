"""benchmarks/provenance.py's ``--out`` option: a JSON that cannot be written is refused when the
options are read, not after the benchmark's minutes of work."""

from __future__ import annotations

import argparse
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def provenance(script_module):
    return script_module("provenance")


def _parser(provenance, tmp_path):
    ap = argparse.ArgumentParser(prog="bench_x.py")
    provenance.out_option(ap, tmp_path / "default.json")
    return ap


def test_unwritable_out_is_refused_by_argparse(provenance, tmp_path, capsys):
    (tmp_path / "a_file").write_text("")
    for bad in (tmp_path, tmp_path / "a_file" / "x.json"):
        with pytest.raises(SystemExit) as err:
            _parser(provenance, tmp_path).parse_args(["--out", str(bad)])
        assert err.value.code == 2
        assert "argument --out" in capsys.readouterr().err


def test_writable_out_and_default_pass(provenance, tmp_path):
    ap = _parser(provenance, tmp_path)
    assert ap.parse_args([]).out == tmp_path / "default.json"
    new = tmp_path / "new" / "x.json"
    assert ap.parse_args(["--out", str(new)]).out == new
    assert new.parent.is_dir()


def test_a_setting_lightfit_refuses_ends_a_script_with_its_message_not_a_traceback(tmp_path):
    """`--n-plants -5` ended nearly every script on a traceback through it with lightfit's clear
    message at the bottom (a review); provenance, which every script imports, prints the message."""
    import subprocess
    import sys

    cmd = [sys.executable, str(ROOT / "benchmarks" / "bench_variance.py"), "--n-plants", "-5"]
    p = subprocess.run([*cmd, "--out", str(tmp_path / "v.json")], capture_output=True, text=True, timeout=300)
    assert p.returncode == 1 and "Traceback" not in p.stderr, p.stderr
    assert p.stderr.strip() == "error: parameter 'n_plants': n_plants=-5 (expected an integer ≥ 1)", p.stderr
    assert not (tmp_path / "v.json").exists()
