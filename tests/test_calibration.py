"""Observations files, twin observations and gradient calibration (lightfit.inference)."""

import dataclasses
import json
import math
from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd
import pytest

from lightfit import replication as rep
from lightfit.errors import InputError
from lightfit.inference.calibration import calibrate, from_unconstrained, make_loss, to_unconstrained
from lightfit.inference.observations import COLUMNS, align, read_observations, write_observations
from lightfit.inference.twin import par_sd_relative, twin_observations
from lightfit.model.parameters import Theta

HEADER = "time," + ",".join(COLUMNS) + "\n"
TRUTH = Theta(specular=0.7, roughness=0.4, subsurface=0.6)


@pytest.fixture(scope="module")
def short_model():
    """Quick configuration on a 3-hour window around noon (7 steps)."""
    w = rep.forcing()
    w = w.loc["2016-04-20 09:00+00:00":"2016-04-20 12:00+00:00"]
    return rep.model_for(rep.ReplicationConfig.quick(), w)


def test_end_to_end_gradient_matches_central_differences(short_model):
    obs = twin_observations(short_model, TRUTH.replace(subsurface=0.5), render_seed=3, noise_seed=1)
    names = ("specular", "subsurface", "light_factor", "vcmax_scale")
    loss = make_loss(short_model, obs, names)
    z = jnp.asarray([to_unconstrained(v, n) for v, n in zip((0.45, 0.35, 1.1, 0.9), names)])
    g = np.asarray(jax.grad(lambda z: loss(z)[0])(z))
    h = 1e-3
    fd = [(float(loss(z.at[i].add(h))[0]) - float(loss(z.at[i].add(-h))[0])) / (2 * h) for i in range(len(names))]
    # Fixed seed + frozen sampling: the loss is smooth in θ and reverse-mode is its exact gradient
    # (up to float32 rendering). Each component gets its own relative
    # tolerance: the components span two orders of magnitude (light_factor ≈ 760, subsurface ≈ 1.7),
    # so a tolerance scaled by the largest one would leave the small leaf-optics gradients unchecked.
    # Measured agreement ≈ 3e-4 relative per component; 1e-2 leaves a 30-fold margin.
    for n, gi, fi in zip(names, g, fd):
        assert abs(fi) > 0.5, (n, fi)  # every component is a real, non-zero derivative
        assert gi == pytest.approx(fi, rel=1e-2), (n, gi, fi)


@pytest.fixture(scope="module")
def twin_model():
    """Quick field with K = 128 samples on 10:00–11:00 UTC (3 steps): the Monte Carlo error of the
    renders is correlated across steps, so more samples (not more steps) make specular identifiable.

    Photosynthesis set giraud2023: its blades are electron-transport limited all day, so canopy An
    follows absorbed light and carries information on specular (SD ≈ 0.07); with winter_wheat, whose
    sunlit blades saturate, the same three steps constrain specular only to SD ≈ 0.15, too wide to
    test recovery from a start at 0.3. The test is about the optimisers, not the set.

    Leaf optics: the paper's grey leaf (base colour 0.5). The default PROSPECT-D leaf reflects only
    ≈ 6 % of PAR, so specular (the glossy 4 % of it) moves absorbed light far less: with it the same
    twin constrains specular only to SD ≈ 0.29. Hence the whole ``paper`` preset's leaf and set."""
    w = rep.forcing().loc["2016-04-20 10:00+00:00":"2016-04-20 11:00+00:00"]
    cfg = dataclasses.replace(rep.ReplicationConfig.quick(), samples=128, photosynthesis="giraud2023", optics="paper")
    return rep.model_for(cfg, w)


@pytest.fixture(scope="module")
def twin_fits(twin_model, tmp_path_factory):
    """Specular calibrated from 0.3 by both optimisers against twin observations rendered with
    ANOTHER seed (3; the model renders with 0), so the renders' Monte Carlo errors differ as with real data."""
    assert twin_model.scenario.seed != 3
    obs = twin_observations(
        twin_model, TRUTH, render_seed=3, noise_seed=2, par_sd=par_sd_relative(0.01), an_sd_umol_m2_s=0.3
    )
    fixed = {"roughness": TRUTH.roughness, "subsurface": TRUTH.subsurface}
    hist = tmp_path_factory.mktemp("twin") / "h.jsonl"
    start = {"specular": 0.3}
    fits = {
        m: calibrate(
            twin_model,
            obs,
            names=("specular",),
            start=start,
            fixed=fixed,
            method=m,
            history=hist if m == "bfgs" else None,
            progress=False,
        )
        for m in ("bfgs", "lbfgsb")
    }
    return obs, fits, hist


def _specular_sd(model, obs) -> float:
    """SD of the fitted specular implied by the measurement SDs σ and the Monte Carlo SDs s.

    Linearised weighted least squares with weights 1/v, v = σ² + s²: the estimate moves by
    δx = Σ J v⁻¹ δm / Σ J² v⁻¹ (J = ∂m/∂specular by central differences). Measurement noise is
    independent per step (variance σ²); the Monte Carlo difference between the two renders (SD √2·s)
    is taken as fully correlated across steps (same geometry, slowly moving sun): the worst case.
    """
    h = 0.02
    up, down, mid = (model.observe(TRUTH.replace(specular=TRUTH.specular + d)) for d in (h, -h, 0.0))
    target = align(obs, model.times)
    den, var_noise, mc_shift = 0.0, 0.0, 0.0
    for v, sd, mc in (
        ("plant_par_umol_m2_s", "plant_par_sd_umol_m2_s", "plant_par_mc_sd_umol_m2_s"),
        ("canopy_an_umol_m2_s", "canopy_an_sd_umol_m2_s", "canopy_an_mc_sd_umol_m2_s"),
    ):
        ok = ~np.isnan(target[v])
        J = ((np.asarray(up[v]) - np.asarray(down[v])) / (2 * h))[ok]
        sig, s = target[sd][ok], np.asarray(mid[mc])[ok]
        w = J / (sig**2 + s**2)
        den += np.sum(w * J)
        var_noise += np.sum(w**2 * sig**2)
        mc_shift += np.sum(np.abs(w) * np.sqrt(2) * s)
    return float(np.hypot(np.sqrt(var_noise), mc_shift) / den)


@pytest.mark.parametrize("box", [(0.6, 0.9), (0.2, 1.0), (0.0, 1.0), (0.5, math.inf), (0.0, math.inf)])
def test_the_unconstrained_coordinates_invert_inside_any_box(box):
    """z ↔ x for a box with lo ≠ 0 too (an emulator's or the user's; every default box starts at 0,
    where a transform that dropped lo still inverted: a mutation audit): x comes back to 1e-12, and
    every z, however large, maps inside the box, so a search cannot leave it."""
    lo, hi = box
    name = "light_factor" if math.isinf(hi) else "specular"
    bounds = {name: box}
    xs = [lo + 0.01, lo + 0.3 * (min(hi, lo + 2) - lo), min(hi, lo + 2) - 0.01]
    for x in xs:
        z = to_unconstrained(x, name, bounds)
        assert float(from_unconstrained(z, name, bounds)) == pytest.approx(x, abs=1e-12)
    ends = [float(from_unconstrained(z, name, bounds)) for z in (-30.0, 0.0, 30.0)]
    assert lo <= ends[0] < ends[1] < ends[2] <= hi
    if not math.isinf(hi):
        assert ends[1] == pytest.approx((lo + hi) / 2, abs=1e-15)


def test_twin_calibration_recovers_specular(twin_model, twin_fits):
    obs, fits, hist = twin_fits
    res = fits["bfgs"]
    sd = _specular_sd(twin_model, obs)  # ≈ 0.07
    assert 3 * sd < TRUTH.specular - 0.3  # the check below means something: the start is > 3 SD away
    assert res.converged and res.steps >= 2 and res.gradients == res.steps <= res.evaluations
    # truth within 3 SDs of the estimate (measurement noise + the two renders' Monte Carlo errors)
    assert abs(res.theta["specular"] - TRUTH.specular) <= 3 * sd, (res.theta["specular"], sd)
    *lines, final = [json.loads(x) for x in hist.read_text().splitlines()]  # steps, then the stop record
    assert final["stopped_by"] == res.stopped_by == "converged" and final["steps"] == res.steps
    assert len(lines) == res.steps and lines[-1]["loss"] <= lines[0]["loss"]
    assert lines[-1]["evaluations"] == res.evaluations and lines[0]["coordinates"] == "unconstrained"


def test_bfgs_and_lbfgsb_reach_the_same_optimum(twin_fits):
    _, fits, _ = twin_fits
    a, b = fits["bfgs"], fits["lbfgsb"]
    assert a.method == "bfgs" and b.method == "lbfgsb" and a.converged and b.converged
    assert b.theta["specular"] == pytest.approx(a.theta["specular"], abs=2e-3)
    assert b.loss == pytest.approx(a.loss, rel=1e-4)
    assert b.theta["roughness"] == TRUTH.roughness and b.theta["light_factor"] == 1.0


def test_calibration_resumes_from_history(short_model, tmp_path):
    obs = twin_observations(short_model, {"specular": 0.7}, render_seed=5, noise_seed=3)
    h = tmp_path / "h.jsonl"

    def run(max_steps: int, resume: bool):
        return calibrate(
            short_model,
            obs,
            names=("specular",),
            start={"specular": 0.2},
            max_steps=max_steps,
            history=h,
            resume=resume,
            progress=False,
        )

    first = run(2, resume=False)
    assert first.stopped_by == "max_steps" and first.steps == 2 and not first.converged
    n_first = len(h.read_text().splitlines())
    # A line cut by an interruption is ignored; finished steps are kept and continued from.
    with open(h, "a") as f:
        f.write('{"step": 99, "loss": 0.1, "the')
    second = run(3, resume=True)
    *lines, final = [json.loads(x) for x in h.read_text().splitlines()]  # the cut line is gone, all others parse
    assert len(lines) == n_first - 1 + second.steps - first.steps > n_first - 1
    assert [r["step"] for r in lines] == list(range(1, len(lines) + 1))
    assert final["stopped_by"] == second.stopped_by and final["steps"] == second.steps == 3
    assert final["evaluations"] == second.evaluations >= lines[-1]["evaluations"]
    assert second.loss <= first.loss + 1e-9


