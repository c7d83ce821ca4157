"""Profile likelihood where only part of the line is allowed (lightfit.inference.identifiability)."""

from __future__ import annotations

import numpy as np

from lightfit.inference.identifiability import profile_likelihood


def test_the_profile_is_infinite_where_no_allowed_point_exists():
    """nll = (x₀ − 3)² + x₁², profiled along x₀ through (1, 0) with x₀ allowed in [0.5, 1.5]: inside,
    the other direction goes to x₁ = 0 and the profile is (x₀ − 3)²; outside, no point of the offset
    is allowed, and the profile is +∞ (it took the slice there, an extrapolation of the posterior's
    emulator beyond its box: 1.0 at x₀ = 2, below every allowed value)."""
    ts = np.array([-0.5, 0.0, 0.5, 1.0, -1.0])
    _, prof, slc = profile_likelihood(
        lambda x: (x[0] - 3.0) ** 2 + x[1] ** 2,
        np.array([1.0, 0.0]),
        np.array([1.0, 0.0]),
        ts,
        scale="natural",
        allowed=lambda x: (x[0] >= 0.5) & (x[0] <= 1.5),
    )
    x0 = 1.0 + ts
    np.testing.assert_allclose(slc, (x0 - 3.0) ** 2, rtol=1e-12)  # the slice goes wherever the line goes
    inside = (x0 >= 0.5) & (x0 <= 1.5)
    np.testing.assert_allclose(prof[inside], (x0[inside] - 3.0) ** 2, atol=1e-9)
    assert np.all(prof[~inside] == np.inf), prof
