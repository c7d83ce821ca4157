"""The coupled-model package: ground area, the one observation operator on every path, the results schema."""

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pandas as pd
import pytest

import lightfit  # noqa: F401
from lightfit import replication as rep
from lightfit.distributed.run import FieldRun, TaskSpec, gather, run_task
from lightfit.errors import InputError
from lightfit.light.bsdf import LEAF_PARAMETERS
from lightfit.model import emulator as E
from lightfit.model import schema
from lightfit.model.coupled import CoupledModel
from lightfit.model.parameters import Theta
from lightfit.model.scenario import Scenario
from lightfit.photosynthesis import solve
from lightfit.plant import Field

FIELD = Field(boundary="finite", n_plants=4, buffer_rows=1, seed=1)
THETA = Theta(specular=0.6, roughness=0.4, subsurface=0.2, light_factor=1.3, vcmax_scale=0.8)


@pytest.fixture(scope="module")
def weather():
    return rep.forcing().iloc[[1, 5, 14]]  # 05:30 local (night), 07:30 (low sun), 12:00


@pytest.fixture(scope="module")
def run(weather):
    sc = Scenario(weather=weather, field=FIELD, samples=8, bounces=2, par_kind="absorbed")
    return FieldRun(sc, tiles=2, theta=THETA)


@pytest.fixture(scope="module")
def model(run):
    return CoupledModel(run.scenario)


@pytest.fixture(scope="module")
def full(model):
    return model.observe(THETA)


@pytest.fixture(scope="module")
def simulated(model):
    return model.simulate(THETA)


def test_scenario_defaults_are_the_credible_defaults(weather):
    """A bare Scenario is lightfit's default model, not the reference paper's setup: a periodic
    cell (no buffer rows on bare soil), the bounces the leaf needs for 1 % truncation, and the
    plant-PAR observable and photosynthesis set of ReplicationConfig (the command line's defaults)."""
    from lightfit.light.estimator import bounces_for_tolerance
    from lightfit.light.scene import Optics

    sc = Scenario(weather=weather)
    cfg = rep.ReplicationConfig()
    assert sc.field.boundary == "periodic" == cfg.boundary
    assert sc.direct == "projection"
    assert sc.bounces == cfg.render_bounces() == bounces_for_tolerance(0.01, sc.optics) == 2
    assert (sc.par_kind, sc.an_per, sc.photosynthesis) == (cfg.par_kind, cfg.an_per, cfg.photosynthesis)
    assert Scenario(weather=weather, optics=Optics.preset("paper")).bounces == 8  # the grey leaf
    assert Scenario(weather=weather, bounces=3).bounces == 3


def test_ground_area_is_plants_times_spacings(weather):
    fld = Field(
        boundary="finite", n_plants=7, buffer_rows=1, row_spacing_m=0.2, plant_spacing_m=0.05
    )  # rounds up to 3×3
    assert fld.ground_area_m2 == pytest.approx(9 * 0.2 * 0.05)
    tiles = fld.tiles(3)
    areas = [fld.measured_area_m2(t) for t in tiles]
    assert sum(areas) == pytest.approx(fld.ground_area_m2)
    assert areas[0] == pytest.approx(len(tiles[0].measured) * 0.01)
    sc = Scenario(weather=weather, field=fld, n_tiles=3, tile=1)
    assert sc.ground_area_m2 == pytest.approx(3 * 0.01)  # a 1×3 block of the 3×3 area
    assert Scenario(weather=weather, field=fld).ground_area_m2 == pytest.approx(0.09)


def test_observables_against_an_independent_computation(model, full, weather):
    """Plant PAR and canopy An from the per-segment fields by plain numpy; the canopy-An Monte Carlo
    SD by central differences of the photosynthesis (the operator uses a JVP)."""
    a = model.area_m2
    absorbed = np.asarray(full["absorbed_par_umol_m2_s"])
    sd = np.asarray(full["absorbed_par_mc_sd_umol_m2_s"])
    mean = np.average(absorbed, axis=1, weights=a)
    spread = np.sqrt(np.average((absorbed - mean[:, None]) ** 2, axis=1, weights=a))
    np.testing.assert_allclose(np.asarray(full["plant_par_umol_m2_s"]), mean, rtol=1e-12)
    np.testing.assert_allclose(np.asarray(full["plant_par_spread_umol_m2_s"]), spread, rtol=1e-9, atol=1e-9)
    mc = np.sqrt(((a / a.sum()) ** 2 * sd**2).sum(axis=1))
    np.testing.assert_allclose(np.asarray(full["plant_par_mc_sd_umol_m2_s"]), mc, rtol=1e-12)
    # Night step: no light, no Monte Carlo error; dark respiration only.
    assert not model.day[0] and model.day[1:].all()
    for k in ("plant_par_umol_m2_s", "plant_par_mc_sd_umol_m2_s", "canopy_an_mc_sd_umol_m2_s"):
        assert float(full[k][0]) == 0.0, k
    assert float(full["canopy_an_umol_m2_s"][0]) < 0
    # Canopy An per ground area: 4 plants × 3 cm × 12.5 cm.
    ground = 4 * 0.03 * 0.125
    b = model.is_blade
    q = np.maximum(absorbed[:, b], 0.0)
    env = [
        np.broadcast_to(weather[c].to_numpy(float)[:, None], q.shape) for c in ("tair_c", "co2_ppm", "rh", "pair_kpa")
    ]
    # Each blade a leaf of its own capacity (the default profile): the set's Vcmax (so Jmax, Rd) and
    # g0 times its factor, solved directly, not through the operator's scaling identity.
    m = model.operator.capacity
    assert m is not None and 0 < m.min() < 0.8 and m.max() <= 1.0  # the top blade may be a buffer plant's
    p = model.operator.photosynthesis_params(THETA.vcmax_scale)
    params = eqx.tree_at(
        lambda x: (x.fvcb.vcmax_ref_umol_m2_s, x.stomata.g0_mol_m2_s),
        p,
        (p.fvcb.vcmax_ref_umol_m2_s * jnp.asarray(m), p.stomata.g0_mol_m2_s * jnp.asarray(m)),
    )

    def an(x):
        return np.asarray(solve(jnp.asarray(x), *env, params).an_umol_m2_s)

    np.testing.assert_allclose(np.asarray(full["canopy_an_umol_m2_s"]), an(q) @ a[b] / ground, rtol=1e-10)
    h = 1e-3
    dan = (an(q + h) - an(np.maximum(q - h, 0.0))) / (q + h - np.maximum(q - h, 0.0))
    mc_an = np.sqrt(((a[b] / ground) ** 2 * (dan * sd[:, b]) ** 2).sum(axis=1))
    np.testing.assert_allclose(np.asarray(full["canopy_an_mc_sd_umol_m2_s"]), mc_an, rtol=1e-3, atol=1e-9)
    # Canopy APAR: every measured segment's absorbed PAR over its one-sided area, per ground area;
    # fAPAR against the above-canopy sensor (0 at night).
    apar = absorbed @ a / ground
    np.testing.assert_allclose(np.asarray(full["canopy_apar_umol_m2_s"]), apar, rtol=1e-12)
    np.testing.assert_allclose(np.asarray(full["canopy_apar_mc_sd_umol_m2_s"]), np.sqrt(sd**2 @ (a / ground) ** 2))
    # The sensor above the canopy reads the weather series' own global PAR times the light factor
    # (a mutation audit: the sensor without the light factor passed this test when fAPAR was only
    # compared with the model's own reading).
    above = np.asarray(full["above_canopy_par_umol_m2_s"])
    assert above[0] == 0
    np.testing.assert_allclose(above, THETA.light_factor * weather["par_umol_m2_s"].to_numpy(), rtol=1e-9)
    np.testing.assert_allclose(np.asarray(full["fapar"])[1:], apar[1:] / above[1:], rtol=1e-12)
    # (fAPAR may exceed 1 here: a 4-plant patch with one buffer row is lit from its sides at a low sun)