def test_observation_file_round_trip_and_alignment(tmp_path):
    times = pd.date_range("2016-04-20 09:00", periods=5, freq="30min", tz="UTC")
    df = pd.DataFrame(
        {
            "plant_par_umol_m2_s": [100.0, np.nan, 300.0, 310.0, 400.0],
            "plant_par_sd_umol_m2_s": [5.0, np.nan, 5, 5, 5],
            "canopy_an_umol_m2_s": [np.nan, 2.0, 3.0, np.nan, 4.0],
            "canopy_an_sd_umol_m2_s": [np.nan, 0.5, 0.5, np.nan, 0.5],
        },
        index=times + pd.Timedelta("2min"),
    )
    p = write_observations(df, tmp_path / "obs.csv", {"provenance": "synthetic"})
    back = read_observations(p)
    assert back.attrs["provenance"] == "synthetic"
    a = align(back, times)
    assert a["plant_par_umol_m2_s"][0] == 100.0 and np.isnan(a["plant_par_umol_m2_s"][1])
    assert a["canopy_an_umol_m2_s"][1] == 2.0
    # Two observations in one step: their inverse-variance weighted mean (equal SDs: the plain mean).
    two = pd.concat([df.iloc[[2]], df.iloc[[2]].assign(plant_par_umol_m2_s=320.0)])
    two.index = [times[2], times[2] + pd.Timedelta("5min")]
    two.attrs = {"source": "x"}
    a2 = align(two, times)
    assert a2["plant_par_umol_m2_s"][2] == pytest.approx(310.0)
    assert a2["plant_par_sd_umol_m2_s"][2] == pytest.approx(5 / np.sqrt(2))
    unequal = two.assign(plant_par_sd_umol_m2_s=[1.0, 10.0])  # 300 ± 1 and 320 ± 10
    unequal.attrs = {"source": "x"}
    a3 = align(unequal, times)
    assert a3["plant_par_umol_m2_s"][2] == pytest.approx((300.0 + 320.0 / 100) / (1 + 1 / 100))
    assert a3["plant_par_sd_umol_m2_s"][2] == pytest.approx((1 + 1 / 100) ** -0.5)
    late = df.iloc[[0]].copy()
    late.index = [times[-1] + pd.Timedelta("3h")]
    late.attrs = {"source": "late.csv"}
    with pytest.raises(InputError, match="outside the run"):
        align(late, times)


@pytest.mark.parametrize(
    "body, match",
    [
        ("time,plant_par_umol_m2_s,plant_par_sd_umol_m2_s,canopy_an_umol_m2_s\n", "missing column"),
        (HEADER + "soon,1,1,,\n", "cannot parse time"),
        (HEADER + "2016-04-20 10:00,bright,1,,\n", "not a (finite )?number"),
        (HEADER + "2016-04-20 10:00,100,,,\n", "standard deviation"),
        (HEADER + "2016-04-20 10:00,-5,1,,\n", "negative value of plant_par_umol_m2_s"),
    ],
)
def test_bad_observation_files(tmp_path, body, match):
    p = tmp_path / "o.csv"
    p.write_text("# provenance: measured\n# time_zone: UTC\n" + body)
    with pytest.raises(InputError, match=match):
        read_observations(p)
    q = tmp_path / "noprov.csv"
    q.write_text(body)
    with pytest.raises(InputError, match="provenance"):
        read_observations(q)


def test_observation_times_need_a_zone_and_are_unique(tmp_path):
    """Times without an offset need ``# time_zone`` (a local chamber log read as UTC would move every
    reading by hours); times with an offset are read as written; a quantity given twice at one time
    is refused, naming both lines (two instruments sharing a time on their own rows are not)."""
    cols = "time,above_canopy_par_umol_m2_s,above_canopy_par_sd_umol_m2_s\n"
    p = tmp_path / "o.csv"
    p.write_text("# provenance: measured\n" + cols + "2016-04-20 12:13:48,1549.31,77.47\n")
    with pytest.raises(InputError, match="no time zone") as e:
        read_observations(p)
    assert e.value.row == 3 and e.value.column == "time" and e.value.file == p
    p.write_text("# provenance: measured\n" + cols + "2016-04-20T12:13:48+02:00,1549.31,77.47\n")
    assert read_observations(p).index[0] == pd.Timestamp("2016-04-20 10:13:48", tz="UTC")
    p.write_text("# provenance: measured\n# time_zone: Europe/Berlin\n" + cols + "2016-04-20 12:13:48,1549.31,77.47\n")
    assert read_observations(p).index[0] == pd.Timestamp("2016-04-20 10:13:48", tz="UTC")
    rows = "2016-04-20 12:00,44,2\n2016-04-20 12:30,40,2\n2016-04-20 12:00,20,2\n"
    p.write_text("# provenance: measured\n# time_zone: UTC\n" + cols + rows)
    with pytest.raises(InputError, match="repeats line 4") as e:
        read_observations(p)
    assert e.value.row == 6 and e.value.column == "above_canopy_par_umol_m2_s"
    # two instruments logging the same time on their own rows: each quantity once, accepted
    two = "time,above_canopy_par_umol_m2_s,above_canopy_par_sd_umol_m2_s,nee_umol_m2_s,nee_sd_umol_m2_s\n"
    rows = "2016-04-20 12:00,1500,75,,\n2016-04-20 12:00,,,-20,2\n"
    p.write_text("# provenance: measured\n# time_zone: UTC\n" + two + rows)
    a = align(read_observations(p), pd.date_range("2016-04-20 11:30", periods=3, freq="30min", tz="UTC"))
    assert a["above_canopy_par_umol_m2_s"][1] == 1500 and a["nee_umol_m2_s"][1] == -20


@pytest.mark.parametrize(
    "column, value, ok",
    [
        ("fapar", 0.94, True),
        ("fapar", 1.1, True),
        ("fapar", 94, False),
        ("ceptometer_fapar", -0.2, True),
        ("ceptometer_fapar", -60, False),
        ("ceptometer_transmittance", 12, False),
    ],
)
def test_fractions_are_refused_as_percentages(tmp_path, column, value, ok):
    p = tmp_path / "o.csv"
    head = f"# provenance: measured\n# time_zone: UTC\ntime,{column},{column}_sd\n"
    p.write_text(head + f"2016-04-20 12:00,{value},0.05\n")
    if ok:
        assert read_observations(p)[column].iloc[0] == pytest.approx(value)
    else:
        with pytest.raises(InputError, match="percentage") as e:
            read_observations(p)
        assert e.value.column == column and e.value.row == 4


def test_old_style_columns_are_refused_with_the_new_names(tmp_path):
    p = tmp_path / "old.csv"
    p.write_text(
        "# provenance: measured\ntime,par_umol_m2_s,par_sd_umol_m2_s,an_umol_m2_s,an_sd_umol_m2_s\n"
        "2016-04-20 10:00,100,5,,\n"
    )
    with pytest.raises(InputError) as err:
        read_observations(p)
    msg = str(err.value)
    assert str(p) in msg and "old-style column names" in msg
    assert "par_umol_m2_s (now plant_par_umol_m2_s)" in msg and "an_sd_umol_m2_s (now canopy_an_sd_umol_m2_s)" in msg
    assert "expected columns time, " + ", ".join(COLUMNS) in msg


def test_bundled_record_is_real_and_par_only():
    """The chamber's record is a horizontal quantum sensor above the canopy (issue 14), nothing else."""
    o = read_observations(rep.OBSERVATIONS)
    assert o.attrs["provenance"] == "measured" and len(o) == 1
    assert o["above_canopy_par_umol_m2_s"].iloc[0] == pytest.approx(1549.31)
    assert o.drop(columns=["above_canopy_par_umol_m2_s", "above_canopy_par_sd_umol_m2_s"]).isna().all().all()
    assert o.index[0] == pd.Timestamp("2016-04-20 10:13:48", tz="UTC")


def test_unknown_parameter_and_no_overlap(short_model):
    record = read_observations(rep.OBSERVATIONS)  # one PAR value at 10:13:48 UTC, inside the window
    # Before any render (a review of the Python API): a NaN tolerance never stops, a negative one
    # means nothing; a file name or an empty table for the observations was an AttributeError; one
    # name as a string was taken letter by letter.
    for name, tol in (("rtol", float("nan")), ("atol", -1e-6), ("gtol", -1.0), ("rtol", "1e-4")):
        with pytest.raises(InputError, match=rf"parameter '{name}'.*a finite tolerance ≥ 0"):
            calibrate(short_model, record, names=("specular",), progress=False, **{name: tol})
    with pytest.raises(InputError, match=r"rtol=0 and atol=0.*rtol > 0 or atol > 0"):  # atol=0 alone: relative
        calibrate(short_model, record, names=("specular",), progress=False, rtol=0.0, atol=0.0)
    with pytest.raises(InputError, match=r"gtol=0.*for method lbfgsb"):
        calibrate(short_model, record, names=("specular",), progress=False, method="lbfgsb", gtol=0.0)
    for obs in ("obs.csv", pd.DataFrame()):
        with pytest.raises(InputError, match=r"parameter 'obs'.*an observations table indexed by aware times"):
            calibrate(short_model, obs, names=("specular",), progress=False)
    from lightfit.model.parameters import check_names

    assert check_names("specular") == ("specular",)
    with pytest.raises(InputError, match="unknown parameter"):
        make_loss(short_model, record, ("glossiness",))
    with pytest.raises(InputError, match="parameter 'parameters'.*no parameter to fit"):
        make_loss(short_model, record, ())
    # the same record a day later falls on no simulated step
    next_day = record.copy()
    next_day.index = record.index + pd.Timedelta("1D")
    next_day.attrs = {**record.attrs, "source": "next_day.csv"}
    with pytest.raises(InputError, match="next_day.csv.*outside the run"):
        make_loss(short_model, next_day, ("specular",))
    # inside the window, but no value of the series used: nothing to fit (named as a series the
    # record lacks, or as none of its values falling on a simulated step)
    nothing = "use names canopy_an, which the observations have no value of|no observation of canopy_an_umol_m2_s"
    with pytest.raises(InputError, match=nothing):
        make_loss(short_model, record, ("specular",), use=("an",))
    with pytest.raises(InputError, match=nothing):
        calibrate(short_model, record, names=("specular",), use=("an",), progress=False)


