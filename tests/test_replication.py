"""The coupled model, observations, calibration and the 20 April 2016 regression curve."""

import json
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

import lightfit  # noqa: F401
from lightfit import replication as rep
from lightfit.cli import app
from lightfit.errors import InputError
from lightfit.inference.calibration import calibrate, make_loss, to_unconstrained
from lightfit.inference.observations import align, read_observations, write_observations
from lightfit.inference.twin import twin_observations
from lightfit.model.parameters import Theta

REFERENCE = Path(__file__).parent / "reference" / "replication_quick.json"


@pytest.fixture(scope="module")
def short_model():
    """Quick configuration on a 3-hour window around noon (7 steps)."""
    w = rep.forcing()
    w = w.loc["2016-04-20 09:00+00:00":"2016-04-20 12:00+00:00"]
    return rep.model_for(rep.ReplicationConfig.quick(), w)


def test_regression_against_stored_20_april_curve():
    ref = json.loads(REFERENCE.read_text())
    cfg = rep.ReplicationConfig(**ref["config"])
    ds, _ = rep.run(cfg, observations=None)
    c = ref["curve"]
    for v, sd in (
        ("plant_par_umol_m2_s", "plant_par_mc_sd_umol_m2_s"),
        ("canopy_an_umol_m2_s", "canopy_an_mc_sd_umol_m2_s"),
    ):
        new, old, err = ds[v].values, np.asarray(c[v]), np.asarray(c[sd])
        # Same seed: identical on the same platform. The tolerance allows other platforms' float
        # rounding; a model change moving the curve by 4 Monte Carlo SDs (of a difference) fails.
        tol = 4 * np.sqrt(2) * err + 1e-6 * np.abs(old) + 1e-9
        assert (np.abs(new - old) <= tol).all(), (v, np.abs(new - old).max())
    assert ds.attrs["weather_provenance"] == "reconstructed"


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


def test_end_to_end_gradient_matches_central_differences(short_model):
    obs = twin_observations(
        short_model, {"specular": 0.6, "roughness": 0.4, "subsurface": 0.5}, render_seed=3, noise_seed=1
    )
    names = ("specular", "subsurface", "light_factor", "vcmax_scale")
    loss = make_loss(short_model, obs, names)
    z = jnp.asarray([to_unconstrained(v, n) for v, n in zip((0.45, 0.35, 1.1, 0.9), names)])
    import jax

    g = np.asarray(jax.grad(lambda z: loss(z)[0])(z))
    h = 1e-3
    fd = [(float(loss(z.at[i].add(h))[0]) - float(loss(z.at[i].add(-h))[0])) / (2 * h) for i in range(len(names))]
    # Fixed seed + frozen sampling: the loss is smooth in θ and reverse-mode is its exact gradient
    # (up to the bilinear albedo table and float32 rendering).
    assert np.allclose(g, fd, rtol=0.03, atol=0.05 * np.abs(fd).max()), (g, fd)


def test_twin_calibration_recovers_specular(short_model, tmp_path):
    truth = {"specular": 0.7, "roughness": 0.4, "subsurface": 0.6}
    # Same render seed as the model: this tests the calibration machinery on an exact model; the
    # honest twin (another seed, so Monte Carlo noise differs) is experiments/twin_2016_04_20.py.
    obs = twin_observations(
        short_model, truth, render_seed=short_model.scenario.seed, noise_seed=2, par_sd_rel=0.01, an_sd_umol_m2_s=0.3
    )
    res = calibrate(
        short_model,
        obs,
        names=("specular",),
        start={"specular": 0.3},
        fixed={"roughness": 0.4, "subsurface": 0.6},
        history=tmp_path / "h.jsonl",
        resume=False,
        progress=False,
    )
    assert res.theta["specular"] == pytest.approx(0.7, abs=0.12)
    lines = (tmp_path / "h.jsonl").read_text().splitlines()
    assert len(lines) >= 2 and json.loads(lines[-1])["loss"] <= json.loads(lines[0])["loss"]


def test_calibration_resumes_from_history(short_model, tmp_path):
    obs = twin_observations(short_model, {"specular": 0.7}, render_seed=5, noise_seed=3)
    h = tmp_path / "h.jsonl"
    first = calibrate(
        short_model,
        obs,
        names=("specular",),
        start={"specular": 0.2},
        max_steps=2,
        history=h,
        resume=False,
        progress=False,
    )
    n_first = len(h.read_text().splitlines())
    # A line cut by an interruption is ignored; finished steps are kept and continued from.
    with open(h, "a") as f:
        f.write('{"step": 99, "loss": 0.1, "the')
    second = calibrate(
        short_model,
        obs,
        names=("specular",),
        start={"specular": 0.2},
        max_steps=3,
        history=h,
        resume=True,
        progress=False,
    )
    lines = h.read_text().splitlines()
    assert len(lines) > n_first
    assert second.loss <= first.loss + 1e-9