def test_every_path_gives_the_same_observables(model, full, run, simulated):
    """Full renders, injected stored parts, emulated parts and the Dask gather all use one operator."""
    parts = model.render(THETA)
    stored = model.with_light(lambda theta: parts)
    assert stored.geometry is model.geometry and stored.light is not model.light
    via_stored = stored.observe(THETA)
    # An emulator of degree 0 fitted to two copies of the same render is those parts.
    design = np.array([[0.2, 0.2, 0.2], [0.8, 0.8, 0.8]])
    v, s = (np.stack([np.asarray(x)] * 2) for x in parts)
    emu = E.fit_emulator(design, v, s, [0, 0, 0], [1, 1, 1], degrees=(0,))
    fast = E.FastObservables(model, emu, n_grid=None)(THETA)
    tasks = [TaskSpec(run=run, tile=k, chunk=0, rows=run.chunk_index()[0]) for k in range(run.tiles)]
    gathered = gather([run_task(t) for t in tasks], run)
    for k in schema.OBSERVABLES:
        ref = np.asarray(full[k])
        np.testing.assert_array_equal(np.asarray(via_stored[k]), ref, err_msg=k)
        np.testing.assert_allclose(np.asarray(fast[k]), ref, rtol=1e-12, atol=1e-12, err_msg=k)
        np.testing.assert_allclose(gathered[k].values, ref, rtol=1e-12, atol=1e-12, err_msg=k)
        np.testing.assert_array_equal(simulated[k].values, ref, err_msg=k)
    # The canopy's Monte Carlo bias is a sum over blades too: tiles add up to the whole field's.
    k = "canopy_an_mc_bias_umol_m2_s"
    np.testing.assert_allclose(gathered[k].values, simulated[k].values, rtol=1e-12, atol=1e-12)
    assert np.all(simulated[k].values <= 0) and simulated[k].values.min() < 0
    assert gathered.attrs["ground_area_m2"] == pytest.approx(FIELD.ground_area_m2)


def test_theta_or_mapping(model, full):
    as_map = model.observe({**THETA.to_dict()})
    for k in schema.OBSERVABLES:
        np.testing.assert_array_equal(np.asarray(as_map[k]), np.asarray(full[k]))
    leaf = dict(zip(LEAF_PARAMETERS, (0.6, 0.4, 0.2)))
    v1, _ = model.render(leaf)
    v2, _ = model.render(THETA)
    np.testing.assert_array_equal(np.asarray(v1), np.asarray(v2))  # light_factor/vcmax do not enter the render


def test_results_carry_the_schema(simulated, tmp_path):
    ds = simulated
    assert ds.attrs["precision"] == "float64" == jnp.zeros(()).dtype.name
    for name in ds.data_vars:
        attrs = ds[name].attrs
        assert attrs["units"] and attrs["long_name"], name
        assert same_attrs(attrs, schema.variable(name).attrs()), name
    for name in ds.coords:
        assert ds[name].attrs["long_name"], name
    # Spot checks of units a reader relies on (written out here, not taken from the schema).
    expect = {
        "leaf_an_umol_m2_s": "umol m-2 s-1",
        "leaf_gs_mol_m2_s": "mol m-2 s-1",
        "leaf_ci_umol_mol": "umol mol-1",
        "dni_w_m2": "W m-2",
        "tair_c": "degC",
        "pair_kpa": "kPa",
        "sun_elevation_deg": "degree",
        "rh": "1",
        "area_m2": "m2",
    }
    for name, u in expect.items():
        assert ds[name].attrs["units"] == u, name
    # The conductance stored is to CO2, as its name says: An = gs (ca − ci) without a boundary
    # layer (a review found it labelled "to water vapour", 1.6× larger).
    assert "CO2" in ds["leaf_gs_mol_m2_s"].attrs["long_name"]
    lit = ds["absorbed_par_umol_m2_s"].values > 100.0
    assert lit.sum() > 100
    gs, ci = ds["leaf_gs_mol_m2_s"].values[lit], ds["leaf_ci_umol_mol"].values[lit]
    ca = np.broadcast_to(ds["co2_ppm"].values[:, None], lit.shape)[lit]
    np.testing.assert_allclose(gs * (ca - ci), ds["leaf_an_umol_m2_s"].values[lit], rtol=1e-6)
    assert not np.allclose(1.6 * gs * (ca - ci), ds["leaf_an_umol_m2_s"].values[lit], rtol=0.1)
    assert not any("_se_" in v or "var" in v for v in ds.data_vars)  # Monte Carlo error only as SDs
    weather_par = rep.forcing().iloc[[1, 5, 14]]["par_umol_m2_s"].to_numpy()
    np.testing.assert_allclose(ds["weather_par_umol_m2_s"].values, weather_par)  # the weather's own PAR
    # The model's above-canopy sensor: the bundled forcing's PAR is 2.285 µmol J⁻¹ × GHI and
    # DNI sin β + DHI = GHI, so the sensor reads light_factor × the weather's PAR.
    # (rtol: the bundled CSV stores PAR and GHI separately, rounded to 8 digits.)
    np.testing.assert_allclose(ds["above_canopy_par_umol_m2_s"].values, THETA.light_factor * weather_par, rtol=1e-7)
    import xarray as xr

    back = xr.open_dataset(rep.write_netcdf(ds, tmp_path / "r.nc"), engine="h5netcdf")
    try:
        assert all(back[v].attrs.get("units") for v in back.data_vars)
        assert back.attrs["precision"] == "float64"
    finally:
        back.close()


@pytest.fixture(scope="module")
def synthetic_and_run(simulated, tmp_path_factory):
    """(synthetic results, run) of the same plants and steps, in memory and read back from netCDF."""
    import xarray as xr

    from lightfit.dataset import synthetic_results

    tmp = tmp_path_factory.mktemp("synthetic_and_run")

    def read_back(ds, name):
        with xr.open_dataset(rep.write_netcdf(ds, tmp / name), engine="h5netcdf") as f:
            return f.load()

    synthetic = synthetic_results(FIELD, simulated.indexes["time"])
    return (synthetic, simulated), (read_back(synthetic, "synthetic.nc"), read_back(simulated, "run.nc"))


