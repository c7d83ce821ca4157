"""Several days in one calibration and one posterior (issue 15 item 4; lightfit.inference.multiday).

Quick field, the bundled real (undated) TERENO day placed on two dates, 11:00–12:00 local (3 steps
each): each day's plants are grown to its date and lit by its own sun.
"""

from __future__ import annotations

import dataclasses
import json

import jax.numpy as jnp
import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from lightfit import replication as rep
from lightfit.cli import app
from lightfit.errors import InputError
from lightfit.inference import posterior as A
from lightfit.inference.calibration import make_loss
from lightfit.inference.likelihood import GaussianLikelihood, mc_correlation, plug_in
from lightfit.inference.mcmc import load_run
from lightfit.inference.multiday import MultiDayModel, joined, with_lights
from lightfit.inference.observations import BY_NAME, write_observations
from lightfit.inference.twin import twin_observations
from lightfit.light.bsdf import LEAF_PARAMETERS
from lightfit.light.scene import Optics
from lightfit.model import emulator as E
from lightfit.model.parameters import Theta
from lightfit.weather.site import Window
from lightfit.weather.timestamps import INSTANTS

REAL_DAY = "selhausen-cplantbox-day"
DATES = ("2016-04-21", "2016-04-27")  # dates the undated CPlantBox day's light fits (data/README.md)
WINDOW = Window("11:00", 1.0)
USE = ("plant_par", "canopy_an")
TRUTH = Theta(specular=0.55, roughness=0.5, subsurface=0.7, light_factor=1.1)
SENSOR = BY_NAME["above_canopy_par"]


@pytest.fixture(scope="module")
def days():
    """Per date: the model with its light rendered once at the truth's leaf (light factor and Vcmax
    need no new render), and twin observations rendered at another seed (7) + noise, with the
    above-canopy sensor (analytic) beside them."""
    cfg = dataclasses.replace(rep.ReplicationConfig.quick(), dates=DATES, window=WINDOW)
    w = rep.forcing(REAL_DAY, dates=DATES, window=WINDOW)
    fixed, obs = {}, []
    for k, (d, wd) in enumerate(rep.days(cfg, w)):
        m = rep.model_for(dataclasses.replace(cfg, dates=(d,)), wd)
        parts = m.render(TRUTH)
        fixed[d] = m.with_light(lambda _, p=parts: p)
        o = twin_observations(m, TRUTH, render_seed=7, noise_seed=k)
        o[SENSOR.value] = np.asarray(fixed[d].observe(TRUTH)[SENSOR.value])
        o[SENSOR.sd] = 20.0
        obs.append(o)
    obs = pd.concat(obs)
    obs.attrs = {"source": "twin (test_multiday)", "provenance": "synthetic"}
    return fixed, obs


