"""The coupled model and the 20 April 2016 regression curve (observations and calibration: test_calibration.py)."""

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
import xarray as xr
from typer.testing import CliRunner

import lightfit  # noqa: F401
from lightfit import replication as rep
from lightfit.cli import app
from lightfit.model.parameters import Theta

REFERENCES = Path(__file__).parent / "reference"
#: The stored 20 April curves: the periodic default (regenerated deliberately for it: PROSPECT-D
#: leaf, winter_wheat) and the reference paper's setup, the ``paper`` preset (finite field with 2
#: buffer rows, grey 0.5 leaf, giraud2023; bitwise the curve of the finite default before the
#: periodic boundary and the credible defaults). Both regenerated when the reconstructed forcing
#: gained its clear sky's diffuse radiation (docs/weather.md, "Sun and split"): the default's daily
#: An −3.6 %, the paper preset's +1.5 %, PAR at the plants +0.1 % and +0.9 %.
REFERENCE = REFERENCES / "replication_quick.json"
REFERENCE_FINITE = REFERENCES / "replication_quick_finite.json"


@pytest.fixture(scope="module")
def short_model():
    """Quick configuration on a 3-hour window around noon (7 steps)."""
    w = rep.forcing()
    w = w.loc["2016-04-20 09:00+00:00":"2016-04-20 12:00+00:00"]
    return rep.model_for(rep.ReplicationConfig.quick(), w)


def config_of(ref: dict) -> rep.ReplicationConfig:
    """A stored reference's configuration (``dataclasses.asdict`` wrote its window and site as dicts)."""
    from lightfit.weather.site import Site, Window

    c = dict(ref["config"])
    c["window"], c["site"] = Window(**c["window"]), Site(**c["site"])
    return rep.ReplicationConfig(**c)


def assert_matches_curve(ds, c):
    for v, sd in (
        ("plant_par_umol_m2_s", "plant_par_mc_sd_umol_m2_s"),
        ("canopy_an_umol_m2_s", "canopy_an_mc_sd_umol_m2_s"),
    ):
        new, old, err = ds[v].values, np.asarray(c[v]), np.asarray(c[sd])
        # Same seed: identical on the same platform. The tolerance allows other platforms' float
        # rounding; a model change moving the curve by 4 Monte Carlo SDs (of a difference) fails.
        tol = 4 * np.sqrt(2) * err + 1e-6 * np.abs(old) + 1e-9
        assert (np.abs(new - old) <= tol).all(), (v, np.abs(new - old).max())


@pytest.mark.parametrize(
    "path, boundary, buffer_rows", [(REFERENCE, "periodic", 0), (REFERENCE_FINITE, "finite", 2)], ids=lambda x: str(x)
)
def test_regression_against_stored_20_april_curve(path, boundary, buffer_rows):
    ref = json.loads(path.read_text())
    cfg = config_of(ref)
    assert cfg.boundary == boundary  # each file says which field it is
    # The periodic curve is the quick default's field, the finite one the reference paper's (2 buffer rows).
    quick = rep.ReplicationConfig.quick()
    assert cfg == (quick if path == REFERENCE else quick.with_preset("paper"))  # the file is that preset's curve
    ds, _ = rep.run(cfg, observations=None)
    assert_matches_curve(ds, ref["curve"])
    assert ds.attrs["weather_provenance"] == "reconstructed"
    assert ds.attrs["boundary"] == boundary and ds.attrs["buffer_rows"] == buffer_rows


def test_cli_preset_paper_reproduces_the_papers_setup(tmp_path):
    """``lightfit replicate --quick --preset paper`` gives the paper preset's reference curve."""
    import xarray as xr

    ref = json.loads(REFERENCE_FINITE.read_text())
    r = CliRunner().invoke(app, ["replicate", "--quick", "--preset", "paper", "--out", str(tmp_path)])
    assert r.exit_code == 0, r.output
    assert "finite field, 2 buffer rows" in " ".join(r.stdout.split())
    with xr.open_dataset(tmp_path / "results.nc", engine="h5netcdf") as ds:
        assert ds.attrs["boundary"] == "finite" and ds.attrs["buffer_rows"] == 2
        assert ds.attrs["photosynthesis"] == "giraud2023" and ds.attrs["base_color"] == 0.5
        assert ds.attrs["theta_subsurface"] == 0.3  # the grey leaf's own leaf defaults
        assert_matches_curve(ds, ref["curve"])