def test_synthetic_results_describe_the_segments_as_a_run_does(synthetic_and_run):
    """The synthetic results of the same plants carry every coordinate along ``segment`` that a run's
    results do, with equal values, dtypes and attributes (a review: they lacked height_m, is_blade and
    organ_type), and the schema's attributes on every variable, through netCDF too."""
    simulated = synthetic_and_run[0][1]
    on_segment = [c for c in simulated.coords if simulated[c].dims == ("segment",)]
    assert {"segment", "plant_id", "organ_type", "area_m2", "height_m", "is_blade"} <= set(on_segment)
    for ds, rendered in synthetic_and_run:
        assert sorted(c for c in ds.coords if ds[c].dims == ("segment",)) == sorted(on_segment)
        for c in on_segment:
            np.testing.assert_array_equal(ds[c].values, rendered[c].values, err_msg=c)
            assert ds[c].dtype == rendered[c].dtype and same_attrs(ds[c].attrs, rendered[c].attrs), c
        for name in ds.variables:
            assert same_attrs(ds[name].attrs, schema.variable(str(name)).attrs()), name


def test_synthetic_results_have_no_value_where_a_run_has_none(synthetic_and_run):
    """Every per-segment variable of the synthetic results has no value (NaN; limitation −1) on the
    segments where a run of the same plants has none, the stems and sheaths for the variables of the
    leaf blades alone, and the run's dtype, in memory and read back from netCDF (a review: their leaf
    variables had values there, limitation 0 or 1, and all were float32 where a run's are float64)."""

    def no_value(da):
        x = da.values
        return np.isnan(x) if x.dtype.kind == "f" else x == schema.variable(str(da.name)).off_blade

    for ds, rendered in synthetic_and_run:
        not_blade = ~rendered["is_blade"].values.astype(bool)
        assert not_blade.any() and not not_blade.all()  # stems and sheaths beside the blades
        per_segment = [v for v in ds.data_vars if ds[v].dims == ("time", "segment")]
        assert {"absorbed_par_umol_m2_s", "leaf_an_umol_m2_s", "leaf_vc_umol_m2_s", "limitation"} <= set(per_segment)
        for v in per_segment:
            assert ds[v].dtype == rendered[v].dtype, v
            np.testing.assert_array_equal(no_value(ds[v]), no_value(rendered[v]), err_msg=v)
            blades_only = schema.variable(v).off_blade is not None
            expect = np.broadcast_to(not_blade & blades_only, rendered[v].shape)
            np.testing.assert_array_equal(no_value(rendered[v]), expect, err_msg=v)


def test_schema_refuses_unknown_variables(simulated):
    ds = simulated[["plant_par_umol_m2_s"]].assign(mystery=("time", np.zeros(simulated.sizes["time"])))
    with pytest.raises(InputError, match="mystery"):
        schema.annotate(ds)


@pytest.mark.parametrize("set_name", ["winter_wheat", "giraud2023"])
def test_tabulated_leaf_gradient_is_finite_with_dark_blades(weather, set_name):
    """Night steps and unlit blades (q = 0) sit where the √q interpolation coordinate has an
    infinite slope; the reverse-mode gradient through the table (as the posterior's MAP search
    takes it) must stay finite and match the exact leaf's on lit blades."""
    import jax

    from lightfit.model.observe import exact_leaf, tabulated_leaf
    from lightfit.model.scenario import Forcing
    from lightfit.photosynthesis import parameter_set

    f, p = Forcing.of(weather), parameter_set(set_name)
    base = jnp.asarray([[0.0, 0.0, 0.0], [0.0, 50.0, 400.0], [0.0, 300.0, 1200.0]])

    def total(leaf, scale):
        return jnp.sum(leaf(scale * base, f, p).an)

    g_tab = float(jax.jit(jax.grad(lambda s: total(tabulated_leaf(64), s)))(1.0))
    g_exact = float(jax.jit(jax.grad(lambda s: total(exact_leaf, s)))(1.0))
    assert np.isfinite(g_tab)
    # The table's error falls as 1/n² (winter_wheat: 2.6e-2 at 8 nodes, 1.4e-3 at 32, 3.4e-4 at 64;
    # giraud2023 3.3e-5 at 64): 2e-3 holds 64 nodes with a 6-fold margin and fails 8 or 16 nodes.
    assert g_tab == pytest.approx(g_exact, rel=2e-3)


def test_tabulated_leaf_at_the_solvers_light_limit(weather):
    """A blade at exactly MAX_PAR_ABS_UMOL_M2_S (1e4, which the solver and with_capacity accept) put
    the table's top node 1e-9 beyond it: refused eagerly, every blade of the step unconverged under
    jit. Now the step converges and matches the exact leaf, eagerly and under jit; a blade beyond
    the limit is flagged, the others of its step not."""
    import jax

    from lightfit.model.observe import exact_leaf, tabulated_leaf
    from lightfit.model.scenario import Forcing
    from lightfit.photosynthesis import MAX_PAR_ABS_UMOL_M2_S, parameter_set

    f, p = Forcing.of(weather), parameter_set("winter_wheat")
    q = jnp.tile(jnp.asarray([10.0, 500.0, MAX_PAR_ABS_UMOL_M2_S]), (len(f.day), 1))
    exact = exact_leaf(q, f, p)
    for out in (tabulated_leaf(64)(q, f, p), jax.jit(lambda x: tabulated_leaf(64)(x, f, p))(q)):
        assert np.asarray(out.converged).all()
        np.testing.assert_allclose(np.asarray(out.an), np.asarray(exact.an), rtol=2e-3, atol=1e-2)
    beyond = q.at[:, 2].set(MAX_PAR_ABS_UMOL_M2_S * 1.001)
    flagged = np.asarray(jax.jit(lambda x: tabulated_leaf(64)(x, f, p).converged)(beyond))
    assert not flagged[:, 2].any() and flagged[:, :2].all()


def test_forced_non_convergence_is_warned_and_counted(model, monkeypatch):
    """A solver capped at one iteration leaves blades unconverged: simulate warns naming the steps
    and blades, and the summary table counts them per step (issue 17)."""
    from lightfit.model.coupled import NonConvergenceWarning
    from lightfit.photosynthesis.solver import SolverConfig
    from lightfit.report import summary

    parts = model.render(THETA)
    stored = model.with_light(lambda theta: parts)
    capped = SolverConfig.for_dtype.__func__
    monkeypatch.setattr(SolverConfig, "for_dtype", classmethod(lambda cls, dtype, max_steps=100: capped(cls, dtype, 1)))
    with pytest.warns(NonConvergenceWarning, match=r"did not converge for \d+ blade-step") as rec:
        ds = stored.simulate(THETA)
    blades = ds["is_blade"].values
    bad = (~ds["converged"].values[:, blades]).sum(1)
    assert bad.sum() > 0
    assert summary(ds)["unconverged_blades"].tolist() == bad.tolist()
    msg = str(rec[0].message)
    for i in np.flatnonzero(bad):
        assert f"({bad[i]} blades)" in msg and pd.Timestamp(ds["time"].values[i]).strftime("%H:%M UTC") in msg


