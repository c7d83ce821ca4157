"""Observation operators that measure what the instruments measure (issue 14) and the observations
CSV that names them; the light factor calibrated from the chamber's above-canopy PAR record."""

import re
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd
import pytest
import xarray as xr

import lightfit  # noqa: F401
from lightfit import replication as rep
from lightfit.errors import InputError
from lightfit.inference.calibration import calibrate
from lightfit.inference.likelihood import GaussianLikelihood, resolve_use
from lightfit.inference.observations import COLUMNS, SERIES, read_observations
from lightfit.light import backend
from lightfit.light.estimator import PARTS
from lightfit.model import observe as O
from lightfit.model import schema
from lightfit.model.coupled import NonConvergenceWarning, warn_unconverged
from lightfit.model.parameters import Theta
from lightfit.report import summary


def test_above_canopy_sensor_matches_pvlib_on_a_horizontal_plane():
    """Peer: pvlib's plane-of-array irradiance at tilt 0 (beam cos z + diffuse, no ground term)."""
    import pvlib

    el = np.array([-5.0, 0.0, 10.0, 30.0, 62.0])
    dni, dhi = np.array([0.0, 0.0, 300.0, 800.0, 900.0]), np.array([0.0, 5.0, 60.0, 120.0, 100.0])
    poa = pvlib.irradiance.get_total_irradiance(0, 180, 90 - el, 180, dni, 300 + dni, dhi)["poa_global"]
    got = O.above_canopy_par(dni, dhi, el, 1.0)
    np.testing.assert_allclose(got, np.maximum(poa, 0), rtol=1e-12, atol=1e-12)
    # numpy and JAX paths agree; the light factor scales it (d/df = value / f)
    j = O.above_canopy_par(jnp.asarray(dni), jnp.asarray(dhi), jnp.asarray(el), jnp.asarray(1.3))
    np.testing.assert_allclose(np.asarray(j), 1.3 * got, rtol=1e-12)
    g = jax.grad(lambda f: O.above_canopy_par(jnp.asarray(dni), jnp.asarray(dhi), jnp.asarray(el), f).sum())(1.3)
    assert float(g) == pytest.approx(got.sum(), rel=1e-12)


def test_above_canopy_sensor_takes_no_beam_from_a_sun_below_the_horizon():
    """Steps with the sun just below the horizon are rendered (above −1°,
    test_daytime_is_light_with_the_sun_above_minus_one_degree_or_diffuse_light_in_civil_twilight)
    and a series may carry a beam there:
    the horizontal sensor takes DNI·sin⁺β, so at β = −0.5° it reads the DHI alone, at +0.5°
    8 + 40·sin 0.5° (a mutation audit: sin β without its clip, a negative beam, passed every test,
    whose steps below the horizon all had DNI = 0)."""
    got = O.above_canopy_par(np.array([40.0, 40.0]), np.array([8.0, 8.0]), np.array([-0.5, 0.5]), 1.0)
    np.testing.assert_allclose(got, [8.0, 8.0 + 40.0 * np.sin(np.radians(0.5))], rtol=1e-12)


def test_fapar_is_zero_at_night_with_finite_gradients():
    apar, sd, above = jnp.array([0.0, 50.0, 900.0]), jnp.array([0.0, 1.0, 9.0]), jnp.array([0.0, 100.0, 1000.0])
    f, f_sd = O.fapar(apar, sd, above)
    np.testing.assert_allclose(np.asarray(f), [0.0, 0.5, 0.9])
    np.testing.assert_allclose(np.asarray(f_sd), [0.0, 0.01, 0.009])
    # d(a/P)/da = 1/P and d(a/P)/dP = −a/P², 0 at night (no NaN from 0/0); it checked finiteness
    # and the night's 0 only, which a ratio that blocked the gradient (all zeros) passed
    g = jax.grad(lambda a: O.fapar(a, sd, above)[0].sum())(apar)
    np.testing.assert_allclose(np.asarray(g), [0.0, 1 / 100, 1 / 1000], rtol=1e-12)
    gp = jax.grad(lambda p: O.fapar(apar, sd, p)[0].sum())(above)
    np.testing.assert_allclose(np.asarray(gp), [0.0, -50 / 100**2, -900 / 1000**2], rtol=1e-12)


def test_plant_par_spread_has_finite_gradients_when_every_segment_has_the_same_par():
    """At night (or any step where all segments see the same PAR) the spread is 0 and √ has an
    infinite derivative there; the gradient is 0, not NaN, with and without jit."""
    area = jnp.array([1.0, 2.0, 1.0])

    def spread(par):
        return O.plant_par(par, jnp.zeros_like(par), area)[1].sum()

    for par in (jnp.zeros((2, 3)), jnp.full((2, 3), 300.0)):
        for fn in (jax.grad(spread), jax.jit(jax.grad(spread))):
            g = np.asarray(fn(par))
            assert np.isfinite(g).all() and (g == 0).all()
    # Away from equality the spread is the weighted SD (weights 1/4, 1/2, 1/4: mean 2, var 0.5).
    assert float(O.plant_par(jnp.array([[1.0, 2.0, 3.0]]), jnp.zeros((1, 3)), area)[1][0]) == pytest.approx(0.5**0.5)


def test_chamber_nee_sign_convention():
    """NEE = soil respiration − canopy net uptake: uptake 10 with soil 2 is −8 (CO2 taken up)."""
    nee, sd = O.chamber_nee(np.array([10.0, -3.0]), np.array([0.5, 0.1]), 2.0)
    np.testing.assert_allclose(nee, [-8.0, 5.0])
    np.testing.assert_allclose(sd, [0.5, 0.1])
    assert O.SOIL_RESPIRATION_UMOL_M2_S == 0.0


def test_nee_is_per_ground_area_when_canopy_an_is_per_leaf_area():
    """With an_per = "leaf" and no soil respiration, NEE is −canopy An per *ground* area, not −canopy_an:
    blades of 0.01 and 0.03 m² at An 10 and 20 µmol m⁻² s⁻¹ on 0.02 m² of ground take up
    0.1 + 0.6 = 0.7 µmol s⁻¹, so canopy An is 0.7 / 0.04 = 17.5 per leaf area and NEE −0.7 / 0.02 = −35
    (by hand)."""
    area = np.array([0.01, 0.03])
    one = np.ones((1, 2))
    out = O.observables(
        one,
        0 * one,
        area,
        np.array([[10.0, 20.0]]),
        0 * one,
        area,
        O.an_denominator(area, "leaf", 0.02),
        absorbed=one,
        absorbed_mc_sd=0 * one,
        ground_area_m2=0.02,
        above_par=np.array([1.0]),
    )
    assert float(out["canopy_an_umol_m2_s"][0]) == pytest.approx(17.5)
    assert float(out["nee_umol_m2_s"][0]) == pytest.approx(-35.0)


def test_soil_respiration_follows_q10():
    """R = R₁₀ Q₁₀^((T − 10)/10): doubling every 10 K at Q₁₀ = 2; constant at Q₁₀ = 1."""
    t = np.array([0.0, 10.0, 20.0, 25.0])
    np.testing.assert_allclose(O.soil_respiration(2.0, 2.0, t), [1.0, 2.0, 4.0, 4.0 * 2**0.5])
    np.testing.assert_allclose(O.soil_respiration(2.0, 1.0, t), 2.0)


@pytest.mark.parametrize(
    "kw, name",
    [
        (dict(soil_respiration_umol_m2_s=-1.0), "soil_respiration_umol_m2_s"),
        (dict(soil_respiration_umol_m2_s=float("nan")), "soil_respiration_umol_m2_s"),
        (dict(soil_respiration_umol_m2_s="2"), "soil_respiration_umol_m2_s"),
        (dict(soil_respiration_q10=0.5), "soil_respiration_q10"),
        (dict(soil_respiration_q10=True), "soil_respiration_q10"),
    ],
)
def test_scenario_refuses_bad_soil_respiration(kw, name):
    from lightfit.model.scenario import Scenario

    with pytest.raises(InputError, match=name):
        Scenario(weather=rep.forcing().iloc[[14]], **kw)


