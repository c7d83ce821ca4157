"""``lightfit field-run``: a field's tiles and time chunks as Dask tasks, gathered into one results netCDF."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import typer

from lightfit.cli.common import THETA_HELP, caution, console, parse_theta, theta_cautions
from lightfit.cli.options import DASK_PANEL as _DASK
from lightfit.cli.options import ConnectTimeout, ModelOptions, Scheduler, Workers, model_options, resolve, scenario
from lightfit.errors import InputError


@model_options
def field_run(
    out: Path = typer.Option(Path("results/field-run/results.nc"), help="Results netCDF (time × segment)."),
    scheduler: Scheduler = None,
    workers: Workers = None,
    threads_per_worker: int = typer.Option(
        None, help="Embedded cluster: threads per worker (Dr.Jit CPU threads too; default 1).", rich_help_panel=_DASK
    ),
    tiles: int = typer.Option(
        1, help="Tiles W: blocks of the measurement area, one task each (× time chunks).", rich_help_panel=_DASK
    ),
    halo_rows: int = typer.Option(
        None,
        help="Geometry around each tile, in plant rows/columns (the reference "
        "paper's approach: smaller scenes, a bias near tile boundaries). Default: the "
        "whole field in every tile (per-segment values bitwise equal to 1 tile).",
        rich_help_panel=_DASK,
    ),
    time_chunks: int = typer.Option(
        1, help="Split the time steps into this many tasks per tile.", rich_help_panel=_DASK
    ),
    timeout: float = typer.Option(
        None, help="Give up waiting for the tasks after this many seconds (default: no limit).", rich_help_panel=_DASK
    ),
    connect_timeout: ConnectTimeout = 30.0,
    theta: str = typer.Option(None, help=THETA_HELP),
    progress: bool = typer.Option(True, help="Progress bar over tiles."),
    resume: bool = typer.Option(
        True,
        help="Take the finished tasks of a killed or timed-out run of the same settings from OUT.parts/, where "
        "every run keeps its finished tasks until the results are written (--no-resume: discard them first).",
    ),
    *,
    model: ModelOptions,
) -> None:
    """Run a field on Dask: tiles (with their halo) and time chunks as tasks, one gathered netCDF."""
    from lightfit.distributed.run import PARTS_SUFFIX, FieldRun, check_cluster_options, run_field
    from lightfit.replication import check_netcdf_name, steps_attrs, when_attrs, write_netcdf
    from lightfit.report import field_label, samples_label

    s = resolve(model)  # the model options' errors first (resolving the leaf may build its albedo table)
    out = check_netcdf_name(out)  # before any plant grows
    check_cluster_options(
        scheduler,
        workers=workers,
        threads_per_worker=threads_per_worker,
        timeout_s=timeout,
        connect_timeout_s=connect_timeout,
    )
    parts = out.with_name(out.name + PARTS_SUFFIX)
    if parts.exists() and not parts.is_dir():
        raise InputError(
            f"{parts} is a file", parameter="out", expected=f"a folder or nothing at {parts} (the finished tasks)"
        )
    th = parse_theta(theta)
    sc = scenario(s)  # one date; its forcing read
    w = sc.weather
    for line in theta_cautions(theta, s.effective(w)):
        caution(line)
    run = FieldRun(sc, tiles=tiles, halo_rows=halo_rows, time_chunks=time_chunks, theta=th)
    sc = run.scenario
    console.print(
        f"{sc.field.area_label}, {field_label(sc.field)}, {tiles} tile(s) × {time_chunks} time "
        f"chunk(s), {len(sc.weather)} steps, {samples_label(sc.samples, sc.target_rse)}, {sc.bounces} bounces, halo: "
        f"{'whole field' if halo_rows is None else f'{halo_rows} rows'}"
    )
    if run.partial_scenes:
        caution(
            f"--halo-rows {halo_rows} < {run.halo_field.exact_halo_rows(tiles)}, which holds the whole field in "
            f"each of the {tiles} tiles: "
            "segments near tile boundaries miss plants that shade them, a bias and not Monte Carlo noise (canopy "
            "APAR +49 % at 1 row, +11 % at 4 in docs/distributed.md's 6 × 6 field), and the ceptometer, which spans "
            "the whole area, is not rendered (its observables NaN); without --halo-rows it is exact"
        )
    if not resume and parts.is_dir():  # after every option is checked: a refused run discards nothing
        shutil.rmtree(parts)
    try:
        ds = run_field(
            run,
            scheduler=scheduler,
            workers=workers,
            threads_per_worker=threads_per_worker,
            progress=progress,
            timeout_s=timeout,
            connect_timeout_s=connect_timeout,
            parts=parts,
        )
    except TimeoutError as err:
        if timeout is None:  # not --timeout's: the message below would misname it (and format None)
            raise
        again = "the same command" if resume else "the command without --no-resume"
        kept = f"no results written; the finished tasks are kept in {parts}: {again} resumes"
        if scheduler and getattr(err, "workers", None) == 0:  # "a longer --timeout" would wait for nothing
            raise InputError(
                f"scheduler={scheduler!r} has no workers: no task ran within --timeout {timeout:g} s ({kept})",
                parameter="scheduler",
                expected="a scheduler with workers (dask worker <address> where they are to run)",
            ) from None
        raise InputError(
            f"the tasks did not finish within {timeout:g} s ({f'{err}; ' if str(err) else ''}{kept})",
            parameter="timeout",
            expected="a longer --timeout, or none",
        ) from None
    cfg = s.replication_config()  # where and when, as replicate records them
    ds.attrs |= when_attrs(cfg, cfg.dates[0]) | steps_attrs(cfg, w) | {"preset": cfg.preset or "none"}
    ds.attrs["replication_config"] = json.dumps(cfg.effective(w))  # as replicate records it
    out.parent.mkdir(parents=True, exist_ok=True)
    write_netcdf(ds, out)
    shutil.rmtree(parts, ignore_errors=True)  # everything is in the results now
    if ds.attrs.get("tasks_resumed"):
        n = ds.attrs["tasks_resumed"]
        console.print(f"resumed: {n} of {ds.attrs['tasks']} tasks were kept from the run before")
    if ds.attrs.get("tasks_discarded"):
        n = ds.attrs["tasks_discarded"]
        console.print(f"run again: {n} task(s) kept by a run of other settings (or unreadable) in {parts}")
    console.print(
        f"{ds.attrs['tasks']} tasks on {ds.attrs['distributed_workers']} worker(s) in "
        f"{ds.attrs['distributed_wall_s']:.1f} s; triangles rendered ÷ measured = "
        f"{ds.attrs['buffer_overhead']:.2f}"
    )
    console.print(f"[green]wrote[/] {out}")