def test_forward_outputs_count_unconverged_blades(model, monkeypatch):
    """The observation operator counts the blades whose photosynthesis did not converge per step,
    with the exact leaf (the same count as simulate's flags) and the tabulated leaf inference uses
    (a step counts all its blades when its grid did not converge); 0 when the solver converges."""
    from lightfit.model.observe import CONVERGENCE_KEY, tabulated_leaf, unconverged
    from lightfit.photosynthesis.solver import SolverConfig

    parts = model.render(THETA)
    stored = model.with_light(lambda theta: parts)
    n_blades = int(model.is_blade.sum())
    for leaf in (None, tabulated_leaf(16)):
        o = stored.operator(*parts, stored.theta(THETA), **({} if leaf is None else {"leaf": leaf}))
        assert int(unconverged(o)) == 0 and np.asarray(o[CONVERGENCE_KEY]).shape == (len(model.times),)
    capped = SolverConfig.for_dtype.__func__
    monkeypatch.setattr(SolverConfig, "for_dtype", classmethod(lambda cls, dtype, max_steps=100: capped(cls, dtype, 1)))
    o = stored.observe(THETA)
    flags = np.asarray(o["photosynthesis"].converged)
    assert np.asarray(o[CONVERGENCE_KEY]).tolist() == (~flags).sum(axis=1).tolist()
    assert int(unconverged(o)) > 0
    tab = np.asarray(stored.operator(*parts, stored.theta(THETA), leaf=tabulated_leaf(16))[CONVERGENCE_KEY])
    assert set(tab.tolist()) <= {0, n_blades} and tab.sum() > 0


def test_an_noise_bias_matches_noise_averaged_photosynthesis(weather):
    """The Jensen bias of leaf An from Gaussian noise in its PAR (nine-node Gauss–Hermite) against
    the brute-force average of the exact leaf solve over 2 × 2 000 antithetic noise draws, at
    night, low sun and midday, 25 % noise (midday 1 600 straddles the Rubisco/electron-transport
    switch, where a three-node rule is 37 % off)."""
    from lightfit.model.observe import an_noise_bias, exact_leaf
    from lightfit.model.scenario import Forcing
    from lightfit.photosynthesis import parameter_set

    f, p = Forcing.of(weather), parameter_set("winter_wheat")
    q = np.array([[0.0, 0.0, 0.0], [20.0, 150.0, 400.0], [300.0, 900.0, 1600.0]])  # night, low sun, midday
    sd = 0.25 * q
    bias = np.asarray(an_noise_bias(jnp.asarray(q), jnp.asarray(sd), f, p))
    assert np.all(np.isfinite(bias)) and np.all(bias[0] == 0.0)  # no light, no noise: no bias
    z = np.random.default_rng(7).standard_normal(2000)
    z = np.concatenate([z, -z])  # antithetic: odd orders of the noise cancel exactly
    draws = np.maximum(q[:, :, None] + sd[:, :, None] * z, 0.0).reshape(3, -1)
    an_draws = np.asarray(exact_leaf(jnp.asarray(draws), f, p).an).reshape(3, 3, -1)
    an_q = np.asarray(exact_leaf(jnp.asarray(q), f, p).an)
    pair = 0.5 * (an_draws[..., :2000] + an_draws[..., 2000:])  # independent antithetic pairs
    brute = pair.mean(-1) - an_q
    se = pair.std(-1, ddof=1) / np.sqrt(2000)
    lit = q > 0
    assert np.all(brute[lit] < 0) and np.all(bias[lit] < 0)  # light saturation: noise lowers An
    assert np.all(np.abs(bias - brute)[lit] <= 4 * se[lit] + 0.05 * np.abs(brute[lit])), (bias, brute, se)
    three = np.asarray(an_noise_bias(jnp.asarray(q), jnp.asarray(sd), f, p, nodes=3))
    assert abs(three[2, 2] - brute[2, 2]) > 5 * se[2, 2]  # the kink (6 SE off): why nine nodes


def test_an_noise_bias_of_a_very_noisy_blade_stays_in_the_leaf_solves_range(weather):
    """Blades at 5 000 ± 1 500 and 3 000 ± 1 600 µmol m⁻² s⁻¹: the top node q + 4.5σ is beyond the
    leaf solve's 1e4 (as in `lightfit replicate --quick --direct-rays-per-m2 1e3`, which rendered and
    then failed with "parameter 'par_abs_umol_m2_s' ... expected absorbed PAR in [0, 1e4]"). The bias
    is the brute-force average over the noise with the light held to [0, 1e4] (the leaf is
    saturated there: A(1e4) within 1 % of A(5 000)), within 4 SE + 5 %."""
    from lightfit.model.observe import an_noise_bias, exact_leaf
    from lightfit.model.scenario import Forcing
    from lightfit.photosynthesis import MAX_PAR_ABS_UMOL_M2_S, parameter_set

    f, p = Forcing.of(weather.iloc[[2]]), parameter_set("winter_wheat")  # 12:00
    q, sd = np.array([[5000.0, 3000.0]]), np.array([[1500.0, 1600.0]])
    bias = np.asarray(an_noise_bias(jnp.asarray(q), jnp.asarray(sd), f, p))
    z = np.random.default_rng(11).standard_normal(2000)
    z = np.concatenate([z, -z])
    draws = np.clip(q[:, :, None] + sd[:, :, None] * z, 0.0, MAX_PAR_ABS_UMOL_M2_S).reshape(1, -1)
    an_draws = np.asarray(exact_leaf(jnp.asarray(draws), f, p).an).reshape(1, 2, -1)
    pair = 0.5 * (an_draws[..., :2000] + an_draws[..., 2000:])
    brute = pair.mean(-1) - np.asarray(exact_leaf(jnp.asarray(q), f, p).an)
    se = pair.std(-1, ddof=1) / np.sqrt(2000)
    sat = np.asarray(exact_leaf(jnp.asarray([[5000.0, MAX_PAR_ABS_UMOL_M2_S]]), f, p).an)[0]
    assert abs(sat[1] / sat[0] - 1) < 0.01  # saturated: holding the light at 1e4 changes little
    assert np.all(bias < 0) and np.all(np.abs(bias - brute) <= 4 * se + 0.05 * np.abs(brute)), (bias, brute, se)


@pytest.mark.parametrize("target_rse", [None, 0.1])
def test_a_run_of_night_steps_only_gives_zero_light_and_respiration(weather, target_rse):
    """Only night steps (a short early window): no render, zero light, the leaves' dark
    respiration; it used to fail stacking an empty list of renders. An adaptive run still reports
    its allocation (made at the highest sun, docs/light.md), so only then is the scene built."""
    night = weather.iloc[[0]]
    m = CoupledModel(Scenario(weather=night, field=FIELD, samples=8, bounces=2, target_rse=target_rse))
    values, se = m.render(THETA)
    assert values.shape == se.shape == (0, 4, m.n_columns)
    ds = m.simulate(THETA)
    assert float(np.abs(ds["absorbed_par_umol_m2_s"]).max()) == 0.0
    assert float(ds["canopy_an_umol_m2_s"].max()) < 0 and np.isfinite(ds["canopy_an_umol_m2_s"]).all()
    if target_rse is None:
        assert "irradiance" not in m.__dict__  # the scene was never built
    else:
        assert (ds["samples_per_segment"] >= 32).all() and ds.attrs["target_rse"] == target_rse
        # allocated at a sun below the horizon weighted 1 : 0.3, which no step's PAR is: not named
        assert not [k for k in ds.attrs if k.startswith("allocation_")]