def test_surrogate_calibration_reaches_the_full_render_optimum(twin_model, twin_fits, tmp_path):
    """Trust-region calibration on the emulator (issue 15) against the direct full-render calibration
    of the same twin: the optimum it returns has a full-render loss within z·σ_L of the direct
    optimum's (σ_L: Monte Carlo SD of the loss, lightfit.inference.trust_region), and its full-render
    check passed; every render is kept in the cache, so a rerun renders nothing and ends the same."""
    from lightfit.inference.trust_region import loss_sd, surrogate_calibrate
    from lightfit.model import emulator as E

    obs, fits, _ = twin_fits
    direct = fits["lbfgsb"]
    fixed = {"roughness": TRUTH.roughness, "subsurface": TRUTH.subsurface}
    kw = dict(names=("specular",), start={"specular": 0.3}, fixed=fixed, lo=(0.0, 0.3, 0.0), hi=(1.0, 1.0, 1.0))
    # independent steps, the form of the direct fits it is compared with (the correlated default is
    # exercised by tests/test_posterior_cli.py and tests/test_multiday.py)
    kw |= dict(n_design=8, cache=tmp_path / "cache", progress=False, say=lambda _: None, mc_correlation=None)
    res = surrogate_calibrate(twin_model, obs, out=tmp_path / "out", **kw)
    assert res.mode == "surrogate" and res.passed and res.rounds[-1]["passed"]
    assert res.rendered == 8 + len(res.rounds)  # design + one check render per round
    row = res.rounds[-1]
    assert abs(row["loss_full"] - row["loss_surrogate"]) <= res.z * row["loss_sd"]
    # the full-render loss at the direct optimum and its Monte Carlo SD
    lik = make_loss(twin_model, obs, ("specular",), fixed).likelihood
    m = twin_model.observe(Theta(**direct.theta))
    sd = loss_sd(lik, m)
    assert res.loss_full <= direct.loss + 2 * sd, (res.loss_full, direct.loss, sd)
    assert abs(res.result.theta["specular"] - direct.theta["specular"]) <= 3 * _specular_sd(twin_model, obs)
    lines = (tmp_path / "out" / "trust_region.jsonl").read_text().splitlines()
    assert [json.loads(x)["passed"] for x in lines] == [r["passed"] for r in res.rounds]
    # rerun (e.g. after a kill): every render from the cache, same rounds and optimum
    before = dict(E.COUNTS)
    again = surrogate_calibrate(twin_model, obs, out=tmp_path / "out2", **kw)
    assert E.COUNTS["rendered"] == before["rendered"] and again.rendered == 0
    assert again.result.theta == res.result.theta and again.loss_full == res.loss_full


@pytest.mark.slow
def test_the_last_rounds_line_does_not_say_refining(short_model, tmp_path):
    """A check that failed in the last round said "(refining)", though no round was left and the run
    ended unpassed: it says so now. The check is made to fail with z = 1e-12 (no surrogate is that
    exact), one round, the smallest design."""
    from lightfit.inference.trust_region import surrogate_calibrate

    obs = twin_observations(short_model, TRUTH, render_seed=3, noise_seed=1)
    said = []
    kw = dict(names=("specular",), n_design=5, max_rounds=1, z=1e-12, lo=(0.0, 0.3, 0.0), hi=(1.0, 1.0, 1.0))
    res = surrogate_calibrate(
        short_model, obs, cache=tmp_path, progress=False, say=said.append, mc_correlation=None, **kw
    )
    assert not res.passed and len(res.rounds) == 1
    line = next(x for x in said if x.startswith("round 0:"))
    assert "refining" not in line and "not passed, no round left of 1" in line, line


def test_a_twin_on_unconverged_photosynthesis_is_refused(short_model, monkeypatch):
    """Synthetic observations are never built on a solve that did not converge (solver capped at one
    iteration): the error names θ."""
    from lightfit.photosynthesis.solver import SolverConfig

    capped = SolverConfig.for_dtype.__func__
    monkeypatch.setattr(SolverConfig, "for_dtype", classmethod(lambda cls, dtype, max_steps=100: capped(cls, dtype, 1)))
    with pytest.raises(InputError, match=r"theta.*did not converge for \d+ blade-step"):
        twin_observations(short_model, {"specular": 0.7}, render_seed=5, noise_seed=3)


# --- resume key, bounds and parameter domains on a closed-form model (no render) ----------------


def _fake():
    """tests/test_posterior.py's closed-form model and its synthetic observations (6 steps)."""
    from test_posterior import FakeModel, _fake_obs

    model = FakeModel()
    return model, _fake_obs(model)


@dataclasses.dataclass
class _FakeScenario:
    """A Scenario-like dataclass: what the resume key hashes of a real model's settings."""

    optics: object
    photosynthesis: str = "winter_wheat"
    an_per: str = "ground"
    theta = property(lambda self: Theta.for_optics(self.optics))


def test_resume_with_other_observations_or_model_is_refused(tmp_path):
    """A history's losses and optimiser state belong to the data and model it was made with: a
    resume on edited observations (one value) or another model setting is refused, naming the
    history and the way out, and leaves the history as it was; the same data (a copy) resume
    exactly, to the uninterrupted run's result; resume=False starts again on the new data."""
    model, obs = _fake()
    kw = dict(names=("light_factor", "vcmax_scale"), progress=False, say=lambda _: None)
    h = tmp_path / "h.jsonl"
    calibrate(model, obs, history=h, max_steps=2, **kw)
    kept = h.read_text()
    edited = obs.copy()
    edited.iloc[3, edited.columns.get_loc("canopy_an_umol_m2_s")] += 0.5
    with pytest.raises(InputError, match="other observations") as e:
        calibrate(model, edited, history=h, max_steps=4, **kw)
    assert e.value.file == h and "--no-resume" in str(e.value) and "another --out" in str(e.value)
    assert h.read_text() == kept
    other = type(model)()
    other.scenario = _FakeScenario(model.scenario.optics, photosynthesis="giraud2023")
    model.scenario = _FakeScenario(model.scenario.optics)
    calibrate(model, obs, history=h, max_steps=2, resume=False, **kw)
    with pytest.raises(InputError, match=r"other model settings \(photosynthesis\)"):
        calibrate(other, obs, history=h, max_steps=4, **kw)
    # the same observations (another object) and model: an exact resume, the uninterrupted run's result
    resumed = calibrate(model, obs.copy(), history=h, max_steps=4, **kw)
    whole = calibrate(model, obs, history=tmp_path / "whole.jsonl", max_steps=4, **kw)
    assert resumed.theta == whole.theta and resumed.loss == whole.loss and resumed.steps == whole.steps
    fresh = calibrate(model, edited, history=h, max_steps=4, resume=False, **kw)
    alone = calibrate(model, edited, max_steps=4, **kw)
    assert fresh.theta == alone.theta and fresh.theta != resumed.theta


def test_model_digest_names_each_scenario_setting():
    """The resume key's model part: one hash per Scenario field of a real scenario (no plants
    grown) and one of its growth file's contents, the same for an equal scenario, and changed only
    where a setting changed."""
    from lightfit.inference.calibration import _model_digest

    w = rep.forcing().loc["2016-04-20 09:00+00:00":"2016-04-20 12:00+00:00"]
    sc = rep.scenario_for(rep.ReplicationConfig.quick(), w)
    m = lambda s: type("M", (), {"scenario": s})()  # noqa: E731
    a = _model_digest(m(sc))
    assert set(a) == {f.name for f in dataclasses.fields(sc)} | {"growth"}
    assert _model_digest(m(dataclasses.replace(sc))) == a
    b = _model_digest(m(dataclasses.replace(sc, photosynthesis="giraud2023")))
    # "auto" is hashed as the profile it gives: giraud2023's own is uniform
    assert [k for k in a if a[k] != b[k]] == ["photosynthesis", "vcmax_profile"]
    assert _model_digest(m(dataclasses.replace(sc, vcmax_profile="lloyd2010"))) == a
    warmer = w.copy()
    warmer.iloc[0, warmer.columns.get_loc("tair_c")] += 1.0
    c = _model_digest(m(dataclasses.replace(sc, weather=warmer)))
    assert [k for k in a if a[k] != c[k]] == ["weather"]


def test_a_history_stored_before_capacity_profiles_was_a_uniform_canopy(tmp_path):
    """A resume key saved before ``vcmax_profile`` existed (every blade the set's) does not match
    today's profiled default, and does match an explicitly uniform run."""
    from lightfit.inference.calibration import _check_same_data, _model_digest

    w = rep.forcing().loc["2016-04-20 09:00+00:00":"2016-04-20 12:00+00:00"]
    sc = rep.scenario_for(rep.ReplicationConfig.quick(), w)
    m = lambda s: type("M", (), {"scenario": s})()  # noqa: E731

    def saved(digest):
        old = {k: v for k, v in digest.items() if k != "vcmax_profile"}
        return {"key": {"data": {"observations": "o", "model": old}}}

    now = _model_digest(m(sc))
    with pytest.raises(InputError, match="vcmax_profile"):
        _check_same_data(saved(now), {"observations": "o", "model": now}, tmp_path / "h.json", print)
    uniform = _model_digest(m(dataclasses.replace(sc, vcmax_profile="uniform")))
    _check_same_data(saved(uniform), {"observations": "o", "model": uniform}, tmp_path / "h.json", print)


