"""Benchmark: per-segment absorbed PAR, lightfit against LESS 3 on the same mesh, optics, sun and sky.

    python benchmarks/bench_less.py [--plants 16] [--boundary finite periodic]
        [--less-samples 16 64] [--lightfit-samples 64 256] [--replicates 4] [--target 0.02] [--out JSON]

LESS 3 (PyPI ``less3d``; Qi et al. 2019, Remote Sens. Environ. 221:695) is an independent ray
tracer used here as a peer only: its licence (LESS Academic and Non-Commercial Research
License 1.0) allows non-commercial research and evaluation, so it is never a lightfit
dependency, never in CI or tests. It lives in its own environment, ``.venv-less`` (README,
"Optional: LESS 3 peer"); without it this script says so and stops (exit 0).

Two steps, so that lightfit and LESS never share an environment: this script grows the field,
writes its triangles, optics and sun to a folder, runs ``benchmarks/less_runner.py`` with the
LESS environment's Python (all LESS runs in one process, side by side with lightfit's runs on the
same cores), reads back LESS's absorbed irradiance per triangle side and compares, per segment:

- **Physics, identical in both**: lightfit's mesh (blades two-sided, stems and sheaths their
  outer side); Lambertian leaves, reflectance 0.0825 and transmittance 0.0675 per side (lightfit
  ``Optics(specular=0, base_color=0.15, subsurface=0.45)``; Caribu's green leaf in PAR); soil
  albedo 0.12; the 2016-04-20 10:00 UTC sun at Selhausen (elevation 46.52°, azimuth 145.82°);
  an isotropic sky; 3 scattering events (LESS ``max_depth=3``; with albedo 0.15 the truncated
  light is < 0.1 %, :func:`~lightfit.light.estimator.bounces_for_tolerance`).
- **Agreement**: absorbed PAR per unit DNI (sun part) and per unit DHI (sky part) per segment,
  from the mean of the replicates at the largest sample counts: median and 90th percentile of
  |LESS − lightfit| / lightfit, the median |z| of the difference over its Monte Carlo SE
  (against Student's t with 2(R − 1) degrees of freedom when the difference is noise alone:
  0.72 for R = 4), and the relative bias of canopy totals (Σ area × value) with its SE. LESS
  runs the sun and the sky separately for this (its runs take one illumination); lightfit's one
  render gives both parts.
- **Noise**: absorbed PAR at DNI 1 and DHI 0.3 (a clear day) in one run of each tool; per
  segment the standard deviation over R replicates (lightfit: seeds; LESS, which has no seed:
  the triangles written in R random orders, its random streams being keyed by primitive index)
  over the replicates' mean, median over blades and over stems. lightfit's own SE
  (``Irradiance.relative_se``) is checked against its seed spread.
- **Time at equal noise**: wall time of one estimate (lightfit: estimator set-up + render, the
  faster of two identical runs; LESS: ``scene.simulate``; scene building apart) at two sample
  counts each; the median relative SE
  follows c·n^(−p) (p fitted, ≈ 0.5) and the time a + b·n, which give each tool's time to a
  median relative SE of ``--target`` on blades and on stems; the ratio LESS ÷ lightfit is the
  speed-up. Both use every core of this machine (Dr.Jit and Embree threads), taking turns
  replicate by replicate so that they meet the same load.
- **Periodic cell** (``--boundary periodic``): lightfit's periodic cell (ray wrapping, periodic
  images of overhanging faces) against LESS's "repetitive scene" on the same cell: LESS
  receives lightfit's periodic images (faces reaching into the cell, shifted by whole periods)
  and a soil tile the size of the cell, and each face is measured on its image whose centroid
  lies in the cell. Measured: LESS 3.0.7's repetitive scene is not a usable peer for a wheat cell
  (12 cm along the rows for 4 × 4 plants): at its default wrap cap (100) the sun part agrees but
  the sky part is about three times lightfit's (stems far more), and with a larger cap
  (``LIGHTFIT_LESS_WRAP_CAP=1000``) the sun part vanishes (docs/light.md, "Peer: LESS 3").

Writes benchmarks/results/less.json (or ``--out``; a boundary not run this time keeps its last run under
``earlier_runs``, with that run's conditions) and prints a table.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from less_runner import LESS_HOW
from provenance import out_option, wide_console, write_result
from rich.console import Console
from rich.table import Table

import lightfit  # noqa: F401
from lightfit.light.estimator import SegmentEstimator
from lightfit.light.scene import SOIL_ALBEDO, FieldScene, Optics
from lightfit.plant import Field, build
from lightfit.plant.growth import organ_class
from lightfit.plant.sheaths import SHEATHS
from lightfit.precision import use_float64

use_float64()  # lightfit's precision policy (lightfit.precision), before any JAX array exists

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "benchmarks" / "results" / "less.json"
RUNNER = ROOT / "benchmarks" / "less_runner.py"
LESS_PYTHON = Path(os.environ.get("LIGHTFIT_LESS_PYTHON", ROOT / ".venv-less" / "bin" / "python"))
#: Lambertian leaf in PAR, per side (Caribu's green leaf; docs/design.md §7).
LEAF_R, LEAF_T = 0.0825, 0.0675
#: 2016-04-20 10:00 UTC at Selhausen (lightfit.weather.solar.solar_position).
SUN_ELEVATION_DEG, SUN_AZIMUTH_DEG = 46.521508, 145.817464
BOUNCES = 3
#: Half-width of the soil quad LESS receives around a finite field, m. LESS's reverse tracer
#: collects the sky for any ray that leaves the scene, downward too, so a ray from a leaf at
#: height h that passes the quad's edge (within ≈ atan(h / W) below the horizon) sees sky instead
#: of soil: +0.56 % sky on blades at 50 m, ≈ +0.1 % at 200 m (experiments/less_soil_edge.py).
#: In float32 a vertex at 200 m is kept to ≈ 15 µm, 5 % of the thinnest radius (0.3 mm).
GROUND_HALF_M = 200.0
LESS_WRAP_CAP = 100  # LESS's own default (repetitive=True)
MIX_DHI = 0.3  # DHI / DNI of the noise runs (a clear day)


def less_version() -> str | None:
    """less3d's version in :data:`LESS_PYTHON`'s environment; ``None`` where that Python is missing or
    cannot import LESS (an environment whose ``pip install less3d`` failed)."""
    exe = shutil.which(str(LESS_PYTHON))
    if exe is None:
        return None
    code = "import less, importlib.metadata as m; print(m.version('less3d'))"
    proc = subprocess.run([exe, "-c", code], capture_output=True, text=True)
    version = proc.stdout.strip()
    return version if proc.returncode == 0 and version else None


def less_missing() -> str:
    """What the LESS scripts say when :func:`less_version` finds no LESS: where they looked, how to
    get it and its licence."""
    found = "has no LESS 3" if shutil.which(str(LESS_PYTHON)) else "missing"
    return f"LESS 3 is not installed ({LESS_PYTHON}: {found}). {LESS_HOW}"


def check_counts(ap: argparse.ArgumentParser, replicates: int, pairs: dict | None = None) -> None:
    """Refuse, when the options are read, what would end a run in NaN or a traceback after its
    minutes of work: fewer than 2 replicates (every SE, noise and |z| is a spread over them) and,
    per option in ``pairs``, sample counts that are not two different counts ≥ 1 (the error's
    exponent and the time per sample are fitted from the two)."""
    if replicates < 2:
        ap.error(f"--replicates {replicates}: at least 2 (the SEs and noise are spreads over the replicates)")
    for option, (n1, n2) in (pairs or {}).items():
        if min(n1, n2) < 1 or n1 == n2:
            ap.error(f"{option} {n1} {n2}: two different counts ≥ 1 (the error's exponent is fitted from the two)")


def lambertian_optics() -> Optics:
    """lightfit optics equal to LESS's ``Lambertian(reflectance=R, transmittance=T)``: no glossy lobe
    (F0 = 0), diffuse albedo c = R + T, transmitted share T / (R + T)."""
    return Optics(
        specular=0.0,
        roughness=0.5,
        subsurface=LEAF_T / (LEAF_R + LEAF_T),
        base_color=LEAF_R + LEAF_T,
        soil_albedo=SOIL_ALBEDO,
    )


def export(geom, boundary: str, folder: Path, runs: list[dict], ground_half_m: float = GROUND_HALF_M) -> dict:
    """Write mesh.npz and job.json for less_runner.py; returns which exported face measures which
    lightfit face (``measure``: index into the exported triangles, one per lightfit face).
    ``ground_half_m``: half-width of the soil quad around a finite field, m."""
    mesh = geom.mesh
    if boundary == "finite":
        tri = mesh.vertices[mesh.faces]
        centre = 0.5 * (mesh.vertices[:, :2].min(0) + mesh.vertices[:, :2].max(0))
        shift = ground_half_m - centre
        size = (2 * ground_half_m, 2 * ground_half_m)
        measure = np.arange(mesh.n_faces)
        repetitive = 0
    else:
        cell = geom.cell
        ea, _ = cell.axes
        if abs(ea[0] - 1) > 1e-9:
            raise SystemExit("the LESS export supports rows running east-west only (row_direction_deg=90)")
        # Each original face and its images, in the order of cell.images (which copies each face
        # once per lattice vector that makes it overlap the cell).
        ids = np.arange(mesh.n_faces)
        tagged = type(mesh)(mesh.vertices, mesh.faces, ids, mesh.face_is_blade)
        img = cell.images(tagged)
        tri = img.vertices[img.faces]
        ab = cell.to_local(tri.mean(1))
        (a0, a1), (b0, b1) = cell.bounds_m
        inside = (ab[:, 0] >= a0) & (ab[:, 0] < a1) & (ab[:, 1] >= b0) & (ab[:, 1] < b1)
        measure = np.full(mesh.n_faces, -1)
        measure[img.face_segment[inside]] = np.nonzero(inside)[0]
        if (measure < 0).any():
            raise SystemExit(f"{int((measure < 0).sum())} faces have no image with its centroid in the cell")
        shift = cell.size_m / 2 - np.asarray(cell.center_xy)
        size = tuple(float(v) for v in cell.size_m)
        repetitive = int(os.environ.get("LIGHTFIT_LESS_WRAP_CAP", LESS_WRAP_CAP))
    tri = tri.copy()
    tri[..., :2] += shift
    w, d = size
    ground = np.array([[0.0, 0.0, 0.0], [w, 0.0, 0.0], [w, d, 0.0], [0.0, d, 0.0]])
    folder.mkdir(parents=True, exist_ok=True)
    np.savez(folder / "mesh.npz", triangles=tri, ground=ground)
    job = {
        "optics": {"reflectance": LEAF_R, "transmittance": LEAF_T, "soil_albedo": SOIL_ALBEDO},
        "sun": {"zenith_deg": 90.0 - SUN_ELEVATION_DEG, "azimuth_deg": SUN_AZIMUTH_DEG},
        "max_depth": BOUNCES,
        "repetitive": int(repetitive),
        "scene_size_m": [float(w), float(d)],
        "runs": runs,
    }
    (folder / "job.json").write_text(json.dumps(job, indent=1))
    return {"measure": measure, "n_exported": len(tri)}


def per_segment(values_face: np.ndarray, geom, seg_index: np.ndarray, n_seg: int) -> np.ndarray:
    """Area-weighted mean over each segment's faces (per unit one-sided area)."""
    a = geom.mesh.face_areas()
    num = np.bincount(seg_index, a * values_face, minlength=n_seg)
    den = np.bincount(seg_index, a, minlength=n_seg)
    return np.divide(num, den, out=np.full(n_seg, np.nan), where=den > 0)