def test_a_model_refuses_float32_jax_naming_the_fix(weather, monkeypatch):
    """lightfit has no float32 mode: a library user who did not call use_float64() gets one clear
    error naming it, instead of float32 results with a truncation warning per array."""
    import lightfit.model.coupled as coupled

    monkeypatch.setattr(coupled, "precision", lambda: "float32")
    with pytest.raises(InputError, match=r"precision.*use_float64\(\)"):
        CoupledModel(Scenario(weather=weather, field=FIELD, samples=8, bounces=2))


def test_a_scenario_records_the_k_it_renders(weather):
    """K is R replicates × equal points: a K the estimator would round up (3 → 4, 50 → 56) is
    refused with the nearest that it takes, so results.nc's samples is what was rendered."""
    from lightfit.light.estimator import samples_used

    assert [samples_used(k) for k in (2, 3, 8, 16, 31, 32, 50, 64)] == [2, 4, 8, 16, 35, 32, 56, 64]
    for k, near in ((3, "2 or 4"), (50, "48 or 56")):
        with pytest.raises(InputError, match=f"samples={k}.*{near}"):
            Scenario(weather=weather, field=FIELD, samples=k)
    assert Scenario(weather=weather, field=FIELD, samples=48).samples == 48
    # With a target the pilot is what is rendered first: raised to 32, so 30 passes and 50 does not.
    assert Scenario(weather=weather, field=FIELD, samples=30, target_rse=0.1).samples == 30
    with pytest.raises(InputError, match="samples=50"):
        Scenario(weather=weather, field=FIELD, samples=50, target_rse=0.1)


def test_a_run_shows_its_renders_progress_only_when_eager(weather, capsys):
    """With progress=True an eager run shows a bar over its daytime steps (the renders are the
    long part); a traced one (jax.grad, as calibration runs it) shows none: its loop runs once,
    at trace time, where a bar would say nothing about the work."""
    import jax

    m = CoupledModel(Scenario(weather=weather, field=FIELD, samples=8, bounces=1), progress=True)
    capsys.readouterr()
    m.render(THETA)
    out = capsys.readouterr().out
    assert "rendering steps" in out and f"{int(m.day.sum())}/{int(m.day.sum())}" in out, out

    def loss(leaf):
        values, _ = m.render(dict(zip(LEAF_PARAMETERS, leaf)))
        return values.sum()

    g = jax.grad(loss)(jnp.asarray(THETA.leaf))
    assert np.isfinite(np.asarray(g)).all() and "rendering steps" not in capsys.readouterr().out


def test_fast_observables_cut_emulated_parts_at_zero_as_the_emulator_does(model):
    """Irradiance ratios are ≥ 0: the polynomial can dip below 0 near the box's corners, and the
    emulator cuts it there; the calibration's and the sampler's FastObservables did not (parts down
    to −0.003 per unit DNI on the quick field; a review). An emulator whose every part is −0.05
    (degree 0) gives 0 through both, and the observables of zero light."""
    n_day = int(np.asarray(model.day).sum())
    v = np.full((2, n_day, 4, model.n_columns), -0.05)
    s = np.full_like(v, 0.01)
    emu = E.fit_emulator(np.array([[0.2, 0.2, 0.2], [0.8, 0.8, 0.8]]), v, s, [0, 0, 0], [1, 1, 1], degrees=(0,))
    fast = E.FastObservables(model, emu, n_grid=None)
    values, _ = fast.parts(THETA)
    assert values.shape[0] == n_day and float(jnp.min(values)) == 0.0 and float(jnp.max(values)) == 0.0
    assert float(jnp.min(emu(THETA)[0])) == 0.0
    dark = fast(THETA)
    assert float(jnp.max(jnp.abs(dark["plant_par_umol_m2_s"]))) == 0.0


def test_fast_observables_fill_unnamed_leaf_parameters_from_the_scenarios_optics(weather):
    """FastObservables is observe() on emulated parts, also for a mapping that names only some
    parameters: the rest are the scenario's (``model.theta``), not Theta's defaults. With the paper's
    grey leaf (subsurface 0.3; Theta's default 0.596) ``fast({"light_factor": 1.2})`` emulated the light
    at subsurface 0.596: plant PAR 31 % above observe's on these leaf-dependent parts (a review)."""
    from lightfit.light.scene import Optics

    sc = Scenario(weather=weather, field=FIELD, samples=8, bounces=2, optics=Optics.preset("paper"))
    model = CoupledModel(sc)
    assert model.theta().subsurface != Theta().subsurface
    n_day = int(np.asarray(model.day).sum())
    design = E.sobol_design(16, [0, 0, 0], [1, 1, 1], seed=0)
    base = np.random.default_rng(0).uniform(0.2, 1.0, (1, n_day, 4, model.n_columns))
    v = base * (0.5 + design[:, 2] + 0.3 * design[:, 0])[:, None, None, None]  # parts that depend on the leaf
    emu = E.fit_emulator(design, v, 0.01 * v, [0, 0, 0], [1, 1, 1], degrees=(1,))
    fast = E.FastObservables(model, emu, n_grid=None)
    given = {"light_factor": 1.2}
    ref = E.emulated_model(model, emu).observe(given)
    got = fast(given)
    for k in ("plant_par_umol_m2_s", "canopy_an_umol_m2_s"):
        np.testing.assert_allclose(np.asarray(got[k]), np.asarray(ref[k]), rtol=1e-10, atol=1e-12)
    np.testing.assert_array_equal(np.asarray(fast.parts(given)[0]), np.asarray(fast.parts(model.theta(given))[0]))


def test_build_emulator_refuses_a_bad_design_size_before_rendering(model):
    """n_design is checked before any render (check_design_size, as the command line does): 3 points
    were rendered and only then refused, 2.5 stopped on "'float' object cannot be interpreted as an
    integer" (a review)."""
    before = dict(E.COUNTS)
    for bad in (3, 2.5, True, -1):
        with pytest.raises(InputError, match="parameter 'n_design'"):
            E.build_emulator(model, n_design=bad, degrees=(1,))
    assert E.COUNTS == before


def test_build_emulator_refuses_a_box_with_a_nan_bound_before_rendering(model):
    """A NaN bound passed the box's check (every comparison with NaN is false) and stopped in scipy's
    Sobol scaling ("ValueError: Bounds are not consistent 'l_bounds' < 'u_bounds'"): refused by name."""
    before = dict(E.COUNTS)
    for lo, hi in (((np.nan, 0.0, 0.0), (1.0, 1.0, 1.0)), ((0.0, 0.0, 0.0), (1.0, np.nan, 1.0))):
        with pytest.raises(InputError, match="parameter 'specular, roughness, subsurface'.*nan"):
            E.build_emulator(model, lo, hi, n_design=5, degrees=(1,))
    assert E.COUNTS == before


