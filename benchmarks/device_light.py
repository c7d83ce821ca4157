"""Issue 16 item 4, prepared for a session that is lent a GPU: the 500-plant cell in ``cuda_ad_mono``.

    python benchmarks/device_light.py prepare [--n-plants 500] [--sheaths wrapped|rods]  # here, once (≈ 1 min)
    bash benchmarks/device_light.sh                                                      # there, through `run`

The device machine (docs/benchmarks.md, "GPU") has Python 3.12, numpy, pandas, scipy, rich and JAX,
no network and no Mitsuba, and a call carries at most 64 MiB. ``prepare`` therefore writes, into the
git-ignored folder ``device/``:

* ``wheels/``: the cp312 Mitsuba and Dr.Jit wheels (the versions pinned in pyproject.toml) with what
  lightfit never loads taken out — the other eight ``*_ad_*`` and the scalar variants' extension
  modules, the headers, the spectral upsampling table and the volume, curve and other plugins that
  no lightfit scene names — 64 → 31 MiB;
* ``geometry.npz``: the bench cell's mesh (``build(Field(n_plants, seed=1, boundary="periodic",
  sheaths=sheaths))``, as ``bench_light.py`` grows it, ``--sheaths`` default the model's default;
  CPlantBox is not needed there), its periodic cell, the PROSPECT-D optics, each segment's organ
  class, the commit it was prepared at and the sheaths (the results' ``prepared``, and their
  ``sheaths``: absent or None where prepared before it was recorded, with rods), and a reference
  render made here (``llvm_ad_mono``, the first setting, seed 11: absorbed PAR and its SE per
  segment).

``run`` (what ``device_light.sh`` calls there, after installing the wheels) first renders the first
setting with seed 12 and compares it with the reference segment by segment (median |z| of the
difference in units of its combined SE, the share above 4, the canopy totals): the GPU's answer
must be the CPU's within Monte Carlo noise before its time means anything. The reverse-mode
gradient with respect to the three leaf parameters is checked too, against the one ``prepare``
made here with the same seed (rounding apart, equal) and against central differences with common
random numbers there, and timed against the primal. Then it renders the cell with
the projection in the variant lightfit picks (``cuda_ad_mono`` where a CUDA device is usable) at
rising ray densities, through ``bench_light.direct_projection_comparison`` (the same two seeds,
the same R-corrected and pooled medians, the same later step of a day), and writes
``$OUT/device_light.json`` after every setting, so a run stopped at its time limit keeps what it
finished. It stops adding settings past ``--budget-s``. A dry run of the whole path on this
machine: ``prepare --python-version 3.11 --n-plants 16`` then ``device_light.sh`` with
``LIGHTFIT_VARIANT=llvm_ad_mono DEVICE_LIGHT_ARGS="--budget-s 60 --settings 16:1e6:2e6"``.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import time
import zipfile
from pathlib import Path

import numpy as np

import lightfit  # noqa: F401  (before Dr.Jit: lightfit.light.backend sets up libLLVM)
from lightfit.precision import use_float64

use_float64()  # lightfit's precision policy (lightfit.precision), before any JAX array exists

ROOT = Path(__file__).resolve().parents[1]
DEVICE = ROOT / "device"
PINS = ("mitsuba==3.9.1", "drjit==1.5.0")
# Variants lightfit can pick (lightfit.light.backend: cuda_ad_mono or llvm_ad_mono); the others go.
KEEP_VARIANTS = ("cuda_ad_mono", "llvm_ad_mono")
# Plugins no lightfit scene names and Mitsuba does not create by default (a scene without a sensor
# still gets a perspective sensor, an hdrfilm, a gaussian filter and an independent sampler).
UNUSED_PLUGINS = {
    "volpath", "volpathmis", "ptracer", "prbvolpath", "ellipsoids", "ellipsoidsmesh", "sdfgrid",
    "bsplinecurve", "linearcurve", "catmullrom", "hair", "measured", "measured_polarized", "pplastic",
    "sunsky", "timed_sunsky", "gridvolume", "heterogeneous", "homogeneous", "constvolume", "sggx",
    "blendphase", "hg", "rayleigh", "tabphase", "polarizer", "retarder", "stokes", "roughconductor",
    "roughdielectric", "roughplastic", "conductor", "dielectric", "plastic", "thindielectric",
    "envmap", "spot", "projector", "thinlens", "moment", "aov", "bumpmap", "normalmap", "blender",
}  # fmt: skip
SETTINGS = ((16, (1.5e7, 2e7)), (16, (6e7, 8e7)), (32, (1.5e8, 2e8)), (64, (4e8, 5e8)))
# The device renders SETTINGS[0] with another seed than the reference made here, so the two are
# independent estimates and their differences, in units of the combined SE, should be noise.
REFERENCE_SEED, DEVICE_SEED = 11, 12
#: The sun of the reference and of every device render (elevation, azimuth), degrees: bench_light's.
SUN_DEG = (50.0, 180.0)
#: The gradient check's leaf parameters and central-difference steps: tests/test_light_projection.py's,
#: where the albedo's roughness table (nodes every 1/32) is smooth across the steps.
GRADIENT_AT = {"specular": 0.5, "roughness": 0.515, "subsurface": 0.45}
FD_STEP = {"specular": 0.1, "roughness": 0.002, "subsurface": 0.1}


def _strip_wheel(src: Path, dst: Path) -> None:
    """Copy a wheel without the members lightfit never loads (RECORD rewritten to match)."""
    variant_ext = ("cuda_ad_", "llvm_ad_", "scalar_")

    def drop(name: str) -> bool:
        base = name.rsplit("/", 1)[-1]
        if name.startswith("mitsuba/") and base.startswith(variant_ext) and base.endswith(".so"):
            return base.split(".")[0] not in KEEP_VARIANTS
        if name.startswith(("mitsuba/include/", "share/")) or name == "mitsuba/data/srgb.coeff":
            return True
        return "/plugins/" in name and base.removesuffix(".so") in UNUSED_PLUGINS

    with zipfile.ZipFile(src) as zin, zipfile.ZipFile(dst, "w", zipfile.ZIP_DEFLATED) as zout:
        kept = [i for i in zin.infolist() if not drop(i.filename)]
        names = {i.filename for i in kept}
        for info in kept:
            data = zin.read(info)
            if info.filename.endswith(".dist-info/RECORD"):
                lines = data.decode().splitlines()
                data = ("\n".join(ln for ln in lines if ln.split(",", 1)[0] in names) + "\n").encode()
            zout.writestr(info, data)


def _render(fs, ids, seed: int):
    """The agreement check's render: the first setting of :data:`SETTINGS`, absorbed PAR at DNI 1,
    DHI 0.3 and its standard error per segment."""
    from lightfit.light.estimator import SegmentEstimator, bounces_for_tolerance

    samples, rays = SETTINGS[0]
    bounces = bounces_for_tolerance(0.01, fs.optics)
    kw = dict(direct="projection", direct_rays_per_m2=rays)
    r = SegmentEstimator(fs, ids, samples=samples, bounces=bounces, seed=seed, **kw).render()
    v = r.total("absorbed", 1.0, 0.3)
    return v, r.total_se()


def _cotangent(n: int) -> dict:
    """The gradient check's objective J = Σ absorbed sun + 0.3 Σ absorbed sky (bench_gradient's)."""
    return {"absorbed_sun": np.ones(n), "absorbed_sky": np.full(n, 0.3)}


def _objective(r, ct: dict) -> float:
    return float(sum(np.sum(ct[p] * getattr(r, p)) for p in ct))


def _gradient_estimator(fs, ids):
    """The first setting of :data:`SETTINGS` with the reference's seed, at :data:`GRADIENT_AT`."""
    from lightfit.light.estimator import SegmentEstimator, bounces_for_tolerance

    samples, rays = SETTINGS[0]
    fs.set_optics(**GRADIENT_AT)
    return SegmentEstimator(
        fs, ids, samples=samples, bounces=bounces_for_tolerance(0.01, fs.optics), seed=REFERENCE_SEED,
        direct="projection", direct_rays_per_m2=rays,
    )  # fmt: skip


