"""``lightfit posterior`` on the CI-sized field, through the real app."""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from lightfit.cache import ENV_CACHE
from lightfit.cli import app
from lightfit.inference.mcmc import load_run
from lightfit.model import emulator as E


@pytest.fixture(autouse=True)
def design_cache(tmp_path, monkeypatch):
    """Every test its own shared design cache (never the user's ~/.cache/lightfit)."""
    monkeypatch.setenv(ENV_CACHE, str(tmp_path / "cache"))
    return tmp_path / "cache"


def test_posterior_cli_quick(tmp_path):
    """Bundled chamber record: the above-canopy sensor needs no render, so the design renders nothing
    (and there is nothing to check the emulator against)."""
    out = tmp_path / "post"
    args = [
        "posterior",
        "--quick",
        "--out",
        str(out),
        "--parameters",
        "specular,light_factor",
        "--walkers",
        "8",
        "--max-steps",
        "30",
        "--n-design",
        "6",
        "--n-test",
        "1",
    ]
    r = CliRunner().invoke(app, args)
    assert r.exit_code == 0, r.output
    s = json.loads((out / "summary.json").read_text())
    assert s["names"] == ["specular", "light_factor"] and s["n_steps"] == 30
    # every seed the run used is in the summary (the design's and the predictive draws' were nowhere)
    assert s["seeds"] == {"sampler": 0, "render": s["seeds"]["render"], "emulator_design": [0], "predictive_draws": 1}
    assert s["seeds"]["render"] == load_run(out / "run.h5")["attrs"]["scenario"]["render_seed"]
    # the settings the run took (null for the leaf's chlorophyll, the set's growth temperature and the
    # bundled weather before: a review), beside the options asked for
    attrs = load_run(out / "run.h5")["attrs"]
    took = attrs["config"]
    assert (took["chlorophyll_ug_cm2"], took["growth_temperature_c"], took["bounces"]) == (50.5, 15.0, 2)
    assert (took["weather_file"], took["buffer_rows"], took["steps"]) == ("2016-04-20", 0, "0:29")
    assert attrs["options_given"] == ["--quick"]
    # The summary has them too (only run.h5 had: a summary read alone, as --theta may, said nothing of
    # the settings its MAP was fitted with), and is still read as a theta source (its MAP).
    from lightfit.cli.common import parse_theta, theta_cautions

    assert (s["config"], s["options_given"]) == (took, attrs["options_given"])
    alone = tmp_path / "elsewhere" / "summary.json"  # no run.h5 beside it
    alone.parent.mkdir()
    alone.write_text((out / "summary.json").read_text())
    assert parse_theta(str(alone)) == {k: pytest.approx(v) for k, v in s["x_map"].items()}
    said = [x for x in theta_cautions(str(alone), took | {"chlorophyll_ug_cm2": 40.0}) if "fitted with" in x]
    assert len(said) == 1 and "chlorophyll_ug_cm2 50.5; this run has chlorophyll_ug_cm2 40.0" in said[0], said
    assert "emulator_error" not in s and "sloppy" in s
    assert "design: none needed (the observed series depend on no rendered light)" in " ".join(r.output.split())
    # The MAP's χ², by hand: the one reading against the light factor × the forcing's PAR read linearly
    # between the steps around it; specular, which above-canopy PAR cannot inform, keeps its prior's SD.
    from lightfit import replication as rep
    from lightfit.inference.observations import read_observations

    obs, par = read_observations(rep.OBSERVATIONS), rep.forcing()["par_umol_m2_s"]
    t = obs.index[0]
    a, b = par.index[par.index <= t][-1], par.index[par.index > t][0]
    at = par[a] + (t - a) / (b - a) * (par[b] - par[a])
    y, sd = obs["above_canopy_par_umol_m2_s"].iloc[0], obs["above_canopy_par_sd_umol_m2_s"].iloc[0]
    assert s["n_observations"] == 1
    assert s["chi2_map"] == pytest.approx(((y - s["x_map"]["light_factor"] * at) / sd) ** 2, rel=1e-6, abs=1e-9)
    assert s["sd_over_prior_sd"]["specular"] > 0.9 > s["sd_over_prior_sd"]["light_factor"]
    assert "the data hardly inform specular" in " ".join(r.output.split())
    # each stage of the analysis is said as it starts (≈ 30 s of silence after the sampling's bar)
    stages = ["analysis: the MAP", "analysis: Fisher information", "analysis: posterior predictive", "posterior ("]
    at = [r.output.find(x) for x in stages]
    assert min(at) >= 0 and at == sorted(at), at
    # the corner plot is written with the analysis (only the notebook drew one): a PNG of a figure
    # with one panel per pair of the sampled parameters
    from PIL import Image

    with Image.open(out / "corner.png") as im:
        assert im.format == "PNG" and min(im.size) > 400
    status = CliRunner().invoke(app, ["posterior-status", str(out)])  # from run.h5's analysis, as said there
    assert status.exit_code == 0 and "the data hardly inform specular" in " ".join(status.output.split())
    # numbers not yet estimable show "–", the flag yes/no (they printed "nan" and Python's False)
    assert "nan" not in status.output + r.output and "emcee suggests 50): no;" in " ".join(status.output.split())
    run = load_run(out / "run.h5")
    # the 5/50/95 % quantiles (in run.h5 and marked in corner.png, not in the summary before): numpy's of
    # the stored chain after the documented burn-in, 25 % of the 30 steps
    kept = run["chain"][int(0.25 * 30) :].reshape(-1, 2)
    for q, p in (("q05", 5), ("q50", 50), ("q95", 95)):
        expect = np.percentile(kept, p, axis=0)
        assert [s[q][n] for n in s["names"]] == pytest.approx(expect, rel=1e-12), q
    # 30 steps keep far fewer than 50 τ: the command's own table says so, as posterior-status does
    assert not run["diagnostics"]["tau_reliable"] and s["tau_reliable"] is False
    assert "τ is not reliable yet" in " ".join(r.output.split())
    # the record observes above-canopy PAR only (nothing rendered): the other series are not predicted
    pred = run["analysis"]["predictive"]
    assert np.isfinite(pred["above_canopy_par_umol_m2_s"]).all() and np.isnan(pred["plant_par_umol_m2_s"]).all()
    assert run["chain"].shape == (30, 8, 2) and "analysis" in run
    # every dataset of the run file says its units and what it is (none did; a review of the outputs)
    import h5py

    described = []

    def visit(name, obj):
        if isinstance(obj, h5py.Dataset):
            described.append((name, "units" in obj.attrs and "long_name" in obj.attrs))

    with h5py.File(out / "run.h5", "r") as f:
        f.visititems(visit)
        assert f["analysis/predictive/above_canopy_par_umol_m2_s"].attrs["units"] == "umol m-2 s-1"
        assert "log-parameter space" in f["analysis/fisher/matrix"].attrs["long_name"]
    assert len(described) > 40 and all(ok for _, ok in described), [n for n, ok in described if not ok]
    # resuming to more steps appends
    r = CliRunner().invoke(app, args[:-6] + ["--max-steps", "40", "--n-design", "6", "--n-test", "1"])
    assert r.exit_code == 0, r.output
    assert load_run(out / "run.h5")["chain"].shape == (40, 8, 2)
    with np.load(out / "emulator.npz") as z:  # the emulator's key names the field it was rendered on
        assert "boundary='periodic'" in json.loads(str(z["key"]))["field"]
    # The stored chain is the periodic field's: resuming it on another field is refused, before any plant grows.
    r = CliRunner().invoke(app, [*args, "--boundary", "finite"])
    assert r.exit_code == 2 and "posterior run" in r.stderr and "boundary: 'periodic' → 'finite'" in r.stderr
    # Another sampler seed would continue the stored chain (seed 0) while the user asked for a new one: refused.
    r = CliRunner().invoke(app, [*args, "--sampler-seed", "3"])
    said = " ".join(r.stderr.split())
    assert r.exit_code == 2 and "sampled with seed 0 (--sampler-seed), this run asks for seed 3" in said
    assert "--no-resume" in said and load_run(out / "run.h5")["chain"].shape == (40, 8, 2)
    # Other walkers or parameters: refused before the plants grow (the sampler refused them after the
    # design, below a line that said the chain was being resumed)
    for other, words in (
        (["--walkers", "6"], "with 8 walkers; this run asks for specular, light_factor with 6"),
        (["--parameters", "light_factor"], "samples specular, light_factor with 8 walkers"),
    ):
        r = CliRunner().invoke(app, [*args[:4], *args[6:], *other] if other[0] == "--parameters" else [*args, *other])
        said = " ".join(r.stderr.split())
        assert r.exit_code == 2 and words in said and "--no-resume" in said, said
        assert "resuming" not in r.output and "plants" not in r.stdout