def test_cli_resume_with_an_edited_observations_file_is_refused(tmp_path):
    """`lightfit calibrate --no-surrogate` resumes its history in --out: with the observations file
    edited (one value) it stops with a named error; --no-resume fits the edited value."""
    from typer.testing import CliRunner

    from lightfit.cli import app

    runner = CliRunner()
    src = rep.OBSERVATIONS.read_text()
    assert "1549.31" in src
    obs = tmp_path / "obs.csv"
    obs.write_text(src)
    args = ["calibrate", str(obs), "--quick", "--steps", "14:16", "--parameters", "light_factor"]
    args += ["--use", "above_canopy_par", "--no-surrogate", "--mc-correlation", "independent", "--out", str(tmp_path)]
    r = runner.invoke(app, args)
    assert r.exit_code == 0, r.output
    assert "caution" not in r.stderr, r.stderr  # a plausible fit says nothing
    first = json.loads((tmp_path / "calibration.json").read_text())["theta"]["light_factor"]
    obs.write_text(src.replace("1549.31", "1400.00"))
    r = runner.invoke(app, args)
    assert r.exit_code == 2, r.output
    err = " ".join(r.stderr.split())
    assert "settings.json: the calibration there was run with other observations (another table" in err
    assert "--no-resume" in err
    r = runner.invoke(app, [*args, "--no-resume"])
    assert r.exit_code == 0, r.output
    again = json.loads((tmp_path / "calibration.json").read_text())["theta"]["light_factor"]
    # light_factor scales the above-canopy PAR: the fit moves with the value
    assert again == pytest.approx(first * 1400.00 / 1549.31, rel=1e-3)


def test_a_unit_slip_in_the_observations_gets_a_caution_not_a_quiet_fit(tmp_path):
    """The record's PAR a tenth of what it was (a slip the forcing check lets through: 0.1 × the
    forcing's PAR; ÷ 1000, mmol, is refused before the run, tests/test_cli.py): the fit converges
    to a light factor of ≈ 0.1, outside its prior's 0.25–4, and says so on stderr (a review found
    it silent)."""
    from typer.testing import CliRunner

    from lightfit.cli import app

    src = rep.OBSERVATIONS.read_text()
    obs = tmp_path / "mmol.csv"
    obs.write_text(src.replace("1549.31,77.47", "154.931,7.747"))
    args = ["calibrate", str(obs), "--quick", "--steps", "14:16", "--parameters", "light_factor", "--no-surrogate"]
    r = CliRunner().invoke(app, [*args, "--use", "above_canopy_par", "--out", str(tmp_path / "cal")])
    assert r.exit_code == 0, r.output
    assert json.loads((tmp_path / "cal" / "calibration.json").read_text())["theta"]["light_factor"] < 0.12
    err = " ".join(r.stderr.split())
    assert "caution: light_factor = 0.1" in err and "outside its prior's range [0.25, 4]" in err, err
    assert "check the observations' units and SDs" in err and "caution" not in r.stdout
    # the range it was searched in is in the result's table (the domain without the surrogate: ∞ above)
    row = next(line for line in r.stdout.splitlines() if "light_factor (calibrated)" in line)
    assert "searched in" in r.stdout and "> 0" in row, r.stdout  # its domain, as check_theta states it


def test_fit_cautions_against_the_chi_square_table():
    """χ² of 45 degrees of freedom exceeds 80.08 with probability 0.001 (standard tables); values on
    the edge of the searched range and outside the prior's are named."""
    from lightfit.inference.calibration import fit_cautions

    box, support = {"roughness": (0.3, 1.0)}, {"roughness": (0.3, 1.0)}
    kw = dict(names=["roughness"], n_values=46, box=box, support=support)
    assert fit_cautions({"roughness": 0.6}, loss=79.9 / 2, **kw) == []
    (misfit, advice) = fit_cautions({"roughness": 0.6}, loss=80.3 / 2, **kw)
    assert "χ² = 80.3 for 46 values and 1 parameter (" in misfit and "check the observations" in advice
    edge = fit_cautions({"roughness": 0.9995}, loss=1.0, **kw)
    assert len(edge) == 2 and "roughness = 0.9995 is on the edge of its search range [0.3, 1]" in edge[0]
    # a good fit with a parameter on its edge is not blamed on units alone (a flat direction does that)
    assert edge[1].startswith("the fit is good (χ² within the data's SDs): an edge can mean the data barely")
    (_, misfit, advice) = fit_cautions({"roughness": 0.9995}, loss=80.3 / 2, **kw)
    assert "χ² = 80.3" in misfit and advice.startswith("check the observations' units")
    # no χ² to call the fit good: an infinite or NaN loss, or no more values than parameters (a review)
    for loss, n in ((math.inf, 46), (math.nan, 46), (1e9, 1)):
        said = fit_cautions({"roughness": 0.9995}, loss=loss, **{**kw, "n_values": n})
        assert said[-1].startswith("check the observations' units") and "fit is good" not in " ".join(said)
    assert fit_cautions({"roughness": 0.99}, loss=1.0, **kw) == []
    out = fit_cautions(
        {"roughness": 0.6, "light_factor": 5.0},
        ["roughness", "light_factor"],
        1.0,
        46,
        {**box, "light_factor": (0.0, float("inf"))},
        {**support, "light_factor": (0.25, 4.0)},
    )
    assert out[0] == "light_factor = 5 lies outside its prior's range [0.25, 4]"


@pytest.mark.parametrize(
    "bounds, match",
    [
        ({"specular": (0.5, 0.5)}, r"bounds specular=\(0.5, 0.5\)"),  # was ZeroDivisionError
        ({"specular": (0.7, 0.3)}, r"bounds specular=\(0.7, 0.3\)"),  # was accepted
        ({"specular": (-0.5, 1.5)}, r"bounds specular=\(-0.5, 1.5\).*0 ≤ lo < hi ≤ 1"),  # was fitted at −0.22
        ({"specular": (0.0, float("nan"))}, r"bounds specular=\(0.0, nan\)"),  # was "unconverged"
        ({"specular": (0.0, float("inf"))}, r"bounds specular=\(0.0, inf\)"),
        ({"light_factor": (float("-inf"), 2.0)}, "bounds light_factor"),
        ({"specular": 0.5}, r"bounds specular=0.5"),
        ({"roughness": (0.3, 1.0)}, "bounds for roughness, which is not calibrated"),  # was ignored
        ({"glossiness": (0.3, 1.0)}, "unknown parameter"),
    ],
)
def test_bad_bounds_are_refused(bounds, match):
    model, obs = _fake()
    names = ("specular", "light_factor")
    with pytest.raises(InputError, match=match) as e:
        calibrate(model, obs, names=names, bounds=bounds, progress=False, say=lambda _: None)
    assert e.value.column == "bounds"
    with pytest.raises(InputError, match=match):
        make_loss(model, obs, names, bounds=bounds)


def test_bounds_hold_the_fit_and_a_start_outside_them_is_refused():
    """Valid bounds keep both optimisers inside (the unbounded optimum of specular is ≈ 0.5; an
    infinite upper bound is kept where the domain has one); a start outside them, named or taken
    from the defaults, is refused instead of being moved to the edge silently."""
    model, obs = _fake()  # truth: specular 0.5 at light_factor 1.1, vcmax_scale 0.9
    kw = dict(names=("specular", "vcmax_scale"), fixed={"light_factor": 1.1}, progress=False, say=lambda _: None)
    free = calibrate(model, obs, **kw)
    assert free.theta["specular"] == pytest.approx(0.5, abs=0.05)
    box = {"specular": (0.6, 0.9), "vcmax_scale": (0.5, math.inf)}
    for method in ("bfgs", "lbfgsb"):
        res = calibrate(model, obs, bounds=box, start={"specular": 0.7}, method=method, **kw)
        assert 0.6 <= res.theta["specular"] <= 0.6 + 1e-3 and res.loss >= free.loss
    with pytest.raises(InputError, match=r"specular=0.9 outside its bounds \[0.4625, 0.7375\]") as e:
        calibrate(model, obs, bounds={"specular": (0.4625, 0.7375)}, start={"specular": 0.9}, **kw)
    assert e.value.column == "start"
    with pytest.raises(InputError, match=r"specular=0.5 \(fixed or default, no start given\) outside"):
        calibrate(model, obs, bounds={"specular": (0.6, 0.9)}, **kw)


def test_lbfgsb_reaches_a_bound_the_loss_falls_towards_and_it_is_reported_on_the_edge():
    """jaxopt's L-BFGS-B error is the projected gradient step, which near a bound is the distance to
    it: with gtol 1e-2 it said "converged" at vcmax_scale 0.79899, short of a bound at 0.8 (loss
    12.026 against 11.919 on the bound, and no edge caution); the reason now says that convergence
    also requires no parameter short of a bound its step reaches. Against numpy: PAR and An decouple, so
    the constrained optimum is vcmax_scale on the bound and the light factor's weighted least squares
    Σ(yP/v)/Σ(P²/v) (v = σ² + s², s the model's SD at the start)."""
    from lightfit.inference.calibration import on_edge

    model, obs = _fake()
    sh = np.asarray(model.shape)
    p = (400 + 100 * model.theta().specular) * sh
    y, ok = obs["plant_par_umol_m2_s"].to_numpy(), obs["plant_par_umol_m2_s"].notna().to_numpy()
    v = 10.0**2 + 2.0**2 * sh
    f_star = float(np.sum((y * p / v)[ok]) / np.sum((p * p / v)[ok]))
    y_an, ok_an = obs["canopy_an_umol_m2_s"].to_numpy(), obs["canopy_an_umol_m2_s"].notna().to_numpy()
    r_an = (y_an - (0.8 * 20 * sh - 2.0)) / np.sqrt(1.0 + 0.1**2 * sh)
    want = 0.5 * np.sum(((y - f_star * p) ** 2 / v)[ok]) + 0.5 * np.sum(r_an[ok_an] ** 2)
    res = calibrate(
        model,
        obs,
        names=("light_factor", "vcmax_scale"),
        method="lbfgsb",
        bounds={"vcmax_scale": (0.2, 0.8)},
        start={"vcmax_scale": 0.5},
        progress=False,
        say=lambda _: None,
    )
    assert res.stopped_by == "converged", res.reason
    # the reason names both conditions: it said only "projected gradient ∞-norm ≤ gtol 0.01", which the
    # run short of the bound met too
    assert "∞-norm ≤ gtol 0.01" in res.reason and "no parameter short of a bound" in res.reason, res.reason
    assert res.theta["vcmax_scale"] == pytest.approx(0.8, abs=1e-5)
    assert on_edge(res.theta["vcmax_scale"], 0.2, 0.8)
    assert res.theta["light_factor"] == pytest.approx(f_star, rel=1e-5)
    assert res.loss == pytest.approx(want, rel=1e-4)