def _reference_render(geom, ids) -> dict:
    """This machine's render for the device's agreement check (seed 11), and its gradient of
    :func:`_objective` at :data:`GRADIENT_AT` with the same seed, which the device's must equal up
    to rounding: Dr.Jit's random streams are the same on both backends."""
    from lightfit.light import backend
    from lightfit.light.scene import FieldScene, Optics

    fs = FieldScene(geom.mesh, Optics.preset("prospect"), cell=geom.cell)
    fs.set_sun(*SUN_DEG)
    v, se = _render(fs, ids, seed=REFERENCE_SEED)
    est = _gradient_estimator(fs, ids)
    ct = _cotangent(len(ids))
    j = _objective(est.render(), ct)
    g = est.vjp(ct)
    return {
        "reference_absorbed": v,
        "reference_se": se,
        "reference_variant": backend.info().variant,
        "reference_objective": j,
        "reference_gradient": json.dumps(g),
    }


def prepare(n_plants: int, python_version: str, sheaths: str) -> None:
    from provenance import commit_state

    from lightfit.light.scene import Optics
    from lightfit.plant import Field, build, organ_class

    (DEVICE / "wheels").mkdir(parents=True, exist_ok=True)
    raw = DEVICE / "raw"
    tag = python_version.replace(".", "")
    plat = ["manylinux_2_28_x86_64", "manylinux_2_27_x86_64", "manylinux_2_17_x86_64", "manylinux2014_x86_64"]
    for w in (DEVICE / "wheels").glob("*.whl"):
        w.unlink()
    subprocess.run(
        [sys.executable, "-m", "pip", "download", "-q", "--no-deps", "--only-binary=:all:", "--python-version",
         python_version, "--implementation", "cp", *[f"--platform={p}" for p in plat], "-d", str(raw), *PINS],
        check=True,
    )  # fmt: skip
    for w in sorted(raw.glob(f"*-cp{tag}-*.whl")):
        _strip_wheel(w, DEVICE / "wheels" / w.name)
    geom = build(Field(n_plants=n_plants, seed=1, boundary="periodic", sheaths=sheaths), progress=True)
    ids = geom.segments.loc[geom.segments["measured"], "segment_id"].to_numpy()
    organ = organ_class(geom.segments.set_index("segment_id").loc[ids])
    m, c = geom.mesh, geom.cell
    ref = _reference_render(geom, ids)  # this machine's llvm_ad_mono, for the device's agreement check
    np.savez_compressed(
        DEVICE / "geometry.npz",
        vertices=m.vertices,
        faces=m.faces.astype(np.int32),
        face_segment=m.face_segment,
        face_is_blade=m.face_is_blade,
        segment_ids=ids,
        organ=organ,
        cell=np.array([c.along_m, c.across_m, c.row_direction_deg, *c.center_xy]),
        optics=json.dumps(Optics.preset("prospect").__dict__),
        meta=json.dumps(
            {
                "n_plants": n_plants,
                "sheaths": sheaths,
                "python": python_version,
                **commit_state(),
                "source_digest": source_digest(),
            }
        ),
        **ref,
    )
    sizes = {p.name: p.stat().st_size for p in [*(DEVICE / "wheels").glob("*.whl"), DEVICE / "geometry.npz"]}
    for name, size in sizes.items():
        print(f"{size / 2**20:7.1f} MiB  device/{'wheels/' if name.endswith('.whl') else ''}{name}")
    print(f"{sum(sizes.values()) / 2**20:7.1f} MiB  to carry (a call carries 64 MiB with the working tree)")
    print('run: command "bash benchmarks/device_light.sh", carry ["device/wheels", "device/geometry.npz"]')