def less_segments(
    folder: Path, label: str, geom, exp: dict, seg_index, n_seg, side: str = "counted"
) -> tuple[np.ndarray, float]:
    """LESS absorbed irradiance per segment and its time. ``side``: ``"counted"``, the sides
    lightfit counts (blades: both; stems and sheaths: the outer), or ``"inner"``, the other side of
    stems and sheaths (0 on blades), which lightfit's light reaches but no segment counts."""
    z = np.load(folder / "out" / f"{label}.npz")
    m = exp["measure"]
    top, bot = z["top"][m], z["bot"][m]
    blade = geom.mesh.face_is_blade
    v = top + np.where(blade, bot, 0.0) if side == "counted" else np.where(blade, 0.0, bot)
    return per_segment(v, geom, seg_index, n_seg), float(z["simulate_s"])


def rel_spread(reps: np.ndarray) -> np.ndarray:
    """Per-segment relative SD of one replicate: SD over replicates (axis 0) / their mean."""
    m = reps.mean(0)
    return np.divide(reps.std(0, ddof=1), np.abs(m), out=np.full(m.shape, np.nan), where=m > 0)


def equal_noise(points: list[dict], target: float) -> dict:
    """Time to a median relative SE of ``target`` from (n, rse, time) points: rse = c·n^-p, t = a + b·n."""
    (n1, r1, t1), (n2, r2, t2) = ((p["n"], p["median_rse"], p["time_s"]) for p in points[:2])
    p = math.log(r1 / r2) / math.log(n2 / n1)
    n_t = n2 * (r2 / target) ** (1 / p)
    b = (t2 - t1) / (n2 - n1)
    a = max(t1 - b * n1, 0.0)
    return {"exponent": p, "n_at_target": n_t, "time_s_at_target": a + b * n_t, "overhead_s": a, "s_per_n": b}