def test_theta_values_are_checked_like_numbers():
    """A Theta is built unchecked (JAX rebuilds it inside traces): its concrete values are checked
    where it enters (as_theta, calibrate's start and fixed), naming the argument; traced values
    pass, so jit and grad through as_theta still work."""
    from lightfit.model.parameters import as_theta

    model, obs = _fake()
    kw = dict(progress=False, say=lambda _: None)
    bad_fixed = Theta(specular=1.5, vcmax_scale=-1.0)  # was calibrated ("converged") with these
    with pytest.raises(InputError, match=r"specular=1.5 \(expected specular in \[0, 1\]\)") as e:
        calibrate(model, obs, names=("light_factor",), fixed=bad_fixed, **kw)
    assert e.value.column == "fixed"
    with pytest.raises(InputError, match="specular=1.5") as e:  # was clamped to 1
        calibrate(model, obs, names=("specular", "light_factor"), start=Theta(specular=1.5), **kw)
    assert e.value.column == "start"
    with pytest.raises(InputError, match=r"vcmax_scale=-1.0 \(expected vcmax_scale > 0\)"):
        as_theta(Theta(vcmax_scale=-1.0))
    with pytest.raises(InputError, match=r"light_factor=0.0"):
        as_theta({"light_factor": np.float32(0.0)})  # numpy numbers too (were taken unchecked)
    with pytest.raises(InputError, match=r"roughness=1.25"):
        as_theta(Theta(roughness=np.array([0.2, 1.25, 0.4])))  # every element of an array
    with pytest.raises(InputError, match="subsurface=nan"):
        as_theta(Theta(subsurface=jnp.asarray(np.nan)))  # a concrete JAX array
    with pytest.raises(InputError, match="specular='0.5'"):
        as_theta(Theta(specular="0.5"))
    assert as_theta(Theta(specular=np.float32(0.25))).specular == np.float32(0.25)
    # traced: checked by nobody here, differentiated as before (d/dx x² = 2x)
    f = lambda x: as_theta(Theta(specular=x, light_factor=2 * x)).specular ** 2  # noqa: E731
    assert float(jax.grad(f)(0.3)) == pytest.approx(0.6)
    assert float(jax.jit(f)(0.3)) == pytest.approx(0.09)
    assert np.allclose(jax.vmap(jax.grad(f))(jnp.asarray([0.1, 0.2])), [0.2, 0.4])
    loss = make_loss(model, obs, ("specular", "light_factor"))
    g = jax.grad(lambda z: loss(z)[0])(jnp.zeros(2))
    assert np.all(np.isfinite(np.asarray(g)))


def test_cli_start_outside_the_emulator_box_is_refused_before_the_plants_grow(tmp_path):
    """With the surrogate (the default) the emulator's box is the informed priors' leaf support
    (specular 0.4625–0.7375 for the default leaf): an explicit --start outside it is refused at once,
    not moved to the box's edge (nor refused only after the design renders)."""
    from typer.testing import CliRunner

    from lightfit.cli import app

    args = ["calibrate", str(rep.OBSERVATIONS), "--quick", "--parameters", "specular", "--start", "specular=0.9"]
    r = CliRunner().invoke(app, [*args, "--out", str(tmp_path)])
    assert r.exit_code == 2, r.output
    err = " ".join(r.stderr.split())
    assert "--start specular=0.9" in err and "[0.4625, 0.7375]" in err and "--no-surrogate" in err
    assert not (tmp_path / "settings.json").exists()  # refused before anything was built or written


def test_the_result_counts_the_likelihoods_entries_not_the_files_rows():
    """Readings that fall in one model step are one likelihood entry (their inverse-variance mean):
    χ²/(n − k) in the command line's misfit caution takes n from the result (it counted the file's
    values, 22 here against 11 entries, so a misfit at 11 passed as a fit at 22)."""
    import pandas as pd

    model, obs = _fake()
    twice = pd.concat([obs, obs.set_axis(obs.index + pd.Timedelta("1min"))]).sort_index()
    twice.attrs = obs.attrs
    res = calibrate(model, twice, names=("light_factor",), max_steps=1, progress=False, say=lambda _: None)
    assert int(twice[["plant_par_umol_m2_s", "canopy_an_umol_m2_s"]].notna().sum().sum()) == 22
    assert res.n_observations == 6 + 5  # PAR at 6 steps, An at 5


def _weighted_least_squares(model, obs, f0: float) -> float:
    """The light factor minimising ½Σ (y − f·a)²/v with v = σ² + s(f0)², in numpy (PAR is f·a)."""
    ok = obs["plant_par_umol_m2_s"].notna().to_numpy()
    a = (400 + 100 * model.theta().specular) * np.asarray(model.shape)
    v = obs["plant_par_sd_umol_m2_s"].to_numpy() ** 2 + (30.0 * f0) ** 2 * np.asarray(model.shape)
    y = obs["plant_par_umol_m2_s"].to_numpy()
    return float(np.sum((y * a / v)[ok]) / np.sum((a * a / v)[ok]))


def test_the_loss_holds_its_monte_carlo_sds_so_its_gradient_is_its_derivative():
    """Where the Monte Carlo SD moves with θ and its gradient is stopped, the loss's value and
    gradient were two functions: a line search met a slope it was not given (L-BFGS-B stopped on a
    failed line search on this model, BFGS short of the minimum). The loss holds the SDs of its
    start (a plug-in, as the correlation is held): the gradient equals central differences, and
    both optimisers converge to the weighted least-squares light factor, solved here in numpy."""
    from test_posterior import NoisyModel, _fake_obs

    model = NoisyModel()
    obs = _fake_obs(model)
    loss = make_loss(model, obs, ("light_factor",), {"light_factor": 1.0})
    for x in (0.8, 1.3):
        g = float(jax.grad(lambda z: loss.natural(z))(jnp.asarray([x]))[0])
        h = 1e-5
        fd = (float(loss.natural(jnp.asarray([x + h]))) - float(loss.natural(jnp.asarray([x - h])))) / (2 * h)
        assert g == pytest.approx(fd, rel=1e-6), (x, g, fd)
    want = _weighted_least_squares(model, obs, 1.0)
    for method in ("lbfgsb", "bfgs"):
        res = calibrate(
            model,
            obs,
            names=("light_factor",),
            start={"light_factor": 1.0},
            method=method,
            progress=False,
            say=lambda _: None,
        )
        assert res.stopped_by == "converged", (method, res.reason)
        assert res.theta["light_factor"] == pytest.approx(want, rel=1e-4), method
    # the held SDs are the start's: another start, another weighting (each a weighted least squares)
    res = calibrate(model, obs, names=("light_factor",), start={"light_factor": 2.0}, progress=False)
    assert res.theta["light_factor"] == pytest.approx(_weighted_least_squares(model, obs, 2.0), rel=1e-4)
    assert abs(_weighted_least_squares(model, obs, 2.0) - want) > 4e-4 * want  # 4× the tolerance above


def test_a_state_saved_with_each_points_own_sds_is_refused_on_resume(tmp_path):
    """A state saved before the loss held its start's Monte Carlo SDs optimised another function:
    its resume is refused, naming the likelihood's mc_sd_at and the way out, not continued with a
    quasi-Newton matrix of the other loss."""
    model, obs = _fake()
    kw = dict(names=("light_factor", "vcmax_scale"), progress=False, say=lambda _: None)
    h = tmp_path / "h.jsonl"
    calibrate(model, obs, history=h, max_steps=2, **kw)
    state = tmp_path / "h.jsonl.state.npz"
    with np.load(state) as z:
        saved = dict(z)
    meta = json.loads(str(saved["meta"]))
    assert meta["key"]["likelihood"]["mc_sd_at"] == "start"
    del meta["key"]["likelihood"]["mc_sd_at"]  # as written before the plug-in
    np.savez(state, **{**saved, "meta": json.dumps(meta)})
    with pytest.raises(InputError, match=r"other likelihood \(mc_sd_at: None → 'start'\)") as e:
        calibrate(model, obs, history=h, max_steps=4, **kw)
    assert "--no-resume" in str(e.value)
    assert calibrate(model, obs, history=h, max_steps=4, resume=False, **kw).steps > 0


def test_the_reported_loss_is_the_answers_own_whatever_the_start():
    """The optimiser holds its start's Monte Carlo SDs, but the result's loss (and with it the χ²
    caution) is the loss at the answer with the answer's own SDs, computed here in numpy: from
    starts 0.3 and 3 the two answers differ slightly, their held losses by a factor of two, their
    reported losses not beyond what their own SDs give (a review: 15.2 from 0.3, 6.5 from 3)."""
    from test_posterior import NoisyModel, _fake_obs

    model = NoisyModel()
    obs = _fake_obs(model)

    def own_loss(f):
        total = 0.0
        for v, sd, pred, mc in (
            ("plant_par_umol_m2_s", "plant_par_sd_umol_m2_s", f * (400 + 100 * model.theta().specular), 30.0 * f),
            ("canopy_an_umol_m2_s", "canopy_an_sd_umol_m2_s", 20.0, 0.1),
        ):
            ok = obs[v].notna().to_numpy()
            shape = np.asarray(model.shape)[ok]
            m = pred * shape - (2.0 if v.startswith("canopy_an") else 0.0)
            var = obs[sd].to_numpy()[ok] ** 2 + mc**2 * shape
            total += 0.5 * np.sum((obs[v].to_numpy()[ok] - m) ** 2 / var)
        return total

    for f0 in (0.3, 3.0):
        res = calibrate(model, obs, names=("light_factor",), start={"light_factor": f0}, progress=False)
        assert res.converged
        assert res.loss == pytest.approx(own_loss(res.theta["light_factor"]), rel=1e-9), f0


