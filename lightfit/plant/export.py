"""Mesh export with per-face segment ids (and any per-segment value) for other tools.

- OBJ (Wavefront; DART, Blender): one group ``g seg_<id>`` per segment, so the id survives in
  every OBJ reader; values go to a sidecar CSV ``<name>.segments.csv``.
- PLY (binary little-endian; MeshLab, trimesh): face properties ``segment_id`` and one float
  property per value. VTK's PLY reader (9.7, so ParaView) reads the faces without their properties:
  for ParaView write VTK.
- VTK legacy polydata, binary (ParaView, VisIt): ``CELL_DATA`` arrays ``segment_id`` and the values.
  Binary, not ASCII: VTK's ASCII reader reads numbers with C++ ``>>``, which fails on ``nan`` (the
  value of a quantity that does not apply, leaf An on a stem), so ParaView refused the file.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from lightfit.errors import InputError
from lightfit.plant.mesh import Mesh

FORMATS = ("obj", "ply", "vtk")


def _face_values(mesh: Mesh, values: dict[str, pd.Series] | None) -> dict[str, np.ndarray]:
    out = {}
    for name, series in (values or {}).items():
        if not (name.isascii() and name.isidentifier()):  # 'An_µmol' is a Python identifier
            raise InputError(  # but not ASCII: the PLY and VTK headers stopped on a UnicodeEncodeError
                f"value name {name!r} is not a plain identifier",
                parameter=name,
                expected="ASCII letters, digits and underscores (it becomes a file attribute)",
            )
        if name == "segment_id":  # it would overwrite the ids every format writes beside the values
            raise InputError(
                "value name 'segment_id' is the id column's own name",
                parameter=name,
                expected="another name (the ids are written with every value)",
            )
        series = pd.Series(series)
        if series.index.has_duplicates:  # pandas' reindex stopped on "duplicate labels", naming no value
            twice = series.index[series.index.duplicated()].unique()[:5]
            raise InputError(
                f"value {name!r} has more than one entry for segment id(s) {twice.tolist()}",
                parameter=name,
                expected="one value per segment id (a table of several time steps: select one step)",
            )
        absent = ~np.isin(mesh.face_segment, series.index.to_numpy())
        if absent.any():  # a NaN entry is a value (e.g. An of a stem); an absent one is a mistake
            missing = np.unique(mesh.face_segment[absent])[:5]
            raise InputError(
                f"value {name!r} has no entry for segment id(s) {missing.tolist()}",
                parameter=name,
                expected="a value (NaN allowed) for every segment in the mesh",
            )
        try:
            v = series.reindex(mesh.face_segment).to_numpy(dtype=float)
        except (TypeError, ValueError) as e:  # a text column (organ_type) stopped in numpy's conversion
            raise InputError(
                f"value {name!r} is not numeric ({e})",
                parameter=name,
                expected="numbers, booleans or NaN (a category as its integer code)",
            ) from None
        out[name] = v
    return out


def _notes(notes: dict[str, str] | None) -> list[str]:
    """``key: value`` lines saying what the values are (units, time, provenance), checked to fit
    a header line: ASCII, one line each."""
    out = []
    for k, v in (notes or {}).items():
        line = f"{k}: {v}"
        if not line.isascii() or not line.isprintable():
            raise InputError(
                f"note {line!r} cannot go into a mesh file's header",
                parameter="notes",
                expected="printable ASCII on one line (UDUNITS units such as 'umol m-2 s-1')",
            )
        out.append(line)
    return out


def sidecar_path(obj_path: str | Path) -> Path:
    """Where :func:`write_obj` puts the segments' values: OBJ has no face attributes."""
    return Path(obj_path).with_suffix(".segments.csv")


def write_obj(
    mesh: Mesh, path: str | Path, values: dict[str, pd.Series] | None = None, notes: dict[str, str] | None = None
) -> Path:
    """Wavefront OBJ with one group per segment; ``values`` go to ``<path>.segments.csv``."""
    path = Path(path)
    fv = _face_values(mesh, values)  # before the OBJ is written: a refused value left a new OBJ beside an old sidecar
    order = np.argsort(mesh.face_segment, kind="stable")
    seg_sorted = mesh.face_segment[order]
    starts = np.flatnonzero(np.r_[len(order) > 0, seg_sorted[1:] != seg_sorted[:-1]])  # none if no faces
    lines = ["# lightfit shoot mesh; units: m; groups seg_<segment_id>"] + [f"# {n}" for n in _notes(notes)]
    lines += [f"v {x:.7g} {y:.7g} {z:.7g}" for x, y, z in mesh.vertices]
    faces = mesh.faces[order] + 1
    bounds = list(starts) + [len(order)]
    for k in range(len(starts)):
        lines.append(f"g seg_{seg_sorted[starts[k]]}")
        lines += [f"f {a} {b} {c}" for a, b, c in faces[bounds[k] : bounds[k + 1]]]
    path.write_text("\n".join(lines) + "\n", encoding="ascii")
    if fv:
        ids = np.unique(mesh.face_segment)
        side = pd.DataFrame(
            {"segment_id": ids}
            | {
                k: pd.Series(v, index=mesh.face_segment).groupby(level=0).first().reindex(ids).to_numpy()
                for k, v in fv.items()
            }
        )
        # Integer-valued columns (ids, flags, counts) as integers, exact at any size (%.12g rounded a
        # parent id of 10001000007295 to 1.00010000073e+13); the others as the shortest text that
        # reads back to the same double. NaN: an empty cell.
        for k in fv:
            v = side[k].to_numpy()
            known = ~np.isnan(v)  # ±inf keeps its column float
            if np.all(np.isfinite(v[known]) & (v[known] == np.round(v[known])) & (np.abs(v[known]) <= 2.0**53)):
                side[k] = pd.Series(np.where(known, v, 0).astype(np.int64), dtype="Int64").mask(~known)
        side.to_csv(sidecar_path(path), index=False)
    return path


