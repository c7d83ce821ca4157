"""Observations between two steps meet the model interpolated linearly in time.

References: interval arithmetic by hand (which steps, what weight), a model linear in time (read
exactly at the readings' times), scipy's multivariate normal on a covariance built from the
definitions, and the interpolated error's covariance A Σ Aᵀ written out from the readings' times.
The chamber record against the bundled forcing is in
``tests/test_observe.py::test_light_factor_from_the_chamber_record_is_near_one``.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd
import pytest
from scipy.stats import multivariate_normal

from lightfit.inference.likelihood import GaussianLikelihood, MCCorrelation, correlation_of, observations_digest
from lightfit.inference.observations import (
    BY_NAME,
    SERIES,
    interpolated,
    interpolation,
    matched_as_by_stamp,
    observation_matching,
)
from lightfit.model import schema
from lightfit.weather.timestamps import INSTANTS, Timestamps

PAR, AN = BY_NAME["above_canopy_par"], BY_NAME["canopy_an"]
STEPS = pd.date_range("2016-04-20 10:00", periods=4, freq="30min", tz="UTC")  # 10:00 … 11:30


def _obs(times, values, sds, s=PAR):
    return pd.DataFrame({s.value: values, s.sd: sds}, index=pd.DatetimeIndex(times, tz="UTC"))


def test_weights_are_the_readings_place_between_their_two_steps():
    obs = _obs(
        ["2016-04-20 10:13:48", "2016-04-20 10:50:00", "2016-04-20 11:00:00", "2016-04-20 11:40:00"],
        [1.0, 2.0, 3.0, 4.0],
        [1.0, 1.0, 1.0, 1.0],
    )
    nb, w = interpolation(obs, STEPS)[PAR.value]
    # 10:13:48 → step 0 (13.8 min away), read towards step 1: 828 s of 1 800. 10:50 and 11:00 both
    # → step 2 (11:00), equal SDs: read at their mean time 10:55, towards step 1: 300 s. Step 1 has
    # no reading. 11:40 lies after the last step: its nearest step, not extrapolated.
    np.testing.assert_array_equal(nb, [1, 1, 1, 3])
    np.testing.assert_allclose(w, [828 / 1800, 0.0, 300 / 1800, 0.0], rtol=1e-12)
    assert interpolated(obs, STEPS)
    # the other series, absent from the file: every step its own
    nb_an, w_an = interpolation(obs, STEPS)[AN.value]
    np.testing.assert_array_equal(nb_an, np.arange(4))
    assert not w_an.any()


def test_several_readings_in_a_step_are_read_at_their_inverse_variance_mean_time():
    obs = _obs(["2016-04-20 10:05:00", "2016-04-20 10:10:00"], [1.0, 2.0], [1.0, 2.0])
    nb, w = interpolation(obs, STEPS)[PAR.value]
    # weights 1 and 1/4: (300 + 600/4) / 1.25 = 360 s after 10:00
    assert nb[0] == 1 and w[0] == pytest.approx(360 / 1800, rel=1e-12)
    before = _obs(["2016-04-20 10:20:00"], [1.0], [1.0])  # nearest 10:30, towards 10:00
    nb, w = interpolation(before, STEPS)[PAR.value]
    assert nb[1] == 0 and w[1] == pytest.approx(600 / 1800)


def test_no_interpolation_for_means_on_steps_or_across_a_gap():
    spot = _obs(["2016-04-20 10:13:48"], [1.0], [1.0])
    end30 = Timestamps("end", pd.Timedelta("30min"))
    for obs, stamps in ((spot, end30), (spot.iloc[:0], INSTANTS)):
        assert not interpolated(obs, STEPS, stamps)
    on = _obs(["2016-04-20 10:30:00"], [1.0], [1.0])
    assert not interpolated(on, STEPS)
    assert observation_matching(on, STEPS, INSTANTS) == "instants to instants, by interval centre"
    assert matched_as_by_stamp(on, STEPS, INSTANTS)
    assert observation_matching(spot, STEPS, INSTANTS) == "instants to instants, interpolated linearly in time"
    assert not matched_as_by_stamp(spot, STEPS, INSTANTS)
    # two days: the reading after day 1's last step is not read towards day 2's first
    two_days = STEPS.append(STEPS + pd.Timedelta("1D"))
    late = _obs(["2016-04-20 11:40:00"], [1.0], [1.0])
    assert not interpolated(late, two_days)
    # a restricted run (a step and its neighbour kept, another day's step far away) still reads both
    cut = pd.DatetimeIndex([STEPS[0], STEPS[1], STEPS[3] + pd.Timedelta("1D")])
    nb, w = interpolation(spot, cut)[PAR.value]
    assert nb[0] == 1 and w[0] == pytest.approx(828 / 1800)


def _linear_model(a, b, s):
    t = np.asarray((STEPS - STEPS[0]).total_seconds(), float)
    return {PAR.value: jnp.asarray(a + b * t), PAR.mc_sd: jnp.asarray(s)}


def test_a_model_linear_in_time_is_read_exactly_at_the_readings():
    times = ["2016-04-20 10:13:48", "2016-04-20 10:50:00", "2016-04-20 11:30:00"]
    t = np.asarray((pd.DatetimeIndex(times, tz="UTC") - STEPS[0]).total_seconds(), float)
    a, b = 1500.0, 0.05
    obs = _obs(times, a + b * t, [10.0, 10.0, 10.0])
    s = np.array([3.0, 4.0, 5.0, 6.0])
    lik = GaussianLikelihood(obs, STEPS, ("above_canopy_par",))
    assert lik.interpolated
    m = _linear_model(a, b, s)
    assert float(lik.loss(m)) == pytest.approx(0.0, abs=1e-20)
    # log L against scipy: residuals 0; Σ = diag(σ²) + A diag(s²) Aᵀ (independent steps, but the
    # first two readings both read step 1)
    w0, w2 = 828 / 1800, 600 / 1800
    a_read = np.array([[1 - w0, w0, 0, 0], [0, w2, 1 - w2, 0], [0, 0, 0, 1.0]])
    cov = np.diag([100.0, 100.0, 100.0]) + a_read @ np.diag(s**2) @ a_read.T
    want = multivariate_normal(np.zeros(3), cov).logpdf(np.zeros(3))
    for f in (lik.log_likelihood, jax.jit(lik.log_likelihood)):
        assert float(f(m, 1.0)) == pytest.approx(want, rel=1e-12)
    # the model 7 too high everywhere: bias 7, and χ² = 7² 1ᵀΣ⁻¹1 with the readings' shared step
    fit = lik.series_fit(_linear_model(a + 7.0, b, s)).loc["above_canopy_par"]
    assert fit.n == 3 and fit.bias == pytest.approx(7.0) and fit.rmse == pytest.approx(7.0)
    assert fit.chi2 == pytest.approx(49.0 * np.sum(np.linalg.solve(cov, np.ones(3))), rel=1e-12)
    # read at the nearest steps instead, the morning's rise would be a residual of 828 s × b
    shifted = _obs([STEPS[0], STEPS[2], STEPS[3]], a + b * t, [10.0, 10.0, 10.0])
    off = GaussianLikelihood(shifted, STEPS, ("above_canopy_par",))
    assert not off.interpolated
    assert float(off.loss(m)) == pytest.approx(0.5 * ((828 * b) ** 2 / 109 + (600 * b) ** 2 / 125), rel=1e-12)


def test_means_on_a_run_of_instants_are_read_at_their_centres():
    """A mean over (10:00, 10:30] against instants at 10:00 and 10:30 meets their average, the
    trapezoid rule's mean over its interval, exact for a model linear in time; it met the earlier
    step, the model 15 min before the mean's centre (an inference review: on a morning's rise,
    200 against a true mean of 300). A 10-min mean ending 10:50 is read at 10:45."""
    end30, end10 = Timestamps("end", pd.Timedelta("30min")), Timestamps("end", pd.Timedelta("10min"))
    a, b = 1500.0, 0.05
    s = np.array([3.0, 4.0, 5.0, 6.0])
    for stamps, times, centres_s in (
        (end30, ["2016-04-20 10:30:00", "2016-04-20 11:00:00"], [900.0, 2700.0]),
        (end10, ["2016-04-20 10:50:00"], [2700.0]),
    ):
        obs = _obs(times, a + b * np.array(centres_s), [10.0] * len(times))
        obs.attrs["timestamps"] = stamps
        nb, w = interpolation(obs, STEPS)[PAR.value]
        assert np.count_nonzero(w) == len(times) and np.all(w[w > 0] == 0.5)
        lik = GaussianLikelihood(obs, STEPS, ("above_canopy_par",))
        assert lik.interpolated and "interpolated linearly in time" in observation_matching(obs, STEPS, INSTANTS)
        assert float(lik.loss(_linear_model(a, b, s))) == pytest.approx(0.0, abs=1e-20)


def test_correlated_monte_carlo_error_is_carried_through_the_interpolation():
    """Σ_MC of the readings = A diag(s) C diag(s) Aᵀ, with A written out from the readings' times;
    log L against scipy on that covariance; gradients finite and equal to central differences, with
    and without jit."""
    rng = np.random.default_rng(3)
    times = ["2016-04-20 10:13:48", "2016-04-20 10:40:00", "2016-04-20 11:20:00"]
    obs = _obs(times, [1520.0, 1600.0, 1650.0], [8.0, 9.0, 10.0])
    x = rng.standard_normal((4, 2))
    corr = MCCorrelation(("above_canopy_par",), 4, correlation_of(x @ x.T + 0.1 * np.eye(4)))
    s = np.array([3.0, 4.0, 5.0, 6.0])
    m = _linear_model(1500.0, 0.04, s)
    lik = GaussianLikelihood(obs, STEPS, ("above_canopy_par",), mc_correlation=corr, mc_scale=2.0)
    # the readings as linear maps of the steps' errors: 10:13:48 is 828 s of 1 800 from step 0 to
    # step 1, 10:40 600 s from step 1 to 2, 11:20 1 200 s from step 2 to 3
    a_read = np.array(
        [
            [1 - 828 / 1800, 828 / 1800, 0.0, 0.0],
            [0.0, 1 - 600 / 1800, 600 / 1800, 0.0],
            [0.0, 0.0, 1 - 1200 / 1800, 1200 / 1800],
        ]
    )
    want_mc = a_read @ (np.outer(s, s) * corr.matrix) @ a_read.T
    got = np.asarray(lik.mc_covariance(m))
    # exact linear algebra (a 200 000-draw sample covariance at 2 % before: it passed weights
    # rounded to whole minutes); float64 round-off only
    np.testing.assert_allclose(got, want_mc, rtol=1e-12, atol=1e-12 * want_mc.max())
    sd_read = np.asarray(lik.mc_sd_read(m)["above_canopy_par"])  # the readings sit at steps 0, 1, 3
    np.testing.assert_allclose(sd_read[[0, 1, 3]], np.sqrt(np.diag(got)), rtol=1e-12)
    assert sd_read[2] == 0.0
    # log L against scipy with the covariance from the definitions
    y = obs[PAR.value].to_numpy()
    t = np.asarray((pd.DatetimeIndex(times, tz="UTC") - STEPS[0]).total_seconds(), float)
    r = y - (1500.0 + 0.04 * t)
    for lam in (1.0, 0.6):
        want = multivariate_normal(np.zeros(3), np.diag((lam * obs[PAR.sd].to_numpy()) ** 2) + 2.0 * want_mc).logpdf(r)
        assert float(lik.log_likelihood(m, lam)) == pytest.approx(want, rel=1e-9)
        w = np.asarray(lik.whitened(m, lam))
        assert 0.5 * np.sum(w**2) == pytest.approx(
            0.5 * r @ np.linalg.solve(np.diag((lam * obs[PAR.sd].to_numpy()) ** 2) + 2.0 * want_mc, r), rel=1e-9
        )

    def f(shift):
        mm = dict(m)
        mm[PAR.value] = m[PAR.value] + shift
        return lik.log_likelihood(mm, 1.0)

    for g in (jax.grad(f), jax.jit(jax.grad(f))):
        d = g(jnp.zeros(4))
        h = 1e-4
        fd = [(float(f(h * np.eye(4)[k])) - float(f(-h * np.eye(4)[k]))) / (2 * h) for k in range(4)]
        assert np.all(np.isfinite(np.asarray(d)))
        np.testing.assert_allclose(np.asarray(d), fd, rtol=1e-6, atol=1e-9)


def test_on_the_steps_nothing_changes():
    """Readings on the steps: no interpolation, and the digest is the one stored before it."""
    obs = _obs(STEPS[[0, 2]], [1500.0, 1600.0], [10.0, 10.0])
    lik = GaussianLikelihood(obs, STEPS, ("above_canopy_par",))
    assert not lik.interpolated
    m = _linear_model(1490.0, 0.0, np.ones(4))
    assert float(lik.loss(m)) == pytest.approx(0.5 * (10**2 + 110**2) / 101, rel=1e-14)
    between = _obs(STEPS[[0, 2]] + pd.Timedelta("5min"), [1500.0, 1600.0], [10.0, 10.0])
    assert observations_digest(GaussianLikelihood(between, STEPS), STEPS) != observations_digest(lik, STEPS)


def test_every_series_has_its_offset_in_the_results_schema():
    for s in SERIES:
        assert schema.variable(f"obs_{s.name}_time_offset_s").units == "s"


def test_a_calibration_renders_the_neighbour_a_reading_is_interpolated_from():
    """observed_model keeps (and renders, for a series that needs light) the step on the far side
    of a reading, and the cut model's likelihood still reads between the two."""
    from lightfit.inference.trust_region import observed_model
    from lightfit.model.coupled import CoupledModel
    from lightfit.model.scenario import Scenario
    from lightfit.plant import Field
    from lightfit.replication import forcing

    w = forcing().iloc[14:18]  # 12:00, 12:30, 13:00, 13:30 local (10:00 … 11:30 UTC)
    sc = Scenario(weather=w, field=Field(boundary="finite", n_plants=4, buffer_rows=1, seed=1), samples=8)
    model = CoupledModel(sc)
    plant = BY_NAME["plant_par"]
    obs = pd.concat(
        [
            _obs(["2016-04-20 10:10:00"], [400.0], [20.0], s=plant),  # between 12:00 and 12:30 local
            _obs(["2016-04-20 11:30:00"], [1600.0], [50.0]),  # the above-canopy sensor, on 13:30
        ]
    ).sort_index()
    obs.attrs = {"source": "test", "provenance": "synthetic"}
    cut, _, n_rendered = observed_model(model, obs, ("plant_par", "above_canopy_par"))
    assert list(cut.times) == list(w.index[[0, 1, 3]])  # 13:00 dropped; 12:30 kept for the reading
    assert cut.step == model.step == pd.Timedelta("30min")  # the cut run keeps the forcing's step
    assert n_rendered == 2 and list(np.asarray(cut.day, bool)) == [True, True, False]  # the sensor renders nothing
    lik = GaussianLikelihood(obs, cut.times, ("plant_par", "above_canopy_par"), stamps=cut.timestamps, step=cut.step)
    assert int(lik.neighbour["plant_par"][0]) == 1 and float(lik.weight["plant_par"][0]) == pytest.approx(1 / 3)
    assert not np.asarray(lik.weight["above_canopy_par"]).any()