def test_a_history_written_before_the_held_sds_is_refused_without_its_state(tmp_path):
    """Without a state, a resume restarts from the history's best point, comparing its losses with
    the new ones: a history written before the loss held its start's SDs has losses of another
    function, and is refused, naming it and the way out."""
    model, obs = _fake()
    kw = dict(names=("light_factor", "vcmax_scale"), progress=False, say=lambda _: None)
    h = tmp_path / "h.jsonl"
    calibrate(model, obs, history=h, max_steps=2, **kw)
    (tmp_path / "h.jsonl.state.npz").unlink()
    lines = [json.loads(x) for x in h.read_text().splitlines()]
    assert all(r.get("mc_sd_at") == "start" for r in lines if "loss" in r)
    h.write_text("".join(json.dumps({k: v for k, v in r.items() if k != "mc_sd_at"}) + "\n" for r in lines))
    with pytest.raises(InputError, match="written before the loss held its start's Monte Carlo SDs") as e:
        calibrate(model, obs, history=h, max_steps=4, **kw)
    assert e.value.file == h and "--no-resume" in str(e.value)
    h.write_text("".join(json.dumps(r) + "\n" for r in lines))  # with the mark: resumed from its best point
    said = []
    calibrate(model, obs, history=h, max_steps=4, **{**kw, "say": said.append})
    assert len(said) == 1 and "without a saved state" in said[0], said


def test_the_surrogates_check_fails_on_either_side():
    """|full − surrogate| ≤ z·σ_L at the optimum: a surrogate 3.1 σ above the full renders' loss fails
    as one 3.1 σ below does, 2 σ either way passes, an unconverged full render (+inf) fails (a
    mutation audit: the check without abs() survived)."""
    from lightfit.inference.trust_region import agrees

    assert agrees(10.0, 12.0, 1.0, 3.0) and agrees(10.0, 8.0, 1.0, 3.0)
    assert not agrees(10.0, 13.1, 1.0, 3.0) and not agrees(10.0, 6.9, 1.0, 3.0)
    assert not agrees(float("inf"), 10.0, 1.0, 3.0)


@pytest.mark.parametrize("max_rounds", [0, -1, 2.5, True])
def test_surrogate_max_rounds_below_one_or_not_an_integer_is_refused(max_rounds):
    """max_rounds 0 ended in an IndexError (rounds[-1] of no round) once the model had been cut, 2.5
    in a TypeError from range(): refused first, naming max_rounds (no model is touched)."""
    from lightfit.inference.trust_region import surrogate_calibrate

    with pytest.raises(InputError, match=r"parameter 'max_rounds'.*max_rounds=.*expected an integer ≥ 1"):
        surrogate_calibrate(None, None, names=("specular",), max_rounds=max_rounds)


@pytest.mark.parametrize("box", [dict(lo=(0.4,), hi=(0.9,)), dict(hi=(1.0, 1.0)), dict(lo=0.0)])
def test_surrogate_box_of_other_than_the_three_leaf_parameters_is_refused(box):
    """lo/hi are the box of (specular, roughness, subsurface) whatever is calibrated: one number per
    calibrated parameter ended in an IndexError; refused naming lo or hi and the three expected."""
    from lightfit.inference.trust_region import surrogate_calibrate

    name = next(iter(box))
    with pytest.raises(InputError, match=rf"parameter '{name}'.*expected 3 numbers.*specular, roughness, subsurface"):
        surrogate_calibrate(None, None, names=("specular",), **box)


@pytest.mark.parametrize("stopped_by", ["unconverged: specular=0.5", "converged"])
def test_the_check_table_says_why_the_surrogate_did_not_pass(stopped_by, monkeypatch):
    """A surrogate run whose round-1 optimisation stopped on unconverged photosynthesis (no check
    render) was captioned "not passed within --max-rounds" though rounds were left; now it says the
    round's optimisation stopped before its check. One that ran out of rounds still says so."""
    import importlib

    from rich.console import Console

    C = importlib.import_module("lightfit.cli.calibrate")  # the module (lightfit.cli exports the command)
    rec = Console(record=True, width=400)
    monkeypatch.setattr(C, "console", rec)
    row = dict(round=0, design=8, degree=1, loss_surrogate=4.0, loss_full=9.0, loss_sd=1.0)
    row |= dict(difference_over_sd=5.0, passed=False)
    tr = SimpleNamespace(mode="surrogate", passed=False, rounds=[row], rendered=9, cached=0, steps_rendered=3, z=2.0)
    tr.result = SimpleNamespace(stopped_by=stopped_by)
    C._print_check(tr)
    text = " ".join(rec.export_text().split())  # the caption wraps to the table's width
    if stopped_by == "converged":
        assert "not passed within --max-rounds" in text
    else:
        assert "--max-rounds" not in text
        assert "not passed: round 1's optimisation on the emulator stopped before its full-render check" in text


def test_bounds_may_reach_the_domains_own_ends():
    """check_bounds takes lo_d ≤ lo < hi ≤ hi_d (its docstring and its message): a pair on the
    domain's own ends, [0, 1] for specular or [0, ∞) for the light factor, is valid and kept (a
    mutation audit: refusing lo = the domain's lower end survived)."""
    from lightfit.inference.calibration import check_bounds

    got = check_bounds({"specular": (0.0, 1.0), "light_factor": (0.0, math.inf)}, ("specular", "light_factor"))
    assert got == {"specular": (0.0, 1.0), "light_factor": (0.0, math.inf)}
    assert check_bounds({"specular": (0.0, 0.4)}, ("specular", "roughness")) == {
        "specular": (0.0, 0.4),
        "roughness": (0.0, 1.0),
    }


def test_on_edge_by_its_docstring():
    """Within EDGE_SHARE (inclusive) of a finite end, of the range's width, or of max(|v|, 1) where the
    range is unbounded above: hand values (a mutation audit: '<' for '≤' and the width |v| instead
    of max(|v|, 1) survived; no test called on_edge directly)."""
    from lightfit.inference.calibration import EDGE_SHARE, on_edge

    assert on_edge(EDGE_SHARE * 2.0, 0.0, 2.0)  # exactly at the share: on the edge
    assert not on_edge(2.5 * EDGE_SHARE * 2.0, 0.0, 2.0)
    assert on_edge(2.0 - EDGE_SHARE, 0.0, 2.0) and not on_edge(1.0, 0.0, 2.0)
    # unbounded above: a light factor of 5e-4 is within 1e-3 · max(5e-4, 1) = 1e-3 of its lower end 0
    assert on_edge(5e-4, 0.0, math.inf)
    assert not on_edge(2e-3, 0.0, math.inf)
    assert not on_edge(1e6, 0.0, math.inf)  # the infinite end is no edge


def test_a_value_on_its_priors_bound_is_not_outside_it():
    """The prior's range is closed (its density is finite on the bounds): a calibrated light factor of
    exactly 4 or 0.25 gets no 'outside its prior's range' caution (a mutation audit: an open range
    survived)."""
    from lightfit.inference.calibration import fit_cautions

    box, support = {"light_factor": (0.0, math.inf)}, {"light_factor": (0.25, 4.0)}
    for v in (0.25, 4.0):
        assert fit_cautions({"light_factor": v}, ["light_factor"], 1.0, 46, box, support) == [], v
    assert fit_cautions({"light_factor": 4.01}, ["light_factor"], 1.0, 46, box, support)[0].endswith(
        "lies outside its prior's range [0.25, 4]"
    )


def test_a_history_without_its_state_restarts_from_its_lowest_loss(tmp_path):
    """Without a saved state a resume restarts from the history's best point (the module docstring):
    the step with the lowest loss, whichever line it is on. With the history's last line made the
    worst, a rerun with max_steps = the steps already taken answers the second line's θ (a mutation
    audit: restarting from the last line survived)."""
    model, obs = _fake()
    kw = dict(names=("light_factor", "vcmax_scale"), progress=False, say=lambda _: None)
    h = tmp_path / "h.jsonl"
    calibrate(model, obs, history=h, max_steps=3, start={"light_factor": 0.6, "vcmax_scale": 0.6}, **kw)
    (tmp_path / "h.jsonl.state.npz").unlink()
    steps = [json.loads(x) for x in h.read_text().splitlines() if "loss" in json.loads(x)]
    assert len(steps) == 3
    steps[-1]["loss"] = 10 * max(r["loss"] for r in steps)  # the last line is now the worst
    h.write_text("".join(json.dumps(r) + "\n" for r in steps))
    best = min(steps, key=lambda r: r["loss"])
    assert best is steps[1]
    res = calibrate(model, obs, history=h, max_steps=3, start={"light_factor": 0.6, "vcmax_scale": 0.6}, **kw)
    assert res.stopped_by == "max_steps"
    assert res.theta["light_factor"] == pytest.approx(best["theta"]["light_factor"], rel=1e-12)
    assert res.theta["vcmax_scale"] == pytest.approx(best["theta"]["vcmax_scale"], rel=1e-12)


def test_an_exact_resume_drops_history_lines_written_after_its_state(tmp_path):
    """A kill between a step's history line and the state saved after it leaves a line the state does
    not know: the exact resume drops it and redoes the step, so the steps are 1, 2, 3 once each
    (a mutation audit: keeping every line survived, giving step 3 twice)."""
    model, obs = _fake()
    kw = dict(names=("light_factor", "vcmax_scale"), progress=False, say=lambda _: None)
    h = tmp_path / "h.jsonl"
    calibrate(model, obs, history=h, max_steps=2, **kw)
    lines = [json.loads(x) for x in h.read_text().splitlines()]
    orphan = {**lines[1], "step": 3, "loss": lines[1]["loss"] / 2}  # written, then killed before the state
    h.write_text("".join(json.dumps(r) + "\n" for r in [*lines, orphan]))
    res = calibrate(model, obs, history=h, max_steps=3, **kw)
    *steps, final = [json.loads(x) for x in h.read_text().splitlines()]
    assert [r["step"] for r in steps] == [1, 2, 3] and final["steps"] == res.steps == 3
    assert steps[2]["loss"] != orphan["loss"]


