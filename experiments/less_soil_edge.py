"""Where LESS 3 and lightfit differ in canopy totals: the edge of LESS's soil (issue 16, item 3).

    python experiments/less_soil_edge.py [--half-widths 5 12.5 50 200] [--replicates 4]
        [--sheaths wrapped|rods] [--out experiments/results/less_soil_edge.json]

Needs the LESS environment (README "Optional: LESS 3 peer"); without it, says so and stops.

`benchmarks/bench_less.py` finds small canopy-total offsets between the two tools on the finite
16-plant field that are beyond their noise (LESS ÷ lightfit − 1: sun on stems ≈ −1.3 %, sky on
blades ≈ +0.6 %, on stems ≈ +1.2 %; docs/light.md "Peer: LESS 3"). lightfit's soil is an infinite
plane; LESS gets an explicit Lambertian soil quad of half-width W around the field (its terrain is
not seen by rays leaving leaves), and in LESS's reverse tracing a ray that leaves the scene in any
direction, downward too, collects the sky. A ray from a leaf at height h going down within
≈ atan(h / W) of the horizon misses the quad and sees the sky instead of the sunlit soil, so the
offset this makes should fall as ≈ 1/W.

This runs LESS (n = 64 per triangle side, ``--replicates`` face orders) on the same field with
soil quads of several half-widths, and lightfit once (K = 256, the same number of seeds), and
fits each canopy-total offset as c₀ + c₁/W: c₁ is the soil edge's share, c₀ what is left for an
infinite soil. Settings are bench_less.py's (Lambertian leaf R 0.0825 / T 0.0675 per side, soil
0.12, 3 scattering events, the sun of 2016-04-20 10:00 UTC, isotropic sky).

Writes experiments/results/less_soil_edge.json and prints a table.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np
from rich.table import Table

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

import bench_less as bl  # noqa: E402  (benchmarks/ is a script folder, not a package)
from provenance import out_option, wide_console, write_result  # noqa: E402

from lightfit.light.scene import FieldScene  # noqa: E402
from lightfit.plant import Field, build  # noqa: E402
from lightfit.plant.sheaths import SHEATHS  # noqa: E402
from lightfit.precision import use_float64  # noqa: E402

use_float64()  # lightfit's precision policy (lightfit.precision), before any JAX array exists

OUT = ROOT / "experiments" / "results" / "less_soil_edge.json"
LESS_N, LIGHTFIT_K = 64, 256


#: The classes fitted: blades, stems and sheaths together, and each apart.
CLASSES = ("blades", "stems", "sheaths", "culms")


def main(half_widths: list[float], reps: int, sheaths: str = SHEATHS[0], out: Path = OUT) -> dict | None:
    console = wide_console()
    if bl.less_version() is None:
        console.print(f"{bl.less_missing()} Nothing run.", markup=False, highlight=False)
        return None
    geom = build(Field(n_plants=16, seed=1, boundary="finite", sheaths=sheaths))
    fs = FieldScene(geom.mesh, bl.lambertian_optics())
    fs.set_sun(bl.SUN_ELEVATION_DEG, bl.SUN_AZIMUTH_DEG)
    seg_ids, seg_index, area, blade = bl.segment_index(geom)
    n_seg = len(seg_ids)
    above_soil = bl.agreement_classes(geom, seg_ids, blade)  # the buried bases apart: see there
    classes = {c: above_soil[c] for c in CLASSES}
    lf = bl.lightfit_renders(fs, seg_ids, LIGHTFIT_K, reps)
    console.print(f"lightfit: {reps} renders at K = {LIGHTFIT_K}")
    rows = []
    for w in half_widths:
        row = {"ground_half_width_m": w}
        row |= bl.finite_agreement(geom, w, LESS_N, reps, seg_index, lf, area, classes)
        rows.append(row)
        console.print(f"soil quad half-width {w} m done")
    fits = {}
    inv_w = 1.0 / np.asarray(half_widths)
    keys = [f"{part}_{c}" for part in ("sun", "sky") for c in CLASSES]
    for key in keys:
        y = np.array([r[key]["canopy_total_bias"] for r in rows])
        s = np.array([r[key]["canopy_total_bias_se"] for r in rows])
        X = np.stack([np.ones_like(inv_w), inv_w], 1) / s[:, None]
        coef, *_ = np.linalg.lstsq(X, y / s, rcond=None)
        cov = np.linalg.inv(X.T @ X)
        fits[key] = {
            "infinite_soil_offset": float(coef[0]),
            "infinite_soil_offset_se": float(math.sqrt(cov[0, 0])),
            "per_inverse_m": float(coef[1]),
            "chi2_per_dof": float(np.sum(((X @ coef) - y / s) ** 2) / max(len(y) - 2, 1)),
        }
    res = {
        "plants_measured": 16,
        "sheaths": sheaths,
        "segments": n_seg,
        "less_samples": LESS_N,
        "lightfit_samples": LIGHTFIT_K,
        "replicates": reps,
        "rows": rows,
        "fits_c0_plus_c1_over_w": fits,
    }
    out.parent.mkdir(parents=True, exist_ok=True)
    write_result(out, res)
    t = Table(title="canopy total, LESS ÷ lightfit − 1, by the half-width W of LESS's soil quad")
    t.add_column("W")
    for k in keys:
        t.add_column(k.replace("_", ", "), justify="right")
    for r in rows:
        t.add_row(
            f"{r['ground_half_width_m']:g} m",
            *(f"{r[k]['canopy_total_bias']:+.2%} ± {r[k]['canopy_total_bias_se']:.2%}" for k in keys),
        )
    t.add_row(
        "fit, W → ∞",
        *(f"{fits[k]['infinite_soil_offset']:+.2%} ± {fits[k]['infinite_soil_offset_se']:.2%}" for k in keys),
    )
    console.print(t)
    return res


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--half-widths", type=float, nargs="+", default=[5.0, 12.5, 50.0, 200.0])
    ap.add_argument("--replicates", type=int, default=4)
    ap.add_argument("--sheaths", choices=SHEATHS, default=SHEATHS[0], help="leaf sheath layout (lightfit.plant.Field)")
    out_option(ap, OUT)
    a = ap.parse_args()
    bl.check_counts(ap, a.replicates)
    if len(set(a.half_widths)) < 2 or min(a.half_widths) <= 0:
        ap.error(
            f"--half-widths {' '.join(map(str, a.half_widths))}: "
            "at least two different widths > 0 m (c₀ + c₁/W is fitted)"
        )
    main(a.half_widths, a.replicates, a.sheaths, a.out)