@pytest.mark.parametrize(
    "col, value, expected",
    [
        ("dni_w_m2", np.nan, "≥ 0"),
        ("dhi_w_m2", -100.0, "≥ 0"),
        ("sun_elevation_deg", np.nan, "sun elevation"),
        ("sun_azimuth_deg", np.nan, "azimuth"),
        ("tair_c", np.nan, r"\[-50, 60\] °C"),
        ("rh", 55.0, "not %"),
        ("pair_kpa", 0.0, "air pressure"),
        ("co2_ppm", np.nan, "CO2"),
    ],
)
def test_scenario_refuses_weather_values_a_file_would_not_pass(col, value, expected):
    """A series built in code meets the file readers' kind of check (a review: a NaN DNI made a midday
    step night with its respiration reported as the result, DHI −100 dimmed it silently, a NaN air
    temperature failed in the leaf solve as ``tleaf_c`` after the plants grew, a NaN azimuth as a JAX
    callback error). The error names the column and the step."""
    from lightfit.model.scenario import Scenario

    w = rep.forcing().iloc[[13, 14]].copy()
    Scenario(weather=w)
    w.iloc[0, w.columns.get_loc(col)] = value
    when = re.escape(str(w.index[0]))
    with pytest.raises(
        InputError, match=rf"column '{col}': weather value .* at {when} \(1 such step\(s\)\).*{expected}"
    ):
        Scenario(weather=w)


def test_every_series_has_an_observable_and_schema_entries():
    for s in SERIES:
        assert s.value in schema.OBSERVABLES and s.mc_sd in schema.OBSERVABLES, s.name
        assert schema.units(s.value) == s.unit, s.name
        for c in (s.value, s.sd):
            assert f"obs_{c}" in schema.VARIABLES, c
        # results.nc called observed PAR at the plants and canopy An "(chamber)", whatever the file held:
        # no instrument reads PAR at the plants (docs/calibration.md), and uptake may come from a tower
        if s.name != "nee":
            assert "chamber" not in schema.VARIABLES[f"obs_{s.value}"].long_name, s.name


def _write(tmp_path, body, name="o.csv"):
    p = tmp_path / name
    p.write_text("# provenance: measured\n# time_zone: UTC\n" + body)
    return p


def test_files_name_their_quantities(tmp_path):
    times = pd.date_range("2016-04-20 09:00", periods=3, freq="30min", tz="UTC")
    # an older file with PAR at the plants only still reads, and means plant PAR
    old = read_observations(
        _write(tmp_path, "time,plant_par_umol_m2_s,plant_par_sd_umol_m2_s\n2016-04-20 09:30,300,9\n")
    )
    assert list(old.columns) == list(COLUMNS) and old["plant_par_umol_m2_s"].iloc[0] == 300.0
    assert resolve_use(None, old) == ("plant_par",)
    assert resolve_use(("an", "par")) == ("plant_par", "canopy_an")  # aliases, SERIES order
    lik = GaussianLikelihood(old, times)
    assert lik.use == ("plant_par",) and lik.n_observations == 1
    # the bundled chamber record: the above-canopy sensor, chosen by default
    rec = read_observations(rep.OBSERVATIONS)
    assert resolve_use(None, rec) == ("above_canopy_par",)
    nee = read_observations(_write(tmp_path, "time,nee_umol_m2_s,nee_sd_umol_m2_s\n2016-04-20 09:00,-12,1\n", "n.csv"))
    assert nee["nee_umol_m2_s"].iloc[0] == -12.0  # NEE may be negative (uptake)


@pytest.mark.parametrize(
    "body, match",
    [
        ("time,co2_flux,co2_flux_sd\n2016-04-20 09:00,1,1\n", r"unknown column\(s\) \['co2_flux', 'co2_flux_sd'\]"),
        ("time,fapar\n2016-04-20 09:00,0.5\n", r"missing column\(s\) \['fapar_sd'\]"),
        ("time\n2016-04-20 09:00\n", "no observed quantity"),
        ("time,canopy_apar_umol_m2_s,canopy_apar_sd_umol_m2_s\n2016-04-20 09:00,-1,1\n", "negative value"),
    ],
)
def test_bad_quantity_columns_name_the_file(tmp_path, body, match):
    p = _write(tmp_path, body)
    with pytest.raises(InputError, match=match) as err:
        read_observations(p)
    assert str(p) in str(err.value)


def test_unknown_series_name_lists_the_known_ones():
    with pytest.raises(InputError, match="above_canopy_par"):
        resolve_use(("co2",))


@pytest.fixture(scope="module")
def noon_model():
    """The quick configuration on a 3-hour window around noon (the record at 10:13:48 UTC is on it)."""
    w = rep.forcing()
    return rep.model_for(rep.ReplicationConfig.quick(), w.loc["2016-04-20 09:00+00:00":"2016-04-20 12:00+00:00"])


def test_chamber_nee_adds_the_soils_respiration_at_each_steps_air_temperature(noon_model):
    """The run option reaches the observable: NEE with R₁₀ = 2, Q₁₀ = 2.5 minus NEE without is
    2 · 2.5^((T − 10)/10) at each step's air temperature from the forcing; nothing else moves, and
    the results record both settings."""
    import dataclasses

    cfg = dataclasses.replace(rep.ReplicationConfig.quick(), soil_respiration_umol_m2_s=2.0, soil_respiration_q10=2.5)
    w = rep.forcing().loc["2016-04-20 09:00+00:00":"2016-04-20 12:00+00:00"]
    parts = noon_model.render(Theta())
    base = noon_model.with_light(lambda theta: parts).observe(Theta())
    m = rep.model_for(cfg, w).with_light(lambda theta: parts)
    got = m.observe(Theta())
    t = w["tair_c"].to_numpy()
    np.testing.assert_allclose(
        np.asarray(got["nee_umol_m2_s"]) - np.asarray(base["nee_umol_m2_s"]), 2.0 * 2.5 ** ((t - 10) / 10), rtol=1e-12
    )
    np.testing.assert_array_equal(np.asarray(got["canopy_an_umol_m2_s"]), np.asarray(base["canopy_an_umol_m2_s"]))
    ds = m.simulate(Theta())
    assert ds.attrs["soil_respiration_umol_m2_s"] == 2.0 and ds.attrs["soil_respiration_q10"] == 2.5


def test_segments_without_monte_carlo_error_keep_the_sds_gradient_finite():
    """The per-segment SD f·√((DNI σ_sun)² + (DHI σ_sky)²) is linear in the light factor f, so
    d ΣSD/df = ΣSD/f, also where a segment's SEs are 0 (a shaded blade, a sensor, an emulated
    source), where √'s infinite slope at 0 made it NaN (grad and jvp, with and without jit)."""
    from lightfit.light.estimator import PARTS
    from lightfit.model.scenario import Forcing

    T, S = 2, 3
    fc = Forcing(
        day=np.array([True, True]),
        dni_par=np.array([1500.0, 0.0]),
        dhi_par=np.array([300.0, 200.0]),
        tair_c=np.full(T, 20.0),
        co2_ppm=np.full(T, 410.0),
        rh=np.full(T, 0.5),
        pair_kpa=np.full(T, 101.325),
    )
    op = type("Op", (), {"forcing": fc})()
    values = jnp.full((T, len(PARTS), S), 0.3)
    se = jnp.asarray(np.random.default_rng(0).uniform(0.001, 0.01, (T, len(PARTS), S))).at[:, :, 1].set(0.0)

    def total_sd(f):
        return jnp.sum(O.ObservationOperator.light(op, values, se, "absorbed", f)[1])

    expected = float(total_sd(1.3)) / 1.3
    for fn in (total_sd, jax.jit(total_sd)):
        assert float(jax.grad(fn)(1.3)) == pytest.approx(expected, rel=1e-12)
        assert float(jax.jvp(fn, (1.3,), (1.0,))[1]) == pytest.approx(expected, rel=1e-12)


def test_a_light_factor_beyond_the_leaves_range_is_named(noon_model):
    """`replicate --theta light_factor=9` ended in a traceback from the photosynthesis's range check
    (absorbed PAR above 1e4): refused naming the light factor; traced (calibration, sampling) the
    blades are flagged unconverged instead, which gives that point no likelihood."""
    import jax

    from lightfit.model.observe import CONVERGENCE_KEY

    parts = noon_model.render(Theta())
    m = noon_model.with_light(lambda theta: parts)
    with pytest.raises(InputError, match="light_factor=9 gives the blades up to") as e:
        m.observe(Theta(light_factor=9.0))
    assert e.value.column == "theta"
    flagged = jax.jit(lambda f: m.observe(Theta(light_factor=f))[CONVERGENCE_KEY])(9.0)
    assert int(np.asarray(flagged).sum()) > 0
    assert int(np.asarray(m.observe(Theta(light_factor=2.0))[CONVERGENCE_KEY]).sum()) == 0