def expected_abs_z(reps: int) -> float:
    """Median |z| of a difference that is noise alone, with both SEs from ``reps`` replicates:
    Student's t with 2(R − 1) degrees of freedom (Welch's, equal variances)."""
    from scipy.stats import t

    return float(t.ppf(0.75, 2 * (reps - 1)))


def agreement(less_mean, less_se, lf_mean, lf_se, area, mask, reps) -> dict:
    """Per-segment and canopy-total agreement of two estimates on the segments in ``mask``."""
    ok = mask & (lf_mean > 0) & np.isfinite(less_mean)
    dark = mask & (lf_mean <= 0)  # no light in lightfit: no relative difference, reported apart
    d = (less_mean - lf_mean)[ok]
    rel = np.abs(d) / lf_mean[ok]
    se = np.hypot(less_se, lf_se)[ok]
    tot_l, tot_f = float(np.sum(area[ok] * less_mean[ok])), float(np.sum(area[ok] * lf_mean[ok]))
    se_tot = math.hypot(
        float(np.sqrt(np.sum((area[ok] * less_se[ok]) ** 2))), float(np.sqrt(np.sum((area[ok] * lf_se[ok]) ** 2)))
    )
    return {
        "segments": int(ok.sum()),
        "median_rel_diff": float(np.median(rel)),
        "p90_rel_diff": float(np.quantile(rel, 0.9)),
        "median_rel_noise_of_diff": float(np.median(se / lf_mean[ok])),
        "median_abs_z": float(np.median(np.abs(d) / np.where(se > 0, se, np.inf))),
        "median_abs_z_if_noise": expected_abs_z(reps),
        "canopy_total_bias": tot_l / tot_f - 1.0,
        "canopy_total_bias_se": se_tot / tot_f,
        "segments_dark_in_lightfit": int(dark.sum()),
        # LESS's light on those, per unit area, relative to the class's mean in lightfit
        "less_on_dark_rel_class_mean": float(np.mean(less_mean[dark]) / np.mean(lf_mean[ok])) if dark.any() else 0.0,
    }


