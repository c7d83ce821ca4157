"""``lightfit weather …``: read, check, convert and plot weather series (a sub-app)."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from lightfit.cli.common import console, weather_report, weather_table

app = typer.Typer(help="Read, check, convert and plot weather series.", no_args_is_help=True)


def load(source: str, fmt: str, date: str | None, tz: str | None, max_gap: str, split: str, time_label=None):
    """A bundled series (by name) or a file, in the weather contract with solar columns."""
    from lightfit import weather

    more = {} if time_label is None else {"time_label": time_label}
    df = weather.read_source(source, format=fmt, date=date, tz=tz, max_gap=max_gap, **more)
    return weather.add_solar(df, split_model=split)


@app.command("show")
def show(
    source: str = typer.Argument(
        "2016-04-20", help="A bundled series name (2016-04-20, selhausen-cplantbox-day) or a file."
    ),
    fmt: str = typer.Option("auto", "--format", help="auto, tereno, cplantbox or lightfit."),
    date: str = typer.Option(None, help="Calendar date for undated files (CPlantBox day), YYYY-MM-DD."),
    tz: str = typer.Option(None, help="Timezone of the file's timestamps (default: the format's convention)."),
    time_label: str = typer.Option(
        None,
        help="Where a TERENO or CPlantBox file stamps each mean in its interval: end (the default), start "
        "or center; the sun is taken at the interval's centre. --csv records it for every later command.",
    ),
    max_gap: str = typer.Option("30min", help="Longest gap to interpolate."),
    split: str = typer.Option("erbs", help="Direct/diffuse split model: erbs or boland."),
    resample: str = typer.Option(None, help="New time step, e.g. 30min."),
    how: str = typer.Option(
        "mean", help="Resampling: mean (whole intervals; a centred window for instants) or sample."
    ),
    plot: Path = typer.Option(None, help="Write a plot here; the suffix gives the format (.png, .pdf, .svg, …)."),
    csv: Path = typer.Option(None, help="Write the contract series as CSV here."),
) -> None:
    """Read a weather series, report its checks and repairs, print it, optionally plot/convert."""
    from lightfit import weather
    from lightfit.figure import figure_format
    from lightfit.weather.plot import plot_forcing

    weather.require_date(source, date)  # an undated file: say --date, as the model commands do
    if plot:
        figure_format(plot)
    df = load(source, fmt, date, tz, max_gap, split, time_label)
    if resample:
        df = weather.resample(df, resample, how)
    weather_report(df)
    name = Path(str(df.attrs.get("source"))).name
    console.print(weather_table(df, f"{df.attrs.get('provenance', '').upper()} weather: {name}"))
    if plot:
        console.print(f"plot → {plot_forcing(df, plot)}")
    if csv:
        meta = {
            "provenance": df.attrs["provenance"],
            "source": str(df.attrs.get("source")),
            "qc": json.dumps(df.attrs.get("qc", []), ensure_ascii=False),
        }
        console.print(f"csv → {weather.write_lightfit_csv(df, csv, meta)}")
