"""Write a labelled synthetic image dataset from a coupled-model results file.

Layout of the dataset directory::

    metadata.json                 cameras, times, sun and sky, exposure, parameters, version
    images/<cam>_<time>.exr       HDR radiance, W m⁻² sr⁻¹ per channel (float32)
    images/<cam>_<time>.png       tone-mapped 8-bit sRGB (camera exposure applied)
    labels/<cam>_<time>.npz       dense labels (see :mod:`lightfit.dataset.labels`)
    gallery.png                   a few images with their labels side by side (like Fig. 3)
    field_values.<ply|vtk>        the coloured field: per-face values of the first time step
"""

from __future__ import annotations

import json
import math
import shutil
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

import lightfit
from lightfit.dataset.camera import Camera, Sweep, camera_sweep, check_unique_names
from lightfit.dataset.exposure import meter, tone_map, write_exr, write_png
from lightfit.dataset.labels import class_map, geometric_labels, quantity_map
from lightfit.dataset.render import RENDER_REVISION, RenderSettings, load_camera, render, variant_for
from lightfit.dataset.results import (
    MARGIN,
    Results,
    build_geometry,
    field_of,
    lighting,
    lighting_provenance,
    open_results,
    select_times,
    synthetic_values,
)
from lightfit.dataset.scene import ORGAN_CODES, VisualMaterials, periodic_canopy, scene_arrays, view_reach_m
from lightfit.errors import InputError, check_integer
from lightfit.files import replace_text

DEFAULT_QUANTITIES = ("absorbed_par", "an", "vc", "vj", "gs", "limitation", MARGIN)
EXPORT_FORMATS = ("ply", "vtk", "none")
#: Class-valued quantities get int8 label maps; the rest float32.
CLASS_QUANTITIES = ("limitation",)


@dataclass
class DatasetSpec:
    """Everything that decides a dataset besides the results file.

    Attributes:
        cameras: explicit cameras; if empty, ``sweep`` generates them around the field.
        sweep: camera sweep used when ``cameras`` is empty.
        times: ISO timestamps of results steps, ``["all"]``, or ``None`` = the highest sun.
        quantities: per-segment quantities to label (short names of
            :data:`~lightfit.dataset.results.QUANTITIES`, full variable names, or
            ``limitation_margin``); quantities absent from the results are skipped only when
            left at the default, otherwise an error.
        settings: renderer knobs (spp, path depth, colour, seed, threads).
        materials: visual materials of the data scene.
        weather: weather source (bundled name or file) for results that carry no sun/sky; refused
            for results that do (their sun and sky lit the labels).
        depth: write the ``depth_m`` label.
        gallery_images: images shown in ``gallery.png`` (0 = no gallery).
        export: ``"ply"``, ``"vtk"`` or ``"none"`` for the coloured field geometry.
        cache_dir: plant cache directory (``None`` = lightfit's default).
    """

    cameras: list[Camera] = field(default_factory=list)
    sweep: Sweep = field(default_factory=Sweep)
    times: list[str] | None = None
    quantities: tuple[str, ...] | None = None
    settings: RenderSettings = field(default_factory=RenderSettings)
    materials: VisualMaterials = field(default_factory=VisualMaterials)
    weather: str | None = None
    depth: bool = True
    gallery_images: int = 4
    export: str = "ply"
    cache_dir: str | None = None


#: Folder in an output folder while :func:`make_dataset` writes it: ``job.json`` (:func:`_job_key`)
#: and each camera's rendered arrays as soon as it is rendered (:func:`~lightfit.dataset.render.save_camera`).
#: An output folder holding it and no metadata.json is an interrupted run's: the same command keeps
#: the cameras rendered and renders the rest.
UNFINISHED = ".unfinished"


def _job_key(arrays, cams, lights, settings: RenderSettings, materials: VisualMaterials) -> str:
    """Hash of everything a camera's render depends on: the scene's arrays (geometry, colours,
    transmission), the cameras, the lighting of each time, the render settings but its thread count,
    the materials, the variant that would render, lightfit's version and the renderer's revision
    (:data:`~lightfit.dataset.render.RENDER_REVISION`). Options that change only
    what is written from the renders (labels, export, gallery) are not in it: those files are
    written again from the kept renders."""
    import hashlib

    h = hashlib.sha256()
    for a in (arrays.vertices, arrays.faces, arrays.face_rgb, arrays.face_transmission):
        h.update(np.ascontiguousarray(a).tobytes())
    job = {
        "cameras": [c.to_dict() for c in cams],
        "lights": [lt.to_dict() for lt in lights],
        "settings": {k: v for k, v in asdict(settings).items() if k != "threads"},
        "materials": asdict(materials),
        "variant": variant_for(settings.colour)[0],
        "lightfit": lightfit.__version__,
        "render_revision": RENDER_REVISION,
    }
    h.update(json.dumps(job, sort_keys=True, default=str).encode())
    return h.hexdigest()[:32]


