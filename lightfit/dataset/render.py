"""Render the data scene: HDR radiance per (camera, time) and per-pixel hits per camera.

**Variant choice (why a subprocess).** A process holds one Mitsuba variant at a time: switching
it invalidates every object built in the other (the model scene, the JAX bridge's kernels), and
``lightfit.light.backend.mitsuba()`` returns whichever variant was set first. So the data scene
renders *in this process* only when the active variant already has the requested colour mode
(``rgb`` or ``mono``), or when no variant is active yet and the requested mode is the one
lightfit would pick by default (``mono``). Otherwise it renders in a child Python process
(``python -m lightfit.dataset.worker``) that sets ``<llvm|cuda>_ad_<mode>``; the arrays go
through a temporary ``.npz``. Results are identical either way for the same variant and seed.

**Determinism.** The image is the mean of ``spp`` passes of one path per pixel. Pass k of image
i uses sub-pixel jitter from ``numpy.random.default_rng([seed, i, k])`` and a Mitsuba
``independent`` sampler seeded with a 32-bit hash of the same triple; every lane is independent
and the passes are averaged in numpy in a fixed order, so the same seed gives the same image bit
for bit on one machine (no atomic accumulation into a film).

**Labels** come from one ray through each pixel centre (no jitter): the face hit (index into
the scene's faces, −1 for sky) and the depth along the optical axis, m.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from lightfit.dataset.camera import Camera
from lightfit.dataset.scene import Lighting, SceneArrays, VisualMaterials
from lightfit.errors import InputError, check_integer
from lightfit.files import UNREADABLE_NPZ, load_npz
from lightfit.light.keyed_random import check_seed
from lightfit.light.scene import ISOTROPIC_RADIANCE_PER_DHI, overcast_radiance_per_dhi, sun_vector

COLOURS = ("rgb", "mono")
#: How the scene's arrays become a Mitsuba scene; raised when that changes what a render gives for the
#: same arrays (an interrupted run's kept cameras are then rendered again). 2: diff_trans = 2τ.
RENDER_REVISION = 2


@dataclass(frozen=True)
class RenderSettings:
    """Knobs of the image renderer (speed against noise).

    Attributes:
        spp: paths per pixel (≥ 1); noise falls as 1/√spp.
        max_depth: longest path, in vertices (Mitsuba ``path`` convention: 2 = direct light
            only, 4 = up to two indirect bounces among leaves and soil).
        colour: ``"rgb"`` (3 channels) or ``"mono"`` (1 channel, luminance).
        seed: base seed; the same seed gives the same images.
        threads: Dr.Jit worker threads for rendering; ``None`` leaves Dr.Jit's setting alone.
    """

    spp: int = 16
    max_depth: int = 4
    colour: str = "rgb"
    seed: int = 0
    threads: int | None = None

    def __post_init__(self):
        for k, lo in (("spp", 1), ("max_depth", 2)):
            check_integer(getattr(self, k), k, lo)
        if self.colour not in COLOURS:
            raise InputError(f"colour={self.colour!r}", parameter="colour", expected=" or ".join(COLOURS))
        check_seed(self.seed)
        if self.threads is not None and (not isinstance(self.threads, (int, np.integer)) or self.threads < 1):
            raise InputError(f"threads={self.threads!r}", parameter="threads", expected="an integer ≥ 1 or None")


@dataclass
class RenderOutput:
    """What :func:`render` returns.

    Attributes:
        radiance: ``radiance[c][t]`` (H, W, C) float32 HDR radiance, W m⁻² sr⁻¹ per channel,
            for camera c and lighting t.
        face: ``face[c]`` (H, W) int64 index of the scene face under each pixel centre, −1 = sky.
        depth_m: ``depth_m[c]`` (H, W) float32 distance along the optical axis, m; NaN = sky.
        variant: the Mitsuba variant that rendered.
        in_process: whether it rendered in this process.
    """

    radiance: list[list[np.ndarray]]
    face: list[np.ndarray]
    depth_m: list[np.ndarray]
    variant: str
    in_process: bool


def variant_for(colour: str) -> tuple[str, bool]:
    """(variant to render with, whether this process can use it without switching)."""
    from lightfit.light import backend

    active = backend._STATE.get("info")  # noqa: SLF001 - read-only look at what the process holds
    if active is not None:
        prefix = active.variant.rsplit("_", 1)[0]
        return f"{prefix}_{colour}", active.variant.endswith("_" + colour)
    default, _ = backend.choose_variant(None, mode=backend.DEFAULT_MODE)
    prefix = default.rsplit("_", 1)[0]
    return f"{prefix}_{colour}", default.endswith("_" + colour)


def pass_seed(seed: int, image: int, k: int) -> int:
    """32-bit sampler seed of pass ``k`` of image ``image``."""
    return int(np.random.SeedSequence([int(seed), int(image), int(k)]).generate_state(1)[0])


def render(
    arrays: SceneArrays,
    cameras: list[Camera],
    lights: list[Lighting],
    settings: RenderSettings = RenderSettings(),
    materials: VisualMaterials = VisualMaterials(),
    camera_index: list[int] | None = None,
    save_dir: Path | None = None,
) -> RenderOutput:
    """Render every camera under every lighting, in this process or a child (module docstring).

    ``camera_index``: each camera's index in the whole set (default 0, 1, …), which with the
    lighting's index seeds each image, so that cameras rendered apart give the images of one call.
    ``save_dir``: each camera's arrays are saved there as soon as it is rendered
    (:func:`save_camera`), so that an interrupted render keeps its finished cameras."""
    if not cameras:
        raise InputError("no cameras", parameter="cameras", expected="at least one camera")
    if not lights:
        raise InputError("no time steps to render", parameter="times", expected="at least one time step")
    variant, here = variant_for(settings.colour)
    if here:
        out = render_here(arrays, cameras, lights, settings, materials, variant, camera_index, save_dir)
        return RenderOutput(*out, variant=variant, in_process=True)
    return _render_child(arrays, cameras, lights, settings, materials, variant, camera_index, save_dir)


def _camera_index(cameras, camera_index) -> list[int]:
    """Each camera's index in the whole set (:func:`render`): 0, 1, … unless given."""
    return list(range(len(cameras))) if camera_index is None else [int(c) for c in camera_index]


