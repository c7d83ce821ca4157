r"""The log-posterior that emcee samples: priors plus the Gaussian likelihood of the observations.

.. math:: \log p(x \mid y) = \sum_j \log \pi_j(x_j) + \log L(\theta(x), \lambda(x)) + \text{const},

with x the sampled values over ``names`` (model parameters and optionally the noise scale λ),
θ(x) the model parameters (:class:`~lightfit.model.parameters.Theta`; unsampled ones from
``fixed`` or the defaults) and log L from :class:`~lightfit.inference.likelihood.GaussianLikelihood`.
The forward model is typically :class:`lightfit.model.emulator.FastObservables` (emulated renders,
tabulated photosynthesis) for speed, or ``model.observe`` for exact checks.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Mapping, Sequence

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd

from lightfit.errors import InputError
from lightfit.inference.likelihood import USES, GaussianLikelihood, MCCorrelation, plug_in
from lightfit.inference.mcmc.priors import NOISE_SCALE, PRIORS_INFORMED, Prior, check_sampled
from lightfit.inference.observations import check_an_area
from lightfit.model.coupled import NonConvergenceWarning
from lightfit.model.parameters import Theta, as_theta
from lightfit.weather.timestamps import INSTANTS, Timestamps


class LogPosterior:
    """Vectorised log-posterior over ``names`` for observations ``obs`` and a forward function.

    Args:
        forward: ``forward(theta: Theta) -> dict`` of observables (``FastObservables`` or
            ``model.observe``); must be JAX-traceable for the vectorised/jitted use.
        times: the model's time steps (``model.times``) — observations are aligned to them.
        obs: observations DataFrame (``read_observations``); ``use``: which series enter the
            likelihood, ``("par", "an")`` or one of them (twin experiments).
        priors: a prior for every sampled name (default :data:`PRIORS_INFORMED`).
        fixed: values of unsampled parameters: model parameters (default: ``Theta()``) and
            ``noise_scale`` (default 1).
        mc_correlation, mc_scale: the model's Monte Carlo correlation and variance factor
            (:class:`~lightfit.inference.likelihood.GaussianLikelihood`; default: independent steps).
        stamps: what ``times`` label (``model.timestamps``; default instants).
        step: the run's forcing step (``model.step``; default the shortest spacing of ``times``).
    """

    def __init__(
        self,
        forward: Callable[[Theta], Mapping],
        times: pd.DatetimeIndex,
        obs: pd.DataFrame,
        names: Sequence[str],
        priors: Mapping[str, Prior] | None = None,
        fixed: Mapping[str, float] | None = None,
        use: Sequence[str] = USES,
        *,
        mc_correlation: MCCorrelation | None = None,
        mc_scale: float = 1.0,
        stamps: Timestamps = INSTANTS,
        step: pd.Timedelta | None = None,
    ):
        self.priors = dict(priors or PRIORS_INFORMED)
        self.names = check_sampled(names, self.priors)
        fixed = dict(fixed or {})
        lam = fixed.pop(NOISE_SCALE, 1.0)
        try:
            self.noise_scale = np.nan if isinstance(lam, bool) else float(lam)
        except (TypeError, ValueError):
            self.noise_scale = np.nan
        if not (np.isfinite(self.noise_scale) and self.noise_scale > 0):  # a finite log-probability otherwise
            raise InputError(f"fixed {NOISE_SCALE}={lam!r}", parameter="fixed", expected=f"{NOISE_SCALE} finite, > 0")
        self.base = as_theta(fixed)
        self.forward = forward
        self.likelihood = GaussianLikelihood(
            obs, times, use, mc_correlation=mc_correlation, mc_scale=mc_scale, stamps=stamps, step=step
        )
        self.use = self.likelihood.use
        self.n_observations = self.likelihood.n_observations
        self._batch = jax.jit(jax.vmap(self.log_prob_refused))
        #: Points inside the priors' support refused so far (:meth:`log_prob_refused`).
        self.refused = 0
        self._batch_ll = jax.jit(jax.vmap(self.log_likelihood))

    @classmethod
    def of_model(
        cls, forward: Callable[[Theta], Mapping], model, obs: pd.DataFrame, names, *args, **kw
    ) -> LogPosterior:
        """The log-posterior of ``obs`` on ``model``'s steps: its ``times``, ``timestamps`` and forcing
        ``step``, as :meth:`GaussianLikelihood.of_model` takes them; ``args``, ``kw``: the rest of
        the constructor's (``priors``, ``fixed``, ``use``, ``mc_correlation``, ``mc_scale``); canopy An
        per another area than the model's refused (:func:`~lightfit.inference.observations.check_an_area`)."""
        check_an_area(obs, model.scenario.an_per)
        lp = cls(forward, model.times, obs, names, *args, stamps=model.timestamps, step=model.step, **kw)
        if getattr(model, "day", None) is not None:  # ratios of light read in the dark refused, as of_model does
            lp.likelihood.check_ratios_lit(obs, model)
        return lp

    def vector(self, x) -> jax.Array:
        """``x`` as a float64 vector of the sampled parameters, or :class:`InputError` for another
        length: JAX clamps an index past the end, so a short vector gave a finite log-probability
        built on repeated values (JAX-traceable: the shape is static)."""
        x = jnp.asarray(x, jnp.float64)
        if x.shape != (len(self.names),):
            raise InputError(
                f"x of shape {x.shape}",
                parameter="x",
                expected=f"a vector of {len(self.names)} values, in order {', '.join(self.names)}",
            )
        return x

    def split(self, x) -> tuple[Theta, jax.Array]:
        """Model parameters θ(x) and noise scale λ(x) of a sampled vector ``x`` (JAX-traceable)."""
        x = self.vector(x)
        model = [(i, n) for i, n in enumerate(self.names) if n != NOISE_SCALE]
        theta = self.base.replace(**{n: x[i] for i, n in model})
        lam = x[self.names.index(NOISE_SCALE)] if NOISE_SCALE in self.names else self.noise_scale
        return theta, jnp.asarray(lam, jnp.float64)

    def observables(self, x) -> tuple[Mapping, jax.Array]:
        """Forward outputs at θ(x), and λ(x)."""
        theta, lam = self.split(x)
        return self.forward(theta), lam

    def log_prior(self, x) -> jax.Array:
        x = self.vector(x)
        return sum(self.priors[n].logpdf(x[i]) for i, n in enumerate(self.names))

    def log_likelihood(self, x, mc: Mapping | None = None) -> jax.Array:
        """log L at ``x``; −inf where it was refused (:meth:`log_prob_refused`). ``mc``: plug-in
        Monte Carlo SDs (:meth:`plug_in`) for an optimiser's objective; default ``x``'s own."""
        return self._log_likelihood_refused(x, mc)[0]

    def plug_in(self, x) -> dict:
        """The Monte Carlo SDs of the outputs at ``x``, held by a gradient optimiser's objective
        (:func:`lightfit.inference.likelihood.plug_in`: value and gradient one function)."""
        return plug_in(self.likelihood, self.observables(jnp.asarray(x, jnp.float64))[0])

    def _log_likelihood_refused(self, x, mc: Mapping | None = None) -> tuple[jax.Array, jax.Array]:
        # −inf already where the photosynthesis did not converge (GaussianLikelihood); NaN too here
        m, lam = self.observables(x)
        ll = self.likelihood.log_likelihood(m, lam, mc)
        refused = ~jnp.isfinite(ll)
        return jnp.where(refused, -jnp.inf, ll), refused

    def residuals(self, x) -> jax.Array:
        """Whitened residuals (y − m)/√v of the used observations (zeros elsewhere), shape (len(use)·T,)."""
        m, lam = self.observables(x)
        return self.likelihood.whitened(m, lam)

    def in_support(self, x) -> bool:
        return bool(np.isfinite(float(self.log_prior(jnp.asarray(x, jnp.float64)))))

    def log_prob_refused(self, x) -> tuple[jax.Array, jax.Array]:
        """log p(x | y), and whether a point inside the priors' support was refused (−inf) because
        a blade's photosynthesis did not converge there or the likelihood was not finite: never a
        NaN (emcee stops on one) and never a value built on an unconverged solve."""
        x = jnp.asarray(x, jnp.float64)
        lp = self.log_prior(x)
        inside = jnp.isfinite(lp)
        # evaluate the likelihood at a safe point outside the support (no NaN from the model)
        ll, refused = self._log_likelihood_refused(jnp.where(inside, x, jnp.asarray(self.center())))
        refused = inside & refused
        return jnp.where(inside & ~refused, lp + ll, -jnp.inf), refused

    def log_prob(self, x) -> jax.Array:
        return self.log_prob_refused(x)[0]

    def center(self) -> np.ndarray:
        """A point inside every prior's support."""
        return np.asarray([self.priors[n].center for n in self.names])

    def __call__(self, xs: np.ndarray) -> np.ndarray:
        """emcee's vectorised log-probability: (n, ndim) → (n,). Refused points (−inf) are counted
        in :attr:`refused`; the first is named in a :class:`NonConvergenceWarning`."""
        xs = np.atleast_2d(xs)
        lp, refused = (np.asarray(a) for a in self._batch(jnp.asarray(xs, jnp.float64)))
        if refused.any():
            if not self.refused:
                first = dict(zip(self.names, (float(v) for v in xs[np.argmax(refused)])))
                warnings.warn(
                    NonConvergenceWarning(
                        f"log-probability −inf inside the priors at {first}: the leaf photosynthesis did not "
                        "converge or the likelihood was not finite there (later ones are counted in the run's "
                        "'refused' attribute)"
                    ),
                    stacklevel=2,
                )
            self.refused += int(refused.sum())
        return lp.astype(np.float64)

    def loglike_batch(self, xs: np.ndarray, chunk: int = 64) -> np.ndarray:
        """Log-likelihood of many points, evaluated ``chunk`` at a time (bounded memory)."""
        xs = np.atleast_2d(xs)
        return np.concatenate(
            [
                np.asarray(self._batch_ll(jnp.asarray(xs[i : i + chunk], jnp.float64)), dtype=np.float64)
                for i in range(0, len(xs), chunk)
            ]
        )

    def initial(self, nwalkers: int, seed: int) -> np.ndarray:
        """Walkers drawn from the prior (generator seeded with ``seed``)."""
        rng = np.random.default_rng(seed)
        return np.column_stack([self.priors[n].sample(rng, nwalkers) for n in self.names])


__all__ = ["LogPosterior"]
