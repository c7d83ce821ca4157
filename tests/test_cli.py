"""The `lightfit` command line, end to end, always through the real app (`lightfit.cli.app`)."""

import json
import os
import re
import subprocess
import sys
import textwrap

import numpy as np
import pandas as pd
import pytest
import typer
from typer.testing import CliRunner

from lightfit.cli import app
from lightfit.errors import InputError
from lightfit.light import backend
from lightfit.weather import add_solar, read_weather
from lightfit.weather.bundled import DATA_DIR

runner = CliRunner()
#: The commands, in the order of ``lightfit --help``.
COMMANDS = tuple(typer.main.get_command(app).commands)
FIXTURE = DATA_DIR / "fixtures" / "tereno_SE_EC_001_fixture.csv"
OBSERVATIONS = DATA_DIR / "observations" / "chamber_2016-04-20_record.csv"
MODEL_COMMANDS = ("replicate", "calibrate", "posterior", "field-run")


def _flat(text: str) -> str:
    """Output with line breaks and runs of spaces collapsed (tables and panels wrap at 80 columns)."""
    return " ".join(text.split())


def assert_user_error(r, *words: str) -> None:
    """Exit status 2, every word in the message on stderr, nothing on stdout's error path, no traceback."""
    assert r.exit_code == 2, r.output
    assert isinstance(r.exception, SystemExit), r.exception  # not an uncaught exception
    err = _flat(r.stderr)
    assert err.startswith("error:") or "Usage:" in err, err
    for w in words:
        assert w in err, (w, err)
    assert "Traceback" not in r.output


@pytest.mark.parametrize("args", [[], *([c] for c in COMMANDS), ["weather", "show"]])
def test_help_texts_are_not_cut_at_80_columns(args):
    """Rich cuts a word longer than the help column with "…": a reference such as
    lightfit.light.estimator.bounces_for_tolerance could not be read in an 80-column terminal, nor
    render-dataset's option --sweep-elevation-deg (shown as "--sweep-elevation-…")."""
    r = runner.invoke(app, [*args, "--help"], env={"COLUMNS": "80"})
    assert r.exit_code == 0 and max(map(len, r.output.splitlines())) <= 80, r.output
    # A cut word ends in "…" at the end of its cell; the texts' own "…" follow a space (".svg, …").
    cut = [line for line in r.output.splitlines() if re.search(r"\S…(\s|$)", line)]
    assert not cut, cut


@pytest.mark.parametrize("args", [[], *([c] for c in COMMANDS), ["weather", "show"]])
def test_flags_are_shown_without_a_value_type(args):
    """Typer 0.29's help showed every flag as `--quick <bool>` (also --help, --resume --no-resume),
    which reads as an option taking a value: `--quick true` is a usage error (a newcomer review).
    Options with values keep their type."""
    r = runner.invoke(app, [*args, "--help"], env={"COLUMNS": "200"})
    assert r.exit_code == 0, r.output
    assert "<bool>" not in r.output and "--help " in r.output, r.output
    assert args != ["replicate"] or "<int>" in r.output


def test_help_lists_every_command():
    r = runner.invoke(app, ["--help"])
    assert r.exit_code == 0, r.output
    assert set(COMMANDS) == {
        "info",
        "weather",
        "field",
        "replicate",
        "calibrate",
        "posterior",
        "field-run",
        "render-dataset",
        "posterior-status",
    }
    for name in COMMANDS:
        assert f" {name} " in r.stdout, name


def test_model_commands_share_their_options():
    """Every command that runs the model has the same field/light/photosynthesis/weather options, with the same help."""
    from lightfit.photosynthesis import PARAMETER_SET_NAMES

    group = typer.main.get_command(app)

    def shared(name):
        return {p.name: (tuple(p.opts), p.help) for p in group.commands[name].params if p.rich_help_panel}

    ref = shared("replicate")
    for flag in (
        "--quick",
        "--n-plants",
        "--boundary",
        "--buffer-rows",
        "--buffer-along",
        "--field-seed",
        "--samples",
        "--bounces",
        "--render-seed",
        "--par-kind",
        "--photosynthesis",
        "--an-per",
        "--weather",
        "--how",
        "--steps",
        "--date",
        "--start-time",
        "--hours",
        "--step",
        "--site",
        "--latitude",
        "--longitude",
        "--altitude-m",
        "--timezone",
    ):
        assert any(flag in opts for opts, _ in ref.values()), flag
    for name in MODEL_COMMANDS[1:]:
        own = {k: v for k, v in shared(name).items() if k in ref}
        assert own == ref, name
    help_text = ref["photosynthesis"][1]
    assert all(n in help_text for n in PARAMETER_SET_NAMES)  # the help lists the sets that exist


def test_option_defaults_are_the_librarys():
    """Options whose default is a library default spelled as a literal (the command modules import no
    JAX or Mitsuba at import time) must stay equal to it: a changed library default would otherwise
    leave the command running another setting."""
    import dataclasses
    import inspect

    from lightfit.dataset import Camera, DatasetSpec, RenderSettings, Sweep
    from lightfit.inference import posterior
    from lightfit.inference.calibration import calibrate
    from lightfit.inference.mcmc import StopRule
    from lightfit.inference.trust_region import surrogate_calibrate
    from lightfit.weather.series import DEFAULT_MAX_GAP

    group = typer.main.get_command(app)

    def default(command, name, sub=None):
        cmd = group.commands[command] if sub is None else group.commands[command].commands[sub]
        (param,) = [p for p in cmd.params if p.name == name]
        return param.default

    def field_default(cls, name):
        f = {f.name: f for f in dataclasses.fields(cls)}[name]
        return f.default_factory() if f.default is dataclasses.MISSING else f.default

    run = inspect.signature(posterior.run).parameters
    cal = inspect.signature(calibrate).parameters
    sur = inspect.signature(surrogate_calibrate).parameters
    assert sur["max_steps"].default == cal["max_steps"].default  # the command passes one --max-steps to both
    pairs = {
        ("calibrate", "max_steps"): cal["max_steps"].default,
        ("calibrate", "max_rounds"): sur["max_rounds"].default,
        ("calibrate", "parameters"): ",".join(cal["names"].default),
        ("posterior", "parameters"): ",".join(posterior.SAMPLED_BY_DEFAULT),
        ("posterior", "walkers"): run["nwalkers"].default,
        ("posterior", "max_steps"): run["max_steps"].default,
        ("posterior", "target_ess"): StopRule().target_ess,
        ("render-dataset", "sweep"): Sweep().n,
        ("render-dataset", "sweep_distance_m"): Sweep().distance_m,
        ("render-dataset", "sweep_elevation_deg"): Sweep().elevation_deg,
        ("render-dataset", "width"): Camera().width_px,
        ("render-dataset", "height"): Camera().height_px,
        ("render-dataset", "fov_deg"): Camera().fov_deg,
        ("render-dataset", "exposure_mode"): Camera().exposure_mode,
        ("render-dataset", "exposure_ev"): Camera().exposure_ev,
        ("render-dataset", "meter_percentile"): Camera().meter_percentile,
        ("render-dataset", "spp"): RenderSettings().spp,
        ("render-dataset", "max_depth"): RenderSettings().max_depth,
        ("render-dataset", "colour"): RenderSettings().colour,
        ("render-dataset", "seed"): RenderSettings().seed,
        ("render-dataset", "gallery"): field_default(DatasetSpec, "gallery_images"),
        ("render-dataset", "export"): field_default(DatasetSpec, "export"),
        ("render-dataset", "depth"): field_default(DatasetSpec, "depth"),
    }
    for (command, name), want in pairs.items():
        assert default(command, name) == want, (command, name, default(command, name), want)
    assert pd.Timedelta(default("weather", "max_gap", "show")) == DEFAULT_MAX_GAP


def test_n_design_help_states_the_design_size():
    """calibrate and posterior share one emulator design; their --n-design help states the size the
    emulator takes (lightfit.defaults.DESIGN_SIZE: the help once held a literal 20 beside it)."""
    from lightfit.model.emulator import DESIGN_SIZE

    group = typer.main.get_command(app)
    for name in ("calibrate", "posterior"):
        (param,) = [p for p in group.commands[name].params if p.name == "n_design"]
        assert param.default is None  # resolved to DESIGN_SIZE in the command
        assert f"(default {DESIGN_SIZE}, the size lightfit " in param.help, (name, param.help)


def test_calibrates_first_try_names_a_bundled_synthetic_file():
    """calibrate needs an observations file and its help names one to try: it must exist, be the
    bundled twin, and be called synthetic there (data honesty: nothing synthetic called measured)."""
    import re

    from lightfit.inference.observations import read_observations

    help_text = typer.main.get_command(app).commands["calibrate"].help
    (named,) = re.findall(r"data/observations/\S+\.csv", help_text)
    path = DATA_DIR.parent / named
    assert path.is_file(), named
    assert "SYNTHETIC" in help_text and read_observations(path).attrs["provenance"] == "synthetic"


def test_info_names_variant_llvm_and_precision():
    r = runner.invoke(app, ["info"])
    assert r.exit_code == 0, r.output
    assert "mitsuba variant" in r.stdout and "_ad_mono" in r.stdout
    assert "libLLVM" in r.stdout
    assert "float64" in r.stdout
    if "llvm_ad_" in r.stdout:  # the CPU Dr.Jit compiles for, as drjit-core reports it
        cpu, _, lanes = backend.llvm_target()
        assert f"{cpu}, {lanes} lanes (" in r.stdout


def test_info_says_the_drjit_threads_in_use_and_how_to_set_them():
    """`lightfit info` said nothing of how many CPU threads render (Dr.Jit's pool: one per core by
    default, set by drjit.set_thread_count alone, no environment variable), a first question on a
    shared machine (a review). It prints the count in use, here one set by hand, and the ways to set it."""
    import drjit as dr

    r0 = runner.invoke(app, ["info"])  # loads the backend (variant, libLLVM) first
    assert r0.exit_code == 0, r0.output
    if "llvm_ad_" not in r0.stdout:
        pytest.skip("a CUDA variant: no CPU thread pool renders")
    before = dr.thread_count()
    try:
        dr.set_thread_count(3)
        r = runner.invoke(app, ["info"])
    finally:
        dr.set_thread_count(before)
    assert r.exit_code == 0, r.output
    row = next(line for line in r.stdout.splitlines() if "Dr.Jit CPU threads" in line)
    assert "│ 3 (" in row, row
    text = re.sub(r"[│\s]+", " ", r.stdout)  # the table wraps its cells
    for way in ("drjit.set_thread_count(n)", "--threads on render-dataset", "--threads-per-worker"):
        assert way in text, way


