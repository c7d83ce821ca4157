"""The default canopy's structure by organ, and its direct-beam transmittance by Beer–Lambert.

    python experiments/canopy_structure.py [--n-plants 100] [--sheaths wrapped|rods]
        [--out experiments/results/canopy_structure.json]

On the main job's field (the measured plants as one periodic cell, seed 1, 20 April 2016; the
leaf sheaths laid out as ``--sheaths`` says, default the model's: docs/plant.md "Leaf sheaths"):

* per organ class (:func:`lightfit.plant.organ_class`: blades, sheaths, stems): the share of the
  segments, of the one-sided area and of the absorbed PAR (sun and sky parts of one projection
  render, K = 16, 1.5 × 10⁷ / 2 × 10⁷ rays per m², sun 50° / 180°, PROSPECT-D leaf);
* the sheaths' geometry: each segment's lean from the vertical (the stems' for comparison), and
  the horizontal distance of each leaf's collar (the top of its sheath, where the blade begins)
  from its stem's base;
* the blades' leaf area index, inclination, and the projection function
  G(s) = Σ A_f |n_f · s| / Σ A_f over the blade faces, and from it Beer–Lambert's direct-beam
  transmittance τ = exp(−G·LAI / sin β) for a random canopy of these leaves, with and without the
  stems' and sheaths' projected area (the faces facing the sun, per ground area, / sin β) — to
  compare with the rendered ceptometer transmittance (docs/model.md).

Writes JSON and prints a table. The stored experiments/results/canopy_structure.json, which the docs
quote, is the ``--sheaths rods`` run: the default layout written to the default ``--out`` replaces it.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from rich.table import Table

from lightfit.plant.sheaths import SHEATHS
from lightfit.precision import use_float64

use_float64()  # lightfit's precision policy (lightfit.precision), before any JAX array exists

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from provenance import wide_console, write_result  # noqa: E402  (commit, cores, load and command with every JSON)

OUT = Path(__file__).resolve().parent / "results" / "canopy_structure.json"
#: Noon sun of the ceptometer check (20 April 2016, 13:00 CEST: elevation 50.3°) at two azimuths.
SUNS_DEG = ((50.3, 165.0), (50.3, 180.0))
ORGANS = ("blade", "sheath", "stem")


def _percentiles(x: np.ndarray) -> list[float]:
    return [float(v) for v in np.percentile(x, [10, 50, 90])]


def organ_shares(geom, ids: np.ndarray) -> dict:
    from lightfit.light.estimator import SegmentEstimator, bounces_for_tolerance
    from lightfit.light.scene import FieldScene, Optics
    from lightfit.plant import one_sided_area_m2, organ_class

    seg = geom.segments.set_index("segment_id").loc[ids]
    organ, area = organ_class(seg), one_sided_area_m2(seg)
    optics = Optics.preset("prospect")
    fs = FieldScene(geom.mesh, optics, cell=geom.cell)
    fs.set_sun(50.0, 180.0)
    r = SegmentEstimator(
        fs,
        ids,
        samples=16,
        bounces=bounces_for_tolerance(0.01, optics),
        seed=1,
        direct="projection",
        direct_rays_per_m2=(1.5e7, 2e7),
    ).render()
    absorbed = {part: r.total("absorbed", *w) * area for part, w in (("sun", (1.0, 0.0)), ("sky", (0.0, 1.0)))}
    return {
        o: {
            "segments": float(np.mean(organ == o)),
            "area": float(area[organ == o].sum() / area.sum()),
            **{f"absorbed_{p}": float(v[organ == o].sum() / v.sum()) for p, v in absorbed.items()},
        }
        for o in ORGANS
    }


def sheath_geometry(segments) -> dict:
    from lightfit.plant import organ_class

    organ = organ_class(segments)

    def lean_deg(s):
        d = s[["x1", "y1", "z1"]].to_numpy() - s[["x0", "y0", "z0"]].to_numpy()
        return np.degrees(np.arccos(np.clip(d[:, 2] / np.linalg.norm(d, axis=1), -1, 1)))

    sheath, stem = segments[organ == "sheath"], segments[organ == "stem"]
    base = stem.sort_values("segment_index").groupby("plant_id")[["x0", "y0"]].first()
    offset = [
        np.hypot(*(g.sort_values("segment_index")[["x1", "y1"]].to_numpy()[-1] - base.loc[pid].to_numpy()))
        for (pid, _), g in sheath.groupby(["plant_id", "organ_id"])
    ]
    return {
        "sheath_radius_mm": sorted({float(r) * 1e3 for r in sheath["radius_m"]}),
        "sheath_length_per_leaf_cm": _percentiles(sheath.groupby(["plant_id", "organ_id"])["length_m"].sum() * 100),
        "sheath_lean_deg_p10_50_90": _percentiles(lean_deg(sheath)),
        "stem_lean_deg_p10_50_90": _percentiles(lean_deg(stem)),
        "collar_offset_from_stem_base_cm_p10_50_90": _percentiles(np.array(offset) * 100),
        "stem_height_cm_p10_50_90": _percentiles(stem.groupby("plant_id")["z1"].max() * 100),
    }


def beer_lambert(geom) -> dict:
    from lightfit.light.scene import sun_vector

    m = geom.mesh
    v = m.vertices[m.faces]
    n = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    a = 0.5 * np.linalg.norm(n, axis=1)
    n = n / (2 * a[:, None])
    blade = m.face_is_blade
    ground = geom.cell.along_m * geom.cell.across_m
    lai = a[blade].sum() / ground
    incl = np.degrees(np.arccos(np.abs(n[blade, 2])))
    out = {
        "lai_blades": float(lai),
        "blade_inclination_deg_mean": float(np.average(incl, weights=a[blade])),
        "blade_inclination_deg_p10_50_90": _percentiles(incl),
        "suns": [],
    }
    for el, az in SUNS_DEG:
        s = sun_vector(el, az)
        g = float((a[blade] * np.abs(n[blade] @ s)).sum() / a[blade].sum())
        # Stems and sheaths are closed prisms: their faces turned to the sun are their shadow.
        thin = float((a[~blade] * np.clip(n[~blade] @ s, 0, None)).sum() / ground)
        sb = np.sin(np.radians(el))
        out["suns"].append(
            {
                "sun_deg": [el, az],
                "G_blades": g,
                "k_blades": g / sb,
                "tau_blades": float(np.exp(-g * lai / sb)),
                "tau_with_stems_and_sheaths": float(np.exp(-(g * lai + thin) / sb)),
            }
        )
    return out


def main(n_plants: int = 100, out: Path = OUT, sheaths: str = SHEATHS[0]) -> dict:
    from lightfit.plant import Field, build

    geom = build(Field(n_plants=n_plants, seed=1, boundary="periodic", sheaths=sheaths), progress=True)
    ids = geom.segments.loc[geom.segments["measured"], "segment_id"].to_numpy()
    res = {
        "n_plants": n_plants,
        "sheath_layout": sheaths,
        "segments": len(ids),
        "organs": organ_shares(geom, ids),
        "sheaths": sheath_geometry(geom.segments),
        "beer_lambert": beer_lambert(geom),
    }
    out.parent.mkdir(parents=True, exist_ok=True)
    write_result(out, res)
    t = Table(title=f"canopy structure: {n_plants}-plant periodic cell, {len(ids)} segments")
    for c in ("organ", "segments", "area", "absorbed PAR, sun / sky"):
        t.add_column(c, justify="right")
    for o, q in res["organs"].items():
        t.add_row(o, f"{q['segments']:.1%}", f"{q['area']:.1%}", f"{q['absorbed_sun']:.2%} / {q['absorbed_sky']:.2%}")
    console = wide_console()
    console.print(t)
    sh, bl = res["sheaths"], res["beer_lambert"]

    def pct(x):
        return " / ".join(f"{v:.1f}" for v in x)

    console.print(
        f"sheaths (10th / 50th / 90th percentiles): radius {pct(sh['sheath_radius_mm'])} mm, lean "
        f"{pct(sh['sheath_lean_deg_p10_50_90'])}° (stems {pct(sh['stem_lean_deg_p10_50_90'])}°), collar "
        f"{pct(sh['collar_offset_from_stem_base_cm_p10_50_90'])} cm from the stem's base"
    )
    console.print(f"blades: LAI {bl['lai_blades']:.2f}, mean inclination {bl['blade_inclination_deg_mean']:.1f}°")
    for q in bl["suns"]:
        console.print(
            f"sun {q['sun_deg']}: G {q['G_blades']:.3f}, k {q['k_blades']:.2f}, Beer–Lambert τ {q['tau_blades']:.3f}"
            f" (blades), {q['tau_with_stems_and_sheaths']:.3f} (with stems and sheaths)"
        )
    return res


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n-plants", type=int, default=100)
    ap.add_argument("--sheaths", default=SHEATHS[0], choices=SHEATHS)
    ap.add_argument("--out", type=Path, default=OUT)
    a = ap.parse_args()
    main(a.n_plants, a.out, a.sheaths)
