"""How far the model's Monte Carlo SDs of PAR overstate the estimator's own, at the main job's setting.

    python experiments/mc_sd_aggregates.py [--seeds 1 2 3 4 5 6 7 8] [--out experiments/results/mc_sd_aggregates.json]

The coupled model turns per-segment standard errors into Monte Carlo SDs with two simplifications
(``lightfit.model.observe``): a segment's PAR SD is ``hypot(DNI·se_sun, DHI·se_sky)``, without the
sun–sky covariance the estimator reports (``Irradiance.cov``, used by ``relative_se``), and a
canopy total's SD is ``sqrt(Σ (a_s·sd_s)²)``, as if segments were independent. With the direct
light projected, segments share one set of rays per replicate (a ray that lands on one segment
cannot land on another), so their errors are correlated. Both simplifications can only be judged
against the estimator's replicates (``meta["replicate_means"]``: R independent estimates per
segment), which is what this script does on the main job's field and settings (the default
``ReplicationConfig``: 10 × 10 plants as one periodic cell, PROSPECT-D leaf, K and bounces of the
main job, the direct light projected), at the day's highest sun with that step's PAR DNI and DHI:

* per segment, absorbed PAR: the SD without the covariance ÷ the SD with it (median, p10, p90;
  blades and all segments);
* canopy absorbed PAR per ground area (Σ a_s·x_s / A_ground) and the area-weighted mean PAR at the
  blades: the independent-segments SD ÷ the SE of the total taken from the R replicate totals;
* across ``--seeds`` (independent renders): the spread of the canopy total, next to the mean of the
  replicate SEs (the two estimate the same SD when replicates are independent; with 8 seeds the
  spread's own uncertainty is ≈ ±27 %).

Writes JSON and prints a table. Values are ratios of SDs; > 1 means the model's SD is larger.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np
from rich.table import Table

from lightfit.precision import use_float64

use_float64()  # lightfit's precision policy (lightfit.precision), before any JAX array exists

OUT = Path(__file__).resolve().parent / "results" / "mc_sd_aggregates.json"
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))


def _quantiles(x: np.ndarray) -> dict:
    x = x[np.isfinite(x)]
    return {"median": float(np.median(x)), "p10": float(np.quantile(x, 0.1)), "p90": float(np.quantile(x, 0.9))}


def _total_ratio(w: np.ndarray, sd: np.ndarray, x_rep: np.ndarray) -> tuple[float, float, float]:
    """(ratio, independent, from replicates): the SD of Σ w_s x_s with segments taken as
    independent (per-segment SDs ``sd`` in quadrature) and the SE of that sum from the R replicates
    ``x_rep`` (S, R)."""
    independent = math.sqrt(float(((w * sd) ** 2).sum()))
    from_replicates = float((w @ x_rep).std(ddof=1)) / math.sqrt(x_rep.shape[1])
    return independent / from_replicates, independent, from_replicates


def main(seeds=tuple(range(1, 9)), out: Path = OUT) -> dict:
    from provenance import wide_console, write_result

    from lightfit import replication as rep
    from lightfit.light.estimator import SegmentEstimator
    from lightfit.light.scene import FieldScene

    cfg = rep.ReplicationConfig()
    model = rep.model_for(cfg, rep.forcing_of(cfg))
    sc, geom = model.scenario, model.geometry
    day = np.flatnonzero(model.day)
    i = int(day[np.argmax(model.sun_deg[day, 0])])
    dni, dhi = float(model.forcing.dni_par[i]), float(model.forcing.dhi_par[i])
    fs = FieldScene(geom.mesh, sc.optics, sky=sc.sky, cell=geom.cell)
    fs.set_sun(*(float(x) for x in model.sun_deg[i]))
    ground_m2 = float(geom.cell.area_m2)
    runs, totals = [], []
    for seed in seeds:
        est = SegmentEstimator(
            fs,
            model.segment_id,
            samples=sc.samples,
            bounces=sc.bounces,
            seed=int(seed),
            direct=sc.direct,
            direct_rays_per_m2=sc.direct_rays_per_m2,
        )
        r = est.render()
        a, blade = r.meta["area_m2"], r.meta["is_blade"]
        reps = r.meta["replicate_means"]
        R = reps["absorbed_sun"].shape[1]
        x = r.total("absorbed", dni, dhi)
        sd_without = np.hypot(dni * r.se["absorbed_sun"], dhi * r.se["absorbed_sky"])
        with np.errstate(divide="ignore", invalid="ignore"):  # segments without light: SD 0, ratio NaN
            sd_with = r.total_se("absorbed", dni, dhi)
            ratio = sd_without / sd_with
        x_rep = dni * reps["absorbed_sun"] + dhi * reps["absorbed_sky"]  # (S, R)

        canopy = _total_ratio(a / ground_m2, sd_without, x_rep)
        canopy_cov = _total_ratio(a / ground_m2, sd_with, x_rep)
        wb = np.where(blade, a, 0.0) / a[blade].sum()
        blades = _total_ratio(wb, sd_without, x_rep)
        totals.append(float(a @ x / ground_m2))
        runs.append(
            {
                "seed": int(seed),
                "replicates": int(R),
                "segment_sd_without_over_with_covariance": {
                    "blades": _quantiles(ratio[blade]),
                    "all": _quantiles(ratio),
                },
                "canopy_absorbed_par_umol_m2_s": totals[-1],
                "canopy_absorbed_par_sd": {
                    "model_umol_m2_s": canopy[1],
                    "replicates_umol_m2_s": canopy[2],
                    "model_over_replicates": canopy[0],
                    "with_covariance_over_replicates": canopy_cov[0],
                },
                "blade_mean_absorbed_par_sd": {
                    "model_umol_m2_s": blades[1],
                    "replicates_umol_m2_s": blades[2],
                    "model_over_replicates": blades[0],
                },
            }
        )
    res = {
        "configuration": {
            "field": repr(sc.field),
            "samples": int(sc.samples),
            "bounces": int(sc.bounces),
            "direct": sc.direct,
            "direct_rays_per_m2": list(sc.direct_rays_per_m2),
            "time_utc": str(model.times[i].tz_convert("UTC")),
            "sun_deg": [float(v) for v in model.sun_deg[i]],
            "dni_par_umol_m2_s": dni,
            "dhi_par_umol_m2_s": dhi,
            "segments": len(model.segment_id),
        },
        "runs": runs,
        "canopy_total_spread_over_seeds_umol_m2_s": float(np.std(totals, ddof=1)) if len(totals) > 1 else None,
        "canopy_total_replicate_se_rms_over_seeds_umol_m2_s": float(
            np.sqrt(np.mean([x["canopy_absorbed_par_sd"]["replicates_umol_m2_s"] ** 2 for x in runs]))
        ),
    }
    out.parent.mkdir(parents=True, exist_ok=True)
    write_result(out, res)
    t = Table(title=f"Monte Carlo SDs: model's ÷ estimator's replicates ({res['configuration']['time_utc']})")
    for c in ("seed", "segment SD w/o cov ÷ with (blades median, p90)", "canopy APAR SD", "blade-mean PAR SD"):
        t.add_column(c, justify="right")
    for run in runs:
        q = run["segment_sd_without_over_with_covariance"]["blades"]
        c, b = run["canopy_absorbed_par_sd"], run["blade_mean_absorbed_par_sd"]
        t.add_row(
            str(run["seed"]),
            f"{q['median']:.2f}, {q['p90']:.2f}",
            f"{c['model_umol_m2_s']:.3f} vs {c['replicates_umol_m2_s']:.3f} ({c['model_over_replicates']:.2f}×)",
            f"{b['model_umol_m2_s']:.3f} vs {b['replicates_umol_m2_s']:.3f} ({b['model_over_replicates']:.2f}×)",
        )
    wide_console().print(t)
    spread = res["canopy_total_spread_over_seeds_umol_m2_s"]
    if spread is not None:
        rms = res["canopy_total_replicate_se_rms_over_seeds_umol_m2_s"]
        model_sd = np.mean([x["canopy_absorbed_par_sd"]["model_umol_m2_s"] for x in runs])
        wide_console().print(
            f"canopy absorbed PAR over {len(seeds)} seeds: {np.mean(totals):.3f} µmol m⁻² s⁻¹, spread {spread:.3f}"
            f" (SD); the replicates' SE {rms:.3f} (RMS over seeds); the model's SD {model_sd:.3f}"
        )
    return res


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=list(range(1, 9)))
    ap.add_argument("--out", type=Path, default=OUT)
    args = ap.parse_args()
    main(tuple(args.seeds), args.out)
