r"""Several days in one calibration or posterior (issue 15 item 4).

Observations from several dates enter one likelihood; each day has its own coupled model (plants
grown to that date, that day's forcing and sun) and, for the surrogate paths, its own emulator
(the shared design cache keys each day's renders by its own render key). The days are joined along
time: :class:`MultiDayModel` looks like one model whose steps are the days' steps in order, and its
forward returns every observable concatenated over the days. The likelihood is then the ordinary
:class:`~lightfit.inference.likelihood.GaussianLikelihood` on the concatenated steps, with

- the Monte Carlo correlation block-diagonal over the days (:func:`block_correlation`): each day is
  rendered from its own scene (its own plants), so its Monte Carlo errors are independent of every
  other day's, while within a day they keep their correlation across steps and series;
- the measurement errors independent, as on one day.

Hence, with :math:`\Sigma` block-diagonal, :math:`r^\top\Sigma^{-1}r = \sum_d r_d^\top\Sigma_d^{-1}r_d`
and :math:`\log\det\Sigma = \sum_d \log\det\Sigma_d`:

.. math:: \log L(\theta, \lambda) = \sum_{d} \log L_d(\theta, \lambda),

the sum of the days' own likelihoods (tested), and the whitened residuals are the days' whitened
residuals side by side, so the Fisher information, profile likelihood and emulator-error report work
unchanged. Calibration (:func:`~lightfit.inference.calibration.calibrate`,
:func:`~lightfit.inference.trust_region.surrogate_calibrate`) and the posterior
(:func:`~lightfit.inference.posterior.run`) take a :class:`MultiDayModel` wherever they take a model.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence

import jax.numpy as jnp
import numpy as np
import pandas as pd

from lightfit.errors import InputError
from lightfit.inference.observations import nearest_steps
from lightfit.model.coupled import CoupledModel
from lightfit.model.observe import CONVERGENCE_KEY
from lightfit.model.parameters import Theta
from lightfit.model.schema import OBSERVABLES


def concat_observables(outs: Sequence[Mapping]) -> dict:
    """The :data:`~lightfit.model.schema.OBSERVABLES` (each (T_d,)) of several days' forward outputs
    and their counts of unconverged blades (:data:`~lightfit.model.observe.CONVERGENCE_KEY`),
    concatenated along time; per-segment fields (whose segments differ from day to day) are left out."""
    keys = (*OBSERVABLES, CONVERGENCE_KEY)
    return {k: jnp.concatenate([jnp.asarray(o[k]) for o in outs]) for k in keys if all(k in o for o in outs)}


class DaysForward:
    """A forward over several days: ``f(theta)`` → the days' observables concatenated in time.
    ``per_day(theta)`` → ``{date: that day's output}``. JAX-traceable when every day's forward is."""

    def __init__(self, dates: Sequence[str], forwards: Sequence[Callable]):
        self.dates, self.forwards = tuple(dates), tuple(forwards)

    def per_day(self, theta) -> dict:
        return {d: f(theta) for d, f in zip(self.dates, self.forwards)}

    def __call__(self, theta) -> dict:
        return concat_observables([f(theta) for f in self.forwards])


class MultiDayModel:
    """Several days' :class:`~lightfit.model.coupled.CoupledModel` (one per date) as one model over
    their concatenated steps.

    Provides what calibration and the posterior use of a model: ``times``, ``timestamps``, ``step``
    (the forcing's step, for readings between two steps), ``day`` (daytime mask),
    ``scenario`` (the first day's: optics, estimator settings — the same on every day), ``theta``,
    ``observe`` (concatenated observables) and, for the Monte Carlo correlation,
    :meth:`mc_correlation`. ``day_models``: ``{date: model}`` in date order.

    Raises :class:`InputError` when the days overlap in time or differ in leaf optics (one set of
    leaf parameters describes every day only if the leaf is the same).
    """

    def __init__(self, models: Mapping[str, CoupledModel]):
        if not models:
            raise InputError("no day", parameter="date", expected="at least one date")
        self.day_models = dict(sorted(models.items()))
        self.dates = tuple(self.day_models)
        first = next(iter(self.day_models.values()))
        self.scenario = first.scenario
        for d, m in self.day_models.items():
            if m.scenario.theta.to_dict() != first.scenario.theta.to_dict():
                raise InputError(
                    f"leaf optics of {d} differ from {self.dates[0]}'s",
                    parameter="optics",
                    expected="the same leaf on every day",
                )
        self.times = pd.DatetimeIndex(np.concatenate([m.times.tz_convert("UTC") for m in self.day_models.values()]))
        if not self.times.is_monotonic_increasing or self.times.has_duplicates:
            raise InputError(
                f"the days' steps overlap ({', '.join(self.dates)})",
                parameter="date",
                expected="days whose windows do not overlap",
            )
        stamps = {m.timestamps for m in self.day_models.values()}
        if len(stamps) > 1:
            raise InputError(
                "the days' weather stamps differ (" + ", ".join(sorted(s.describe() for s in stamps)) + ")",
                column="time_label",
                expected="one time convention on every day",
            )
        #: what ``times`` label (every day's forcing has the same :class:`~lightfit.weather.timestamps.Timestamps`)
        self.timestamps = stamps.pop()
        self.day = np.concatenate([np.asarray(m.day, bool) for m in self.day_models.values()])
        self.n_steps = [len(m.times) for m in self.day_models.values()]
        #: the days' longest forcing step (observations between two steps this far apart are read
        #: between them; the night between two days is longer; 0 when every day has one step)
        self.step = max(m.step for m in self.day_models.values())

    @property
    def models(self) -> list[CoupledModel]:
        return list(self.day_models.values())

    def theta(self, theta: Theta | Mapping[str, float] | None = None) -> Theta:
        """``theta`` completed with the run's leaf defaults (the same on every day)."""
        return self.models[0].theta(theta)

    def compose(self, forwards: Sequence[Callable]) -> DaysForward:
        """One forward of the days' ``forwards`` (in date order)."""
        if len(forwards) != len(self.dates):
            raise InputError(
                f"{len(forwards)} forwards", parameter="forward", expected=f"one per day ({len(self.dates)})"
            )
        return DaysForward(self.dates, forwards)

    def observe(self, theta) -> dict:
        """Observables of every day at ``theta``, concatenated in time."""
        return self.compose([m.observe for m in self.models])(theta)

    def with_light(self, lights: Sequence) -> MultiDayModel:
        """The days' models with other light sources (one per day, e.g. their emulators)."""
        if len(lights) != len(self.dates):
            raise InputError(
                f"{len(lights)} light sources", parameter="light", expected=f"one per day ({len(self.dates)})"
            )
        return MultiDayModel({d: m.with_light(x) for (d, m), x in zip(self.day_models.items(), lights)})

    def mc_correlation(self, theta, names=None):
        """Each day's Monte Carlo correlation (:func:`~lightfit.inference.likelihood.mc_correlation`
        of its model at ``theta``), joined block-diagonally (:func:`block_correlation`)."""
        from lightfit.inference.likelihood import mc_correlation

        return block_correlation([mc_correlation(m, theta, names) for m in self.models])

    def split(self, obs: pd.DataFrame) -> dict[str, pd.DataFrame]:
        """The observations of each day: every row goes to the day of the step whose centre is
        nearest its own (as in :func:`~lightfit.inference.observations.align`; the day's own
        alignment then refuses rows more than half a step away)."""
        step, _ = nearest_steps(obs, self.times, self.timestamps)
        day_of = np.searchsorted(np.cumsum(self.n_steps), step, side="right")
        out = {}
        for k, d in enumerate(self.dates):
            part = obs[day_of == k]
            part.attrs = dict(obs.attrs)
            out[d] = part
        return out


def days_of(model) -> list:
    """The day models of ``model`` (a :class:`MultiDayModel`), or ``[model]``."""
    return model.models if isinstance(model, MultiDayModel) else [model]


def joined(model, per_day: Sequence):
    """Per-day forwards joined like ``model`` (:meth:`MultiDayModel.compose`), or the one forward."""
    return model.compose(per_day) if isinstance(model, MultiDayModel) else per_day[0]


def with_lights(model, lights: Sequence):
    """``model`` with a light source per day (:meth:`MultiDayModel.with_light`), or with ``lights[0]``."""
    return model.with_light(lights) if isinstance(model, MultiDayModel) else model.with_light(lights[0])


def block_correlation(corrs: Sequence):
    """Several days' :class:`~lightfit.inference.likelihood.MCCorrelation` (same series) as one over
    their concatenated steps: each day's block as it was, zero between days (their Monte Carlo errors
    are independent: different scenes). ``theta``: the first day's."""
    from lightfit.inference.likelihood import MCCorrelation

    names = corrs[0].names
    if any(c.names != names for c in corrs):
        raise InputError("days' correlations over different series", parameter="mc_correlation", expected=str(names))
    T = sum(c.n_steps for c in corrs)
    out = np.zeros((len(names) * T, len(names) * T))
    off = 0
    for c in corrs:
        # global index of (series i, day step t): i·T + off + t
        idx = np.concatenate([i * T + off + np.arange(c.n_steps) for i in range(len(names))])
        out[np.ix_(idx, idx)] = c.matrix
        off += c.n_steps
    return MCCorrelation(names, T, out, corrs[0].theta)


__all__ = [
    "DaysForward",
    "MultiDayModel",
    "block_correlation",
    "concat_observables",
    "days_of",
    "joined",
    "with_lights",
]