def _unfinished(out: Path, job: str, started: bool) -> tuple[Path, int]:
    """The marker folder of ``out``: kept with its rendered cameras when it is the same job's
    (``started``: an interrupted run left files), else (re)made empty for this job; and how many
    cameras an interrupted run of another job had rendered there (discarded, to be said)."""
    marker = out / UNFINISHED
    if started and marker.is_dir():
        try:
            if json.loads((marker / "job.json").read_text()).get("job") == job:
                return marker, 0
        except (OSError, ValueError, AttributeError):
            pass
    discarded = 0
    if marker.is_dir():
        discarded = len(list(marker.glob("camera_*.npz")))
        shutil.rmtree(marker)
    elif marker.exists():  # an older version's marker file
        marker.unlink()
    marker.mkdir(parents=True)
    replace_text(marker / "job.json", json.dumps({"job": job}))
    return marker, discarded


def make_dataset(results, out_dir: str | Path, spec: DatasetSpec = DatasetSpec()) -> dict:
    """Render ``spec``'s cameras at its times and write the dataset to ``out_dir``; return the metadata.

    Each camera's render is kept in the folder's marker (:data:`UNFINISHED`) as soon as it is
    done, so an interrupted run loses at most the camera it was rendering: the same call takes the
    finished cameras over (their images bitwise those of an uninterrupted run: each image's random
    numbers depend on its camera's and time's index only) and renders the rest in one batch;
    ``meta["cameras_taken_over"]`` counts them; ``meta["cameras_discarded"]`` those an interrupted
    run of other settings (cameras, lights, render settings, materials, scene) had rendered.
    """
    if spec.export not in EXPORT_FORMATS:
        raise InputError(f"export={spec.export!r}", parameter="export", expected=" or ".join(EXPORT_FORMATS))
    check_integer(spec.gallery_images, "gallery_images", 0)
    out = Path(out_dir)
    earlier = [d for d in ("images", "labels") if (out / d).is_dir() and any((out / d).iterdir())]
    started = (out / UNFINISHED).exists() and not (out / "metadata.json").exists()
    if earlier and not started:  # their files would mix with this dataset's, while metadata.json lists only this one's
        raise InputError(
            f"the output folder already holds a dataset ({', '.join(f'{d}/' for d in earlier)} not empty)",
            file=out,
            expected="a new or empty output folder (-o)",
        )
    res = results if isinstance(results, Results) else open_results(results)
    quantities = resolve_quantities(res, spec.quantities)
    tix = select_times(res, spec.times)
    per_segment = {t: {q: res.values(q, t) for q in quantities} for t in tix}
    for t in tix:  # labels of NaN alone would pass for a labelled image: before anything renders
        for q, v in per_segment[t].items():
            if not np.isfinite(v.to_numpy(dtype=float)).any():
                raise InputError(
                    f"quantity {q} has no finite value at {res.times[t]:%Y-%m-%d %H:%M} UTC",
                    file=res.path or "results",
                    parameter="quantities",
                    expected="a step with values (--time), or another quantity",
                )
    lights = lighting(res, tix, spec.weather)
    geom = build_geometry(res, cache_dir=spec.cache_dir)
    cams = spec.cameras or camera_sweep(spec.sweep, canopy_height_m=_canopy_height(geom.segments))
    check_unique_names(cams)
    # A periodic field is one cell of an endless canopy: the scene repeats the cell as far as the
    # cameras see the ground (copies keep segment ids, so labels name the plant imaged).
    mesh, periodic = geom.mesh, None
    if geom.cell is not None:
        reach = view_reach_m(cams, geom.cell.center_xy, spec.materials.periodic_max_reach_m)
        mesh, periodic = periodic_canopy(geom.mesh, geom.cell, reach)
    arrays = scene_arrays(mesh, geom.segments, spec.materials, seed=spec.settings.seed)
    marker, discarded = _unfinished(out, _job_key(arrays, cams, lights, spec.settings, spec.materials), started)
    for d in earlier:  # written again from the marker's cameras
        shutil.rmtree(out / d)
    kept = {c: load_camera(marker / f"camera_{c}.npz", len(lights)) for c in range(len(cams))}
    todo = [c for c, k in kept.items() if k is None]
    rendered = None
    if todo:
        rendered = render(arrays, [cams[c] for c in todo], lights, spec.settings, spec.materials, todo, marker)
        for i, c in enumerate(todo):
            kept[c] = (rendered.radiance[i], rendered.face[i], rendered.depth_m[i])

    (out / "images").mkdir(parents=True, exist_ok=True)
    (out / "labels").mkdir(exist_ok=True)
    images = []
    for c, cam in enumerate(cams):
        radiance, face, depth = kept[c]
        geo = geometric_labels(face, depth, mesh, geom.segments)
        if not spec.depth:
            geo.pop("depth_m")
        for k, t in enumerate(tix):
            images.append(_write_image(out, cam, res.times[t], t, lights[k], radiance[k], geo, per_segment[t]))
    meta = _metadata(res, spec, quantities, cams, images, rendered)
    meta["cameras_taken_over"] = len(cams) - len(todo)
    meta["cameras_discarded"] = discarded  # an interrupted run's of other settings: rendered again
    meta["field_boundary"] = "periodic" if periodic else "finite"
    # What the rebuild used, including the defaults of files written before a setting existed.
    fld = field_of(res)
    meta["field_sheaths"], meta["field_headings"] = fld.sheaths, fld.headings
    if periodic:
        meta["periodic_canopy"] = periodic
    meta["lighting"] = lighting_provenance(res, spec.weather)
    if spec.gallery_images and images:
        from lightfit.dataset.gallery import gallery

        units = {q: res.units(q) for q in quantities}
        shown = images[: spec.gallery_images]
        meta["gallery"] = gallery(out, shown, quantities, units, results=res, lighting=meta["lighting"]).name
    if spec.export != "none":
        # The file says which step, whose values and their units: opened alone (MeshLab, ParaView) it said none
        when = res.times[tix[0]].isoformat()  # the first selected step's
        notes = {
            "time_utc": when,
            "values": "SYNTHETIC (not a model run)" if synthetic_values(res.ds.attrs) else "model output",
            "results_file": ascii(Path(res.path).name)[1:-1] if res.path else "in memory",  # a header's ASCII
        } | {f"units of {q}": res.units(q) for q in quantities}
        path = out / f"field_values.{spec.export}"
        meta["field_export"] = export_field(geom.mesh, per_segment[tix[0]], path, notes)
        meta["field_export"]["time_utc"] = when
    replace_text(out / "metadata.json", json.dumps(meta, indent=2, default=_json_default))
    shutil.rmtree(marker)
    return meta


