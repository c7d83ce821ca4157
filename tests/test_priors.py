"""Prior densities against scipy.stats (lightfit.inference.mcmc.priors)."""

from __future__ import annotations

import math

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


def test_centres_are_the_midpoint_the_geometric_midpoint_and_the_median():
    """Prior.center by hand: (a + b)/2, √(ab), the median a (a mutation audit: the arithmetic midpoint
    for a log-uniform survived; the noise scale's 0.3–3 centre is √0.9 ≈ 0.949, not 1.65)."""
    assert Prior("uniform", 0.2, 0.6, "test").center == pytest.approx(0.4, rel=1e-15)
    assert Prior("loguniform", 0.3, 3.0, "test").center == pytest.approx(math.sqrt(0.9), rel=1e-15)
    assert Prior("lognormal", 1.3, 0.5, "test", lo=0.25, hi=4.0).center == 1.3


def test_loguniform_draws_follow_its_density():
    """Walkers drawn from a log-uniform prior follow scipy's log-uniform (Kolmogorov–Smirnov, fixed
    seed, threshold 0.01) and stay in its support (a mutation audit: uniform draws in x survived;
    they give p ≈ 0 on 0.3–3)."""
    from scipy.stats import kstest, loguniform

    x = Prior("loguniform", 0.3, 3.0, "test").sample(np.random.default_rng(0), 5000)
    assert 0.3 <= x.min() and x.max() <= 3.0
    assert kstest(x, loguniform(0.3, 3.0).cdf).pvalue > 0.01


def test_the_informed_priors_are_their_stated_sources():
    """The informed priors against the numbers their sources state: specular = reflection / 0.08 for the
    upper leaf surface's 3.7–5.9 % (docs/design.md §6), roughness 0.3–1, the light factor log-normal
    with median 1 and log-SD 0.5 on 0.25–4, Vcmax ± 25 % (log-SD 0.25) on 0.25–4, the noise scale
    log-uniform 0.3–3; the wide set spans [0, 1] for specular and subsurface (a mutation audit: a
    transposed digit in the specular bound and a doubled Vcmax SD survived)."""
    from lightfit.inference.mcmc.priors import PRIORS_INFORMED, PRIORS_WIDE

    want = {
        "specular": ("uniform", 0.037 / 0.08, 0.059 / 0.08, None, None),
        "roughness": ("uniform", 0.3, 1.0, None, None),
        "light_factor": ("lognormal", 1.0, 0.5, 0.25, 4.0),
        "vcmax_scale": ("lognormal", 1.0, 0.25, 0.25, 4.0),
        "noise_scale": ("loguniform", 0.3, 3.0, None, None),
    }
    for n, (kind, a, b, lo, hi) in want.items():
        p = PRIORS_INFORMED[n]
        assert (p.kind, p.lo, p.hi) == (kind, lo, hi), n
        assert (p.a, p.b) == pytest.approx((a, b), rel=1e-12), n
    for n in ("specular", "subsurface"):
        assert PRIORS_WIDE[n].support == (0.0, 1.0)


def test_a_posterior_of_the_noise_scale_alone_is_refused():
    """check_sampled: a posterior needs a model parameter; the noise scale alone answers nothing about
    the model (a mutation audit: dropping the check survived)."""
    from lightfit.errors import InputError
    from lightfit.inference.mcmc.priors import PRIORS_INFORMED, check_sampled

    with pytest.raises(InputError, match="no model parameter"):
        check_sampled(("noise_scale",), PRIORS_INFORMED)
    assert check_sampled(["light_factor", "noise_scale"], PRIORS_INFORMED) == ("light_factor", "noise_scale")


@pytest.mark.parametrize(
    ("args", "said"),
    [
        (("lognormal", 1.0, 0.5, "test", 4.0, 0.25), "truncated to [4.0, 0.25]"),  # bounds swapped
        (("lognormal", 10.0, 0.5, "test", 0.25, 4.0), "median 10.0 truncated to [0.25, 4.0]"),
        (("lognormal", 1.0, 0.5, "test", -1.0, 4.0), "truncated to [-1.0, 4.0]"),
        (("lognormal", 1.0, math.inf, "test"), "b=inf"),
        (("uniform", 0.0, math.inf, "test"), "b=inf"),
        (("uniform", 0.2, 0.8, "test", 0.3, 0.5), "uniform prior with lo=0.3, hi=0.5"),
        (("loguniform", 0.3, 3.0, "test", None, 2.0), "loguniform prior with lo=None, hi=2.0"),
    ],
)
def test_a_prior_whose_bounds_cannot_hold_it_is_refused(args, said):
    """A Prior the library user builds (log_posterior's priors=): a log-normal truncated to lo > hi was
    accepted and a numpy traceback ("high - low < 0") when the walkers were drawn; one whose median lay
    outside its truncation had its centre (the fallback point of the sampler, the Monte Carlo
    correlation's reference) at zero density; an infinite log-SD drew 0 and inf; lo / hi given to a
    uniform or log-uniform prior were ignored (its support stayed [a, b]). Each is refused, naming
    the prior. A one-sided truncation stays allowed."""
    from lightfit.errors import InputError

    with pytest.raises(InputError, match="parameter 'prior'") as e:
        Prior(*args)
    assert said in str(e.value), e.value
    assert Prior("lognormal", 1.3, 0.5, "test", lo=0.8, hi=None).support == (0.8, math.inf)
