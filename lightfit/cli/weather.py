"""``lightfit weather …``: the ``show`` command, which reads a weather series, reports its checks and
repairs and prints it, and converts it to a lightfit CSV (``--csv``) or plots it (``--plot``)."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from lightfit.cli.common import LightfitCommand, console, output_file, weather_report, weather_table
from lightfit.cli.options import SPLIT_HELP, ModelOptions, option, site_of

app = typer.Typer(
    help="Weather series: 'show' reads one (a bundled name or a file), reports its checks and repairs and "
    "prints it; with --csv it converts it to a lightfit CSV, with --plot it plots it.",
    no_args_is_help=True,
)


def load(
    source: str,
    fmt: str,
    date: str | None,
    tz: str | None,
    max_gap: str,
    split: str,
    time_label=None,
    provenance: str | None = None,
    site=None,
):
    """A bundled series (by name) or a file, in the weather contract with solar columns (the sun at
    ``site``, default Selhausen)."""
    from lightfit import weather

    more = {} if time_label is None else {"time_label": time_label}
    if provenance is not None:
        more["provenance"] = provenance
    df = weather.read_source(source, format=fmt, date=date, tz=tz, max_gap=max_gap, **more)
    return weather.add_solar(df, site=site, split_model=split)


@app.command("show", cls=LightfitCommand)
def show(
    source: str = typer.Argument(
        "2016-04-20", help="A bundled series name (2016-04-20, selhausen-cplantbox-day) or a file."
    ),
    fmt: str = typer.Option("auto", "--format", help="auto, tereno, cplantbox or lightfit."),
    date: str = typer.Option(
        None, help="Calendar date for undated files (CPlantBox day), YYYY-MM-DD; refused for dated files."
    ),
    tz: str = typer.Option(
        None,
        help="Timezone of a TERENO or CPlantBox file's timestamps, an IANA name or UTC±H (default: the TERENO "
        "header's 'Time zone:', else the format's convention); refused for a lightfit CSV (UTC).",
    ),
    provenance: str = typer.Option(
        None,
        help="What the file is where it does not say: measured (a real sensor record), reconstructed or "
        "synthetic. Default: the file's own word, else 'unstated'. Contradicting the file is refused.",
    ),
    time_label: str = typer.Option(
        None,
        help="Where a TERENO or CPlantBox file stamps each mean in its interval: end (the default), start "
        "or center; the sun is taken at the interval's centre. --csv records it for every later command.",
    ),
    max_gap: str = typer.Option(
        "30min", help="Longest gap to interpolate, a time span with its unit (e.g. 30min, 2h; 0min: none)."
    ),
    split: str = typer.Option(None, help=SPLIT_HELP),
    resample: str = typer.Option(None, help="New time step, a time span with its unit, e.g. 30min or 1h."),
    how: str = typer.Option(
        None,
        help="Resampling (with --resample): mean (whole intervals; a centred window for instants; the default) or "
        "sample. The model commands' --how defaults to sample (each step's instant, where its sun is taken).",
    ),
    plot: Path = typer.Option(None, help="Write a plot here; the suffix gives the format (.png, .pdf, .svg, …)."),
    csv: Path = typer.Option(None, help="Write the contract series as CSV here."),
    site: option("site") = None,
    latitude: option("latitude") = None,
    longitude: option("longitude") = None,
    altitude_m: option("altitude_m") = None,
    timezone: option("timezone") = None,
) -> None:
    """Read a weather series, report its checks and repairs and print it; --csv converts it, --plot plots it."""
    from lightfit import weather
    from lightfit.errors import InputError
    from lightfit.figure import figure_format
    from lightfit.weather.plot import plot_forcing, provenance_label

    weather.require_date(source, date, fmt)  # an undated file: say --date, as the model commands do
    if date is not None and not weather.is_undated(source, fmt):
        raise InputError(
            f"--date {date} given for a file whose timestamps carry their dates",
            file=weather.source_path(source),
            expected="no --date (it places an undated CPlantBox day only)",
        )
    # before the series is read: a folder given as --csv failed after the table, naming a temporary file
    if plot:
        figure_format(output_file(plot, "plot"))
    if csv:
        output_file(csv, "csv")
    if how is not None:  # it was checked only with --resample: --how foo alone passed unsaid
        weather.series.check_how(how)
        if not resample:
            raise InputError(
                f"--how {how} given without --resample", parameter="how", expected="--resample STEP with it"
            )
    coords = {"latitude": latitude, "longitude": longitude, "altitude_m": altitude_m, "timezone": timezone}
    where = site_of(ModelOptions(site=site, **coords))
    df = load(source, fmt, date, tz, max_gap, split, time_label, provenance, where)
    if resample:
        df = weather.resample(df, resample, how or "mean")
    weather_report(df)
    name = Path(str(df.attrs.get("source"))).name
    console.print(weather_table(df, f"{provenance_label(df.attrs)} weather: {name} at {where.name}", tz=where.timezone))
    if plot:
        console.print(f"plot → {plot_forcing(df, plot, tz=where.timezone)}")
    if csv:
        meta = {
            "provenance": df.attrs["provenance"],
            "source": str(df.attrs.get("source")),
            "qc": json.dumps(df.attrs.get("qc", []), ensure_ascii=False),
        }
        console.print(f"csv → {weather.write_lightfit_csv(df, csv, meta)}")
