"""``lightfit field``: build a field of CPlantBox wheat, report it, export and preview its mesh."""

from __future__ import annotations

from pathlib import Path

import typer
from rich.table import Table

from lightfit.cli.common import console, output_file
from lightfit.cli.options import (
    BOUNDARY_HELP,
    BUFFER_ALONG_HELP,
    BUFFER_ROWS_HELP,
    HEADINGS_HELP,
    PARAMETER_FILE_HELP,
    PLANT_SPACING_HELP,
    PLANTS_PER_ROW_HELP,
    ROW_DIRECTION_HELP,
    ROW_SPACING_HELP,
    SEASON_START_HELP,
    SHEATHS_HELP,
    check_boundary,
)
from lightfit.defaults import (
    DEFAULT_DATE,
    DEFAULT_PARAMETER_FILE,
    DEFAULT_PLANT_SPACING_M,
    DEFAULT_ROW_DIRECTION_DEG,
    DEFAULT_ROW_SPACING_M,
    HEADINGS,
    MESH_ACROSS,
    MESH_ALONG,
    MESH_AROUND,
    SHEATHS,
)
from lightfit.errors import InputError


def field(
    n_plants: int = typer.Option(
        None,
        help="Plants in the measurement area, rounded up to a square N×N or to whole rows with "
        "--plants-per-row (default: the main job's, as replicate and field-run build; --quick: theirs).",
        show_default=False,
    ),
    plants_per_row: int = typer.Option(None, help=PLANTS_PER_ROW_HELP, show_default=False),
    quick: bool = typer.Option(False, "--quick", help="The small field of replicate --quick and field-run --quick."),
    # the help texts say the defaults with their reasons (shared with the model commands' options)
    row_spacing: float = typer.Option(DEFAULT_ROW_SPACING_M, help=ROW_SPACING_HELP, show_default=False),
    plant_spacing: float = typer.Option(DEFAULT_PLANT_SPACING_M, help=PLANT_SPACING_HELP, show_default=False),
    boundary: str = typer.Option("periodic", help=BOUNDARY_HELP),
    buffer_rows: int = typer.Option(None, help=BUFFER_ROWS_HELP),
    buffer_along: int = typer.Option(None, help=BUFFER_ALONG_HELP),
    sheaths: str = typer.Option(SHEATHS[0], help=SHEATHS_HELP),
    headings: str = typer.Option(HEADINGS[0], help=HEADINGS_HELP),
    row_direction: float = typer.Option(DEFAULT_ROW_DIRECTION_DEG, help=ROW_DIRECTION_HELP),
    field_seed: int = typer.Option(
        1, "--field-seed", help="Field seed: plant seeds derive from it and each plant's grid position."
    ),
    parameter_file: str = typer.Option(DEFAULT_PARAMETER_FILE, help=PARAMETER_FILE_HELP),
    season_start: str = typer.Option(None, help=SEASON_START_HELP),
    date: str = typer.Option(DEFAULT_DATE, help="Date the plants are grown to."),
    tiles: int = typer.Option(1, help="Partition the measurement area into this many tiles (each with its buffer)."),
    tile: int = typer.Option(None, help="Build only this tile (0-based) with its buffer ring."),
    along: int = typer.Option(MESH_ALONG, help="Mesh subdivisions along each segment."),
    across: int = typer.Option(MESH_ACROSS, help="Mesh subdivisions across each leaf blade."),
    around: int = typer.Option(MESH_AROUND, help="Sides of stem/sheath prisms."),
    export: list[Path] = typer.Option(None, help="Write the mesh: .obj, .ply or .vtk (repeatable)."),
    preview: Path = typer.Option(
        None, help="Write an image with top and side views; the suffix gives the format (.png, .pdf, .svg, …)."
    ),
    segments_csv: Path = typer.Option(
        None,
        "--segments",
        help="Write the segment table (G1) as CSV: coordinates x0…z1 in m (field coordinates, z up), "
        "length_m, radius_m, blade_width_m in m, blade_area_m2 in m², creation_time_d in days after "
        "the season start, bx by bz the branching direction (lightfit.plant.growth's table); '# key: value' lines "
        "above it say the field and the units (read it with pandas.read_csv(path, comment='#')).",
    ),
) -> None:
    """Build a field of CPlantBox wheat: report plants, segments, triangles; export and preview."""
    import numpy as np

    from lightfit import plant
    from lightfit.figure import figure_format
    from lightfit.plant.export import mesh_format, sidecar_path
    from lightfit.plant.preview import plot_field
    from lightfit.replication import ReplicationConfig
    from lightfit.report import field_label

    if n_plants is None:  # the field the model commands run, so that a preview shows it
        n_plants = (ReplicationConfig.quick() if quick else ReplicationConfig()).n_plants
    buffer_rows, buffer_along = check_boundary(boundary, buffer_rows, buffer_along)
    sidecars = set()  # the OBJs' files of values beside them
    for path in export or []:  # before minutes of plant growth
        if mesh_format(output_file(path, "export")) == "obj":
            sidecars.add(output_file(sidecar_path(path), "export").resolve())
    if preview:
        figure_format(output_file(preview, "preview"))
    if segments_csv:
        output_file(segments_csv, "segments_csv")
        if segments_csv.resolve() in sidecars:  # one file would silently replace the other
            raise InputError(
                f"{segments_csv} is also the OBJ export's sidecar of per-segment values",
                parameter="segments_csv",
                expected="another file name than the --export OBJ's <name>.segments.csv",
            )
    g = plant.GrowthConfig(parameter_file, season_start, date)
    fld = plant.Field(
        n_plants,
        row_spacing,
        plant_spacing,
        buffer_rows,
        row_direction,
        field_seed,
        g,
        buffer_along,
        boundary,
        sheaths,
        headings,
        plants_per_row,
    )
    parts = fld.tiles(tiles)
    if tile is not None and not 0 <= tile < len(parts):
        raise InputError(f"tile {tile} does not exist", parameter="tile", expected=f"0 … {len(parts) - 1}")
    res = plant.MeshResolution(along, across, around)
    geom = plant.build(fld, tile=parts[tile] if tile is not None else None, resolution=res, progress=True)
    seg = geom.segments
    meas = seg[seg["measured"]]
    area_m2 = fld.ground_area_m2
    t = Table(
        title=f"field {fld.area_label} measured, "
        f"{field_label(fld)}, grown "
        f"{g.season_start} → {g.target_date} ({g.days:.0f} d), {g.path.name}",
        caption="blade area, leaf area index, heights and inclination: the measured plants only "
        "(buffer plants are geometry only)",
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
    t.add_row("leaf sheaths", fld.sheaths)
    t.add_row("plant headings", fld.headings)
    t.add_row("triangles", str(geom.mesh.n_faces))
    t.add_row("triangles per plant", f"{geom.mesh.n_faces / len(geom.plants):.0f}")
    # The plant summary is the measured plants' (the tile's with --tile), as the LAI is: buffer plants
    # are geometry only. It averaged every plant built, buffer included, beside a measured-only LAI.
    blade_m2 = meas["blade_area_m2"].sum()
    t.add_row("one-sided leaf blade area per measured plant (m²)", f"{blade_m2 / max(n_meas, 1):.4f}")
    if tile is None:
        t.add_row("leaf area index of the measurement area", f"{blade_m2 / area_m2:.2f}")
    # A crew's canopy height is a typical plant's top, not the one tallest leaf tip of the field.
    tops = meas[["z0", "z1"]].max(axis=1).groupby(meas["plant_id"]).max()
    t.add_row("plant height, mean of the measured plants' tops (m)", f"{tops.mean():.3f}")
    measured_mesh = geom.mesh.of_faces(np.isin(geom.mesh.face_segment, meas["segment_id"].to_numpy()))
    t.add_row(
        "highest point of the measured plants' mesh (m)", f"{measured_mesh.vertices[measured_mesh.faces, 2].max():.3f}"
    )
    t.add_row(
        "blade inclination, measured plants' mean (° from horizontal)", f"{measured_mesh.blade_inclination_deg():.1f}"
    )
    if tiles > 1:
        sizes = [f"{len(p.measured)}+{len(p.buffer)}" for p in parts]
        t.add_row(
            f"tiles (measured+buffer plants), overhead ×{sum(len(p.plant_ids) for p in parts) / fld.n_measured:.2f}",
            ", ".join(sizes),
        )
    console.print(t)
    for path in export or []:
        values = {
            "measured": seg.set_index("segment_id")["measured"].astype(float),
            "plant_id": seg.set_index("segment_id")["plant_id"].astype(float),
        }
        console.print(f"[green]wrote[/] {plant.export(geom.mesh, path, values)}")
        if mesh_format(path) == "obj":
            side = sidecar_path(path)
            console.print(f"[green]wrote[/] {side} (measured and plant_id per segment: OBJ has no face values)")
    if segments_csv:
        from lightfit.files import replace_text
        from lightfit.weather.readers import metadata_lines

        segments_csv.parent.mkdir(parents=True, exist_ok=True)
        # With --tile the table is one tile's scene: its measured plants are the tile's, and the rest of
        # the field's measured plants are its buffer (False). Without the tile said, the file read as the
        # whole field's with most of its measured plants unmeasured (a review).
        part = {} if tile is None else {"tile": f"{tile} of {len(parts)} (0-based)"}
        whose = "a measured plant's" if tile is None else "a plant the tile measures"
        head = {  # what the table is and stands on, as lightfit's other CSVs say it (read with comment="#")
            "provenance": "synthetic (CPlantBox plants grown and placed by lightfit, not measured)",
            **fld.attrs(),
            **part,
            # n_plants is the number asked for; the area holds it rounded up to a square or whole rows
            "measured_plants": f"{n_meas} ("
            + (fld.area_label if tile is None else f"tile {tile}'s of the field's {fld.area_label}")
            + ")",
            "measured_ground_area_m2": f"{fld.measured_area_m2(parts[tile] if tile is not None else None):.8g}",
            "columns": "x0 y0 z0 x1 y1 z1 in m (field coordinates, z up); bx by bz a unit vector (the parent "
            "organ's axis where the organ branches off); length_m, radius_m, blade_width_m in m; blade_area_m2 "
            f"in m2 (one side); creation_time_d in days after season_start; measured True for {whose} "
            "segment, False for a buffer plant's; docs/plant.md",
        }
        replace_text(segments_csv, metadata_lines(head) + seg.to_csv(index=False, float_format="%.8g"))
        console.print(f"[green]wrote[/] {segments_csv}")
    if preview:
        console.print(f"[green]wrote[/] {plot_field(geom, preview)}")
