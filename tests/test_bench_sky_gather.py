"""benchmarks/bench_sky_gather.py's medians leave out unlit segments (0 / 0), by hand."""

from __future__ import annotations

import numpy as np
import pytest


@pytest.fixture(scope="module")
def bench(script_module):
    return script_module("bench_sky_gather")


def test_lit_median_skips_unlit_segments(bench):
    """SEs 0.1, 0.3, 0.2 on values 1, 2, 4 (relative 0.1, 0.15, 0.05: median 0.1) and one unlit
    segment (0 / 0), which made the reported median NaN."""
    se = np.array([0.1, 0.3, 0.0, 0.2])
    x = np.array([1.0, 2.0, 0.0, 4.0])
    with np.errstate(all="raise"):
        assert bench.lit_median(se, x) == pytest.approx(0.1)


def test_lit_median_of_shares(bench):
    var_sky, var = np.array([1.0, 0.0, 3.0]), np.array([2.0, 0.0, 4.0])
    assert bench.lit_median(var_sky, var) == pytest.approx((0.5 + 0.75) / 2)
