"""Shared test configuration.

float64 is enabled for the whole suite so that float64 paths (finite-difference checks,
peer comparisons) are available; float32 paths are exercised by passing float32 arrays
explicitly. lightfit itself never changes JAX's global configuration on import.
"""

import os

os.environ.setdefault("JAX_PLATFORMS", "cpu")

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)
