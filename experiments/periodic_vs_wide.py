"""Periodic cell vs the same plants in the middle of a wide finite field (issue 13's 2 % check).

    python experiments/periodic_vs_wide.py [--n-plants 100] [--plants-per-row P] [--field-seed 1]
        [--samples 64] [--seeds 2] [--optics prospect|paper] [--bounces B] [--out PATH]

Same measured plants (N × N, default 10 × 10, or whole rows of ``--plants-per-row``: 100 plants as
5 rows × 20 make a cell as wide as long in metres; the default wrapped sheaths; ``--field-seed``:
other plants), same sun and weather
(2016-04-20 10:00 UTC, reconstructed forcing), K samples, the leaf of ``--optics`` (default the
default PROSPECT-D leaf; the first runs used the paper's grey leaf) with its bounces for 1 %
truncation (or ``--bounces``). Canopy absorbed PAR (µmol s⁻¹ over the measured
plants' segments, sun + sky parts) for:

- ``periodic``: the measured plants as one periodic cell (no buffer plants);
- ``wide``: the measured plants inside 8 buffer rows and 32 buffer plants along the rows
  (≈ 1 m of buffer both ways; the reference for the edge bias);
- ``default``: the reference paper's 2 buffer rows (and 2 plants along);
- ``copies``: the periodic field built the way VPL and Eradiate do it, an independent check of
  the ray wrapping: explicit shifted copies of the cell's mesh (≈ 1 m of copies each way, new
  segment ids) in a finite scene, measuring the central copy.

``periodic`` against ``copies`` isolates the wrapping (same infinite field; only the copies'
far edge differs); ``copies`` against ``wide`` is how representative N × N plants repeated are of
a field of all-different plants.

Each is rendered with ``--seeds`` independent seeds; the canopy total's Monte Carlo SD comes from
the per-segment standard errors (segments have independent random numbers). Growing the wide
field's ≈ 1 900 plants takes minutes the first time (then they are cached). Prints a table and
writes ``--out`` (default experiments/results/periodic_vs_wide.json).
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd

import lightfit  # noqa: F401
from lightfit import weather
from lightfit.light.estimator import SegmentEstimator, bounces_for_tolerance
from lightfit.light.leaf_optics import DEFAULT_PRESET, PRESETS
from lightfit.light.scene import FieldScene, Optics
from lightfit.model.scenario import Forcing
from lightfit.plant import Field, Mesh, build
from lightfit.precision import use_float64

use_float64()  # lightfit's precision policy (lightfit.precision), before any JAX array exists

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from provenance import write_result  # noqa: E402  (commit, cores, load and command with every JSON)

ROOT = Path(__file__).resolve().parents[1]
SETUPS = {
    "periodic": dict(boundary="periodic"),
    "copies": dict(boundary="periodic"),
    "wide": dict(boundary="finite", buffer_rows=8, buffer_along=32),
    "default": dict(boundary="finite", buffer_rows=2),
}
#: Reach of the explicit copies around the central cell, m (as the wide field's buffer).
COPIES_REACH_M = 1.0


def copies(mesh: Mesh, cell) -> tuple[Mesh, int]:
    """The cell's mesh tiled by lattice vectors out to :data:`COPIES_REACH_M` each way.

    Copy (i, j) ≠ (0, 0) gets segment ids + k·``stride`` (k ≥ 1), so the estimator samples only
    the central copy's (original) ids. Returns the mesh and the stride.
    """
    stride = 10 ** len(str(int(mesh.face_segment.max())))
    ni, nj = (int(math_ceil(COPIES_REACH_M / p)) for p in cell.size_m)
    parts, k = [mesh], 1
    for i in range(-ni, ni + 1):
        for j in range(-nj, nj + 1):
            if i == 0 and j == 0:
                continue
            v = mesh.vertices.copy()
            v[:, :2] += cell.lattice_shift(i, j)
            parts.append(Mesh(v, mesh.faces, mesh.face_segment + k * stride, mesh.face_is_blade))
            k += 1
    return Mesh.concatenate(parts), stride


def light(when: str = "2016-04-20 10:00") -> tuple[tuple[float, float], float, float]:
    """The sun (elevation, azimuth, degrees) and the direct-normal and diffuse-horizontal PAR
    (µmol m⁻² s⁻¹) at ``when`` (UTC) of the reconstructed 2016-04-20 forcing, as the coupled model
    takes them (:meth:`lightfit.model.scenario.Forcing.of`: the measured PAR, Spitters' diffuse share)."""
    step = weather.load("2016-04-20").loc[[pd.Timestamp(when, tz="UTC")]]
    par = Forcing.of(step)
    sun = (float(step["sun_elevation_deg"].iloc[0]), float(step["sun_azimuth_deg"].iloc[0]))
    return sun, float(par.dni_par[0]), float(par.dhi_par[0])


def math_ceil(x: float) -> int:
    return int(math.ceil(x - 1e-9))


def main(
    n_plants: int = 100,
    samples: int = 64,
    seeds: int = 2,
    optics: str = DEFAULT_PRESET,
    bounces: int | None = None,
    out: Path | None = None,
    plants_per_row: int | None = None,
    field_seed: int = 1,
) -> dict:
    sun, dni, dhi = light()
    leaf = Optics.preset(optics)
    bounces = bounces_for_tolerance(0.01, leaf) if bounces is None else bounces
    res = {}
    for name, kw in SETUPS.items():
        t = time.perf_counter()
        g = build(Field(n_plants=n_plants, seed=field_seed, plants_per_row=plants_per_row, **kw), progress=True)
        grow_s = time.perf_counter() - t
        if name == "copies":
            fs = FieldScene(copies(g.mesh, g.cell)[0], leaf)
        else:
            fs = FieldScene(g.mesh, leaf, cell=g.cell)
        fs.set_sun(*sun)
        ids = g.segments.loc[g.segments["measured"], "segment_id"].to_numpy()
        totals, variances, render_s, meta = [], [], [], None
        for seed in range(seeds):
            t = time.perf_counter()
            r = SegmentEstimator(fs, ids, samples=samples, bounces=bounces, seed=seed).render()
            render_s.append(time.perf_counter() - t)
            a = r.meta["area_m2"]
            totals.append(float(r.total("absorbed", dni, dhi) @ a))
            variances.append(
                float(((a * dni * r.se["absorbed_sun"]) ** 2 + (a * dhi * r.se["absorbed_sky"]) ** 2).sum())
            )
            meta = r.meta.get("periodic")
        res[name] = {
            **kw,
            "plants": len(g.plants),
            "mesh_faces": g.mesh.n_faces,
            "scene_faces": fs.n_scene_faces,
            "grow_or_load_s": grow_s,
            "render_s": render_s,
            "canopy_absorbed_umol_s": float(np.mean(totals)),
            "canopy_absorbed_sd": math.sqrt(sum(variances)) / seeds,
            "per_seed": totals,
            "periodic": meta,
        }
    ref = res["wide"]
    area = Field(n_plants=n_plants, plants_per_row=plants_per_row)
    print(
        f"{area.area_label} (field seed {field_seed}), leaf {optics}, K = {samples}, {bounces} bounces, "
        f"{seeds} seed(s), sun {sun[0]:.1f}° / {sun[1]:.1f}°"
    )
    print("| field | plants built | render (s) | canopy absorbed PAR vs wide field | MC SD of that |")
    for name, v in res.items():
        ratio = v["canopy_absorbed_umol_s"] / ref["canopy_absorbed_umol_s"]
        sd = ratio * math.hypot(
            v["canopy_absorbed_sd"] / v["canopy_absorbed_umol_s"],
            ref["canopy_absorbed_sd"] / ref["canopy_absorbed_umol_s"],
        )
        v["vs_wide"], v["vs_wide_sd"] = ratio - 1, sd if name != "wide" else 0.0
        print(
            f"| {name} | {v['plants']} | {np.mean(v['render_s']):.2f} | {100 * (ratio - 1):+.2f} % | "
            f"{100 * v['vs_wide_sd']:.2f} % |"
        )
    p, c = res["periodic"], res["copies"]
    wrap = p["canopy_absorbed_umol_s"] / c["canopy_absorbed_umol_s"] - 1
    wrap_sd = math.hypot(
        p["canopy_absorbed_sd"] / p["canopy_absorbed_umol_s"], c["canopy_absorbed_sd"] / c["canopy_absorbed_umol_s"]
    )
    res["periodic"]["vs_copies"], res["periodic"]["vs_copies_sd"] = wrap, wrap_sd
    print(f"periodic (ray wrapping) vs explicit copies: {100 * wrap:+.2f} % (MC SD {100 * wrap_sd:.2f} %)")
    out = ROOT / "experiments" / "results" / "periodic_vs_wide.json" if out is None else Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    write_result(
        out,
        {
            "sun_deg": sun,
            "dni_par": dni,
            "dhi_par": dhi,
            "samples": samples,
            "bounces": bounces,
            "optics": optics,
            "sheaths": Field().sheaths,
            "n_plants": n_plants,
            "plants_per_row": plants_per_row,
            "field_seed": field_seed,
            "measurement_area": area.area_label,
            "cell_m": [area.cell.along_m, area.cell.across_m],
            "fields": res,
        },
    )
    return res


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n-plants", type=int, default=100)
    ap.add_argument("--samples", type=int, default=64)
    ap.add_argument("--seeds", type=int, default=2)
    ap.add_argument("--optics", choices=PRESETS, default=DEFAULT_PRESET)
    ap.add_argument("--bounces", type=int, default=None, help="default: the leaf's for 1 %% truncation")
    ap.add_argument("--plants-per-row", type=int, default=None, help="default: a square N × N")
    ap.add_argument("--field-seed", type=int, default=1, help="the field's seed (its plants)")
    ap.add_argument("--out", type=Path, default=None)
    a = ap.parse_args()
    main(a.n_plants, a.samples, a.seeds, a.optics, a.bounces, a.out, a.plants_per_row, a.field_seed)
