"""``lightfit replicate``: the main job, the 20 April 2016 Selhausen replication by default; any day
and site with ``--date``, ``--start-time/--hours/--step`` and ``--site`` or coordinates."""

from __future__ import annotations

import dataclasses
import shutil
from pathlib import Path

import numpy as np
import typer
from rich import box
from rich.table import Table

from lightfit.cli.common import (
    THETA_HELP,
    caution,
    console,
    fixed,
    observations_for_run,
    observations_lines,
    output_folder,
    parse_theta,
    soil_respiration_note,
    theta_cautions,
    weather_report,
    weather_table,
)
from lightfit.cli.options import ModelOptions, model_options, option_error, resolve, weather
from lightfit.errors import InputError

#: Short head and decimals of each summary column in the printed table (summary.csv keeps full names).
SUMMARY_HEADS = {
    "local_time": ("local", None),
    "sun_elevation_deg": ("sun°", 1),
    "above_canopy_par_umol_m2_s": ("PAR↑", 0),
    "plant_par_umol_m2_s": ("PARpl", 0),
    "plant_par_spread_umol_m2_s": ("±", 0),
    "canopy_apar_umol_m2_s": ("APAR", 0),
    "fapar": ("fAPAR", 2),
    "canopy_an_umol_m2_s": ("An", 1),
    "canopy_an_mc_sd_umol_m2_s": ("±MC", 2),
    "frac_light_limited": ("light", 2),
    "unconverged_blades": ("nc", 0),
}


def summary_rows(table, tz: str) -> list[list[str]]:
    """The printed rows of :func:`lightfit.report.summary`'s ``table``: its cells with the short
    decimals of :data:`SUMMARY_HEADS`, and, where the steps span several local dates (``--date`` twice),
    a row with the local date (``21 Apr``) before each day's first step: the local clock alone repeats
    every day's times (the UTC date is in summary.csv's index only)."""
    import pandas as pd

    days = pd.DatetimeIndex(table.index).tz_convert(tz).date
    dated = len(set(days)) > 1
    rows = []
    for i, (_, r) in enumerate(table.iterrows()):
        if dated and (i == 0 or days[i] != days[i - 1]):
            rows.append([f"{days[i]:%d %b}"] + [""] * (len(table.columns) - 1))
        rows.append([_cell(r[c], SUMMARY_HEADS.get(c, (c, 3))[1]) for c in table.columns])
    return rows


def _cell(value, decimals: int | None) -> str:
    if decimals is None:
        return str(value)
    return fixed(value, decimals)


