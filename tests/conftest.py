"""Shared test configuration.

float64 is enabled for the whole suite so that float64 paths (finite-difference checks,
peer comparisons) are available; float32 paths are exercised by passing float32 arrays
explicitly. lightfit itself never changes JAX's global configuration on import.
"""

import importlib.util
import os
import sys
from pathlib import Path

os.environ.setdefault("JAX_PLATFORMS", "cpu")

import jax  # noqa: E402
import pytest  # noqa: E402

jax.config.update("jax_enable_x64", True)


# The modules whose tests take longest (tens of seconds each: killed-and-resumed runs, calibrations,
# the posterior command line) run first. pytest-xdist hands tests out in collection order, so
# collected last they left one worker finishing them alone while the other idled.
_LONGEST_FIRST = ("test_resume.py", "test_calibration.py", "test_posterior_cli.py", "test_multiday.py")


def pytest_collection_modifyitems(config, items):
    def rank(item):
        name = item.path.name
        return _LONGEST_FIRST.index(name) if name in _LONGEST_FIRST else len(_LONGEST_FIRST)

    items.sort(key=rank)  # stable: the order within each module is kept


@pytest.fixture(scope="session")
def script_module():
    """``load(path)``: a script under benchmarks/ or experiments/ (a path, or a benchmark's name) run as
    a module, with benchmarks/ and the script's folder on ``sys.path`` while it loads (the scripts
    import their sibling scripts by name)."""
    benchmarks = Path(__file__).resolve().parents[1] / "benchmarks"

    def load(path):
        path = Path(path) if str(path).endswith(".py") else benchmarks / f"{path}.py"
        folders = [str(benchmarks), str(path.parent)]
        sys.path[:0] = folders
        try:
            spec = importlib.util.spec_from_file_location(path.stem, path)
            module = importlib.util.module_from_spec(spec)
            spec.loader.exec_module(module)
            return module
        finally:
            for folder in folders:
                sys.path.remove(folder)

    return load


# A worker killed by a fatal signal (a crash in native code: XLA, Dr.Jit, HDF5) printed its Python
# stacks to stderr followed by ~180 extension module names, and CI logs keep only the tail: the stacks
# were lost. Each worker writes its fatal-error report to a file instead, the controller prints the
# stacks in its summary, and a test that crashed its worker runs once more in another worker process: a second
# crash fails the run as before, one that passes is listed as "rerun" with the first crash's stacks.
_CRASH_DIR = "LIGHTFIT_TEST_CRASH_DIR"
_crashed: set[str] = set()


def pytest_configure(config):
    workers = config.pluginmanager.has_plugin("xdist") and config.getoption("dist", "no") != "no"
    if workers and "PYTEST_XDIST_WORKER" not in os.environ:
        import tempfile

        os.environ[_CRASH_DIR] = tempfile.mkdtemp(prefix="lightfit-test-crashes-")  # the workers inherit it


@pytest.fixture(autouse=True, scope="session")
def _fatal_errors_to_a_file():
    folder, worker = os.environ.get(_CRASH_DIR), os.environ.get("PYTEST_XDIST_WORKER")
    if not (folder and worker):
        yield
        return
    import faulthandler

    with open(Path(folder) / f"{worker}-{os.getpid()}.txt", "w") as f:
        faulthandler.enable(file=f, all_threads=True)
        yield
        faulthandler.enable(file=sys.stderr, all_threads=True)


@pytest.hookimpl(optionalhook=True)
def pytest_handlecrashitem(crashitem, report, sched):
    if crashitem not in _crashed:
        _crashed.add(crashitem)
        sched.mark_test_pending(crashitem)
        report.outcome = "rerun"


def pytest_unconfigure(config):
    folder = os.environ.get(_CRASH_DIR)
    if folder and "PYTEST_XDIST_WORKER" not in os.environ:
        import shutil

        shutil.rmtree(folder, ignore_errors=True)


def pytest_report_teststatus(report):
    if report.outcome == "rerun":
        return "rerun", "R", "RERUN"
    return None


def pytest_terminal_summary(terminalreporter):
    folder = os.environ.get(_CRASH_DIR)
    if not folder or "PYTEST_XDIST_WORKER" in os.environ:
        return
    reports = [(p.stem, p.read_text(errors="replace")) for p in sorted(Path(folder).glob("*.txt"))]
    reports = [(name, _stacks(text)) for name, text in reports if text.strip()]
    if reports or _crashed:
        terminalreporter.section("worker crashes", red=True)
        for item in sorted(_crashed):
            terminalreporter.line(f"crashed its worker, run again in another worker: {item}")
        for name, text in reports:
            terminalreporter.line(f"--- fatal error in worker {name} (its Python stacks) ---")
            terminalreporter.line(text.rstrip())


def _stacks(report: str) -> str:
    """A fatal-error report without its list of extension modules and pytest's own frames."""
    runner = ("_pytest", "pluggy", "xdist", "execnet")
    lines = report.split("\nExtension modules:")[0].splitlines()
    return "\n".join(ln for ln in lines if not any(f"site-packages/{r}/" in ln for r in runner))