def test_blade_light_beyond_the_leaves_range_at_light_factor_1_names_the_renders_noise(noon_model):
    """`replicate --quick --direct-rays-per-m2 300`: one projected ray's flux on a small blade gave it
    22349 µmol m-2 s-1 at light_factor=1, refused as if the light factor were too large ("a smaller
    light_factor"). At light_factor=1 the cause is the render's noise: named, with that blade's
    Monte Carlo SD, and the options that reduce it."""
    values, se = noon_model.render(Theta())
    values, se = np.array(values), np.array(se)
    blade = int(np.flatnonzero(noon_model.operator.is_blade)[3])
    sun = PARTS.index("absorbed_sun")
    values[:, sun, blade] = 40.0  # per unit DNI: ~40 × full sun, far beyond 1e4 µmol m-2 s-1
    se[:, sun, blade], se[:, PARTS.index("absorbed_sky"), blade] = 35.0, 0.0
    m = noon_model.with_light(lambda theta: (values, se))
    with pytest.raises(InputError, match="at light_factor=1") as e:
        m.observe(Theta())
    msg = str(e.value)
    assert "Monte Carlo" in msg and "--direct-rays-per-m2" in msg and "--samples" in msg
    assert "smaller light_factor" not in msg and e.value.column == "direct_rays_per_m2"
    # the blade's light and its SD, from the forcing's PAR at the brightest daytime step
    fc = noon_model.operator.forcing
    day = np.flatnonzero(fc.day)
    dni, dhi = np.asarray(fc.dni_par)[day], np.asarray(fc.dhi_par)[day]
    t = int(np.argmax(40.0 * dni + dhi * values[:, PARTS.index("absorbed_sky"), blade]))
    expected = 40.0 * dni[t] + dhi[t] * values[t, PARTS.index("absorbed_sky"), blade]
    assert f"{expected:.0f} ± {35.0 * dni[t]:.0f}" in msg
    # where, as results.nc names it: the blade's segment id and the step's time in UTC (it said
    # "blade 3", an index among the blade columns that no file shows)
    seg_id = int(noon_model.segment_id[blade])
    step = int(day[t])
    when = noon_model.times[step].tz_convert("UTC").tz_localize(None).isoformat()
    assert f"(step {step}, time {when} UTC, segment {seg_id})" in msg, msg
    assert seg_id != 3  # not the blade column's index (the fourth blade)
    # a model cut to some steps (emulator.restrict, a calibration's) names the same instant
    from lightfit.model import emulator as E

    assert fc.day.all()  # every step of the window is rendered: the parts' rows are the steps
    keep = np.arange(len(fc.day)) >= 2
    cut = E.restrict(noon_model, keep).with_light(lambda theta: (values[keep], se[keep]))
    with pytest.raises(InputError, match=f"step {step - 2}, time {when} UTC, segment {seg_id}"):
        cut.observe(Theta())


@pytest.mark.parametrize(
    "name, value",
    [("light_factor", -1.0), ("light_factor", 0.0), ("vcmax_scale", 0.0), ("specular", 1.5), ("roughness", -0.1)]
    + [("subsurface", float("nan"))],
)
def test_a_traced_theta_outside_its_domain_has_no_likelihood(noon_model, name, value):
    """Under jax.jit a light factor of -1 gave negative PAR that the leaves took as dark, finite and
    'converged', and a specular of 1.5 the specular-1 leaf with a zero gradient (an adversarial
    review; eagerly both are refused). Traced, every blade is flagged unconverged, so the loss is
    inf and the log-likelihood -inf; at the domains' edges (specular 0 and 1) the point stands."""
    import jax

    from lightfit.inference.likelihood import GaussianLikelihood
    from lightfit.model.observe import CONVERGENCE_KEY
    from lightfit.model.parameters import NAMES, outside_domain

    parts = noon_model.render(Theta())
    m = noon_model.with_light(lambda theta: parts)
    with pytest.raises(InputError, match=name):
        m.observe(Theta().replace(**{name: value}))  # eagerly: refused, as before
    flag = jax.jit(lambda x: m.observe(Theta().replace(**{name: x}))[CONVERGENCE_KEY])(value)
    assert (np.asarray(flag) == len(m.operator.blades)).all()  # every blade, a count of blades still
    t = m.times[[2]]
    obs = pd.DataFrame({"plant_par_umol_m2_s": [900.0], "plant_par_sd_umol_m2_s": [50.0]}, index=t)
    lik = GaussianLikelihood(obs, m.times, ["plant_par"])
    x = jnp.array([float(getattr(Theta(), n)) for n in NAMES]).at[NAMES.index(name)].set(value)
    loss = jax.jit(lambda v: lik.loss(m.observe(Theta().with_vector(NAMES, v))))
    assert float(loss(x)) == np.inf
    assert np.isfinite(float(loss(x.at[NAMES.index(name)].set(float(getattr(Theta(), name))))))
    for edge in (0.0, 1.0):
        assert not bool(outside_domain(Theta(specular=edge)))
        ok = jax.jit(lambda s: m.observe(Theta(specular=s))[CONVERGENCE_KEY])(edge)
        assert int(np.asarray(ok).sum()) == 0


def test_light_factor_from_the_chamber_record_is_near_one(noon_model):
    """Issue 14's done-when: calibrated against the chamber's above-canopy PAR with the matching
    operator, the light factor is in 0.9–1.1 (it was ≈ 3.9 against absorbed PAR at the plants).

    The real calibration path (likelihood, BFGS) on the bundled forcing; the light factor does
    not enter the render, so one render is stored and reused. With one observation y between steps
    k and k + 1 the optimum is y / ((1 − w) P_k + w P_{k+1}) (P: the sensor at f = 1, w the reading's
    fraction of the way from t_k to t_{k+1}), an independent check of the optimiser and of the
    interpolation in time. The reconstructed forcing was anchored on this very reading (its header's
    ``anchor``: 1549.31 µmol m⁻² s⁻¹ at 12:13:48 local), so f is 1 up to linear interpolation's
    error on the morning's curved PAR between 30-min steps (1546.15 read from the file's own rows:
    0.2 %). Read at the nearest step instead, 13.8 min earlier, f was 1.023."""
    m = noon_model
    parts = m.render(Theta())
    stored = m.with_light(lambda theta: parts)
    rec = read_observations(rep.OBSERVATIONS)
    res = calibrate(stored, rec, names=("light_factor",), use=("above_canopy_par",), progress=False)
    f = res.theta["light_factor"]
    t = rec.index[0]
    k = int(np.searchsorted(m.times, t)) - 1
    w = (t - m.times[k]) / (m.times[k + 1] - m.times[k])
    p = np.asarray(stored.observe(Theta())["above_canopy_par_umol_m2_s"])
    y = rec.iloc[0]["above_canopy_par_umol_m2_s"]
    print(f"calibrated light factor {f:.4f} (analytic {y / ((1 - w) * p[k] + w * p[k + 1]):.4f}, w {w:.3f})")
    assert res.converged
    assert 0.4 < w < 0.6  # the reading lies well between two steps
    assert f == pytest.approx(y / ((1 - w) * p[k] + w * p[k + 1]), rel=1e-4)
    assert f == pytest.approx(1.0, abs=0.003)


def _unconverged_ds():
    t = pd.date_range("2016-04-20 10:00", periods=3, freq="30min").values
    conv = np.ones((3, 4), bool)
    conv[1, [0, 2]] = False
    conv[2, 3] = False  # not a blade: does not count
    return xr.Dataset(
        {
            "converged": (("time", "segment"), conv),
            "limitation": (("time", "segment"), np.zeros((3, 4), np.int8)),
            "sun_elevation_deg": ("time", [40.0, 45.0, 48.0]),
        },
        coords={"time": t, "segment": np.arange(4), "is_blade": ("segment", [True, True, True, False])},
    )


def test_unconverged_solves_are_counted_and_warned():
    ds = _unconverged_ds()
    with pytest.warns(NonConvergenceWarning, match=r"2 blade-step\(s\) of 3 blades at 1 step\(s\): 2016-04-20 10:30"):
        assert warn_unconverged(ds) == 2
    assert summary(ds)["unconverged_blades"].tolist() == [0, 2, 0]
    ok = ds.assign(converged=ds["converged"] | True)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert warn_unconverged(ok) == 0