def test_paper_preset_is_what_the_paper_prints():
    """Each setting of ``ReplicationConfig.paper()`` that the reference paper prints (Baker et al.,
    in silico Plants 2025), typed from the paper's text, against the settings the run records
    (``effective``): not against lightfit's own constants."""
    from lightfit.light.scene import Optics

    eff = rep.ReplicationConfig.paper().effective()
    # §2.4: the Field Minirhizotron Facility, 50.865° N, 6.447° E
    assert (eff["site"]["latitude_deg"], eff["site"]["longitude_deg"]) == (50.865, 6.447)
    # §2.4: growth simulated from 5 March 2016; §3.2: the day compared is 20 April 2016
    assert (eff["season_start"], eff["dates"]) == ("2016-03-05", ["2016-04-20"])
    # §3.2: the 10-minute weather "sub-sampled" to 30-minute intervals (values taken, not averaged)
    assert (eff["window"]["step"], eff["how"]) == ("30min", "sample")
    # §4.1: two rows of buffer plants around the measurement area
    assert (eff["boundary"], eff["buffer_rows"], eff["buffer_along"]) == ("finite", 2, 2)
    # §2.2: the leaf's diffuse colour set to grey (0.5, 0.5, 0.5)
    assert Optics.preset(eff["optics"]).base_color == 0.5
    # §2.4 and Fig. 4: absorbed PAR per segment and CO2 uptake per (ground) area
    assert (eff["par_kind"], eff["an_per"]) == ("absorbed", "ground")
    # §1, §3.1: CPlantBox's photosynthesis module (Giraud et al. 2023)
    assert eff["photosynthesis"] == "giraud2023"


def test_presets_and_leaf_options():
    """The paper preset is the paper's setup; presets keep the run's size; bad leaf options name themselves."""
    from lightfit.errors import InputError
    from lightfit.light.scene import Optics

    paper = rep.ReplicationConfig.paper()
    assert (paper.boundary, paper.buffer_rows, paper.optics, paper.photosynthesis, paper.par_kind) == (
        "finite",
        2,
        "paper",
        "giraud2023",
        "absorbed",
    )
    assert paper.leaf_optics() == Optics.preset("paper")
    assert paper.with_preset("default") == rep.ReplicationConfig()
    quick_paper = rep.ReplicationConfig.quick().with_preset("paper")
    assert (quick_paper.n_plants, quick_paper.samples, quick_paper.bounces) == (4, 16, 2)
    assert rep.ReplicationConfig().leaf_optics() == Optics.preset("prospect")
    lo = rep.ReplicationConfig(chlorophyll_ug_cm2=36.4).leaf_optics()
    assert lo.base_color > Optics.preset("prospect").base_color  # less chlorophyll: a paler leaf
    for settings, column in (
        ({"optics": "grey"}, "optics"),
        ({"optics": "paper", "chlorophyll_ug_cm2": 40.0}, "chlorophyll_ug_cm2"),
        ({"chlorophyll_ug_cm2": -3.0}, "chlorophyll_ug_cm2"),
    ):
        with pytest.raises(InputError) as err:  # when the configuration is made (ReplicationConfig.check)
            rep.ReplicationConfig(**settings)
        assert err.value.column == column
    with pytest.raises(InputError, match="preset"):
        rep.ReplicationConfig().with_preset("unreal")


