"""The ``lightfit`` command line: one entry point, one subcommand per task."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from lightfit.errors import InputError

app = typer.Typer(
    help="Differentiable light and photosynthesis for wheat canopies.",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
)
weather_app = typer.Typer(help="Read, check, convert and plot weather series.", no_args_is_help=True)
app.add_typer(weather_app, name="weather")
console = Console()
err_console = Console(stderr=True)

_STATE: dict[str, str | None] = {"variant": None}


@app.callback()
def _main(
    variant: str = typer.Option(
        None,
        "--variant",
        envvar="LIGHTFIT_VARIANT",
        help="Mitsuba variant, e.g. llvm_ad_mono or cuda_ad_mono (default: auto).",
    ),
):
    _STATE["variant"] = variant


def _fail(err: Exception) -> None:
    err_console.print(f"[bold red]error:[/] {escape(str(err))}")
    raise typer.Exit(2)


@app.command()
def info():
    """Print versions, the Mitsuba variant in use and the libLLVM path."""
    import importlib.metadata as md

    from lightfit.light import backend

    t = Table(title="lightfit environment", show_header=False)
    t.add_row("python", sys.version.split()[0])
    for pkg in (
        "lightfit",
        "jax",
        "jaxlib",
        "drjit",
        "mitsuba",
        "optimistix",
        "jaxopt",
        "emcee",
        "cplantbox",
        "pvlib",
        "numpy",
        "pandas",
        "xarray",
        "trimesh",
    ):
        try:
            t.add_row(pkg, md.version(pkg))
        except md.PackageNotFoundError:
            t.add_row(pkg, "[red]not installed[/]")
    try:
        b = backend.info() if _STATE["variant"] is None else (backend.mitsuba(_STATE["variant"]), backend.info())[1]
    except backend.BackendError as err:
        console.print(t)
        _fail(err)
    t.add_row("mitsuba variant", f"{b.variant} ({b.variant_source})")
    t.add_row("libLLVM", f"{b.libllvm} ({b.libllvm_source})")
    t.add_row("CUDA usable", str(backend.cuda_usable()))
    console.print(t)


def _load(source: str, fmt: str, date: str | None, tz: str | None, max_gap: str, split: str):
    from lightfit import weather

    if source in weather.BUNDLED:
        df = weather.read_weather(
            weather.bundled_path(source), date=date or weather.BUNDLED[source][1], max_gap=max_gap
        )
    else:
        df = weather.read_weather(source, format=fmt, date=date, tz=tz, max_gap=max_gap)
    return weather.add_solar(df, split_model=split)


_SHORT = {
    "par_umol_m2_s": "PAR",
    "ghi_w_m2": "GHI",
    "dni_w_m2": "DNI",
    "dhi_w_m2": "DHI",
    "sun_elevation_deg": "sun°",
    "tair_c": "T °C",
    "rh": "RH",
    "pair_kpa": "p kPa",
    "co2_ppm": "CO2",
}


_DIGITS = {"rh": 2, "tair_c": 1, "pair_kpa": 1}


def _table(df, title: str, max_rows: int = 40, tz: str = "Europe/Berlin") -> Table:
    t = Table(title=title, caption="PAR µmol m⁻² s⁻¹; GHI/DNI/DHI W m⁻²; sun° elevation; RH 0–1; CO2 ppm")
    t.add_column("UTC")
    t.add_column(tz.split("/")[-1])
    cols = [c for c in _SHORT if c in df.columns]
    for c in cols:
        t.add_column(_SHORT[c], justify="right")
    step = max(1, len(df) // max_rows)
    for ts, row in df.iloc[::step].iterrows():
        t.add_row(
            ts.strftime("%m-%d %H:%M"),
            ts.tz_convert(tz).strftime("%H:%M"),
            *(f"{row[c]:.{_DIGITS.get(c, 0)}f}" for c in cols),
        )
    return t


def _report(df) -> None:
    a = df.attrs
    console.print(
        f"[bold]source[/] {a.get('source')}  [bold]format[/] {a.get('format')}  "
        f"[bold]provenance[/] [magenta]{a.get('provenance')}[/]  "
        f"[bold]timestamps assumed in[/] {a.get('timezone_assumed')}"
    )
    for k, v in a.get("columns_used", {}).items():
        if k != v:
            console.print(f"  {k:>14} ← {v}")
    if a.get("unused_columns"):
        console.print(f"  [dim]not used: {', '.join(a['unused_columns'])}[/]")
    for q in a.get("qc", []):
        console.print(f"  [yellow]repair[/] {q['kind']}: {escape(q['detail'])}")


@weather_app.command("show")
def weather_show(
    source: str = typer.Argument(
        "2016-04-20", help="A bundled series name (2016-04-20, selhausen-cplantbox-day) or a file."
    ),
    fmt: str = typer.Option("auto", "--format", help="auto, tereno, cplantbox or lightfit."),
    date: str = typer.Option(None, help="Calendar date for undated files (CPlantBox day), YYYY-MM-DD."),
    tz: str = typer.Option(None, help="Timezone of the file's timestamps (default: the format's convention)."),
    max_gap: str = typer.Option("30min", help="Longest gap to interpolate."),
    split: str = typer.Option("erbs", help="Direct/diffuse split model: erbs or boland."),
    resample: str = typer.Option(None, help="New time step, e.g. 30min."),
    how: str = typer.Option("mean", help="Resampling: mean (centred window) or sample."),
    plot: Path = typer.Option(None, help="Write a PNG plot here."),
    csv: Path = typer.Option(None, help="Write the contract series as CSV here."),
):
    """Read a weather series, report its checks and repairs, print it, optionally plot/convert."""
    from lightfit import weather
    from lightfit.weather.plot import plot_forcing

    try:
        df = _load(source, fmt, date, tz, max_gap, split)
        if resample:
            df = weather.resample(df, resample, how)
    except InputError as err:
        _fail(err)
    _report(df)
    console.print(
        _table(df, f"{df.attrs.get('provenance', '').upper()} weather: {Path(str(df.attrs.get('source'))).name}")
    )
    if plot:
        console.print(f"plot → {plot_forcing(df, plot)}")
    if csv:
        meta = {
            "provenance": df.attrs["provenance"],
            "source": str(df.attrs.get("source")),
            "qc": json.dumps(df.attrs.get("qc", []), ensure_ascii=False),
        }
        console.print(f"csv → {weather.write_lightfit_csv(df, csv, meta)}")


def _theta(theta: str | None) -> dict:
    """Parameters from a JSON file (a calibration's output) or ``key=value,key=value``."""
    if not theta:
        return {}
    p = Path(theta)
    if p.exists():
        data = json.loads(p.read_text())
        return data.get("theta", data)
    out = {}
    for item in theta.split(","):
        k, _, v = item.partition("=")
        try:
            out[k.strip()] = float(v)
        except ValueError:
            raise InputError(
                f"cannot read parameter {item!r}",
                column="theta",
                expected="a JSON file or key=value pairs, e.g. specular=0.4,roughness=0.6",
            ) from None
    return out


@app.command()
def replicate(
    out: Path = typer.Option(Path("results/2016-04-20"), help="Output directory."),
    weather_file: Path = typer.Option(
        None,
        "--weather",
        help="A real TERENO export (or other weather file) to use instead of the bundled reconstructed forcing.",
    ),
    observations: Path = typer.Option(None, help="Chamber observations CSV (default: the bundled record of the day)."),
    quick: bool = typer.Option(False, "--quick", help="First look in under a minute: 4 plants, K=16, 2 bounces."),
    n_plants: int = typer.Option(None, help="Plants in the measurement area (default 100; quick: 4)."),
    buffer_rows: int = typer.Option(None, help="Buffer rows (default 2, the reference paper's finding)."),
    buffer_along: int = typer.Option(
        None,
        help="Buffer plants along each row end (default: = buffer rows; "
        "≈ 4× buffer rows makes the buffer as wide in metres both ways).",
    ),
    samples: int = typer.Option(None, help="Irradiance samples per segment K (default 64; quick: 16)."),
    bounces: int = typer.Option(None, help="Scattering orders (default 3; quick: 2)."),
    theta: str = typer.Option(
        None,
        help="Leaf/light parameters: a calibration JSON or key=value,... "
        "(specular, roughness, subsurface, light_factor, vcmax_scale).",
    ),
    how: str = typer.Option("sample", help="30-min steps from 10-min data: sample (as the reference paper) or mean."),
):
    """The main job: the 20 April 2016 Selhausen replication (forcing, light, photosynthesis, Fig 4)."""
    import dataclasses

    from lightfit import replication as rep
    from lightfit.weather.plot import plot_forcing

    cfg = rep.ReplicationConfig.quick() if quick else rep.ReplicationConfig()
    cfg = dataclasses.replace(
        cfg,
        how=how,
        **{
            k: v
            for k, v in dict(
                n_plants=n_plants, buffer_rows=buffer_rows, buffer_along=buffer_along, samples=samples, bounces=bounces
            ).items()
            if v is not None
        },
    )
    try:
        w = rep.forcing(weather_file, how)
        out.mkdir(parents=True, exist_ok=True)
        _report(w)
        label = str(w.attrs.get("provenance", "")).upper()
        console.print(_table(w, f"{label} forcing of the diurnal run ({len(w)} steps of {rep.STEP})"))
        meta = {
            "provenance": w.attrs["provenance"],
            "source": str(w.attrs.get("source")),
            "note": f"{len(w)} steps of {rep.STEP} from {rep.START_LOCAL} local ({how})",
        }
        from lightfit import weather

        weather.write_lightfit_csv(w, out / "forcing.csv", meta)
        plot_forcing(w, out / "forcing.png", title=f"{label} forcing, Selhausen 2016-04-20")
        console.print(
            f"running: {cfg.n_plants} plants + {cfg.buffer_rows} buffer rows, K={cfg.samples}, {cfg.bounces} bounces …"
        )
        ds, obs = rep.run(
            cfg,
            weather_file=weather_file,
            theta=_theta(theta),
            forcing_df=w,
            observations=observations or rep.OBSERVATIONS,
            out=out,
            progress=True,
        )
    except InputError as err:
        _fail(err)
    s = rep.summary(ds)
    t = Table(title=f"replication summary ({label} forcing; model PAR = {cfg.par_kind}, An per {cfg.an_per} area)")
    for c in [
        "local_time",
        "sun_elevation_deg",
        "par_above_umol_m2_s",
        "plant_par_umol_m2_s",
        "plant_par_sd_umol_m2_s",
        "canopy_an_umol_m2_s",
        "canopy_an_mc_sd",
        "frac_light_limited",
    ]:
        t.add_column(c.replace("_umol_m2_s", "").replace("_", " "), justify="right")
    for _, r in s.iterrows():
        t.add_row(r["local_time"], *(f"{r[c]:.3g}" if np.isfinite(r[c]) else "–" for c in list(s.columns)[1:]))
    console.print(t)
    if obs is not None:
        console.print(f"observations: {obs.attrs['source']} ({obs.attrs['provenance']}, {len(obs)} row(s))")
    for f in ("forcing.csv", "forcing.png", "results.nc", "replication.png", "summary.csv"):
        console.print(f"[green]wrote[/] {out / f}")


@app.command()
def calibrate(
    observations: Path = typer.Argument(..., help="Observations CSV (time, PAR, net CO2 uptake and their SDs)."),
    out: Path = typer.Option(Path("results/calibration"), help="Output directory (history, result JSON, plot)."),
    weather_file: Path = typer.Option(
        None, "--weather", help="TERENO export or other weather file (default: bundled)."
    ),
    parameters: str = typer.Option("specular,roughness,subsurface", help="Parameters to calibrate, comma-separated."),
    start: str = typer.Option(None, help="Start values key=value,... (default: 0.5, 0.5, 0.3, 1, 1)."),
    quick: bool = typer.Option(False, "--quick", help="CI-sized field (4 plants, K=16)."),
    n_plants: int = typer.Option(None, help="Plants in the measurement area."),
    samples: int = typer.Option(None, help="Irradiance samples per segment K."),
    max_steps: int = typer.Option(30, help="Maximum optimiser steps."),
    resume: bool = typer.Option(True, help="Continue from the history in OUT if present."),
):
    """Calibrate leaf surface (and optionally light_factor, vcmax_scale) parameters by gradients."""
    import dataclasses

    from lightfit import replication as rep
    from lightfit.inference.calibration import calibrate as run_calibration
    from lightfit.inference.observations import read_observations

    cfg = rep.ReplicationConfig.quick() if quick else rep.ReplicationConfig()
    cfg = dataclasses.replace(
        cfg, **{k: v for k, v in dict(n_plants=n_plants, samples=samples).items() if v is not None}
    )
    try:
        obs = read_observations(observations)
        w = rep.forcing(weather_file, cfg.how)
        model = rep.model_for(cfg, w, progress=True)
        names = tuple(n.strip() for n in parameters.split(",") if n.strip())
        out.mkdir(parents=True, exist_ok=True)
        res = run_calibration(
            model,
            obs,
            names=names,
            start=_theta(start),
            max_steps=max_steps,
            history=out / "history.jsonl",
            resume=resume,
        )
    except InputError as err:
        _fail(err)
    (out / "calibration.json").write_text(
        json.dumps(
            {
                "theta": res.theta,
                "loss": res.loss,
                "steps": res.steps,
                "converged": bool(res.converged),
                "seconds": res.seconds,
                "observations": str(observations),
                "parameters": list(names),
                "config": dataclasses.asdict(cfg),
            },
            indent=2,
        )
    )
    t = Table(
        title=f"calibration ({'converged' if res.converged else 'not converged'}, "
        f"{res.steps} steps, {res.seconds:.0f} s)"
    )
    t.add_column("parameter")
    t.add_column("value", justify="right")
    for k, v in res.theta.items():
        t.add_row(k + (" (calibrated)" if k in names else ""), f"{v:.4g}")
    t.add_row("loss (Gaussian NLL)", f"{res.loss:.4g}")
    console.print(t)
    console.print(
        f"[green]wrote[/] {out / 'calibration.json'}, {out / 'history.jsonl'}; "
        f"rerun `lightfit replicate --theta {out / 'calibration.json'}` to see the fit"
    )


@app.command("field")
def field_cmd(
    n_plants: int = typer.Option(25, help="Plants in the measurement area (rounded up to a square N×N)."),
    row_spacing: float = typer.Option(0.125, help="Distance between wheat rows, m."),
    plant_spacing: float = typer.Option(0.03, help="Distance between plants in a row, m."),
    buffer_rows: int = typer.Option(2, help="Rows of unmeasured buffer plants around the measurement area."),
    buffer_along: int = typer.Option(None, help="Buffer plants along each row end (default: = buffer rows)."),
    row_direction: float = typer.Option(90.0, help="Compass azimuth of the rows, degrees (90 = east–west)."),
    seed: int = typer.Option(0, help="Global seed; plant seeds derive from it and grid positions."),
    parameter_file: str = typer.Option(
        "Triticum_aestivum_adapted_2023.xml", help="CPlantBox plant XML (path or bundled name)."
    ),
    season_start: str = typer.Option("2016-03-05", help="First day of growth."),
    date: str = typer.Option("2016-04-20", help="Date the plants are grown to."),
    tiles: int = typer.Option(1, help="Partition the measurement area into this many tiles (each with its buffer)."),
    tile: int = typer.Option(None, help="Build only this tile (0-based) with its buffer ring."),
    along: int = typer.Option(1, help="Mesh subdivisions along each segment."),
    across: int = typer.Option(1, help="Mesh subdivisions across each leaf blade."),
    around: int = typer.Option(6, help="Sides of stem/sheath prisms."),
    export: list[Path] = typer.Option(None, help="Write the mesh: .obj, .ply or .vtk (repeatable)."),
    preview: Path = typer.Option(None, help="Write a PNG with top and side views."),
    segments_csv: Path = typer.Option(None, "--segments", help="Write the segment table (G1) as CSV."),
):
    """Build a field of CPlantBox wheat: report plants, segments, triangles; export and preview."""
    from lightfit import plant
    from lightfit.plant.preview import plot_field

    try:
        g = plant.GrowthConfig(parameter_file, season_start, date)
        fld = plant.Field(n_plants, row_spacing, plant_spacing, buffer_rows, row_direction, seed, g, buffer_along)
        parts = fld.tiles(tiles)
        if tile is not None and not 0 <= tile < len(parts):
            raise InputError(f"tile {tile} does not exist", column="tile", expected=f"0 … {len(parts) - 1}")
        res = plant.MeshResolution(along, across, around)
        geom = plant.build(fld, tile=parts[tile] if tile is not None else None, resolution=res, progress=True)
    except InputError as err:
        _fail(err)
    seg = geom.segments
    meas = seg[seg["measured"]]
    area_m2 = fld.n * fld.plant_spacing_m * fld.n * fld.row_spacing_m
    t = Table(
        title=f"field {fld.n}×{fld.n} measured + {fld.buffer_rows} buffer rows, grown "
        f"{g.season_start} → {g.target_date} ({g.days:.0f} d), {g.path.name}"
    )
    t.add_column("quantity")
    t.add_column("value", justify="right")
    n_meas = int(geom.plants["measured"].sum()) if tile is None else len(parts[tile].measured)
    t.add_row("plants built (measured / buffer)", f"{len(geom.plants)} ({n_meas} / {len(geom.plants) - n_meas})")
    t.add_row("plants from cache", str(geom.cache_hits))
    t.add_row(
        "shoot segments (leaf / stem)",
        f"{len(seg)} ({int((seg.organ_type == 'leaf').sum())} / {int((seg.organ_type == 'stem').sum())})",
    )
    t.add_row("measured segments", str(len(meas)))
    t.add_row("triangles", str(geom.mesh.n_faces))
    t.add_row("triangles per plant", f"{geom.mesh.n_faces / len(geom.plants):.0f}")
    t.add_row("one-sided leaf blade area per plant (m²)", f"{seg['blade_area_m2'].sum() / len(geom.plants):.4f}")
    if tile is None:
        t.add_row("leaf area index of the measurement area", f"{meas['blade_area_m2'].sum() / area_m2:.2f}")
    t.add_row("canopy height (m)", f"{geom.mesh.vertices[:, 2].max():.3f}")
    if tiles > 1:
        sizes = [f"{len(p.measured)}+{len(p.buffer)}" for p in parts]
        t.add_row(
            f"tiles (measured+buffer plants), overhead ×{sum(len(p.plant_ids) for p in parts) / (fld.n**2):.2f}",
            ", ".join(sizes),
        )
    console.print(t)
    for path in export or []:
        try:
            values = {
                "measured": seg.set_index("segment_id")["measured"].astype(float),
                "plant_id": seg.set_index("segment_id")["plant_id"].astype(float),
            }
            console.print(f"[green]wrote[/] {plant.export(geom.mesh, path, values)}")
        except InputError as err:
            _fail(err)
    if segments_csv:
        segments_csv.parent.mkdir(parents=True, exist_ok=True)
        seg.to_csv(segments_csv, index=False, float_format="%.8g")
        console.print(f"[green]wrote[/] {segments_csv}")
    if preview:
        console.print(f"[green]wrote[/] {plot_field(geom, preview)}")


def _register_subcommands() -> None:
    """Commands whose code lives with their capability (imports stay lazy inside them)."""
    from lightfit.cli.field_run import field_run
    from lightfit.cli.posterior import posterior
    from lightfit.cli.render_dataset import render_dataset

    app.command("posterior")(posterior)
    app.command("render-dataset")(render_dataset)
    app.command("field-run")(field_run)


_register_subcommands()


if __name__ == "__main__":
    app()