def test_cli_shows_lightfit_warnings_as_one_line():
    """The command line prints a lightfit warning as one ``warning: …`` line on stderr (exit 0)."""
    import typer
    from typer.testing import CliRunner

    from lightfit.cli.common import LightfitGroup

    app = typer.Typer(cls=LightfitGroup)

    @app.command()
    def go():
        warnings.warn("leaf photosynthesis did not converge for 2 blade-step(s)", NonConvergenceWarning, stacklevel=1)

    @app.command()
    def other():
        pass

    r = CliRunner().invoke(app, ["go"])
    assert r.exit_code == 0, r.output
    assert r.stderr.strip().splitlines() == ["warning: leaf photosynthesis did not converge for 2 blade-step(s)"]


def test_figure_with_a_compared_preset(noon_model, tmp_path):
    """The figure draws a second run beside the first; runs are named by their preset."""
    import json
    from dataclasses import asdict

    from lightfit.report import plot, preset_name

    ds = noon_model.simulate(Theta())
    a, b = (
        ds.assign_attrs(replication_config=json.dumps(asdict(c)), preset=c.preset)
        for c in (rep.ReplicationConfig.quick(), rep.ReplicationConfig.quick().with_preset("paper"))
    )
    assert (preset_name(a.attrs), preset_name(b.attrs), preset_name({}, "x")) == ("default", "paper", "x")
    assert plot(a, tmp_path / "f.png", compare=b).stat().st_size > 10_000


def test_figure_title_gives_the_compared_runs_own_size(noon_model):
    """--compare-preset paper runs the paper's leaf and field with K and bounces resolved for them (64
    from the paths, 8 for the grey leaf, where the main job has 32 and 2): the title gave the main
    run's plants and K alone, read as the dashed run's too. Each run's line now says its own."""
    import json
    from dataclasses import asdict

    import matplotlib.pyplot as plt

    from lightfit.report import figure

    ds = noon_model.simulate(Theta())  # the quick configuration: 2 × 2 plants, K=16, 2 bounces
    paper = rep.ReplicationConfig.quick().with_preset("paper")
    other = ds.assign_attrs(
        replication_config=json.dumps(asdict(paper)), preset="paper", n_plants=9, samples=64, bounces=8
    )
    fig = figure(ds, compare=other)
    try:
        lines = fig._suptitle.get_text().splitlines()
        assert lines[0].endswith("; 4 plants, K=16, 2 bounces"), lines
        assert lines[-1].startswith("paper: ") and lines[-1].endswith(" (dashed; 9 plants, K=64, 8 bounces)"), lines
    finally:
        plt.close(fig)


def test_figure_says_whose_bands_they_are_beside_a_compared_run(noon_model):
    """Panel (b)'s 10–90 % band and panel (c)'s ±2 Monte Carlo SD band are drawn for the main
    (solid) run alone; beside a compared (dashed) run their labels did not say so, and could be read
    as the compared run's too. They name the main run where a compared run is drawn, and only then."""
    import json
    from dataclasses import asdict

    import matplotlib.pyplot as plt

    from lightfit.report import figure

    ds = noon_model.simulate(Theta()).assign_attrs(preset="default")
    paper = rep.ReplicationConfig.quick().with_preset("paper")
    other = ds.assign_attrs(replication_config=json.dumps(asdict(paper)), preset="paper")
    for compare, said in ((other, " — solid line (default) only"), (None, "")):
        fig = figure(ds, compare=compare)
        try:
            _, ax_b, ax_c = fig.axes[:3]
            bands = [
                t.get_text()
                for ax in (ax_b, ax_c)
                for t in ax.get_legend().get_texts()
                if t.get_text().startswith(("10–90 %", "± SD", "± 2 Monte Carlo SD"))
            ]
            assert len(bands) == 2, bands
            assert bands[0].startswith(("10–90 % of the segments' area", "± SD of segments")), bands
            assert bands[1].startswith("± 2 Monte Carlo SD"), bands
            assert all(b.endswith(said) for b in bands) and (said or "solid" not in " ".join(bands)), bands
        finally:
            plt.close(fig)


def test_figure_names_the_observations_provenance(noon_model):
    """Synthetic observations are drawn as synthetic, in the legend and the title (a review found
    every observation labelled "observed (chamber quantum sensor …)", whatever its file said)."""
    import json

    import matplotlib.pyplot as plt

    from lightfit.report import figure

    ds = noon_model.simulate(Theta())
    par = np.full(ds.sizes["time"], np.nan)
    par[0] = 1500.0
    ds["obs_above_canopy_par_umol_m2_s"] = ("time", par)
    ds["obs_above_canopy_par_sd_umol_m2_s"] = ("time", par * 0.05)
    ds.attrs.update(observations="/x/twin.csv (synthetic)", observations_provenance="synthetic")
    fig = figure(ds)
    try:
        labels = [t.get_text() for ax in fig.axes for t in ax.get_legend().get_texts()]
        assert "synthetic PAR above the canopy (± its SD)" in labels, labels
        assert not any(lab.startswith("measured") or "chamber" in lab for lab in labels), labels
        assert "SYNTHETIC observations (twin.csv)" in fig._suptitle.get_text()
    finally:
        plt.close(fig)
    del ds.attrs["observations_provenance"]  # files written before the attribute: the word in "observations"
    fig = figure(ds)
    try:
        labels = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
        assert "synthetic PAR above the canopy (± its SD)" in labels
    finally:
        plt.close(fig)
    # The chamber point the bundled forcing was scaled to agrees by construction, and the legend says
    # so (a newcomer review read panel (a) as a validation); the anchor comes from the forcing's header.
    assert json.loads(ds.attrs["weather_anchor"])["par_umol_m2_s"] == 1549.31
    ds["obs_above_canopy_par_umol_m2_s"] = ("time", np.where(np.isnan(par), np.nan, 1549.31))
    fig = figure(ds)
    try:
        labels = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
        assert "synthetic PAR above the canopy (± its SD); the forcing is scaled to it" in labels, labels
    finally:
        plt.close(fig)


