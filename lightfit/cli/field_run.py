"""Command line: run a field's tiles on Dask (``lightfit field-run``, registered by ``lightfit/cli.py``).

:func:`field_run` is a plain typer command function; this module also has its own ``app``
(``python -m lightfit.cli.field_run --help``) for use before registration.
"""

from __future__ import annotations

from pathlib import Path

import typer

from lightfit.errors import InputError


def field_run(
    out: Path = typer.Option(Path("results/field-run/results.nc"), help="Results netCDF (time × segment)."),
    scheduler: str = typer.Option(
        None, help="Join this Dask scheduler (e.g. tcp://host:8786) instead of starting an embedded LocalCluster."
    ),
    workers: int = typer.Option(
        None,
        help="Embedded cluster: worker processes (default: one per GPU, else one "
        "per core, at most one per 2 GiB of memory).",
    ),
    threads_per_worker: int = typer.Option(
        None, help="Embedded cluster: threads per worker (Dr.Jit CPU threads too; default 1)."
    ),
    tiles: int = typer.Option(1, help="Tiles W: blocks of the measurement area, one task each (× time chunks)."),
    halo_rows: int = typer.Option(
        None,
        help="Geometry around each tile, in plant rows/columns (the reference "
        "paper's approach: smaller scenes, a bias near tile boundaries). Default: the "
        "whole field in every tile (per-segment values bitwise equal to 1 tile).",
    ),
    time_chunks: int = typer.Option(1, help="Split the time steps into this many tasks per tile."),
    n_plants: int = typer.Option(100, help="Plants in the measurement area (rounded up to a square)."),
    buffer_rows: int = typer.Option(2, help="Buffer rows around the measurement area."),
    seed: int = typer.Option(1, help="Field seed (plant seeds derive from it and the plant's position)."),
    samples: int = typer.Option(64, help="Irradiance samples per segment K."),
    bounces: int = typer.Option(3, help="Scattering orders."),
    render_seed: int = typer.Option(0, help="Seed of the irradiance sample streams (common random numbers)."),
    weather_file: Path = typer.Option(
        None,
        "--weather",
        help="Weather file (default: the bundled 2016-04-20 reconstructed forcing, 29 half-hour steps).",
    ),
    steps: str = typer.Option(
        None, help="Time steps to run: a count from the start of the day (e.g. 5) or positions a:b (default: all)."
    ),
    par_kind: str = typer.Option("absorbed", help="PAR observable: incident or absorbed."),
    an_per: str = typer.Option("ground", help="Canopy An per ground or leaf area."),
    timeout: float = typer.Option(
        None, help="Give up waiting for the tasks after this many seconds (default: no limit)."
    ),
    connect_timeout: float = typer.Option(30.0, help="Give up connecting to the scheduler after this many seconds."),
    progress: bool = typer.Option(True, help="Progress bar over tiles."),
):
    """Run a field on Dask: tiles (with their halo) and time chunks as tasks, one gathered netCDF."""
    from rich.console import Console

    from lightfit.distributed.run import FieldRun, run_field
    from lightfit.plant import Field
    from lightfit.replication import forcing, write_netcdf

    console = Console()
    try:
        w = forcing(weather_file)
        if steps:
            w = w.iloc[_steps(steps, len(w))]
        run = FieldRun(
            field=Field(n_plants=n_plants, buffer_rows=buffer_rows, seed=seed),
            weather=w,
            tiles=tiles,
            halo_rows=halo_rows,
            time_chunks=time_chunks,
            samples=samples,
            bounces=bounces,
            seed=render_seed,
            par_kind=par_kind,
            an_per=an_per,
        )
        console.print(
            f"{run.field.n}² plants + {buffer_rows} buffer rows, {tiles} tile(s) × {time_chunks} time "
            f"chunk(s), {len(w)} steps, K={samples}, {bounces} bounces, halo: "
            f"{'whole field' if halo_rows is None else f'{halo_rows} rows'}"
        )
        ds = run_field(
            run,
            scheduler=scheduler,
            workers=workers,
            threads_per_worker=threads_per_worker,
            progress=progress,
            timeout_s=timeout,
            connect_timeout_s=connect_timeout,
        )
    except InputError as err:
        console.print(f"[red]error:[/] {err}")
        raise typer.Exit(2) from None
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    write_netcdf(ds, out)
    console.print(
        f"{ds.attrs['tasks']} tasks on {ds.attrs['distributed_workers']} worker(s) in "
        f"{ds.attrs['distributed_wall_s']:.1f} s; triangles rendered ÷ measured = "
        f"{ds.attrs['buffer_overhead']:.2f}"
    )
    console.print(f"[green]wrote[/] {out}")


def _steps(text: str, n: int):
    try:
        if ":" in text:
            a, _, b = text.partition(":")
            sl = slice(int(a) if a else None, int(b) if b else None)
            if not range(n)[sl]:
                raise ValueError
            return sl
        k = int(text)
        if not 1 <= k <= n:
            raise ValueError
        return slice(0, k)
    except ValueError:
        raise InputError(f"steps={text!r}", column="steps", expected=f"a count 1…{n} or positions a:b") from None


app = typer.Typer(add_completion=False)
app.command("field-run")(field_run)


@app.callback()
def _root():
    """lightfit distributed runs."""


if __name__ == "__main__":
    app()