def test_a_resumed_calibration_counts_the_seconds_of_every_call(tmp_path):
    """``seconds`` (the result's and the history's) counted the last call alone, so a run resumed for
    its last step read as seconds long (a review). The state (exact resume) and the history (resume
    without a state) carry the time spent before: here a first call said to have taken 1000 s."""
    model, obs = _fake()
    kw = dict(names=("light_factor", "vcmax_scale"), progress=False, say=lambda _: None)
    for exact in (True, False):
        h = tmp_path / f"exact_{exact}" / "h.jsonl"
        first = calibrate(model, obs, history=h, max_steps=2, **kw)
        assert first.seconds < 1000
        state = h.with_name(h.name + ".state.npz")
        if exact:
            with np.load(state) as z:
                arrays = dict(z)
            meta = json.loads(str(arrays["meta"]))
            arrays["meta"] = np.asarray(json.dumps(meta | {"seconds": 1000.0}))
            np.savez(state, **arrays)
        else:
            state.unlink()
            *steps, _ = [json.loads(x) for x in h.read_text().splitlines()]
            steps[-1]["seconds"] = 1000.0
            h.write_text("".join(json.dumps(r) + "\n" for r in steps))
        res = calibrate(model, obs, history=h, max_steps=3, **kw)
        *steps, _ = [json.loads(x) for x in h.read_text().splitlines()]
        assert 1000 < res.seconds < 1000 + 600 and steps[-1]["seconds"] > 1000, (exact, res.seconds, steps)