def run_less(folder: Path, rep: int) -> None:
    """Run less_runner.py on the export in ``folder`` for replicate (face order) ``rep``."""
    proc = subprocess.run([str(LESS_PYTHON), str(RUNNER), str(folder), str(rep)], capture_output=True, text=True)
    if proc.returncode != 0:
        raise SystemExit(f"less_runner failed:\n{proc.stdout[-2000:]}\n{proc.stderr[-4000:]}")


def part_agreement(folder, part: str, geom, exp: dict, seg_index, renders, area, classes: dict) -> dict:
    """:func:`agreement` per class of the mean of LESS's replicates ``<part>_r1`` … and of
    lightfit's ``renders`` (one per replicate) for ``part`` ("sun" or "sky")."""
    reps, n_seg = len(renders), len(area)
    L = np.array([less_segments(folder, f"{part}_r{r}", geom, exp, seg_index, n_seg)[0] for r in range(1, reps + 1)])
    F = np.array([getattr(x, f"absorbed_{part}") for x in renders])
    l_m, l_se = L.mean(0), L.std(0, ddof=1) / math.sqrt(reps)
    f_m, f_se = F.mean(0), F.std(0, ddof=1) / math.sqrt(reps)
    return {c: agreement(l_m, l_se, f_m, f_se, area, m, reps) for c, m in classes.items()}


def finite_agreement(geom, ground_half_m: float, less_n: int, reps: int, seg_index, renders, area, classes) -> dict:
    """LESS on ``geom`` as a finite field on a soil quad of half-width ``ground_half_m`` (m): sun
    and sky, ``reps`` runs of ``less_n`` samples each (one face order per replicate), against
    lightfit's ``renders``. Per ``<part>_<class>``: the canopy total's bias, its SE and the
    median |z| (:func:`part_agreement`). The experiments on LESS's scene take it from here."""
    runs = [
        {"label": f"{part}_r{r}", "n_samples": less_n, "permutation_seed": r, "dni": dni, "dhi": dhi}
        for r in range(1, reps + 1)
        for part, dni, dhi in (("sun", 1.0, 0.0), ("sky", 0.0, 1.0))
    ]
    keep = ("canopy_total_bias", "canopy_total_bias_se", "median_abs_z")
    out = {}
    with tempfile.TemporaryDirectory(prefix="lightfit-less-", ignore_cleanup_errors=True) as d:
        folder = Path(d)
        exp = export(geom, "finite", folder, runs, ground_half_m=ground_half_m)
        for r in range(1, reps + 1):
            run_less(folder, r)
        for part in ("sun", "sky"):
            for c, a in part_agreement(folder, part, geom, exp, seg_index, renders, area, classes).items():
                out[f"{part}_{c}"] = {k: a[k] for k in keep}
    return out


def segment_index(geom) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(segment ids, each face's index into them, each segment's area (m²), whether it is a
    blade)`` of a built field, in the order both tools' per-segment values take."""
    seg_ids = np.unique(geom.mesh.face_segment)
    seg_index = np.searchsorted(seg_ids, geom.mesh.face_segment)
    area = np.bincount(seg_index, geom.mesh.face_areas(), minlength=len(seg_ids))
    blade = np.zeros(len(seg_ids), bool)
    np.logical_or.at(blade, seg_index, geom.mesh.face_is_blade)
    return seg_ids, seg_index, area, blade