@pytest.mark.parametrize(
    "args, message",
    [
        (["--preset", "unreal"], "preset"),
        (["--optics", "grey"], "optics"),
        (["--optics", "paper", "--chlorophyll-ug-cm2", "40"], "chlorophyll"),
        (["--chlorophyll-ug-cm2", "500"], "chlorophyll"),
    ],
)
def test_cli_bad_preset_or_leaf_exits_2_with_one_line(tmp_path, args, message):
    r = CliRunner().invoke(app, ["replicate", "--quick", "--out", str(tmp_path), *args])
    assert r.exit_code == 2 and message in r.stderr, r.output
    assert not (tmp_path / "results.nc").exists()


def test_observables_are_consistent_with_the_segment_fields(short_model):
    m = short_model
    o = m.observe(Theta())
    w = m.area_m2 / m.area_m2.sum()
    assert np.allclose(np.asarray(o["plant_par_umol_m2_s"]), np.asarray(o["absorbed_par_umol_m2_s"]) @ w)
    b = o["blade_index"]
    an = np.asarray(o["photosynthesis"].an_umol_m2_s) @ m.area_m2[b] / m.ground_area_m2
    assert np.allclose(np.asarray(o["canopy_an_umol_m2_s"]), an)
    # Doubling the light factor doubles absorbed PAR exactly (weather only rescales renders).
    o2 = m.observe(Theta(light_factor=2.0))
    assert np.allclose(np.asarray(o2["absorbed_par_umol_m2_s"]), 2 * np.asarray(o["absorbed_par_umol_m2_s"]))
    assert (np.asarray(o["plant_par_mc_sd_umol_m2_s"])[m.day] > 0).all()
    assert np.isfinite(np.asarray(o["canopy_an_mc_sd_umol_m2_s"])).all()