def write_ply(
    mesh: Mesh, path: str | Path, values: dict[str, pd.Series] | None = None, notes: dict[str, str] | None = None
) -> Path:
    """Binary PLY with face properties ``segment_id`` and the values, all ``double``: the PLY format
    has no 64-bit integer (``int64`` was written, which VTK's reader and so ParaView do not know),
    and segment ids (plant id · 10⁶ + index) are exact in a double below 2⁵³."""
    path = Path(path)
    fv = _face_values(mesh, values)
    header = [
        "ply",
        "format binary_little_endian 1.0",
        "comment lightfit shoot mesh, units m",
        *(f"comment {n}" for n in _notes(notes)),
        f"element vertex {len(mesh.vertices)}",
        "property double x",
        "property double y",
        "property double z",
        f"element face {mesh.n_faces}",
        "property list uchar int vertex_indices",
        "property double segment_id",
    ]
    header += [f"property double {k}" for k in fv]
    header.append("end_header")
    vdt = np.dtype([("x", "<f8"), ("y", "<f8"), ("z", "<f8")])
    fdt = np.dtype([("n", "u1"), ("v", "<i4", (3,)), ("segment_id", "<f8")] + [(k, "<f8") for k in fv])
    verts = np.empty(len(mesh.vertices), vdt)
    verts["x"], verts["y"], verts["z"] = mesh.vertices.T
    faces = np.empty(mesh.n_faces, fdt)
    faces["n"], faces["v"], faces["segment_id"] = 3, mesh.faces, mesh.face_segment
    for k, v in fv.items():
        faces[k] = v
    with open(path, "wb") as f:
        f.write(("\n".join(header) + "\n").encode("ascii"))
        f.write(verts.tobytes())
        f.write(faces.tobytes())
    return path


def write_vtk(
    mesh: Mesh, path: str | Path, values: dict[str, pd.Series] | None = None, notes: dict[str, str] | None = None
) -> Path:
    """VTK legacy binary polydata (big-endian, as the format says) with cell arrays ``segment_id``
    and the values, all ``double``: exact ids below 2⁵³ (VTK's long is 32 bits on Windows) and NaN
    kept as NaN (an ASCII ``nan`` stops VTK's reader)."""
    path = Path(path)
    fv = _face_values(mesh, values)
    head = [
        "# vtk DataFile Version 3.0",
        "; ".join(["lightfit shoot mesh (m)", *_notes(notes)])[:255],  # the format's title: one line, 256 bytes
        "BINARY",
        "DATASET POLYDATA",
        f"POINTS {len(mesh.vertices)} double",
    ]
    cells = np.column_stack([np.full(mesh.n_faces, 3), mesh.faces]).astype(">i4")
    with open(path, "wb") as f:
        f.write(("\n".join(head) + "\n").encode("ascii"))
        f.write(np.asarray(mesh.vertices, dtype=">f8").tobytes())
        if not mesh.n_faces:  # VTK's reader fails on "POLYGONS 0 0" ("Error reading polygons"); its
            f.write(b"\n")  # own writer ends the file after the points, as here
            return path
        f.write(f"\nPOLYGONS {mesh.n_faces} {4 * mesh.n_faces}\n".encode("ascii"))
        f.write(cells.tobytes())
        f.write(f"\nCELL_DATA {mesh.n_faces}\n".encode("ascii"))
        for k, v in ({"segment_id": mesh.face_segment} | fv).items():
            f.write(f"SCALARS {k} double 1\nLOOKUP_TABLE default\n".encode("ascii"))
            f.write(np.asarray(v, dtype=">f8").tobytes() + b"\n")
    return path


def mesh_format(path: str | Path) -> str:
    """The mesh format a file name asks for (``obj``, ``ply`` or ``vtk``), or :class:`InputError`
    naming the file (callers check their outputs before the plants are grown)."""
    path = Path(path)
    fmt = path.suffix.lower().lstrip(".")
    if fmt not in FORMATS:
        raise InputError(f"unknown mesh format {path.suffix!r}", file=path, expected="a .obj, .ply or .vtk file name")
    return fmt


def export(
    mesh: Mesh, path: str | Path, values: dict[str, pd.Series] | None = None, notes: dict[str, str] | None = None
) -> Path:
    """Write ``mesh`` in the format named by the suffix of ``path`` (.obj, .ply or .vtk).

    ``notes`` (``{"units of an": "umol m-2 s-1", "time_utc": ...}``) say what the values are: PLY
    ``comment`` and OBJ ``#`` lines, and the VTK title (one line, cut at 255 characters)."""
    path = Path(path)
    fmt = mesh_format(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    return {"obj": write_obj, "ply": write_ply, "vtk": write_vtk}[fmt](mesh, path, values, notes)