def test_observation_file_round_trip_and_alignment(tmp_path):
    times = pd.date_range("2016-04-20 09:00", periods=5, freq="30min", tz="UTC")
    df = pd.DataFrame(
        {
            "par_umol_m2_s": [100.0, np.nan, 300.0, 310.0, 400.0],
            "par_sd_umol_m2_s": [5.0, np.nan, 5, 5, 5],
            "an_umol_m2_s": [np.nan, 2.0, 3.0, np.nan, 4.0],
            "an_sd_umol_m2_s": [np.nan, 0.5, 0.5, np.nan, 0.5],
        },
        index=times + pd.Timedelta("2min"),
    )
    p = write_observations(df, tmp_path / "obs.csv", {"provenance": "synthetic"})
    back = read_observations(p)
    assert back.attrs["provenance"] == "synthetic"
    a = align(back, times)
    assert a["par_umol_m2_s"][0] == 100.0 and np.isnan(a["par_umol_m2_s"][1])
    assert a["an_umol_m2_s"][1] == 2.0
    # Two observations in one step are averaged; SD of the mean.
    two = pd.concat([df.iloc[[2]], df.iloc[[2]].assign(par_umol_m2_s=320.0)])
    two.index = [times[2], times[2] + pd.Timedelta("5min")]
    two.attrs = {"source": "x"}
    a2 = align(two, times)
    assert a2["par_umol_m2_s"][2] == pytest.approx(310.0) and a2["par_sd_umol_m2_s"][2] == pytest.approx(5 / np.sqrt(2))
    late = df.iloc[[0]].copy()
    late.index = [times[-1] + pd.Timedelta("3h")]
    late.attrs = {"source": "late.csv"}
    with pytest.raises(InputError, match="outside the run"):
        align(late, times)


@pytest.mark.parametrize(
    "body, match",
    [
        ("time,par_umol_m2_s,par_sd_umol_m2_s,an_umol_m2_s\n", "missing column"),
        ("time,par_umol_m2_s,par_sd_umol_m2_s,an_umol_m2_s,an_sd_umol_m2_s\nsoon,1,1,,\n", "cannot parse time"),
        (
            "time,par_umol_m2_s,par_sd_umol_m2_s,an_umol_m2_s,an_sd_umol_m2_s\n2016-04-20 10:00,bright,1,,\n",
            "not a number",
        ),
        (
            "time,par_umol_m2_s,par_sd_umol_m2_s,an_umol_m2_s,an_sd_umol_m2_s\n2016-04-20 10:00,100,,,\n",
            "standard deviation",
        ),
        ("time,par_umol_m2_s,par_sd_umol_m2_s,an_umol_m2_s,an_sd_umol_m2_s\n2016-04-20 10:00,-5,1,,\n", "negative PAR"),
    ],
)
def test_bad_observation_files(tmp_path, body, match):
    p = tmp_path / "o.csv"
    p.write_text("# provenance: measured\n" + body)
    with pytest.raises(InputError, match=match):
        read_observations(p)
    q = tmp_path / "noprov.csv"
    q.write_text(body)
    with pytest.raises(InputError, match="provenance"):
        read_observations(q)


def test_bundled_record_is_real_and_par_only():
    o = read_observations(rep.OBSERVATIONS)
    assert o.attrs["provenance"] == "measured" and len(o) == 1
    assert o["par_umol_m2_s"].iloc[0] == pytest.approx(1549.31) and np.isnan(o["an_umol_m2_s"].iloc[0])
    assert o.index[0] == pd.Timestamp("2016-04-20 10:13:48", tz="UTC")


def test_unknown_parameter_and_no_overlap(short_model):
    obs = read_observations(rep.OBSERVATIONS)
    with pytest.raises(InputError, match="unknown parameter"):
        make_loss(short_model, obs, ("glossiness",))


def test_cli_replicate_quick_and_calibrate(tmp_path, monkeypatch):
    runner = CliRunner()
    r = runner.invoke(app, ["replicate", "--quick", "--out", str(tmp_path / "rep")])
    assert r.exit_code == 0, r.output
    for f in ("results.nc", "replication.png", "summary.csv", "forcing.csv"):
        assert (tmp_path / "rep" / f).exists()
    import xarray as xr

    ds = xr.open_dataset(tmp_path / "rep" / "results.nc", engine="h5netcdf")
    assert set(ds.dims) == {"time", "segment"} and ds.sizes["time"] == 29
    assert "obs_par_umol_m2_s" in ds and np.isfinite(ds["obs_par_umol_m2_s"].values).sum() == 1
    ds.close()
    obs = tmp_path / "obs.csv"
    obs.write_text(
        "# provenance: synthetic\n# time_zone: UTC\ntime,par_umol_m2_s,par_sd_umol_m2_s,an_umol_m2_s,an_sd_umol_m2_s\n"
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
            "--max-steps",
            "3",
            "--out",
            str(tmp_path / "cal"),
        ],
    )
    assert r.exit_code == 0, r.output
    res = json.loads((tmp_path / "cal" / "calibration.json").read_text())
    assert res["parameters"] == ["light_factor"] and res["theta"]["light_factor"] > 0
    r = runner.invoke(app, ["calibrate", str(obs), "--quick", "--parameters", "shininess"])
    assert r.exit_code == 2 and "unknown parameter" in r.output