def test_multiday_likelihood_is_the_sum_of_the_days(days):
    """One likelihood over both days (block-diagonal Monte Carlo correlation) = the sum of the days'
    own likelihoods, each with its own correlation; the whitened residuals are the days' side by side."""
    fixed, obs = days
    multi = MultiDayModel(fixed)
    assert multi.dates == DATES and len(multi.times) == 6 and list(multi.n_steps) == [3, 3]
    corr = mc_correlation(multi, TRUTH, USE)
    singles = {d: mc_correlation(m, TRUTH, USE) for d, m in fixed.items()}
    # the days' blocks as they were, zero between the days
    c = corr.matrix.reshape(2, 6, 2, 6)
    for k, d in enumerate(DATES):
        np.testing.assert_array_equal(c[:, 3 * k : 3 * k + 3, :, 3 * k : 3 * k + 3].reshape(6, 6), singles[d].matrix)
    assert not c[:, :3, :, 3:].any()
    lik = GaussianLikelihood(obs, multi.times, USE, mc_correlation=corr, mc_scale=2.0)
    parts = multi.split(obs)
    own = {
        d: GaussianLikelihood(parts[d], m.times, USE, mc_correlation=singles[d], mc_scale=2.0) for d, m in fixed.items()
    }
    assert lik.n_observations == sum(x.n_observations for x in own.values()) == 12
    th = TRUTH.replace(light_factor=1.04, vcmax_scale=0.9)
    m_all = multi.observe(th)
    m_day = {d: m.observe(th) for d, m in fixed.items()}
    # the days' counts of unconverged blades travel with their observables (inference refuses on them)
    key = "unconverged_blades"
    assert np.asarray(m_all[key]).tolist() == [n for d in DATES for n in np.asarray(m_day[d][key]).tolist()]
    for lam in (1.0, 0.6):
        want = sum(float(x.log_likelihood(m_day[d], lam)) for d, x in own.items())
        assert float(lik.log_likelihood(m_all, lam)) == pytest.approx(want, rel=1e-10)
    assert float(lik.loss(m_all)) == pytest.approx(sum(float(x.loss(m_day[d])) for d, x in own.items()), rel=1e-10)
    w = np.asarray(lik.whitened(m_all)).reshape(2, 6)
    w_days = np.concatenate([np.asarray(own[d].whitened(m_day[d])).reshape(2, 3) for d in DATES], axis=1)
    np.testing.assert_allclose(w, w_days, rtol=1e-9, atol=1e-12)
    # make_loss computes the same correlation itself ("model") from the days' models, and holds the
    # Monte Carlo SDs of its reference point (the fixed values, TRUTH)
    loss = make_loss(multi, obs, ("light_factor",), TRUTH, use=USE, mc_correlation="model", mc_scale=2.0)
    held = plug_in(lik, multi.observe(TRUTH))
    assert float(loss.natural(jnp.asarray([1.04]))) == pytest.approx(
        float(lik.loss(multi.observe(TRUTH.replace(light_factor=1.04)), held)), rel=1e-10
    )
    # one leaf describes every day only if it is the same leaf
    grey = fixed[DATES[1]].with_light(None)  # a copy; its scenario replaced by the grey leaf's
    grey.scenario = dataclasses.replace(grey.scenario, optics=Optics.preset("paper"))
    with pytest.raises(InputError, match="leaf optics"):
        MultiDayModel({DATES[0]: fixed[DATES[0]], DATES[1]: grey})


@pytest.mark.slow  # 16 s alone (5 s after the test above), load 3: compiles the days' emulated forwards
def test_multiday_posterior_on_emulators_is_the_sum_of_the_days(days):
    """The posterior's two-date path on emulators, as ``lightfit posterior --date … --date …`` builds it
    (one emulator per day, :func:`joined` fast forwards, Monte Carlo correlation from the emulated days at
    the priors' centre): its log-likelihood equals the sum of the days' own single-day posteriors on the
    same emulators, each with its own correlation, to 1e-10, at points across the prior box."""
    fixed, obs = days
    multi = MultiDayModel(fixed)
    priors = A.prior_set("informed", multi.scenario.optics)
    lo, hi = ([priors[n].support[k] for n in LEAF_PARAMETERS] for k in (0, 1))
    # 5 renders per day (3 steps each), degree 1: enough to exercise the path; accuracy is not tested here
    emus = [E.build_emulator(m, lo, hi, n_design=5, degrees=(1,), seed=0) for m in multi.models]
    fasts = [E.FastObservables(m, e) for m, e in zip(multi.models, emus)]
    names = (*LEAF_PARAMETERS, "light_factor")
    kw = dict(names=names, use=USE, mc_scale=2.0)
    lp = A.log_posterior(multi, obs, joined(multi, fasts), light_model=with_lights(multi, emus), **kw)
    parts = multi.split(obs)
    own = [
        A.log_posterior(m, parts[d], f, light_model=m.with_light(e), **kw)
        for (d, m), f, e in zip(multi.day_models.items(), fasts, emus)
    ]
    assert lp.likelihood.n_observations == sum(o.likelihood.n_observations for o in own) == 12
    for x in (lp.center(), np.array([0.47, 0.35, 0.95, 0.9])):
        want = sum(float(o.log_likelihood(jnp.asarray(x))) for o in own)
        assert float(lp.log_likelihood(jnp.asarray(x))) == pytest.approx(want, rel=1e-10)