def test_posterior_cli_bad_parameter(tmp_path):
    r = CliRunner().invoke(app, ["posterior", "--quick", "--out", str(tmp_path), "--parameters", "specularity"])
    assert r.exit_code == 2 and "specularity" in r.stderr


def test_posterior_cli_n_test_zero(tmp_path):
    """--n-test 0: no held-out renders, no emulator-error report (it used to end in a ValueError traceback)."""
    args = ["posterior", "--quick", "--steps", "12:15", "--out", str(tmp_path), "--parameters", "light_factor"]
    r = CliRunner().invoke(app, [*args, "--walkers", "4", "--max-steps", "20", "--n-design", "6", "--n-test", "0"])
    assert r.exit_code == 0, r.output
    s = json.loads((tmp_path / "summary.json").read_text())
    assert s["n_steps"] == 20 and "emulator_error" not in s
    assert (tmp_path / "corner.png").stat().st_size > 10_000  # one parameter: a histogram, not corner's grid


def test_posterior_summary_says_the_observations_are_synthetic(tmp_path):
    """summary.json named neither the observations nor what they are (run.h5 had their path and
    provenance): a summary read alone, as --theta reads it, could not tell a posterior of the
    bundled synthetic twin from one of measurements. It now has the file, its provenance and its
    title and generator lines, and the printed table says the observations are synthetic."""
    from lightfit.weather.bundled import DATA_DIR

    twin = DATA_DIR / "observations" / "twin_2016-04-20_synthetic.csv"
    args = ["posterior", str(twin), "--quick", "--steps", "12:15", "--out", str(tmp_path), "--parameters"]
    args += ["light_factor", "--walkers", "4", "--max-steps", "20", "--n-design", "6", "--n-test", "0"]
    r = CliRunner().invoke(app, args)
    assert r.exit_code == 0, r.output
    s = json.loads((tmp_path / "summary.json").read_text())
    assert s["observations"] == str(twin.resolve()) and s["observations_provenance"] == "synthetic"
    head = dict(line[2:].split(": ", 1) for line in twin.read_text().splitlines() if line.startswith("# "))
    assert s["observations_metadata"] == {k: head[k] for k in ("title", "generator")}
    assert "posterior to synthetic observations" in " ".join(r.output.split())