@model_options
def replicate(
    out: Path = typer.Option(None, help="Output directory (default results/DATE, e.g. results/2016-04-20)."),
    observations: Path = typer.Option(
        None,
        help="Chamber observations CSV (default: the bundled record of 20 April 2016, "
        "used when the run's steps reach it).",
    ),
    theta: str = typer.Option(None, help=THETA_HELP + " This run only: not the --compare-preset run."),
    compare_preset: str = typer.Option(
        None,
        help="Also run this preset (default or paper) on the same forcing and draw it dashed in the figure "
        "(results_compare.nc; a second full run). It runs the preset's own leaf and scales: --theta is not "
        "applied to it.",
    ),
    resume: bool = typer.Option(
        True,
        help="Take the steps that an interrupted or killed run of the same settings kept in OUT/.kept-steps/, "
        "where every run keeps its rendered steps until its results are written (--no-resume: discard them first).",
    ),
    *,
    model: ModelOptions,
) -> None:
    """The main job: a diurnal run, by default the 20 April 2016 Selhausen replication (Fig 4).

    Another day or site: --date, --start-time/--hours/--step, --site or --latitude/--longitude/--timezone.
    """
    import pandas as pd

    from lightfit import replication as rep
    from lightfit.inference.calibration import misfit
    from lightfit.inference.observations import SERIES, observation_cautions, observed
    from lightfit.report import field_label, observations_fit, samples_label, site_timezone, summary
    from lightfit.weather.plot import provenance_label

    s = resolve(model)
    cfg = s.replication_config()
    fld = cfg.field()  # checks boundary and buffers before anything is written
    th = parse_theta(theta)  # names and domains, before minutes of plant growth, not after
    cmp = None if compare_preset is None else _comparison(model, compare_preset)
    if cmp is not None and cmp == cfg:  # a second run of this very configuration: twice the time, one answer
        raise InputError(
            f"--compare-preset {compare_preset} is this run's own configuration",
            parameter="compare_preset",
            expected="the other preset (--compare-preset paper for the default run, default for --preset paper)",
        )
    w = weather(s)
    # the fit's settings against what this run takes (the forcing's growth temperature among them)
    for line in theta_cautions(theta, s.effective(w)):  # said before the run; they do not stop it
        caution(line)
    # read and placed before anything is written; the bundled record by default, where the run reaches it
    given = None if observations is None else observations_for_run(observations, w, s)
    obs = rep.observations_for(w, rep.OBSERVATIONS if given is None else given, optional=given is None)
    out = out or Path("results") / "+".join(s.dates)
    output_folder(out)
    if out.suffix.lower() == ".nc":  # field-run's --out is the file; here it is the folder of five files
        raise InputError(
            "--out is the folder for results.nc, summary.csv and the figures; this name is a netCDF file's",
            file=out,
            expected="a folder name (e.g. results/run1; field-run's --out is the .nc file itself)",
        )
    out.mkdir(parents=True, exist_ok=True)
    if not resume:
        shutil.rmtree(out / rep.UNFINISHED, ignore_errors=True)
    before = stored_settings(out / "results.nc")  # compared with the run's own once it has run
    weather_report(w)
    label = provenance_label(w.attrs)
    title = f"{label} forcing of the diurnal run ({len(w)} steps: {rep.describe_steps(cfg, w)})"
    console.print(weather_table(w, title, tz=s.site.timezone))
    k, n_b = s.samples, cfg.render_bounces()  # bounces None: resolved from the leaf, as the run does
    rays = "" if s.direct != "projection" else ", {:.3g} / {:.3g} sun / sky rays per m²".format(*cfg.direct_rays_per_m2)
    k = samples_label(k, cfg.target_rse)
    console.print(
        f"running: {fld.area_label}, {field_label(fld)}, {fld.sheaths} sheaths, {fld.headings} headings, {k}, "
        f"{n_b} bounces{rays} …",
        soft_wrap=True,  # one line, not a lone "…" in an 80-column pipe
    )
    if th:  # said only in the figure's title and the netCDF attributes before (a newcomer review)
        source = f" (from {theta})" if Path(theta).exists() else ""
        said = "parameters (--theta): " + ", ".join(f"{k}={v:.4g}" for k, v in th.items()) + source
        console.print(said, soft_wrap=True)  # a path stays on one line
    ds, obs = rep.run(
        cfg,
        weather_file=s.weather_file,
        theta=th,
        forcing_df=w,
        observations=obs,
        out=out,
        progress=True,
        compare=cmp,
    )
    changed = replaced_settings(before, ds)
    if changed:  # a quick test run into the default folder replaced the main job's results unsaid
        console.print(f"note: replaced the results in {out}, made with other settings ({changed}); --out keeps both")
    table = summary(ds)
    t = Table(
        title=f"replication summary ({label} forcing; {field_label(ds.attrs)}; "
        f"model PAR = {s.par_kind}, An per {s.an_per} area)",
        caption="PAR↑: the above-canopy sensor; PARpl: PAR at the plants (± its spread across "
        f"segments); APAR: per ground area; An: per {s.an_per} area; ±MC: Monte Carlo SD; light: share of "
        "light-limited blades; nc: blades whose leaf solve did not converge. µmol m⁻² s⁻¹ unless a share.",
        box=box.SIMPLE_HEAD,
        padding=(0, 1),
        pad_edge=False,
    )
    # The columns are the summary's own (lightfit.report.summary); short heads and fixed decimals
    # keep all of them readable in an 80-column terminal.
    for c in table.columns:
        t.add_column(SUMMARY_HEADS.get(c, (c, 3))[0], justify="right")
    for row in summary_rows(table, site_timezone(ds)):
        t.add_row(*row)
    console.print(t)
    cmp_edge, cmp_fit = "", None
    if cmp is not None:  # the compared preset's results, read back once: its edge note and its fit below
        import xarray as xr

        with xr.open_dataset(out / "results_compare.nc", engine="h5netcdf") as other:
            cmp_edge, cmp_fit = compared_edge_line(other, compare_preset), observations_fit(other)
    # the compared preset's APAR above the sensor is drawn beside this run's: its edge note too
    for line in (mc_bias_line(ds), edge_line(ds), cmp_edge):
        if line:
            console.print(line)
    if short := target_shortfall(ds):
        caution(short)
    if obs is not None:
        observations_lines(obs, w)
        fit = observations_fit(ds)
        console.print(fit_table(fit))
        if cmp is not None:  # the compared preset against the same readings
            console.print(fit_table(cmp_fit, f"the {compare_preset} preset"))
        # the series' χ² add up: without a Monte Carlo correlation the series' errors are independent
        for said in misfit(fit.chi2.sum(), fit.n.sum(), 0, what="the run"):
            caution(said)
        soil_respiration_note(observed(obs), s.soil_respiration)  # as calibrate and posterior say it
        # judged against the model's own values (its fit factor), not the forcing's alone
        times = pd.DatetimeIndex(ds["time"].values).tz_localize("UTC")
        values = [x.value for x in SERIES if x.value in ds and ds[x.value].dims == ("time",)]
        model_at = {c: pd.Series(ds[c].values, index=times) for c in values}
        for said in observation_cautions(obs, w, model_at):
            caution(said)
    files = ("forcing.csv", "forcing.png", "results.nc", "replication.png", "summary.csv")
    for f in files + (("results_compare.nc",) if cmp is not None else ()):
        console.print(f"[green]wrote[/] {out / f}")


