"""Speed/accuracy trade of the per-segment irradiance estimator.

    python experiments/light_speed_accuracy.py [--n-plants 16] [--out results/light_speed_accuracy]

Sweeps samples per segment K, path depth (bounces), mesh resolution and buffer rows on one
field and sun position (2016-04-20, 10:00 UTC at Selhausen), and compares absorbed PAR per
segment and the canopy total with a high-sample reference (K = 1024, 8 bounces): for the
samples, depth and resolution knobs one with the same buffer rows (their own error), for the
buffer rows knob (and the default as a whole) one with 6 buffer rows (the field-edge bias).
Absorbed PAR uses that moment's reconstructed weather (DNI and DHI in PAR units). Writes a CSV,
a JSON and a Pareto plot (error vs time), and prints a table. Segments are matched across
settings by plant position and segment index, which do not depend on the buffer rows.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
from rich.console import Console  # noqa: E402
from rich.table import Table  # noqa: E402

import lightfit  # noqa: E402,F401
from lightfit import weather  # noqa: E402
from lightfit.light.estimator import SegmentEstimator  # noqa: E402
from lightfit.light.scene import FieldScene, Optics  # noqa: E402
from lightfit.plant import Field, MeshResolution, build  # noqa: E402
from lightfit.precision import use_float64
from lightfit.weather.units import par_from_ghi  # noqa: E402

use_float64()  # lightfit's precision policy (lightfit.precision), before any JAX array exists

ROOT = Path(__file__).resolve().parents[1]
REFERENCE = dict(samples=1024, bounces=8, buffer_rows=6, along=1, across=1)
DEFAULT = dict(samples=64, bounces=3, buffer_rows=2, along=1, across=1)
SWEEP = (
    [{"samples": k} for k in (8, 16, 32, 64, 128, 256)]
    + [{"bounces": b} for b in (0, 1, 2, 4, 6)]
    + [{"buffer_rows": b} for b in (0, 1, 3, 4, 6)]
    + [{"along": 3, "across": 2}]
)


def _absorbed(n_plants: int, setting: dict, sun: tuple[float, float], dni: float, dhi: float, seed: int):
    fld = Field(n_plants=n_plants, buffer_rows=setting["buffer_rows"], seed=1)
    geom = build(fld, resolution=MeshResolution(setting["along"], setting["across"]))
    fs = FieldScene(geom.mesh, Optics())
    fs.set_sun(*sun)
    seg = geom.segments[geom.segments["measured"]]
    t0 = time.perf_counter()
    est = SegmentEstimator(
        fs, seg["segment_id"].to_numpy(), samples=setting["samples"], bounces=setting["bounces"], seed=seed
    )
    r = est.render()
    elapsed = time.perf_counter() - t0
    key = seg.set_index("segment_id").loc[r.segment_id]
    plants = fld.plants().set_index("plant_id").loc[key["plant_id"]]
    out = pd.DataFrame(
        {
            "r": plants["r"].to_numpy(),
            "c": plants["c"].to_numpy(),
            "segment_index": key["segment_index"].to_numpy(),
            "area_m2": r.meta["area_m2"],
            "absorbed": r.total("absorbed", dni, dhi),
            "rse": r.relative_se("absorbed", dni, dhi),
        }
    ).set_index(["r", "c", "segment_index"])
    return out, elapsed, est.n_evaluations


def main(n_plants: int = 16, out_dir: Path = ROOT / "results" / "light_speed_accuracy") -> pd.DataFrame:
    out_dir.mkdir(parents=True, exist_ok=True)
    w = weather.load("2016-04-20")
    row = w.loc[pd.Timestamp("2016-04-20 10:00", tz="UTC")]
    sun = (float(row["sun_elevation_deg"]), float(row["sun_azimuth_deg"]))
    dni, dhi = float(par_from_ghi(row["dni_w_m2"])), float(par_from_ghi(row["dhi_w_m2"]))
    console = Console()
    console.print(
        f"sun {sun[0]:.1f}° / {sun[1]:.1f}°, PAR DNI {dni:.0f}, DHI {dhi:.0f} µmol m⁻² s⁻¹ (RECONSTRUCTED forcing)"
    )
    refs = {}

    def reference(buffer_rows):
        if buffer_rows not in refs:
            r, t, _ = _absorbed(n_plants, {**REFERENCE, "buffer_rows": buffer_rows}, sun, dni, dhi, seed=12345)
            refs[buffer_rows] = (r, float((r["absorbed"] * r["area_m2"]).sum()), t)
        return refs[buffer_rows]

    rows = []
    for change in [{}] + SWEEP:
        setting = {**DEFAULT, **change}
        # Sampling, depth and resolution are judged against a reference with the same buffer
        # (their own error); buffer rows against the wide-buffer reference (the edge bias).
        ref, ref_total, t_ref = reference(
            REFERENCE["buffer_rows"] if "buffer_rows" in change or not change else setting["buffer_rows"]
        )
        res, t, n_ev = _absorbed(n_plants, setting, sun, dni, dhi, seed=1)
        j = res.join(ref, rsuffix="_ref", how="inner")
        lit = j["absorbed_ref"] > 1e-3 * j["absorbed_ref"].max()
        rel = (j["absorbed"] - j["absorbed_ref"]).abs()[lit] / j["absorbed_ref"][lit]
        total = float((res["absorbed"] * res["area_m2"]).sum())
        rows.append(
            {
                **setting,
                "changed": ",".join(change) or "default",
                "time_s": t,
                "evaluations": n_ev,
                "median_rel_err_segment": float(rel.median()),
                "p90_rel_err_segment": float(rel.quantile(0.9)),
                "median_reported_rse": float(np.nanmedian(res["rse"])),
                "canopy_total_rel_err": abs(total - ref_total) / ref_total,
            }
        )
        console.print(rows[-1])
    df = pd.DataFrame(rows)
    df.to_csv(out_dir / "sweep.csv", index=False)
    (out_dir / "sweep.json").write_text(
        json.dumps(
            {
                "reference": REFERENCE,
                "reference_time_s": {str(k): v[2] for k, v in refs.items()},
                "sun_deg": sun,
                "dni_par": dni,
                "dhi_par": dhi,
                "n_plants": n_plants,
                "rows": rows,
            },
            indent=2,
        )
    )
    fig, ax = plt.subplots(1, 2, figsize=(12, 5), constrained_layout=True)
    for name, grp in df.groupby("changed"):
        for a, col in zip(ax, ("median_rel_err_segment", "canopy_total_rel_err")):
            a.plot(grp["time_s"], grp[col], "o-" if len(grp) > 1 else "o", label=name)
    for a, title in zip(ax, ("median per-segment error", "canopy-total error")):
        a.set_xscale("log")
        a.set_yscale("log")
        a.set_xlabel("wall time (s), 2 CPU cores")
        a.set_ylabel("relative error vs reference")
        a.set_title(title)
        a.grid(True, which="both", alpha=0.3)
    ax[0].legend(title="knob varied from default", fontsize=8)
    fig.suptitle(f"Irradiance speed/accuracy, {n_plants} measured plants (reference: K=1024, 8 bounces, 6 buffer rows)")
    fig.savefig(out_dir / "pareto.png", dpi=110)
    t = Table(title="speed/accuracy (absorbed PAR, vs reference)")
    columns = (
        "changed",
        "samples",
        "bounces",
        "buffer_rows",
        "along",
        "time_s",
        "median_rel_err_segment",
        "p90_rel_err_segment",
        "median_reported_rse",
        "canopy_total_rel_err",
    )
    for c in columns:
        t.add_column(c, justify="right")
    for r in rows:
        t.add_row(*(f"{r[c]:.3g}" if isinstance(r[c], float) else str(r[c]) for c in columns))
    console.print(t)
    return df


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n-plants", type=int, default=16)
    ap.add_argument("--out", type=Path, default=ROOT / "results" / "light_speed_accuracy")
    a = ap.parse_args()
    main(a.n_plants, a.out)
