"""Bias of canopy photosynthesis from per-segment Monte Carlo noise (Jensen), at the main job's settings.

    python experiments/an_noise_bias.py [--samples 32 64 512] [--seeds 4] [--out experiments/results/an_noise_bias.json]

Leaf net assimilation is concave in absorbed PAR (light saturation), so noise in a blade's
absorbed PAR lowers its expected An: to second order E[An(q + ε)] − An(q) = ½ An''(q) Var(ε)
< 0. The canopy An of ``lightfit replicate`` therefore carries a bias that falls as 1/K (the
per-segment variance does), while its reported Monte Carlo SD falls only as 1/√K and, being
the spread of a sum over thousands of blades, is far smaller. This runs the main job
(``lightfit replicate``, its defaults: periodic 10 × 10 cell, PROSPECT-D leaf, 2 bounces,
``winter_wheat``) at each K with render seeds 0 … ``--seeds`` − 1, fits the seed mean of the
daily sum of daytime canopy An as An(K) = An∞ + c / K (least squares over the Ks, weighted by the
seed means' standard errors), and reports each K's bias (An(K) − An∞) / An∞ with its standard
error from the seed spread, next to the reported Monte Carlo SD of one run's daily sum (two
bounds: the steps' errors are correlated, frozen sampling), the same for canopy APAR (linear in
PAR: no bias expected, its differences from the fit are noise), and the bias the run
itself predicts (``canopy_an_mc_bias_umol_m2_s``, :func:`lightfit.model.observe.an_noise_bias`),
an independent check of the fit. Writes JSON and prints a table. Plants and kernels come from the
user's caches.

The stored experiments/results/an_noise_bias.json (2026-12-02) is of the main job as it was then:
its direct light from the paths, the sheaths as rods. Today's main job projects the direct light,
so this script now measures a bias an order of magnitude smaller: that file is not reproduced
(docs/model.md, "Monte Carlo bias of canopy An").
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import xarray as xr
from rich.table import Table

from lightfit.precision import use_float64

use_float64()  # lightfit's precision policy (lightfit.precision); the main jobs run in subprocesses

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from provenance import wide_console, write_result  # noqa: E402  (commit, cores, load and command with every JSON)

ROOT = Path(__file__).resolve().parents[1]


def run(samples: int, seed: int, out: Path) -> dict:
    """One main job at K = ``samples``: daily sums of daytime canopy An and APAR with their MC SDs."""
    t = time.perf_counter()
    subprocess.run(
        [
            sys.executable,
            "-m",
            "lightfit.cli",
            "replicate",
            "--samples",
            str(samples),
            "--render-seed",
            str(seed),
            "--out",
            str(out),
        ],
        check=True,
        stdout=subprocess.DEVNULL,
    )
    wall = time.perf_counter() - t
    with xr.open_dataset(out / "results.nc", engine="h5netcdf") as ds:
        day = ds["sun_elevation_deg"].values > 0
        res = {"samples": samples, "seed": seed, "wall_s": wall}
        for name in ("canopy_an", "canopy_apar"):
            v = ds[f"{name}_umol_m2_s"].values[day]
            sd = ds[f"{name}_mc_sd_umol_m2_s"].values[day]
            res[f"{name}_daily_sum"] = float(v.sum())
            # Bounds of the daily sum's MC SD: a segment draws the same random numbers at every step
            # (frozen sampling), so its sky part errs alike all day (lightfit.model.observe.mc_covariance):
            # steps independent (root sum of squares) or fully correlated (sum of SDs).
            res[f"{name}_daily_sum_mc_sd_independent"] = float(np.sqrt((sd**2).sum()))
            res[f"{name}_daily_sum_mc_sd_correlated"] = float(sd.sum())
            res[f"{name}_per_step"] = v.tolist()
        if "canopy_an_mc_bias_umol_m2_s" in ds:  # the Gauss–Hermite prediction (an_noise_bias)
            res["canopy_an_predicted_bias_daily_sum"] = float(ds["canopy_an_mc_bias_umol_m2_s"].values[day].sum())
    return res


def main(samples: list[int], seeds: int, out: Path) -> dict:
    console = wide_console()
    runs = []
    with tempfile.TemporaryDirectory(prefix="lightfit-an-bias-") as d:
        for k in samples:
            for seed in range(seeds):
                runs.append(run(k, seed, Path(d) / f"k{k}_s{seed}"))
                console.print(f"K = {k}, seed {seed}: {runs[-1]['wall_s']:.0f} s")
    res = {"samples": samples, "seeds": seeds, "runs": runs, "load_average_end": os.getloadavg()[0]}
    inv_k = np.array([1.0 / k for k in samples])
    for name in ("canopy_an", "canopy_apar"):
        per_k = [np.array([r[f"{name}_daily_sum"] for r in runs if r["samples"] == k]) for k in samples]
        mean = np.array([v.mean() for v in per_k])
        se = np.array([v.std(ddof=1) / np.sqrt(len(v)) if len(v) > 1 else np.nan for v in per_k])
        w = 1.0 / se if np.all(np.isfinite(se) & (se > 0)) else None
        c, a_inf = np.polyfit(inv_k, mean, 1, w=w)  # mean = a_inf + c / K
        res[name] = {
            "daily_sum_at_infinite_k": float(a_inf),
            "c": float(c),
            "relative_bias": {str(k): float((m - a_inf) / a_inf) for k, m in zip(samples, mean)},
            "relative_bias_se": {str(k): float(e / abs(a_inf)) for k, e in zip(samples, se)},
            "relative_reported_mc_sd_one_run_bounds": {
                str(k): [
                    float(np.mean([r[f"{name}_daily_sum_mc_sd_{b}"] for r in runs if r["samples"] == k]) / abs(a_inf))
                    for b in ("independent", "correlated")
                ]
                for k in samples
            },
        }
        if name == "canopy_an":
            res[name]["relative_predicted_bias"] = {
                str(k): float(
                    np.mean([r["canopy_an_predicted_bias_daily_sum"] for r in runs if r["samples"] == k]) / abs(a_inf)
                )
                for k in samples
            }
    out.parent.mkdir(parents=True, exist_ok=True)
    write_result(out, res, indent=1)
    t = Table(
        title=f"daily sums of daytime canopy An and APAR, mean of {seeds} render seeds, against An(K) = An∞ + c/K"
    )
    cols = ("K", "An bias (fit)", "An bias (predicted)", "one run's MC SD", "APAR diff. (fit)")
    for col in cols:
        t.add_column(col, justify="right")
    for k in map(str, samples):
        an, ap = res["canopy_an"], res["canopy_apar"]
        t.add_row(
            k,
            f"{an['relative_bias'][k]:+.3%} ± {an['relative_bias_se'][k]:.3%}",
            f"{an['relative_predicted_bias'][k]:+.3%}",
            "{:.3%} – {:.3%}".format(*an["relative_reported_mc_sd_one_run_bounds"][k]),
            f"{ap['relative_bias'][k]:+.3%} ± {ap['relative_bias_se'][k]:.3%}",
        )
    console.print(t)
    console.print(f"wrote {out}")
    return res


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, nargs="+", default=[32, 64, 512])
    ap.add_argument("--seeds", type=int, default=4, help="render seeds per K (≥ 2 for standard errors)")
    ap.add_argument("--out", type=Path, default=ROOT / "experiments" / "results" / "an_noise_bias.json")
    a = ap.parse_args()
    if len(set(a.samples)) < 2:  # the bias is fitted as a + c / K: one K cannot separate them
        ap.error("--samples needs at least two different K (the bias is fitted as a + c/K)")
    main(a.samples, a.seeds, a.out)