def test_independent_steps_still_share_a_step_between_two_readings():
    """Two readings read from the same two steps share their Monte Carlo errors even when the steps'
    errors are independent: Σ_MC = A diag(s²) Aᵀ, the form with the identity as correlation
    (a review's case: 10:10 and 10:20 against 30-min steps)."""
    obs = _obs(["2016-04-20 10:10:00", "2016-04-20 10:20:00"], [1510.0, 1530.0], [8.0, 8.0])
    s = np.array([5.0, 10.0, 3.0, 3.0])
    m = _linear_model(1500.0, 0.02, s)
    ind = GaussianLikelihood(obs, STEPS, ("above_canopy_par",))
    eye = GaussianLikelihood(
        obs, STEPS, ("above_canopy_par",), mc_correlation=MCCorrelation(("above_canopy_par",), 4, np.eye(4))
    )
    w = 1 / 3  # 10:10 → step 0, read towards 1; 10:20 → step 1 (10:30), read towards 0
    a = np.array([[1 - w, w], [w, 1 - w]])  # rows: readings, columns: steps 0, 1
    want = a @ np.diag(s[:2] ** 2) @ a.T
    for lik in (ind, eye):
        assert lik.dense
        np.testing.assert_allclose(np.asarray(lik.mc_covariance(m)), want, rtol=1e-12)
    assert float(ind.log_likelihood(m, 0.7)) == pytest.approx(float(eye.log_likelihood(m, 0.7)), rel=1e-12)