def save_camera(save_dir: Path, index: int, radiance: list[np.ndarray], face: np.ndarray, depth: np.ndarray) -> Path:
    """One rendered camera's arrays (its images under every lighting, the face and depth under
    each pixel centre) as ``save_dir/camera_<index>.npz``, written whole or not at all."""
    from lightfit.files import replaced

    path = Path(save_dir) / f"camera_{int(index)}.npz"
    with replaced(path) as tmp:
        with open(tmp, "wb") as f:
            np.savez(f, face=face, depth=depth, **{f"radiance_{t}": r for t, r in enumerate(radiance)})
    return path


def load_camera(path: Path, n_lights: int) -> tuple[list[np.ndarray], np.ndarray, np.ndarray] | None:
    """A camera saved by :func:`save_camera` (``None``: missing, unreadable or of another count of
    lightings)."""
    try:
        with load_npz(path) as z:
            return [z[f"radiance_{t}"] for t in range(n_lights)], z["face"], z["depth"]
    except UNREADABLE_NPZ:  # damaged: rendered again
        return None


def render_here(arrays, cameras, lights, settings, materials, variant, camera_index=None, save_dir=None):
    """Render in this process with ``variant`` (must not switch an active variant)."""
    from lightfit.light.backend import mitsuba

    mi = mitsuba(variant)
    import drjit as dr

    if settings.threads is not None:
        dr.set_thread_count(int(settings.threads))
    index = _camera_index(cameras, camera_index)
    scene_of = _SceneBuilder(mi, dr, arrays, materials)
    radiance, faces, depths = [], [], []
    for ci, cam in enumerate(cameras):
        face, depth = _primary_hits(mi, dr, scene_of.scene(None), cam)
        faces.append(face)
        depths.append(depth)
        radiance.append(
            [
                _radiance(mi, dr, scene_of.scene(light), cam, settings, index[ci] * len(lights) + ti)
                for ti, light in enumerate(lights)
            ]
        )
        if save_dir is not None:
            save_camera(save_dir, index[ci], radiance[-1], face, depth)
    return radiance, faces, depths