def test_posterior_cli_refuses_a_leaf_parameter_outside_the_emulator_box(tmp_path):
    """--optics paper without subsurface among the parameters: the grey leaf's own subsurface (0.3)
    lies outside the box the emulator is built on (its informed prior, 0.04–0.17), where the emulated
    light would be extrapolated; refused naming it, before any design render (it ran to the end).
    Sampling specular against data that cannot inform it is said first."""
    before = dict(E.COUNTS)
    args = ["posterior", "--quick", "--steps", "12:15", "--optics", "paper", "--parameters", "specular,light_factor"]
    r = CliRunner().invoke(app, [*args, "--walkers", "4", "--max-steps", "5", "--n-test", "0", "--out", str(tmp_path)])
    said = " ".join(r.stderr.split())
    assert r.exit_code == 2, r.output
    assert "subsurface is not sampled and stays at 0.3" in said and "box [0.04, 0.17]" in said
    assert "add it to --parameters" in said and "--priors wide" in said
    assert E.COUNTS == before and not (tmp_path / "run.h5").exists()
    # The chamber record (above-canopy PAR) does not depend on specular: said before anything runs.
    out = " ".join(r.stdout.split())
    assert "no observed series in the likelihood (above_canopy_par) depends on specular:" in out
    assert "their posterior is their prior" in out and "light_factor" not in out.split("depends on")[1]


OBS = (
    "# provenance: synthetic\n# note: cache test\ntime,plant_par_umol_m2_s,plant_par_sd_umol_m2_s\n"
    "2016-04-20T09:00:00Z,300,20\n2016-04-20T10:00:00Z,400,20\n"
)