def test_a_step_no_reading_needs_cannot_spoil_the_likelihood():
    """A non-finite Monte Carlo SD at a step neither holding nor neighbouring a reading stays out."""
    obs = _obs(["2016-04-20 10:10:00"], [1510.0], [8.0])
    for bad in (np.inf, np.nan):
        s = np.array([5.0, 10.0, 3.0, bad])
        m = _linear_model(1500.0, 0.02, s)
        for corr in (None, MCCorrelation(("above_canopy_par",), 4, np.eye(4))):
            lik = GaussianLikelihood(obs, STEPS, ("above_canopy_par",), mc_correlation=corr)
            assert np.isfinite(float(lik.log_likelihood(m, 1.0)))
            g = jax.grad(lambda x: lik.log_likelihood({**m, PAR.value: m[PAR.value] + x}, 1.0))(jnp.zeros(4))
            assert np.all(np.isfinite(np.asarray(g)))


def test_only_the_used_series_decide_how_observations_meet_the_steps():
    """A series left out of the likelihood (here above-canopy PAR between two steps) does not make the
    run's matching 'interpolated' (a state stored before would be refused for nothing)."""
    plant = BY_NAME["plant_par"]
    obs = pd.concat(
        [_obs(["2016-04-20 10:30:00"], [400.0], [20.0], s=plant), _obs(["2016-04-20 10:13:48"], [1.0], [1.0])]
    )
    assert interpolated(obs, STEPS) and not interpolated(obs, STEPS, use=("plant_par",))
    assert matched_as_by_stamp(obs, STEPS, INSTANTS, use=("plant_par",))
    assert observation_matching(obs, STEPS, INSTANTS, use=("plant_par",)).endswith("by interval centre")


def test_a_cut_run_keeps_its_own_step():
    """Two days cut to one step each (the gap between them a night): with the run's 30-min step a
    reading after day 1's last step is not read towards day 2; the gap alone would have allowed it."""
    cut = pd.DatetimeIndex(["2016-04-20 11:30", "2016-04-21 10:00"], tz="UTC")
    late = _obs(["2016-04-20 11:40:00"], [1.0], [1.0])
    assert interpolated(late, cut)  # the cut times alone: their shortest spacing is the night
    assert not interpolated(late, cut, step=pd.Timedelta("30min"))
    assert not GaussianLikelihood(late, cut, step=pd.Timedelta("30min")).interpolated
    # several days of one step each (step 0): nothing is read between them
    one = _obs(["2016-04-20 11:50:00"], [1.0], [1.0])
    assert not interpolated(one, cut, step=pd.Timedelta(0))