def test_cli_start_on_the_emulator_boxs_edge_is_inside_it(tmp_path, monkeypatch):
    """The box is closed, [lo, hi] as its error says: --start specular=0.4625 (the informed priors'
    lower end for the default leaf) passes the check (a mutation audit: the check made strict
    survived). The run is stopped at the next step, reading the observations."""
    from typer.testing import CliRunner

    import lightfit.inference.observations as observations
    from lightfit.cli import app

    def stop(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(observations, "read_observations", stop)
    args = ["calibrate", str(rep.OBSERVATIONS), "--quick", "--parameters", "specular", "--out", str(tmp_path)]
    for value in ("0.4625", "0.7375"):
        r = CliRunner().invoke(app, [*args, "--start", f"specular={value}"])
        assert r.exit_code == 130, r.output  # reached the observations: the start was accepted
    r = CliRunner().invoke(app, [*args, "--start", "specular=0.46"])
    assert r.exit_code == 2 and "[0.4625, 0.7375]" in " ".join(r.stderr.split()), r.output


def test_a_mapping_takes_the_rest_from_its_base():
    """as_theta of some names: the rest from ``base`` (docstring), e.g. the paper leaf's subsurface 0.3
    where a run gives only a light factor; the defaults only without a base (a mutation audit: the
    base ignored survived, so a paper-preset run given --theta light_factor=… took the default leaf)."""
    from lightfit.light.scene import Optics
    from lightfit.model.parameters import as_theta

    base = Theta(specular=0.2, roughness=0.3, subsurface=0.4, light_factor=1.1, vcmax_scale=0.9)
    th = as_theta({"light_factor": 2.0, "roughness": np.float64(0.7)}, base=base)
    want = {"specular": 0.2, "roughness": 0.7, "subsurface": 0.4, "light_factor": 2.0, "vcmax_scale": 0.9}
    assert th.to_dict() == want
    assert as_theta({"vcmax_scale": 1.2}, base=Theta.for_optics(Optics.preset("paper"))).subsurface == 0.3
    assert as_theta(None, base=base) == base
    assert as_theta({"light_factor": 2.0}).subsurface == Theta().subsurface  # no base: the defaults


def test_cli_calibrate_records_the_observations_absolute_and_hints_a_fit_folder_of_its_own(tmp_path, monkeypatch):
    """Run from another folder with relative names: calibration.json names the observations by their
    absolute path (read back from elsewhere it still finds them), and the hint's replicate writes into
    OUT/fit, not over the calibration in OUT (a mutation audit: both survived)."""
    import shutil

    from typer.testing import CliRunner

    from lightfit.cli import app

    shutil.copy(rep.OBSERVATIONS, tmp_path / "obs.csv")
    monkeypatch.chdir(tmp_path)
    args = ["calibrate", "obs.csv", "--quick", "--steps", "14:16", "--parameters", "light_factor"]
    r = CliRunner().invoke(app, [*args, "--use", "above_canopy_par", "--max-steps", "2", "--out", "cal"])
    assert r.exit_code == 0, r.output
    res = json.loads((tmp_path / "cal" / "calibration.json").read_text())
    assert res["observations"] == str((tmp_path / "obs.csv").resolve())
    hint = " ".join(r.stdout.split()).split("to see the fit: ")[1]
    assert hint.endswith("--theta cal/calibration.json --observations obs.csv --out cal/fit"), hint


@pytest.mark.parametrize("name, text", [("settings.json", "{"), ("calibration.json", "[1, 2]")])
def test_cli_calibrate_refuses_an_earlier_record_that_is_not_a_json_object(tmp_path, name, text):
    """A settings.json or calibration.json in --out that is cut short or hand-edited into something
    else is --out's error, naming the file, before any plant grows (it was a JSONDecodeError
    traceback, exit 1; a mutation audit's probe)."""
    from typer.testing import CliRunner

    from lightfit.cli import app

    out = tmp_path / "cal"
    out.mkdir()
    (out / name).write_text(text)
    args = ["calibrate", str(rep.OBSERVATIONS), "--quick", "--parameters", "light_factor", "--out", str(out)]
    r = CliRunner().invoke(app, args)
    err = " ".join(r.stderr.split())
    assert r.exit_code == 2 and isinstance(r.exception, SystemExit), r.output
    assert err.startswith("error:") and "--out" in err and name in err and "--no-resume" in err, err
    assert "Traceback" not in r.output


def test_twin_noise_is_the_documented_draws_on_a_stand_in_model(monkeypatch):
    """twin_observations on a stand-in for the coupled model (known PAR and An, no render), against its
    docstring written out: rendered at ``render_seed``; from default_rng(noise_seed) one standard-normal
    draw per step for PAR (SD max(3 % PAR, 1)), clipped at 0, then one per step for An (SD
    an_sd_umol_m2_s); night steps missing, An kept at night only with an_at_night; SDs written."""
    import dataclasses

    import lightfit.inference.twin as twin

    @dataclasses.dataclass(frozen=True)
    class Scenario:
        seed: int = 0
        an_per: str = "ground"

    par = np.array([0.0, 0.2, 800.0, 1500.0, 0.0])
    an = np.array([-2.0, 5.0, 20.0, 25.0, -1.5])
    day = np.array([False, True, True, True, False])
    rendered = []

    class StandIn:
        def __init__(self, scenario):
            self.scenario = scenario

        def observe(self, theta):
            rendered.append(self.scenario.seed)
            return {"plant_par_umol_m2_s": par, "canopy_an_umol_m2_s": an}

    monkeypatch.setattr(twin, "CoupledModel", StandIn)
    times = pd.date_range("2016-06-01 00:00", periods=5, freq="6h", tz="UTC")
    model = SimpleNamespace(scenario=Scenario(seed=11), day=day, times=times, timestamps="instant")
    z = np.random.default_rng(2).standard_normal(10)  # PAR's five draws, then An's five
    assert par[1] + z[1] < 0  # this seed puts a PAR value below zero: the clip is exercised
    sd = np.array([1.0, 1.0, 24.0, 45.0, 1.0])
    want_par = np.clip(par + sd * z[:5], 0.0, None)
    want_an = an + 0.7 * z[5:]
    for at_night in (False, True):
        df = twin.twin_observations(
            model, {"specular": 0.7}, render_seed=5, noise_seed=2, an_sd_umol_m2_s=0.7, an_at_night=at_night
        )
        assert rendered[-1] == 5
        np.testing.assert_allclose(df["plant_par_umol_m2_s"], np.where(day, want_par, np.nan), rtol=1e-12)
        np.testing.assert_allclose(df["plant_par_sd_umol_m2_s"], np.where(day, sd, np.nan), rtol=1e-12)
        an_steps = np.ones(5, bool) if at_night else day
        np.testing.assert_allclose(df["canopy_an_umol_m2_s"], np.where(an_steps, want_an, np.nan), rtol=1e-12)
        np.testing.assert_allclose(df["canopy_an_sd_umol_m2_s"], np.where(an_steps, 0.7, np.nan), rtol=1e-12)
        assert df.attrs["provenance"] == "synthetic" and df.index.equals(times)
    assert df.loc[times[1], "plant_par_umol_m2_s"] == 0.0


def test_a_start_of_a_parameter_not_calibrated_is_refused_unless_it_is_the_held_value():
    """A start value of a parameter outside ``names`` was ignored: the parameter stayed at the run
    leaf's value (the result listed it as fixed there) while the loss's Monte Carlo SDs were taken
    at the start (a review: --parameters light_factor --start specular=0.2 fitted at specular 0.5
    unsaid). It is refused, naming it and the value held; the held value itself (a calibration.json
    of the same run lists every parameter) passes, and fits as without it."""
    model, obs = _fake()
    kw = dict(names=("light_factor",), progress=False, say=lambda _: None)
    held = model.theta().roughness
    with pytest.raises(InputError, match=r"parameter 'start'.*roughness=0\.2 \(held at") as e:
        calibrate(model, obs, start={"light_factor": 1.0, "roughness": 0.2}, **kw)
    assert "only for the calibrated parameters (light_factor)" in str(e.value)
    same = calibrate(model, obs, start={"light_factor": 1.0, "roughness": held}, **kw)
    plain = calibrate(model, obs, start={"light_factor": 1.0}, **kw)
    assert same.theta == plain.theta and same.theta["roughness"] == held


def test_cli_start_of_a_parameter_not_calibrated_is_refused_before_the_plants_grow(tmp_path):
    """The command line's --start specular=0.2 with --parameters light_factor: refused at once
    (it calibrated the light factor at specular 0.5 and listed specular 0.5 as fixed)."""
    from typer.testing import CliRunner

    from lightfit.cli import app

    args = ["calibrate", str(rep.OBSERVATIONS), "--quick", "--parameters", "light_factor"]
    r = CliRunner().invoke(app, [*args, "--start", "specular=0.2", "--out", str(tmp_path)])
    assert r.exit_code == 2, r.output
    err = " ".join(r.stderr.split())
    assert "--start" in err and "specular=0.2 (held at 0.5)" in err and "(light_factor)" in err
    assert not (tmp_path / "settings.json").exists()  # refused before anything was built or written


def test_an_unconverged_calibration_is_told_what_helps():
    """More steps help a run that ran out of them (a resume resets only those limits,
    calibration.py); after a failed line search or an unconverged leaf a rerun restores the same
    state and stops the same way, where "a larger --max-steps" was said too (a review)."""
    from lightfit.cli.calibrate import unconverged_remedy

    for limit in ("max_steps", "stalled"):
        assert unconverged_remedy(limit).startswith("rerun with a larger --max-steps")
    for failed in ("failed: line search", "unconverged: specular=0.5", "against unconverged: specular=0.9"):
        said = unconverged_remedy(failed)
        assert "stop the same way" in said and "--no-resume" in said and "rerun with a larger" not in said
    # on the surrogate (the command line's default) the rounds are redone, not resumed from a history
    # (trust_region.surrogate_calibrate: resume=False), where "continues from its history" was said
    said = unconverged_remedy("max_steps", surrogate=True)
    assert "history" not in said and "redoes the optimisation on the cached renders" in said
    assert "resume the same state" not in unconverged_remedy("failed: line search", surrogate=True)


def test_bfgs_stopped_on_max_steps_at_a_bound_is_told_to_use_lbfgsb():
    """bfgs works in logit coordinates and approaches a bound without reaching it: with the optimum
    on a bound (vcmax_scale's loss falls towards 0.8, the test above) it ran to the step limit at
    every limit tried, and "rerun with a larger --max-steps" was advised, which cannot help (a
    review). Where it stopped on max_steps with a parameter on its range's edge, lbfgsb (which
    steps onto bounds and converges there, the test above) is advised instead."""
    from lightfit.cli.calibrate import unconverged_remedy
    from lightfit.inference.calibration import on_edge

    model, obs = _fake()
    kw = dict(names=("light_factor", "vcmax_scale"), bounds={"vcmax_scale": (0.2, 0.8)}, progress=False)
    res = calibrate(model, obs, method="bfgs", start={"vcmax_scale": 0.5}, max_steps=8, say=lambda _: None, **kw)
    assert res.stopped_by == "max_steps" and 0.79 < res.theta["vcmax_scale"] < 0.8
    edges = [n for n, (lo, hi) in {"vcmax_scale": (0.2, 0.8)}.items() if on_edge(res.theta[n], lo, hi)]
    assert edges == ["vcmax_scale"]
    said = unconverged_remedy(res.stopped_by, method="bfgs", edges=edges)
    assert "--method lbfgsb" in said and "vcmax_scale" in said and "rerun with a larger" not in said
    assert "--no-resume" in said  # a resume keeps the method (check_resumable)
    # more steps still help bfgs away from an edge, and lbfgsb at one
    assert unconverged_remedy("max_steps", method="bfgs").startswith("rerun with a larger --max-steps")
    assert unconverged_remedy("max_steps", method="lbfgsb", edges=edges).startswith("rerun with a larger")


def test_canopy_an_per_another_area_than_the_run_is_refused(tmp_path):
    """A chamber's canopy An is per ground area; with --an-per leaf the model's is per leaf area,
    ≈ LAI × smaller, and the two were compared as they stood (a review). A file now says its area
    (`# canopy_an_per: leaf`; ground where unsaid), written back as read, and a likelihood or
    log-posterior of a model whose an_per differs is refused naming the file and column."""
    from lightfit.inference.likelihood import GaussianLikelihood
    from lightfit.inference.mcmc.log_posterior import LogPosterior
    from lightfit.inference.observations import check_an_area

    times = pd.date_range("2016-04-20 09:00", periods=3, freq="30min", tz="UTC")
    an = {"canopy_an_umol_m2_s": [2.0, 3.0, 4.0], "canopy_an_sd_umol_m2_s": [0.5, 0.5, 0.5]}
    df = pd.DataFrame(an, index=times)
    ground = read_observations(write_observations(df, tmp_path / "ground.csv", {"provenance": "synthetic"}))
    assert (
        ground.attrs["canopy_an_per"] == "ground" and "# canopy_an_per: ground" in (tmp_path / "ground.csv").read_text()
    )
    df.attrs["canopy_an_per"] = "leaf"
    leaf = read_observations(write_observations(df, tmp_path / "leaf.csv", {"provenance": "synthetic"}))
    assert leaf.attrs["canopy_an_per"] == "leaf"
    check_an_area(leaf, "leaf")
    check_an_area(ground, "ground")
    with pytest.raises(InputError, match="canopy An per ground area") as e:
        check_an_area(ground, "leaf")
    assert (
        e.value.column == "canopy_an_umol_m2_s" and "ground.csv" in str(e.value) and "--an-per ground" in str(e.value)
    )
    unsaid = (tmp_path / "ground.csv").read_text().replace("# canopy_an_per: ground\n", "")
    (tmp_path / "unsaid.csv").write_text(unsaid)
    with pytest.raises(InputError, match="unsaid"):
        check_an_area(read_observations(tmp_path / "unsaid.csv"), "leaf")
    par_only = pd.DataFrame({"plant_par_umol_m2_s": [1.0], "plant_par_sd_umol_m2_s": [0.1]}, index=times[:1])
    check_an_area(par_only, "leaf")  # no canopy An reading: nothing to compare per an area
    (tmp_path / "bad.csv").write_text(unsaid.replace("# provenance", "# canopy_an_per: plant\n# provenance"))
    with pytest.raises(InputError, match="plant") as e:
        read_observations(tmp_path / "bad.csv")
    assert e.value.column == "canopy_an_per"
    model = SimpleNamespace(scenario=SimpleNamespace(an_per="leaf"), times=times, timestamps=None, step=None)
    for build in (
        lambda: GaussianLikelihood.of_model(model, ground),
        lambda: LogPosterior.of_model(lambda th: {}, model, ground, ["specular"]),
    ):
        with pytest.raises(InputError, match="per leaf area"):
            build()


@pytest.mark.parametrize("damage", ["empty", "cut"])
def test_an_unreadable_state_restarts_from_the_historys_best_point(tmp_path, damage):
    """A state file that cannot be read (empty, or cut short: a full disk, a copy interrupted) is
    what the module docstring says it is, no state: the resume restarts from the history's best point
    and says so. An empty file raised EOFError (the command line's bare "Aborted."), a cut one
    zipfile.BadZipFile (a traceback)."""
    model, obs = _fake()
    kw = dict(names=("light_factor", "vcmax_scale"), progress=False)
    h = tmp_path / "h.jsonl"
    calibrate(model, obs, history=h, max_steps=2, say=lambda _: None, **kw)
    kept = [json.loads(x) for x in h.read_text().splitlines()][:2]
    state = tmp_path / "h.jsonl.state.npz"
    state.write_bytes(b"" if damage == "empty" else state.read_bytes()[:300])
    said = []
    res = calibrate(model, obs, history=h, max_steps=3, say=said.append, **kw)
    assert len(said) == 1 and "without a saved state: 2 steps kept" in said[0], said
    steps = [json.loads(x) for x in h.read_text().splitlines() if "loss" in json.loads(x)]
    assert steps[:2] == kept and res.steps == len(steps) == 3
    best = min(kept, key=lambda r: r["loss"])["theta"]
    assert steps[2]["theta"] == best  # BFGS's first accepted point is its start: the best kept one


def test_a_history_damaged_before_its_last_line_is_refused_naming_it(tmp_path):
    """Only an interruption's cut last line may be unreadable (the history is appended to). A line
    damaged before it dropped every later step unsaid: with the state, the resumed history read steps
    1, 2, 5, 6 (the state's count went on); without it, the restart took the best of the first two.
    Refused now, naming the file and line; the intact history resumes as before."""
    model, obs = _fake()
    start = {"light_factor": 0.6, "vcmax_scale": 0.6}  # four steps before it converges
    kw = dict(names=("light_factor", "vcmax_scale"), start=start, progress=False, say=lambda _: None)
    h = tmp_path / "h.jsonl"
    calibrate(model, obs, history=h, max_steps=4, **kw)
    intact = h.read_text()
    lines = intact.splitlines()
    assert len(lines) == 5  # four steps and the final record
    state = tmp_path / "h.jsonl.state.npz"
    saved = state.read_bytes()
    h.write_text("\n".join([*lines[:2], "{not json", *lines[3:]]) + "\n")
    with pytest.raises(InputError, match="line 3: not a JSON object") as e:
        calibrate(model, obs, history=h, max_steps=6, **kw)
    assert e.value.file == h and "--no-resume" in str(e.value)
    state.unlink()  # the same without the state
    with pytest.raises(InputError, match="line 3: not a JSON object"):
        calibrate(model, obs, history=h, max_steps=6, **kw)
    # lines lost (not damaged) since the state was saved: fewer steps than the state's four
    state.write_bytes(saved)
    h.write_text("\n".join(lines[:2]) + "\n")
    with pytest.raises(InputError, match="2 readable steps, where its saved optimiser state") as e:
        calibrate(model, obs, history=h, max_steps=6, **kw)
    assert e.value.file == h
    h.write_text(intact + '{"step": 5, "lo')  # a cut last line: an interruption's, dropped
    res = calibrate(model, obs, history=h, max_steps=5, **kw)
    steps = [json.loads(x) for x in h.read_text().splitlines()][:-1]
    assert [r["step"] for r in steps] == [1, 2, 3, 4, 5] and res.steps == 5


def test_a_resume_with_a_smaller_step_limit_says_how_many_steps_it_has(tmp_path):
    """A run of 3 steps resumed with max_steps=2 takes none: its reason said "step limit: 2 accepted
    steps" beside 3 steps in the result and the history; it now says the 3 are already taken."""
    model, obs = _fake()
    start = {"light_factor": 0.6, "vcmax_scale": 0.6}  # not converged in 3 steps
    kw = dict(names=("light_factor", "vcmax_scale"), start=start, progress=False, say=lambda _: None)
    h = tmp_path / "h.jsonl"
    first = calibrate(model, obs, history=h, max_steps=3, **kw)
    assert first.reason == "step limit: 3 accepted steps"
    res = calibrate(model, obs, history=h, max_steps=2, **kw)
    assert res.steps == 3 and res.theta == first.theta
    assert res.reason == "step limit: 2 accepted steps (3 already taken)"
    assert json.loads(h.read_text().splitlines()[-1])["reason"] == res.reason