def test_calibrate_then_posterior_share_the_design_and_a_key_change_rebuilds(tmp_path, design_cache):
    """One emulator design for both commands (issue 15): lightfit calibrate renders the design (and its
    check renders), lightfit posterior on the same configuration renders nothing new; another render
    setting (--samples) is another key, so its design is rendered afresh."""
    obs = tmp_path / "obs.csv"
    obs.write_text(OBS, encoding="utf-8")
    model = ["--quick", "--steps", "12:15", "--n-design", "6"]
    r = CliRunner().invoke(
        app, ["calibrate", str(obs), *model, "--parameters", "specular", "--out", str(tmp_path / "cal")]
    )
    assert r.exit_code == 0, r.output
    cal = json.loads((tmp_path / "cal" / "calibration.json").read_text())["surrogate"]
    assert cal["mode"] == "surrogate" and cal["passed"] and cal["sun_positions_rendered"] == 2
    assert cal["renders_new"] == 6 + len(cal["rounds"]) and "full-render check" in r.output
    before = dict(E.COUNTS)
    post = ["posterior", str(obs), *model, "--parameters", "specular", "--walkers", "4", "--max-steps", "10"]
    r = CliRunner().invoke(app, [*post, "--n-test", "0", "--no-analysis", "--out", str(tmp_path / "post")])
    assert r.exit_code == 0, r.output
    assert E.COUNTS["rendered"] == before["rendered"]  # counted: no render at all
    # calibrate's first-round emulator (the plain Sobol design) is this one: not even refitted
    assert "design: no renders (2 sun positions" in r.output.replace("\n", "")
    assert "; the stored emulator of 6 design points reused" in r.output.replace("\n", "")  # not 'no design'
    (d,) = (design_cache / "designs").iterdir()
    assert len(list((d / "renders").glob("*.npz"))) == 6 + len(cal["rounds"])
    # another render key (samples 16 → 8): a new design directory, rendered anew
    r = CliRunner().invoke(
        app, [*post, "--samples", "8", "--n-test", "0", "--no-analysis", "--out", str(tmp_path / "post8")]
    )
    assert r.exit_code == 0, r.output
    assert E.COUNTS["rendered"] == before["rendered"] + 6
    assert len(list((design_cache / "designs").iterdir())) == 2


def test_posterior_cli_interrupted_while_sampling_says_how_to_resume(tmp_path, monkeypatch):
    """Ctrl-C while sampling (a KeyboardInterrupt from the log-probability after 12 calls): exit 130,
    a line saying that the run keeps its steps and to rerun the same command, and no analysis of the
    partial chain (it used to exit 0 and analyse it); the same command then resumes and analyses."""
    from lightfit.inference import posterior as A

    real = A.sample

    class Interrupting:
        def __init__(self, lp):
            self.lp, self.calls = lp, 0

        def __getattr__(self, name):
            return getattr(self.lp, name)

        def __call__(self, x):
            self.calls += 1
            if self.calls > 12:
                raise KeyboardInterrupt
            return self.lp(x)

    monkeypatch.setattr(A, "sample", lambda lp, *a, **k: real(Interrupting(lp), *a, **k))
    out = tmp_path / "post"
    args = ["posterior", "--quick", "--out", str(out), "--parameters", "specular,light_factor", "--walkers", "8"]
    args += ["--max-steps", "30", "--n-design", "6", "--n-test", "1"]
    r = CliRunner().invoke(app, args)
    assert r.exit_code == 130, r.output
    assert "rerun the same command to resume" in " ".join(r.stderr.split())  # on stderr, as every error
    run = load_run(out / "run.h5")
    assert 0 < run["chain"].shape[0] < 30 and "analysis" not in run
    monkeypatch.setattr(A, "sample", real)
    r = CliRunner().invoke(app, args)
    assert r.exit_code == 0, r.output
    run = load_run(out / "run.h5")
    assert run["chain"].shape == (30, 8, 2) and "analysis" in run