def test_cli_replicate_quick_and_calibrate(tmp_path, monkeypatch):
    runner = CliRunner()
    r = runner.invoke(app, ["replicate", "--quick", "--out", str(tmp_path / "rep")])
    assert r.exit_code == 0, r.output
    for f in ("results.nc", "replication.png", "summary.csv", "forcing.csv"):
        assert (tmp_path / "rep" / f).exists()
    import xarray as xr

    ds = xr.open_dataset(tmp_path / "rep" / "results.nc", engine="h5netcdf")
    assert set(ds.dims) == {"time", "segment"} and ds.sizes["time"] == 29
    assert ds.attrs["boundary"] == "periodic" and ds.attrs["buffer_rows"] == 0  # the default field
    assert "periodic boundary" in " ".join(r.stdout.split())
    # summary.csv says what it stands on (a reconstructed forcing must not pass for measured weather)
    # in lightfit's `# key: value` lines, and is the summary of results.nc below them.
    import pandas as pd

    from lightfit.report import summary

    text = (tmp_path / "rep" / "summary.csv").read_text(encoding="utf-8").splitlines()
    head = dict(line[2:].split(": ", 1) for line in text if line.startswith("# "))
    assert head["forcing_provenance"] == ds.attrs["weather_provenance"] == "reconstructed"
    assert head["observations"] == ds.attrs["observations"] and head["preset"] == "default"
    assert head["local_time"] == "the site's clock, HH:MM in Europe/Berlin (time_utc is UTC)"  # its column's zone
    table = pd.read_csv(tmp_path / "rep" / "summary.csv", comment="#", index_col=0)
    np.testing.assert_allclose(table["canopy_an_umol_m2_s"], summary(ds)["canopy_an_umol_m2_s"], rtol=1e-3)
    # The bundled chamber record is an above-canopy quantum sensor: compared with that operator.
    obs_par = "obs_above_canopy_par_umol_m2_s"
    assert obs_par in ds and np.isfinite(ds[obs_par].values).sum() == 1
    # read 13.8 min after the 12:00 local step (10:00 UTC), where the figure draws it
    offset = ds["obs_above_canopy_par_time_offset_s"].values
    k = int(np.flatnonzero(np.isfinite(ds[obs_par].values))[0])
    assert str(ds["time"].values[k])[:16] == "2016-04-20T10:00" and offset[k] == pytest.approx(828.0)
    assert ds["obs_above_canopy_par_time_offset_s"].attrs["units"] == "s" and np.count_nonzero(offset) == 1
    # How the model meets that reading, written out: read 828 s of 1 800 towards the next step, its
    # Monte Carlo variance (1 − w)²s_k² + w²s_{k+1}² beside the reading's SD².
    from lightfit.report import observations_fit

    w = 828.0 / 1800.0
    model = ds["above_canopy_par_umol_m2_s"].values[k : k + 2].astype(float)
    s_mc = ds["above_canopy_par_mc_sd_umol_m2_s"].values[k : k + 2].astype(float)
    d = (1 - w) * model[0] + w * model[1] - float(ds[obs_par].values[k])
    v = (
        float(ds["obs_above_canopy_par_sd_umol_m2_s"].values[k]) ** 2
        + (1 - w) ** 2 * s_mc[0] ** 2
        + w**2 * s_mc[1] ** 2
    )
    fit = observations_fit(ds)
    assert list(fit.index) == ["above_canopy_par"] and fit.loc["above_canopy_par", "n"] == 1
    assert fit.loc["above_canopy_par", "bias"] == pytest.approx(d, rel=1e-9)
    assert fit.loc["above_canopy_par", "rmse"] == pytest.approx(abs(d), rel=1e-9)
    assert fit.loc["above_canopy_par", "chi2"] == pytest.approx(d**2 / v, rel=1e-9)
    assert head["observations_fit"].startswith(f"above_canopy_par: n 1, bias {d:+.3g}, RMSE {abs(d):.3g} umol m-2 s-1")
    assert "model against the observations" in r.stdout and "above_canopy_par" in r.stdout
    assert ds.attrs["preset"] == "default"
    # The run's PAR at the plants and its Monte Carlo SD at 10:00 and 11:00 UTC (θ's defaults:
    # light_factor 1), for the least-squares light factor below.
    at = [int(np.flatnonzero(ds["time"].values == np.datetime64(f"2016-04-20T{h}:00"))[0]) for h in (10, 11)]
    m_par = ds["plant_par_umol_m2_s"].values[at]
    s_par = ds["plant_par_mc_sd_umol_m2_s"].values[at]
    ds.close()
    obs = tmp_path / "obs.csv"
    obs.write_text(
        "# provenance: synthetic\n# time_zone: UTC\n"
        "time,plant_par_umol_m2_s,plant_par_sd_umol_m2_s,canopy_an_umol_m2_s,canopy_an_sd_umol_m2_s\n"
        "2016-04-20 10:00,450,20,60,3\n2016-04-20 11:00,480,20,70,3\n"
    )
    r = runner.invoke(
        app,
        [
            "calibrate",
            str(obs),
            "--quick",
            "--parameters",
            "light_factor",
            "--use",
            "par",
            "--max-steps",
            "20",
            "--out",
            str(tmp_path / "cal"),
        ],
    )
    assert r.exit_code == 0, r.output
    res = json.loads((tmp_path / "cal" / "calibration.json").read_text())
    assert res["parameters"] == ["light_factor"] and res["use"] == ["plant_par"]  # --use par: An left out
    # PAR at the plants is linear in light_factor (the weather's PAR is rescaled, the renders are not:
    # test_observables_are_consistent_with_the_segment_fields), so the loss ½ Σ (y − f·m)²/v is
    # quadratic in f and its minimiser is the weighted least-squares ratio Σ y m/v / Σ m²/v, with
    # v = σ² + s² (the Monte Carlo variance grows with f², s²/σ² ≈ 3e-4: neglected). Measured
    # agreement 2e-6 once converged; 3 L-BFGS-B steps stop 1.7e-3 short, so the run must converge.
    y, v = np.array([450.0, 480.0]), 20.0**2 + s_par**2
    f_ls = np.sum(y * m_par / v) / np.sum(m_par**2 / v)
    assert res["converged"] and res["theta"]["light_factor"] == pytest.approx(f_ls, rel=1e-3), (res["theta"], f_ls)
    assert res["precision"] == "float64" and res["method"] == "lbfgsb"  # the command line's default
    r = runner.invoke(app, ["calibrate", str(obs), "--quick", "--parameters", "shininess"])
    assert r.exit_code == 2 and "unknown parameter" in r.stderr and "shininess" in r.stderr


