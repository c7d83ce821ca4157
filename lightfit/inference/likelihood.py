r"""The Gaussian likelihood of chamber observations given the coupled model's observables.

For every used series u (a quantity of :data:`lightfit.inference.observations.SERIES`, e.g.
``"above_canopy_par"``: a horizontal quantum sensor above the canopy, ``"canopy_an"``: canopy net
CO2 uptake; each compared with the observation operator of the same name in
:mod:`lightfit.model.observe`) and every time step k with an observation,

.. math::

    r_k = y_k - m_k(\theta), \qquad v_k = (\lambda\,\sigma_k)^2 + s_k(\theta)^2,

with the observation :math:`y_k` and its measurement SD :math:`\sigma_k` (µmol m⁻² s⁻¹, from the
observations file, aligned to the run's steps by :func:`~lightfit.inference.observations.align`),
the model's observable :math:`m_k` and Monte Carlo SD :math:`s_k` (keys ``SERIES[i].value`` and
``SERIES[i].mc_sd`` of the forward dict), and the noise scale :math:`\lambda` (dimensionless,
default 1; it multiplies the reported measurement SDs and is a parameter of inference only, never
of the model). Steps without an observation, and series not in ``use``, do not enter. Then

.. math::

    \log L(\theta, \lambda) = -\tfrac12 \sum_k \Big[\frac{r_k^2}{v_k} + \log(2\pi v_k)\Big]
    \qquad\text{(:meth:`GaussianLikelihood.log_likelihood`)},

    \mathcal L_{cal}(\theta) = \tfrac12 \sum_k \frac{r_k^2}{v_k}
    \qquad\text{(:meth:`GaussianLikelihood.loss`, λ = 1)},

    w_k = r_k / \sqrt{v_k} \qquad\text{(whitened residuals, :meth:`GaussianLikelihood.whitened`)}.

The calibration loss leaves out the normalisation ½Σ log(2π v_k): with λ fixed it depends on θ
only through the Monte Carlo SDs, which the forward model returns without gradient (an estimate
of the renderer's noise, not something to optimise: otherwise the optimiser would be rewarded
for parameters that merely make the renders noisier). So
:math:`\mathcal L_{cal} = -\log L - \tfrac12\sum_k \log(2\pi v_k)` at λ = 1, and the gradient of
both is the same. The posterior samples λ and therefore needs the normalisation.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd

from lightfit.errors import InputError
from lightfit.inference.observations import ALIASES, SERIES, align, observed, series

#: Short names of the series a likelihood can use, in order.
USES = tuple(s.name for s in SERIES)


def resolve_use(use: Sequence[str] | None, obs: pd.DataFrame | None = None) -> tuple[str, ...]:
    """Series names of ``use`` (aliases ``par``/``an`` resolved, order of :data:`SERIES`, no
    duplicates); ``None`` or empty: every series with a value in ``obs``. :class:`InputError` for
    an unknown name."""
    if not use:
        if obs is None:
            return USES
        use = observed(obs)
        if not use:
            raise InputError(
                "no observed value in any column",
                file=obs.attrs.get("source"),
                expected="at least one value of " + ", ".join(s.value for s in SERIES),
            )
    names = {series(str(u)).name for u in use}
    return tuple(n for n in USES if n in names)


class GaussianLikelihood:
    """Observations aligned to a run's time steps, and the Gaussian likelihood of model outputs.

    Args:
        obs: observations (:func:`~lightfit.inference.observations.read_observations`).
        times: the run's time steps (``model.times``).
        use: which series enter (names of :data:`USES` or their aliases ``par``, ``an``); ``None``:
            every series the observations have a value of.

    Raises :class:`InputError` when an observation lies outside the run or no observation of the
    used series falls on a simulated step.
    """

    def __init__(self, obs: pd.DataFrame, times: pd.DatetimeIndex, use: Sequence[str] | None = None):
        if use is not None and (isinstance(use, str) or not tuple(use)):
            raise InputError(f"use={use!r}", column="use", expected="a non-empty sequence of " + ", ".join(USES))
        use = resolve_use(use, obs)
        target = align(obs, times)
        requested = tuple(s for s in SERIES if s.name in use)
        # A requested series without any observation on the run's steps adds nothing to the
        # likelihood; it is left out, so the forward model need not provide it (the default
        # ``use=USES`` of callers means "whatever the observations have").
        self.series = tuple(s for s in requested if not np.isnan(target[s.value]).all())
        self.use = tuple(s.name for s in self.series)
        #: per used series: observation y (0 where missing), measurement SD σ (1 where missing), mask
        self.y = {s.name: jnp.asarray(np.nan_to_num(target[s.value])) for s in self.series}
        self.sd = {s.name: jnp.asarray(np.nan_to_num(target[s.sd], nan=1.0)) for s in self.series}
        self.mask = {s.name: jnp.asarray(~np.isnan(target[s.value])) for s in self.series}
        self.n_observations = int(sum(np.asarray(m).sum() for m in self.mask.values()))
        if self.n_observations == 0:
            raise InputError(
                f"no observation of {' or '.join(s.value for s in requested)} falls on a simulated step",
                file=obs.attrs.get("source"),
                column="use",
                expected="observations of the used series within the run",
            )

    def variances(self, m: Mapping, noise_scale=1.0) -> dict:
        """v_k = (λσ_k)² + s_k² per used series, 1 where there is no observation (µmol² m⁻⁴ s⁻²)."""
        lam = jnp.asarray(noise_scale, jnp.float64)
        return {
            s.name: jnp.where(self.mask[s.name], (lam * self.sd[s.name]) ** 2 + m[s.mc_sd] ** 2, 1.0)
            for s in self.series
        }

    def whiten(self, delta: Mapping, m: Mapping, noise_scale=1.0) -> jax.Array:
        """δ_k/√v_k of per-series differences ``delta[series name]`` (T,), concatenated over the used
        series in order, zero where there is no observation: shape (len(use)·T,)."""
        v = self.variances(m, noise_scale)
        return jnp.concatenate(
            [jnp.where(self.mask[s.name], delta[s.name] / jnp.sqrt(v[s.name]), 0.0) for s in self.series]
        )

    def whitened(self, m: Mapping, noise_scale=1.0) -> jax.Array:
        """Whitened residuals w_k = (y_k − m_k)/√v_k (see :meth:`whiten`)."""
        return self.whiten({s.name: self.y[s.name] - m[s.value] for s in self.series}, m, noise_scale)

    def loss(self, m: Mapping) -> jax.Array:
        """Calibration loss ½ Σ r²/v at λ = 1 (no normalisation; see the module docstring)."""
        return 0.5 * jnp.sum(self.whitened(m) ** 2)

    def log_likelihood(self, m: Mapping, noise_scale=1.0) -> jax.Array:
        """log L = −½ Σ [r²/v + log(2π v)] over the observed steps of the used series."""
        v = self.variances(m, noise_scale)
        log_norm = sum(jnp.sum(jnp.where(self.mask[s.name], jnp.log(2 * jnp.pi * v[s.name]), 0.0)) for s in self.series)
        return -0.5 * (jnp.sum(self.whitened(m, noise_scale) ** 2) + log_norm)


__all__ = ["ALIASES", "USES", "GaussianLikelihood", "resolve_use"]