def test_the_emulator_is_checked_at_the_maps_own_leaf(tmp_path):
    """The held-out renders lie inside the emulator's box, where it is best; the MAP may sit on the
    box's edge, where a review measured 1.5–2 Monte Carlo SDs of emulator error. The analysis renders
    the MAP's leaf too and reports the shift there, the last held-out point."""
    obs = tmp_path / "obs.csv"
    obs.write_text(OBS)
    out = tmp_path / "post"
    args = ["posterior", str(obs), "--quick", "--out", str(out), "--parameters", "specular,light_factor"]
    r = CliRunner().invoke(app, [*args, "--walkers", "8", "--max-steps", "20", "--n-design", "6", "--n-test", "1"])
    assert r.exit_code == 0, r.output
    run = load_run(out / "run.h5")
    ee, x_map = run["analysis"]["emulator_error"], np.asarray(run["analysis"]["x_map"])
    assert int(ee["n_test"]) == 2  # the Sobol point and the MAP's leaf
    leaf = np.asarray(ee["at_map_leaf"])
    assert leaf[0] == pytest.approx(x_map[0], abs=0, rel=1e-12)  # specular from the MAP; the rest the leaf's own
    assert float(ee["at_map_shift_over_sd"]) == pytest.approx(float(np.asarray(ee["shift_over_sd_per_point"])[-1]))
    assert "over 1 held-out render and the MAP's leaf (" in " ".join(r.output.split())
    # the held-out render is counted apart from the design's six (a review: one line counted both)
    assert "design: 6 new renders, 0 from the cache" in r.output.replace("\n", "")
    assert "; held-out check: 1 new, 0 from the cache" in r.output.replace("\n", "")
    # and its progress line says so: "rendering design: 1/1" read as a design render (a review)
    assert "rendering design: 6/6" in r.output and "rendering held-out check: 1/1" in r.output, r.output
    assert np.asarray(ee["se_ratio_per_point"]).shape == (2,) and (np.asarray(ee["se_ratio_per_point"]) > 0).all()


def test_posterior_cli_damaged_run_file_is_named_or_replaced(tmp_path):
    """A run.h5 HDF5 cannot open (a kill inside HDF5's own write; a review of resumed runs truncated
    one) ended in h5py's traceback, with --no-resume too (after the plants and the design). Now a
    resume is refused naming the file and the way on, and --no-resume removes it and starts again."""
    out = tmp_path / "post"
    out.mkdir()
    (out / "run.h5").write_bytes(b"\x89HDF\r\n\x1a\n" + bytes(300))
    args = ["posterior", "--quick", "--steps", "12:15", "--out", str(out), "--parameters", "light_factor"]
    args += ["--walkers", "4", "--max-steps", "10", "--n-design", "6", "--n-test", "0", "--no-analysis"]
    r = CliRunner().invoke(app, args)
    said = " ".join(r.stderr.split())
    assert r.exit_code == 2 and "run.h5" in said and "not readable as a posterior run" in said
    assert "--no-resume" in said and (out / "run.h5").stat().st_size == 308
    r = CliRunner().invoke(app, [*args, "--no-resume"])
    assert r.exit_code == 0, r.output
    assert "not readable as a posterior run" in " ".join(r.output.split())
    assert load_run(out / "run.h5")["chain"].shape == (10, 4, 1)


def test_status_of_a_chain_too_short_for_its_diagnostics_prints_dashes_not_nan():
    """τ, ESS and split-R̂ are NaN until a chain is long enough; the tables printed "nan" and the
    reliability flag Python's False (a newcomer's audit). The stored tiny run with its τ, ESS and
    R̂ made NaN, as a 3-step chain has them."""
    from pathlib import Path

    from lightfit.cli.common import console
    from lightfit.cli.posterior import _print_status
    from lightfit.inference.mcmc.backend import run_status

    st = run_status(Path(__file__).parent / "fixtures" / "posterior_tiny.h5")
    for k in ("tau", "ess", "rhat"):
        st["diagnostics"][k] = np.full_like(st["diagnostics"][k], np.nan)
    with console.capture() as cap:
        _print_status(st)
    text = " ".join(cap.get().split())
    assert "nan" not in text.lower() and "False" not in text, text
    assert "emcee suggests 50): no; max split-R̂ –;" in text and "max τ –;" in text and "│ specular │ – │ – │" in text