def source_digest() -> str:
    """SHA-256 (first 12 hex digits) of lightfit's sources and this script, as they run: the
    device gets a copy of the working tree without its git history, so the results name the code
    by content; ``prepare`` records it too, with the commit."""
    import hashlib

    h = hashlib.sha256()
    for f in sorted([*(ROOT / "lightfit").rglob("*.py"), Path(__file__).resolve()]):
        h.update(f.relative_to(ROOT).as_posix().encode() + b"\0" + f.read_bytes())
    return h.hexdigest()[:12]


def run(out: Path, budget_s: float, settings) -> dict:
    from bench_light import direct_projection_comparison
    from provenance import write_result

    from lightfit.light import backend
    from lightfit.light.estimator import bounces_for_tolerance
    from lightfit.light.scene import FieldScene, Optics
    from lightfit.plant.mesh import Mesh
    from lightfit.plant.periodic import PeriodicCell

    t0 = time.perf_counter()
    g = np.load(DEVICE / "geometry.npz")
    mesh = Mesh(g["vertices"], g["faces"].astype(np.int64), g["face_segment"], g["face_is_blade"])
    a, b, row, cx, cy = (float(v) for v in g["cell"])
    optics = Optics(**json.loads(str(g["optics"])))
    fs = FieldScene(mesh, optics, cell=PeriodicCell(a, b, row, (cx, cy)))
    fs.set_sun(*SUN_DEG)
    ids, organ = g["segment_ids"], g["organ"]
    bounces = bounces_for_tolerance(0.01, optics)
    smi = ["nvidia-smi", "--query-gpu=name,driver_version", "--format=csv,noheader"]
    gpu = subprocess.run(smi, capture_output=True, text=True).stdout.strip() if shutil.which(smi[0]) else ""
    prepared = json.loads(str(g["meta"]))
    res = {
        "prepared": prepared,
        "sheaths": prepared.get("sheaths"),  # None: prepared before it was recorded (rods)
        "source_digest": source_digest(),
        "mitsuba_variant": backend.info().variant,
        "gpu": gpu or None,
        "segments": len(ids),
        "triangles": int(mesh.n_faces),
        "bounces": bounces,
        "scene_s": time.perf_counter() - t0,
        "settings": [],
    }
    out.mkdir(parents=True, exist_ok=True)

    def save():  # after every stage: a run stopped by the device's time limit keeps what it measured
        write_result(out / "device_light.json", res, indent=2)  # no git there: the code is source_digest

    res["agreement"] = _agreement(fs, ids, g)
    print(
        f"{'agrees' if res['agreement']['agrees'] else 'DISAGREES'}: "
        f"{res['mitsuba_variant']} against {res['agreement']['reference_variant']}: median |z| "
        f"{res['agreement']['median_abs_z']:.3f} (noise: {res['agreement']['median_abs_z_if_noise']:.3f}), "
        f"canopy total ratio − 1 {res['agreement']['canopy_total_ratio_minus_1']:+.2e} "
        f"± {res['agreement']['canopy_total_ratio_se']:.1e}",
        flush=True,
    )
    save()
    if "reference_gradient" in g.files:
        res["gradient"] = _gradient_check(fs, ids, g)
        gr = res["gradient"]
        print(
            f"gradient {'agrees' if gr['agrees'] else 'DISAGREES'}: max |relative difference| against "
            f"{gr['reference_variant']} {gr['max_rel_diff_reference']:.1e}, against central differences "
            f"(common random numbers) {gr['max_rel_diff_fd']:.1e}; vjp / primal {gr['vjp_over_primal']:.2f} "
            f"({gr['vjp_s']:.2f} / {gr['primal_s']:.2f} s)",
            flush=True,
        )
        save()
    for samples, rays in settings:
        if time.perf_counter() - t0 > budget_s:
            res["stopped_at_budget_s"] = budget_s
            break
        row = direct_projection_comparison(fs, ids, bounces, [(samples, rays)], organ=organ)["settings"][0]
        res["settings"].append(row)
        res["elapsed_s"] = time.perf_counter() - t0
        save()
        a = row["rse_absorbed"]["all"]
        print(
            f"K={samples} rays/m² {rays}: {row['render_s']:.2f} s (first {row['first_render_s']:.2f} s), "
            f"median / p90 {a['median']:.2%} / {a['p90']:.2%}, R-corrected {row['median_rse_r_corrected']:.2%} "
            f"→ 2 % median ≈ {row['extrapolated_s_at_2pct_r_corrected']:.1f} s; later step {row['day_step_s']:.2f} s",
            flush=True,
        )
    return res


