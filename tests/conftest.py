"""Shared test configuration.

float64 is enabled for the whole suite so that float64 paths (finite-difference checks,
peer comparisons) are available; float32 paths are exercised by passing float32 arrays
explicitly. lightfit itself never changes JAX's global configuration on import.
"""

import os

os.environ.setdefault("JAX_PLATFORMS", "cpu")

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