def fit_table(fit, model: str = "model") -> Table:
    """The run against its observations, one row per series (:func:`lightfit.report.observations_fit`)."""
    t = Table(
        title=f"{model} against the observations (model − observed)",
        caption="n: steps with a reading; χ²: the series alone, with the readings' and the Monte Carlo "
        "SDs (≈ n where the model fits; inf: a leaf solve did not converge)",
        box=box.SIMPLE_HEAD,
        padding=(0, 1),
        pad_edge=False,
    )
    for head in ("series", "n", "bias", "RMSE", "unit", "χ²"):
        t.add_column(head, justify="left" if head in ("series", "unit") else "right")
    for name, r in fit.iterrows():
        t.add_row(name, str(r.n), f"{r.bias:+.3g}", f"{r.rmse:.3g}", r.unit, f"{r.chi2:.3g}")
    return t


#: Results attributes that say nothing about the settings (or repeat one another's): not compared.
NOT_SETTINGS = {
    "software_versions",
    "mitsuba_variant",
    "llvm_target",
    "replication_config",
    "steps_run",  # the steps are compared as steps (the results' times)
    "theta_given",
    "observations_fit",
    "title",
    "conventions",
    "layout_fingerprint",
    "observations_provenance",
    "growth_temperature_applied_c",
    "kn_per_lai",
    "ground_area_m2",
}


def stored_settings(path: Path):
    """``(attrs, times)`` of the results in ``path``, ``None`` where there are none, or the string
    ``"unreadable"``; read before a run replaces them (:func:`replaced_settings`)."""
    if not path.is_file():
        return None
    try:
        import xarray as xr

        with xr.open_dataset(path, engine="h5netcdf") as ds:
            return dict(ds.attrs), np.asarray(ds["time"].values, "datetime64[ns]")
    except Exception:  # noqa: BLE001 - any file lightfit cannot read is replaced, and said so
        return "unreadable"


def replaced_settings(before, ds) -> str | None:
    """What differs between the results a run replaced (``before``: :func:`stored_settings`) and its
    own ``ds``, as resolved settings (the results' attributes: ``samples 32 → 16``, the weather file,
    θ) and steps; ``None`` where nothing does or nothing was there."""
    if before is None:
        return None
    if isinstance(before, str):
        return "a file lightfit cannot read"
    old, times = before
    new = dict(ds.attrs)

    def same(a, b) -> bool:
        return np.array_equal(np.asarray(a), np.asarray(b)) if a is not None and b is not None else a is b

    diffs = [
        f"{k} {_short(k, old.get(k))} → {_short(k, new.get(k))}"
        for k in sorted(set(old) | set(new))
        if k not in NOT_SETTINGS and not same(old.get(k), new.get(k))
    ]
    now = np.asarray(ds["time"].values, "datetime64[ns]")
    if len(times) != len(now) or (times != now).any():
        diffs.append(f"{len(times)} steps → {len(now)}" if len(times) != len(now) else "other steps")
    return ", ".join(diffs) or None


#: Results attributes that name a file: shown by its name (any "/" elsewhere is not a path: Europe/Berlin).
FILE_ATTRS = {"weather_source", "observations", "parameter_file"}