def test_emulator_refuses_extra_points_outside_its_box_and_renders_that_are_not_finite(model):
    """Two silent paths (a review): extra design points outside the box were rendered and fitted,
    bending the polynomial towards where it is never evaluated; a NaN render made every degree's
    leave-one-out RMS NaN and the first degree was kept. Both are refused by name, before any
    render for the extra points."""
    before = dict(E.COUNTS)
    for bad in ([[0.5, 0.5, 1.2]], [[0.5, np.nan, 0.5]], [[0.5, 0.5]]):
        with pytest.raises(InputError, match="parameter 'extra'"):
            E.build_emulator(model, (0.2, 0.2, 0.2), (0.8, 0.8, 0.8), n_design=5, degrees=(1,), extra=bad)
    assert E.COUNTS == before
    on_face = np.array([[0.8 + 1e-12, 0.5, 0.2 - 1e-12]])  # an optimum on the box's faces, to round-off
    np.testing.assert_array_equal(E.checked_extra(on_face, np.full(3, 0.2), np.full(3, 0.8)), on_face)
    design = E.sobol_design(8, np.zeros(3), np.ones(3), 0)
    v = np.ones((8, 2)) + design[:, :1]
    E.fit_emulator(design, v, 0.01 * v, [0, 0, 0], [1, 1, 1], degrees=(1,))  # finite: fitted
    v[3, 1] = np.nan
    with pytest.raises(InputError, match=r"1 design render\(s\) not finite, the first at point 3"):
        E.fit_emulator(design, v, 0.01 * np.ones_like(v), [0, 0, 0], [1, 1, 1], degrees=(1,))


def test_key_changes_show_where_two_long_values_differ():
    """A cache key's optics and field are reprs longer than the 40 characters shown: a change of the
    soil albedo or the field's seed read "optics: 'Optics(specular=0.5, roughness=0.5, … →
    'Optics(specular=0.5, roughness=0.5, …", the same on both sides (a review), in the posterior's
    refusal to resume and the rebuild line. The part that differs is shown."""
    optics = "Optics(specular=0.5, roughness=0.5, subsurface=0.6, base_color=0.07, soil_albedo={})"
    before = {"optics": optics.format(0.12), "samples": 16, "sky": "isotropic"}
    now = {"optics": optics.format(0.2), "samples": 16, "sky": "isotropic"}
    (line,) = E.key_changes(before, now)
    old, new = line.split(" → ")
    assert old.startswith("optics: ") and "soil_albedo=0.12" in old and "soil_albedo=0.2)" in new
    assert len(old) <= len("optics: ") + 40 and len(new) <= 40
    # short values and values that differ within the first 37 characters are shown as before
    assert E.key_changes({**before, "samples": 16}, {**before, "samples": 32}) == ["samples: 16 → 32"]
    field = "Field(n_plants={}, row_spacing_m=0.125, plant_spacing_m=0.03, buffer_rows=0)"
    assert E.key_changes({"field": field.format(4)}, {"field": field.format(9)}) == [
        "field: 'Field(n_plants=4, row_spacing_m=0.12… → 'Field(n_plants=9, row_spacing_m=0.12…"
    ]


def test_the_emulator_refuses_points_outside_its_box_naming_the_parameter():
    """PartsEmulator.basis takes points (n, 3) as well as one (3,): one of several points outside the
    box stopped on "IndexError: tuple index out of range" (the flat index of the point's entry taken
    for a parameter's; a review), or named the wrong parameter. It names the parameter and the point."""
    lo, hi = np.array([0.2, 0.3, 0.0]), np.array([0.8, 1.0, 0.5])
    design = E.sobol_design(8, lo, hi, seed=0)
    emu = E.fit_emulator(design, np.ones((8, 1, 4, 1)) + design[:, :1, None, None], np.ones((8, 1, 4, 1)), lo, hi)
    points = np.array([[0.5, 0.5, 0.25], [0.5, 0.5, 0.25], [0.5, 1.2, 0.25]])
    with pytest.raises(InputError, match=r"roughness=1\.2 outside the emulator's box \[0\.3, 1\] \(point 2\)"):
        emu.basis(points)
    with pytest.raises(InputError, match=r"subsurface=0\.6 outside the emulator's box \[0, 0\.5\]") as one:
        emu.basis(np.array([0.5, 0.5, 0.6]))
    assert "point" not in str(one.value)  # one point: no index to name
    assert np.asarray(emu.basis(points[:2])).shape == (2, 4)  # inside: the degree-1 basis of each point


def test_every_variables_units_are_the_unit_its_name_carries():
    """A variable's name ends in its unit (``_umol_m2_s`` …), written out here as UDUNITS strings; the
    fractions and their SDs are dimensionless. The results' own check compares attributes with the
    schema itself, so a wrong unit in the schema (a mutation audit: canopy APAR's SD as "1") passed."""
    suffixes = (  # longest first: "_umol_m2_s" before "_s"
        ("_umol_m2_s", "umol m-2 s-1"),
        ("_mol_m2_s", "mol m-2 s-1"),
        ("_umol_mol", "umol mol-1"),
        ("_w_m2", "W m-2"),
        ("_kpa", "kPa"),
        ("_deg", "degree"),
        ("_ppm", "ppm"),
        ("_m2", "m2"),
        ("_offset_s", "s"),
        ("tair_c", "degC"),
    )
    dimensionless = ("fapar", "transmittance", "fapar_sd", "transmittance_sd", "fapar_mc_sd", "transmittance_mc_sd")
    checked = 0
    for name, v in schema.VARIABLES.items():
        unit = next((u for s, u in suffixes if name.endswith(s)), None)
        if unit is None and name.endswith(dimensionless):
            unit = "1"
        if unit is not None:
            assert v.units == unit, name
            checked += 1
    assert checked > 60


def test_the_fractions_say_what_a_finite_field_does_to_them():
    """fAPAR is APAR per ground area of the measured plants over the PAR above: on a finite field it
    reached 4.5 at a 4° sun (`--quick --boundary finite`, docs/model.md) with results.nc saying only
    "fraction of absorbed PAR ... canopy APAR / PAR above" (a review). The attributes name the area and
    the field's sides, for fAPAR and for the ceptometer's transmittance that reads the same side light."""
    fapar = schema.variable("fapar").attrs()["comment"]
    assert "ground area of the measured plants" in fapar and "ground_area_m2" in fapar
    assert "finite field" in fapar and "exceed 1" in fapar and "sides" in fapar
    tau = schema.variable("ceptometer_transmittance").attrs()["comment"]
    assert "finite field" in tau and "sides" in tau


def test_flags_are_cf_lists():
    """CF 1.x §3.5: flag_values is a list of the flag variable's own type (int8 as written), flag_meanings
    a blank-separated string, one word per meaning. flag_values was the text "-1 0 1" (a review)."""
    a = schema.variable("is_blade").attrs()
    assert a["flag_values"].dtype == np.int8 and a["flag_values"].tolist() == [0, 1]
    assert a["flag_meanings"] == "no yes"
    a = schema.variable("limitation").attrs()
    assert a["flag_values"].dtype == np.int8 and a["flag_values"].tolist() == [-1, 0, 1]
    assert a["flag_meanings"] == "no_value Rubisco_limited electron_transport_limited"