def test_figure_band_is_the_segments_area_range_and_the_title_names_a_given_theta(noon_model):
    """Panel (b)'s band is the 10–90 % range of the segments' area (area-weighted quantiles, checked
    against numpy's on area-repeated values): mean ± SD was cut at 0, lopsided for a skewed PAR. A
    run with --theta says so in the title (it said "default" only). The results name the software
    and the Mitsuba variant that made them."""
    import json

    import matplotlib.pyplot as plt

    from lightfit.report import area_quantiles, figure

    ds = noon_model.simulate(Theta())
    v = ds["absorbed_par_umol_m2_s"].values
    area = ds["area_m2"].values
    lo, hi = area_quantiles(v, area, (0.1, 0.9))
    units = np.maximum(np.round(area / area.min()).astype(int), 1)  # integer weights: repeat each value
    for k in range(v.shape[0]):
        rep_k = np.repeat(v[k], units)
        q = np.quantile(rep_k, [0.1, 0.9], method="inverted_cdf")
        w_lo, w_hi = area_quantiles(v[k : k + 1], units.astype(float), (0.1, 0.9))
        assert (w_lo[0], w_hi[0]) == (q[0], q[1])
    assert (lo <= hi).all() and (hi > lo).any()
    # several days' results: a segment is NaN on the other day and weighs nothing there (the band's
    # top was NaN and its bottom too high); each day's band is its own
    two = np.full((2, 2 * v.shape[1]), np.nan)
    two[0, : v.shape[1]], two[1, v.shape[1] :] = v[0], v[-1]
    both = area_quantiles(two, np.r_[area, area], (0.1, 0.9))
    np.testing.assert_array_equal(both[:, 0], area_quantiles(v[:1], area, (0.1, 0.9))[:, 0])
    np.testing.assert_array_equal(both[:, 1], area_quantiles(v[-1:], area, (0.1, 0.9))[:, 0])
    assert np.isnan(area_quantiles(np.full((1, 3), np.nan), np.ones(3), (0.5,))).all()
    versions = json.loads(ds.attrs["software_versions"])
    assert set(versions) >= {"lightfit", "estimator", "mitsuba", "drjit", "jax", "cplantbox"}
    assert ds.attrs["mitsuba_variant"].startswith("llvm_ad_")
    cpu, _, lanes = backend.llvm_target()  # what drjit-core compiled the renders for
    assert ds.attrs["llvm_target"].startswith(f"{cpu}, {lanes} lanes (")
    ds.attrs["theta_given"] = json.dumps({"specular": 0.7375, "light_factor": 1.1})
    fig = figure(ds)
    try:
        b = fig.axes[1]
        labels = [t.get_text() for t in b.get_legend().get_texts()]
        assert "10–90 % of the segments' area" in labels, labels
        # per leaf/stem area in (b), per ground area in (a): canopy APAR, a flux per ground area, was
        # drawn on (b)'s axis beside the per-segment-area PAR (a review of the main job's figure)
        a_labels = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
        assert not any("APAR" in lab for lab in labels), labels
        assert any(lab.startswith("absorbed by the canopy, APAR") for lab in a_labels), a_labels
        assert "ground s⁻¹" in fig.axes[0].get_ylabel() and "leaf/stem s⁻¹" in b.get_ylabel()
        band = next(c for c in b.collections if c.get_label() == "10–90 % of the segments' area")
        path = band.get_paths()[0].vertices[:, 1]
        np.testing.assert_allclose(np.unique(path), np.unique(np.r_[lo, hi]), rtol=1e-12)
        assert "θ given: specular 0.7375, light_factor 1.1" in fig._suptitle.get_text()
        # the legends too: "model (default)" beside a given θ read as the preset's leaf
        assert any(lab.startswith("absorbed PAR") and lab.endswith(", θ given)") for lab in labels), labels
    finally:
        plt.close(fig)
    # A long run label (a given θ, the capacity profile, overrides) wraps inside the figure: the
    # review's calibrated fit had the title's model line cut at both edges of replication.png.
    ds.attrs.update(vcmax_profile="lloyd2010", photosynthesis_overrides=json.dumps({"vcmax_ref_umol_m2_s": 85.0}))
    fig = figure(ds)
    try:
        fig.canvas.draw()
        box = fig._suptitle.get_window_extent()
        assert box.x0 >= 0 and box.x1 <= fig.bbox.width, (box, fig.bbox.width)
    finally:
        plt.close(fig)


def test_an_per_leaf_changes_canopy_an_only():
    """``an_per="leaf"`` divides canopy An by the blade area instead of the ground; NEE (a chamber's
    flux per ground area) and APAR must not move. Plain numpy on random per-segment fields (a mutation
    audit: NEE built from the per-leaf An, off by the LAI, passed every test)."""
    rng = np.random.default_rng(3)
    t, s = 4, 9
    blade = np.array([True, True, False, True, True, False, True, True, True])
    area = rng.uniform(1e-4, 3e-4, s)
    absorbed, absorbed_sd = rng.uniform(0, 900, (t, s)), rng.uniform(1, 20, (t, s))
    an, an_sd = rng.uniform(-2, 30, (t, blade.sum())), rng.uniform(0.1, 1, (t, blade.sum()))
    above = rng.uniform(100, 2000, t)
    ground = 0.45 * area[blade].sum()  # LAI ≈ 2.2
    out = {}
    for per in ("ground", "leaf"):
        den = O.an_denominator(area[blade], per, ground)
        out[per] = O.observables(
            absorbed, absorbed_sd, area, an, an_sd, area[blade], den,
            absorbed=absorbed, absorbed_mc_sd=absorbed_sd, ground_area_m2=ground, above_par=above,
            soil_respiration_umol_m2_s=1.5,
        )  # fmt: skip
    an_ground = an @ area[blade] / ground
    np.testing.assert_allclose(out["ground"]["canopy_an_umol_m2_s"], an_ground, rtol=1e-12)
    np.testing.assert_allclose(out["leaf"]["canopy_an_umol_m2_s"], an @ area[blade] / area[blade].sum(), rtol=1e-12)
    for per in ("ground", "leaf"):
        o = out[per]
        np.testing.assert_allclose(o["nee_umol_m2_s"], 1.5 - an_ground, rtol=1e-12)
        np.testing.assert_allclose(o["nee_mc_sd_umol_m2_s"], np.sqrt(an_sd**2 @ (area[blade] / ground) ** 2))
        np.testing.assert_allclose(o["canopy_apar_umol_m2_s"], absorbed @ area / ground, rtol=1e-12)
        np.testing.assert_allclose(o["fapar"], absorbed @ area / ground / above, rtol=1e-12)


def test_the_observation_tables_digest_changes_with_a_value_or_the_time_label_only(tmp_path):
    """calibrate refuses a rerun on another observation table by this digest: the same readings read
    twice or written in another row order agree; an edited value or another time label (readings
    as interval means, which meet the steps otherwise) does not."""
    from lightfit.inference.observations import observation_table_digest

    columns = "time,above_canopy_par_umol_m2_s,above_canopy_par_sd_umol_m2_s\n"
    head = "# provenance: synthetic\n# time_zone: UTC\n{label}" + columns
    rows = ["2016-04-20T10:00:00Z,1500,75\n", "2016-04-20T10:30:00Z,1600,80\n"]
    files = {}
    for name, label, body in (
        ("a", "", rows),
        ("b", "", rows[::-1]),
        ("edited", "", [rows[0], rows[1].replace("1600", "1601")]),
        ("means", "# time_label: end\n# averaging_interval: 30min\n", rows),
    ):
        files[name] = tmp_path / f"{name}.csv"
        files[name].write_text(head.format(label=label) + "".join(body))
    d = {k: observation_table_digest(read_observations(f)) for k, f in files.items()}
    assert d["a"] == d["b"] == observation_table_digest(read_observations(files["a"]))
    assert len({d["a"], d["edited"], d["means"]}) == 3


@pytest.mark.parametrize(("sd", "said"), [("-20", "(SD -20)"), ("0", "(SD 0)"), ("", "(SD missing)")])
def test_a_value_without_a_positive_sd_is_refused_with_its_sd(tmp_path, sd, said):
    """A negative, zero or missing SD is refused at its line and column, saying which (a review: the
    message was the same for all three and did not show the value)."""
    f = tmp_path / "obs.csv"
    rows = f"2016-04-20T10:00:00Z,1500,75\n2016-04-20T10:30:00Z,1600,{sd}\n"
    head = "# provenance: synthetic\n# time_zone: UTC\ntime,above_canopy_par_umol_m2_s,above_canopy_par_sd_umol_m2_s\n"
    f.write_text(head + rows)
    where = "obs.csv, line 5, column 'above_canopy_par_sd_umol_m2_s'"
    with pytest.raises(InputError, match=rf"{where}: .*{re.escape(said)}"):
        read_observations(f)


@pytest.mark.parametrize("sd", ["1e200", "1e-200"])
def test_an_sd_whose_weight_leaves_float64_is_refused(tmp_path, sd):
    """An SD of 1e200 (or 1e-200) has an inverse square of 0 (inf): the step's inverse-variance
    mean was 0/0, the reading NaN, dropped from the comparison and the fit with a RuntimeWarning
    only (a review). Refused at its line, in the file and in a table built in code."""
    from lightfit.inference.observations import SD_RANGE, check_sds

    f = tmp_path / "obs.csv"
    rows = f"2016-04-20T10:00:00Z,1500,{sd}\n2016-04-20T10:30:00Z,1600,80\n"
    head = "# provenance: synthetic\n# time_zone: UTC\ntime,above_canopy_par_umol_m2_s,above_canopy_par_sd_umol_m2_s\n"
    f.write_text(head + rows)
    assert not SD_RANGE[0] <= float(sd) <= SD_RANGE[1]
    said = re.escape(f"{float(sd):g}")  # 1e+200
    with pytest.raises(InputError, match=rf"line 4, column 'above_canopy_par_sd_umol_m2_s': .*is {said}.*an SD in"):
        read_observations(f)
    table = pd.DataFrame(
        {"above_canopy_par_umol_m2_s": [1500.0, 1600.0], "above_canopy_par_sd_umol_m2_s": [float(sd), 80.0]},
        index=pd.DatetimeIndex(["2016-04-20T10:00Z", "2016-04-20T10:30Z"]),
    )
    with pytest.raises(InputError, match="an SD in"):
        check_sds(table)
    # the edges are numbers still: the weights and a χ² of a 10⁴ residual stay finite
    w = np.array(SD_RANGE) ** -2.0
    assert np.isfinite(w).all() and (w > 0).all() and np.isfinite((1e4 / SD_RANGE[0]) ** 2)


