"""Field-edge bias of absorbed PAR vs buffer width (rows across, plants along the rows).

    python experiments/buffer_edge_bias.py [--n-plants 16] [--samples 128]

Same measured plants (4 × 4 by default), same sun and weather (2016-04-20 10:00 UTC,
reconstructed forcing), the paper's grey leaf, K samples, 3 bounces; canopy absorbed PAR of the measured segments for
several (buffer_rows, buffer_along) against the widest field (10 rows, 40 plants along). Prints the
"Field-edge bias" table in docs/light.md and writes ``--out`` (default
experiments/results/buffer_edge_bias.json).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import lightfit  # noqa: F401
from lightfit.light.estimator import SegmentEstimator
from lightfit.light.scene import FieldScene, Optics
from lightfit.plant import Field, build
from lightfit.precision import use_float64

use_float64()  # lightfit's precision policy (lightfit.precision), before any JAX array exists

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from periodic_vs_wide import light  # noqa: E402  (the moment and its PAR, one home for these experiments)
from provenance import write_result  # noqa: E402  (commit, cores, load and command with every JSON)

ROOT = Path(__file__).resolve().parents[1]
BUFFERS = [(2, 2), (6, 6), (2, 8), (3, 12), (6, 24), (10, 40)]


def main(n_plants: int = 16, samples: int = 128, out: Path | None = None) -> dict:
    sun, dni, dhi = light()  # the coupled model's PAR: the measured PAR, Spitters' diffuse share
    res = {}
    for rows, along in BUFFERS:
        g = build(Field(boundary="finite", n_plants=n_plants, buffer_rows=rows, buffer_along=along, seed=1))
        fs = FieldScene(g.mesh, Optics.preset("paper"))
        fs.set_sun(*sun)
        ids = g.segments.loc[g.segments["measured"], "segment_id"].to_numpy()
        t = time.perf_counter()
        r = SegmentEstimator(fs, ids, samples=samples, bounces=3, seed=1).render()
        total = float((r.total("absorbed", dni, dhi) * r.meta["area_m2"]).sum())
        res[f"{rows},{along}"] = {
            "buffer_rows": rows,
            "buffer_along": along,
            "plants": len(g.plants),
            "render_s": time.perf_counter() - t,
            "canopy_absorbed": total,
        }
    ref = res[f"{BUFFERS[-1][0]},{BUFFERS[-1][1]}"]["canopy_absorbed"]
    print("| buffer rows | buffer_along | plants built | canopy absorbed PAR vs wide field |")
    for v in res.values():
        v["bias"] = v["canopy_absorbed"] / ref - 1
        print(f"| {v['buffer_rows']} | {v['buffer_along']} | {v['plants']} | {100 * v['bias']:+.1f} % |")
    out = ROOT / "experiments" / "results" / "buffer_edge_bias.json" if out is None else out
    out.parent.mkdir(parents=True, exist_ok=True)
    write_result(
        out, {"sun_deg": sun, "dni_par": dni, "dhi_par": dhi, "samples": samples, "n_plants": n_plants, "rows": res}
    )
    return res


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n-plants", type=int, default=16)
    ap.add_argument("--samples", type=int, default=128)
    ap.add_argument(
        "--out", type=Path, default=None, help="JSON to write (default experiments/results/buffer_edge_bias.json)"
    )
    a = ap.parse_args()
    main(a.n_plants, a.samples, a.out)