def _agreement(fs, ids, g) -> dict:
    """This variant's render against the reference made by ``prepare``: per-segment |z| (median
    0.674 when the two differ by noise alone, with SEs from R = 4 replicates a little more) and
    the canopy totals (area-weighted sums would need the areas; the plain sums are compared)."""
    from scipy.stats import t as student_t

    v, se = _render(fs, ids, seed=DEVICE_SEED)
    ref, ref_se = g["reference_absorbed"], g["reference_se"]
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.abs(v - ref) / np.hypot(se, ref_se)
    z = z[np.isfinite(z)]
    total, total_ref = v.sum(), ref.sum()
    ratio_se = float(np.hypot(np.sqrt((se**2).sum()) / total, np.sqrt((ref_se**2).sum()) / total_ref))
    median_z, noise_z = float(np.median(z)), float(student_t.ppf(0.75, 6))  # two renders, R − 1 = 3 each
    ratio = float(total / total_ref - 1)
    return {
        "reference_variant": str(g["reference_variant"]),
        "segments_compared": int(z.size),
        "median_abs_z": median_z,
        "median_abs_z_if_noise": noise_z,
        "share_abs_z_above_4": float(np.mean(z > 4)),
        "share_abs_z_above_4_if_noise": float(2 * student_t.sf(4.0, 6)),
        "canopy_total_ratio_minus_1": ratio,
        "canopy_total_ratio_se": ratio_se,
        # Noise alone: the median |z| within 10 % of t₆'s (over 66 125 segments it hardly moves) and
        # the totals within 4 SE (p ≈ 6 × 10⁻⁵ to fail).
        "agrees": median_z < 1.1 * noise_z and abs(ratio) < 4 * ratio_se,
    }


