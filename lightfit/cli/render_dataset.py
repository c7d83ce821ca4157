"""``lightfit render-dataset``: a labelled image dataset from a results file."""

from __future__ import annotations

from pathlib import Path

import typer

from lightfit.cli.common import caution, console, output_folder
from lightfit.errors import InputError

#: Help panels: in one table with --out's required mark and -o/-q, the options' columns left too
#: little width at 80 columns and rich cut --sweep-elevation-deg and two examples with "…".
_CAMERAS = "Sweep cameras (without --cameras)"
_IMAGES = "Images and labels"

#: Options that describe the sweep's cameras: with --cameras (whose JSON carries each camera's own
#: settings) they would be ignored, so naming one there is refused.
SWEEP_OPTIONS = (
    "sweep",
    "sweep_distance_m",
    "sweep_elevation_deg",
    "width",
    "height",
    "fov_deg",
    "exposure_mode",
    "exposure_ev",
    "meter_percentile",
)


def render_dataset(
    ctx: typer.Context,
    results: Path = typer.Argument(..., help="Results netCDF of the coupled model (dims time × segment)."),
    out: Path = typer.Option(..., "--out", "-o", help="Dataset directory to write (created if missing)."),
    cameras: Path = typer.Option(None, "--cameras", help="JSON list of cameras (Camera fields); default: a sweep."),
    sweep: int = typer.Option(
        4, "--sweep", help="Cameras on a circle around the field when --cameras is not given.", rich_help_panel=_CAMERAS
    ),
    sweep_distance_m: float = typer.Option(
        1.0, help="Horizontal distance of sweep cameras from the field centre, m.", rich_help_panel=_CAMERAS
    ),
    sweep_elevation_deg: float = typer.Option(
        35.0, help="Elevation of the sweep cameras' line of sight, degrees.", rich_help_panel=_CAMERAS
    ),
    width: int = typer.Option(512, help="Image width of sweep cameras, pixels.", rich_help_panel=_CAMERAS),
    height: int = typer.Option(512, help="Image height of sweep cameras, pixels.", rich_help_panel=_CAMERAS),
    fov_deg: float = typer.Option(
        45.0, help="Horizontal field of view of sweep cameras, degrees.", rich_help_panel=_CAMERAS
    ),
    exposure_mode: str = typer.Option(
        "leaf", help="Sweep cameras' metering: leaf (leaf pixels only), scene or fixed.", rich_help_panel=_CAMERAS
    ),
    exposure_ev: float = typer.Option(
        0.0, help="Exposure compensation of sweep cameras, stops.", rich_help_panel=_CAMERAS
    ),
    meter_percentile: float = typer.Option(
        99.0, help="Leaf metering: percentile of leaf pixels mapped to white.", rich_help_panel=_CAMERAS
    ),
    time: list[str] = typer.Option(
        None,
        "--time",
        help="Results time step(s) (repeatable): HH:MM local site time on the results' day, or ISO 8601 "
        "(UTC unless zoned, e.g. 2016-04-20T10:00 or 2016-04-20T12:00+02:00); default: highest sun.",
        rich_help_panel=_IMAGES,
    ),
    all_times: bool = typer.Option(
        False, "--all-times", help="Render every time step of the results.", rich_help_panel=_IMAGES
    ),
    quantity: list[str] = typer.Option(
        None,
        "--quantity",
        "-q",
        help="Quantity to label (repeatable): absorbed_par, an, vc, vj, gs, limitation, "
        "limitation_margin or a per-segment results variable of the schema (e.g. absorbed_par_mc_sd_umol_m2_s, "
        "the Monte Carlo SD, or reached_rse of an adaptive run); default: all available.",
        rich_help_panel=_IMAGES,
    ),
    spp: int = typer.Option(16, help="Paths per pixel (noise ∝ 1/√spp).", rich_help_panel=_IMAGES),
    max_depth: int = typer.Option(
        4, help="Longest light path in vertices (2 = direct light only).", rich_help_panel=_IMAGES
    ),
    colour: str = typer.Option("rgb", help="rgb or mono (luminance) images.", rich_help_panel=_IMAGES),
    seed: int = typer.Option(
        0, help="Seed of the render and of organ colours (same seed → same images).", rich_help_panel=_IMAGES
    ),
    threads: int = typer.Option(
        None, help="Dr.Jit render threads (default: Dr.Jit's choice).", rich_help_panel=_IMAGES
    ),
    weather: str = typer.Option(
        None, help="Weather (bundled name or file) for results that carry no sun/sky (refused for those that do)."
    ),
    depth: bool = typer.Option(True, "--depth/--no-depth", help="Write the depth_m label."),
    gallery: int = typer.Option(4, help="Images in gallery.png (0 = none)."),
    export: str = typer.Option("ply", help="Coloured field geometry: ply, vtk or none."),
    cache_dir: Path = typer.Option(None, help="Plant cache directory (default: lightfit's)."),
) -> None:
    """Render synthetic images with dense functional labels (absorbed PAR, An, Fj/Fc limitation) from a run.

    The labels are the run's values per segment; the images' colours are visible-band materials of
    the data scene (lightfit.dataset.VisualMaterials: green leaves, loam soil), not the run's PAR
    leaf optics or fitted leaf parameters, which describe another waveband.
    """
    from rich.markup import escape

    from lightfit.dataset import Camera, DatasetSpec, RenderSettings, Sweep, load_cameras, make_dataset

    output_folder(out)
    if cameras:
        # By name: typer vendors click, so click's own ParameterSource is another enum.
        given = [n for n in SWEEP_OPTIONS if getattr(ctx.get_parameter_source(n), "name", "") == "COMMANDLINE"]
        if given:  # the sweep's settings; the JSON cameras keep their own (e.g. exposure_mode) silently
            flags = ", ".join("--" + n.replace("_", "-") for n in given)
            raise InputError(
                f"{flags} with --cameras",
                parameter="cameras",
                expected='each camera\'s settings in the --cameras JSON (e.g. "exposure_mode": "scene"); '
                f"{flags} set the sweep's cameras only",
            )
    if time and all_times:
        raise InputError("--time and --all-times both given", parameter="time", expected="one of them")
    cam_fields = {
        "width_px": width,
        "height_px": height,
        "fov_deg": fov_deg,
        "exposure_mode": exposure_mode,
        "exposure_ev": exposure_ev,
        "meter_percentile": meter_percentile,
    }
    Camera(**cam_fields)  # validate the sweep camera settings before any geometry is built
    spec = DatasetSpec(
        cameras=load_cameras(cameras) if cameras else [],
        sweep=Sweep(n=sweep, distance_m=sweep_distance_m, elevation_deg=sweep_elevation_deg, camera=cam_fields),
        times=["all"] if all_times else (list(time or []) or None),
        quantities=tuple(quantity) if quantity else None,
        settings=RenderSettings(spp=spp, max_depth=max_depth, colour=colour, seed=seed, threads=threads),
        weather=weather,
        depth=depth,
        gallery_images=gallery,
        export=export,
        cache_dir=str(cache_dir) if cache_dir else None,
    )
    meta = make_dataset(results, out, spec)
    for im in meta["images"]:
        clip = im["exposure"]["clipped_leaf_fraction"]
        clip_txt = "no leaf in view" if clip is None else f"clipped leaf pixels {clip:.1%}"
        console.print(f"{escape(im['name'])}: {im['pixels']['leaf']} leaf px, {clip_txt}")
    if not quantity:  # the default set keeps what the results have: say what it left out
        from lightfit.dataset import DEFAULT_QUANTITIES

        left = [q for q in DEFAULT_QUANTITIES if q not in meta["quantities"]]
        if left:
            console.print(f"labels: {', '.join(meta['quantities'])}; not in the results: {', '.join(left)}")
    pc = meta.get("periodic_canopy") or {}
    if pc.get("capped_by_max_faces"):  # only metadata.json said it (a newcomer's audit)
        caution(
            f"the periodic canopy was cut at {pc['copies']} copies of the cell ({pc['plant_faces']:,} faces): it "
            f"covers {pc['reach_m']:.2f} m of the {pc['requested_reach_m']:.2f} m the cameras see, bare soil beyond; "
            "closer or steeper cameras see none of it"
        )
    n = meta["cameras_taken_over"]
    taken = f", {n} camera(s) rendered by the interrupted run" if n else ""
    if meta["cameras_discarded"]:
        taken += f", {meta['cameras_discarded']} camera(s) of an interrupted run of other settings rendered again"
    console.print(
        f"wrote {len(meta['images'])} image(s) with labels to {escape(str(out))} "
        f"({meta['render']['variant']}, {meta['render']['spp']} spp{taken})"
    )