def lightfit_renders(fs, seg_ids: np.ndarray, samples: int, reps: int) -> list:
    """lightfit's renders of ``seg_ids`` at seeds 1 … ``reps`` (the LESS replicates' partners)."""
    return [
        SegmentEstimator(fs, seg_ids, samples=samples, bounces=BOUNCES, seed=r).render() for r in range(1, reps + 1)
    ]


def agreement_classes(geom, seg_ids: np.ndarray, blade: np.ndarray) -> dict[str, np.ndarray]:
    """The segment classes compared between the tools: blades, "stems" (stem and sheath prisms or
    tubes; also apart: the sheaths, and the culms, which wrapped sheaths enclose) and
    all above the soil, and apart the stem and sheath segments partly below it (CPlantBox starts
    each stem, and the leaf at its first node, at the seed, 3 mm deep). lightfit
    gives a buried point nothing; LESS's reverse tracer collects the sky for any ray that leaves
    the scene, so a buried point there sees the sky from below its soil quad (and no sun)."""
    s = geom.segments.set_index("segment_id").loc[seg_ids]
    buried = (np.minimum(s["z0"].to_numpy(), s["z1"].to_numpy()) < 0).astype(bool)
    organ = organ_class(s.reset_index())
    return {
        "blades": blade & ~buried,
        "stems": ~blade & ~buried,
        "sheaths": (organ == "sheath") & ~buried,
        "culms": (organ == "stem") & ~buried,
        "all": ~buried,
        "stems partly below the soil": ~blade & buried,
    }


def _timed_render(fs, ids, samples: int, seed: int) -> tuple[float, object]:
    """(seconds, render) of a fresh estimator (set-up + render, estimator freed): the faster of
    two identical runs, so that a one-off pause of the shared machine (or freeing the previous
    estimator's memory) is not charged to one sample count."""
    best, r = math.inf, None
    for _ in range(2):
        t = time.perf_counter()
        r = SegmentEstimator(fs, ids, samples=samples, bounces=BOUNCES, seed=seed).render()
        best = min(best, time.perf_counter() - t)
    return best, r


def run_boundary(boundary, n_plants, less_n, lf_k, reps, target, console, lf_alloc=None, sheaths=SHEATHS[0]) -> dict:
    with tempfile.TemporaryDirectory(prefix=f"lightfit-less-{boundary}-", ignore_cleanup_errors=True) as d:
        return _run_in(Path(d), boundary, n_plants, less_n, lf_k, reps, target, console, lf_alloc, sheaths)


def inner_side(folder, geom, exp, seg_index, n_seg, area, agree_classes, reps) -> dict:
    """LESS's light absorbed on the inner side of the stems and sheaths (mean of the replicates),
    which lightfit's estimators do not count for any segment: per part, as a share of the counted
    light of the sheaths, of the culms and of every segment (Σ area × value)."""
    out = {}
    for part in ("sun", "sky"):
        get = [
            [less_segments(folder, f"{part}_r{r}", geom, exp, seg_index, n_seg, side)[0] for r in range(1, reps + 1)]
            for side in ("counted", "inner")
        ]
        counted, inner = (np.nan_to_num(np.mean(g, axis=0)) * area for g in get)
        out[part] = {
            f"inner_over_counted_{c}": float(inner[m].sum() / counted[m].sum())
            for c, m in agree_classes.items()
            if c in ("sheaths", "culms", "all") and counted[m].sum() > 0
        }
    return out


