"""What wrapping the leaf sheaths around the stem changes: CPlantBox's rods against the default.

    python experiments/wrapped_sheaths.py [--n-plants 100] [--out JSON]

CPlantBox draws each wheat leaf's basal zone (its first 8 cm, no blade width: the sheath) as a
0.6 mm rod leaning 13–24° from the vertical, so each blade starts 1.6–3.9 cm from its stem
(docs/plant.md, "Leaf sheaths"; `experiments/canopy_structure.py`). A wheat sheath is a tube
around the culm up to the collar: `Field(sheaths="wrapped")`, the default
(`lightfit.plant.sheaths`). This experiment renders both layouts of the main job's field — the
measured plants as one periodic cell, seed 1, 20 April 2016 — `sheaths="rods"` (CPlantBox's, the
paper preset's) and `sheaths="wrapped"`:

Rendered with the PROSPECT-D leaf and its bounces, K = 16, the direct light projected
(1.5 × 10⁷ / 2 × 10⁷ rays per m², sun and sky), sun 50° / 180°, seed 2, absorbed PAR at DNI 1,
DHI 0.3: canopy absorbed PAR per ground area by organ, the blades' per-segment distribution, the
median relative SE per organ, and a ceptometer on the soil (the sensor of docs/model.md).

Writes experiments/results/wrapped_sheaths.json (or ``--out``) and prints a table.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from rich.table import Table

from lightfit.precision import use_float64

use_float64()  # lightfit's precision policy (lightfit.precision), before any JAX array exists

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from provenance import wide_console, write_result  # noqa: E402  (commit, cores, load and command with every JSON)

OUT = Path(__file__).resolve().parent / "results" / "wrapped_sheaths.json"
SUN_DEG = (50.0, 180.0)
DHI_PER_DNI = 0.3
ORGANS = ("blade", "sheath", "stem")
ROD, WRAPPED = "rods (CPlantBox, the paper preset)", "wrapped around the stem (default)"


def render(geom, fld) -> dict:
    from lightfit.light.estimator import SegmentEstimator, bounces_for_tolerance
    from lightfit.light.scene import FieldScene, Optics
    from lightfit.light.sensors import SensorEstimator, ceptometer, measured_area
    from lightfit.plant import one_sided_area_m2, organ_class

    optics = Optics.preset("prospect")
    bounces = bounces_for_tolerance(0.01, optics)
    fs = FieldScene(geom.mesh, optics, cell=geom.cell)
    segments = geom.segments
    fs.set_sun(*SUN_DEG)
    ids = segments.loc[segments["measured"], "segment_id"].to_numpy()
    seg = segments.set_index("segment_id").loc[ids]
    organ, area = organ_class(seg), one_sided_area_m2(seg)
    r = SegmentEstimator(
        fs, ids, samples=16, bounces=bounces, seed=2, direct="projection", direct_rays_per_m2=(1.5e7, 2e7)
    ).render()
    v = r.total("absorbed", 1.0, DHI_PER_DNI)
    rse = r.relative_se("absorbed", 1.0, DHI_PER_DNI)
    # Blades absorb on both sides: per unit one-sided area, times that area, is the segment's flux.
    ground = geom.cell.area_m2
    c = SensorEstimator(fs, [ceptometer(measured_area(fld))], samples=4096, bounces=bounces, seed=2).render()
    above = np.sin(np.radians(SUN_DEG[0])) + DHI_PER_DNI  # PAR above the canopy, per unit DNI
    cept = c.total("incident", 1.0, DHI_PER_DNI)[0] / above
    cept_se = cept * c.relative_se("incident", 1.0, DHI_PER_DNI)[0]
    out = {"ceptometer_transmittance": float(cept), "ceptometer_transmittance_se": float(cept_se), "organs": {}}
    for o in ORGANS:
        m = organ == o
        ok = m & np.isfinite(rse)
        out["organs"][o] = {
            "absorbed_per_ground": float(np.sum(v[m] * area[m]) / ground),
            "absorbed_per_area_p10_50_90": [float(x) for x in np.percentile(v[m], [10, 50, 90])],
            "median_rse": float(np.median(np.where(ok, rse, np.inf)[m])),
        }
    finite = np.isfinite(rse)
    # A segment without light has no relative SE: counted as above any target, not left out.
    out["median_rse_all"] = float(np.median(np.where(finite, rse, np.inf)))
    out["segments_without_light"] = int(np.sum(~finite))
    return out


def main(n_plants: int = 100, out: Path = OUT) -> dict:
    from lightfit.plant import Field, build

    res = {"n_plants": int(Field(n_plants=n_plants).n_measured), "sun_deg": SUN_DEG, "dhi_per_dni": DHI_PER_DNI}
    for name, sheaths in ((ROD, "rods"), (WRAPPED, "wrapped")):
        fld = Field(n_plants=n_plants, seed=1, boundary="periodic", sheaths=sheaths)
        geom = build(fld)
        res[name] = render(geom, fld)
    out.parent.mkdir(parents=True, exist_ok=True)
    write_result(out, res)
    t = Table(title=f"sheaths as rods or as tubes around the stem: {res['n_plants']} plants, periodic cell")
    t.add_column("quantity")
    names = (ROD, WRAPPED)
    for n in names:
        t.add_column(n, justify="right")
    t.add_row(
        "ceptometer transmittance",
        *(f"{res[n]['ceptometer_transmittance']:.3f} ± {res[n]['ceptometer_transmittance_se']:.3f}" for n in names),
    )
    for o in ORGANS:
        per_ground = (f"{res[n]['organs'][o]['absorbed_per_ground']:.4f}" for n in names)
        t.add_row(f"{o}s: absorbed PAR per ground area", *per_ground)
        t.add_row(
            f"{o}s: per unit area p10 / 50 / 90",
            *(" / ".join(f"{x:.3f}" for x in res[n]["organs"][o]["absorbed_per_area_p10_50_90"]) for n in names),
        )
        t.add_row(f"{o}s: median relative SE", *(f"{res[n]['organs'][o]['median_rse']:.2%}" for n in names))
    t.add_row("all segments: median relative SE", *(f"{res[n]['median_rse_all']:.2%}" for n in names))
    t.add_row("segments without light", *(str(res[n]["segments_without_light"]) for n in names))
    wide_console().print(t)
    return res


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n-plants", type=int, default=100)
    ap.add_argument("--out", type=Path, default=OUT, help="JSON to write (default: the tracked result the docs cite)")
    args = ap.parse_args()
    main(args.n_plants, args.out)
    print(f"wrote {args.out}")