def test_a_file_without_a_single_reading_is_refused(tmp_path):
    """Value columns empty in every row: `replicate --observations` reported '2 of 2 with their
    nearest step' and compared nothing (a review); calibrate refused it only later, as a likelihood
    without data. Refused where it is read, naming the file and the empty series."""
    f = tmp_path / "empty.csv"
    head = "# provenance: measured\n# time_zone: UTC\ntime,above_canopy_par_umol_m2_s,above_canopy_par_sd_umol_m2_s\n"
    f.write_text(head + "2016-04-20T10:00:00Z,,5\n2016-04-20T10:30:00Z,,\n")
    with pytest.raises(InputError, match=r"empty\.csv: no reading: above_canopy_par_umol_m2_s empty in every row"):
        read_observations(f)
    f.write_text(head + "2016-04-20T10:00:00Z,,5\n2016-04-20T10:30:00Z,1500,75\n")
    assert read_observations(f)["above_canopy_par_umol_m2_s"].notna().sum() == 1  # one reading is a comparison


def test_summary_light_limited_share_counts_blades_with_a_value():
    """frac_light_limited: of the blades with a limitation (−1 = none), the share electron-transport
    limited (1); NaN where no blade has one; a stem (not a blade) never counts."""
    ds = _unconverged_ds()
    lim = np.array([[1, 0, -1, 1], [-1, -1, -1, 1], [1, 1, 0, 0]], np.int8)
    got = summary(ds.assign(limitation=(("time", "segment"), lim)))["frac_light_limited"].to_numpy()
    np.testing.assert_allclose(got, [1 / 2, np.nan, 2 / 3])


def test_area_quantiles_take_the_smallest_value_reaching_the_share():
    """The q-quantile is the smallest value at or below which at least q of the area lies: with cumulative
    shares landing exactly on q, that value itself (numpy's inverted_cdf), not the next one."""
    from lightfit.report import area_quantiles

    np.testing.assert_array_equal(
        area_quantiles([[4.0, 1.0, 3.0, 2.0]], np.ones(4), (0.25, 0.5, 0.75, 1.0)).ravel(), [1, 2, 3, 4]
    )
    # areas 1, 1, 2 on values 5, 1, 3: shares 0.25 (1), 0.75 (3), 1.0 (5)
    np.testing.assert_array_equal(
        area_quantiles([[5.0, 1.0, 3.0]], [1.0, 1.0, 2.0], (0.25, 0.26, 0.75, 0.76)).ravel(), [1, 3, 3, 5]
    )


def test_field_label_names_the_buffers():
    """In words, one row or plant singular; results written before buffer_along had as many buffer plants
    along the rows as buffer rows."""
    from lightfit.report import field_label

    assert field_label({"boundary": "finite", "buffer_rows": 1}) == "finite field, 1 buffer row"
    assert field_label({"buffer_rows": 2, "buffer_along": 2}) == "finite field, 2 buffer rows"
    assert field_label({"buffer_rows": 1, "buffer_along": 3}) == "finite field, 1 buffer row and 3 plants along"
    assert field_label({"buffer_rows": 3, "buffer_along": 1}) == "finite field, 3 buffer rows and 1 plant along"
    assert (
        field_label({"boundary": "periodic", "buffer_rows": 0}) == "periodic boundary (one cell of an infinite field)"
    )


def test_canopy_apar_and_fapar_are_absorbed_par_whatever_the_plant_par_kind():
    """APAR and fAPAR are the canopy's *absorbed* PAR even where plant PAR is the incident kind (a
    mutation audit: APAR built from the plant-PAR kind passed every test, all of which ran absorbed).
    By hand: areas 0.1 and 0.3 m² on 0.2 m² of ground; absorbed 900 and 400 give
    (90 + 120) / 0.2 = 1050 µmol m⁻² s⁻¹, SD √((10·0.5)² + (20·1.5)²) = √925; over 1500 above, 0.7."""
    area = np.array([0.1, 0.3])
    incident, incident_sd = np.array([[1000.0, 500.0]]), np.array([[30.0, 40.0]])
    absorbed, absorbed_sd = np.array([[900.0, 400.0]]), np.array([[10.0, 20.0]])
    o = O.observables(
        incident, incident_sd, area, np.array([[10.0, 5.0]]), np.array([[0.1, 0.1]]), area, 0.2,
        absorbed=absorbed, absorbed_mc_sd=absorbed_sd, ground_area_m2=0.2, above_par=np.array([1500.0]),
    )  # fmt: skip
    np.testing.assert_allclose(o["plant_par_umol_m2_s"], [(1000 * 0.1 + 500 * 0.3) / 0.4], rtol=1e-12)
    # the area-weighted mean's SD: weights ¼ and ¾ squared (a mutation audit: weights not squared
    # were caught only by a slow module fixture in test_model)
    np.testing.assert_allclose(o["plant_par_mc_sd_umol_m2_s"], [((30 / 4) ** 2 + (40 * 3 / 4) ** 2) ** 0.5], rtol=1e-12)
    np.testing.assert_allclose(o["canopy_apar_umol_m2_s"], [1050.0], rtol=1e-12)
    np.testing.assert_allclose(o["canopy_apar_mc_sd_umol_m2_s"], [925.0**0.5], rtol=1e-12)
    np.testing.assert_allclose(o["fapar"], [0.7], rtol=1e-12)
    np.testing.assert_allclose(o["fapar_mc_sd"], [925.0**0.5 / 1500.0], rtol=1e-12)


def test_without_a_ceptometer_its_observables_are_nan_at_night_too():
    """With no ceptometer rendered (``sensors=()``) the schema says its observables are NaN; its
    transmittance and fAPAR were NaN by day but 0 at night, the ratios' night convention of a sensor
    that is there (a review). With one, night stays 0."""
    area = np.array([0.1])
    part = np.array([[500.0], [0.0]])
    kw = dict(absorbed=part, absorbed_mc_sd=part / 50, ground_area_m2=0.2, above_par=np.array([1500.0, 0.0]))
    o = O.observables(part, part / 50, area, np.array([[5.0], [-1.0]]), np.full((2, 1), 0.1), area, 0.2, **kw)
    from lightfit.model.schema import SENSOR_OBSERVABLES

    for key in SENSOR_OBSERVABLES:
        assert np.isnan(o[key]).all(), (key, o[key])
    seen = O.observables(
        part, part / 50, area, np.array([[5.0], [-1.0]]), np.full((2, 1), 0.1), area, 0.2, **kw,
        transmitted=np.array([150.0, 0.0]), transmitted_mc_sd=np.array([3.0, 0.0]),
    )  # fmt: skip
    np.testing.assert_allclose(seen["ceptometer_transmittance"], [0.1, 0.0])
    np.testing.assert_allclose(seen["ceptometer_fapar"], [0.9, 0.0])


