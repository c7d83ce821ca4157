"""Shared test configuration.

float64 is enabled for the whole suite so that float64 paths (finite-difference checks,
peer comparisons) are available; float32 paths are exercised by passing float32 arrays
explicitly. lightfit itself never changes JAX's global configuration on import.
"""

import os
import shutil
import tempfile

os.environ.setdefault("JAX_PLATFORMS", "cpu")
# One persistent JAX compilation cache for the whole run, its xdist workers (they inherit the
# controller's environment) and the command lines the tests start: the tests give lightfit a cache
# root each, and every command-line subprocess compiled the same programs again (a large share of
# the resume tests' time, a run-time audit). With a size limit JAX locks the folder around each read
# and write, so that parallel processes never read an entry half written. A folder the user set wins.
_OWN_JAX_CACHE = None
if "JAX_COMPILATION_CACHE_DIR" not in os.environ:
    _OWN_JAX_CACHE = os.environ["JAX_COMPILATION_CACHE_DIR"] = tempfile.mkdtemp(prefix="lightfit-tests-jax-")
    os.environ.setdefault("JAX_COMPILATION_CACHE_MAX_SIZE", str(2**31))

import jax  # noqa: E402

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


def pytest_unconfigure(config):
    if _OWN_JAX_CACHE is not None:  # the process that made it (xdist's controller) removes it
        shutil.rmtree(_OWN_JAX_CACHE, ignore_errors=True)