@pytest.mark.parametrize(
    ("args", "env", "source"), [(["--variant", "llvm_ad_mono"], None, "argument"), ([], "llvm_ad_mono", "env")]
)
def test_info_says_where_the_variant_came_from(tmp_path, args, env, source):
    """A variant from LIGHTFIT_VARIANT was reported as "(argument)": typer passes the variable to the
    --variant option. A fresh process each, as the backend keeps its first choice."""
    environ = {k: v for k, v in os.environ.items() if k != backend.ENV_VARIANT}
    environ |= {"COLUMNS": "200", "LIGHTFIT_CACHE": str(tmp_path)} | ({backend.ENV_VARIANT: env} if env else {})
    cmd = [sys.executable, "-m", "lightfit.cli", *args, "info"]
    r = subprocess.run(cmd, env=environ, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert f"llvm_ad_mono ({source})" in r.stdout, r.stdout


def test_info_bad_variant_exits_2():
    r = runner.invoke(app, ["--variant", "nonsense_variant", "info"])
    assert_user_error(r, "nonsense_variant")


def test_weather_show_file_with_plot_and_csv(tmp_path):
    png, csv = tmp_path / "w.png", tmp_path / "w.csv"
    r = runner.invoke(
        app, ["weather", "show", str(FIXTURE), "--resample", "30min", "--plot", str(png), "--csv", str(csv)]
    )
    assert r.exit_code == 0, r.output
    assert "clamped" in r.stdout  # night PAR offsets are reported, not hidden
    assert png.stat().st_size > 10_000
    back = read_weather(csv)
    assert (back.index[1:] - back.index[:-1] == pd.Timedelta("30min")).all()
    # The 30-min means of end-stamped 10-min means keep their meaning through the CSV.
    assert "as the ends of 30-min means" in " ".join(r.stdout.split())
    assert (back.attrs["timestamps"].label, back.attrs["timestamps"].interval) == ("end", pd.Timedelta("30min"))


def test_weather_show_time_label(tmp_path):
    """--time-label start: the sun 5 min after each stamp, recorded in the CSV; refused for a lightfit CSV."""
    csv = tmp_path / "w.csv"
    r = runner.invoke(app, ["weather", "show", str(FIXTURE), "--time-label", "start", "--csv", str(csv)])
    assert r.exit_code == 0, r.output
    back = read_weather(csv)
    assert back.attrs["timestamps"].label == "start"
    end = read_weather(FIXTURE)
    t = pd.Timestamp("2016-04-20 08:00", tz="UTC")
    assert add_solar(back).loc[t, "sun_elevation_deg"] == pytest.approx(
        add_solar(end).loc[t + pd.Timedelta("10min"), "sun_elevation_deg"], abs=1e-9
    )
    assert_user_error(runner.invoke(app, ["weather", "show", str(csv), "--time-label", "end"]), "w.csv", "time_label")
    assert_user_error(runner.invoke(app, ["weather", "show", str(FIXTURE), "--time-label", "middle"]), "time_label")


def test_weather_show_bad_input_exits_2_with_message(tmp_path):
    bad = tmp_path / "bad.csv"
    bad.write_text(FIXTURE.read_text(encoding="utf-8").replace("[mbar]", "[psi]"), encoding="utf-8")
    assert_user_error(runner.invoke(app, ["weather", "show", str(bad)]), "bad.csv", "psi")
    assert_user_error(runner.invoke(app, ["weather", "show", "selhausen-cplantbox-day"]), "date")
    assert_user_error(runner.invoke(app, ["weather", "show", str(tmp_path / "missing.csv")]), "missing.csv")
    # --how was checked only with --resample: a misspelled one, or one without --resample, passed unsaid
    assert_user_error(runner.invoke(app, ["weather", "show", str(FIXTURE), "--how", "foo"]), "--how", "'foo'", "sample")
    assert_user_error(runner.invoke(app, ["weather", "show", str(FIXTURE), "--how", "sample"]), "without --resample")
    # a folder as --csv or --plot failed after the table, naming a temporary file beside it
    for option in ("--csv", "--plot"):
        r = runner.invoke(app, ["weather", "show", str(FIXTURE), option, str(tmp_path)])
        assert_user_error(r, option.lstrip("-"), f"{tmp_path} is a folder")
        assert "time" not in r.stdout  # refused before the series' table


def test_replicate_interrupted_leaves_the_last_run_s_files_whole(tmp_path, monkeypatch):
    """A rerun into the same folder interrupted in its compared run (the second of two) had already
    replaced results.nc and the forcing files, beside the last run's comparison, figure and summary,
    with nothing to tell the halves apart (a review of interrupted runs). Every file is now written
    after everything is computed: interrupted there, the folder is the last run's, byte for byte."""
    from lightfit import replication as rep

    args = ["replicate", "--quick", "--steps", "12:14", "--compare-preset", "paper", "--out", str(tmp_path)]
    assert runner.invoke(app, args).exit_code == 0
    before = {f.name: f.read_bytes() for f in tmp_path.iterdir() if f.is_file()}
    assert {"results.nc", "results_compare.nc", "forcing.csv", "summary.csv"} <= set(before)
    main_run = rep.run

    def interrupted_in_the_compared_run(cfg, *a, **k):
        if k.get("out") is None:  # the compared run writes nothing itself
            raise KeyboardInterrupt
        return main_run(cfg, *a, **k)

    monkeypatch.setattr(rep, "run", interrupted_in_the_compared_run)
    r = runner.invoke(app, [*args[:3], "12:15", *args[4:]])  # another run: one step more
    assert r.exit_code == 130, r.output
    assert {f.name: f.read_bytes() for f in tmp_path.iterdir() if f.is_file()} == before


def test_replicate_with_steps_records_the_steps_it_ran(tmp_path):
    """With --steps, summary.csv's window line and results.nc's window attribute gave the whole
    window (05:00 + 14 h) of a run of two steps (a review): the steps run are said beside it. Steps
    12 and 13 of a window from 05:00 local in 30-min steps are 05:00 + 6 h and + 6.5 h."""
    import xarray as xr

    r = runner.invoke(app, ["replicate", "--quick", "--steps", "12:14", "--out", str(tmp_path)])
    assert r.exit_code == 0, r.output
    head = dict(
        line[2:].split(": ", 1) for line in (tmp_path / "summary.csv").read_text().splitlines() if line.startswith("# ")
    )
    ran = "2016-04-20 11:00 … 11:30, steps 12:14 of 2016-04-20 05:00 + 14 h"
    assert head["window"].startswith("2016-04-20 05:00 + 14 h") and head["steps_run"].startswith(ran), head
    with xr.open_dataset(tmp_path / "results.nc", engine="h5netcdf") as ds:
        assert ds.attrs["steps_run"].startswith(ran) and ds.sizes["time"] == 2
    # the whole window run: no steps_run, the window alone says what ran
    r = runner.invoke(app, ["replicate", "--quick", "--start-time", "11:00", "--hours", "0.5", "--out", str(tmp_path)])
    assert r.exit_code == 0, r.output
    assert "steps_run" not in (tmp_path / "summary.csv").read_text()
    with xr.open_dataset(tmp_path / "results.nc", engine="h5netcdf") as ds:
        assert "steps_run" not in ds.attrs and ds.attrs["window"].startswith("2016-04-20 11:00 + 0.5 h")


def test_replicate_writes_labelled_forcing(tmp_path):
    r = runner.invoke(app, ["replicate", "--quick", "--out", str(tmp_path)])
    assert r.exit_code == 0, r.output
    assert "RECONSTRUCTED" in r.stdout
    f = read_weather(tmp_path / "forcing.csv")
    assert len(f) == 29 and f.attrs["provenance"] == "reconstructed"
    assert (tmp_path / "forcing.png").stat().st_size > 10_000
    import xarray as xr

    with xr.open_dataset(tmp_path / "results.nc", engine="h5netcdf") as ds:
        ran = json.loads(ds.attrs["replication_config"])  # the configuration as it ran, not as given
    assert (ran["chlorophyll_ug_cm2"], ran["growth_temperature_c"], ran["vcmax_profile"]) == (50.5, 15.0, "lloyd2010")
    assert (ran["bounces"], ran["buffer_rows"], ran["season_start"]) == (2, 0, "2016-03-05")


@pytest.mark.parametrize(
    "args, bounces, k",
    [
        ([], 2, 32),
        (["--preset", "paper"], 8, 64),
        (["--preset", "paper", "--bounces", "3"], 3, 64),
        (["--direct", "paths"], 2, 64),
        (["--samples", "48"], 2, 48),
        (["--target-rse", "0.05"], 2, "target 0.05 (K from 32 to 8192 per segment)"),
        (["--target-rse", "0.05", "--samples", "64"], 2, "target 0.05 (K from 64 to 8192 per segment)"),
    ],
)
def test_replicate_names_the_bounces_and_samples_it_renders(tmp_path, monkeypatch, args, bounces, k):
    """The "running:" line gives the resolved number of bounces (not "None" when left at the default:
    2 for the PROSPECT-D leaf, 8 for the paper's grey leaf of albedo 0.5; ReplicationConfig.render_bounces)
    and samples (32 with the projected direct light, 64 with the paths, unless given)."""
    from lightfit import replication
    from lightfit.errors import InputError

    def stop(cfg, **kwargs):
        assert cfg.render_bounces() == bounces and (isinstance(k, str) or cfg.render_samples() == k)
        raise InputError("stopped before rendering", column="test", expected="nothing")

    monkeypatch.setattr(replication, "run", stop)
    r = runner.invoke(app, ["replicate", "--out", str(tmp_path), *args])
    assert r.exit_code == 2, r.output
    out = " ".join(r.stdout.split())  # rich wraps at the terminal width
    said = k if isinstance(k, str) else f"K={k}"  # adaptive: the target and the range of K, not the pilot's
    assert f"{said}, {bounces} bounces" in out and "None bounces" not in out


def test_field_soil_and_sky_options_reach_the_run(tmp_path):
    """--row-spacing, --plant-spacing, --row-direction, --parameter-file, --soil-albedo and --sky (a field
    scientist's own field; before, only the library could set them) reach the results' attributes, and
    the soil albedo acts as physics says: under common random numbers the canopy absorbs more with a
    brighter soil, and no more than the soil can send back up, ρ/(1 − ρ) × (PAR above − APAR at ρ = 0)
    (the light reaching the soil is at most what the canopy did not absorb; the 1/(1 − ρ) bounds the
    soil–canopy round trips)."""
    import xarray as xr

    from lightfit.light.scene import SOIL_ALBEDO

    layout = ["--row-spacing", "0.15", "--plant-spacing", "0.025", "--row-direction", "0", "--sky", "overcast"]
    layout += ["--parameter-file", "Triticum_aestivum_adapted_2021.xml"]
    apar, above = {}, None
    for rho in (0.0, 0.3):
        out = tmp_path / f"rho{rho}"
        args = ["replicate", "--quick", "--steps", "14:16", "--soil-albedo", str(rho), *layout, "--out", str(out)]
        r = runner.invoke(app, args)
        assert r.exit_code == 0, r.output
        with xr.open_dataset(out / "results.nc") as ds:
            a = ds.attrs
            assert (a["row_spacing_m"], a["plant_spacing_m"], a["row_direction_deg"]) == (0.15, 0.025, 0.0)
            assert (a["soil_albedo"], a["sky"], a["parameter_file"]) == (rho, "overcast", layout[-1])
            assert a["ground_area_m2"] == pytest.approx(4 * 0.15 * 0.025)
            apar[rho] = ds["canopy_apar_umol_m2_s"].values
            above = ds["above_canopy_par_umol_m2_s"].values
    gain = apar[0.3] - apar[0.0]
    assert (gain > 0).all(), gain
    assert (gain <= 0.3 / 0.7 * (above - apar[0.0])).all(), (gain, above - apar[0.0])
    assert SOIL_ALBEDO not in (0.0, 0.3)  # both runs differ from the default


@pytest.mark.parametrize(
    "args, words",
    [
        (["--row-spacing", "-1"], ["--row-spacing", "positive distance"]),
        (["--plant-spacing", "0"], ["--plant-spacing", "positive distance"]),
        (["--row-direction", "nan"], ["--row-direction", "azimuth"]),
        (["--row-direction", "400"], ["--row-direction", "0 ≤ azimuth < 360"]),  # was kept as 400
        (["--row-direction", "-90"], ["--row-direction", "0 ≤ azimuth < 360"]),
        (["--parameter-file", "nope.xml"], ["--parameter-file", "not found"]),
        (["--soil-albedo", "1.5"], ["--soil-albedo", "[0, 1]"]),
        (["--sky", "cloudy"], ["--sky", "isotropic or overcast"]),
    ],
)
def test_field_soil_and_sky_options_are_checked_before_plants_grow(tmp_path, args, words):
    """Refused before anything is grown or written (the forcing is the first file a run writes)."""
    out = tmp_path / "out"
    assert_user_error(runner.invoke(app, ["replicate", "--quick", *args, "--out", str(out)]), *words)
    assert not out.exists()


def test_a_soil_too_bright_for_the_bounce_rule_is_refused_before_the_run_unless_bounces_are_given(tmp_path):
    """The bounces are chosen from leaf and soil when not given; for an albedo no number of them brings
    under 1 % the run is refused before anything is written (it was, after the forcing); given bounces
    (or --quick's) run, with a caution saying what they leave out."""
    out = tmp_path / "out"
    r = runner.invoke(app, ["replicate", "--soil-albedo", "0.99", "--out", str(out)])
    assert_user_error(r, "--soil-albedo", "an albedo of 0.99", "soil albedo 0.99", "--bounces given")
    assert not out.exists()
    r = runner.invoke(app, ["replicate", "--quick", "--soil-albedo", "0.99", "--steps", "14:15", "--out", str(out)])
    assert r.exit_code == 0, r.output
    assert "no number of bounces the rule hands out keeps it under 1 %" in _flat(r.stderr)


def test_a_relative_parameter_file_is_recorded_absolute(tmp_path, monkeypatch):
    """A parameter file given by a relative path is recorded as its absolute path (results, resumed
    settings): read back from another folder, the relative one named no file (a review); a bundled
    name stays a name."""
    from lightfit.cli.options import ModelOptions, resolve
    from lightfit.plant.growth import resolve_parameter_file
    from lightfit.replication import ReplicationConfig

    own = tmp_path / "mine" / "wheat.xml"
    own.parent.mkdir()
    own.write_bytes(resolve_parameter_file("Triticum_aestivum_adapted_2021.xml").read_bytes())
    monkeypatch.chdir(own.parent)
    s = resolve(ModelOptions(quick=True, parameter_file="wheat.xml"))
    assert s.parameter_file == str(own) and s.replication_config().parameter_file == str(own)
    assert ReplicationConfig(parameter_file="wheat.xml").parameter_file == str(own)
    bundled = "Triticum_aestivum_adapted_2021.xml"
    assert resolve(ModelOptions(quick=True, parameter_file=bundled)).parameter_file == bundled
    # An edited copy under a bundled name in the working folder is not picked up by the bare name (the
    # default run names its file bare: it ran the local copy labelled as the default preset; a review);
    # ./NAME reads it.
    (own.parent / bundled).write_text(own.read_text().replace("<plant", "<plant edited='yes'", 1))
    assert ReplicationConfig(parameter_file=bundled).parameter_file == bundled
    assert resolve_parameter_file(bundled).resolve() != (own.parent / bundled).resolve()
    assert resolve_parameter_file(f"./{bundled}").resolve() == (own.parent / bundled).resolve()
    assert ReplicationConfig(parameter_file=f"./{bundled}").parameter_file == str(own.parent / bundled)


def test_a_run_with_its_own_soil_sky_or_plants_is_neither_preset_and_a_preset_resets_them():
    """A preset names a run only where its plants, soil and sky are the preset's too (the figure and
    results said 'default' for an overcast run on a bright soil); a preset applied (--compare-preset)
    resets them, so the comparison is the preset, not a hybrid; explicit options still win over it."""
    from lightfit.cli.options import ModelOptions, resolve
    from lightfit.light.scene import SOIL_ALBEDO
    from lightfit.replication import ReplicationConfig

    assert ReplicationConfig().preset == "default" and ReplicationConfig.paper().preset == "paper"
    for own in ({"soil_albedo": 0.3}, {"sky": "overcast"}, {"parameter_file": "Triticum_aestivum_adapted_2021.xml"}):
        cfg = ReplicationConfig(**own)
        assert cfg.preset is None, own
        for name in ("default", "paper"):
            assert cfg.with_preset(name).preset == name, (own, name)
    assert ReplicationConfig(soil_albedo=0.3).with_preset("paper").soil_albedo == SOIL_ALBEDO
    s = resolve(ModelOptions(quick=True, preset="paper", soil_albedo=0.3))
    assert s.soil_albedo == 0.3 and s.replication_config().preset is None


def test_runs_stored_before_the_field_soil_and_sky_options_compare_as_their_defaults():
    """Calibrations and posteriors stored before these options existed ran with the library's values:
    they resume; another value is named."""
    from lightfit.cli.options import ModelOptions, changed_settings, resolve

    default = resolve(ModelOptions(quick=True))
    new = ("row_spacing_m", "plant_spacing_m", "row_direction_deg", "parameter_file", "soil_albedo", "sky")
    stored_before = {k: v for k, v in default.as_dict().items() if k not in new}
    assert changed_settings(stored_before, default) == []
    brighter = resolve(ModelOptions(quick=True, soil_albedo=0.2))
    assert changed_settings(stored_before, brighter) == ["soil_albedo: 0.12 → 0.2"]


def test_direct_rays_option_reaches_the_scenario_and_is_a_render_setting(tmp_path, monkeypatch):
    """--direct-rays-per-m2 SUN,SKY (or one number for both) sets the projection's rays of the run's
    scenario and is named on the "running:" line; with the paths' direct light it is refused; a run
    stored before the option existed compares as the default."""
    from lightfit import replication
    from lightfit.cli.options import ModelOptions, changed_settings, resolve
    from lightfit.defaults import DEFAULT_RAYS_PER_M2
    from lightfit.errors import InputError

    seen = []

    def stop(cfg, **kwargs):
        seen.append(replication.scenario_for(cfg, replication.forcing_of(cfg)).direct_rays_per_m2)
        raise InputError("stopped before rendering", column="test", expected="nothing")

    monkeypatch.setattr(replication, "run", stop)
    for given, rays in (("1e7,6e7", (1e7, 6e7)), ("2e7", (2e7, 2e7))):
        r = runner.invoke(app, ["replicate", "--quick", "--out", str(tmp_path), "--direct-rays-per-m2", given])
        assert r.exit_code == 2 and seen[-1] == rays, r.output
        assert "{:.3g} / {:.3g} sun / sky rays per m²".format(*rays) in " ".join(r.stdout.split())
    r = runner.invoke(
        app, ["replicate", "--quick", "--out", str(tmp_path), "--direct", "paths", "--direct-rays-per-m2", "1e7"]
    )
    assert_user_error(r, "--direct-rays-per-m2", "paths")
    r = runner.invoke(app, ["replicate", "--quick", "--out", str(tmp_path), "--direct-rays-per-m2", "1e7,1e12"])
    assert_user_error(r, "--direct-rays-per-m2", "1e+10")
    default, more = resolve(ModelOptions(quick=True)), resolve(ModelOptions(quick=True, direct_rays_per_m2="1e7"))
    assert default.direct_rays_per_m2 == DEFAULT_RAYS_PER_M2
    stored_before = {k: v for k, v in default.as_dict().items() if k != "direct_rays_per_m2"}
    assert changed_settings(stored_before, default) == []
    assert changed_settings(default.as_dict(), more) == [
        "direct_rays_per_m2: [2500000.0, 10000000.0] → [10000000.0, 10000000.0]"
    ]


def test_replicate_with_a_tereno_export_and_a_few_steps(tmp_path):
    r = runner.invoke(
        app, ["replicate", "--quick", "--out", str(tmp_path), "--weather", str(FIXTURE), "--steps", "14:16"]
    )
    assert r.exit_code == 0, r.output
    f = read_weather(tmp_path / "forcing.csv")
    # The fixture is a synthetic file in the export layout and says so in its header.
    assert len(f) == 2 and f.attrs["provenance"] == "synthetic"


def test_weather_provenance_option_labels_a_file_that_does_not_say(tmp_path):
    """--weather-provenance declares what an export without a provenance header is; a file that
    says, or a bundled file, cannot be relabelled; an unknown word fails before any plant grows."""
    from lightfit.cli.options import ModelOptions, resolve
    from lightfit.cli.options import weather as run_weather

    lines = FIXTURE.read_text(encoding="utf-8").splitlines(keepends=True)
    plain = tmp_path / "export.csv"  # the fixture without its "SYNTHETIC FIXTURE" line: a file that says nothing
    plain.write_text("".join(line for line in lines if "SYNTHETIC" not in line), encoding="utf-8")

    def provenance(path, word):
        opts = ModelOptions(quick=True, weather_file=str(path), weather_provenance=word, steps="14:16")
        return run_weather(resolve(opts)).attrs["provenance"]

    assert provenance(plain, None) == "unstated"
    assert provenance(plain, "measured") == "measured"
    assert provenance(FIXTURE, "synthetic") == "synthetic"
    with pytest.raises(InputError, match="contradicts"):
        provenance(FIXTURE, "measured")
    with pytest.raises(InputError, match="contradicts"):
        run_weather(resolve(ModelOptions(quick=True, weather_provenance="measured")))  # the bundled reconstruction
    r = runner.invoke(app, ["replicate", "--quick", "--out", str(tmp_path / "r"), "--weather-provenance", "real"])
    assert_user_error(r, "--weather-provenance real", "measured / reconstructed / synthetic")
    assert not (tmp_path / "r").exists()


def test_weather_tz_and_time_label_options_read_a_file_as_weather_show_does(tmp_path):
    """--weather-tz / --weather-time-label on the model commands (only `weather show` had --tz and
    --time-label, so an export on another clock, or stamped at its intervals' starts, had to be
    converted first). The fixture rewritten on a UTC+2 clock without its zone line: read by the
    TERENO convention (UTC+1) its light comes an hour late for its sun and is refused; with
    --weather-tz UTC+2 the run's forcing is the original fixture's, as its own header reads it. Bad
    values, and either option with a lightfit CSV (the bundled default among them), fail before any
    plant grows."""
    from lightfit import weather as wx
    from lightfit.cli.options import ModelOptions, changed_settings, resolve
    from lightfit.cli.options import weather as run_weather
    from lightfit.weather import timestamps

    def later(line: str) -> str:  # a data row's stamp one hour on; header lines as they are
        stamp = line.split(",", 1)[0]
        if not stamp[:4].isdigit():
            return line
        return f"{pd.Timestamp(stamp) + pd.Timedelta('1h'):%Y-%m-%d %H:%M:%S}," + line.split(",", 1)[1]

    lines = FIXTURE.read_text(encoding="utf-8").splitlines(keepends=True)
    east = tmp_path / "export.csv"
    east.write_text("".join(later(x) for x in lines if not x.startswith("Time zone")), encoding="utf-8")

    def forcing(path=east, **kw):
        return run_weather(resolve(ModelOptions(quick=True, weather_file=str(path), steps="12:18", **kw)))

    with pytest.raises(InputError, match="more light than their sun can give.*--weather-tz and --weather-time-label"):
        forcing()
    read = forcing(weather_tz="UTC+2")
    own = forcing(FIXTURE)
    assert len(read) == 6 and read.index.equals(own.index)
    for col in ("par_umol_m2_s", "ghi_w_m2", "tair_c", "co2_ppm", "sun_elevation_deg"):
        assert np.array_equal(read[col].to_numpy(), own[col].to_numpy()), col

    start = forcing(FIXTURE, weather_time_label="start")
    assert timestamps.of(start).label == "start" and timestamps.of(own).label == "end"
    same = wx.add_solar(wx.read_source(FIXTURE, time_label="start"))  # as `weather show --time-label start`
    assert np.array_equal(start["sun_elevation_deg"], same["sun_elevation_deg"].loc[start.index])
    assert not np.array_equal(start["sun_elevation_deg"], own["sun_elevation_deg"])  # 10 min apart

    s = resolve(ModelOptions(quick=True, weather_file=str(east), weather_tz="UTC+2"))
    assert changed_settings(resolve(ModelOptions(quick=True, weather_file=str(east))).as_dict(), s) == [
        "weather_tz: None → 'UTC+2'"
    ]  # a resumed run that read the file another way: refused
    for args, words in (
        (["--weather", str(east), "--weather-tz", "Mars/Olympus"], ["--weather-tz: ", "Mars/Olympus", "UTC±H"]),
        (["--weather", str(east), "--weather-time-label", "middle"], ["--weather-time-label", "'start', 'center'"]),
        (["--weather-tz", "UTC+1"], ["--weather-tz given for a lightfit CSV (the default forcing, ", "2016-04-20"]),
    ):
        r = runner.invoke(app, ["replicate", "--quick", "--out", str(tmp_path / "r"), *args])
        assert_user_error(r, *words)
        assert not (tmp_path / "r").exists()


@pytest.mark.parametrize(
    "command, args, words",
    [
        ("replicate", ["--weather", "no-such-weather.csv"], ["no-such-weather.csv"]),
        ("replicate", ["--observations", "no-such-obs.csv"], ["no-such-obs.csv"]),
        ("replicate", ["--photosynthesis", "c3-magic"], ["photosynthesis", "c3-magic", "giraud2023"]),
        ("replicate", ["--theta", "specular=shiny"], ["theta", "specular=shiny"]),
        ("calibrate", ["no-such-obs.csv"], ["no-such-obs.csv"]),
        ("calibrate", ["ADIR"], ["a folder, not a file", "an observations CSV"]),  # was the OS's "Is a directory"
        ("replicate", ["--observations", "ADIR"], ["a folder, not a file"]),
        ("calibrate", ["OBS", "--steps", "40"], ["steps", "40"]),
        ("calibrate", ["OBS", "--how", "median"], ["how", "median"]),
        ("calibrate", ["OBS", "--method", "newton"], ["method", "newton", "lbfgsb"]),
        ("calibrate", ["OBS", "--use", "co2"], ["use", "co2"]),
        # A series the file lacks was refused by the likelihood, after --out/settings.json was written,
        # which then refused the corrected rerun as "run with other use" (a newcomer review).
        ("calibrate", ["OBS", "--use", "fapar"], ["use names fapar", "no value of", "above_canopy_par"]),
        ("calibrate", ["OBS", "--use", "fapar", "--no-surrogate"], ["use names fapar"]),
        # the surrogate's settings were dropped unsaid with --no-surrogate (a review of bad input)
        ("calibrate", ["OBS", "--no-surrogate", "--n-design", "10"], ["option --n-design", "with --no-surrogate"]),
        (
            "calibrate",
            ["OBS", "--no-surrogate", "--max-rounds", "3"],
            ["option --max-rounds", "only with the surrogate"],
        ),
        ("calibrate", ["OBS", "--no-surrogate", "--cache", "ADIR"], ["option --cache", "with --no-surrogate"]),
        ("calibrate", ["OBS", "--parameters", "shininess"], ["unknown parameter", "shininess"]),
        ("calibrate", ["OBS", "--parameters", "specular,specular"], ["['specular'] given more than once"]),
        # crashed after the design renders ("Need at least one array to stack"), leaving a settings.json
        # that refused every later run into the same --out (a review of bad input)
        ("calibrate", ["OBS", "--parameters", ""], ["--parameters", "no parameter to fit", "specular"]),
        ("calibrate", ["OBS", "--parameters", ","], ["--parameters", "no parameter to fit"]),
        ("calibrate", ["OBS", "--start", "specular=0.4,specular=0.6"], ["--start", "specular given more than once"]),
        ("calibrate", ["OBS", "--start", "glossiness=1"], ["start", "glossiness"]),
        ("replicate", ["--theta", "glossiness=1"], ["theta", "glossiness"]),
        ("posterior", ["--priors", "flat"], ["priors", "flat"]),
        ("posterior", ["--samples", "0"], ["samples"]),
        ("posterior", ["--no-analysis", "--n-test", "3"], ["option --n-test", "with --no-analysis"]),  # was dropped
        ("posterior", ["--parameters", "noise_scale"], ["no model parameter", "specular"]),  # crashed after sampling
        ("posterior", ["--sampler-seed", "-1"], ["--sampler-seed", "-1", "≥ 0"]),  # numpy: ValueError
        ("replicate", ["--samples", "50"], ["samples=50", "48 or 56"]),  # 8 replicates × 7 = 56 would run
        ("replicate", ["--out", "run/results.nc"], ["--out is the folder", "field-run"]),
        ("field-run", ["--steps", "0"], ["steps"]),
        ("field-run", ["--bounces", "-1"], ["bounces"]),
        ("replicate", ["--bounces", "10000"], ["bounces", "[0, 64]"]),  # memory ran out
        ("replicate", ["--buffer-rows", "2"], ["--buffer-rows", "--boundary periodic"]),
        ("calibrate", ["OBS", "--buffer-along", "8"], ["--buffer-along", "--boundary periodic"]),
        ("posterior", ["--boundary", "torus"], ["boundary", "torus", "periodic"]),
        ("field-run", ["--buffer-rows", "1", "--buffer-along", "4"], ["--buffer-rows and --buffer-along", "periodic"]),
        ("replicate", ["--boundary", "periodic", "--buffer-rows", "0"], ["--buffer-rows"]),
    ],
)
def test_model_commands_reject_bad_input_before_running(command, args, words, tmp_path):
    """Bad options of the shared group are caught before any plant is grown or anything written: exit
    2, message naming them, no --out."""
    args = [str(OBSERVATIONS) if a == "OBS" else str(tmp_path) if a == "ADIR" else a for a in args]
    r = runner.invoke(app, [command, "--quick", "--out", str(tmp_path / "out"), *args])
    assert_user_error(r, *words)
    assert not (tmp_path / "out").exists()
    assert "plants" not in r.stdout  # field-run's banner comes after the plants have grown


@pytest.mark.parametrize(
    "args, words",
    [
        (["--timeout", "0"], ["--timeout", "> 0 seconds"]),
        (["--connect-timeout", "nan"], ["--connect-timeout", "> 0 seconds"]),
        # passed, ran, then a traceback (OverflowError) when Dask closed the cluster (a review of bad input)
        (["--timeout", "1e15"], ["--timeout", "at most 10,000,000 (116 days)"]),
        (["--connect-timeout", "1e308"], ["--connect-timeout", "at most 10,000,000"]),
        (["--threads-per-worker", "0"], ["--threads-per-worker", "≥ 1"]),
        (["--scheduler", "foo"], ["--scheduler", "'foo'", "tcp://host:8786"]),
        (["--scheduler", "tcp://host:8786", "--workers", "2"], ["--workers", "joining an existing cluster"]),
    ],
)
def test_field_run_checks_the_cluster_options_before_the_plants_grow(tmp_path, args, words):
    """The cluster's options were checked when the cluster was started, after the plants had grown and
    the banner was printed (a review of bad input); now before anything is built or written."""
    r = runner.invoke(app, ["field-run", "--quick", "--out", str(tmp_path / "r.nc"), *args])
    assert_user_error(r, *words)
    assert "plants" not in r.stdout and not list(tmp_path.iterdir())


def test_field_run_refuses_a_results_name_that_is_not_netcdf(tmp_path, monkeypatch):
    """`field-run --out r.csv` wrote netCDF under a text file's name; now refused before any plant grows
    (the model options are resolved first, which may build the leaf's albedo table in the cache: a
    process that had not built it yet did, so the whole cache folder is no measure)."""
    monkeypatch.setenv("LIGHTFIT_CACHE", str(tmp_path / "cache"))
    r = runner.invoke(app, ["field-run", "--quick", "--out", str(tmp_path / "r.csv")])
    assert_user_error(r, str(tmp_path / "r.csv"), "netCDF", ".nc")
    assert not (tmp_path / "cache" / "plants").exists() and not (tmp_path / "r.csv").exists()


def test_a_cache_that_cannot_be_written_is_an_error_naming_lightfit_cache(tmp_path, monkeypatch):
    """A cache root below a file (or otherwise unwritable) stopped the run with the path and the OS's
    reason only; the message now says it is lightfit's cache and which variable moves it. A file
    error elsewhere gets no such hint."""
    import errno

    from lightfit.cli.common import error_message

    (tmp_path / "afile").write_text("")
    monkeypatch.setenv("LIGHTFIT_CACHE", str(tmp_path / "afile" / "cache"))
    r = runner.invoke(app, ["replicate", "--quick", "--out", str(tmp_path / "out")])
    assert_user_error(r, str(tmp_path / "afile" / "cache" / "plants"), "Not a directory", "set LIGHTFIT_CACHE to")
    elsewhere = OSError(errno.ENOTDIR, "Not a directory", str(tmp_path / "afile" / "x.csv"))
    assert error_message(elsewhere) == f"{tmp_path / 'afile' / 'x.csv'}: Not a directory"

    def no_home():  # Path.home() with HOME unset and no passwd entry (a review: a traceback in the handler)
        raise RuntimeError("Could not determine home directory.")

    monkeypatch.setattr("lightfit.cli.common.cache_root", no_home)
    assert error_message(elsewhere) == f"{tmp_path / 'afile' / 'x.csv'}: Not a directory"


def test_field_run_refuses_unwritable_results_names_before_any_work(tmp_path, monkeypatch):
    """A name without .nc, a folder named r.nc, a file where the folder should be, or an existing file
    that is not netCDF (it was overwritten) are refused naming --out before any plant grows (a folder was
    found only after every task had run)."""
    monkeypatch.setenv("LIGHTFIT_CACHE", str(tmp_path / "cache"))
    (tmp_path / "d.nc").mkdir()
    (tmp_path / "text.nc").write_text("hello\n")
    for out, words in (
        ("d.nc", ["is a folder"]),
        ("text.nc", ["exists and is not a netCDF file"]),
        ("text.nc/r.nc", ["text.nc is a file"]),
        ("r.csv", ["results are written as netCDF", "a file name ending in .nc"]),  # named --out too
    ):
        r = runner.invoke(app, ["field-run", "--quick", "--out", str(tmp_path / out)])
        assert_user_error(r, "option --out", *words)
    assert not (tmp_path / "cache" / "plants").exists() and (tmp_path / "text.nc").read_text() == "hello\n"
    from lightfit.replication import check_netcdf_name

    (tmp_path / "empty.nc").touch()  # an empty file (mktemp) is replaced freely
    assert check_netcdf_name(tmp_path / "empty.nc") == tmp_path / "empty.nc"


def test_an_interrupted_results_write_leaves_the_previous_file_whole(tmp_path, monkeypatch):
    """write_netcdf writes beside the file and renames: a write that fails half way (a kill) keeps
    the previous results readable and leaves no partial file behind (it truncated them)."""
    import xarray as xr

    from lightfit import replication as rep

    path = rep.write_netcdf(xr.Dataset({"a": ("x", np.arange(3.0))}), tmp_path / "r.nc")
    real = xr.Dataset.to_netcdf

    def dies_half_way(self, target, *a, **k):
        real(self, target, *a, **k)
        with open(target, "r+b") as f:
            f.truncate(100)
        raise KeyboardInterrupt

    monkeypatch.setattr(xr.Dataset, "to_netcdf", dies_half_way)
    with pytest.raises(KeyboardInterrupt):
        rep.write_netcdf(xr.Dataset({"a": ("x", np.arange(5.0))}), path)
    monkeypatch.undo()
    with xr.open_dataset(path, engine="h5netcdf") as back:
        np.testing.assert_array_equal(back["a"].values, np.arange(3.0))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r.nc"]


@pytest.mark.parametrize(
    "command, extra", [("replicate", []), ("posterior", []), ("posterior", ["--no-resume"]), ("field", [])]
)
def test_ctrl_c_exits_130_saying_what_was_kept(command, extra, tmp_path, monkeypatch):
    """A KeyboardInterrupt anywhere in a command: exit 130 (128 + SIGINT) and one line on stderr;
    a command that resumes says what it keeps (tests/test_resume.py sends a real SIGINT), one that
    does not (field, seconds long) that it starts again."""

    def interrupted(*a, **k):
        raise KeyboardInterrupt

    import importlib

    if command == "field":
        monkeypatch.setattr(importlib.import_module("lightfit.plant"), "build", interrupted)
        r = runner.invoke(app, [command, "--n-plants", "4", "--export", str(tmp_path / "f.obj")])
    else:  # the module, not the command function of the same name that lightfit.cli exports
        monkeypatch.setattr(importlib.import_module(f"lightfit.cli.{command}"), "resolve", interrupted)
        r = runner.invoke(app, [command, "--quick", "--out", str(tmp_path), *extra])
    assert r.exit_code == 130, r.output
    line = " ".join(r.stderr.split())
    assert line.startswith("interrupted: ") and "Traceback" not in r.output and "Aborted" not in r.output
    if extra:  # the same command would start over again: say how to resume instead
        assert "design cache" in line and line.endswith("rerun without --no-resume to resume")
    elif command == "posterior":
        assert "design cache" in line and line.endswith("rerun the same command to resume")
    elif command == "replicate":
        assert line == (
            "interrupted: every rendered step is kept in --out (its .kept-steps folder); "
            "rerun the same command to resume"
        )
    else:
        assert line == "interrupted: rerun the command to start it again"


def test_bad_par_kind_names_the_parameter(tmp_path):
    r = runner.invoke(app, ["replicate", "--quick", "--out", str(tmp_path), "--par-kind", "diffuse"])
    assert_user_error(r, "par_kind", "diffuse")


@pytest.mark.parametrize(
    "args, token",
    [
        (["--soil-respiration", "-1"], "--soil-respiration"),
        (["--soil-respiration", "1e308"], "--soil-respiration"),  # NEE was inf
        (["--soil-respiration", "101"], "--soil-respiration"),
        (["--soil-respiration-q10", "9"], "q10"),
    ],
)
def test_bad_soil_respiration_names_the_option(tmp_path, args, token):
    r = runner.invoke(app, ["replicate", "--quick", "--out", str(tmp_path), *args])
    assert_user_error(r, token, repr(float(args[1])).replace("inf", args[1]))


def test_soil_respiration_options_reach_the_run_configuration():
    from lightfit.cli.options import ModelOptions, resolve

    cfg = resolve(ModelOptions(quick=True, soil_respiration=1.5, soil_respiration_q10=1.8)).replication_config()
    assert (cfg.soil_respiration_umol_m2_s, cfg.soil_respiration_q10) == (1.5, 1.8)
    default = resolve(ModelOptions(quick=True)).replication_config()
    assert (default.soil_respiration_umol_m2_s, default.soil_respiration_q10) == (0.0, 2.0)


def test_soil_respiration_help_says_how_to_bring_a_reading_to_10_c():
    """--soil-respiration is R₁₀, at 10 °C; its help sends the user to bare-soil or night readings,
    made at other temperatures, and said nothing of scaling them, so a reading given as it was came
    back at its own temperature as Q₁₀^((T − 10)/10) times itself (0.71× at 5 °C, Q₁₀ = 2). The help
    now states R / Q10^((T − 10)/10); by that rule a 1.0 µmol m⁻² s⁻¹ reading at 5 °C is
    1/2^(−0.5) = 1.4142 at 10 °C, and the model returns the reading at 5 °C."""
    from lightfit.model.observe import soil_respiration

    (param,) = [p for p in typer.main.get_command(app).commands["replicate"].params if p.name == "soil_respiration"]
    assert "R / Q10^((T − 10)/10)" in param.help, param.help
    r10 = 1.0 / 2.0 ** ((5.0 - 10.0) / 10.0)
    assert r10 == pytest.approx(1.41421356)
    assert float(soil_respiration(r10, 2.0, 5.0)) == pytest.approx(1.0, rel=1e-12)


@pytest.mark.parametrize(
    "args, words",
    [
        (["--vcmax-profile", "steep"], ["vcmax_profile", "steep", "lloyd2010"]),
        (["--vcmax-profile", "-0.2"], ["vcmax_profile", "-0.2"]),
        (["--photosynthesis", "giraud2023", "--vcmax-profile", "lloyd2010"], ["vcmax_profile", "Vcmax", "uniform"]),
        (["--growth-temperature-c", "40"], ["growth_temperature_c", "40", "[0, 35]"]),
        (["--photosynthesis", "giraud2023", "--growth-temperature-c", "9"], ["growth_temperature_c", "giraud2023"]),
    ],
)
def test_bad_photosynthesis_options_name_the_option(tmp_path, args, words):
    r = runner.invoke(app, ["replicate", "--quick", "--out", str(tmp_path / "r"), *args])
    assert_user_error(r, *words)
    assert not (tmp_path / "r").exists()  # refused before anything grows


def test_vcmax_profile_reaches_the_run_resolved():
    """The settings record the profile the run used ("auto" resolved by the set), and a run stored
    before profiles (no key: every blade alike) differs from today's default on resume."""
    from lightfit.cli.options import ModelOptions, changed_settings, resolve

    s = resolve(ModelOptions(quick=True))
    assert s.vcmax_profile == "lloyd2010" and s.replication_config().vcmax_profile == "lloyd2010"
    assert resolve(ModelOptions(quick=True, preset="paper")).vcmax_profile == "uniform"
    assert resolve(ModelOptions(quick=True, vcmax_profile="0.3")).vcmax_profile == 0.3
    old = {k: v for k, v in s.as_dict().items() if k != "vcmax_profile"}
    assert changed_settings(old, s) == ["vcmax_profile: 'uniform' → 'lloyd2010'"]
    assert changed_settings(old, resolve(ModelOptions(quick=True, vcmax_profile="uniform"))) == []
    cfg = resolve(ModelOptions(quick=True, growth_temperature_c=9.0)).replication_config()
    assert cfg.growth_temperature_c == 9.0 and s.growth_temperature_c is None  # None: the set's own 15 °C
    # A run stored before the option had the set's own: no change to report.
    before = {k: v for k, v in s.as_dict().items() if k != "growth_temperature_c"}
    assert changed_settings(before, s) == []


def test_photosynthesis_override_options_reach_the_configuration():
    """--photosynthesis-override NAME=VALUE (repeatable) is stored sorted by name as a mapping in the
    run's settings and as pairs in its configuration, which then matches no preset; text that is not
    NAME=number is refused naming the option; settings stored before the option had none."""
    from lightfit.cli.options import ModelOptions, changed_settings, resolve

    s = resolve(ModelOptions(quick=True, photosynthesis_override=["vcmax_ref_umol_m2_s=85", " a1 = 4.5"]))
    assert s.as_dict()["photosynthesis_overrides"] == {"a1": 4.5, "vcmax_ref_umol_m2_s": 85.0}
    cfg = s.replication_config()
    assert cfg.photosynthesis_overrides == (("a1", 4.5), ("vcmax_ref_umol_m2_s", 85.0)) and cfg.preset is None
    plain = resolve(ModelOptions(quick=True))
    assert plain.photosynthesis_overrides == {} and plain.replication_config().preset == "default"
    old = {k: v for k, v in plain.as_dict().items() if k != "photosynthesis_overrides"}
    assert changed_settings(old, plain) == []
    assert changed_settings(old, s) == ["photosynthesis_overrides: {} → {'a1': 4.5, 'vcmax_ref_umol_m2_s': 85.0}"]
    for text, match in [("a1", "'a1'.*NAME=VALUE"), ("a1=x", "'a1=x'.*NAME=VALUE"), ("g1=4", "unknown parameter 'g1'")]:
        with pytest.raises(InputError, match=match) as e:
            resolve(ModelOptions(quick=True, photosynthesis_override=[text]))
        assert e.value.parameter == "photosynthesis_override"
    # A value outside its domain is refused by the set's own check (parameter photosynthesis_overrides):
    # the message names the option given, not "parameter 'photosynthesis_overrides'".
    for command in ("replicate", "calibrate", "posterior"):
        args = [
            command,
            *([str(DATA_DIR / "observations" / "twin_2016-04-20_synthetic.csv")] if command == "calibrate" else []),
        ]
        r = runner.invoke(app, [*args, "--quick", "--photosynthesis-override", "curvature=2"])
        assert r.exit_code == 2 and "curvature=2.0" in r.output and "in (0, 1]" in r.output, r.output
        assert "error: option --photosynthesis-override: curvature=2.0" in r.stderr, (command, r.stderr)


def test_field_command_reports_exports_and_previews(tmp_path, monkeypatch):
    monkeypatch.setenv("LIGHTFIT_CACHE", str(tmp_path / "cache"))
    ply, png = tmp_path / "f.ply", tmp_path / "f.png"
    r = runner.invoke(
        app,
        [
            "field",
            "--n-plants",
            "4",
            "--boundary",
            "finite",
            "--buffer-rows",
            "1",
            "--tiles",
            "2",
            "--export",
            str(ply),
            "--preview",
            str(png),
            "--segments",
            str(tmp_path / "seg.csv"),
        ],
    )
    assert r.exit_code == 0, r.output
    assert "triangles" in r.stdout and "16 (4 / 12)" in r.stdout
    assert ply.stat().st_size > 0 and png.stat().st_size > 10_000
    seg = pd.read_csv(tmp_path / "seg.csv", comment="#")
    assert seg["measured"].sum() > 0 and set(seg["organ_type"]) == {"leaf", "stem"}
    head = [ln for ln in (tmp_path / "seg.csv").read_text().splitlines() if ln.startswith("#")]
    assert "# provenance: synthetic" in head[0] and "# seed: 1" in head and "# n_plants: 4" in head
    assert any(ln.startswith("# columns: x0 y0 z0 x1 y1 z1 in m") for ln in head)
    # The plant height reported is the mean of each measured plant's top (not the field's single tallest tip).
    tops = seg[seg["measured"]][["z0", "z1"]].max(axis=1).groupby(seg["plant_id"]).max()
    line = next(ln for ln in r.stdout.splitlines() if "plant height" in ln)
    assert f"{tops.mean():.3f}" in line and tops.mean() < tops.max()
    assert_user_error(runner.invoke(app, ["field", "--row-spacing", "-1"]), "row_spacing_m")
    assert_user_error(
        runner.invoke(app, ["field", "--n-plants", "4", "--season-start", "2016-05-01"]), "not after season_start"
    )
    assert_user_error(runner.invoke(app, ["field", "--n-plants", "4", "--tiles", "2", "--tile", "5"]), "tile")
    # Default periodic: the measurement area alone is the field (no buffer plants); buffers refused.
    # --quick is the model commands' quick field (it was refused as an unknown option).
    for size in (["--n-plants", "4"], ["--quick"]):
        r = runner.invoke(app, ["field", *size])
        assert r.exit_code == 0, r.output
        assert "4 (4 / 0)" in r.stdout and "periodic boundary" in _flat(r.stdout)
    assert_user_error(runner.invoke(app, ["field", "--n-plants", "4", "--buffer-rows", "2"]), "--buffer-rows")
    # whole rows: 4 plants in one row of 4, said in the title and written in the segments' header
    r = runner.invoke(app, ["field", "--n-plants", "4", "--plants-per-row", "4", "--segments", str(tmp_path / "r.csv")])
    assert r.exit_code == 0, r.output
    assert "4 (4 / 0)" in r.stdout and "field 1 row × 4 plants measured" in _flat(r.stdout)
    assert "# plants_per_row: 4" in (tmp_path / "r.csv").read_text().splitlines()
    assert_user_error(runner.invoke(app, ["field", "--n-plants", "4", "--plants-per-row", "0"]), "plants_per_row")


def test_field_summary_is_the_measured_plants_as_the_lai_is(tmp_path, monkeypatch):
    """A finite field's buffer plants are geometry only: the heights and the blade inclination are the
    measured plants', as the LAI is (they averaged every plant built, the 12 buffer plants of a 2×2 area
    with one buffer row included, beside a measured-only LAI). Checked against the segment table and
    trimesh's face normals and areas of the measured plants' blade faces."""
    from lightfit import plant

    monkeypatch.setenv("LIGHTFIT_CACHE", str(tmp_path / "cache"))
    args = ["field", "--n-plants", "4", "--boundary", "finite", "--buffer-rows", "1"]
    r = runner.invoke(app, [*args, "--segments", str(tmp_path / "seg.csv")])
    assert r.exit_code == 0, r.output
    out = _flat(r.stdout)
    assert "the measured plants only" in out, out
    seg = pd.read_csv(tmp_path / "seg.csv", comment="#")
    meas = seg[seg["measured"]]
    tops = meas[["z0", "z1"]].max(axis=1).groupby(meas["plant_id"]).max()
    everyone = seg[["z0", "z1"]].max(axis=1).groupby(seg["plant_id"]).max()
    assert f"{tops.mean():.3f}" != f"{everyone.mean():.3f}"  # the buffer plants would move it
    line = next(ln for ln in r.stdout.splitlines() if "plant height" in ln)
    assert f"{tops.mean():.3f}" in line, line
    # the blades' area-weighted tilt from trimesh's normals, measured plants' faces only
    geom = plant.build(plant.Field(4, boundary="finite", buffer_rows=1, seed=1))  # the CLI's --field-seed 1
    tm = geom.mesh.to_trimesh()
    keep = geom.mesh.face_is_blade & np.isin(tm.face_attributes["segment_id"], meas["segment_id"])
    tilt = np.degrees(np.arccos(np.abs(tm.face_normals[keep, 2])))
    want = np.average(tilt, weights=tm.area_faces[keep])
    every = geom.mesh.face_is_blade
    assert (
        f"{want:.1f}"
        != f"{np.average(np.degrees(np.arccos(np.abs(tm.face_normals[every, 2]))), weights=tm.area_faces[every]):.1f}"
    )
    line = next(ln for ln in r.stdout.splitlines() if "blade inclination" in ln)
    assert f"{want:.1f}" in line, line
    top = max(tm.vertices[tm.faces[np.isin(tm.face_attributes["segment_id"], meas["segment_id"])]][..., 2].ravel())
    line = next(ln for ln in r.stdout.splitlines() if "highest point" in ln)
    assert f"{top:.3f}" in line, line


def test_plants_per_row_reaches_the_field_and_is_a_render_setting():
    """--plants-per-row makes the run's field whole rows; a run stored before the option (no key: a
    square) compares as a square, and rows of the square's own side are the same measurement area."""
    from lightfit.cli.options import RENDER_SETTINGS, ModelOptions, changed_settings, resolve

    s = resolve(ModelOptions(quick=True, n_plants=6, plants_per_row=3))
    fld = s.replication_config().field()
    assert (fld.n_rows, fld.n_along, fld.n_measured) == (2, 3, 6) and "plants_per_row" in RENDER_SETTINGS
    square = resolve(ModelOptions(quick=True))
    stored_before = {k: v for k, v in square.as_dict().items() if k != "plants_per_row"}
    assert changed_settings(stored_before, square) == []
    assert changed_settings(stored_before, resolve(ModelOptions(quick=True, plants_per_row=2))) == []  # 2 × 2 again
    assert changed_settings(stored_before, resolve(ModelOptions(quick=True, plants_per_row=4))) == [
        "plants_per_row: 2 → 4"
    ]
    # the area is compared as built, its two settings together (a review: each passed as given alone)
    nine_rows = resolve(ModelOptions(n_plants=90, plants_per_row=10))
    assert changed_settings(nine_rows.effective(), resolve(ModelOptions(n_plants=90))) == ["n_plants: 90 → 100"]
    assert changed_settings(nine_rows.as_dict(), resolve(ModelOptions(n_plants=90))) == ["n_plants: 90 → 100"]
    five = resolve(ModelOptions(quick=True, n_plants=5)).as_dict()
    old_five = {k: v for k, v in five.items() if k != "plants_per_row"}
    assert changed_settings(old_five, resolve(ModelOptions(quick=True, n_plants=5, plants_per_row=3))) == [
        "n_plants: 9 → 6"
    ]


def test_calibrate_refuses_to_resume_a_history_of_other_settings(tmp_path):
    """A history from the finite default (results written before the periodic boundary carry no
    'boundary') is not resumed into a periodic run; --boundary finite passes that check."""
    out = tmp_path / "cal"
    out.mkdir()
    (out / "history.jsonl").write_text('{"step": 1, "loss": 3.0, "theta": {"light_factor": 1.2}}\n')
    old = {"quick": True, "n_plants": 4, "buffer_rows": 2, "buffer_along": None, "field_seed": 1, "samples": 16}
    old |= {"bounces": 2, "render_seed": 0, "par_kind": "absorbed", "photosynthesis": "giraud2023"}
    old |= {"an_per": "ground", "weather_file": None, "how": "sample", "steps": None}
    (out / "calibration.json").write_text(json.dumps({"config": old}))
    args = ["calibrate", str(OBSERVATIONS), "--quick", "--photosynthesis", "giraud2023", "--out", str(out)]
    args += ["--parameters", "light_factor"]  # what the chamber record informs
    r = runner.invoke(app, args)
    # the periodic field's buffers as it has them (0), not the option left unset (None)
    assert_user_error(r, "calibration history", "boundary: 'finite' → 'periodic'", "buffer_rows: 2 → 0", "--no-resume")
    r = runner.invoke(app, [*args, "--boundary", "finite", "--samples", "8"])
    assert_user_error(r, "samples: 16 → 8")  # the same field now; only K differs


def test_error_messages_name_the_file_or_the_limit():
    from lightfit.cli.common import error_message

    assert (
        error_message(FileNotFoundError(2, "No such file or directory", "x.csv")) == "x.csv: No such file or directory"
    )
    assert error_message(TimeoutError()) == "timed out"
    assert error_message(TimeoutError("3 s")) == "timed out: 3 s"


def test_usage_errors_exit_2():
    r = runner.invoke(app, ["replicate", "--no-such-option"])
    assert r.exit_code == 2 and "no-such-option" in r.stderr


def _child_env() -> dict[str, str]:
    """The environment of a user's shell: no JAX_ENABLE_X64 (the test suite enables x64 in-process only)."""
    env = {k: v for k, v in os.environ.items() if k != "JAX_ENABLE_X64"}
    env["JAX_PLATFORMS"] = "cpu"
    return env


@pytest.mark.slow
def test_replicate_subprocess_runs_float64_without_warnings(tmp_path):
    """`lightfit replicate --quick` as a user runs it: float64 results, recorded, and a quiet stderr."""
    import xarray as xr

    p = subprocess.run(
        [sys.executable, "-m", "lightfit.cli", "replicate", "--quick", "--out", str(tmp_path)],
        env=_child_env(),
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert p.returncode == 0, p.stderr
    assert "warning" not in p.stderr.lower(), p.stderr
    assert "truncated" not in p.stderr + p.stdout
    with xr.open_dataset(tmp_path / "results.nc", engine="h5netcdf") as ds:
        floats = {v: ds[v].dtype for v in ds.data_vars if np.issubdtype(ds[v].dtype, np.floating)}
        assert floats and all(dt == np.float64 for dt in floats.values()), floats
        assert ds.attrs["precision"] == "float64"


def test_calibration_json_says_the_observations_are_synthetic(tmp_path):
    """calibration.json kept the observations' path (settings.json their SHA-256) but not what the
    file declares itself: a reader of the result alone could not tell a fit to the bundled synthetic
    twin from one to measurements. It now records the file's provenance and its title and generator
    lines, and the printed result says the fit was to synthetic observations."""
    twin = DATA_DIR / "observations" / "twin_2016-04-20_synthetic.csv"
    args = ["calibrate", str(twin), "--quick", "--steps", "14:16", "--parameters", "light_factor", "--no-surrogate"]
    r = runner.invoke(app, [*args, "--max-steps", "1", "--out", str(tmp_path)])
    assert r.exit_code == 0, r.output
    res = json.loads((tmp_path / "calibration.json").read_text())
    assert res["observations"] == str(twin.resolve()) and res["observations_provenance"] == "synthetic"
    head = dict(line[2:].split(": ", 1) for line in twin.read_text().splitlines() if line.startswith("# "))
    assert res["observations_metadata"] == {k: head[k] for k in ("title", "generator")}
    assert "SYNTHETIC twin" in res["observations_metadata"]["title"]
    assert "calibration: lbfgsb, to synthetic observations" in _flat(r.stdout)


def test_calibrate_bounded_method_on_two_steps(tmp_path):
    """--method lbfgsb and --use reach the calibration; --steps keeps it to the two steps around the observation."""
    args = ["calibrate", str(OBSERVATIONS), "--quick", "--steps", "14:16", "--parameters", "light_factor"]
    # from a far start one step cannot converge: the caution below must show (the default start converged)
    args += ["--start", "light_factor=3"]
    r = runner.invoke(
        app, [*args, "--method", "lbfgsb", "--use", "above_canopy_par", "--max-steps", "1", "--out", str(tmp_path)]
    )
    assert r.exit_code == 0, r.output
    res = json.loads((tmp_path / "calibration.json").read_text())
    assert res["method"] == "lbfgsb" and res["use"] == ["above_canopy_par"] and res["steps"] >= 1
    assert "lbfgsb" in r.stdout
    # an unconverged optimiser is said as such (a newcomer read "the fit is good" as the verdict)
    assert not res["optimizer_converged"] and res["stopped_by"] == "max_steps"
    assert "caution: the optimiser did not converge (step limit: 1 accepted step" in _flat(r.output)
    assert f"wrote {tmp_path / 'calibration.json'}, {tmp_path / 'settings.json'}, " in _flat(r.stdout)
    # The settings the run took, not the options left unset (null for the leaf's 50.5 µg cm⁻², the set's
    # 15 °C, the bundled weather, …: a review); null only where nothing is taken. What was asked is beside.
    config = res["config"]
    took = {"chlorophyll_ug_cm2": 50.5, "growth_temperature_c": 15.0, "bounces": 2, "samples": 16, "buffer_rows": 0}
    took |= {"weather_file": "2016-04-20", "split": "diffuse", "season_start": "2016-03-05", "steps": "14:16"}
    assert {k: config[k] for k in took} == took, config
    assert [k for k, v in config.items() if v is None] == ["target_rse"], config
    assert json.loads((tmp_path / "settings.json").read_text())["config"] == config
    assert res["options_given"] == ["--quick", "--steps", "14:16"] and config["preset"] == "default"
    # the hint reruns the same model (quick field, the two steps) against the same observations
    hint = _flat(r.stdout).split("to see the fit: ")[1]
    assert hint.startswith("lightfit replicate --quick --steps 14:16 --theta ")
    assert f"--observations {OBSERVATIONS}" in hint


def test_model_options_as_arguments_parse_back_to_themselves():
    """ModelOptions.args() (the calibration's hint) gives flags that the model commands parse back
    to the same options: every flag real, repeated --date kept."""
    from lightfit.cli.options import ModelOptions

    opts = ModelOptions(
        quick=True,
        n_plants=6,
        samples=16,
        direct_rays_per_m2="1e7,2e7",
        par_kind="absorbed",
        weather_file="selhausen-cplantbox-day",
        dates=["2016-04-27", "2016-04-28"],
        start_time="06:00",
        hours=14.0,
        step="10min",
        latitude=50.9,
        photosynthesis_override=["a1=4.5", "vcmax_ref_umol_m2_s=85"],
    )
    cmd = typer.main.get_command(app).commands["replicate"]
    ctx = cmd.make_context("replicate", [*opts.args(), "--out", "x"])
    assert ModelOptions(**{k: ctx.params[k] for k in ModelOptions.__dataclass_fields__}) == opts
    # repeatable options not given come as empty tuples: not given (args() wrote "--date ()")
    ctx = cmd.make_context("replicate", ["--quick", "--out", "x"])
    bare = ModelOptions(**{k: ctx.params[k] for k in ModelOptions.__dataclass_fields__})
    assert bare == ModelOptions(quick=True) and bare.args() == ["--quick"]


@pytest.mark.slow
def test_calibrate_exits_3_when_the_full_render_check_did_not_pass(tmp_path, monkeypatch):
    """A surrogate calibration whose full-render check did not pass exited 0, said in red only, so a
    script running calibrations could not tell (a review): it writes its result (converged false)
    and exits 3, neither 0 nor bad input's 2. The check's outcome is stood in for (a real failure
    needs a design that the emulator misses); the run itself is the cheap light-factor one."""
    import dataclasses

    import lightfit.inference.trust_region as T

    real = T.surrogate_calibrate
    monkeypatch.setattr(
        T, "surrogate_calibrate", lambda *a, **k: dataclasses.replace(real(*a, **k), passed=False, mode="surrogate")
    )
    args = ["calibrate", str(OBSERVATIONS), "--quick", "--steps", "14:16", "--parameters", "light_factor"]
    r = runner.invoke(app, [*args, "--out", str(tmp_path)])
    assert r.exit_code == 3, r.output
    assert isinstance(r.exception, SystemExit), r.exception  # no traceback
    res = json.loads((tmp_path / "calibration.json").read_text())
    assert res["converged"] is False and res["surrogate"]["passed"] is False
    assert "not passed within --max-rounds" in _flat(r.stdout)
    assert "the full-render check did not pass" in _flat(r.stderr) and "exit status 3" in _flat(r.stderr)
    # the same run, checked as passed (one render: exact), exits 0
    monkeypatch.setattr(T, "surrogate_calibrate", real)
    r = runner.invoke(app, [*args, "--out", str(tmp_path / "passed")])
    assert r.exit_code == 0, r.output
    assert json.loads((tmp_path / "passed" / "calibration.json").read_text())["surrogate"]["passed"] is True


def test_calibrate_subprocess_runs_bfgs_in_float64(tmp_path):
    """Two time steps around the bundled record's one PAR observation (12:13 local), two BFGS steps."""
    args = ["calibrate", str(OBSERVATIONS), "--quick", "--steps", "14:16", "--parameters", "light_factor"]
    p = subprocess.run(
        [sys.executable, "-m", "lightfit.cli", *args, "--max-steps", "2", "--out", str(tmp_path / "cal")],
        env=_child_env(),
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert p.returncode == 0, p.stderr
    assert "warning" not in p.stderr.lower(), p.stderr
    res = json.loads((tmp_path / "cal" / "calibration.json").read_text())
    assert res["precision"] == "float64" and res["config"]["steps"] == "14:16"
    assert res["theta"]["light_factor"] > 0


#: A bad value for every option of every command whose values lightfit checks itself (typer checks
#: int/float types; the walker covers those with "x"). Keyed by option flag; "OBS" is the record.
BAD_VALUES = {
    "--date": ["2016-02-30", "April", "2015-06-23", "2016-12-01"],
    "--start-time": ["25:00", "5"],
    "--hours": ["0", "30"],
    "--step": ["2x", "0min", "20h", "30"],
    "--site": ["atlantis"],
    "--latitude": ["95"],
    "--timezone": ["Mars/Olympus"],
    "--weather": ["no-such-weather.csv", "selhausen-cplantbox-dayz"],
    "--boundary": ["torus"],
    "--par-kind": ["diffuse"],
    "--photosynthesis": ["c3-magic"],
    "--an-per": ["plant"],
    "--how": ["median"],
    "--steps": ["0", "a:b"],
    "--samples": ["1", "x"],
    "--bounces": ["-1", "x"],
    "--n-plants": ["0", "x"],
    "--field-seed": ["-3"],
    "--buffer-rows": ["2"],
    "--direct-rays-per-m2": ["0", "1e7,x", "1e6,2e6,3e6", "nan"],
    "--theta": ["specular=-1", "light_factor=0", "roughness=nan", "subsurface=1.5"],
    "--start": ["specular=5", "vcmax_scale=-1"],
    "--max-steps": ["0", "-1"],
    "--walkers": ["3", "2"],
    "--render-seed": ["-1"],
    "--ceptometer-height-m": ["-1"],
    "--soil-respiration": ["-1", "1e308"],
    "--soil-respiration-q10": ["0.5", "1e308"],
    "--photosynthesis-override": ["curvature=1.5", "a1=1e308", "vcmax_ref_umol_m2_s=1e30"],
    "--n-design": ["0", "1"],
    "--target-ess": ["0"],
    "--max-minutes": ["-1", "0"],
    "--max-rounds": ["0"],
    "--timeout": ["-5"],
    "--connect-timeout": ["0"],
}
#: Options that need others to be wrong (a site's coordinates come together).
WITH = {"--latitude": ["--longitude", "6", "--timezone", "UTC"], "--timezone": ["--latitude", "50", "--longitude", "6"]}


def _walk():
    group = typer.main.get_command(app)
    for name in MODEL_COMMANDS:
        flags = {o for p in group.commands[name].params for o in p.opts}
        for flag, values in BAD_VALUES.items():
            if flag in flags:
                for v in values:
                    yield name, flag, v


@pytest.mark.parametrize("command, flag, value", list(_walk()))
def test_every_bad_option_value_exits_2_with_one_line(command, flag, value, tmp_path, monkeypatch):
    """Issue 17 item 6: each model command, each checked option, bad values: exit 2, one line naming
    the option (or its parameter), no traceback, and nothing grown or rendered (an empty plant cache)."""
    monkeypatch.setenv("LIGHTFIT_CACHE", str(tmp_path / "cache"))
    # The chamber record informs only light_factor (the leaf parameters are refused before the rest).
    own = [str(OBSERVATIONS), "--parameters", "light_factor"] if command in ("calibrate",) else []
    out = tmp_path / ("out.nc" if command == "field-run" else "out")  # field-run writes one netCDF file
    r = runner.invoke(app, [command, *own, "--quick", "--out", str(out), flag, value, *WITH.get(flag, [])])
    assert_user_error(r)
    err = r.stderr.strip()
    if err.startswith("error:"):
        assert len(err.splitlines()) == 1, err
        words = {flag.lstrip("-"), flag.lstrip("-").replace("-", "_"), value}
        assert any(w in err for w in words) or flag in err, err
        if err.startswith("error: option "):  # the option named is the one given (not calibrate's --start),
            assert err.startswith(f"error: option {flag}") or flag in err, err  # or one it conflicts with
    assert not (tmp_path / "cache").exists() or not any((tmp_path / "cache").rglob("*.npz"))
    assert not (tmp_path / "out" / "forcing.csv").exists()  # nothing written either


def test_weather_option_takes_bundled_names_and_undated_files_need_a_date(tmp_path):
    """--weather accepts what `lightfit weather show` accepts; an undated file without --date names both."""
    for source in ("selhausen-cplantbox-day", str(DATA_DIR / "weather" / "selhausen_cplantbox_day.txt")):
        r = runner.invoke(app, ["replicate", "--quick", "--out", str(tmp_path), "--weather", source])
        assert_user_error(r, "selhausen_cplantbox_day.txt", "no date", "--date")
    r = runner.invoke(
        app,
        ["replicate", "--quick", "--out", str(tmp_path), "--weather", "selhausen-cplantbox-day", "--date", "2016-04-27"]
        + ["--start-time", "20:00", "--hours", "6"],
    )
    said = ("selhausen_cplantbox_day.txt: the window 2016-04-27 20:00 + 6 h", "--date, --start-time, --hours")
    assert_user_error(r, *said)
    two = ["--date", "2016-04-20", "--date", "2016-04-21"]
    assert_user_error(runner.invoke(app, ["field-run", "--quick", "--out", str(tmp_path / "r.nc"), *two]), "one --date")
    bad = tmp_path / "renamed.txt"
    bad.write_text((DATA_DIR / "weather" / "selhausen_cplantbox_day.txt").read_text().replace('"Tair"', '"Temp"'))
    r = runner.invoke(
        app, ["replicate", "--quick", "--out", str(tmp_path), "--weather", str(bad), "--date", "2016-04-27"]
    )
    assert_user_error(r, "renamed.txt", "Tair")


@pytest.mark.parametrize(
    "body, words",
    [
        ("# time_zone: UTC\ntime,fapar,fapar_sd\n", ["no data rows"]),
        ("time,fapar,fapar_sd\n2016-04-20 12:00,0.9,0.05\n", ["line 3", "time", "# time_zone:"]),
        ("# time_zone: UTC\ntime,fapar,fapar_sd\n2016-04-20 12:00,94,3\n", ["line 4", "fapar", "percentage"]),
        # a ratio of light in the dark (03:00 UTC, before sunrise): the model's is 0 by convention there
        (
            "# time_zone: UTC\ntime,fapar,fapar_sd\n2016-04-20 03:00,0.9,0.03\n2016-04-20 10:00,0.9,0.03\n",
            ["line 4", "column 'fapar'", "no PAR above the canopy", "daylight"],
        ),
        # ... and at dawn (04:50 UTC, the sun 3° up) between a dark step (04:30) and a lit one (05:00): read
        # between them, the model's fAPAR is a third its conventional 0 there (0.63 for 07:00's 0.94)
        (
            "# time_zone: UTC\ntime,fapar,fapar_sd\n2016-04-20 10:00,0.9,0.03\n2016-04-20 04:50,0.9,0.03\n",
            ["line 5", "column 'fapar'", "no PAR above the canopy", "night at 2016-04-20T04:30:00+00:00"],
        ),
    ],
)
def test_replicate_refuses_bad_observations_before_running(body, words, tmp_path, monkeypatch):
    """A bad observations file ends the run in seconds, before plants grow or the forcing is written
    (a newcomer's review: it used to fail after the whole simulation, a header-only file with a traceback)."""
    monkeypatch.setenv("LIGHTFIT_CACHE", str(tmp_path / "cache"))
    f = tmp_path / "obs.csv"
    f.write_text("# provenance: measured\n" + body, encoding="utf-8")
    r = runner.invoke(app, ["replicate", "--quick", "--out", str(tmp_path / "out"), "--observations", str(f)])
    assert_user_error(r, str(f), *words)
    assert not (tmp_path / "out" / "forcing.csv").exists()
    assert not (tmp_path / "cache").exists() or not any((tmp_path / "cache").rglob("*.npz"))


@pytest.mark.parametrize("command", ["replicate", "calibrate", "posterior"])
def test_observed_light_off_the_forcings_scale_is_refused_before_running(command, tmp_path):
    """The chamber record's PAR in mmol m⁻² s⁻¹ (1.549 at 12:13 with the sun at 47°: 10⁻³ of the
    forcing's ≈ 1 500) was accepted, and calibrate fitted a light factor of 0.001 with a caution (a
    CLI review); the weather reader refuses the same slip in the forcing. The record as it is, at
    1.0 × the forcing's PAR, passes (the main job's own run)."""
    f = tmp_path / "obs_mmol.csv"
    record = OBSERVATIONS.read_text()
    f.write_text(record.replace("1549.31,77.47", "1.54931,0.07747"))
    args = [command, "--quick", "--out", str(tmp_path / "out")]
    args += ["--observations", str(f)] if command == "replicate" else [str(f)]
    r = runner.invoke(app, args)
    assert_user_error(r, "obs_mmol.csv", "above_canopy_par_umol_m2_s", "0.00102 × the forcing's PAR", "mmol")
    assert not (tmp_path / "out" / "forcing.csv").exists()
    from lightfit import replication as rep
    from lightfit.inference.observations import check_light_scale, read_observations

    check_light_scale(read_observations(OBSERVATIONS), rep.forcing())  # the record itself: no error


def test_nee_with_uptake_counted_positive_gets_a_caution_before_the_plants_grow(tmp_path):
    """Chamber NEE with the wrong sign convention (uptake positive) was fitted: vcmax_scale went to 0
    with generic cautions (a review). Positive NEE at every reading in strong light is named, with the
    file, the column and the convention, before the plants grow; a caution, not a refusal, because a
    sparse canopy over a respiring soil can release CO2 by day. Uptake negative: nothing said."""
    from lightfit import replication as rep
    from lightfit.inference.observations import co2_sign_caution, read_observations

    head = "# provenance: synthetic\n# time_zone: UTC\ntime,nee_umol_m2_s,nee_sd_umol_m2_s\n"
    rows = "".join(f"2016-04-20T{h}:00:00Z,{{sign}}{v},1.5\n" for h, v in (("10", 25), ("10:30", 28), ("11", 30)))
    rows = rows.replace("10:30:00:00", "10:30:00")
    wrong, right = tmp_path / "nee_wrong.csv", tmp_path / "nee.csv"
    wrong.write_text(head + rows.format(sign=""))
    right.write_text(head + rows.format(sign="-"))
    w = rep.forcing()
    said = co2_sign_caution(read_observations(wrong), w)
    assert "nee_wrong.csv, column 'nee_umol_m2_s'" in said and "positive (a release) at all 3 readings" in said
    assert "negate the column" in said and co2_sign_caution(read_observations(right), w) is None
    # A NaN reading is not counted, and one reading alone is not judged.
    one = tmp_path / "one.csv"
    one.write_text(head + "2016-04-20T10:00:00Z,25,1.5\n")
    assert co2_sign_caution(read_observations(one), w) is None
    args = ["calibrate", str(wrong), "--quick", "--steps", "14:17", "--parameters", "vcmax_scale", "--no-surrogate"]
    r = runner.invoke(app, [*args, "--max-steps", "1", "--out", str(tmp_path / "out")])
    text = " ".join(r.output.split())
    assert "caution" in text and "NEE is positive (a release) at all 3 readings" in text, text
    assert r.exit_code == 0 and text.index("NEE is positive") < text.index("observations:"), text  # before growing


def test_canopy_an_with_uptake_counted_negative_gets_a_caution(tmp_path):
    """Canopy An in NEE's sign (uptake negative: a chamber's NEE copied into canopy_an_umol_m2_s, or the
    bundled twin negated) passed unsaid, while the same slip in NEE is cautioned: fitted, it drives
    vcmax_scale to 0. Negative at every reading in strong light is now named with the file, the
    column and the convention; the twin as it is says nothing."""
    from lightfit import replication as rep
    from lightfit.inference.observations import observation_cautions, read_observations

    twin = DATA_DIR / "observations" / "twin_2016-04-20_synthetic.csv"
    lines = twin.read_text().splitlines()
    k = lines.index(next(ln for ln in lines if ln.startswith("time,"))) + 1
    an = lines[k - 1].split(",").index("canopy_an_umol_m2_s")

    def negated(ln):
        c = ln.split(",")
        c[an] = f"{-float(c[an]):g}" if c[an] else ""
        return ",".join(c)

    flipped = tmp_path / "twin_flipped.csv"
    flipped.write_text("\n".join(lines[:k] + [negated(ln) for ln in lines[k:]]) + "\n")
    w = rep.forcing()
    said = " ".join(observation_cautions(read_observations(flipped), w))
    assert "twin_flipped.csv, column 'canopy_an_umol_m2_s': canopy An is negative (a release) at all" in said, said
    assert "positive for uptake" in said and "negate the column if the file counts uptake as negative" in said
    assert observation_cautions(read_observations(twin), w) == []


def test_above_canopy_par_in_w_m2_gets_a_caution_before_the_plants_grow(tmp_path):
    """The chamber record's PAR in W m⁻² (1549.31 / 4.57 = 339: 0.22 × the forcing's PAR) passed the
    unit check, whose range is wide enough for a spot reading against a mean under broken cloud, and
    would have calibrated a light factor of 0.22 without a word. It is now named, with the file, the
    column and the factor, before the plants grow; the record as it is (1.0 ×) and a reading under
    a cloud's shadow at 0.4 × say nothing."""
    from lightfit import replication as rep
    from lightfit.inference.observations import observation_cautions, par_unit_caution, read_observations

    record, w = OBSERVATIONS.read_text(), rep.forcing()
    cases = {"w_m2": ("339.02,16.95", True), "shade": ("620.0,31.0", False), "record": ("1549.31,77.47", False)}
    for name, (row, said) in cases.items():
        f = tmp_path / f"obs_{name}.csv"
        f.write_text(record.replace("1549.31,77.47", row))
        got = par_unit_caution(read_observations(f), w)
        assert (got is not None) == said, (name, got)
    obs = read_observations(tmp_path / "obs_w_m2.csv")
    (got,) = observation_cautions(obs, w)
    assert "obs_w_m2.csv, column 'above_canopy_par_umol_m2_s'" in got and "0.224 × the forcing's PAR" in got
    assert "multiply it by 4.57" in got
    args = ["calibrate", str(tmp_path / "obs_w_m2.csv"), "--quick", "--parameters", "light_factor", "--no-surrogate"]
    r = runner.invoke(app, [*args, "--max-steps", "1", "--out", str(tmp_path / "out")])
    text = " ".join(r.output.split())
    assert r.exit_code == 0 and "caution" in text and text.index("multiply it by 4.57") < text.index("observations:")


def test_observations_asked_for_outside_the_window_are_refused_even_the_bundled_file(tmp_path):
    """--observations names a file the user wants compared: outside the run's steps it is an error
    (the bundled record's own path was dropped silently); only the default record is optional."""
    from lightfit import replication as rep
    from lightfit.weather import Window

    args = ["replicate", "--quick", "--start-time", "06:00", "--hours", "1", "--out", str(tmp_path / "r")]
    r = runner.invoke(app, [*args, "--observations", str(OBSERVATIONS)])
    # its line, and its time in the file's own zone (it said 10:13:48+00:00 for a Berlin record)
    assert_user_error(r, "chamber_2016-04-20_record.csv", "line 8", "observation at 2016-04-20T12:13:48+02:00")
    # the lines it keeps for that leave the frame one pandas can concatenate (attrs compared with ==)
    from lightfit.inference.observations import read_observations

    a, b = read_observations(OBSERVATIONS), read_observations(OBSERVATIONS)
    assert a.attrs == b.attrs and len(pd.concat([a, b.set_axis(b.index + pd.Timedelta("1min"))])) == 2
    assert not (tmp_path / "r").exists()
    w = rep.forcing(window=Window("06:00", 1.0))
    assert rep.observations_for(w) is None  # the default record, optional
    with pytest.raises(InputError):
        rep.observations_for(w, OBSERVATIONS, optional=False)


def test_steps_compare_the_observations_within_them(tmp_path):
    """--steps runs some of the window's steps: a day's observations file was refused because its
    other rows (and its empty 03:00 rows) lay outside those steps (a review). The rows within the
    steps are compared, the others left out with a line saying how many; a row without any value is
    never an observation outside the run; without a reading in the steps it is still an error."""
    import xarray as xr

    twin = DATA_DIR / "observations" / "twin_2016-04-20_synthetic.csv"
    out = tmp_path / "r"
    r = runner.invoke(app, ["replicate", "--quick", "--steps", "14:16", "--observations", str(twin), "--out", str(out)])
    text = " ".join(r.output.split())
    assert r.exit_code == 0, text
    assert "27 of 29 row(s) outside --steps 14:16 left out" in text and "2 of 2 with their nearest step" in text
    with xr.open_dataset(out / "results.nc") as ds:
        assert np.isfinite(ds["obs_plant_par_umol_m2_s"].values).all() and ds.sizes["time"] == 2
    # no reading within the steps: refused, naming the first reading outside (not an empty row)
    r = runner.invoke(app, ["replicate", "--quick", "--steps", "0:2", "--observations", str(twin), "--out", str(out)])
    assert_user_error(r, "twin_2016-04-20_synthetic.csv", "line 15", "lies outside the run")
    # readings beyond the day's window are still refused with --steps (a clock slip is not cut away)
    obs = pd.read_csv(twin, comment="#")
    obs["time"] = (pd.to_datetime(obs["time"]) + pd.Timedelta("2h")).dt.strftime("%Y-%m-%dT%H:%M:%SZ")
    shifted = tmp_path / "shifted.csv"
    head = "".join(line for line in twin.read_text().splitlines(keepends=True) if line.startswith("#"))
    shifted.write_text(head + obs.to_csv(index=False))
    for steps in ("0:29", "14:16"):
        r = runner.invoke(
            app, ["replicate", "--quick", "--steps", steps, "--observations", str(shifted), "--out", str(out)]
        )
        assert_user_error(r, "shifted.csv", "line 36", "2016-04-20T17:30:00+00:00 lies outside the run")


def test_errors_name_the_option_that_caused_them(tmp_path):
    """An off-grid window start names --start-time (it blamed --step), an option applied to a file
    names the option and the file (it said "column 'tz'"), and a file where an output folder should
    be is refused by every command before any work (it failed after the run with "File exists")."""
    r = runner.invoke(app, ["replicate", "--quick", "--start-time", "12:07", "--hours", "1", "--out", str(tmp_path)])
    assert_user_error(r, "option --start-time:", "12:07", "rows every 10 min")
    # calibrate has its own --start (the starting leaf): the window's start is still --start-time
    args = ["calibrate", str(OBSERVATIONS), "--quick", "--parameters", "light_factor", "--start-time", "05:05"]
    r = runner.invoke(app, [*args, "--out", str(tmp_path)])
    assert_user_error(r, "option --start-time:", "05:05")
    recon = str(DATA_DIR / "weather" / "selhausen_2016-04-20_reconstructed.csv")
    assert_user_error(runner.invoke(app, ["weather", "show", recon, "--tz", "UTC"]), "reconstructed.csv: option --tz:")
    a_file = tmp_path / "a_file"
    a_file.write_text("")
    for command in (["replicate", "--quick"], ["calibrate", str(OBSERVATIONS), "--quick"], ["posterior", "--quick"]):
        assert_user_error(runner.invoke(app, [*command, "--out", str(a_file)]), "option --out:", "is a file")
    r = runner.invoke(app, ["render-dataset", str(tmp_path / "results.nc"), "--out", str(a_file)])
    assert_user_error(r, "option --out:", "is a file")
    # a file above the output folder: "Not a directory", naming .unfinished, once the field was built
    for command in (["render-dataset", str(tmp_path / "results.nc")], ["replicate", "--quick"]):
        r = runner.invoke(app, [*command, "--out", str(a_file / "ds")])
        assert_user_error(r, "option --out:", "a_file is a file, not a folder")


def test_compare_preset_paper_runs_the_papers_setup_beside_the_default(tmp_path):
    """--compare-preset paper renders the paper's finite field with its own direct light (the
    default's projection is refused there; the option failed after the main run), on the same steps."""
    import xarray as xr

    r = runner.invoke(
        app, ["replicate", "--quick", "--compare-preset", "paper", "--steps", "14:16", "--out", str(tmp_path)]
    )
    assert r.exit_code == 0, r.output
    with xr.open_dataset(tmp_path / "results.nc") as main, xr.open_dataset(tmp_path / "results_compare.nc") as cmp:
        assert (main.attrs["preset"], main.attrs["boundary"], main.attrs["direct"]) == (
            "default",
            "periodic",
            "projection",
        )
        assert (cmp.attrs["preset"], cmp.attrs["boundary"], cmp.attrs["direct"]) == ("paper", "finite", "paths")
        assert cmp.attrs["photosynthesis"] == "giraud2023" and cmp.attrs["sheaths"] == "rods"
        np.testing.assert_array_equal(main["time"].values, cmp["time"].values)
        # both runs met the bundled record's 12:13:48 PAR reading, each says how
        from lightfit.report import observations_fit

        assert (
            observations_fit(main).loc["above_canopy_par", "n"]
            == observations_fit(cmp).loc["above_canopy_par", "n"]
            == 1
        )
    out = _flat(r.stdout)
    assert "model against the observations" in out and "the paper preset against the observations" in out
    assert (tmp_path / "replication.png").stat().st_size > 10_000
    # Rerun into the same folder without the option: the earlier comparison does not stay beside
    # results it does not belong to (a newcomer review).
    r = runner.invoke(app, ["replicate", "--quick", "--steps", "14:16", "--out", str(tmp_path)])
    assert r.exit_code == 0, r.output
    assert (tmp_path / "results.nc").exists() and not (tmp_path / "results_compare.nc").exists()
    # the run's own model choices do not leak into the comparison: it is the preset, not a hybrid
    from lightfit.cli.options import ModelOptions
    from lightfit.cli.replicate import _comparison

    mixed = _comparison(ModelOptions(quick=True, boundary="periodic", photosynthesis="winter_wheat"), "paper")
    got = (mixed.boundary, mixed.photosynthesis, mixed.optics, mixed.preset)
    assert got == ("finite", "giraud2023", "paper", "paper")
    own = _comparison(ModelOptions(quick=True, vcmax_profile="lloyd2010"), "paper")  # the run's, not the paper's
    assert (own.vcmax_profile, own.preset) == ("uniform", "paper")
    import dataclasses

    from lightfit.replication import ReplicationConfig

    assert dataclasses.replace(ReplicationConfig.paper(), vcmax_profile=0.5).preset is None
    assert dataclasses.replace(ReplicationConfig.paper(), vcmax_profile="uniform").preset == "paper"


def test_compare_preset_help_says_the_compared_run_does_not_take_theta():
    """replication.run runs the --compare-preset configuration with its preset's own leaf and
    scales (no θ): a reader of --help must not take the dashed curves for the preset at the θ given
    (a review: the help of neither option said so)."""
    params = {p.name: p.help for p in typer.main.get_command(app).commands["replicate"].params}
    assert "--theta is not applied to it" in params["compare_preset"]
    assert "not the --compare-preset run" in params["theta"]


@pytest.mark.parametrize(
    "args, flag",
    [
        (["replicate", "--quick", "--field-seed", "-1"], "option --field-seed:"),
        (["replicate", "--quick", "--preset", "foo"], "option --preset:"),
        (["replicate", "--quick", "--compare-preset", "foo"], "--compare-preset:"),
        (["replicate", "--quick", "--compare-preset", "default"], "--compare-preset default is this run's own"),
        (["replicate", "--quick", "--preset", "paper", "--bounces", "8", "--compare-preset", "paper"], "paper is this"),
        (["weather", "show", "--resample", "7min", "--how", "sample"], "option --resample:"),
        (["weather", "show", "--resample", "bogus"], "option --resample:"),
        (["weather", "show", "--max-gap", "foo"], "option --max-gap:"),
        (["replicate", "--quick", "--timezone", "Mars/X"], "--timezone given without"),
    ],
)
def test_errors_name_the_option_the_command_has(args, flag, tmp_path):
    """A library error about a parameter names the invoked command's own option (a review found
    --field-seed reported as render-dataset's --seed, weather show's --resample as --step, and a
    lone --timezone blamed on --site)."""
    r = runner.invoke(app, [*args, "--out", str(tmp_path)] if args[0] == "replicate" else args)
    assert_user_error(r, flag)
    err = _flat(r.stderr)
    assert "column '" not in err and "Traceback" not in r.output
    for other in {"--seed:", "--step:", "--site:"} - {flag.split()[-1]}:
        assert f"option {other}" not in err, err


def test_field_refuses_an_unknown_export_format_before_growing(tmp_path, monkeypatch):
    """`lightfit field --export f.stl` fails before any plant grows (it used to print the whole report first)."""
    monkeypatch.setenv("LIGHTFIT_CACHE", str(tmp_path / "cache"))
    r = runner.invoke(app, ["field", "--n-plants", "4", "--export", str(tmp_path / "f.stl")])
    assert_user_error(r, "f.stl", "unknown mesh format", ".obj, .ply or .vtk")
    assert "plants" not in r.stdout and not (tmp_path / "cache").exists()


@pytest.mark.parametrize("option, name", [("--export", "f.ply"), ("--segments", "s.csv"), ("--preview", "p.png")])
def test_field_refuses_an_output_under_a_file_before_growing(tmp_path, monkeypatch, option, name):
    """An output whose folder is a file (`--export notes.txt/f.ply`) cannot be written: it failed
    with "notes.txt: File exists" only after the plants had grown and the report was printed."""
    monkeypatch.setenv("LIGHTFIT_CACHE", str(tmp_path / "cache"))
    (tmp_path / "notes.txt").write_text("a file\n")
    r = runner.invoke(app, ["field", "--n-plants", "4", option, str(tmp_path / "notes.txt" / "sub" / name)])
    assert_user_error(r, f"option {option}", "notes.txt is a file, not a folder")
    assert "plants" not in r.stdout and not (tmp_path / "cache").exists()


def test_field_refuses_an_obj_whose_sidecar_is_a_folder_before_growing(tmp_path, monkeypatch):
    """`--export f.obj` writes the values to f.segments.csv too: a folder of that name failed with
    "Is a directory" after the plants had grown, the OBJ written without its values."""
    monkeypatch.setenv("LIGHTFIT_CACHE", str(tmp_path / "cache"))
    (tmp_path / "f.segments.csv").mkdir()
    r = runner.invoke(app, ["field", "--n-plants", "4", "--export", str(tmp_path / "f.obj")])
    assert_user_error(r, "option --export", "f.segments.csv is a folder")
    assert "plants" not in r.stdout and not (tmp_path / "cache").exists() and not (tmp_path / "f.obj").exists()


def test_field_refuses_a_segment_table_named_as_the_obj_sidecar_before_growing(tmp_path, monkeypatch):
    """`--export a.obj --segments a.segments.csv`: the segment table silently replaced the OBJ's
    sidecar of per-segment values (same name; a review). Refused before any plant grows."""
    monkeypatch.setenv("LIGHTFIT_CACHE", str(tmp_path / "cache"))
    args = ["field", "--n-plants", "4", "--export", str(tmp_path / "a.obj")]
    r = runner.invoke(app, [*args, "--segments", str(tmp_path / "a.segments.csv")])
    assert_user_error(r, "a.segments.csv is also the OBJ export's sidecar")
    assert "plants" not in r.stdout and not (tmp_path / "cache").exists()


@pytest.mark.parametrize("name", ["f.stl", "f"])
def test_figure_names_without_a_known_format_are_refused_first(tmp_path, monkeypatch, name):
    """`field --preview` and `weather show --plot` take the format from the suffix (a .jpg
    preview is a JPEG); a name with no format they can write fails before any plant grows or
    any weather is read."""
    monkeypatch.setenv("LIGHTFIT_CACHE", str(tmp_path / "cache"))
    r = runner.invoke(app, ["field", "--n-plants", "4", "--preview", str(tmp_path / name)])
    assert_user_error(r, str(tmp_path / name), "image format", ".png, .pdf, .svg")
    assert "plants" not in r.stdout and not (tmp_path / "cache").exists()
    r = runner.invoke(app, ["weather", "show", str(FIXTURE), "--plot", str(tmp_path / name)])
    assert_user_error(r, str(tmp_path / name), "image format")
    assert "clamped" not in r.stdout  # refused before the file was read and reported


def test_weather_plot_format_follows_the_suffix(tmp_path):
    svg = tmp_path / "w.svg"
    r = runner.invoke(app, ["weather", "show", str(FIXTURE), "--plot", str(svg)])
    assert r.exit_code == 0, r.output
    assert svg.read_text().lstrip().startswith("<?xml") and "<svg" in svg.read_text()[:2000]


def test_multiline_library_errors_print_as_one_line(tmp_path):
    """A results file that is not netCDF: xarray's multi-line message is one line on stderr."""
    r = runner.invoke(app, ["render-dataset", str(OBSERVATIONS), "-o", str(tmp_path / "x")])
    assert_user_error(r)
    assert len(r.stderr.strip().splitlines()) == 1, r.stderr


def test_banners_name_an_adaptive_runs_target_and_k_range():
    """replicate's and field-run's banner: a fixed K, or the target with the pilot raised to 32 and
    the cap (the estimator's; field-run said K=16 under --quick --target-rse)."""
    from lightfit.report import samples_label

    assert samples_label(16, None) == "K=16"
    assert samples_label(16, 0.1) == "target 0.1 (K from 32 to 8192 per segment)"
    assert samples_label(16384, 0.05) == "target 0.05 (K from 16384 to 16384 per segment)"
    # summary.csv's header said "K = 16" of an adaptive run (the pilot's base; a review): its target
    # and the cap the results file records
    import xarray as xr

    from lightfit.report import summary_metadata

    a = {"samples": 16, "bounces": 2, "n_plants": 9, "boundary": "periodic"}
    adaptive = summary_metadata(xr.Dataset(attrs=a | {"target_rse": 0.05, "max_samples": 4096}))["field"]
    assert adaptive == "9 plants, periodic boundary, target 0.05 (K from 32 to 4096 per segment), 2 bounces"
    assert summary_metadata(xr.Dataset(attrs=a))["field"] == "9 plants, periodic boundary, K=16, 2 bounces"


def test_field_run_records_where_and_when_as_replicate_does(tmp_path):
    """field-run's file named no site, window, date or preset (a newcomer could not tell where a
    field-scale result came from); it records them as replicate does (replication.when_attrs)."""
    import xarray as xr

    out = tmp_path / "r.nc"
    args = ["field-run", "--quick", "--start-time", "11:00", "--hours", "0.5", "--workers", "1", "--no-progress"]
    r = runner.invoke(app, [*args, "--out", str(out)])
    assert r.exit_code == 0, r.output
    with xr.open_dataset(out) as ds:
        a = ds.attrs
        where = (a["site"], a["site_timezone"], a["date"], a["preset"])
        assert where == ("Selhausen", "Europe/Berlin", "2016-04-20", "default")
        assert a["window"].startswith("2016-04-20 11:00 + 0.5 h") and '"n_plants"' in a["replication_config"]
        ran = json.loads(a["replication_config"])  # what ran: null for bounces and chlorophyll before
        assert (ran["bounces"], ran["samples"], ran["direct"], ran["chlorophyll_ug_cm2"]) == (2, 16, "projection", 50.5)
        above = ds["above_canopy_par_umol_m2_s"].values
    # --theta runs the field at given parameters, as replicate does (field-run had no way to take a
    # calibration's; a newcomer's audit): the sensor above the canopy scales with the light factor alone
    r = runner.invoke(app, [*args, "--theta", "light_factor=1.25,specular=0.4", "--out", str(tmp_path / "t.nc")])
    assert r.exit_code == 0, r.output
    with xr.open_dataset(tmp_path / "t.nc") as ds:
        assert (ds.attrs["theta_light_factor"], ds.attrs["theta_specular"]) == (1.25, 0.4)
        np.testing.assert_allclose(ds["above_canopy_par_umol_m2_s"].values, 1.25 * above, rtol=1e-12)


def test_edge_note_only_where_fapar_exceeds_one():
    """replicate's table is flagged where canopy APAR exceeds the PAR above the canopy (a finite
    field's edge; the paper preset's quick field reaches 1.4), and only there."""
    import xarray as xr

    from lightfit.cli.replicate import edge_line

    edge = xr.Dataset({"fapar": ("time", [0.0, 0.93, 1.2, 1.39])}, attrs={"boundary": "finite"})
    line = edge_line(edge)
    assert "fAPAR above 1 at 2 of 4 steps (up to 1.39)" in line and "finite field" in line
    assert edge_line(xr.Dataset({"fapar": ("time", [0.0, 0.93, 1.0])})) == ""


def test_offset_line_says_how_observations_meet_the_steps():
    """The bundled record (12:13:48 local) lies between the 12:00 and 12:30 steps of 30-min
    instants, 13.8 min from the nearer: read between them. With 12:00 alone it meets that step."""
    from lightfit import replication as rep
    from lightfit.cli.common import offset_line
    from lightfit.inference.observations import read_observations

    rec = read_observations(OBSERVATIONS)
    w = rep.forcing().iloc[14:16]  # 12:00 and 12:30 local
    line = " ".join(offset_line(rec, w).split())
    # the bundled forcing was scaled to that very reading: said, so that the match is not read as a check
    anchored = "the PAR reading at 2016-04-20 12:13:48 Europe/Berlin is the point the reconstructed forcing was "
    anchored += "scaled to: it agrees by construction and validates nothing"
    assert line == (
        "1 of 1 compared with the model interpolated linearly in time between the two steps around them; " + anchored
    )
    w = rep.forcing().iloc[13:15]  # 11:30 and 12:00: the reading lies after the last step
    line = " ".join(offset_line(rec, w).split())
    assert line.startswith("1 of 1 with their nearest step, up to 13.8 min away (instants to instants, by interval")
    w.attrs = {}  # a forcing not scaled to any reading (a measured series): nothing of the kind said
    assert "by construction" not in offset_line(rec, w)
    # one reading between two steps, one after the last: each said
    two = pd.concat([rec, rec.set_axis(rec.index + pd.Timedelta("25min"))])
    two.attrs = rec.attrs
    line = " ".join(offset_line(two, rep.forcing().iloc[14:16]).split())
    assert (
        line.startswith("1 of 2 compared with the model interpolated")
        and "; 1 of 2 with their nearest step, up to 8.8" in line
    )


def test_calibrate_into_a_folder_of_another_calibration_is_refused(tmp_path, monkeypatch):
    """A second calibrate of other parameters into the same --out replaced the first run's result and
    history without a word; it is refused before any plant grows (--no-resume replaces it)."""
    monkeypatch.setenv("LIGHTFIT_CACHE", str(tmp_path / "cache"))
    out = tmp_path / "cal"
    out.mkdir()
    (out / "calibration.json").write_text(json.dumps({"parameters": ["specular", "roughness", "subsurface"]}))
    args = ["calibrate", str(OBSERVATIONS), "--quick", "--parameters", "light_factor", "--out", str(out)]
    r = runner.invoke(app, args)
    assert_user_error(r, "option --out", "holds a calibration of specular, roughness, subsurface", "--no-resume")
    # nothing grown or rendered (a first import in a fresh process may make the folder for its kernels)
    assert not any((tmp_path / "cache").rglob("*.npz"))


def test_calibrate_rerun_over_a_result_written_before_the_record_compares_what_it_kept(tmp_path, monkeypatch):
    """An --out from before calibrate recorded its observations and start (settings.json without
    'calibration') was replaced without any comparison (a review): its calibration.json's series,
    method and likelihood are compared instead, and the rest is said to be unchecked."""
    from lightfit.cli.options import ModelOptions, resolve
    from lightfit.inference.likelihood import likelihood_form

    monkeypatch.setenv("LIGHTFIT_CACHE", str(tmp_path / "cache"))
    out = tmp_path / "cal"
    out.mkdir()
    config = resolve(ModelOptions(quick=True)).as_dict()
    (out / "settings.json").write_text(json.dumps({"config": config}))
    (out / "history.jsonl").write_text("")
    old = {
        "parameters": ["light_factor"],
        "method": "lbfgsb",
        "use": ["plant_par"],
        "likelihood": likelihood_form("model", 1.0),
    }
    (out / "calibration.json").write_text(json.dumps(old))
    args = ["calibrate", str(OBSERVATIONS), "--quick", "--parameters", "light_factor", "--no-surrogate"]
    r = runner.invoke(app, [*args, "--out", str(out)])
    assert_user_error(r, "calibration.json", "other use (['plant_par'] → ['above_canopy_par'])", "--no-resume")
    assert "calibration.json was written before lightfit recorded" in " ".join(r.output.split())
    assert "resuming without comparing them (the rest compared)" in " ".join(r.output.split())
    # a result of the surrogate (it has a surrogate record) is not resumed by full renders
    (out / "calibration.json").write_text(json.dumps({**old, "use": ["above_canopy_par"], "surrogate": {}}))
    r = runner.invoke(app, [*args, "--out", str(out)])
    assert_user_error(r, "calibration.json", "other surrogate (True → False)")
    assert not any((tmp_path / "cache").rglob("*.npz"))  # refused before anything grew or rendered


def test_use_help_names_every_observed_series():
    from lightfit.inference.observations import SERIES

    for command in ("calibrate", "posterior"):
        opt = next(p for p in typer.main.get_command(app).commands[command].params if p.name == "use")
        missing = [s.name for s in SERIES if s.name not in opt.help]
        assert not missing, (command, missing)


def test_fewer_bounces_than_the_leafs_default_get_a_caution(monkeypatch):
    """--bounces below the leaf's 1 % order says what it leaves out (the bound of
    lightfit.light.estimator.truncation_bound, written out here: ρ^(b+1) / (1 − ρ)); the default
    and more orders say nothing."""
    from lightfit.cli import common
    from lightfit.cli.options import ModelOptions, resolve
    from lightfit.light.bsdf import lobe_weights
    from lightfit.replication import ReplicationConfig

    optics = ReplicationConfig.quick().leaf_optics()
    rho = max(sum(lobe_weights(optics.specular, optics.subsurface, optics.base_color)), optics.soil_albedo)
    said = []
    monkeypatch.setattr(common, "caution", said.append)
    for bounces, expected in ((0, f"up to {rho / (1 - rho):.1%} of the unscattered light"), (2, None), (None, None)):
        said.clear()
        resolve(ModelOptions(quick=True, bounces=bounces))
        assert (len(said) == 1 and expected in said[0]) if expected else said == [], (bounces, said)
    # --quick's 2 bounces under the paper's grey leaf (8 for 1 %) truncate too: said (it was silent)
    grey = ReplicationConfig.quick().with_preset("paper").leaf_optics()
    rho = max(sum(lobe_weights(grey.specular, grey.subsurface, grey.base_color)), grey.soil_albedo)
    said.clear()
    resolve(ModelOptions(quick=True, preset="paper"))
    assert len(said) == 1 and said[0].startswith("--quick's 2 bounces") and "(--bounces 8)" in said[0], said
    assert f"up to {rho**3 / (1 - rho):.1%} of the unscattered light" in said[0], said


def test_theta_from_a_calibration_a_posterior_summary_or_text(tmp_path):
    """--theta takes a calibration's theta, a posterior summary's MAP (without its noise scale), or
    key=value text; errors about the file name the option."""
    from lightfit.cli.common import parse_theta

    cal = tmp_path / "calibration.json"
    cal.write_text(json.dumps({"theta": {"specular": 0.5, "light_factor": 1.2}, "loss": 3.0}))
    assert parse_theta(str(cal)) == {"specular": 0.5, "light_factor": 1.2}
    # the run says which values it used, and from where (only the figure and results.nc said it)
    r = runner.invoke(app, ["replicate", "--quick", "--steps", "14:16", "--theta", str(cal), "--out", str(tmp_path)])
    assert r.exit_code == 0, r.output
    assert f"parameters (--theta): specular=0.5, light_factor=1.2 (from {cal})" in _flat(r.stdout)
    post = tmp_path / "summary.json"
    x_map = {"specular": 0.46, "roughness": 1.0, "light_factor": 1.04, "noise_scale": 1.3}
    post.write_text(json.dumps({"names": list(x_map), "x_map": x_map, "mean": {"specular": 0.6}}))
    assert parse_theta(str(post)) == {"specular": 0.46, "roughness": 1.0, "light_factor": 1.04}
    assert parse_theta("roughness=0.7,vcmax_scale=1.1") == {"roughness": 0.7, "vcmax_scale": 1.1}
    other = tmp_path / "other.json"
    other.write_text(json.dumps({"names": ["a"]}))
    r = runner.invoke(app, ["replicate", "--quick", "--theta", str(other), "--out", str(tmp_path / "o")])
    assert r.exit_code == 2 and "other.json: option --theta: unknown parameter(s) ['names']" in _flat(r.stderr)
    # calibrate's --start takes the same files; its errors named "column 'theta'" (a review)
    obs = ["calibrate", str(OBSERVATIONS), "--quick", "--out", str(tmp_path / "c"), "--start", str(other)]
    r = runner.invoke(app, obs)
    assert r.exit_code == 2 and "other.json: option --start: unknown parameter(s) ['names']" in _flat(r.stderr)
    # Files that hold no parameters, and repeated names, are refused naming the file or option (a
    # list gave an AttributeError traceback, Latin-1 bytes a UnicodeDecodeError, a folder "Is a
    # directory"; a repeated name took its last value).
    (tmp_path / "list.json").write_text("[0.5, 0.4]")
    (tmp_path / "latin1.json").write_bytes(b'{"specular": 0.5, "caf\xe9": 1}')
    (tmp_path / "theta_list.json").write_text(json.dumps({"theta": [0.5]}))
    (tmp_path / "folder").mkdir()
    for value, words in (
        (str(tmp_path / "list.json"), ["list.json", "--theta", "holds a JSON list"]),
        (str(tmp_path / "latin1.json"), ["latin1.json", "--theta", "not JSON"]),
        (str(tmp_path / "theta_list.json"), ["theta_list.json", "its theta is a JSON list"]),
        (str(tmp_path / "folder"), ["folder", "--theta", "cannot be read"]),
        (str(tmp_path / "missing.json"), ["--theta", "no file", "missing.json"]),
        ("specular=0.5,specular=0.6", ["--theta", "specular given more than once"]),
    ):
        r = runner.invoke(app, ["replicate", "--quick", "--theta", value, "--out", str(tmp_path / "o")])
        assert_user_error(r, *words)


def test_theta_from_a_file_is_cautioned_where_it_may_not_hold(tmp_path):
    """replicate --theta said nothing of a calibration that stopped at its step limit, a posterior whose
    walkers disagree, or a fit made with another leaf or photosynthesis set (a newcomer's audit); a
    posterior summary written by --no-analysis has no MAP and is refused saying so (its keys were
    reported as unknown parameters)."""
    from lightfit.cli.common import parse_theta, theta_cautions

    run = {"optics": "prospect", "photosynthesis": "winter_wheat", "chlorophyll_ug_cm2": None, "weather_file": None}
    cal = tmp_path / "calibration.json"
    # settings as the run takes them: unset is the default (50.5), a file is its name wherever it lies
    same = {"chlorophyll_ug_cm2": 50.5, "weather_file": "/data/SE_EC_001.csv"}
    fit = {"theta": {"specular": 0.5}, "converged": True, "config": dict(run) | same}
    cal.write_text(json.dumps(fit))
    assert theta_cautions(str(cal), run | {"weather_file": "../SE_EC_001.csv"}) == []
    (said,) = theta_cautions(str(cal), run | {"chlorophyll_ug_cm2": 40.0, "weather_file": "../SE_EC_001.csv"})
    assert "fitted with chlorophyll_ug_cm2 50.5; this run has chlorophyll_ug_cm2 40.0" in said, said
    # A run's settings as it takes them (ModelSettings.effective) against a fit recorded so, or
    # recorded as given by an older lightfit (null for the defaults, "auto"): the same settings, no
    # caution (the set's 15 °C against null, the bundled weather by name against null, said before).
    from lightfit.cli.options import ModelOptions, resolve

    taken = resolve(ModelOptions(quick=True)).effective()
    older = resolve(ModelOptions(quick=True)).as_dict() | {"vcmax_profile": "auto"}
    for config in (taken, older):
        cal.write_text(json.dumps({"theta": {"specular": 0.5}, "config": config}))
        assert theta_cautions(str(cal), taken) == [], config
    warm = resolve(ModelOptions(quick=True, growth_temperature_c="9")).effective()
    (said,) = theta_cautions(str(cal), warm)
    assert "fitted with growth_temperature_c 15.0; this run has growth_temperature_c 9.0" in said, said
    fit["config"] = dict(run)
    assert theta_cautions("specular=0.5", run) == [] and theta_cautions(None, run) == []
    fit |= {"converged": False, "stopped_by": "max_steps", "reason": "step limit: 2 accepted steps"}
    fit["config"] |= {"optics": "paper", "photosynthesis": "giraud2023"}
    cal.write_text(json.dumps(fit))
    said = theta_cautions(str(cal), run)
    assert len(said) == 2, said
    assert "did not converge (max_steps: step limit: 2 accepted steps)" in said[0]
    then = "fitted with optics paper, chlorophyll_ug_cm2 not used, photosynthesis giraud2023; "
    assert then + "this run has optics prospect, chlorophyll_ug_cm2 50.5, photosynthesis winter_wheat" in said[1]
    post = tmp_path / "post"
    post.mkdir()
    summary = {"names": ["specular", "roughness"], "stopped_by": "max_steps", "rhat": [1.01, 7.7], "tau": [1, 1]}
    (post / "summary.json").write_text(json.dumps(summary))
    with pytest.raises(InputError, match=r"without its analysis \(written by --no-analysis\): it has no MAP"):
        parse_theta(str(post / "summary.json"))
    summary["x_map"] = {"specular": 0.5, "roughness": 0.6}
    (post / "summary.json").write_text(json.dumps(summary))
    (said,) = theta_cautions(str(post / "summary.json"), run)
    assert "the walkers disagree (split-R̂ 7.7 for roughness" in said, said
    # a summary whose diagnostics are malformed is said so, not a traceback (a review)
    for broken in ({"chi2_map": 3.0}, {"rhat": [1.0, 1.0, 9.0]}, {"prior_support": {"specular": 0.5}}):
        (post / "summary.json").write_text(json.dumps(summary | {"rhat": [1.0, 1.0]} | broken))
        (said,) = theta_cautions(str(post / "summary.json"), run)
        assert "are not those lightfit posterior writes" in said, (broken, said)


def test_ctrl_c_inside_a_render_exits_130_on_one_line(tmp_path, monkeypatch, caplog):
    """Ctrl-C while Mitsuba renders (inside the JAX host callback of lightfit.light.bridge): exit
    130 and the interrupt line, without the traceback JAX logs for the callback's exception
    ("jax.pure_callback failed", ≈ 40 lines on stderr before the interrupt line; pytest captures
    logs, hence caplog) and without the re-raised error's (tests/test_interrupts.py)."""
    from lightfit.light.estimator import SegmentEstimator

    def interrupted(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(SegmentEstimator, "render", interrupted)
    r = runner.invoke(app, ["replicate", "--quick", "--out", str(tmp_path / "o")])
    assert r.exit_code == 130, r.output
    said = " ".join(r.stderr.split())
    assert said.startswith("interrupted: every rendered step is kept in --out") and said.count("interrupted") == 1, said
    assert "pure_callback failed" not in caplog.text and "KeyboardInterrupt" not in caplog.text


def test_an_per_leaf_is_named_in_the_caption_and_the_summary_file(tmp_path):
    """--an-per leaf: the printed caption said "APAR, An: per ground area" and summary.csv's
    canopy_an_umol_m2_s could not tell per what (a CLI review); results.nc says it in an_per."""
    import re

    import pandas as pd

    out = tmp_path / "o"
    r = runner.invoke(app, ["replicate", "--quick", "--steps", "14:16", "--an-per", "leaf", "--out", str(out)])
    assert r.exit_code == 0, r.output
    assert "An: per leaf area" in _flat(r.stdout) and "An: per ground" not in _flat(r.stdout)
    cols = pd.read_csv(out / "summary.csv", comment="#").columns
    assert "canopy_an_per_leaf_area_umol_m2_s" in cols and "canopy_an_umol_m2_s" not in cols
    assert "canopy_apar_umol_m2_s" in cols  # APAR stays per ground area
    # The printed table: each row's fAPAR and An are summary.csv's, with 2 and 1 decimals (SUMMARY_HEADS,
    # written out; a mutation audit: fAPAR printed with no decimals, 0 or 1, survived).
    table = pd.read_csv(out / "summary.csv", comment="#")
    rows = {x.split()[0]: x.split() for x in r.stdout.splitlines() if x.split()[:1] in (["12:00"], ["12:30"])}
    assert list(rows) == list(table["local_time"]), r.stdout
    for _, row in table.iterrows():  # local sun° PAR↑ PARpl ± APAR fAPAR An ...
        fapar, an = rows[row["local_time"]][6:8]
        assert re.fullmatch(r"\d\.\d\d", fapar) and abs(float(fapar) - row["fapar"]) <= 0.0051, (fapar, row)
        assert re.fullmatch(r"-?\d+\.\d", an) and abs(float(an) - row["canopy_an_per_leaf_area_umol_m2_s"]) <= 0.051, an


def test_an_per_leaf_refuses_observations_of_canopy_an_per_ground_area_before_running(tmp_path):
    """The bundled twin's canopy An is per ground area (its file unsaid: a chamber's area); with
    --an-per leaf it met the model's per-leaf-area An unsaid (a review). Refused before plants grow."""
    twin = DATA_DIR / "observations" / "twin_2016-04-20_synthetic.csv"
    for cmd in (["replicate", "--observations", str(twin)], ["calibrate", str(twin)], ["posterior", str(twin)]):
        r = runner.invoke(app, [*cmd, "--quick", "--an-per", "leaf", "--out", str(tmp_path / "o")])
        assert_user_error(r, "twin_2016-04-20_synthetic.csv", "canopy An per ground area", "--an-per ground")
        assert "running" not in _flat(r.stdout)


def test_a_thinned_weather_table_says_so():
    """`weather show` prints every k-th row of a long file: the caption says so (10-minute rows
    looked like 30-minute data; a CLI review)."""
    import pandas as pd

    from lightfit.cli.common import weather_table

    t = pd.date_range("2016-04-20", periods=144, freq="10min", tz="UTC")
    df = pd.DataFrame({"par_umol_m2_s": np.arange(144.0), "tair_c": 10.0}, index=t)
    thinned = weather_table(df, "w", max_rows=40)
    assert thinned.row_count == 48 and "1 row in 3 of 144 shown" in str(thinned.caption)
    whole = weather_table(df.iloc[:30], "w", max_rows=40)
    assert whole.row_count == 30 and "shown" not in str(whole.caption)


@pytest.mark.parametrize(
    "args, words",
    [
        (["field", "--quick", "--segments", "DIR"], ["option --segments", "is a folder"]),
        (["field", "--quick", "--preview", "DIR"], ["option --preview", "is a folder"]),
        (["weather", "show", "DIR"], ["a folder, not a file", "bundled names"]),
        (["render-dataset", "DIR", "--out", "DIR/ds"], ["a folder, not a file", "a netCDF written by the coupled"]),
    ],
)
def test_a_folder_where_a_file_is_read_or_written_is_named(args, words, tmp_path):
    """A folder given for a file: "Is a directory" after the plants grew, or "no such weather file"
    (a CLI review); now refused first, naming the option."""
    r = runner.invoke(app, [a.replace("DIR", str(tmp_path)) for a in args])
    assert_user_error(r, *words)


@pytest.mark.parametrize(
    "args, words",
    [
        (
            ["replicate", "--quick", "--observations", "XLSX"],
            ["a ZIP archive", "Excel .xlsx", "export the sheet as CSV"],
        ),
        (["calibrate", "XLSX", "--quick"], ["not text", "expected an observations CSV"]),
        (["replicate", "--quick", "--weather", "XLSX"], ["a ZIP archive", "expected a weather file"]),
        (["weather", "show", "PNG"], ["the file is a PNG image, not text", "expected a weather file"]),
    ],
)
def test_a_spreadsheet_or_image_given_for_a_csv_is_called_what_it_is(args, words, tmp_path):
    """An Excel workbook (or a PNG) given for a CSV was refused as "line 3: byte 0x.. is not UTF-8 text
    (the file is in another encoding, e.g. Latin-1) (expected a UTF-8 file: save it as UTF-8)", which
    sends a user to re-save a spreadsheet's encoding (a review of bad input); now named from its
    signature, before anything runs."""
    import zipfile

    xlsx, png = tmp_path / "book.xlsx", tmp_path / "plot.png"
    with zipfile.ZipFile(xlsx, "w", zipfile.ZIP_STORED) as z:  # stored: the sheet's bytes as they are
        z.writestr("xl/worksheets/sheet1.xml", bytes(range(256)) * 4)
    png.write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(range(256)))
    args = [{"XLSX": str(xlsx), "PNG": str(png)}.get(a, a) for a in args]
    r = runner.invoke(app, [*args, *(["--out", str(tmp_path / "out")] if args[0] != "weather" else [])])
    assert_user_error(r, *words)
    assert "UTF-8" not in r.stderr and not (tmp_path / "out").exists()


def test_replicate_says_when_it_replaces_results_made_with_other_settings(tmp_path, monkeypatch):
    """A quick test run into the main job's folder replaced its 100-plant results unsaid (a
    newcomer's review); now one line names what differs, as the results record the settings
    (resolved: a library run's "auto" is the command's resolved value). The same command again says
    nothing."""
    out = ["--out", str(tmp_path / "r")]
    first = runner.invoke(app, ["replicate", "--quick", "--steps", "14:16", *out])
    assert first.exit_code == 0 and "replacing" not in first.output, first.output
    again = runner.invoke(app, ["replicate", "--quick", "--steps", "14:16", *out])
    assert again.exit_code == 0 and "replacing" not in again.output, again.output
    other = runner.invoke(app, ["replicate", "--quick", "--steps", "14:15", "--theta", "specular=0.6", *out])
    assert other.exit_code == 0, other.output
    text = " ".join(other.output.split())
    assert "note: replaced the results in" in text and "(theta_specular 0.5 → 0.6, 2 steps → 1)" in text, text
    bigger = runner.invoke(app, ["replicate", "--quick", "--steps", "14:15", "--samples", "8", *out])
    text = " ".join(bigger.output.split())
    assert "(samples 16 → 8, theta_specular 0.6 → 0.5)" in text, text
    # settings as resolved: the library's run of the same model (its config says "auto") is no change
    from lightfit import replication as rep

    w = rep.forcing()
    lib = tmp_path / "lib"
    rep.run(rep.ReplicationConfig.quick(), forcing_df=w.iloc[14:16], out=lib)
    assert not (lib / rep.UNFINISHED).exists()  # the run's kept steps go with its end
    # ... which it kept while it ran: a folder given is the caller's, and holds the two daytime steps
    rep.run(rep.ReplicationConfig.quick(), forcing_df=w.iloc[14:16], out=tmp_path / "kept", keep_steps=tmp_path / "k")
    assert len(list((tmp_path / "k").glob("*.npz"))) == 2
    # ... and keeps none with keep_steps=False (the library could not opt out)
    given = []
    real = rep.model_for
    monkeypatch.setattr(rep, "model_for", lambda *a: given.append(a[3]) or real(*a))
    rep.run(rep.ReplicationConfig.quick(), forcing_df=w.iloc[14:15], out=tmp_path / "nokeep", keep_steps=False)
    assert given == [None] and not (tmp_path / "nokeep" / rep.UNFINISHED).exists()
    monkeypatch.undo()
    # The library's folder is the command's: the forcing it ran on too (written by the command alone before)
    f = read_weather(lib / "forcing.csv")
    np.testing.assert_array_equal(f.index, w.index[14:16])
    np.testing.assert_allclose(f[w.columns].to_numpy(float), w.iloc[14:16].to_numpy(float), rtol=1e-7, atol=1e-9)
    assert f.attrs["provenance"] == w.attrs["provenance"] == "reconstructed"
    assert f.attrs["metadata"]["note"] == (
        "2 steps, 2016-04-20 12:00 … 12:30, steps 14:16 of 2016-04-20 05:00 + 14 h (Europe/Berlin), 30min steps, "
        "Selhausen (sample)"
    )
    one = "2016-04-20 12:00, step 14 of 2016-04-20 05:00 + 14 h (Europe/Berlin), 30min steps"
    assert rep.describe_steps(rep.ReplicationConfig.quick(), w.iloc[14:15]) == one  # was "12:00 … 12:00, steps 14:15"
    written = {n: (lib / n).read_bytes() for n in ("forcing.csv", "forcing.png", "summary.csv")}
    same = runner.invoke(app, ["replicate", "--quick", "--steps", "14:16", "--out", str(lib)])
    assert same.exit_code == 0 and "replaced" not in same.output, same.output
    assert {n: (lib / n).read_bytes() for n in written} == written
    assert not (lib / rep.UNFINISHED).exists()
    # the weather is a setting: another file is said
    dim = tmp_path / "dim.csv"
    dim.write_text((tmp_path / "lib" / "forcing.csv").read_text())
    args = ["replicate", "--quick", "--weather", str(dim), "--start-time", "12:00", "--hours", "0.5"]
    moved = runner.invoke(app, [*args, "--out", str(tmp_path / "lib")])
    text = " ".join(moved.output.split())
    assert "weather_source" in text and "dim.csv" in text, text  # a file by its name
    assert "window 2016-04-20 05:00 + 14 h (Euro" in text, text  # not cut at the zone's "/" as a path


def test_every_model_setting_is_compared_on_resume_and_old_records_read_as_they_ran():
    """A mutation audit: `split` dropped from MODEL_SETTINGS, and wrong 'before' literals for the
    soil respiration's Q10 or the window's start, all survived. Every ModelSettings field is a
    compared setting but the labels that change no number (listed here); a record written before
    the later options existed compares equal to the same run today, and a real change against the
    literal it ran with (Q10 2, 05:00, …, the 20 April 2016 day) is named."""
    import dataclasses

    from lightfit.cli.options import MODEL_SETTINGS, ModelOptions, ModelSettings, changed_settings, resolve

    labels = {"preset", "quick", "weather_provenance"}  # what a run is called or where its weather came from
    fields = {f.name for f in dataclasses.fields(ModelSettings)}
    assert fields - set(MODEL_SETTINGS) == labels, fields - set(MODEL_SETTINGS)
    erbs = resolve(ModelOptions(quick=True, split="erbs"))
    assert changed_settings(erbs.as_dict(), resolve(ModelOptions(quick=True, split="boland"))) == [
        "split: 'erbs' → 'boland'"
    ]
    now = resolve(ModelOptions(quick=True))
    old = now.as_dict()
    for key in ("soil_respiration", "soil_respiration_q10", "dates", "start_time", "hours", "step", "site"):
        old.pop(key)  # a record from before these were options
    assert changed_settings(old, now) == []
    q10 = resolve(ModelOptions(quick=True, soil_respiration_q10=2.3))
    assert changed_settings(old, q10) == ["soil_respiration_q10: 2.0 → 2.3"]
    later = resolve(ModelOptions(quick=True, start_time="06:00"))
    assert changed_settings(old, later) == ["start_time: '05:00' → '06:00'"]


def test_runs_record_the_settings_they_take_and_older_records_still_compare():
    """A run's record (calibration.json, settings.json, run.h5) held the options as given: null where
    the run took the leaf's 50.5 µg cm⁻² of chlorophyll, the leaf's bounces, the set's growth
    temperature, the bundled weather, … (a review). ModelSettings.effective holds what the run takes,
    from the objects it is made of; a record written before (nulls, --steps 5) still compares equal to
    the same run, and a change is named with the value taken."""
    from lightfit.cli.options import ModelOptions, changed_settings, resolve, weather
    from lightfit.light.leaf_optics import LeafTraits

    main = resolve(ModelOptions())  # the main job: bounces left to the leaf's rule
    took = main.effective()
    expect = {"chlorophyll_ug_cm2": LeafTraits().Cab, "bounces": 2, "growth_temperature_c": 15.0, "samples": 32}
    expect |= {"direct": "projection", "vcmax_profile": "lloyd2010", "buffer_rows": 0, "buffer_along": 0}
    expect |= {"weather_file": "2016-04-20", "season_start": "2016-03-05", "steps": "0:29"}
    assert {k: took[k] for k in expect} == expect
    paper = resolve(ModelOptions(preset="paper")).effective()  # the grey leaf has no chlorophyll, giraud2023 no T_g
    expect = {"chlorophyll_ug_cm2": None, "bounces": 8, "growth_temperature_c": None, "samples": 64}
    expect |= {"direct": "paths", "vcmax_profile": "uniform", "buffer_rows": 2, "buffer_along": 2, "preset": "paper"}
    assert {k: paper[k] for k in expect} == expect
    # the forcing says how its file was read
    five = resolve(ModelOptions(quick=True, steps="5"))
    w = weather(five)
    read = five.effective(w)
    assert (read["weather_provenance"], read["weather_tz"], read["split"], read["steps"]) == (
        "reconstructed",
        "UTC",
        "diffuse",
        "0:5",
    )
    # an older record (as given) and a new one both resume the same run; a change is named as taken
    for record in (five.as_dict(), read):
        assert changed_settings(record, five, w=w) == [], record
    assert changed_settings(main.as_dict(), resolve(ModelOptions(bounces=3))) == ["bounces: None → 3"]
    assert changed_settings(took, resolve(ModelOptions(bounces=3))) == ["bounces: 2 → 3"]
    assert changed_settings(took, resolve(ModelOptions(chlorophyll_ug_cm2=40.0))) == ["chlorophyll_ug_cm2: 50.5 → 40.0"]
    assert changed_settings(took, resolve(ModelOptions(chlorophyll_ug_cm2=50.5))) == []  # the default, given


def test_runs_record_the_plants_the_field_builds():
    """config recorded n_plants as asked: 5, where the field builds 3 × 3 (a review). The record holds
    the plants the field builds, the number asked stays in options_given, and records written before
    and new ones resume the same run."""
    from lightfit.cli.options import ModelOptions, changed_settings, resolve

    opts = ModelOptions(quick=True, n_plants=5)
    five = resolve(opts)
    took = five.effective()
    built = int(five.replication_config().field().plants()["measured"].sum())
    assert took["n_plants"] == built != 5 and opts.args() == ["--quick", "--n-plants", "5"]
    for record in (five.as_dict(), took):
        assert changed_settings(record, five) == [], record
    assert changed_settings(took, resolve(ModelOptions(quick=True, n_plants=built))) == []  # the same field
    # one plant more builds the next square, 4 × 4: both the plants and the rows' length change
    said = changed_settings(took, resolve(ModelOptions(quick=True, n_plants=built + 1)))
    assert said == [f"n_plants: {built} → 16", "plants_per_row: 3 → 4"], said


def test_runs_record_no_rays_where_the_paths_carry_the_direct_light():
    """config recorded the projection's rays per m² where the direct light came from the paths, which
    cast none (a review): null there now. Records written before (the default's rays, or no key) and
    new ones resume the same run; a change of direct light names the rays it brings."""
    from lightfit.cli.options import ModelOptions, changed_settings, resolve

    finite = resolve(ModelOptions(quick=True, boundary="finite"))  # direct light from the paths
    took = finite.effective()
    assert took["direct"] == "paths" and took["direct_rays_per_m2"] is None
    assert finite.as_dict()["direct_rays_per_m2"] is not None  # what records held before
    for record in (finite.as_dict(), took, {k: v for k, v in took.items() if k != "direct_rays_per_m2"}):
        assert changed_settings(record, finite) == [], record
    periodic = resolve(ModelOptions(quick=True))
    rays = list(periodic.direct_rays_per_m2)
    assert periodic.effective()["direct_rays_per_m2"] == rays
    assert f"direct_rays_per_m2: None → {rays!r}" in changed_settings(took, periodic)


def test_runs_record_the_time_label_their_weather_was_read_with():
    """config recorded weather_time_label null where the file's own '# time_label:' line or the
    reader's convention (a TERENO export's stamps at the ends of its means) was applied (a review):
    the label applied is recorded, also where averaging relabels the run's steps; a record as given
    (null) and one as taken resume the same run."""
    from lightfit.cli.options import ModelOptions, changed_settings, resolve, weather
    from lightfit.weather import timestamps
    from lightfit.weather.bundled import source_path

    lines = source_path("2016-04-20").read_text(encoding="utf-8").splitlines()
    (own,) = [x.split(":", 1)[1].strip() for x in lines if x.startswith("# time_label:")]
    runs = [(resolve(ModelOptions(quick=True, how=how, steps="14:16")), own) for how in ("sample", "mean")]
    # the fixture says nothing: a TERENO logger's stamps close its means ("end"), or the option
    for given, label in ((None, "end"), ("start", "start")):
        opts = ModelOptions(quick=True, weather_file=str(FIXTURE), steps="12:18", weather_time_label=given)
        runs.append((resolve(opts), label))
    for s, label in runs:
        w = weather(s)
        took = s.effective(w)
        assert took["weather_time_label"] == label is not None, (s.how, s.weather_file)
        for record in (s.as_dict(), took):
            assert changed_settings(record, s, w=w) == [], record
    assert timestamps.of(weather(runs[1][0])).label != own  # the mean's steps: labelled anew


def test_field_tile_past_the_last_is_refused_before_growing(tmp_path, monkeypatch):
    """--tiles 2 makes tiles 0 and 1: --tile 2 (one past the last) and --tile -1 are refused naming
    --tile and the range, before any plant grows (one past the last would reach an IndexError)."""
    monkeypatch.setenv("LIGHTFIT_CACHE", str(tmp_path / "cache"))
    for tile in ("2", "-1"):
        r = runner.invoke(app, ["field", "--n-plants", "4", "--tiles", "2", "--tile", tile])
        assert_user_error(r, "--tile", f"tile {tile} does not exist", "0 … 1")
    assert not (tmp_path / "cache").exists()


def test_field_reports_each_tiles_plants_and_the_overhead(tmp_path, monkeypatch):
    """2×2 measured plants, one buffer row (a 4×4 grid), 2 tiles: each tile measures one column of 2
    plants and renders 4 rows × 3 columns = 12, so 2+10 each and 24 rendered ÷ 4 measured = ×6.00
    (by hand, as Field.tiles defines the ring)."""
    monkeypatch.setenv("LIGHTFIT_CACHE", str(tmp_path / "cache"))
    r = runner.invoke(app, ["field", "--n-plants", "4", "--boundary", "finite", "--buffer-rows", "1", "--tiles", "2"])
    assert r.exit_code == 0, r.output
    out = _flat(r.stdout)
    assert "tiles (measured+buffer plants), overhead ×6.00" in out and "2+10, 2+10" in out, out


def test_field_segments_of_one_tile_say_the_tile(tmp_path, monkeypatch):
    """--tile K --segments writes tile K's scene: its measured plants are the tile's (Field.tiles), the
    rest of the field's measured plants its buffer; the header says which tile (it said only the
    field, so the table read as the whole field's with half its measured plants unmeasured)."""
    from lightfit.plant import Field

    monkeypatch.setenv("LIGHTFIT_CACHE", str(tmp_path / "cache"))
    csv = tmp_path / "t.csv"
    args = ["field", "--n-plants", "4", "--boundary", "finite", "--buffer-rows", "1", "--tiles", "2", "--tile", "1"]
    r = runner.invoke(app, [*args, "--segments", str(csv)])
    assert r.exit_code == 0, r.output
    seg = pd.read_csv(csv, comment="#")
    want = Field(4, buffer_rows=1, boundary="finite").tiles(2)[1].measured
    np.testing.assert_array_equal(np.unique(seg.loc[seg["measured"], "plant_id"]), want)
    head = [ln for ln in csv.read_text().splitlines() if ln.startswith("#")]
    assert "# tile: 1 of 2 (0-based)" in head and "# n_plants: 4" in head, head
    assert any("measured True for a plant the tile measures" in ln for ln in head), head


def test_info_lists_the_installed_versions():
    """Each package's row holds the version importlib.metadata reports; the CUDA row says True or False."""
    import importlib.metadata

    r = runner.invoke(app, ["info"])
    assert r.exit_code == 0, r.output
    rows = {}
    for line in r.stdout.splitlines():
        cells = [c.strip() for c in line.split("│")[1:-1]]
        if len(cells) == 2:
            rows[cells[0]] = cells[1]
    for pkg in ("mitsuba", "drjit", "jax", "jaxlib", "numpy", "pandas", "xarray", "pvlib", "emcee", "trimesh"):
        assert rows.get(pkg) == importlib.metadata.version(pkg), (pkg, rows.get(pkg))
    assert rows["python"] == sys.version.split()[0]
    assert rows["CUDA usable"] in ("True", "False")


def test_render_dataset_options_reach_the_dataset_spec(tmp_path, monkeypatch):
    """Each render-dataset option lands in its DatasetSpec field (make_dataset is stood in for): the
    sweep's distance and elevation not swapped, --seed the render's seed, --no-depth off, and so on."""
    import lightfit.dataset

    specs = []

    def fake_make_dataset(results, out, spec):
        specs.append((results, out, spec))
        return {
            "images": [],
            "cameras_taken_over": 0,
            "cameras_discarded": 0,
            "quantities": {},
            "render": {"variant": "v", "spp": spec.settings.spp},
        }

    monkeypatch.setattr(lightfit.dataset, "make_dataset", fake_make_dataset)
    results, out = tmp_path / "results.nc", tmp_path / "ds"
    args = ["render-dataset", str(results), "--out", str(out), "--sweep", "3", "--sweep-distance-m", "2.5"]
    args += ["--sweep-elevation-deg", "20", "--width", "40", "--height", "30", "--fov-deg", "50"]
    args += ["--exposure-mode", "scene", "--exposure-ev", "-1", "--meter-percentile", "90"]
    args += ["--time", "2016-04-20T11:00", "--time", "2016-04-20T12:00", "-q", "an", "-q", "vc", "--spp", "3"]
    args += ["--max-depth", "5", "--colour", "mono", "--seed", "7", "--threads", "2", "--weather", "2016-04-20"]
    args += ["--no-depth", "--gallery", "1", "--export", "vtk", "--cache-dir", str(tmp_path / "plants")]
    r = runner.invoke(app, args)
    assert r.exit_code == 0, r.output
    ((res, where, spec),) = specs
    assert (res, where) == (results, out)
    assert (spec.sweep.n, spec.sweep.distance_m, spec.sweep.elevation_deg) == (3, 2.5, 20.0)
    cam = spec.sweep.camera
    assert (cam["width_px"], cam["height_px"], cam["fov_deg"]) == (40, 30, 50.0)
    assert (cam["exposure_mode"], cam["exposure_ev"], cam["meter_percentile"]) == ("scene", -1.0, 90.0)
    assert spec.times == ["2016-04-20T11:00", "2016-04-20T12:00"] and spec.quantities == ("an", "vc")
    s = spec.settings
    assert (s.spp, s.max_depth, s.colour, s.seed, s.threads) == (3, 5, "mono", 7, 2)
    assert (spec.weather, spec.depth, spec.gallery_images, spec.export) == ("2016-04-20", False, 1, "vtk")
    assert spec.cache_dir == str(tmp_path / "plants") and spec.cameras == []
    specs.clear()
    assert runner.invoke(app, ["render-dataset", str(results), "--out", str(out), "--all-times"]).exit_code == 0
    assert specs[0][2].times == ["all"] and specs[0][2].quantities is None and specs[0][2].depth is True


@pytest.mark.parametrize("ev", ["1100", "-1100", "65"])
def test_render_dataset_refuses_an_exposure_beyond_64_stops_before_reading_the_results(ev, tmp_path):
    """2.0 ** 1100 (the gain of --exposure-ev 1100) was an OverflowError traceback after the renders,
    -1100 a gain of 0 (black images, unsaid); now refused with the sweep's other settings, first."""
    r = runner.invoke(app, ["render-dataset", str(tmp_path / "none.nc"), "--out", str(tmp_path / "ds")])
    assert_user_error(r, "results file not found")  # the results are read after the cameras are checked
    r = runner.invoke(
        app, ["render-dataset", str(tmp_path / "none.nc"), "--out", str(tmp_path / "ds"), "--exposure-ev", ev]
    )
    assert_user_error(r, "option --exposure-ev", "−64 … 64")


def test_a_run_over_other_steps_of_the_same_count_is_said_to_replace_them():
    """replaced_settings against the steps and settings written out by hand (a mutation audit: the
    steps compared only by their number survived): same count, other times → "other steps"; what
    says nothing about the settings (software versions) is not compared; nothing stored → None."""
    import xarray as xr

    from lightfit.cli.replicate import replaced_settings

    times = np.array(["2016-04-20T10:00", "2016-04-20T10:30"], "datetime64[ns]")
    before = ({"samples": 16, "software_versions": "{}"}, times)

    def ds(t, **attrs):
        return xr.Dataset(coords={"time": t}, attrs={"samples": 16, "software_versions": '{"jax": "x"}', **attrs})

    assert replaced_settings(before, ds(times)) is None
    assert replaced_settings(before, ds(times + np.timedelta64(10, "m"))) == "other steps"
    assert replaced_settings(before, ds(times[:1], samples=8)) == "samples 16 → 8, 2 steps → 1"
    assert replaced_settings(None, ds(times)) is None
    assert replaced_settings("unreadable", ds(times)) == "a file lightfit cannot read"


def test_calibrate_ctrl_c_says_what_each_mode_keeps(tmp_path, monkeypatch):
    """Ctrl-C in calibrate: the surrogate keeps design renders (its trust-region rounds are redone
    from them, not kept: a review found the line claiming so), --no-surrogate its history.jsonl
    (RESUMABLE; a mutation audit: the --no-surrogate line never said survived)."""
    import importlib

    def interrupted(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(importlib.import_module("lightfit.cli.calibrate"), "resolve", interrupted)
    args = ["calibrate", str(OBSERVATIONS), "--quick", "--out", str(tmp_path)]
    r = runner.invoke(app, [*args, "--no-surrogate"])
    assert r.exit_code == 130, r.output
    assert " ".join(r.stderr.split()) == (
        "interrupted: every accepted step is kept in --out's history.jsonl; rerun the same command to resume"
    )
    r = runner.invoke(app, args)
    said = " ".join(r.stderr.split())
    assert r.exit_code == 130 and "design cache" in said and "without rendering again" in said, r.output
    assert "trust_region" not in said


def test_option_named_only_for_a_files_error_without_a_line_about_an_option():
    """error_message (FILE_OPTIONS, written out by hand; a mutation audit: "and" taken for "or"
    survived): --tz on a CSV with no line is the option's error; a line of the file, or a metadata
    key of the file that is no option applied to it (time_label), stays the file's."""
    from lightfit.cli.common import error_message

    flags = {"tz": "--tz", "time_label": "--time-label"}
    tz = InputError("UTC+2 given for a lightfit CSV", file="w.csv", parameter="tz", expected="no --tz")
    assert error_message(tz, flags) == "w.csv: option --tz: UTC+2 given for a lightfit CSV (expected no --tz)"
    line = InputError("'Mars'", file="w.csv", row=5, column="tz")
    assert error_message(line, flags) == "w.csv, line 5, column 'tz': 'Mars'"
    own = InputError("'middle'", file="w.csv", column="time_label", expected="start, end or center")
    assert error_message(own, flags) == "w.csv, column 'time_label': 'middle' (expected start, end or center)"


def test_soil_respiration_note_only_for_nee_without_soil_respiration(capsys):
    """The note (docstring): NEE fitted with --soil-respiration 0; not for other series, nor with a
    soil respiration given (a mutation audit: either condition alone survived)."""
    from lightfit.cli.common import soil_respiration_note

    soil_respiration_note(("canopy_an", "plant_par"), 0.0)
    soil_respiration_note(("nee",), 1.5)
    assert capsys.readouterr().out == ""
    soil_respiration_note(("plant_par", "nee"), 0.0)
    assert "note: NEE is modelled without soil and root respiration" in " ".join(capsys.readouterr().out.split())


def test_replicate_notes_nee_compared_without_soil_respiration(tmp_path):
    """replicate compares chamber NEE with the model's, which leaves out soil and root respiration
    by default: it says so, as calibrate and posterior do (a plant physiologist's review: the
    default `nee` is minus the blades' net uptake)."""
    obs = tmp_path / "nee.csv"
    obs.write_text(
        "# provenance: synthetic\n# time_zone: Europe/Berlin\n"
        "time,nee_umol_m2_s,nee_sd_umol_m2_s\n2016-04-20 12:00,-20,2\n",
        encoding="utf-8",
    )
    note = "note: NEE is modelled without soil and root respiration"
    args = ["replicate", "--quick", "--steps", "14:16", "--observations", str(obs), "--out", str(tmp_path / "r")]
    r = runner.invoke(app, args)
    assert r.exit_code == 0 and note in _flat(r.stdout), r.output
    r = runner.invoke(app, [*args, "--soil-respiration", "1.5"])
    assert r.exit_code == 0 and note not in _flat(r.stdout), r.output


def test_replicate_says_how_the_model_meets_the_observations(tmp_path):
    """replicate prints each series' n, bias, RMSE and χ² against its observations (it printed only
    how many readings it compared), and cautions where χ² is beyond the readings' SDs; the values
    against results.nc are in ``test_replication.py::test_cli_replicate_quick_and_calibrate``."""
    import xarray as xr

    from lightfit.report import observations_fit

    obs = tmp_path / "par.csv"
    args = ["replicate", "--quick", "--steps", "14:16", "--observations", str(obs), "--out", str(tmp_path / "r")]
    caution = "the run leaves χ²"
    for sd, cautioned in ((1.0, True), (1e4, False)):  # the quick run: ≈ 240 at the plants at noon
        obs.write_text(
            "# provenance: synthetic\n# time_zone: Europe/Berlin\n"
            f"time,plant_par_umol_m2_s,plant_par_sd_umol_m2_s\n2016-04-20 12:00,100,{sd}\n",
            encoding="utf-8",
        )
        r = runner.invoke(app, args)
        assert r.exit_code == 0, r.output
        with xr.open_dataset(tmp_path / "r" / "results.nc") as ds:
            fit = observations_fit(ds).loc["plant_par"]
            model = float(ds["plant_par_umol_m2_s"].values[0])  # step 14 is 12:00
        assert fit.bias == pytest.approx(model - 100.0, rel=1e-6) and fit.bias > 100
        out = _flat(r.stdout)
        assert "model against the observations" in out and f"plant_par 1 {fit.bias:+.3g}" in out
        assert (caution in _flat(r.stderr)) is cautioned, r.stderr


def test_weather_show_prints_the_local_clock_of_the_site_given(monkeypatch):
    """--timezone UTC+3 (with coordinates): the table's local column is that zone's clock, UTC + 3 h
    on every row (a mutation audit: the table kept Selhausen's zone and this survived)."""
    import re

    from lightfit.cli import common

    # The console's width is fixed when it is made (COLUMNS given to invoke comes too late): a narrow
    # terminal cuts the stamps to "0…".
    monkeypatch.setattr(common.console, "_width", 200)
    args = ["weather", "show", str(FIXTURE), "--latitude", "50.87", "--longitude", "6.45", "--timezone", "UTC+3"]
    r = runner.invoke(app, args)
    assert r.exit_code == 0, r.output
    assert "UTC+3" in r.stdout
    # one UTC date: the clock alone in the table, the date in its caption (80 columns when piped)
    rows = re.findall(r"│ (\d\d):(\d\d) │ (\d\d):(\d\d) ", r.stdout)
    assert len(rows) > 20 and "UTC date 2016-04-20" in r.stdout
    for h, m, lh, lm in rows:
        assert (int(lh), lm) == ((int(h) + 3) % 24, m), (h, m, lh, lm)


def test_weather_show_how_sample_keeps_the_values_at_the_new_stamps(tmp_path):
    """--resample 30min --how sample (documented: the value at each new timestamp) against the file's
    own 10-min values at those stamps; --how mean averages them (a mutation audit: --how not reaching
    the resampling survived)."""
    csv, mean = tmp_path / "s.csv", tmp_path / "m.csv"
    base = ["weather", "show", str(FIXTURE), "--resample", "30min"]
    assert runner.invoke(app, [*base, "--how", "sample", "--csv", str(csv)]).exit_code == 0
    assert runner.invoke(app, [*base, "--csv", str(mean)]).exit_code == 0
    tenmin, sampled, averaged = read_weather(FIXTURE), read_weather(csv), read_weather(mean)
    assert (sampled.index[1:] - sampled.index[:-1] == pd.Timedelta("30min")).all()
    par = tenmin["par_umol_m2_s"]
    np.testing.assert_allclose(sampled["par_umol_m2_s"], par.loc[sampled.index], rtol=1e-6)
    assert not np.allclose(averaged["par_umol_m2_s"], par.reindex(averaged.index), rtol=1e-3, equal_nan=True)


def _calibration_out(tmp_path, monkeypatch, record: dict, history: str):
    """An --out holding a calibration of the quick model with ``record`` as its settings.json's
    calibration, and its history (``history.jsonl`` or the surrogate's ``trust_region/``); calibrate
    is stopped (Ctrl-C, exit 130) where it would build the model, after comparing the record."""
    import importlib

    from lightfit.cli.options import ModelOptions, resolve

    def stop(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(importlib.import_module("lightfit.cli.calibrate"), "run_model", stop)
    out = tmp_path / "cal"
    out.mkdir()
    config = resolve(ModelOptions(quick=True)).as_dict()
    (out / "settings.json").write_text(json.dumps({"config": config, "calibration": record}))
    if history == "trust_region":
        (out / history).mkdir()
    else:
        (out / history).write_text("")
    return out


def test_calibrate_compares_a_surrogate_runs_record_before_resuming_it(tmp_path, monkeypatch):
    """A surrogate calibration keeps trust_region/, not history.jsonl: its record is compared all the
    same, so other observations are refused (a mutation audit: only history.jsonl looked for survived);
    the model is never built here (run_model stops the run: exit 130 had the check been skipped)."""
    out = _calibration_out(tmp_path, monkeypatch, {"observation_table_sha256": "0" * 64}, "trust_region")
    args = ["calibrate", str(OBSERVATIONS), "--quick", "--parameters", "light_factor", "--out", str(out)]
    assert_user_error(runner.invoke(app, args), "settings.json", "observations (another table: its SHA-256 differs)")


def test_calibrate_without_the_surrogate_does_not_compare_the_surrogates_settings(tmp_path, monkeypatch):
    """--priors and --n-design shape only the surrogate's emulator: a --no-surrogate history is
    resumed whatever they were (a mutation audit: recording them for every run, which then refused
    a rerun for a setting it does not use, survived). Stopped where the model would be built."""
    out = _calibration_out(
        tmp_path, monkeypatch, {"surrogate": False, "priors": "wide", "n_design": 7}, "history.jsonl"
    )
    args = ["calibrate", str(OBSERVATIONS), "--quick", "--parameters", "light_factor", "--no-surrogate"]
    r = runner.invoke(app, [*args, "--out", str(out)])
    assert r.exit_code == 130, r.output  # passed the comparison, stopped at the model


def test_python_dash_m_lightfit_runs_the_command_line():
    """`python -m lightfit` (as `python -m lightfit.cli`) for environments without the console script."""
    p = subprocess.run([sys.executable, "-m", "lightfit", "--help"], capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr
    assert "replicate" in p.stdout and "calibrate" in p.stdout


#: What help and usage errors must not import: seconds of JAX, pvlib, Mitsuba, pandas … before any text.
HEAVY_MODULES = (
    "jax",
    "jaxlib",
    "equinox",
    "optimistix",
    "lineax",
    "jaxopt",
    "emcee",
    "pvlib",
    "mitsuba",
    "drjit",
    "plantbox",
    "trimesh",
    "xarray",
    "h5py",
    "pandas",
    "scipy",
    "matplotlib",
    "PIL",
    "dask",
    "distributed",
    "xleaf",
)


def test_help_and_usage_errors_import_no_heavy_library():
    """`lightfit --help` took 2 s: the command modules imported JAX, pvlib and pandas at import time (the
    defaults their help states, read from the library), and the app callback imported JAX for the
    precision policy before the command read its arguments. Every help and a usage error import none
    of them (in a fresh process); a command that runs still computes in float64."""
    script = textwrap.dedent(
        f"""
        import sys
        import typer
        from typer.testing import CliRunner
        from lightfit.cli import app

        runner = CliRunner()
        commands = [[name] for name in typer.main.get_command(app).commands] + [["weather", "show"]]
        cases = [([], 2), *(([*c, "--help"], 0) for c in commands), (["replicate", "--nope"], 2)]
        cases += [(["field", "--along", "x"], 2), (["calibrate"], 2), (["nope"], 2)]
        for args, code in cases:
            r = runner.invoke(app, args)
            assert r.exit_code == code, (args, r.output)
        print(sorted({{m.split(".")[0] for m in sys.modules}} & set({HEAVY_MODULES!r})))
        r = runner.invoke(app, ["weather", "show", "--how", "nope"])  # runs the command, then refuses --how
        assert r.exit_code == 2 and "--how" in r.stderr, r.output
        print(sys.modules["jax"].config.jax_enable_x64)
        """
    )
    p = subprocess.run([sys.executable, "-c", script], env=_child_env(), capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr
    assert p.stdout.splitlines() == ["[]", "True"], p.stdout


def test_ctrl_c_after_a_command_finished_keeps_its_exit_status():
    """A Ctrl-C in the second or so of teardown after a command wrote its results gave exit 130 and
    no message, as if the run had failed (a review): from the first exit handler on, one Ctrl-C is
    ignored (the handlers and teardown finish, status 0), a second leaves at once with the command's
    status; a process that calls main() and goes on keeps its own Ctrl-C."""
    script = textwrap.dedent(
        """
        import atexit, os, signal, sys, time
        import lightfit.cli as cli

        # Ctrl-C as a terminal's Python has it: a suite started in the background (`cmd &` in a
        # script) ignores SIGINT, which Python keeps, and this process then never saw its own.
        signal.signal(signal.SIGINT, signal.default_int_handler)
        presses = int(sys.argv[1])

        def later_exit_handler():  # registered first: runs after main()'s own
            for _ in range(presses):
                os.kill(os.getpid(), signal.SIGINT)
                time.sleep(0.2)
            print("teardown went on", flush=True)

        atexit.register(later_exit_handler)

        def finished(**kw):
            raise SystemExit(3)

        cli.app = finished
        try:
            cli.main()
        except SystemExit as e:
            try:
                os.kill(os.getpid(), signal.SIGINT)  # before exit: still the process's own Ctrl-C
                time.sleep(5)
            except KeyboardInterrupt:
                print("own ctrl-c", flush=True)
            raise
        """
    )
    for presses, went_on in ((1, True), (2, False)):
        p = subprocess.run([sys.executable, "-c", script, str(presses)], capture_output=True, text=True, timeout=120)
        assert p.returncode == 3 and "KeyboardInterrupt" not in p.stderr, p
        assert "own ctrl-c" in p.stdout and ("teardown went on" in p.stdout) == went_on, p


def test_an_sd_without_its_value_is_said_not_dropped_unsaid(tmp_path):
    """A row with an SD but an empty value was accepted and the SD ignored without a word (a
    review): perhaps a value forgotten. It is no reading, so it is still ignored, but every command
    that reads observations cautions, naming the file, the column and the lines."""
    from lightfit.inference.observations import read_observations, sd_without_value

    twin = DATA_DIR / "observations" / "twin_2016-04-20_synthetic.csv"
    lines = twin.read_text().splitlines()
    header = next(i for i, x in enumerate(lines) if not x.startswith("#"))
    k = next(i for i in range(header + 1, len(lines)) if lines[i].split(",")[1])  # the first row with a reading
    cells = lines[k].split(",")
    cells[1] = ""  # plant PAR's value gone, its SD kept
    lines[k] = ",".join(cells)
    path = tmp_path / "forgot.csv"
    path.write_text("\n".join(lines) + "\n")
    said = sd_without_value(read_observations(path))
    column = "plant_par_sd_umol_m2_s"
    assert said == f"{path}: an SD without its value, ignored (no reading): {column} on 1 line(s) ({k + 1})"
    assert sd_without_value(read_observations(twin)) is None
    out = tmp_path / "r"
    r = runner.invoke(app, ["replicate", "--quick", "--steps", "14:16", "--observations", str(path), "--out", str(out)])
    assert r.exit_code == 0, r.output
    assert "caution: " + said in " ".join(r.stderr.split())


def test_a_row_with_fewer_cells_than_the_header_is_said(tmp_path):
    """A row cut short (its last cells missing) was read as readings missing from those columns
    without a word (a review of bad input); sparse hand-written files rely on it, so it is still read
    so, and every command that reads observations says so, naming the file and the lines."""
    from lightfit.inference.observations import read_observations, short_rows

    twin = DATA_DIR / "observations" / "twin_2016-04-20_synthetic.csv"
    assert short_rows(read_observations(twin)) is None
    lines = twin.read_text().splitlines()
    header = next(i for i, x in enumerate(lines) if not x.startswith("#"))
    k = next(i for i in range(header + 1, len(lines)) if lines[i].split(",")[1])  # the first row with a reading
    cells = lines[k].split(",")
    lines[k] = ",".join(cells[:3])  # time, plant PAR and its SD: the later columns cut off
    path = tmp_path / "cut.csv"
    path.write_text("\n".join(lines) + "\n")
    obs = read_observations(path)
    said = short_rows(obs)
    told = "their last columns are read as no reading"
    assert said == f"{path}: 1 row(s) with fewer cells than the header (line(s) {k + 1}): {told}"
    row = obs.iloc[[i for i, n in enumerate(obs.attrs["lines"]) if n == k + 1][0]]
    assert np.isfinite(row["plant_par_umol_m2_s"]) and np.isnan(row["canopy_an_umol_m2_s"])
    out = tmp_path / "r"
    r = runner.invoke(app, ["replicate", "--quick", "--steps", "14:16", "--observations", str(path), "--out", str(out)])
    assert r.exit_code == 0, r.output
    assert "note: " + said in " ".join(r.stdout.split())


def test_priors_help_states_the_prior_sets_leaf_ranges():
    """calibrate's and posterior's --priors help give the ranges (a newcomer review found posterior's
    without any): the informed set's for the default leaf and the wide set's, as the priors module
    defines them."""
    from lightfit.cli.common import PRIORS_HELP
    from lightfit.inference.mcmc.priors import PRIORS_WIDE, informed_priors

    informed = informed_priors()
    for n in ("specular", "roughness", "subsurface"):
        lo, hi = informed[n].support
        assert f"{n} {lo:g}–{hi:g}" in PRIORS_HELP, n
    assert all(PRIORS_WIDE[n].support == (0.0, 1.0) for n in ("specular", "subsurface"))
    assert "'wide' (specular and subsurface 0–1)" in PRIORS_HELP
    for command in ("calibrate", "posterior"):
        text = " ".join(CliRunner().invoke(app, [command, "--help"], env={"COLUMNS": "200"}).output.split())
        assert "specular 0.4625–0.7375, roughness 0.3–1, subsurface 0.31–1" in text.replace("│", "").replace("  ", " ")


def test_fixed_prints_no_negative_zero_and_a_dash_for_no_number():
    """Table cells: a value that rounds to zero prints without its sign (a sun 0.4° below the horizon
    read "-0" in the forcing table, a review); NaN and inf print "–"; other values as formatted."""
    from lightfit.cli.common import fixed

    assert [fixed(v, 1) for v in (-0.04, -0.06, 0.04, -12.345)] == ["0.0", "-0.1", "0.0", "-12.3"]
    assert fixed(-0.4, 0) == "0" and fixed(-0.6, 0) == "-1"
    assert fixed(float("nan"), 2) == fixed(float("inf"), 0) == "–"


def test_printed_summary_of_several_days_says_each_days_date():
    """With --date twice the printed table showed each day's local times again and nothing to tell
    the days apart (the UTC date is in summary.csv's index only; a review). A row with the local date
    now opens each day; one day's table is unchanged. 22:30 UTC is already the next day in Berlin."""
    from lightfit.cli.replicate import summary_rows

    t = pd.DatetimeIndex(["2016-04-20 10:00", "2016-04-20 22:30", "2016-04-21 10:00"], tz="UTC")
    table = pd.DataFrame({"local_time": ["12:00", "00:30", "12:00"], "fapar": [0.9, 0.0, 0.91]}, index=t)
    rows = summary_rows(table, "Europe/Berlin")
    assert rows == [["20 Apr", ""], ["12:00", "0.90"], ["21 Apr", ""], ["00:30", "0.00"], ["12:00", "0.91"]]
    assert summary_rows(table.iloc[:1], "Europe/Berlin") == [["12:00", "0.90"]]
    assert summary_rows(table, "UTC")[3] == ["21 Apr", ""]  # the same instants, another day's bounds


def test_calibration_json_is_strict_json_when_a_full_render_did_not_converge(tmp_path, monkeypatch):
    """A surrogate round whose full render's photosynthesis did not converge has loss +inf; its
    calibration.json and trust_region.jsonl rows wrote ``Infinity``, which strict JSON parsers (jq,
    JavaScript) refuse: null now. The real run's result with such a round put in (the quick model)."""
    import dataclasses
    import importlib
    import math

    tr_mod = importlib.import_module("lightfit.inference.trust_region")
    real = tr_mod.surrogate_calibrate
    bad = {"round": 1, "design": 8, "degree": 1, "theta": {"light_factor": 1.0}, "loss_surrogate": 2.0}
    bad |= {"loss_full": math.inf, "loss_sd": 0.5, "difference_over_sd": math.inf, "passed": False}

    def with_an_unconverged_round(*a, **k):
        return dataclasses.replace(real(*a, **k), loss_full=math.inf, rounds=[bad])

    monkeypatch.setattr(tr_mod, "surrogate_calibrate", with_an_unconverged_round)
    args = ["calibrate", str(OBSERVATIONS), "--quick", "--steps", "14:16", "--parameters", "light_factor"]
    r = runner.invoke(app, [*args, "--out", str(tmp_path)])
    assert r.exit_code == 0, r.output

    def refuse(c):
        raise ValueError(f"not strict JSON: {c}")

    res = json.loads((tmp_path / "calibration.json").read_text(), parse_constant=refuse)
    assert res["surrogate"]["loss_full"] is None
    assert res["surrogate"]["rounds"] == [bad | {"loss_full": None, "difference_over_sd": None}]


def test_the_compared_presets_edge_is_noted_too():
    """`replicate --compare-preset paper` draws the paper preset's canopy APAR dashed beside the
    run's; its finite field's edge put that line above the PAR above the canopy (fAPAR up to 2.2 on
    20 April) with no word, where the run's own table gets the edge note (a review of the main job)."""
    import xarray as xr

    from lightfit.cli.replicate import compared_edge_line

    paper = xr.Dataset({"fapar": ("time", [0.0, 2.22, 1.02, 0.99])}, attrs={"boundary": "finite"})
    line = compared_edge_line(paper, "paper")
    assert line.startswith("note: the paper preset (dashed in the figure): fAPAR above 1 at 2 of 4 steps (up to 2.22)")
    assert "finite field" in line
    assert compared_edge_line(xr.Dataset({"fapar": ("time", [0.0, 0.95])}), "default") == ""


def test_field_segments_csv_says_how_many_plants_it_measures(tmp_path, monkeypatch):
    """--n-plants 3 builds a 2 × 2 square, 4 measured plants, but the CSV's head said only
    ``n_plants: 3`` (the number asked for): a reader dividing the blade area by 3 plants' ground got
    the leaf area index a third too high. The head now says the measured plants and their ground
    area, 4 × 0.125 m × 0.03 m = 0.015 m² by hand, and the LAI printed is the CSV's blade area over it."""
    monkeypatch.setenv("LIGHTFIT_CACHE", str(tmp_path / "cache"))
    csv = tmp_path / "seg.csv"
    r = runner.invoke(app, ["field", "--n-plants", "3", "--segments", str(csv)])
    assert r.exit_code == 0, r.output
    head = dict(ln[2:].split(": ", 1) for ln in csv.read_text().splitlines() if ln.startswith("# "))
    seg = pd.read_csv(csv, comment="#")
    assert head["n_plants"] == "3"
    assert (
        head["measured_plants"]
        == "4 (2 rows × 2 plants)"
        == f"{seg.loc[seg.measured, 'plant_id'].nunique()} (2 rows × 2 plants)"
    )
    assert float(head["measured_ground_area_m2"]) == pytest.approx(4 * 0.125 * 0.03, rel=1e-9)
    lai = seg.loc[seg.measured, "blade_area_m2"].sum() / (4 * 0.125 * 0.03)
    line = next(ln for ln in r.stdout.splitlines() if "leaf area index" in ln)
    assert f"{lai:.2f}" in line


def test_weather_show_spans_without_a_unit_are_refused_and_iso_ones_resample():
    """pandas reads a number without a unit as nanoseconds: --max-gap 10 (meant as 10 min) turned
    interpolation off unsaid, --resample 7 ended in a pandas ValueError traceback; both are refused
    naming the option. A span pandas' Timedelta reads but its offsets do not ('1 hour', ISO 8601 'PT1H')
    was a traceback too; it resamples now, to hourly steps 1 h apart."""
    for option, value in (("--max-gap", "10"), ("--resample", "7")):
        out = runner.invoke(app, ["weather", "show", "2016-04-20", option, value])
        assert out.exit_code == 2, (option, out.output)
        assert f"option {option}" in out.output and "with its unit" in out.output, out.output
    from lightfit.weather import read_source, resample

    day = read_source("2016-04-20")
    for freq in ("1 hour", "PT1H"):
        r = resample(day, freq, "mean")
        assert (r.index[1:] - r.index[:-1] == pd.Timedelta(hours=1)).all() and len(r) == 23