def resolve_quantities(res: Results, requested) -> list[str]:
    """Validated quantity names; the default set keeps only those the results can provide."""
    if requested is None:
        have = []
        for q in DEFAULT_QUANTITIES:
            try:
                res.variable(q if q != MARGIN else "vc"), res.variable(q if q != MARGIN else "vj")
                have.append(q)
            except InputError:
                continue
        if not have:  # images with no label but the geometry's would pass for a labelled dataset
            raise InputError(
                "the results hold none of the label quantities",
                file=res.path or "results",
                expected="a results file of the coupled model (absorbed PAR, leaf An, Vc, Vj, gs, limitation)",
            )
        return have
    for q in requested:
        res.variable(q)
        if q == MARGIN:
            res.variable("vc"), res.variable("vj")
    return list(dict.fromkeys(requested))


def _canopy_height(segments: pd.DataFrame) -> float:
    return float(segments[["z0", "z1"]].to_numpy().max()) if len(segments) else 0.5


def _stem(cam: Camera, time: pd.Timestamp) -> str:
    """``<camera>_<UTC time>``, to the minute, with seconds where the time has them: steps less
    than a minute apart wrote one file (a review)."""
    return f"{cam.name}_{time.strftime('%Y%m%dT%H%M')}{time.strftime('%S') if time.second else ''}Z"


