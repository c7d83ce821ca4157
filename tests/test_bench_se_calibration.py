"""The F distribution's expected mean and median in benchmarks/bench_se_calibration.py, against
scipy's and the closed form, including few degrees of freedom (2 seeds at R = 2: d2 = 2)."""

from __future__ import annotations

import pytest
from scipy.stats import f as fisher


@pytest.fixture(scope="module")
def bench(script_module):
    return script_module("bench_se_calibration")


@pytest.mark.parametrize(("d1", "d2"), [(11, 36), (1, 3), (3, 10)])
def test_expected_ratio_is_the_f_mean_and_median(bench, d1, d2):
    mean, median = bench.expected_ratio(d1, d2)
    assert mean == pytest.approx(d2 / (d2 - 2))
    assert mean == pytest.approx(fisher.mean(d1, d2))
    assert median == pytest.approx(fisher.median(d1, d2))


@pytest.mark.parametrize(("d1", "d2"), [(1, 2), (1, 1)])
def test_expected_mean_is_infinite_for_two_or_fewer_degrees_of_freedom(bench, d1, d2):
    """2 seeds at R = 2 (d2 = 2) ended the run in a ZeroDivisionError after its renders."""
    assert fisher.mean(d1, d2) == float("inf")
    mean, median = bench.expected_ratio(d1, d2)
    assert mean is None
    assert median == pytest.approx(fisher.median(d1, d2))
