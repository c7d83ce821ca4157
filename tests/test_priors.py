"""Prior densities against scipy.stats (lightfit.inference.mcmc.priors)."""

from __future__ import annotations

import jax
import numpy as np
import pytest
from scipy.stats import lognorm, loguniform

from lightfit.inference.mcmc.priors import Prior


@pytest.mark.parametrize("jit", [False, True])
def test_log_densities_equal_scipys_up_to_a_constant_and_are_minus_inf_outside(jit):
    """Inside the support the log densities differ from scipy's by one constant (the normalisation
    the sampler does not need); at 0 and outside they are −inf, never NaN (the log-normal with its
    support starting at 0 gave NaN at 0: log 0 − (log 0)²)."""
    x = np.array([0.05, 0.3, 1.0, 2.5, 7.0])
    for prior, ref in (
        (Prior("lognormal", 1.2, 0.5, "test"), lognorm(0.5, scale=1.2)),
        (Prior("loguniform", 0.01, 10.0, "test"), loguniform(0.01, 10.0)),
    ):
        f = jax.jit(prior.logpdf) if jit else prior.logpdf
        diff = np.asarray(f(x)) - ref.logpdf(x)
        np.testing.assert_allclose(diff, diff[0], rtol=0, atol=1e-12)
        outside = np.asarray(f(np.array([0.0, -1.0])))
        assert np.all(outside == -np.inf), (prior.kind, outside)
    assert np.all(np.isfinite(np.asarray(Prior("uniform", 0.0, 1.0, "test").logpdf(np.array([0.0, 1.0])))))