class _SceneBuilder:
    """One shared plant+soil mesh; a Mitsuba scene per lighting (sun and sky emitters)."""

    def __init__(self, mi, dr, arrays: SceneArrays, materials: VisualMaterials):
        self.mi, self.cache = mi, {}
        props = mi.Properties()
        # principledthin: a thin two-sided sheet with diffuse transmission — leaves lit from
        # behind glow as in real images; transmission 0 on soil and stems.
        props["bsdf"] = mi.load_dict(
            {
                "type": "principledthin",
                "roughness": float(materials.roughness),
                "base_color": {"type": "mesh_attribute", "name": "face_rgb"},
                "diff_trans": {"type": "mesh_attribute", "name": "face_transmission"},
            }
        )
        mesh = mi.Mesh("data_scene", len(arrays.vertices), len(arrays.faces), props, False, False)
        mesh.add_attribute("face_rgb", 3, mi.Float(np.ascontiguousarray(arrays.face_rgb, dtype=np.float32).ravel()))
        # principledthin's diff_trans runs from 0 to 2 and is halved inside (its documentation):
        # diff_trans = 2τ sends the share τ of the diffuse light through, 1 − τ back (passed τ as is,
        # leaves transmitted half the documented share; a review, tested against hand values).
        mesh.add_attribute(
            "face_transmission",
            1,
            mi.Float(np.ascontiguousarray(2.0 * np.asarray(arrays.face_transmission), dtype=np.float32)),
        )
        p = mi.traverse(mesh)
        p["vertex_positions"] = dr.ravel(mi.Point3f(np.ascontiguousarray(arrays.vertices.T, dtype=np.float32)))
        p["faces"] = dr.ravel(mi.Vector3u(np.ascontiguousarray(arrays.faces.T, dtype=np.uint32)))
        p.update()
        self.mesh = mesh

    def scene(self, light: Lighting | None):
        key = None if light is None else tuple(asdict(light).values())
        if key not in self.cache:
            d = {"type": "scene", "field": self.mesh}
            if light is not None:
                d |= _emitters(light)
            self.cache[key] = self.mi.load_dict(d)
        return self.cache[key]


def _emitters(light: Lighting) -> dict:
    """Sun (directional, DNI) above the horizon and the sky: isotropic, radiance DHI/π, or the CIE
    overcast sky with the same DHI (:func:`_overcast_sky`)."""
    out = {}
    if light.sun_elevation_deg > 0 and light.dni_w_m2 > 0:
        s = sun_vector(light.sun_elevation_deg, light.sun_azimuth_deg)
        out["sun"] = {
            "type": "directional",
            "direction": (-s).tolist(),
            "irradiance": {"type": "rgb", "value": float(light.dni_w_m2)},
        }
    if light.dhi_w_m2 > 0:
        if light.sky == "overcast":
            out["sky"] = _overcast_sky(light.dhi_w_m2)
        else:
            radiance = float(light.dhi_w_m2) * ISOTROPIC_RADIANCE_PER_DHI
            out["sky"] = {"type": "constant", "radiance": {"type": "rgb", "value": radiance}}
    return out


#: Rows of the overcast sky's latitude–longitude map (zenith angle 0–180° in 0.7° rows; the
#: horizon on a row boundary). Its horizontal irradiance is DHI to 0.1 % (tests/test_dataset.py).
OVERCAST_ROWS = 256


def _overcast_sky(dhi_w_m2: float) -> dict:
    """Mitsuba ``envmap`` of the CIE standard overcast sky whose horizontal irradiance is ``dhi_w_m2``:
    radiance by zenith angle from :func:`lightfit.light.scene.overcast_radiance_per_dhi`, 0 below the
    horizon, the map's up axis (+Y) turned to the scene's +Z."""
    from lightfit.light.backend import mitsuba

    mi = mitsuba()
    theta = (np.arange(OVERCAST_ROWS) + 0.5) / OVERCAST_ROWS * np.pi
    cos_z = np.cos(theta)
    row = np.where(cos_z > 0, dhi_w_m2 * overcast_radiance_per_dhi(cos_z), 0.0).astype(np.float32)
    img = np.repeat(np.repeat(row[:, None, None], 2 * OVERCAST_ROWS, axis=1), 3, axis=2)
    return {
        "type": "envmap",
        "bitmap": mi.Bitmap(np.ascontiguousarray(img)),
        "to_world": mi.ScalarTransform4f().rotate([1, 0, 0], 90),
    }


def _rays(mi, cam: Camera, dirs: np.ndarray):
    n = len(dirs)
    o = [np.full(n, c, dtype=np.float32) for c in cam.position_m]
    d = np.ascontiguousarray(dirs.T, dtype=np.float32)
    return mi.Ray3f(mi.Point3f(*o), mi.Vector3f(d[0], d[1], d[2]))


def _primary_hits(mi, dr, scene, cam: Camera) -> tuple[np.ndarray, np.ndarray]:
    """Face index (−1 = sky) and depth along the optical axis (m, NaN = sky) at pixel centres."""
    dirs = cam.directions()
    si = scene.ray_intersect(_rays(mi, cam, dirs))
    valid = np.array(si.is_valid(), dtype=bool)
    face = np.where(valid, np.array(si.prim_index, dtype=np.int64), -1)
    t = np.array(si.t, dtype=np.float64)
    depth = np.where(valid, t * (dirs @ cam.basis()[2]), np.nan).astype(np.float32)
    shape = (cam.height_px, cam.width_px)
    return face.reshape(shape), depth.reshape(shape)