def test_flag_values_are_written_in_the_type_of_their_variable(tmp_path):
    """In the file (read with h5py, no xarray decoding) each flag variable's flag_values attribute is
    numbers of the variable's on-disk type, booleans written as int8 included."""
    import h5py
    import xarray as xr

    ds = xr.Dataset(
        {
            "limitation": (("time", "segment"), np.array([[-1, 0, 1]], np.int8)),
            "converged": (("time", "segment"), np.array([[True, False, True]])),
        },
        coords={
            "time": pd.DatetimeIndex(["2016-04-20 10:00"]).values,
            "segment": np.arange(3, dtype=np.int64),
            "is_blade": ("segment", np.array([False, True, True])),
        },
    )
    path = rep.write_netcdf(schema.annotate(ds), tmp_path / "flags.nc")
    with h5py.File(path, "r") as f:
        for name, values in (("limitation", [-1, 0, 1]), ("converged", [0, 1]), ("is_blade", [0, 1])):
            flags = f[name].attrs["flag_values"]
            assert flags.dtype == f[name].dtype == np.int8, name
            assert flags.tolist() == values, name


def same_attrs(a, b) -> bool:
    """Two attribute dicts alike, arrays (flag_values) compared by value."""
    return a.keys() == b.keys() and all(np.array_equal(a[k], b[k]) for k in a)


def test_nee_is_described_in_the_micrometeorological_sign_convention():
    """NEE positive = CO2 released to the air (Baldocchi 2003): a canopy taking up 10 with no soil
    respiration has NEE −10, and the results say so on NEE, its SD and its observations."""
    from lightfit.model import observe

    assert float(observe.chamber_nee(np.array([10.0]), np.array([0.0]), 0.0)[0][0]) == -10.0
    for name in ("nee_umol_m2_s", "nee_mc_sd_umol_m2_s", "obs_nee_umol_m2_s"):
        comment = schema.variable(name).comment
        assert "positive = CO2 released to the air" in comment and "per unit ground area" in comment, name


def test_a_finite_field_cannot_take_projected_direct_light():
    """Projection casts rays over the periodic cell: a finite field is refused when the scenario is made
    (before plants grow), and ``auto`` means projection only where the field is periodic."""
    from lightfit.model.scenario import resolve_direct

    assert resolve_direct("auto", "periodic") == "projection" and resolve_direct("auto", "finite") == "paths"
    with pytest.raises(InputError, match="direct"):
        resolve_direct("projection", "finite")
    w = rep.forcing().iloc[[14]]
    with pytest.raises(InputError, match="direct='projection' with a finite field"):
        Scenario(weather=w, field=FIELD, direct="projection")
    assert Scenario(weather=w, field=FIELD, direct="paths").direct == "paths"


def test_forcing_lights_the_canopy_with_the_series_measured_par():
    """Forcing.of takes the horizontal PAR of the light model from the series' PAR column wherever it has
    one: DNI^PAR sin β + DHI^PAR equals that column at every step with light, also where it is not the
    fixed 2.285 µmol J⁻¹ × GHI of a series without one (the bundled day's PAR is that constant, so only
    a column of other values can show it is read)."""
    from lightfit.model.scenario import Forcing
    from lightfit.weather.units import par_from_ghi

    el = np.array([-5.0, 10.0, 30.0, 55.0])
    dni, dhi = np.array([0.0, 200.0, 600.0, 800.0]), np.array([0.0, 50.0, 100.0, 120.0])
    ghi = dni * np.sin(np.radians(el)) * (el > 0) + dhi
    measured = np.array([0.0, 1.7, 2.6, 1.9]) * ghi  # µmol m⁻² s⁻¹, any ratio to GHI
    base = dict(dni_w_m2=dni, dhi_w_m2=dhi, sun_elevation_deg=el, tair_c=10.0, co2_ppm=400.0, rh=0.6, pair_kpa=100.0)
    for par, want in ((measured, measured), (None, float(par_from_ghi(1.0)) * ghi)):
        w = pd.DataFrame({**base, **({} if par is None else {"par_umol_m2_s": par})})
        f = Forcing.of(w)
        horizontal = np.asarray(f.dni_par) * np.sin(np.radians(el)) + np.asarray(f.dhi_par)
        np.testing.assert_allclose(horizontal[1:], want[1:], rtol=1e-12)
        assert np.asarray(f.day).tolist() == [False, True, True, True]


def test_adaptive_sampling_allocates_at_the_highest_daytime_sun_or_a_clear_days_mix():
    """allocation_point (a mutation audit: the daytime filter dropped, and the clear-day fallback
    taken only for negative PAR, both survived): the highest sun among the *daytime* steps, its own
    DNI / DHI PAR; a night-only run: the highest sun, weighted 1 : 0.3 (docstring), not 0 : 0."""
    from types import SimpleNamespace

    from lightfit.model.coupled import allocation_point

    sun = np.array([[60.0, 10.0], [20.0, 90.0], [40.0, 180.0], [-3.0, 270.0]])
    leaf = np.array([0.5, 0.5, 0.3])
    # step 0 has the highest sun but is no daytime step (e.g. dark in the forcing): step 2 is taken
    day = SimpleNamespace(
        day=np.array([False, True, True, False]), dni_par=np.array([9.0, 300.0, 800.0, 0.0]), dhi_par=[1.0, 50, 120, 0]
    )
    lf, at, dni, dhi = allocation_point(day, sun, leaf)
    assert list(at) == [40.0, 180.0] and (dni, dhi) == (800.0, 120.0) and list(lf) == [0.5, 0.5, 0.3]
    night = SimpleNamespace(day=np.zeros(3, bool), dni_par=np.zeros(3), dhi_par=np.zeros(3))
    _, at, dni, dhi = allocation_point(night, np.array([[-10.0, 0.0], [-2.0, 45.0], [-20.0, 90.0]]), leaf)
    assert list(at) == [-2.0, 45.0] and (dni, dhi) == (1.0, 0.3)
    # a daytime step whose PAR is zero weighs the parts the clear-day way too
    dim = SimpleNamespace(day=np.array([True]), dni_par=np.zeros(1), dhi_par=np.zeros(1))
    assert allocation_point(dim, np.array([[5.0, 100.0]]), leaf)[2:] == (1.0, 0.3)


def test_results_carry_the_forcings_weather_and_the_theta_run(simulated):
    """Each weather variable in the results is the forcing's own column at the run's steps, and the
    theta_* attributes are the θ run (THETA, not the scenario's defaults): a mutation audit swapped
    DNI and DHI in the results, and wrote the defaults' θ, and both survived."""
    w = rep.forcing().iloc[[1, 5, 14]]
    for name in ("dni_w_m2", "dhi_w_m2", "tair_c", "co2_ppm", "rh", "pair_kpa", "sun_elevation_deg", "sun_azimuth_deg"):
        if name in w:
            np.testing.assert_array_equal(simulated[name].values, w[name].to_numpy(np.float64), err_msg=name)
    assert not np.allclose(w["dni_w_m2"], w["dhi_w_m2"])  # a swap would show
    given = {"specular": 0.6, "roughness": 0.4, "subsurface": 0.2, "light_factor": 1.3, "vcmax_scale": 0.8}
    assert {k: simulated.attrs[f"theta_{k}"] for k in given} == given


