"""The suite's handling of a worker killed by a fatal signal (tests/conftest.py): the crashed test
runs once more in another worker process, and the crash's Python stacks are printed in the summary, where a
CI log's tail keeps them."""

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

CRASHING = """
import ctypes
from pathlib import Path

def test_crashes_once(tmp_path_factory):
    marker = Path(__file__).with_name("crashed_once")
    if not marker.exists():
        marker.write_text("")
        ctypes.string_at(0)  # SIGSEGV

def test_crashes_always():
    if Path(__file__).with_name("crash_always").exists():
        ctypes.string_at(0)
"""


def _suite(folder: Path) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k not in ("PYTEST_XDIST_WORKER", "LIGHTFIT_TEST_CRASH_DIR")}
    return subprocess.run(
        [sys.executable, "-m", "pytest", "-n", "2", "-p", "no:cacheprovider", "-q", str(folder)],
        cwd=folder,
        env=env | {"COLUMNS": "200"},
        capture_output=True,
        text=True,
        timeout=300,
    )


@pytest.mark.slow
def test_a_crashed_test_runs_again_and_its_stack_is_printed(tmp_path):
    shutil.copy(Path(__file__).with_name("conftest.py"), tmp_path / "conftest.py")
    (tmp_path / "test_crash.py").write_text(CRASHING)
    run = _suite(tmp_path)
    assert run.returncode == 0, run.stdout + run.stderr
    summary = run.stdout.split("worker crashes")[1]
    assert "run again in another worker: test_crash.py::test_crashes_once" in summary
    assert "Fatal Python error: Segmentation fault" in summary and "in test_crashes_once" in summary
    assert "Extension modules" not in summary and "_pytest/" not in summary
    assert "2 passed, 1 rerun" in run.stdout

    (tmp_path / "crash_always").write_text("")  # a second crash of the same test fails the run
    run = _suite(tmp_path)
    assert run.returncode == 1, run.stdout + run.stderr
    assert "FAILED test_crash.py::test_crashes_always" in run.stdout
    assert "run again in another worker: test_crash.py::test_crashes_always" in run.stdout