def _run_in(folder, boundary, n_plants, less_n, lf_k, reps, target, console, lf_alloc=None, sheaths=SHEATHS[0]):
    fld = Field(n_plants=n_plants, seed=1, boundary=boundary, sheaths=sheaths)
    geom = build(fld)
    t = time.perf_counter()
    fs = FieldScene(geom.mesh, lambertian_optics(), cell=geom.cell)
    scene_s = time.perf_counter() - t
    fs.set_sun(SUN_ELEVATION_DEG, SUN_AZIMUTH_DEG)
    seg_ids, seg_index, area, blade = segment_index(geom)
    n_seg = len(seg_ids)

    # LESS runs, grouped by replicate (one scene build per face order).
    runs = []
    for r in range(1, reps + 1):
        runs += [
            {"label": f"sun_r{r}", "n_samples": max(less_n), "permutation_seed": r, "dni": 1.0, "dhi": 0.0},
            {"label": f"sky_r{r}", "n_samples": max(less_n), "permutation_seed": r, "dni": 0.0, "dhi": 1.0},
        ]
        runs += [
            {"label": f"mix_n{n}_r{r}", "n_samples": n, "permutation_seed": r, "dni": 1.0, "dhi": MIX_DHI}
            for n in less_n
        ]
    exp = export(geom, boundary, folder, runs)
    classes = {"blades": blade, "stems": ~blade, "all": np.ones(n_seg, bool)}
    agree_classes = agreement_classes(geom, seg_ids, blade)
    # Per-class allocation (--allocated-samples): each class rendered on its own at its own K.
    alloc = {} if lf_alloc is None else {"blades": int(lf_alloc[0]), "stems": int(lf_alloc[1])}
    lf_class = {c: [] for c in alloc}
    console.print(f"[{boundary}] {n_seg} segments, {geom.mesh.n_faces} faces ({exp['n_exported']} exported to LESS)")
    # Taking turns, replicate by replicate, so that both tools meet the same load on the shared
    # cores: LESS (one process per replicate: one face order, one scene build), then lightfit's
    # seed r at every K, after one lightfit warm-up render (kernel compilation).
    t = time.perf_counter()
    SegmentEstimator(fs, seg_ids, samples=min(lf_k), bounces=BOUNCES, seed=0).render()
    warmup_s = time.perf_counter() - t
    lf = {k: [] for k in lf_k}
    less_wall = 0.0
    for rep in range(1, reps + 1):
        t = time.perf_counter()
        run_less(folder, rep)
        less_wall += time.perf_counter() - t
        for k in lf_k:
            lf[k].append(_timed_render(fs, seg_ids, k, rep))
        for c, k in alloc.items():
            lf_class[c].append(_timed_render(fs, seg_ids[classes[c]], k, rep))
        console.print(f"[{boundary}] replicate {rep}/{reps} done, load average {os.getloadavg()[0]:.1f}")

    # Agreement per part at the largest sample counts.
    res_agree = {}
    big = lf[max(lf_k)]
    for part in ("sun", "sky"):
        res_agree[part] = part_agreement(folder, part, geom, exp, seg_index, [x[1] for x in big], area, agree_classes)
    res_inner = inner_side(folder, geom, exp, seg_index, n_seg, area, agree_classes, reps)

    # Noise and time at DNI 1, DHI 0.3.
    res_noise = {"less": {}, "lightfit": {}}
    for n in less_n:
        got = [less_segments(folder, f"mix_n{n}_r{r}", geom, exp, seg_index, n_seg) for r in range(1, reps + 1)]
        rse = rel_spread(np.array([g[0] for g in got]))
        res_noise["less"][n] = {
            "time_s": float(np.median([g[1] for g in got])),
            **{c: float(np.nanmedian(rse[m])) for c, m in classes.items()},
        }
    for k in lf_k:
        vals = np.array([x[1].total("absorbed", 1.0, MIX_DHI) for x in lf[k]])
        rse = rel_spread(vals)
        own = np.median([x[1].relative_se("absorbed", 1.0, MIX_DHI) for x in lf[k]], axis=0)
        res_noise["lightfit"][k] = {
            "time_s": float(np.median([x[0] for x in lf[k]])),
            **{c: float(np.nanmedian(rse[m])) for c, m in classes.items()},
            **{f"own_se_{c}": float(np.nanmedian(own[m])) for c, m in classes.items()},
        }
    res_equal = {}
    for c in classes:
        eq = {}
        for tool, d in res_noise.items():
            pts = [{"n": n, "median_rse": v[c], "time_s": v["time_s"]} for n, v in sorted(d.items())]
            eq[tool] = equal_noise(pts, target)
        eq["speedup_lightfit_over_less"] = eq["less"]["time_s_at_target"] / eq["lightfit"]["time_s_at_target"]
        res_equal[c] = eq
    res_alloc = allocated(lf_class, res_noise["less"]) if alloc else None
    return {
        "boundary": boundary,
        "plants_grown": int(len(geom.plants)),
        "segments": n_seg,
        "blade_segments": int(blade.sum()),
        "faces": int(geom.mesh.n_faces),
        "faces_exported_to_less": int(exp["n_exported"]),
        "lightfit_scene_s": scene_s,
        "lightfit_warmup_s": warmup_s,
        "less_build_s": float(np.load(folder / "out" / "sun_r1.npz")["build_s"]),
        "less_process_wall_s": less_wall,
        "agreement": res_agree,
        "less_inner_side": res_inner,
        "noise": {t: {str(k): v for k, v in d.items()} for t, d in res_noise.items()},
        "equal_noise": res_equal,
        **({} if res_alloc is None else {"allocated": res_alloc}),
    }