def test_the_operator_on_a_two_segment_canopy_worked_by_hand():
    """The whole operator on hand-made light parts of one blade (0.1 m²) and one stem (0.3 m²) on
    0.4 m² of ground, with a linear leaf An = 0.02·q − 1.5 (dAn/dq = 0.02), so every observable is a
    line of arithmetic (a mutation audit: the plant PAR taken from the absorbed parts whatever
    ``par_kind`` and a segment's sun and sky errors summed instead of in quadrature, or each
    weighted by the other's weather, passed every test).

    Light factor 1.5; a night step (5 °C) and a day step (DNI 1000, DHI 200 µmol m⁻² s⁻¹, sun at
    30°, 25 °C). Incident PAR: blade 1.5·(1000·0.8 + 200·0.5) = 1350, stem 1.5·(300 + 40) = 510;
    SDs 1.5·√(30² + 4²) and 1.5·√(10² + 8²). Absorbed: blade 1.5·(700 + 80) = 1170, stem
    1.5·(250 + 30) = 420, SDs 1.5·√(20² + 2²) and 1.5·√(10² + 4²)."""
    from lightfit.light.estimator import PARTS
    from lightfit.model.scenario import Forcing
    from lightfit.photosynthesis import parameter_set

    fc = Forcing(
        day=np.array([False, True]), dni_par=np.array([0.0, 1000.0]), dhi_par=np.array([0.0, 200.0]),
        tair_c=np.array([5.0, 25.0]), co2_ppm=np.full(2, 400.0), rh=np.full(2, 0.6), pair_kpa=np.full(2, 100.0),
    )  # fmt: skip
    area = np.array([0.1, 0.3])
    op = O.ObservationOperator(
        forcing=fc, area_m2=area, is_blade=np.array([True, False]), par_kind="incident", denominator_m2=0.4,
        params=parameter_set("winter_wheat"), ground_area_m2=0.4, sun_elevation_deg=np.array([-20.0, 30.0]),
        soil_respiration_umol_m2_s=2.0, soil_respiration_q10=2.0,
    )  # fmt: skip
    parts = {
        "incident_sun": ([0.8, 0.3], [0.03, 0.01]),
        "incident_sky": ([0.5, 0.2], [0.02, 0.04]),
        "absorbed_sun": ([0.7, 0.25], [0.02, 0.01]),
        "absorbed_sky": ([0.4, 0.15], [0.01, 0.02]),
    }
    values = jnp.asarray([[parts[p][0] for p in PARTS]])  # (T_day, PARTS, S)
    se = jnp.asarray([[parts[p][1] for p in PARTS]])

    def linear_leaf(q, forcing, params):
        return O.LeafResponse(0.02 * q - 1.5, jnp.full_like(q, 0.02), jnp.ones(q.shape, bool))

    o = {
        k: np.asarray(v)
        for k, v in op(values, se, Theta(light_factor=1.5), leaf=linear_leaf).items()
        if k != "photosynthesis"
    }
    # Per segment: 0 at night; the parts' errors in quadrature, each with its own part's weather.
    np.testing.assert_allclose(o["incident_par_umol_m2_s"], [[0, 0], [1350, 510]], rtol=1e-12)
    inc_sd = 1.5 * np.sqrt([30.0**2 + 4.0**2, 10.0**2 + 8.0**2])
    np.testing.assert_allclose(o["incident_par_mc_sd_umol_m2_s"], [[0, 0], inc_sd], rtol=1e-12)
    np.testing.assert_allclose(o["absorbed_par_umol_m2_s"], [[0, 0], [1170, 420]], rtol=1e-12)
    abs_sd = 1.5 * np.sqrt(20.0**2 + 2.0**2)
    # Plant PAR is the incident kind here: weights ¼ and ¾, the SD in quadrature with them.
    np.testing.assert_allclose(o["plant_par_umol_m2_s"], [0, (1350 * 0.1 + 510 * 0.3) / 0.4], rtol=1e-12)
    np.testing.assert_allclose(
        o["plant_par_mc_sd_umol_m2_s"], [0, np.hypot(inc_sd[0] / 4, 3 * inc_sd[1] / 4)], rtol=1e-12
    )
    # The blade's An from its absorbed PAR (night: −1.5, its dark respiration), per ground area.
    an = np.array([-1.5, 0.02 * 1170 - 1.5])
    np.testing.assert_allclose(o["leaf_an_umol_m2_s"][:, 0], an, rtol=1e-12)
    np.testing.assert_allclose(o["canopy_an_umol_m2_s"], an * 0.1 / 0.4, rtol=1e-12)
    np.testing.assert_allclose(o["canopy_an_mc_sd_umol_m2_s"], [0, 0.02 * abs_sd * 0.1 / 0.4], rtol=1e-12)
    # NEE: R₁₀ Q₁₀^((T − 10)/10) at each step's air temperature minus the canopy's uptake.
    soil = 2.0 * 2.0 ** (np.array([5.0 - 10.0, 25.0 - 10.0]) / 10.0)  # 2/√2 and 2·2^1.5
    np.testing.assert_allclose(o["nee_umol_m2_s"], soil - an * 0.1 / 0.4, rtol=1e-12)
    # The sensor above: 1.5·(1000·sin 30° + 200) = 1050; APAR (117 + 126)/0.4 = 607.5, fAPAR its share.
    np.testing.assert_allclose(o["above_canopy_par_umol_m2_s"], [0, 1050], rtol=1e-12)
    np.testing.assert_allclose(o["canopy_apar_umol_m2_s"], [0, 607.5], rtol=1e-12)
    stem_sd = 1.5 * np.sqrt(10.0**2 + 4.0**2)  # independent segments: in quadrature, each by its area
    np.testing.assert_allclose(
        o["canopy_apar_mc_sd_umol_m2_s"], [0, np.hypot(abs_sd * 0.1, stem_sd * 0.3) / 0.4], rtol=1e-12
    )
    np.testing.assert_allclose(o["fapar"], [0, 607.5 / 1050], rtol=1e-12)


def test_a_step_with_light_above_that_is_not_rendered_reads_no_ceptometer_fapar():
    """A step with the sun at −7° and diffuse light above (DHI 20 µmol m⁻² s⁻¹, a sensor's offset)
    is not rendered (daytime: below civil twilight, −6°): the plants and the ceptometer get no light
    there, the canopy fAPAR is 0, and the ceptometer's τ and fAPAR are 0 as at night. 1 − τ gave a
    ceptometer fAPAR of 1 there (a review). The day step: sun at 30°, DNI 1000, DHI 200; the
    ceptometer's parts 0.1 per DNI and 0.2 per DHI read 1000·0.1 + 200·0.2 = 140 under
    1000·½ + 200 = 700 above, τ = 0.2."""
    from lightfit.light.estimator import PARTS
    from lightfit.model.scenario import Forcing
    from lightfit.photosynthesis import parameter_set

    fc = Forcing(
        day=np.array([False, True]), dni_par=np.array([0.0, 1000.0]), dhi_par=np.array([20.0, 200.0]),
        tair_c=np.array([5.0, 25.0]), co2_ppm=np.full(2, 400.0), rh=np.full(2, 0.6), pair_kpa=np.full(2, 100.0),
    )  # fmt: skip
    op = O.ObservationOperator(
        forcing=fc, area_m2=np.array([0.1]), is_blade=np.array([True]), par_kind="absorbed", denominator_m2=0.4,
        params=parameter_set("winter_wheat"), ground_area_m2=0.4, sun_elevation_deg=np.array([-7.0, 30.0]),
        sensors=("ceptometer",),
    )  # fmt: skip
    blade = {"incident_sun": 0.8, "incident_sky": 0.5, "absorbed_sun": 0.7, "absorbed_sky": 0.4}
    sensor = {"incident_sun": 0.1, "incident_sky": 0.2, "absorbed_sun": 0.0, "absorbed_sky": 0.0}
    values = jnp.asarray([[[blade[p], sensor[p]] for p in PARTS]])  # (T_day, PARTS, S + 1)
    o = op(values, jnp.zeros_like(values), Theta())
    np.testing.assert_allclose(np.asarray(o["above_canopy_par_umol_m2_s"]), [20.0, 700.0], rtol=1e-12)
    np.testing.assert_allclose(np.asarray(o["transmitted_par_umol_m2_s"]), [0.0, 140.0], rtol=1e-12)
    np.testing.assert_allclose(np.asarray(o["fapar"])[0], 0.0, atol=0)
    np.testing.assert_allclose(np.asarray(o["ceptometer_transmittance"]), [0.0, 0.2], rtol=1e-12)
    np.testing.assert_allclose(np.asarray(o["ceptometer_fapar"]), [0.0, 0.8], rtol=1e-12)


def test_daytime_is_light_with_the_sun_above_minus_one_degree_or_diffuse_light_in_civil_twilight():
    """The rendered steps: DNI + DHI > 0 and the sun above −1° (where refraction already shows the
    sun's disc), or DHI > 0 with the sun above −6° (civil twilight: the sky alone lights the canopy;
    such steps at −3° and −1° were left dark under their PAR above). A beam alone below −1° is not
    light (its part is 0 below the horizon), nor diffuse light below −6° (a sensor's offset)."""
    from lightfit.model.scenario import daytime

    w = pd.DataFrame(
        {
            "sun_elevation_deg": [-7.0, -6.0, -5.9, -3.0, -1.0, -3.0, -0.5, 0.5, 30.0, 30.0],
            "dni_w_m2": [0.0, 0.0, 0.0, 0.0, 0.0, 5.0, 0.0, 5.0, 0.0, 0.0],
            "dhi_w_m2": [2.0, 2.0, 2.0, 2.0, 3.0, 0.0, 4.0, 8.0, 100.0, 0.0],
        }
    )
    np.testing.assert_array_equal(daytime(w), [False, False, True, True, True, False, True, True, True, False])