def test_dates_are_sorted_and_a_repeated_date_is_refused():
    """Several dates run in calendar order; the same date twice would run (and concatenate) one day twice."""
    from lightfit.errors import InputError

    assert rep.as_dates(("2016-04-27", "2016-04-20")) == ("2016-04-20", "2016-04-27")
    for dates in (("2016-04-20", "2016-04-20"), ()):
        with pytest.raises(InputError, match="date"):
            rep.as_dates(dates)
    with pytest.raises(InputError, match="date"):
        rep.ReplicationConfig(dates=("2016-04-20", "2016-04-20"))


def test_only_a_site_south_of_the_equator_needs_its_season_start():
    """5 March is refused as a default only south of the equator (latitude < 0); the equator keeps it."""
    from lightfit.errors import InputError
    from lightfit.weather.site import Site

    assert rep.check_season_start(None, Site(0.0, 10.0, 0.0, "equator", "UTC")) is None
    with pytest.raises(InputError, match="season_start"):
        rep.check_season_start(None, Site(-0.5, 10.0, 0.0, "just south", "UTC"))


def test_run_refuses_what_is_not_a_configuration():
    """replication.run("quick") was an AttributeError ('str' object has no attribute 'how'; a review
    of the Python API)."""
    from lightfit.errors import InputError

    with pytest.raises(InputError, match=r"cfg of type str.*ReplicationConfig.quick\(\)"):
        rep.run("quick")


@pytest.mark.parametrize(
    ("setting", "value", "named"),
    [
        ("n_plants", 0, "n_plants"),
        ("samples", 1, "samples"),
        ("bounces", -1, "bounces"),
        ("target_rse", 1.5, "target_rse"),
        ("direct", "rays", "direct"),
        ("optics", "green", "optics"),
        ("soil_albedo", 1.2, "soil_albedo"),
        ("how", "median", "how"),
        ("par_kind", "reflected", "par_kind"),
        ("an_per", "plant", "an_per"),
        ("photosynthesis", "maize", "photosynthesis"),
        ("photosynthesis_overrides", {"curvature": 1.5}, "photosynthesis_overrides"),
        ("photosynthesis_overrides", {"g1": 4.0}, "photosynthesis_overrides"),
        ("photosynthesis_overrides", {"a1": 1e308}, "photosynthesis_overrides"),
        ("ceptometer_height_m", -0.1, "ceptometer_height_m"),
        ("render_seed", "a", "render_seed"),
        ("row_spacing_m", 0.0, "row_spacing_m"),
        ("row_direction_deg", 360.0, "row_direction_deg"),
        ("sheaths", "tubes", "sheaths"),
        ("headings", "north", "headings"),
        ("chlorophyll_ug_cm2", -5.0, "chlorophyll_ug_cm2"),
        ("soil_respiration_q10", 0.5, "soil_respiration_q10"),
        ("soil_respiration_umol_m2_s", 1e308, "soil_respiration_umol_m2_s"),
        ("parameter_file", "no_such_plant.xml", "parameter_file"),
    ],
)
def test_a_configuration_refuses_a_bad_setting_when_it_is_made(setting, value, named):
    """ReplicationConfig took these as given and the run refused them (a review): now the
    configuration checks every setting when it is made, with the run's own checks
    (ReplicationConfig.check; Scenario's list is model.scenario.check_settings), naming the setting."""
    with pytest.raises(rep.InputError, match=rf"parameter '{named}'"):
        rep.ReplicationConfig(**{setting: value})