def allocated(lf_class: dict, less_noise: dict) -> dict:
    """lightfit with each class at its own K, against LESS at the error lightfit reached.

    ``lf_class[c]``: per replicate (time, render of class c's segments alone at its K). Per class:
    lightfit's measured time and median relative SE (seed spread), and LESS's time to that same
    median from its fit (:func:`equal_noise`). ``both``: lightfit's two renders together (every
    segment, each class at its K) against LESS at the larger of the two classes' n (LESS has one n
    for every triangle).
    """
    out = {}
    for c, runs in lf_class.items():
        vals = np.array([r.total("absorbed", 1.0, MIX_DHI) for _, r in runs])
        reached = float(np.nanmedian(rel_spread(vals)))
        pts = [{"n": n, "median_rse": v[c], "time_s": v["time_s"]} for n, v in sorted(less_noise.items())]
        less = equal_noise(pts, reached)
        t = float(np.median([x[0] for x in runs]))
        out[c] = {
            "lightfit_samples": int(runs[0][1].samples),
            "lightfit_segments": int(len(runs[0][1].segment_id)),
            "lightfit_time_s": t,
            "reached_median_rse": reached,
            "less": less,
            "speedup_lightfit_over_less": less["time_s_at_target"] / t,
        }
    if len(out) == 2:
        t = sum(v["lightfit_time_s"] for v in out.values())
        n = max(v["less"]["n_at_target"] for v in out.values())
        less = next(iter(out.values()))["less"]
        t_less = less["overhead_s"] + less["s_per_n"] * n
        out["both"] = {
            "lightfit_time_s": t,
            "less_n": n,
            "less_time_s": t_less,
            "speedup_lightfit_over_less": t_less / t,
        }
    return out


def main(n_plants, boundaries, less_n, lf_k, reps, target, lf_alloc=None, sheaths=SHEATHS[0], out=OUT) -> dict | None:
    console = wide_console()
    version = less_version()
    if version is None:
        console.print(f"{less_missing()} Skipping.", markup=False, highlight=False)
        return None
    res = {
        "less3d": version,
        "settings": {
            "leaf_reflectance": LEAF_R,
            "leaf_transmittance": LEAF_T,
            "soil_albedo": SOIL_ALBEDO,
            "sun_elevation_deg": SUN_ELEVATION_DEG,
            "sun_azimuth_deg": SUN_AZIMUTH_DEG,
            "bounces": BOUNCES,
            "sky": "isotropic",
            "noise_mix_dhi_over_dni": MIX_DHI,
            "replicates": reps,
            "target_median_rse": target,
            "less_samples_per_triangle_side": list(less_n),
            "lightfit_samples_per_segment": list(lf_k),
            "n_plants_measured": n_plants,
            "lightfit_allocated_samples_blades_stems": None if lf_alloc is None else list(lf_alloc),
            "sheaths": sheaths,
        },
        "results": {},
    }
    for b in boundaries:
        res["results"][b] = run_boundary(b, n_plants, less_n, lf_k, reps, target, console, lf_alloc, sheaths)
    if out.exists():  # keep the last run of a boundary not run now, with its own conditions
        old = json.loads(out.read_text())
        earlier = {b: r for b, r in old.get("earlier_runs", {}).items() if b not in boundaries}
        for b, r in old.get("results", {}).items():
            if b not in boundaries:
                earlier[b] = {**{k: v for k, v in old.items() if k not in ("results", "earlier_runs")}, "result": r}
        if earlier:
            res["earlier_runs"] = earlier
    write_result(out, res, indent=2)
    print_tables(res, console)
    return res