def test_status_before_the_first_step_has_no_acceptance_to_judge():
    """A run read before its first step (posterior-status while it starts, a Ctrl-C during the first
    step) read "acceptance 0.00 (outside 0.1–0.8)": 0 accepted of max(0, 1) steps. There is no rate
    yet: NaN, not judged, printed as a dash."""
    from pathlib import Path

    from lightfit.cli.common import console
    from lightfit.cli.posterior import _print_status
    from lightfit.inference.mcmc.backend import run_status
    from lightfit.inference.mcmc.diagnostics import diagnostics

    d = diagnostics(np.zeros((0, 4, 2)), np.zeros(4))
    assert np.isnan(d["acceptance_mean"]) and np.isnan(d["acceptance"]).all() and d["acceptance_ok"] is True
    assert diagnostics(np.zeros((10, 4, 2)), np.zeros(4))["acceptance_ok"] is False  # 0 of 10: judged
    st = run_status(Path(__file__).parent / "fixtures" / "posterior_tiny.h5")
    st["diagnostics"] |= {k: d[k] for k in ("acceptance", "acceptance_mean", "acceptance_ok")}
    with console.capture() as cap:
        _print_status(st)
    text = " ".join(cap.get().split())
    assert "acceptance (kept steps) –; τ reliable" in text and "outside" not in text, text


def test_cautions_say_how_a_short_chain_goes_on_by_why_it_stopped():
    """After a Ctrl-C (or a kill, or --max-minutes) the R̂ and τ cautions said "resume with a larger
    --max-steps" beside Ctrl-C's right "rerun the same command": a rerun resumes the chain, the steps
    limit was not what stopped it. Only a run that used its --max-steps needs a larger one."""
    from lightfit.cli.posterior import _cautions

    short = {"names": ["specular"], "rhat": [1.6], "tau_reliable": False, "tau_multiple": 20}
    for why in ({"stopped_by": "interrupted"}, {"stopped_by": "max_seconds"}, {"state": "killed"}):
        said = _cautions(short | why)
        assert len(said) == 2 and all("rerun the same command to resume it" in s for s in said), said
        assert not any("--max-steps" in s for s in said), said
    said = _cautions(short | {"stopped_by": "max_steps"})
    assert len(said) == 2 and all("resume with a larger --max-steps" in s for s in said), said
    said = _cautions(short | {"state": "running", "stopped_by": None})
    assert all("it is still running" in s for s in said), said


def test_no_analysis_on_an_analysed_chain_it_does_not_extend_keeps_its_summary_and_corner(tmp_path):
    """--no-analysis on a finished, analysed run whose chain it did not extend replaced summary.json
    with the sampling's numbers alone (no MAP, means or SDs: --theta OUT/summary.json found no MAP)
    and removed corner.png, while run.h5 kept the analysis and the status it printed said "analysis
    written"; it also told to rerun to analyse. Both now stay; a call that extends the chain still
    drops them (they describe the shorter chain)."""
    out = tmp_path / "post"
    args = ["posterior", "--quick", "--steps", "12:15", "--out", str(out), "--parameters", "light_factor"]
    args += ["--walkers", "4", "--n-design", "6", "--n-test", "0"]
    r = CliRunner().invoke(app, [*args, "--max-steps", "20"])
    assert r.exit_code == 0, r.output
    before = json.loads((out / "summary.json").read_text())
    assert "x_map" in before and (out / "corner.png").exists()
    r = CliRunner().invoke(app, [*args, "--max-steps", "20", "--no-analysis"])
    assert r.exit_code == 0, r.output
    said = " ".join(r.output.split())
    assert "analysis written" in said and "the chain was not extended" in said and "rerun with" not in said
    assert json.loads((out / "summary.json").read_text()) == before and (out / "corner.png").exists()
    assert "analysis" in load_run(out / "run.h5")
    r = CliRunner().invoke(app, [*args, "--max-steps", "30", "--no-analysis"])  # extends it: 20 → 30 steps
    assert r.exit_code == 0, r.output
    after = json.loads((out / "summary.json").read_text())
    assert after["n_steps"] == 30 and "x_map" not in after and not (out / "corner.png").exists()
    assert "analysis" not in load_run(out / "run.h5") and "rerun with --analysis" in " ".join(r.output.split())