def test_an_adaptive_pilot_above_the_cap_is_refused_naming_samples():
    """With a target, samples is each segment's pilot count and the documented cap is 8 192
    (docs/light.md, "Adaptive sampling"): `lightfit replicate --target-rse 0.1 --samples 8200` grew
    the plants and then stopped naming 'max_samples', which no option sets. Now the configuration
    refuses it naming samples; the cap itself is a valid pilot, and a fixed K has no such cap."""
    with pytest.raises(rep.InputError, match=r"parameter 'samples'.*at most the adaptive cap of 8192"):
        rep.ReplicationConfig(samples=8200, target_rse=0.1)
    assert rep.ReplicationConfig(samples=8192, target_rse=0.1).samples == 8192
    assert rep.ReplicationConfig(samples=16384).samples == 16384


def test_overrides_are_stored_in_one_form_and_read_back_equal():
    """A configuration's photosynthesis_overrides from a mapping or from the lists its JSON gives
    back are the same sorted pairs: the configuration read back compares equal."""
    from dataclasses import asdict, replace

    cfg = replace(rep.ReplicationConfig.quick(), photosynthesis_overrides={"vcmax_ref_umol_m2_s": 85, "a1": 4.5})
    assert cfg.photosynthesis_overrides == (("a1", 4.5), ("vcmax_ref_umol_m2_s", 85.0))
    stored = json.loads(json.dumps(asdict(cfg)))
    assert stored["photosynthesis_overrides"] == [["a1", 4.5], ["vcmax_ref_umol_m2_s", 85.0]]
    assert replace(cfg, photosynthesis_overrides=stored["photosynthesis_overrides"]) == cfg


def test_a_configuration_can_be_changed_a_setting_at_a_time():
    """The dates' growth range is checked at the run, not when a configuration is made: a season
    start moved before the dates that fit it passes (a review found such chains refused, naming a
    target_date never set); a misspelt set is named before the growth temperature it decides; and
    making one computes no leaf spectra (no renderer needed)."""
    from dataclasses import replace

    cfg = replace(replace(rep.ReplicationConfig(), season_start="2016-05-01"), dates=("2016-06-01",))
    assert cfg.field().growth.target_date == "2016-06-01"
    with pytest.raises(rep.InputError, match="target_date"):  # the run's field still checks the range
        replace(rep.ReplicationConfig(), season_start="2016-05-01").field()
    with pytest.raises(rep.InputError, match="parameter 'photosynthesis'"):
        rep.ReplicationConfig(photosynthesis="foo", growth_temperature_c=20.0)


def test_a_valid_configuration_is_what_the_scenario_takes():
    """The settings a configuration checks are the ones its scenario is built from: the main job's,
    the quick one and the paper preset pass both, and the configuration's normalised values are the
    scenario's (checked once, in one place)."""
    for cfg in (rep.ReplicationConfig(), rep.ReplicationConfig.quick(), rep.ReplicationConfig.paper()):
        sc = rep.scenario_for(cfg, rep.forcing_of(cfg))
        assert sc.direct == rep.resolve_direct(cfg.direct, cfg.boundary)
        assert sc.samples == cfg.render_samples() and sc.seed == cfg.render_seed
        assert sc.photosynthesis == cfg.photosynthesis and sc.par_kind == cfg.par_kind