def _short(key: str, v) -> str:
    text = "–" if v is None else (Path(str(v)).name if key in FILE_ATTRS else str(v))
    return text if len(text) <= 30 else text[:29] + "…"


def mc_bias_line(ds) -> str:
    """The run's Monte Carlo bias of the day's canopy An as one line ("" when the canopy took up
    nothing), naming what sets the noise: a fixed K, or the adaptive target and its K range."""
    an, bias = (float(ds[v].sum()) for v in ("canopy_an_umol_m2_s", "canopy_an_mc_bias_umol_m2_s"))
    if an <= 0:
        return ""
    # The bias goes as the blades' PAR variance: 1/K from the paths, and with a projection
    # (attribute direct) also 1/rays.
    falls = "falling as 1/K"
    if ds.attrs.get("direct") == "projection":
        falls = "falling with K and the projection's rays"
    at = f"K={ds.attrs['samples']}"
    if "target_rse" in ds.attrs:  # adaptive: --samples is only the pilot, K differs per segment
        k = ds["samples_per_segment"].values  # (time, segment) with NaN between days when several
        at = f"a target of {float(ds.attrs['target_rse']):.3g} (K {np.nanmin(k):.0f}–{np.nanmax(k):.0f} per segment)"
        falls = "falling with the target"
    return (
        f"Monte Carlo bias of the day's canopy An (noise in the blades' PAR through the concave light "
        f"response; not subtracted): {bias / an:+.2%} at {at}, {falls} (docs/model.md)"
    )


def target_shortfall(ds) -> str:
    """Where adaptive sampling left segments above its ``--target-rse`` (they reached the cap of
    points, :data:`~lightfit.defaults.MAX_ADAPTIVE_SAMPLES`; those done by the light floor
    met their rule): how many, and how far they got ("" when every segment met the target, or
    without a target)."""
    if "target_rse" not in ds.attrs or "reached_rse" not in ds:
        return ""
    target = float(ds.attrs["target_rse"])
    reached = np.asarray(ds["reached_rse"].values, dtype=float)
    missed = (reached > target) & (np.asarray(ds["stopped_on_floor"].values) == 0) & np.isfinite(reached)
    if not missed.any():
        return ""
    k = np.asarray(ds["samples_per_segment"].values, dtype=float)[missed]
    n = int((~np.isnan(reached)).sum())  # several days: NaN where a day lacks the segment, each day's counted
    return (
        f"{int(missed.sum())} of {n} segments did not reach --target-rse {target:.3g}: they stopped "
        f"at {np.nanmax(k):.0f} points, the cap, with relative SEs of {np.median(reached[missed]):.3g} (median) "
        f"up to {reached[missed].max():.3g}; each segment's is in results.nc (reached_rse)"
    )


def edge_line(ds) -> str:
    """A note where canopy APAR exceeds the PAR above the canopy (fAPAR > 1: light entering a
    finite field's measured area through its sides), so the table is not read as a canopy's
    ("" when fAPAR stays at or below 1)."""
    from lightfit.report import fapar_over_one

    line = fapar_over_one(ds)
    return f"note: fAPAR {line}" if line else ""


def compared_edge_line(other, preset: str) -> str:
    """:func:`edge_line` of the ``--compare-preset`` run's results ``other``, named as that preset's
    (its dashed lines in the figure); "" where its fAPAR stays at or below 1."""
    line = edge_line(other)
    return line and f"note: the {preset} preset (dashed in the figure): " + line.removeprefix("note: ")


def _comparison(model: ModelOptions, preset: str):
    """The configuration of ``--compare-preset``: the run's size and forcing options with the
    preset's model choices, as ``--preset`` resolves them (the run's own field, leaf, sheaths,
    photosynthesis and direct-light options are the preset's, not the run's: the comparison is the
    preset, not a hybrid), checked before anything runs; errors are named as the option."""
    from lightfit.replication import PAPER_PRESET

    choices = {k: None for k in (*PAPER_PRESET, "direct", "direct_rays_per_m2")}

    def make():
        from lightfit.cli.common import caution

        def say(line: str) -> None:  # a caution about the comparison's settings, labelled as its
            caution(f"--compare-preset {preset}: {line}")

        cfg = resolve(dataclasses.replace(model, preset=preset, **choices), say).replication_config()
        cfg.field()
        return cfg

    return option_error(make, "--compare-preset")