def _write_image(out: Path, cam: Camera, time, t: int, light, radiance: np.ndarray, geo: dict, values: dict) -> dict:
    """Write one image's EXR, PNG and label npz; return its metadata entry."""
    stem = _stem(cam, time)
    labels = dict(geo)
    valid = np.zeros(geo["segment_id"].shape, dtype=bool)
    for q, v in values.items():
        f, known = quantity_map(geo["segment_id"], v.astype(float))
        valid |= known
        labels[q] = class_map(f) if (q in CLASS_QUANTITIES or v.name in CLASS_QUANTITIES) else f
    labels["valid"] = valid
    leaf = geo["organ"] == ORGAN_CODES["leaf"]
    exp = meter(radiance, leaf, cam)
    write_exr(radiance, out / "images" / f"{stem}.exr")
    write_png(tone_map(radiance, exp.gain), out / "images" / f"{stem}.png")
    np.savez_compressed(out / "labels" / f"{stem}.npz", **labels)
    counts = {name: int((geo["organ"] == code).sum()) for name, code in ORGAN_CODES.items()}
    return {
        "name": stem,
        "camera": cam.name,
        "time_utc": time.isoformat(),
        "time_index": int(t),
        "exr": f"images/{stem}.exr",
        "png": f"images/{stem}.png",
        "labels": f"labels/{stem}.npz",
        "lighting": light.to_dict(),
        "exposure": exp.to_dict(),
        "pixels": counts | {"valid": int(valid.sum())},
    }


def export_field(mesh, values: dict[str, pd.Series], path: Path, notes: dict[str, str] | None = None) -> dict:
    """Write the faces of segments with results (a finite value of some quantity), per-face values
    attached (NaN where a quantity does not apply: leaf An on stems and sheaths).

    Uses :func:`lightfit.plant.export` (PLY or VTK by suffix). Buffer plants (no results) are left
    out; the counts are returned for the metadata. ``notes`` (time, provenance, units) go into
    the file's header.
    """
    from lightfit.plant import export

    numeric = {q: v.astype(float) for q, v in values.items()}
    keep = np.zeros(mesh.n_faces, dtype=bool)
    for v in numeric.values():  # a stem has PAR but no An: kept (every stem was left out)
        keep |= np.isfinite(v.reindex(mesh.face_segment).to_numpy())
    if not keep.any():
        return {"file": None, "faces": 0, "faces_left_out": int(mesh.n_faces), "reason": "no segment has finite values"}
    sub = mesh.of_faces(keep)
    export(sub, path, values=numeric, notes=notes)
    return {"file": path.name, "faces": int(keep.sum()), "faces_left_out": int((~keep).sum()), "values": list(numeric)}


def _metadata(res: Results, spec: DatasetSpec, quantities, cams, images, rendered) -> dict:
    return {
        "lightfit_version": lightfit.__version__,
        "results_file": str(res.path) if res.path else None,
        "results_attrs": {k: res.ds.attrs[k] for k in res.ds.attrs},
        "synthetic_values": synthetic_values(res.ds.attrs),
        "render": asdict(spec.settings) | _how_rendered(spec.settings, rendered),
        "materials": asdict(spec.materials),
        "cameras": [c.to_dict() for c in cams],
        "quantities": {q: {"variable": res.variable(q), "units": res.units(q)} for q in quantities},
        "label_codes": {
            "organ": ORGAN_CODES,
            "segment_id_background": -1,
            "plant_id_background": -1,
            "limitation": {
                "1": "electron-transport limited (Fj < Fc; below the CO2 compensation point the larger rate limits)",
                "0": "Rubisco limited (Fc <= Fj, ties included; reversed below the CO2 compensation point)",
                "-1": "no value",
            },
            "float_no_value": "NaN (see 'valid')",
            "depth_m": "distance along the optical axis, m; NaN = sky",
            MARGIN: "(Vj - Vc)/(Vj + Vc): > 0 Fj > Fc (red), < 0 Fj < Fc (blue)",
        },
        "image_units": "HDR radiance W m-2 sr-1 per channel under a white sun (DNI) and "
        + (
            "a white CIE standard overcast sky of horizontal irradiance DHI (the run's sky)"
            if res.ds.attrs.get("sky") == "overcast"
            else "isotropic white sky (DHI/pi)"
        ),
        "labels_sampling": "one ray through each pixel centre; images average spp jittered paths per pixel",
        "images": images,
    }


def _how_rendered(settings: RenderSettings, rendered) -> dict:
    """The variant that rendered and whether in this process (``rendered``: the last camera's
    output; ``None`` when every image was taken over from an interrupted run: the variant chosen
    now, which chose theirs)."""
    if rendered is not None:
        return {"variant": rendered.variant, "in_process": rendered.in_process}
    variant, here = variant_for(settings.colour)
    return {"variant": variant, "in_process": here}


def _json_default(o):
    if isinstance(o, (np.integer,)):
        return int(o)
    if isinstance(o, (np.floating,)):
        return None if not math.isfinite(o) else float(o)
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, np.bool_):
        return bool(o)
    return str(o)