def test_the_rhat_caution_points_to_corner_png_only_where_it_shows_this_chain(tmp_path, monkeypatch):
    """The walkers-disagree caution ended "(the run's corner.png shows where they are)" also where no
    corner plot of the chain exists: posterior-status of an interrupted run or of one sampled with
    --no-analysis (none, or an earlier, shorter chain's left beside it). Said only where the run has
    its analysis and the file is there."""
    import importlib
    import shutil
    from pathlib import Path

    from lightfit.inference.mcmc.backend import run_status

    C = importlib.import_module("lightfit.cli.posterior")  # the module (lightfit.cli's name is the command)

    path = tmp_path / "run.h5"
    shutil.copy(Path(__file__).parent / "fixtures" / "posterior_tiny.h5", path)
    lines = []
    monkeypatch.setattr(C, "caution", lines.append)  # the cautions, as printed on stderr

    def said(analysed: bool) -> str:
        st = run_status(path)
        st["diagnostics"]["rhat"] = np.full_like(st["diagnostics"]["rhat"], 1.5)  # walkers disagree
        st["analysis"] = analysed
        lines.clear()
        with C.console.capture():
            C._print_status(st)
        (text,) = [x for x in lines if x.startswith("the walkers disagree (split-R̂ 1.5")]
        return text

    assert "corner.png" not in said(True)  # analysed, but no corner plot beside it
    (tmp_path / "corner.png").write_bytes(b"")
    assert "(the run's corner.png shows where they are)" in said(True)
    assert "corner.png" not in said(False)  # an earlier chain's plot: the analysis was dropped


def test_reanalysing_a_finished_chain_says_it_sampled_nothing_now_and_gives_the_same_numbers(tmp_path):
    """The same command on a finished run analyses the stored chain again without sampling. Its table
    read "(max_steps, 20 steps, 0 s sampling)", as if the 20 steps had taken no time (the seconds are
    this call's): it now says how many steps this call sampled, as summary.json does; the means, SDs
    and MAP are the first analysis's."""
    out = tmp_path / "post"
    args = ["posterior", "--quick", "--steps", "12:15", "--out", str(out), "--parameters", "light_factor"]
    args += ["--walkers", "4", "--n-design", "6", "--n-test", "0", "--max-steps", "20"]
    r = CliRunner().invoke(app, args)
    assert r.exit_code == 0, r.output
    first = json.loads((out / "summary.json").read_text())
    assert first["steps_this_call"] == 20 and "20 steps; this call sampled 20 in" in " ".join(r.output.split())
    r = CliRunner().invoke(app, args)
    assert r.exit_code == 0, r.output
    again = json.loads((out / "summary.json").read_text())
    assert again["steps_this_call"] == 0 and "20 steps; this call sampled 0 in" in " ".join(r.output.split())
    for k in ("mean", "sd", "x_map", "chi2_map", "tau", "ess", "rhat", "acceptance_mean"):
        assert again[k] == first[k], k


def test_the_printed_directions_say_their_widths_and_which_the_data_leave_free():
    """y = a·b·x fixes only a·b: by hand F = S·[[1, 1], [1, 1]] in log coordinates, S = Σ(a·b·x/σ)², so the
    stiff direction's 1σ width is 1/√(2S) and the sloppy one's is unbounded (eigenvalue 0). The printed
    line named both combinations alike, a direction the data fix to 0.7 % and one they say nothing of."""
    import jax.numpy as jnp

    from lightfit.cli.posterior import _directions
    from lightfit.inference.identifiability import fisher_information

    x, sigma, a, b = np.linspace(0.1, 2.0, 20), 0.05, 2.0, 0.5
    fi = fisher_information(lambda p: (a * b * x - p[0] * p[1] * jnp.asarray(x)) / sigma, [a, b], ("a", "b"))
    res = {"fisher": fi.table(), "stiff": fi.stiff, "sloppy": fi.sloppy}
    stiff_width = 1.0 / np.sqrt(2.0 * np.sum((a * b * x / sigma) ** 2))
    line = _directions(res)
    assert f"stiffest: +0.71 log a +0.71 log b (1σ width {stiff_width:.3g})" in line
    assert "sloppiest: +0.71 log a -0.71 log b (1σ width ∞)" in line
    assert "1 of 2 directions not identifiable" in line and "log units" in line
    # summary.json's strict JSON writes the unbounded width as null
    json_rows = [
        r | {"width_1sigma": None if not np.isfinite(r["width_1sigma"]) else r["width_1sigma"]} for r in res["fisher"]
    ]
    assert _directions(res | {"fisher": json_rows}) == line