def _gradient_check(fs, ids, g, repeats: int = 3) -> dict:
    """The reverse-mode gradient on this variant against (a) the reference's, same seed, and (b)
    central differences with common random numbers (the same estimator rendered at θ ± h), and
    its time against the primal's (wall clock, medians of ``repeats``). The primal re-weighs the
    estimator's kept paths and projected rays at the same sun, as a calibration's renders at new
    leaf parameters do; a later step of a day, which casts the sun's rays again, is
    ``day_step_s`` of the settings."""
    ct = _cotangent(len(ids))
    leaf = {k: getattr(fs.optics, k) for k in GRADIENT_AT}
    est = _gradient_estimator(fs, ids)
    try:
        j = _objective(est.render(), ct)
        grad = est.vjp(ct)
        primal, vjp = [], []
        for _ in range(repeats):
            est._suns_kept.clear()
            t = time.perf_counter()
            est.render()
            primal.append(time.perf_counter() - t)
            t = time.perf_counter()
            est.vjp(ct)
            vjp.append(time.perf_counter() - t)
        fd = {}
        for k, h in FD_STEP.items():
            fs.set_optics(**{k: GRADIENT_AT[k] + h})
            jp = _objective(est.render(), ct)
            fs.set_optics(**{k: GRADIENT_AT[k] - h})
            fd[k] = (jp - _objective(est.render(), ct)) / (2 * h)
            fs.set_optics(**{k: GRADIENT_AT[k]})
    finally:
        fs.set_optics(**leaf)
    ref = json.loads(str(g["reference_gradient"]))
    # Relative to the largest component: a near-zero component's own ratio means nothing.
    scale = max(abs(v) for v in ref.values())
    d_ref = max(abs(grad[k] - ref[k]) for k in ref) / scale
    d_fd = max(abs(grad[k] - fd[k]) for k in ref) / scale
    return {
        "at": GRADIENT_AT,
        "fd_step": FD_STEP,
        "reference_variant": str(g["reference_variant"]),
        "objective": j,
        "reference_objective": float(g["reference_objective"]),
        "gradient": grad,
        "reference_gradient": ref,
        "central_differences": fd,
        "max_rel_diff_reference": d_ref,
        "max_rel_diff_fd": d_fd,
        "primal_s": float(np.median(primal)),
        "vjp_s": float(np.median(vjp)),
        "vjp_over_primal": float(np.median(vjp) / np.median(primal)),
        # Rounding alone (the same random numbers) within 10⁻³; central differences within
        # tests/test_light_projection.py's 3 %.
        "agrees": d_ref < 1e-3 and d_fd < 0.03,
    }


def _setting(text: str):
    k, sun, sky = text.split(":")
    return int(k), (float(sun), float(sky))


if __name__ == "__main__":
    from lightfit.plant import SHEATHS

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    p = sub.add_parser("prepare", help="wheels and geometry into device/ (here)")
    p.add_argument("--n-plants", type=int, default=500)
    p.add_argument("--python-version", default="3.12", help="the device's Python (3.12); 3.11 for a dry run here")
    p.add_argument("--sheaths", choices=SHEATHS, default=SHEATHS[0], help="leaf sheath layout (lightfit.plant.Field)")
    r = sub.add_parser("run", help="render on the device (device_light.sh calls this)")
    r.add_argument("--out", type=Path, default=Path(os.environ.get("OUT", ROOT / "benchmarks" / "results")))
    r.add_argument("--budget-s", type=float, default=420.0, help="start no new setting after this many seconds")
    r.add_argument("--settings", type=_setting, nargs="*", default=SETTINGS, help="K:sun_rays:sky_rays per m²")
    a = ap.parse_args()
    if a.cmd == "prepare":
        prepare(a.n_plants, a.python_version, a.sheaths)
    else:
        run(a.out, a.budget_s, a.settings)