def test_a_configuration_records_what_its_scenario_takes():
    """results.nc's replication_config held the configuration as given: null bounces, chlorophyll,
    buffers and season start, "auto" direct light and profile where the run took numbers and names (a
    review). ReplicationConfig.effective records what the run's Scenario is made with."""
    from lightfit.light.leaf_optics import LeafTraits
    from lightfit.light.scene import Optics
    from lightfit.photosynthesis.canopy import profile_for
    from lightfit.photosynthesis.parameters import growth_temperature

    for cfg in (rep.ReplicationConfig(), rep.ReplicationConfig.quick(), rep.ReplicationConfig.paper()):
        w = rep.forcing_of(cfg)
        sc, took = rep.scenario_for(cfg, w), cfg.effective(w)
        assert (took["samples"], took["bounces"], took["direct"]) == (sc.samples, sc.bounces, sc.direct)
        assert took["vcmax_profile"] == profile_for(sc.vcmax_profile, sc.photosynthesis)
        assert took["growth_temperature_c"] == growth_temperature(sc.photosynthesis, sc.growth_temperature_c)
        assert (took["buffer_rows"], took["buffer_along"]) == (sc.field.buffer_rows, sc.field.b_along)
        assert took["season_start"] == sc.field.growth.season_start
        chl = took["chlorophyll_ug_cm2"]
        leaf = Optics.preset("paper") if chl is None else Optics.from_traits(LeafTraits(Cab=chl))
        assert leaf == sc.optics
        assert json.loads(json.dumps(took)) == took and None not in (took["bounces"], took["samples"])
        assert took["photosynthesis_overrides"] == dict(sc.photosynthesis_overrides) == {}
        assert took["n_plants"] == int(sc.field.plants()["measured"].sum())
        # the paths cast no projected rays: none recorded there (the default's were, a review)
        assert took["direct_rays_per_m2"] == (None if sc.direct == "paths" else list(sc.direct_rays_per_m2))
    # 5 plants asked for build the 3 × 3 measurement area: its 9 recorded, not 5 (a review)
    from lightfit.report import summary_metadata

    for boundary in ("periodic", "finite"):
        five = dataclasses.replace(rep.ReplicationConfig.quick(), n_plants=5, boundary=boundary)
        w = rep.forcing_of(five)
        fld = rep.scenario_for(five, w).field
        built = fld.plants()
        assert five.effective(w)["n_plants"] == int(built["measured"].sum()) != five.n_plants
        # the summary header and the figure's title say so too (they said "5 plants")
        attrs = fld.attrs() | {"samples": 16, "bounces": 2}
        assert summary_metadata(xr.Dataset(attrs=attrs))["field"].startswith(f"{int(built['measured'].sum())} plants")
        assert five.effective(w)["plants_per_row"] == 3  # the square's side: the record rebuilds the same area
    # whole rows (plants_per_row): 5 plants in rows of 3 build 2 × 3, recorded and said as 6
    rows = dataclasses.replace(rep.ReplicationConfig.quick(), n_plants=5, plants_per_row=3)
    fld = rows.field()
    assert (fld.n_rows, fld.n_along) == (2, 3) and fld.plants()["measured"].sum() == 6
    assert {k: rows.effective()[k] for k in ("n_plants", "plants_per_row")} == {"n_plants": 6, "plants_per_row": 3}
    header = summary_metadata(xr.Dataset(attrs=fld.attrs() | {"samples": 16, "bounces": 2}))
    assert header["field"].startswith("6 plants")
    own = dataclasses.replace(rep.ReplicationConfig.quick(), photosynthesis_overrides={"a1": 4.5})
    assert own.effective()["photosynthesis_overrides"] == {"a1": 4.5}
    # dates in two years: each its own 5 March
    two = rep.ReplicationConfig(dates=("2016-04-20", "2017-04-20")).effective()
    assert two["season_start"] == {"2016-04-20": "2016-03-05", "2017-04-20": "2017-03-05"}


def test_the_summary_header_names_a_given_theta():
    """summary.csv of `replicate --theta` said "preset: default" and nothing of the fitted leaf, so a
    calibrated day's table read as the preset's (a review with a user's own data); the figure's
    title named θ already."""
    from lightfit.report import summary_metadata

    attrs = {"preset": "default", "samples": 16, "bounces": 2}
    assert "theta_given" not in summary_metadata(xr.Dataset(attrs=attrs))
    given = json.dumps({"specular": 0.4625, "light_factor": 0.9643})
    assert summary_metadata(xr.Dataset(attrs=attrs | {"theta_given": given}))["theta_given"] == given