def print_tables(res: dict, console: Console) -> None:
    for b, r in res["results"].items():
        t = Table(
            title=f"LESS {res['less3d']} vs lightfit, {b}: {r['segments']} segments, agreement "
            f"(mean of {res['settings']['replicates']} replicates)"
        )
        z0 = next(iter(next(iter(r["agreement"].values())).values()))["median_abs_z_if_noise"]
        for c in (
            "part",
            "segments",
            "median |rel diff|",
            "p90 |rel diff|",
            "median noise of diff",
            f"median |z| (noise: {z0:.2f})",
            "canopy total bias",
            "dark in lightfit (LESS there ÷ class mean)",
        ):
            t.add_column(c, justify="right")
        for part, d in r["agreement"].items():
            for c, a in d.items():
                t.add_row(
                    f"{part} {c}",
                    str(a["segments"]),
                    f"{a['median_rel_diff']:.2%}",
                    f"{a['p90_rel_diff']:.2%}",
                    f"{a['median_rel_noise_of_diff']:.2%}",
                    f"{a['median_abs_z']:.2f}",
                    f"{a['canopy_total_bias']:+.2%} ± {a['canopy_total_bias_se']:.2%}",
                    f"{a.get('segments_dark_in_lightfit', 0)} ({a.get('less_on_dark_rel_class_mean', 0):.1%})",
                )
        console.print(t)
        for part, d in r.get("less_inner_side", {}).items():
            shares = ", ".join(f"{k.removeprefix('inner_over_counted_')} {v:.2%}" for k, v in d.items())
            console.print(f"LESS, {part}: light absorbed on stems' and sheaths' inner side ÷ counted light: {shares}")
        t = Table(title=f"{b}: median per-segment relative SE (DNI 1, DHI 0.3) and time per estimate")
        for c in ("tool", "n", "time s", "blades", "stems", "all", "own SE blades/stems"):
            t.add_column(c, justify="right")
        for tool, d in r["noise"].items():
            for n, v in d.items():
                own = f"{v['own_se_blades']:.2%} / {v['own_se_stems']:.2%}" if "own_se_blades" in v else ""
                t.add_row(
                    tool, n, f"{v['time_s']:.2f}", f"{v['blades']:.2%}", f"{v['stems']:.2%}", f"{v['all']:.2%}", own
                )
        console.print(t)
        tgt = res["settings"]["target_median_rse"]
        t = Table(title=f"{b}: time to a median relative SE of {tgt:.0%}")
        for c in ("segments", "lightfit K", "lightfit s", "LESS n", "LESS s", "LESS ÷ lightfit", "exponents lf / LESS"):
            t.add_column(c, justify="right")
        for c, e in r["equal_noise"].items():
            t.add_row(
                c,
                f"{e['lightfit']['n_at_target']:.0f}",
                f"{e['lightfit']['time_s_at_target']:.2f}",
                f"{e['less']['n_at_target']:.0f}",
                f"{e['less']['time_s_at_target']:.2f}",
                f"{e['speedup_lightfit_over_less']:.2f}",
                f"{e['lightfit']['exponent']:.2f} / {e['less']['exponent']:.2f}",
            )
        console.print(t)
        if "allocated" in r:
            t = Table(title=f"{b}: lightfit with each class at its own K, LESS at the median error lightfit reached")
            for c in ("segments", "lightfit K", "lightfit s", "median rel. SE", "LESS n", "LESS s", "LESS ÷ lightfit"):
                t.add_column(c, justify="right")
            for c, e in r["allocated"].items():
                if c == "both":
                    t.add_row(
                        "both classes",
                        "",
                        f"{e['lightfit_time_s']:.2f}",
                        "",
                        f"{e['less_n']:.0f}",
                        f"{e['less_time_s']:.2f}",
                        f"{e['speedup_lightfit_over_less']:.2f}",
                    )
                    continue
                t.add_row(
                    c,
                    str(e["lightfit_samples"]),
                    f"{e['lightfit_time_s']:.2f}",
                    f"{e['reached_median_rse']:.2%}",
                    f"{e['less']['n_at_target']:.0f}",
                    f"{e['less']['time_s_at_target']:.2f}",
                    f"{e['speedup_lightfit_over_less']:.2f}",
                )
            console.print(t)


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--plants", type=int, default=16, help="measured plants (N × N)")
    ap.add_argument("--boundary", nargs="+", default=["finite", "periodic"], choices=["finite", "periodic"])
    ap.add_argument("--less-samples", type=int, nargs=2, default=[16, 64], help="LESS n per triangle side")
    ap.add_argument("--lightfit-samples", type=int, nargs=2, default=[64, 256], help="lightfit K per segment")
    ap.add_argument("--replicates", type=int, default=4)
    ap.add_argument("--target", type=float, default=0.02, help="median relative SE for the equal-noise times")
    ap.add_argument(
        "--allocated-samples",
        type=int,
        nargs=2,
        metavar=("K_BLADES", "K_STEMS"),
        help="also render blades and stems each at its own K (e.g. the K each class needs for the target, "
        "from a previous run's fits) and compare with LESS at the error reached",
    )
    ap.add_argument("--sheaths", choices=SHEATHS, default=SHEATHS[0], help="leaf sheath layout (lightfit.plant.Field)")
    out_option(ap, OUT)
    a = ap.parse_args()
    check_counts(ap, a.replicates, {"--less-samples": a.less_samples, "--lightfit-samples": a.lightfit_samples})
    if not 0 < a.target < 1:
        ap.error(f"--target {a.target}: a median relative SE in (0, 1), e.g. 0.02")
    if a.allocated_samples is not None and min(a.allocated_samples) < 1:
        ap.error(f"--allocated-samples {' '.join(map(str, a.allocated_samples))}: counts ≥ 1")
    args = (a.plants, a.boundary, a.less_samples, a.lightfit_samples, a.replicates, a.target, a.allocated_samples)
    if main(*args, sheaths=a.sheaths, out=a.out) is None:
        sys.exit(0)
