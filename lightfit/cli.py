"""The ``lightfit`` command line: one entry point, one subcommand per task."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from lightfit.errors import InputError

app = typer.Typer(help="Differentiable light and photosynthesis for wheat canopies.", no_args_is_help=True,
                  pretty_exceptions_enable=False)
weather_app = typer.Typer(help="Read, check, convert and plot weather series.", no_args_is_help=True)
app.add_typer(weather_app, name="weather")
console = Console()
err_console = Console(stderr=True)

_STATE: dict[str, str | None] = {"variant": None}


@app.callback()
def _main(variant: str = typer.Option(None, "--variant", envvar="LIGHTFIT_VARIANT",
                                      help="Mitsuba variant, e.g. llvm_ad_mono or cuda_ad_mono (default: auto).")):
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
    for pkg in ("lightfit", "jax", "jaxlib", "drjit", "mitsuba", "optimistix", "jaxopt", "emcee", "cplantbox",
                "pvlib", "numpy", "pandas", "xarray", "trimesh"):
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
        df = weather.read_weather(weather.bundled_path(source), date=date or weather.BUNDLED[source][1], max_gap=max_gap)
    else:
        df = weather.read_weather(source, format=fmt, date=date, tz=tz, max_gap=max_gap)
    return weather.add_solar(df, split_model=split)


_SHORT = {"par_umol_m2_s": "PAR", "ghi_w_m2": "GHI", "dni_w_m2": "DNI", "dhi_w_m2": "DHI", "sun_elevation_deg": "sun°",
          "tair_c": "T °C", "rh": "RH", "pair_kpa": "p kPa", "co2_ppm": "CO2"}


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
        t.add_row(ts.strftime("%m-%d %H:%M"), ts.tz_convert(tz).strftime("%H:%M"),
                  *(f"{row[c]:.{_DIGITS.get(c, 0)}f}" for c in cols))
    return t


def _report(df) -> None:
    a = df.attrs
    console.print(f"[bold]source[/] {a.get('source')}  [bold]format[/] {a.get('format')}  "
                  f"[bold]provenance[/] [magenta]{a.get('provenance')}[/]  [bold]timestamps assumed in[/] {a.get('timezone_assumed')}")
    for k, v in a.get("columns_used", {}).items():
        if k != v:
            console.print(f"  {k:>14} ← {v}")
    if a.get("unused_columns"):
        console.print(f"  [dim]not used: {', '.join(a['unused_columns'])}[/]")
    for q in a.get("qc", []):
        console.print(f"  [yellow]repair[/] {q['kind']}: {escape(q['detail'])}")


@weather_app.command("show")
def weather_show(
    source: str = typer.Argument("2016-04-20", help="A bundled series name (2016-04-20, selhausen-cplantbox-day) or a file."),
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
    console.print(_table(df, f"{df.attrs.get('provenance', '').upper()} weather: {Path(str(df.attrs.get('source'))).name}"))
    if plot:
        console.print(f"plot → {plot_forcing(df, plot)}")
    if csv:
        meta = {"provenance": df.attrs["provenance"], "source": str(df.attrs.get("source")),
                "qc": json.dumps(df.attrs.get("qc", []), ensure_ascii=False)}
        console.print(f"csv → {weather.write_lightfit_csv(df, csv, meta)}")


@app.command()
def replicate(
    out: Path = typer.Option(Path("results/2016-04-20"), help="Output directory."),
    weather_file: Path = typer.Option(None, "--weather", help="A real TERENO export (or other weather file) to use "
                                      "instead of the bundled reconstructed forcing."),
    start: str = typer.Option("2016-04-20 05:00", help="First time step, local time (Europe/Berlin)."),
    hours: float = typer.Option(14.0, help="Length of the diurnal run, hours."),
    step: str = typer.Option("30min", help="Time step of the run."),
    how: str = typer.Option("sample", help="How the step is taken from the 10-min data: sample (as the reference paper) or mean."),
):
    """The main job: the 20 April 2016 Selhausen replication.

    Currently: prepares and shows the forcing of the diurnal run (table, CSV, PNG). The
    light, photosynthesis and calibration stages join as they land.
    """
    from lightfit import weather
    from lightfit.weather.plot import plot_forcing

    try:
        src = weather.read_weather(weather_file) if weather_file else weather.read_weather(weather.bundled_path("2016-04-20"))
        src = weather.add_solar(src)
        run = weather.window(src, start, hours, step, how=how)
    except InputError as err:
        _fail(err)
    out.mkdir(parents=True, exist_ok=True)
    _report(src)
    label = src.attrs["provenance"].upper()
    console.print(_table(run, f"{label} forcing of the diurnal run ({len(run)} steps of {step})"))
    meta = {"provenance": src.attrs["provenance"], "source": str(src.attrs.get("source")),
            "note": f"{len(run)} steps of {step} from {start} local ({how})"}
    csv = weather.write_lightfit_csv(run, out / "forcing.csv", meta)
    png = plot_forcing(src.loc[run.index[0]:run.index[-1]], out / "forcing.png",
                       title=f"{label} forcing, Selhausen {start[:10]} — {Path(str(src.attrs.get('source'))).name}")
    console.print(f"[green]wrote[/] {csv}\n[green]wrote[/] {png}")


if __name__ == "__main__":
    app()
