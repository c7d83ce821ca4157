"""Is LESS 3's extra light on the culms inside their sheaths geometry or LESS? The field scaled up.

    python experiments/less_scaled_scene.py [--scales 1 10] [--ground-half-width 200] [--replicates 4]
        [--out experiments/results/less_scaled_scene.json]

Needs the LESS environment (README "Optional: LESS 3 peer"); without it, says so and stops.

With the default's wrapped sheaths, `benchmarks/bench_less.py` finds LESS giving the culms
(the stems inside their sheath tubes) ≈ 1.4 % more sun and ≈ 3.8 % more sky than lightfit, beyond
both tools' noise, while blades and sheaths agree as before (docs/light.md, "Peer: LESS 3").
A culm is 0.06–0.3 mm from its innermost sheath (a 1.5 mm hexagonal prism inside a 1.8 mm one).
Light transport is scale-free: scaling every vertex by S changes no irradiance per unit area (the
sun and sky are directional, the soil is a plane), but it scales those gaps by S against any fixed
ray offset or intersection tolerance a tracer has. So LESS runs here on the same field scaled by
each of ``--scales`` (the soil quad ``--ground-half-width`` in scaled metres, so its edge moves
as W / S), against lightfit at scale 1 (K = 256, as many seeds as LESS's replicates). An
offset on the culms that vanishes at a larger scale, with the blades' offset unchanged apart from
the soil edge, is LESS's handling of sub-millimetre gaps.

Settings are bench_less.py's. Writes experiments/results/less_scaled_scene.json and prints a table.
"""

from __future__ import annotations

import argparse
import sys
import types
from pathlib import Path

from rich.table import Table

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

import bench_less as bl  # noqa: E402  (benchmarks/ is a script folder, not a package)
from provenance import out_option, wide_console, write_result  # noqa: E402

from lightfit.light.scene import FieldScene  # noqa: E402
from lightfit.plant import Field, build  # noqa: E402
from lightfit.precision import use_float64  # noqa: E402

use_float64()  # lightfit's precision policy (lightfit.precision), before any JAX array exists

OUT = ROOT / "experiments" / "results" / "less_scaled_scene.json"
LESS_N, LIGHTFIT_K = 64, 256
CLASSES = ("blades", "sheaths", "culms")


def main(scales: list[float], ground_half_m: float, reps: int, out: Path) -> dict | None:
    console = wide_console()
    if bl.less_version() is None:
        console.print(f"{bl.less_missing()} Nothing run.", markup=False, highlight=False)
        return None
    fld = Field(n_plants=16, seed=1, boundary="finite")
    geom = build(fld)
    fs = FieldScene(geom.mesh, bl.lambertian_optics())
    fs.set_sun(bl.SUN_ELEVATION_DEG, bl.SUN_AZIMUTH_DEG)
    seg_ids, seg_index, area, blade = bl.segment_index(geom)
    classes = {c: m for c, m in bl.agreement_classes(geom, seg_ids, blade).items() if c in CLASSES}
    lf = bl.lightfit_renders(fs, seg_ids, LIGHTFIT_K, reps)
    rows = []
    for s in scales:
        m = geom.mesh
        scaled = types.SimpleNamespace(
            mesh=type(m)(m.vertices * s, m.faces, m.face_segment, m.face_is_blade), segments=geom.segments
        )
        row = {"scale": s, "ground_half_width_m": ground_half_m, "ground_half_width_unscaled_m": ground_half_m / s}
        row |= bl.finite_agreement(scaled, ground_half_m, LESS_N, reps, seg_index, lf, area, classes)
        rows.append(row)
        console.print(f"scale {s:g} done")
    res = {
        "plants_measured": 16,
        "sheaths": fld.sheaths,
        "less_samples": LESS_N,
        "lightfit_samples": LIGHTFIT_K,
        "replicates": reps,
        "median_abs_z_if_noise": bl.expected_abs_z(reps),
        "rows": rows,
    }
    out.parent.mkdir(parents=True, exist_ok=True)
    write_result(out, res)
    t = Table(title="canopy total, LESS (scene × S) ÷ lightfit (scale 1) − 1, and median |z| per segment")
    t.add_column("S (soil half-width, unscaled)")
    keys = [f"{p}_{c}" for p in ("sun", "sky") for c in CLASSES]
    for k in keys:
        t.add_column(k.replace("_", ", "), justify="right")
    for r in rows:
        t.add_row(
            f"{r['scale']:g} ({r['ground_half_width_unscaled_m']:g} m)",
            *(
                f"{r[k]['canopy_total_bias']:+.2%} ± {r[k]['canopy_total_bias_se']:.2%}, {r[k]['median_abs_z']:.2f}"
                for k in keys
            ),
        )
    console.print(t)
    return res


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scales", type=float, nargs="+", default=[1.0, 10.0])
    ap.add_argument("--ground-half-width", type=float, default=200.0, help="LESS's soil quad half-width, scaled m")
    ap.add_argument("--replicates", type=int, default=4)
    out_option(ap, OUT)
    a = ap.parse_args()
    bl.check_counts(ap, a.replicates)
    if min(a.scales) <= 0 or a.ground_half_width <= 0:
        ap.error("--scales and --ground-half-width: numbers > 0")
    main(a.scales, a.ground_half_width, a.replicates, a.out)
