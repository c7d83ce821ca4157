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
``SERIES[i].mc_sd`` of the forward dict) read where step k's observations are: instants between two
instants meet the model interpolated linearly in time, :math:`(1 - w_k)\,m_k + w_k\,m_{n_k}`, with
Monte Carlo variance :math:`(1 - w_k)^2 s_k^2 + w_k^2 s_{n_k}^2`
(:func:`~lightfit.inference.observations.interpolation`; :math:`w_k = 0` on the steps), and the
noise scale :math:`\lambda` (dimensionless, default 1; it multiplies the reported measurement SDs
and is a parameter of inference only, never of the model). Steps without an observation, and
series not in ``use``, do not enter. Then

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

**Plug-in Monte Carlo variance** (``mc=`` of :meth:`GaussianLikelihood.loss` and
:meth:`~GaussianLikelihood.log_likelihood`, :func:`plug_in`). The SDs' *values* still move with θ
(the PAR SD scales with the light factor, the An SD with dAn/dPAR, a render's SE with the leaf)
while their gradient is stopped, so the gradient of :math:`r^2/v(\theta)` is not the derivative
of its value: where s² is a large share of v, a line search meets a function whose slope it is
not given (on a closed-form model with s ∝ light factor, L-BFGS-B stopped on a failed line
search). The optimisers therefore take s at a reference θ₀ and hold it,
:math:`v_k = (\lambda\sigma_k)^2 + c\,s_k(\theta_0)^2`, as C is held: value and gradient are then
one function. :func:`~lightfit.inference.calibration.calibrate` takes θ₀ = its start (the
surrogate's rounds: each round's start, so s follows the optimum round by round), the posterior's
MAP search the best sample. emcee needs no gradient and samples the likelihood with s(θ).

**Correlated Monte Carlo error** (``mc_correlation``, docs/posterior.md "Monte Carlo covariance").
The renderer reuses a segment's random numbers at every time step, so its error is shared across
steps (the sky part's exactly) and across series: the steps are not independent. With the
observed entries of all used series stacked into one vector (series blocks in :data:`SERIES`
order, steps in time order), the covariance is

.. math::

    \Sigma(\theta, \lambda) = \lambda^2\,\mathrm{diag}(\sigma^2)
        + c\,\mathrm{diag}(s(\theta))\, C\, \mathrm{diag}(s(\theta)),

with the model's Monte Carlo SDs s(θ) as above, their correlation C (:class:`MCCorrelation`, from
:func:`mc_correlation`: fixed, computed once at a reference θ; where the model is read between
steps, the second term is :math:`c\,A\,\mathrm{diag}(s)\,C\,\mathrm{diag}(s)\,A^\top` over all
steps, A the interpolation), and ``mc_scale`` c (1 for measured
data; 2 for twin observations that are themselves renders at the model's samples from another
seed: their error adds a second, independent copy). With the Cholesky factor
:math:`\Sigma = L L^\top`,

.. math::

    w = L^{-1} r, \qquad \log L(\theta, \lambda) = -\tfrac12\Big[\|w\|^2 + n \log 2\pi
        + 2 \sum_i \log L_{ii}\Big],

:math:`\mathcal L_{cal} = \tfrac12\|w\|^2`, and :math:`w` takes the place of the whitened
residuals (``‖w‖² = rᵀΣ⁻¹r``, so the Fisher information JᵀJ of :mod:`.identifiability` is
unchanged in form). Without ``mc_correlation`` (C = I) and with every reading on a step this is the
diagonal form above, computed without a factorisation; a reading between two steps reads two
steps' errors, Σ_MC = A diag(s) C diag(s) Aᵀ with C = I, and Σ is a full matrix again
(:attr:`GaussianLikelihood.dense`).

A model output whose leaf photosynthesis did not converge (a nonzero
:data:`~lightfit.model.observe.CONVERGENCE_KEY` count) has no likelihood: the loss is +inf and
log L −inf there, so optimisers reject the point and samplers never accept it.
"""

from __future__ import annotations

import hashlib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd

from lightfit.errors import InputError, check_real
from lightfit.inference.observations import (
    ALIASES,
    BY_NAME,
    SERIES,
    align,
    check_an_area,
    check_ratios_lit_at,
    check_sds,
    dependencies,
    interpolation,
    observed,
    read_between,
    series,
)
from lightfit.model.observe import mc_covariance, unconverged
from lightfit.model.parameters import NAMES, as_theta
from lightfit.weather.timestamps import INSTANTS, Timestamps

#: Short names of the series a likelihood can use, in order.
USES = tuple(s.name for s in SERIES)


def resolve_use(use: Sequence[str] | None, obs: pd.DataFrame | None = None) -> tuple[str, ...]:
    """Series names of ``use`` (aliases ``par``/``an`` resolved, order of :data:`SERIES`, no
    duplicates); ``None`` or empty: every series with a value in ``obs``. :class:`InputError` for
    an unknown name, and for a name of which ``obs`` (where given) has no value, unless ``use`` is
    :data:`USES` (callers' "whatever the file has")."""
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
    chosen = tuple(n for n in USES if n in names)
    if obs is not None and tuple(use) != USES:
        absent = [n for n in chosen if n not in observed(obs)]
        if absent:
            raise InputError(
                f"use names {', '.join(absent)}, which the observations have no value of",
                file=obs.attrs.get("source"),
                parameter="use",
                expected="series the observations have: " + (", ".join(observed(obs)) or "none"),
            )
    return chosen


def run_settings(model) -> dict:
    """``bounces`` and ``par_kind`` of ``model``'s scenario (a multi-day model's first day; 1 and
    "absorbed" for a model without them, e.g. a test double): what
    :func:`~lightfit.inference.observations.dependencies` needs."""
    days = getattr(model, "day_models", None)
    sc = getattr(next(iter(days.values())) if days else model, "scenario", None)
    return {"bounces": int(getattr(sc, "bounces", 1)), "par_kind": str(getattr(sc, "par_kind", "absorbed"))}


def uninformed(
    names: Sequence[str], use: Sequence[str], *, bounces: int = 1, par_kind: str = "absorbed"
) -> tuple[str, ...]:
    """Those of the model parameters ``names`` on which no series of ``use`` depends in a run with
    ``bounces`` and ``par_kind`` (:func:`~lightfit.inference.observations.dependencies`): a
    likelihood of those series is flat along them, so an optimiser cannot move them and their
    posterior is their prior (e.g. the leaf parameters against the above-canopy sensor alone, which
    sees the sky). Names that are not model parameters (the noise scale) are not judged."""
    seen = {p for n in resolve_use(tuple(use)) for p in dependencies(BY_NAME[n], bounces=bounces, par_kind=par_kind)}
    return tuple(n for n in names if n in NAMES and n not in seen)


def check_informed(names: Sequence[str], use: Sequence[str], *, bounces: int = 1, par_kind: str = "absorbed") -> None:
    """:class:`InputError` naming the parameters of ``names`` that no series of ``use`` depends on
    (:func:`uninformed`): a calibration of them would stop where it started and call it converged.
    The message names, per such parameter, the series that would inform it."""
    run = {"bounces": bounces, "par_kind": par_kind}
    flat = uninformed(names, use, **run)
    if flat:
        use = resolve_use(tuple(use))
        can = [n for n in NAMES if not uninformed([n], use, **run)]
        need = {p: [s for s in USES if p in dependencies(BY_NAME[s], **run)] for p in flat}
        by = "; ".join(f"{p}: {', '.join(v) if v else 'none at bounces 0'}" for p, v in need.items())
        raise InputError(
            f"the observed series in the likelihood ({', '.join(use)}) do not depend on {', '.join(flat)}"
            + (" (no light is scattered: bounces 0)" if bounces < 1 else ""),
            parameter="parameters",
            expected=(f"parameters they inform ({', '.join(can)})" if can else "other parameters")
            + f", or observed series that do (use= / --use, or another observations file: {by})",
        )


#: Shrinkage of a Monte Carlo correlation towards the identity, C ← (1 − ε) C + ε I: the sky
#: error is one number per segment, so C can be singular (exactly degenerate modes); ε keeps Σ
#: positive definite when the measurement SDs are tiny (λ → 0) without changing any variance.
MC_CORRELATION_JITTER = 1e-9


@dataclass(frozen=True)
class MCCorrelation:
    """Correlation of the model's Monte Carlo errors across the series ``names`` and ``n_steps``
    time steps: ``matrix`` (len(names)·T, len(names)·T), blocks of T steps in the order of
    ``names`` (short series names of :data:`~lightfit.inference.observations.SERIES`); diagonal 1,
    entries of quantities without Monte Carlo error (night steps, the above-canopy sensor) 0 off
    the diagonal. ``theta``: the parameters it was computed at."""

    names: tuple[str, ...]
    n_steps: int
    matrix: np.ndarray
    theta: dict | None = None

    def select(self, names: Sequence[str]) -> np.ndarray:
        """The correlation of the series ``names`` (a sub-matrix, blocks in that order)."""
        missing = [n for n in names if n not in self.names]
        if missing:
            raise InputError(
                f"Monte Carlo correlation lacks series {missing}",
                parameter="mc_correlation",
                expected="a correlation computed for the used series " + ", ".join(names),
            )
        T = self.n_steps
        idx = np.concatenate([self.names.index(n) * T + np.arange(T) for n in names])
        return self.matrix[np.ix_(idx, idx)]


def correlation_of(cov: np.ndarray) -> np.ndarray:
    """Correlation matrix of a covariance; rows with zero variance get 1 on the diagonal, 0 off it;
    shrunk by :data:`MC_CORRELATION_JITTER` towards the identity."""
    cov = np.asarray(cov, np.float64)
    sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
    pos = sd > 0
    inv = np.where(pos, 1.0 / np.where(pos, sd, 1.0), 0.0)
    c = cov * inv[:, None] * inv[None, :]
    np.fill_diagonal(c, 1.0)
    return (1.0 - MC_CORRELATION_JITTER) * c + MC_CORRELATION_JITTER * np.eye(len(c))


def mc_correlation(model, theta=None, names: Sequence[str] | None = None, parts=None) -> MCCorrelation:
    """Correlation of the Monte Carlo errors of ``model``'s observables at ``theta``.

    The covariance is :func:`lightfit.model.observe.mc_covariance` (sky error shared by all steps,
    sun errors per step) of the light parts ``parts = (values, se)`` (default ``model.parts(theta)``:
    a full render, or the emulator's parts for a model with emulated light), through the model's
    observation operator with the exact leaf photosynthesis. ``names``: series (default all of
    :data:`~lightfit.inference.observations.SERIES`). Cost: one forward pass and one reverse pass
    per series. A :class:`~lightfit.inference.multiday.MultiDayModel`: each day's correlation,
    independent across days (block-diagonal).
    """
    if getattr(model, "day_models", None) is not None:  # several days (lightfit.inference.multiday)
        return model.mc_correlation(theta, names)
    # parameters not named: the scenario's (its optics' leaf, CoupledModel.theta), as observe() takes them
    complete = getattr(model, "theta", None)
    theta = complete(theta) if callable(complete) else as_theta(theta)
    names = tuple(series(n).name for n in (names or USES))
    values, se = model.parts(theta) if parts is None else parts
    cov = mc_covariance(model.operator, values, se, theta, [BY_NAME[n].value for n in names])
    return MCCorrelation(names, len(model.times), correlation_of(cov), theta.to_dict())


#: The two forms of the Monte Carlo part of the likelihood (``mc_correlation`` argument of
#: :func:`likelihood_form`): the model's correlation across steps and series, or independent steps.
MC_FORMS = ("model", "independent")


def likelihood_form(mc_correlation, mc_scale: float = 1.0) -> dict:
    """The likelihood's form as it enters resume keys: ``{"mc_correlation": "model" | "independent",
    "mc_scale": c}``. ``mc_correlation``: ``"model"``, ``None``/``"independent"``/``"none"`` or an
    :class:`MCCorrelation` (``"model"``: a run resumed with the other form would mix two
    likelihoods). :class:`InputError` for anything else."""
    if isinstance(mc_correlation, MCCorrelation):
        mode = "model"
    elif mc_correlation is None or mc_correlation in ("independent", "none"):
        mode = "independent"
    elif mc_correlation == "model":
        mode = "model"
    else:
        raise InputError(
            f"mc_correlation={mc_correlation!r}", parameter="mc_correlation", expected="'model' or 'independent'"
        )
    return {"mc_correlation": mode, "mc_scale": float(mc_scale)}


class GaussianLikelihood:
    """Observations aligned to a run's time steps, and the Gaussian likelihood of model outputs.

    Args:
        obs: observations (:func:`~lightfit.inference.observations.read_observations`).
        times: the run's time steps (``model.times``).
        use: which series enter (names of :data:`USES` or their aliases ``par``, ``an``); ``None``:
            every series the observations have a value of.
        mc_correlation: correlation of the model's Monte Carlo errors (:func:`mc_correlation`),
            covering at least the used series; ``None``: independent errors (diagonal covariance).
        mc_scale: c ≥ 0, multiplies the model's Monte Carlo variance (1: measured observations;
            2: twin observations rendered at the model's samples with another seed).
        stamps: what ``times`` label (``model.timestamps``: instants, or the start, centre or
            end of means); observations go to the step whose centre is nearest theirs
            (:func:`~lightfit.inference.observations.align`).
        step: the run's forcing step (``model.step``; ``None``: the shortest spacing of ``times``,
            right for a run that is not cut to its observed steps): readings between two steps
            this far apart meet the model interpolated between them
            (:func:`~lightfit.inference.observations.interpolation`).

    Raises :class:`InputError` when an observation lies outside the run or no observation of the
    used series falls on a simulated step.
    """

    def __init__(
        self,
        obs: pd.DataFrame,
        times: pd.DatetimeIndex,
        use: Sequence[str] | None = None,
        *,
        mc_correlation: MCCorrelation | None = None,
        mc_scale: float = 1.0,
        stamps: Timestamps = INSTANTS,
        step: pd.Timedelta | None = None,
    ):
        if not (isinstance(obs, pd.DataFrame) and isinstance(obs.index, pd.DatetimeIndex) and obs.index.tz):
            index = f" indexed by {type(obs.index).__name__}" if hasattr(obs, "index") else ""
            raise InputError(  # a file name or an empty table was an AttributeError further in
                f"obs of type {type(obs).__name__}{index}",
                parameter="obs",
                expected="an observations table indexed by aware times (observations.read_observations reads one)",
            )
        if use is not None and (isinstance(use, str) or not tuple(use)):
            raise InputError(f"use={use!r}", parameter="use", expected="a non-empty sequence of " + ", ".join(USES))
        mc_scale = check_real(mc_scale, "mc_scale", 0.0, expected="a finite number ≥ 0")  # "2": numpy's TypeError
        use = resolve_use(use, obs)  # a series the observations lack refused
        check_sds(obs)
        self.stamps = stamps
        #: the run's forcing step that readings are interpolated within (None: the spacing of ``times``)
        self.step = step
        target = align(obs, times, stamps)
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
        lerp = interpolation(obs, times, stamps, step)
        #: per used series: each step's neighbour and weight of the model read at its observations
        #: (:func:`~lightfit.inference.observations.interpolation`; weight 0: the step's own value)
        self.neighbour = {s.name: jnp.asarray(lerp[s.value][0]) for s in self.series}
        self.weight = {s.name: jnp.asarray(lerp[s.value][1]) for s in self.series}
        #: whether any observation lies between two steps (else the model is read at the steps)
        self.interpolated = bool(any(np.asarray(w).any() for w in self.weight.values()))
        self.n_observations = int(sum(np.asarray(m).sum() for m in self.mask.values()))
        if self.n_observations == 0:
            raise InputError(
                f"no observation of {' or '.join(s.value for s in requested)} falls on a simulated step",
                file=obs.attrs.get("source"),
                parameter="use",
                expected="observations of the used series within the run",
            )
        self.mc_scale = float(mc_scale)
        T = len(times)
        #: positions of the observed entries in the stacked (len(use)·T,) vector
        self.observed_index = np.concatenate(
            [i * T + np.flatnonzero(np.asarray(self.mask[s.name])) for i, s in enumerate(self.series)]
        )
        #: the correlation given (None: independent steps); :attr:`correlation` is its observed part
        self.mc_correlation = mc_correlation
        self.correlation = None
        # Interpolated: the model at the observations is A·m over the stacked steps; only the
        # steps A reads (columns ``_cols``) enter, so a step read by none cannot spoil Σ.
        self._interp = self._cols = self._full_correlation = None
        if self.interpolated:
            a = self._interpolation_matrix(T)
            cols = np.flatnonzero(np.abs(a).sum(0) > 0)
            self._interp, self._cols = jnp.asarray(a[:, cols]), cols
        if mc_correlation is not None:
            if mc_correlation.n_steps != T:
                raise InputError(
                    f"Monte Carlo correlation over {mc_correlation.n_steps} steps",
                    parameter="mc_correlation",
                    expected=f"one computed for this run's {T} steps",
                )
            c = mc_correlation.select(self.use)
            self.correlation = jnp.asarray(c[np.ix_(self.observed_index, self.observed_index)])
            if self.interpolated:
                self._full_correlation = jnp.asarray(c[np.ix_(self._cols, self._cols)])
        #: whether Σ is a full matrix (a Cholesky factor): with the model's correlation, or where
        #: readings between steps share a step's Monte Carlo error even with independent steps
        self.dense = self.correlation is not None or self.interpolated

    @classmethod
    def of_model(cls, model, obs: pd.DataFrame, use: Sequence[str] | None = None, **kw) -> GaussianLikelihood:
        """The likelihood of ``obs`` on ``model``'s steps: its ``times``, ``timestamps`` and forcing
        ``step`` (a :class:`~lightfit.model.coupled.CoupledModel`, one cut to its observed steps, or a
        :class:`~lightfit.inference.multiday.MultiDayModel`); ``kw``: ``mc_correlation``, ``mc_scale``.
        Observations of canopy An per another area than the model's ``an_per`` are refused
        (:func:`~lightfit.inference.observations.check_an_area`)."""
        check_an_area(obs, model.scenario.an_per)
        lik = cls(obs, model.times, use, stamps=model.timestamps, step=model.step, **kw)
        if getattr(model, "day", None) is not None:  # a test double may have none
            lik.check_ratios_lit(obs, model)
        return lik

    def check_ratios_lit(self, obs: pd.DataFrame, model) -> None:
        """The used ratios of light read at a step ``model`` does not render, or towards one, refused
        (:func:`~lightfit.inference.observations.check_ratios_lit_at`); unused series are not judged."""
        used = {c for s in self.series for c in (s.value, s.sd)}
        used_obs = obs[[c for c in obs.columns if c in used]]
        # read between steps as this likelihood reads them: the model's forcing step, not its times' spacing
        check_ratios_lit_at(used_obs, model.times, model.timestamps, model.day, getattr(model, "step", None))

    def _interpolation_matrix(self, T: int) -> np.ndarray:
        """A (n_observations, len(use)·T): row r reads the stacked steps at observed entry r,
        (1 − w) at its step and w at its neighbour."""
        a = np.zeros((len(self.observed_index), len(self.series) * T))
        for r, g in enumerate(self.observed_index):
            i, k = divmod(int(g), T)
            name = self.series[i].name
            w = float(self.weight[name][k])
            a[r, g] += 1.0 - w
            a[r, i * T + int(self.neighbour[name][k])] += w
        return a

    def at_observations(self, name: str, x) -> jax.Array:
        """A model quantity of series ``name`` (T,) read where its observations are: at each step,
        (1 − w)·x_k + w·x_n (:attr:`weight`, :attr:`neighbour`), x_k itself at weight 0."""
        return read_between(x, self.neighbour[name], self.weight[name], xp=jnp)

    def variances(self, m: Mapping, noise_scale=1.0) -> dict:
        """v_k = (λσ_k)² + c·s_k² per used series, 1 where there is no observation (µmol² m⁻⁴ s⁻²):
        the diagonal of Σ where Σ is diagonal (not :attr:`dense`: every reading on a step)."""
        lam = jnp.asarray(noise_scale, jnp.float64)
        return {
            s.name: jnp.where(
                self.mask[s.name],
                (lam * self.sd[s.name]) ** 2 + self.mc_scale * m[s.mc_sd] ** 2,
                1.0,
            )
            for s in self.series
        }

    def _stack(self, per_series: Mapping) -> jax.Array:
        """Observed entries of per-series (T,) arrays, stacked in series order: (n_observations,)."""
        return jnp.concatenate([jnp.asarray(per_series[s.name]) for s in self.series])[self.observed_index]

    def covariance(self, m: Mapping, noise_scale=1.0) -> jax.Array:
        """Σ over the observed entries, (n_observations, n_observations), µmol² m⁻⁴ s⁻²: λ²diag(σ²)
        plus c times the model's Monte Carlo covariance (:meth:`_correlated_mc`), or diag(v)
        (:meth:`variances`) where Σ is diagonal (not :attr:`dense`)."""
        if not self.dense:
            return jnp.diag(self._stack(self.variances(m, noise_scale)))
        sd = jnp.asarray(noise_scale, jnp.float64) * self._stack(self.sd)
        return jnp.diag(sd**2) + self.mc_scale * self._correlated_mc(m)

    def cholesky(self, m: Mapping, noise_scale=1.0) -> jax.Array:
        """Lower Cholesky factor L of Σ over the observed entries (:meth:`covariance`),
        (n_observations, n_observations)."""
        return jnp.linalg.cholesky(self.covariance(m, noise_scale))

    def series_fit(self, m: Mapping) -> pd.DataFrame:
        r"""How model outputs ``m`` meet each used series at λ = 1, one row per series (index: its
        name, :data:`SERIES` order) with the residuals :math:`d = \hat m - y` (model read at the
        observations minus observed, the series' ``unit``):

        * ``n``: steps with a reading (the readings of one step enter as their inverse-variance
          mean, :func:`~lightfit.inference.observations.align`, as everywhere in the likelihood);
          ``bias``: mean of d over them; ``rmse``: :math:`\sqrt{\overline{d^2}}`;
        * ``chi2``: :math:`d_s^\top \Sigma_{ss}^{-1} d_s`, Σ_ss the series' own block of
          :meth:`covariance` (the χ² of the series alone; with χ²_{n} as its distribution where the
          model is right). Where Σ is diagonal the rows add up to the whole χ² = 2·:meth:`loss`;
          with correlated errors across series they need not. +inf where ``m``'s photosynthesis did
          not converge (:meth:`loss`'s refusal); ``bias`` and ``rmse`` are still those of ``m``'s
          values (the solver's last iterate that results.nc keeps), not of the zeros the refusal
          puts in their place.
        """
        refused = bool(unconverged(m) > 0)
        d = -np.asarray(self._stack(self._residuals(m)), np.float64)
        cov = np.asarray(self.covariance(m), np.float64)
        series_of = self.observed_index // len(self.y[self.series[0].name])
        rows = {}
        for i, s in enumerate(self.series):
            k = series_of == i
            ds = d[k]
            chi2 = np.inf if refused else float(ds @ np.linalg.solve(cov[np.ix_(k, k)], ds))
            rows[s.name] = {
                "n": int(k.sum()),
                "bias": float(ds.mean()),
                "rmse": float(np.sqrt(np.mean(ds**2))),
                "chi2": chi2,
                "unit": s.unit,
            }
        return pd.DataFrame.from_dict(rows, orient="index").rename_axis("series")

    def _correlated_mc(self, m: Mapping) -> jax.Array:
        """diag(s) C diag(s) over the observed entries, or, where the model is read between steps,
        A diag(s) C diag(s) Aᵀ over the steps A reads (A: :meth:`_interpolation_matrix`; C = I
        without ``mc_correlation``: independent steps, whose errors two readings still share)."""
        if not self.interpolated:
            s = self._stack({x.name: m[x.mc_sd] for x in self.series})
            return (s[:, None] * s[None, :]) * self.correlation
        s = jnp.concatenate([jnp.asarray(m[x.mc_sd]) for x in self.series])[self._cols]
        b = self._interp * s[None, :]
        return b @ b.T if self._full_correlation is None else b @ self._full_correlation @ b.T

    def mc_covariance(self, m: Mapping) -> jax.Array:
        """The model's own Monte Carlo covariance over the observed entries, diag(s) C diag(s), or
        A diag(s) C diag(s) Aᵀ where the model is read between steps (C = I without
        ``mc_correlation``; not multiplied by ``mc_scale``: the error one render of the model
        carries), (n_observations, n_observations), µmol² m⁻⁴ s⁻²."""
        if not self.dense:
            return jnp.diag(self._stack({x.name: m[x.mc_sd] ** 2 for x in self.series}))
        return self._correlated_mc(m)

    def mc_sd_read(self, m: Mapping) -> dict:
        """The model's Monte Carlo SD where each step's observations read it (the square root of
        :meth:`mc_covariance`'s diagonal), per used series (T,), 0 at steps without an observation."""
        d = jnp.sqrt(jnp.diag(self.mc_covariance(m)))
        T = len(self.y[self.series[0].name])
        full = jnp.zeros(len(self.series) * T).at[self.observed_index].set(d)
        return {s.name: full[i * T : (i + 1) * T] for i, s in enumerate(self.series)}

    def whitened_mc_covariance(self, m: Mapping, noise_scale=1.0) -> jax.Array:
        """W = L⁻¹ Σ_MC L⁻ᵀ (Σ = LLᵀ the likelihood's covariance at λ = ``noise_scale``, Σ_MC from
        :meth:`mc_covariance`): the model's Monte Carlo covariance in whitened coordinates
        (dimensionless, over the observed entries); diag(s²/v) where Σ is diagonal."""
        mc = self.mc_covariance(m)
        if not self.dense:
            v = self._stack(self.variances(m, noise_scale))
            return mc / jnp.sqrt(v[:, None] * v[None, :])
        L = self.cholesky(m, noise_scale)
        a = jax.scipy.linalg.solve_triangular(L, mc, lower=True)
        return jax.scipy.linalg.solve_triangular(L, a.T, lower=True).T

    def _whiten(self, delta: Mapping, m: Mapping, noise_scale):
        """(whitened vector in the (len(use)·T,) layout, log det Σ over the observed entries) of
        differences ``delta`` already read at the observations."""
        if not self.dense:
            v = self.variances(m, noise_scale)
            w = jnp.concatenate(
                [jnp.where(self.mask[s.name], delta[s.name] / jnp.sqrt(v[s.name]), 0.0) for s in self.series]
            )
            logdet = sum(jnp.sum(jnp.where(self.mask[s.name], jnp.log(v[s.name]), 0.0)) for s in self.series)
            return w, logdet
        L = self.cholesky(m, noise_scale)
        w_obs = jax.scipy.linalg.solve_triangular(L, self._stack(delta), lower=True)
        w = jnp.zeros(len(self.series) * len(self.y[self.series[0].name])).at[self.observed_index].set(w_obs)
        return w, 2.0 * jnp.sum(jnp.log(jnp.diag(L)))

    def whiten(self, delta: Mapping, m: Mapping, noise_scale=1.0) -> jax.Array:
        """Whitened per-series differences of the model ``delta[series name]`` (T,) (e.g. an
        emulator's error), read at the observations (:meth:`at_observations`, δ̂ = Aδ): w = L⁻¹δ̂
        over the observed entries (δ̂_k/√v_k where Σ is diagonal), placed in a (len(use)·T,)
        vector, series blocks in order, zero where there is no observation; ‖w‖² = δ̂ᵀΣ⁻¹δ̂. Linear
        in δ: the whitened residuals of model outputs m and m + δ differ by −w."""
        read = {s.name: self.at_observations(s.name, delta[s.name]) for s in self.series}
        return self._whiten(read, m, noise_scale)[0]

    def whitened(self, m: Mapping, noise_scale=1.0) -> jax.Array:
        """Whitened residuals r = y − m̂ (m̂: ``m`` read at the observations), in the layout of
        :meth:`whiten`."""
        return self._whiten(self._residuals(m), m, noise_scale)[0]

    def _residuals(self, m: Mapping) -> dict:
        """y − m read at the observations, per used series (T,)."""
        return {s.name: self.y[s.name] - self.at_observations(s.name, m[s.value]) for s in self.series}

    def loss(self, m: Mapping, mc: Mapping | None = None) -> jax.Array:
        """Calibration loss ½ rᵀΣ⁻¹r at λ = 1 (no normalisation; see the module docstring); +inf where
        ``m``'s photosynthesis did not converge. ``mc``: outputs whose Monte Carlo SDs build Σ (a
        plug-in, e.g. :func:`plug_in` at a reference θ; default ``m``'s own)."""
        refused, m, mc = self._refusable(m, mc)
        w = self._whiten(self._residuals(m), mc, 1.0)[0]
        return jnp.where(refused, jnp.inf, 0.5 * jnp.sum(w**2))

    def log_likelihood(self, m: Mapping, noise_scale=1.0, mc: Mapping | None = None) -> jax.Array:
        """log L = −½ [rᵀΣ⁻¹r + n log 2π + log det Σ] over the observed steps of the used series;
        −inf where ``m``'s photosynthesis did not converge. ``mc`` as in :meth:`loss`."""
        refused, m, mc = self._refusable(m, mc)
        w, logdet = self._whiten(self._residuals(m), mc, noise_scale)
        ll = -0.5 * (jnp.sum(w**2) + self.n_observations * jnp.log(2 * jnp.pi) + logdet)
        return jnp.where(refused, -jnp.inf, ll)

    def _refusable(self, m: Mapping, mc: Mapping | None) -> tuple[jax.Array, dict, Mapping]:
        """(refused, m, mc): whether ``m`` has no likelihood (:func:`unconverged`), ``m`` with the used
        series' values and Monte Carlo SDs 0 where it has none, and the SDs that build Σ (``mc``, or
        that ``m``; a given ``mc`` zeroed alike). The value there is a constant (±inf), but an
        unconverged solve may leave NaN outputs (no steady state, docs/photosynthesis.md), and a NaN
        in the discarded branch of the final ``where`` still reached the gradient as 0·NaN (d log L/dλ
        was NaN)."""
        refused = unconverged(m) > 0

        def zeroed(d: Mapping) -> dict:
            used = [k for s in self.series for k in (s.value, s.mc_sd) if k in d]
            return {**d, **{k: jnp.where(refused, 0.0, d[k]) for k in used}}

        m = zeroed(m)
        return refused, m, m if mc is None else zeroed(mc)


def plug_in(lik: GaussianLikelihood, m: Mapping) -> dict:
    """The Monte Carlo SDs of model outputs ``m`` that :class:`GaussianLikelihood` reads (each used
    series' ``mc_sd`` key), as concrete numpy arrays: the plug-in variance of a loss optimised by
    gradient (``mc=`` of :meth:`GaussianLikelihood.loss`), taken once at a reference θ, as the
    correlation C is (see the module docstring, "Plug-in Monte Carlo variance")."""
    return {s.mc_sd: np.asarray(m[s.mc_sd], np.float64) for s in lik.series}


def observations_digest(lik: GaussianLikelihood, times: pd.DatetimeIndex) -> str:
    """SHA-256 of the observations as the likelihood sees them: per used series its values, SDs and
    mask on the run's steps (and the interpolation's weights and neighbours where a reading lies
    between two steps), and the steps' times. Two runs with the same digest fit the same data
    (another file, column order or an unused series do not change it)."""
    h = hashlib.sha256(b"lightfit observations v1")
    h.update(np.asarray(pd.DatetimeIndex(times).asi8, np.int64).tobytes())
    for s in lik.series:
        h.update(s.name.encode())
        h.update(np.ascontiguousarray(np.asarray(lik.y[s.name], np.float64)).tobytes())
        h.update(np.ascontiguousarray(np.asarray(lik.sd[s.name], np.float64)).tobytes())
        h.update(np.ascontiguousarray(np.asarray(lik.mask[s.name], np.uint8)).tobytes())
        if lik.interpolated:  # else as before interpolation, so that digests stored then still match
            h.update(np.ascontiguousarray(np.asarray(lik.weight[s.name], np.float64)).tobytes())
            h.update(np.ascontiguousarray(np.asarray(lik.neighbour[s.name], np.int64)).tobytes())
    return h.hexdigest()


__all__ = [
    "ALIASES",
    "MC_CORRELATION_JITTER",
    "MC_FORMS",
    "USES",
    "GaussianLikelihood",
    "MCCorrelation",
    "check_informed",
    "correlation_of",
    "likelihood_form",
    "mc_correlation",
    "observations_digest",
    "plug_in",
    "resolve_use",
    "run_settings",
    "uninformed",
]