def test_two_dates_in_one_calibration_and_one_posterior(days, tmp_path, monkeypatch):
    """The command line takes several --date for calibrate and posterior: one model (and design
    directory) per date, one likelihood over both. Calibrating the light factor needs one render per
    day (exact; no emulator); the posterior of the above-canopy sensor alone renders nothing."""
    monkeypatch.setenv("LIGHTFIT_CACHE", str(tmp_path / "cache"))
    _, obs = days
    path = write_observations(obs, tmp_path / "obs.csv", {"provenance": "synthetic", "note": "test_multiday twin"})
    when = ["--weather", REAL_DAY, "--date", DATES[0], "--date", DATES[1], "--start-time", "11:00", "--hours", "1"]
    r = CliRunner().invoke(
        app,
        [
            "calibrate",
            str(path),
            "--quick",
            *when,
            "--parameters",
            "light_factor",
            "--mc-scale",
            "2",
            "--out",
            str(tmp_path / "cal"),
        ],
    )
    assert r.exit_code == 0, r.output
    cal = json.loads((tmp_path / "cal" / "calibration.json").read_text())
    assert cal["dates"] == list(DATES) and cal["config"]["dates"] == list(DATES)
    assert cal["likelihood"] == {"mc_correlation": "model", "mc_scale": 2.0}
    sur = cal["surrogate"]
    assert sur["mode"] == "one render" and sur["renders_new"] == 2 and len(sur["design_dir"]) == 2
    assert sur["sun_positions_rendered"] == 6
    # the twin's light factor (1.1) from both days; the model renders at its own seed (0), the twin at 7
    assert cal["theta"]["light_factor"] == pytest.approx(TRUTH.light_factor, abs=0.05)
    post = ["posterior", str(path), "--quick", *when, "--parameters", "light_factor", "--use", "above_canopy_par"]
    post += ["--walkers", "4", "--max-steps", "10", "--n-test", "0", "--no-analysis", "--out", str(tmp_path / "post")]
    r = CliRunner().invoke(app, post)
    assert r.exit_code == 0, r.output
    run = load_run(tmp_path / "post" / "run.h5")
    assert run["chain"].shape == (10, 4, 1)
    assert run["attrs"]["scenario"]["dates"] == list(DATES) and sorted(run["attrs"]["emulator_key"]) == list(DATES)
    assert all((tmp_path / "post" / f"emulator-{d}.npz").exists() for d in DATES)
    # resuming with another likelihood form is refused, before any plant grows
    r = CliRunner().invoke(app, [*post, "--mc-correlation", "independent"])
    assert r.exit_code == 2 and "another likelihood (mc_correlation: 'model' → 'independent')" in r.stderr


class _Day:
    """What :class:`MultiDayModel` reads of a day's model (no plants, no render)."""

    def __init__(self, start: str, n: int = 3):
        self.times = pd.date_range(start, periods=n, freq="30min", tz="UTC")
        self.timestamps = INSTANTS
        self.step = pd.Timedelta("30min")
        self.day = np.ones(n, bool)
        self.scenario = type("S", (), {"theta": Theta()})()


def test_days_are_joined_in_date_order_and_may_not_overlap():
    """Days given out of order are joined in date order (their steps then increase); two days whose
    steps share a stamp are refused as overlapping, as are two whose windows interleave (a mutation
    audit: dropping the sort, or the duplicate-stamp check, survived; no test built such days)."""
    a, b = _Day("2016-04-21 10:00"), _Day("2016-04-27 10:00")
    m = MultiDayModel({"2016-04-27": b, "2016-04-21": a})
    assert m.dates == ("2016-04-21", "2016-04-27") and m.models == [a, b]
    assert list(m.times) == [*a.times, *b.times] and m.n_steps == [3, 3]
    # day two starting on day one's last stamp: one step twice
    with pytest.raises(InputError, match="overlap"):
        MultiDayModel({"x": _Day("2016-04-21 10:00"), "y": _Day("2016-04-21 11:00")})
    with pytest.raises(InputError, match="overlap"):
        MultiDayModel({"x": _Day("2016-04-21 10:00"), "y": _Day("2016-04-21 10:15")})


def test_an_undated_file_placed_on_two_dates_names_both():
    """The bundled undated day placed on two dates: the forcing's ``date_given`` (the figures' titles,
    results.nc's ``weather_date_given``) named the first date alone (a review); each date now, as
    ``provenance_label`` prints it. One date keeps its one date."""
    from lightfit.weather.plot import provenance_label

    both = rep.forcing(REAL_DAY, dates=DATES, window=WINDOW)
    assert both.attrs["date_given"] == "; ".join(DATES)
    assert provenance_label(both.attrs).endswith(f"(undated file placed on {DATES[0]}; {DATES[1]})")
    assert rep.forcing(REAL_DAY, dates=DATES[:1], window=WINDOW).attrs["date_given"] == DATES[0]