def test_soil_respiration_q10_takes_the_ends_of_its_range():
    """Q₁₀ = 1 (a constant respiration, the documented 'no temperature dependence') and 5 are accepted;
    just outside them is refused."""
    from lightfit.model.scenario import Scenario

    w = rep.forcing().iloc[[14]]
    for q10 in (1.0, 5.0):
        assert Scenario(weather=w, soil_respiration_q10=q10).soil_respiration_q10 == q10
    for q10 in (0.99, 5.01):
        with pytest.raises(InputError, match="soil_respiration_q10"):
            Scenario(weather=w, soil_respiration_q10=q10)


def test_mc_covariance_shares_each_segments_sky_error_across_steps_and_not_its_sun_error():
    """Plant PAR is linear in the parts, so its covariance is written out by hand: with weights
    w_s = a_s / Σa, step t's sky loading w_s·DHI_t·se_sky and sun loading w_s·DNI_t·se_sun;
    Cov(t, t') = Σ_s sky_t·sky_t' + δ_tt' Σ_s sun_t² (module docstring; a mutation audit: sun and sky
    rows swapped passed every test)."""
    from lightfit.model.scenario import Forcing
    from lightfit.photosynthesis import parameter_set

    two = np.ones(2)
    fc = Forcing(
        day=np.array([True, True]), dni_par=np.array([800.0, 400.0]), dhi_par=np.array([200.0, 300.0]),
        tair_c=20 * two, co2_ppm=400 * two, rh=0.6 * two, pair_kpa=100 * two,
    )  # fmt: skip
    area = np.array([1.0, 3.0])
    op = O.ObservationOperator(
        forcing=fc, area_m2=area, is_blade=np.array([True, True]), par_kind="absorbed", denominator_m2=1.0,
        params=parameter_set("winter_wheat"), ground_area_m2=1.0, sun_elevation_deg=np.array([40.0, 20.0]),
    )  # fmt: skip
    values = np.full((2, 4, 2), 0.3)  # (T_day, PARTS, S)
    se = np.zeros((2, 4, 2))
    se[:, 2] = [[0.01, 0.02], [0.03, 0.04]]  # absorbed_sun
    se[:, 3] = [[0.05, 0.06], [0.05, 0.06]]  # absorbed_sky: one error per segment for the day
    cov = O.mc_covariance(op, values, se, Theta(), ["plant_par_umol_m2_s"])
    w = area / area.sum()
    sky = w * fc.dhi_par[:, None] * se[:, 3]
    sun = w * fc.dni_par[:, None] * se[:, 2]
    want = sky @ sky.T + np.diag((sun**2).sum(1))
    np.testing.assert_allclose(cov, want, rtol=1e-10)


@pytest.mark.parametrize("series", [s.name for s in SERIES])
def test_files_and_tables_refuse_a_reading_by_the_same_rule(tmp_path, series):
    """One rule table (observations.reading_rules) serves files and tables built in code: for each
    series, a zero SD, an SD beyond float64's weights, a negative value, a percentage and a CO2 flux
    in another unit are refused by both with the same column and the same expectation (the two
    paths were parallel lists, and the CO2 message was built twice)."""
    from lightfit.inference.observations import BY_NAME, check_sds, read_observations, reading_rules

    s = BY_NAME[series]
    times = ["2016-04-20T10:00:00Z", "2016-04-20T10:30:00Z"]
    checked = set()
    for v, sd in [(0.5, 0.0), (0.5, 1e200), (-1.0, 0.1), (94.0, 0.1), (1000.0, 0.1)]:
        flagged = [r for r in reading_rules(s) if r[1](np.array([v]), np.array([sd]))[0]]
        if not flagged:
            continue
        col, _, expected, _ = flagged[0]
        f = tmp_path / "obs.csv"
        f.write_text(
            f"# provenance: synthetic\n# time_zone: UTC\ntime,{s.value},{s.sd}\n"
            f"{times[0]},0.5,0.1\n{times[1]},{v!r},{sd!r}\n"
        )
        with pytest.raises(InputError, match=rf"obs.csv, line 5, column '{col}'.*{re.escape(expected)}"):
            read_observations(f)
        table = pd.DataFrame({s.value: [0.5, v], s.sd: [0.1, sd]}, index=pd.DatetimeIndex(times))
        with pytest.raises(InputError, match=rf"column '{col}'.*{re.escape(expected)}"):
            check_sds(table)
        checked.add(expected)
    # every rule of the series was met: the two SD rules, and the value rules its kind has
    assert checked == {r[2] for r in reading_rules(s)}
    assert len(checked) == 2 + s.nonnegative + (s.unit == "1") + bool(np.isfinite(s.max_abs))


def test_a_run_of_one_step_a_day_takes_only_readings_near_its_steps():
    """Two dates cut to one step each (``--steps 14:15``): the steps' spacing was taken from the first
    two steps, a day apart, so readings from 14 hours around a step were all that step's (a review).
    A step a day from the next stands alone, as a one-step run's does (30 min)."""
    from lightfit.inference.observations import align, far_from_steps

    times = pd.DatetimeIndex(["2016-04-20T10:00Z", "2016-04-21T10:00Z"])
    obs = pd.DataFrame(
        {"plant_par_umol_m2_s": [300.0, 310.0], "plant_par_sd_umol_m2_s": [10.0, 10.0]},
        index=pd.DatetimeIndex(["2016-04-20T10:10Z", "2016-04-20T14:00Z"]),
    )
    obs.attrs = {"source": "test.csv"}
    assert far_from_steps(obs, times).tolist() == [False, True]
    with pytest.raises(InputError, match="test.csv.*2016-04-20T14:00:00\\+00:00 lies outside the run"):
        align(obs, times)
    assert align(obs.iloc[:1], times)["plant_par_umol_m2_s"].tolist()[0] == 300.0
    # steps 30 min apart on each of two days: the spacing is the steps', not the night's gap
    two = pd.DatetimeIndex(["2016-04-20T10:00Z", "2016-04-20T10:30Z", "2016-04-21T10:00Z", "2016-04-21T10:30Z"])
    assert far_from_steps(obs, two).tolist() == [False, True]


def test_a_ratio_of_light_read_at_an_unrendered_step_with_par_is_refused(tmp_path):
    """A step with diffuse light and PAR above but the sun at −9.2° is not rendered (daytime: diffuse
    light above −6°; below, a sensor's offset), so the model's fAPAR and ceptometer readings are 0
    there by convention, as at night: a ceptometer fAPAR read then is refused as one read in the
    dark is (it was accepted: the forcing had PAR). One read at −5°, in civil twilight, with light
    above is rendered and accepted (it was refused while twilight steps were left dark)."""
    from lightfit.inference.observations import check_light_scale, read_observations

    w = rep.forcing().copy()
    night, dusk = pd.Timestamp("2016-04-20 03:30", tz="UTC"), pd.Timestamp("2016-04-20 04:00", tz="UTC")
    assert w.loc[night, "sun_elevation_deg"] == pytest.approx(-9.20, abs=0.01)
    assert w.loc[dusk, "sun_elevation_deg"] == pytest.approx(-5.03, abs=0.01)
    w.loc[[night, dusk], ["dhi_w_m2", "par_umol_m2_s"]] = (5.0, 11.0)
    f = tmp_path / "obs.csv"
    f.write_text(
        "# provenance: synthetic\n# time_zone: UTC\ntime,ceptometer_fapar,ceptometer_fapar_sd\n"
        "2016-04-20 10:00,0.9,0.03\n2016-04-20 03:30,0.9,0.03\n",
        encoding="utf-8",
    )
    with pytest.raises(InputError, match=r"ceptometer_fapar read at 2016-04-20T03:30.*not rendered: DNI \+ DHI > 0"):
        check_light_scale(read_observations(f), w)
    # the rule's two angles with the Unicode minus the messages use (the second had an ASCII hyphen)
    with pytest.raises(InputError, match="the sun above −1°, or DHI > 0 with the sun above −6°\\)"):
        check_light_scale(read_observations(f), w)
    f.write_text(f.read_text().replace("2016-04-20 03:30,0.9,0.03\n", "2016-04-20 04:00,0.9,0.03\n"))
    check_light_scale(read_observations(f), w)  # daylight and civil twilight: no error