def test_the_summary_header_says_where_fapar_exceeds_one_and_per_which_area():
    """A finite field's fapar reached 4.50 at a 4° sun (`--quick --boundary finite`): the console
    said why in a note, summary.csv's column stood there without it. Its header now says how many
    steps, the largest value and the area APAR is per; nothing where fAPAR stays at or below 1."""
    from lightfit.report import summary_metadata

    attrs = {"boundary": "finite", "ground_area_m2": 4 * 0.03 * 0.125, "samples": 16, "bounces": 2}
    edge = xr.Dataset({"fapar": ("time", [0.0, 0.93, 4.497, 2.079, 1.0])}, attrs=attrs)
    line = summary_metadata(edge)["fapar"]
    assert line.startswith("above 1 at 2 of 5 steps (up to 4.50)")  # 4.497 and 2.079; 1.0 is not above
    assert "per ground area of the measured plants (0.015 m2)" in line and "finite field" in line
    canopy = xr.Dataset({"fapar": ("time", [0.0, 0.9397, 0.954])}, attrs=attrs | {"boundary": "periodic"})
    assert "fapar" not in summary_metadata(canopy)


def test_a_forcing_its_forcing_csv_cannot_hold_is_refused_before_the_run(tmp_path, monkeypatch):
    """run(out=...) writes the forcing as a lightfit CSV, whose provenance is one of four words. A
    forcing_df saying another ("station") rendered every step, wrote results.nc, replication.png and
    summary.csv, and only then failed at forcing.csv: a folder without its forcing, after minutes.
    It is refused before the plants grow and nothing is written; so is a forcing with no step in the
    run's windows, with its own error (its description raised an IndexError there first)."""
    from lightfit.errors import InputError

    monkeypatch.setattr(rep, "model_for", lambda *a, **k: pytest.fail("the run began"))
    w = rep.forcing().iloc[14:15]
    w.attrs = dict(w.attrs, provenance="station")
    with pytest.raises(InputError, match="provenance.*measured / reconstructed / synthetic / unstated"):
        rep.run(rep.ReplicationConfig.quick(), forcing_df=w, observations=None, out=tmp_path / "o")
    later = rep.forcing().iloc[14:15]
    later.index = later.index + np.timedelta64(1, "D")
    with pytest.raises(InputError, match="the forcing has no step in the run's windows"):
        rep.run(rep.ReplicationConfig.quick(), forcing_df=later, observations=None, out=tmp_path / "o")
    assert not (tmp_path / "o").exists()


def test_an_observations_frame_without_sds_is_refused_before_the_run(tmp_path, monkeypatch):
    """run(observations=frame) reads the run's fit with the readings' SDs (observations_fit). A frame
    with a value but no SD passed the checks before the run, rendered every step and then failed
    there, after the whole simulation; it is refused first, as the same readings in a file are by
    their reader."""
    import pandas as pd

    from lightfit.errors import InputError
    from lightfit.inference.observations import read_observations

    w = rep.forcing().iloc[14:15]
    f = tmp_path / "obs.csv"
    f.write_text(
        "# provenance: synthetic\n# time_zone: UTC\ntime,plant_par_umol_m2_s,plant_par_sd_umol_m2_s\n"
        f"{w.index[0]:%Y-%m-%d %H:%M},200,\n"
    )
    with pytest.raises(InputError, match="without a positive standard deviation"):
        read_observations(f)  # the file: refused by its reader
    obs = pd.DataFrame({"plant_par_umol_m2_s": [200.0], "plant_par_sd_umol_m2_s": [np.nan]}, index=w.index)
    obs.attrs = {"source": "frame", "provenance": "synthetic"}
    monkeypatch.setattr(rep, "model_for", lambda *a, **k: pytest.fail("the run began"))
    with pytest.raises(InputError, match="plant_par_sd_umol_m2_s.*a finite SD > 0"):
        rep.run(rep.ReplicationConfig.quick(), forcing_df=w, observations=obs, out=tmp_path / "o")
    assert not (tmp_path / "o").exists()
    # a frame without any value (its reader refuses such a file): refused first too
    empty = obs.assign(plant_par_umol_m2_s=np.nan)
    with pytest.raises(InputError, match="frame: no observed value in any column"):
        rep.run(rep.ReplicationConfig.quick(), forcing_df=w, observations=empty, out=tmp_path / "o")
    assert not (tmp_path / "o").exists()