def _radiance(mi, dr, scene, cam: Camera, settings: RenderSettings, image: int) -> np.ndarray:
    """Mean of ``spp`` one-path-per-pixel passes, (H, W, C) float32, W m⁻² sr⁻¹."""
    integrator = mi.load_dict({"type": "path", "max_depth": int(settings.max_depth), "hide_emitters": False})
    sampler = mi.load_dict({"type": "independent"})
    n = cam.height_px * cam.width_px
    acc = None
    for k in range(settings.spp):
        jitter = np.random.default_rng([settings.seed, image, k]).random((cam.height_px, cam.width_px, 2))
        # Opaque seed: a literal would compile a new kernel for every pass.
        sampler.seed(dr.opaque(mi.UInt32, pass_seed(settings.seed, image, k)), n)
        spec, _, _ = integrator.sample(scene, sampler, _rays(mi, cam, cam.directions(jitter)))
        a = np.array(spec, dtype=np.float64).reshape(-1, n).T
        acc = a if acc is None else acc + a
    img = (acc / settings.spp).reshape(cam.height_px, cam.width_px, -1)
    return np.nan_to_num(img, nan=0.0, posinf=0.0).astype(np.float32)


def _render_child(
    arrays, cameras, lights, settings, materials, variant, camera_index=None, save_dir=None
) -> RenderOutput:
    """Render in ``python -m lightfit.dataset.worker`` with ``variant``; arrays via a temp .npz."""
    with tempfile.TemporaryDirectory(prefix="lightfit-render-") as tmp:
        job, out = Path(tmp) / "job.npz", Path(tmp) / "out.npz"
        spec = {
            "cameras": [c.to_dict() for c in cameras],
            "lights": [lt.to_dict() for lt in lights],
            "settings": asdict(settings),
            "materials": asdict(materials),
            "variant": variant,
            "camera_index": _camera_index(cameras, camera_index),
            "save_dir": None if save_dir is None else str(save_dir),
            "n_plant_faces": arrays.n_plant_faces,
        }
        np.savez(
            job,
            vertices=arrays.vertices,
            faces=arrays.faces,
            face_rgb=arrays.face_rgb,
            face_transmission=arrays.face_transmission,
            spec=np.array(json.dumps(spec)),
        )
        env = dict(os.environ)
        env.pop("LIGHTFIT_VARIANT", None)  # the worker sets the variant explicitly
        proc = subprocess.run(
            [sys.executable, "-m", "lightfit.dataset.worker", str(job), str(out)],
            capture_output=True,
            text=True,
            env=env,
        )
        if proc.returncode != 0:
            raise RuntimeError(
                f"data-scene render in a child process ({variant}) failed with exit code "
                f"{proc.returncode}:\n{proc.stderr[-4000:]}"
            )
        with np.load(out) as z:
            nc, nt = len(cameras), len(lights)
            radiance = [[z[f"radiance_{c}_{t}"] for t in range(nt)] for c in range(nc)]
            return RenderOutput(
                radiance,
                [z[f"face_{c}"] for c in range(nc)],
                [z[f"depth_{c}"] for c in range(nc)],
                variant=variant,
                in_process=False,
            )


def run_job(job: Path, out: Path) -> None:
    """Worker side of :func:`_render_child`."""
    with np.load(job) as z:
        spec = json.loads(str(z["spec"]))
        arrays = SceneArrays(z["vertices"], z["faces"], z["face_rgb"], z["face_transmission"], spec["n_plant_faces"])
    cameras = [Camera(**{k: tuple(v) if isinstance(v, list) else v for k, v in c.items()}) for c in spec["cameras"]]
    lights = [Lighting(**lt) for lt in spec["lights"]]
    settings = RenderSettings(**spec["settings"])
    m = spec["materials"]
    materials = VisualMaterials(**{k: tuple(v) if isinstance(v, list) else v for k, v in m.items()})
    radiance, faces, depths = render_here(
        arrays, cameras, lights, settings, materials, spec["variant"], spec["camera_index"], spec["save_dir"]
    )
    arrays_out = {f"face_{c}": f for c, f in enumerate(faces)} | {f"depth_{c}": d for c, d in enumerate(depths)}
    arrays_out |= {f"radiance_{c}_{t}": r for c, row in enumerate(radiance) for t, r in enumerate(row)}
    np.savez(out, **arrays_out)