def test_results_bias_is_the_documented_quadrature_at_the_blades_own_light_and_capacity(model, simulated):
    """leaf_an_mc_bias (an_noise_bias's docstring: b = Σ wᵢ A(max(q̂ + xᵢσ, 0)) − A(q̂), nine
    probabilists' Gauss–Hermite nodes) at each blade's stored absorbed PAR and its Monte Carlo SD,
    with the leaf function that reproduces the stored leaf An (so θ's vcmax_scale and the blade's
    capacity): a mutation audit fed the bias the defaults' vcmax_scale, or the light factor twice,
    and both survived."""
    ds = simulated
    b = np.flatnonzero(ds["is_blade"].values)
    q = ds["absorbed_par_umol_m2_s"].values[:, b]
    sd = ds["absorbed_par_mc_sd_umol_m2_s"].values[:, b]
    leaf, params = model.operator.leaf(), model.operator.photosynthesis_params(0.8)  # THETA.vcmax_scale

    def an(x):
        return np.asarray(leaf(jnp.asarray(np.maximum(x, 0.0)), model.forcing, params).an)

    np.testing.assert_allclose(an(q), ds["leaf_an_umol_m2_s"].values[:, b], rtol=1e-9, atol=1e-9)  # this A is the run's
    x, w = np.polynomial.hermite_e.hermegauss(9)
    want = sum(wi / w.sum() * an(q + xi * sd) for xi, wi in zip(x, w)) - an(q)
    assert np.abs(want).max() > 1e-4  # a bias to tell apart
    np.testing.assert_allclose(ds["leaf_an_mc_bias_umol_m2_s"].values[:, b], want, rtol=1e-6, atol=1e-9)


def test_photosynthesis_overrides_reach_the_model_and_its_results(model):
    """A user's Vcmax (photosynthesis_overrides) is the set's Vcmax scaled: at the same capacity
    profile, Vcmax_ref 80 gives the canopy An of the set's 100 × vcmax_scale 0.8 (θ scales Vcmax and,
    through the set's ratios, Jmax and Rd). Lloyd's profile follows the user's Vcmax, and the results
    record the overrides in their attributes and run label."""
    import dataclasses
    import json

    from lightfit.photosynthesis.canopy import kn_lloyd2010
    from lightfit.report import run_label

    sc = dataclasses.replace(
        model.scenario, photosynthesis_overrides={"vcmax_ref_umol_m2_s": 80.0}, vcmax_profile=model.kn
    )
    own = CoupledModel(sc, light=model.light)  # the same renders: only the photosynthesis differs
    np.testing.assert_allclose(
        own.observe(THETA.replace(vcmax_scale=1.0))["canopy_an_umol_m2_s"],
        model.observe(THETA)["canopy_an_umol_m2_s"],
        rtol=1e-10,
    )
    assert own.operator.params.fvcb.vcmax_ref_umol_m2_s == 80.0 and own.scenario.photosynthesis_overrides == (
        ("vcmax_ref_umol_m2_s", 80.0),
    )
    auto = dataclasses.replace(sc, vcmax_profile="auto")
    assert auto.kn() == pytest.approx(kn_lloyd2010(80.0)) and model.kn == pytest.approx(kn_lloyd2010(100.0))
    attrs = own.simulate(THETA).attrs
    assert json.loads(attrs["photosynthesis_overrides"]) == {"vcmax_ref_umol_m2_s": 80.0}
    assert "vcmax_ref_umol_m2_s 80" in run_label(attrs)
    assert json.loads(model.simulate(THETA).attrs["photosynthesis_overrides"]) == {}
    with pytest.raises(InputError, match="photosynthesis_overrides.*a1=-1"):
        dataclasses.replace(sc, photosynthesis_overrides={"a1": -1.0})


def test_a_civil_twilight_step_with_diffuse_light_is_rendered_by_the_sky_alone():
    """A step with the sun at −5° and diffuse light above (DHI 5 W m⁻², PAR 11 µmol m⁻² s⁻¹) is
    rendered (daytime: diffuse light in civil twilight, above −6°): its plants absorb light, by the
    sky alone. The reference: the same field at 12:00 UTC with the sun's part switched off (DNI 0,
    DHI 100 W m⁻², PAR 228.5), whose canopy APAR scaled by the ratio of the two diffuse PARs is the
    twilight step's (linearity in DHI; the sky's radiance does not depend on the sun), within the
    Monte Carlo error. Before, the twilight step was not rendered: 0 absorbed under 11 above, a
    canopy fAPAR of 0, and a render key without that step, so a cache of the dark run would have
    served the lit one."""
    from lightfit.model.emulator import render_key

    w = rep.forcing().iloc[[2, 14]].copy()  # 04:00 UTC (sun −5.03°) and 10:00 UTC (46.5°)
    assert w["sun_elevation_deg"].iloc[0] == pytest.approx(-5.03, abs=0.01)
    w.loc[w.index[0], ["dni_w_m2", "dhi_w_m2", "par_umol_m2_s"]] = (0.0, 5.0, 11.0)
    w.loc[w.index[1], ["dni_w_m2", "dhi_w_m2", "par_umol_m2_s"]] = (0.0, 100.0, 228.5)
    m = CoupledModel(Scenario(weather=w, field=FIELD, samples=8, bounces=2, par_kind="absorbed"))
    o = m.observe(Theta())
    above = np.asarray(o["above_canopy_par_umol_m2_s"])
    np.testing.assert_allclose(above, [11.0, 228.5], rtol=1e-12)  # all diffuse: the horizontal PAR
    apar, sd = np.asarray(o["canopy_apar_umol_m2_s"]), np.asarray(o["canopy_apar_mc_sd_umol_m2_s"])
    assert apar[0] > 0 and np.asarray(o["transmitted_par_umol_m2_s"])[0] > 0
    assert m.day.tolist() == [True, True]
    assert str(w.index[0]) in render_key(m)["times_utc"]
    expected = apar[1] * 11.0 / 228.5
    assert abs(apar[0] - expected) <= 4 * np.hypot(sd[0], sd[1] * 11.0 / 228.5) + 1e-12 * expected
    # the canopy's fAPAR under a sky alone is the same at both steps (a finite field: > 1 with its edge light)
    f = np.asarray(o["fapar"])
    assert f[0] > 0 and f[0] == pytest.approx(f[1], abs=4 * float(np.asarray(o["fapar_mc_sd"])[1]) + 1e-12)
    # the twilight leaves photosynthesise: their An lies above the dark respiration at the same step
    dark = w.copy()
    dark.loc[dark.index[0], ["dhi_w_m2", "par_umol_m2_s"]] = (0.0, 0.0)
    d = CoupledModel(Scenario(weather=dark, field=FIELD, samples=8, bounces=2, par_kind="absorbed"))
    assert d.day.tolist() == [False, True] and str(w.index[0]) not in render_key(d)["times_utc"]
    assert float(o["canopy_an_umol_m2_s"][0]) > float(d.observe(Theta())["canopy_an_umol_m2_s"][0])
