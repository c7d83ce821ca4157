"""The default photosynthesis set against published winter-wheat ranges (issue 14, item 2).

    python experiments/photosynthesis_default_check.py [--full]

1. Leaf level: the light response (An against absorbed PAR at 25 °C, 400 ppm, RH 0.6) of every
   named set; light-saturated An is compared with the 20–35 µmol m⁻² s⁻¹ of wheat flag leaves.
2. Canopy level: the main job's quick configuration (``ReplicationConfig.quick()``; with
   ``--full`` also the default configuration) run by :func:`lightfit.replication.run` once per set,
   reading the night-time (sun below the horizon) and noon (12:00–14:00 local) canopy net CO2
   exchange per ground area, checked against −8 … −1 (night) and 15 … 50 (noon) µmol m⁻² s⁻¹,
   and the fraction of Rubisco-limited blades at noon, with the default PROSPECT-D leaf
   (absorptance 0.90); the quick configuration is also run with the reference paper's grey 0.5
   leaf (``optics="paper"``, absorptance 0.49) to show what the leaf optics change.

Prints a Markdown table and writes ``--out`` (default
experiments/results/photosynthesis_default_check.json). Every number comes
from the model run here.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd

from lightfit.precision import use_float64

use_float64()  # lightfit's precision policy (lightfit.precision), before any JAX array exists

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from provenance import write_result  # noqa: E402  (commit, cores, load and command with every JSON)

import lightfit.photosynthesis as ps  # noqa: E402
from lightfit.replication import ReplicationConfig, run  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SETS = (ps.DEFAULT_PARAMETER_SET, "giraud2023")
#: Published ranges checked (docs/photosynthesis.md, "Checks against published ranges").
NIGHT_RANGE = (-8.0, -1.0)
NOON_RANGE = (15.0, 50.0)
LEAF_SATURATED_RANGE = (20.0, 35.0)
PAR_GRID = np.array([0.0, 25.0, 50.0, 100.0, 200.0, 400.0, 600.0, 800.0, 1000.0, 1500.0, 2000.0])


def light_response(name: str) -> dict:
    """An against absorbed PAR at 25 °C, 400 ppm, RH 0.6, 101.325 kPa (no boundary layer)."""
    r = ps.solve(PAR_GRID, 25.0, 400.0, 0.6, 101.325, ps.parameter_set(name))
    an = np.asarray(r.an_umol_m2_s)
    return {
        "par_abs_umol_m2_s": PAR_GRID.tolist(),
        "an_umol_m2_s": an.round(3).tolist(),
        "limitation": np.asarray(r.limitation).tolist(),
        "converged": bool(np.all(r.converged)),
        "dark_an_umol_m2_s": float(an[0]),
        "saturated_an_umol_m2_s": float(an.max()),
        "initial_slope_mol_mol": float((an[1] - an[0]) / PAR_GRID[1]),
        "saturated_in_range": bool(LEAF_SATURATED_RANGE[0] <= an.max() <= LEAF_SATURATED_RANGE[1]),
    }


def canopy(cfg: ReplicationConfig, name: str, optics: str | None = None) -> dict:
    t0 = time.perf_counter()
    cfg = replace(cfg, photosynthesis=name, **({} if optics is None else {"optics": optics}))
    ds, _ = run(cfg, observations=None)
    local = pd.DatetimeIndex(ds["time"].values).tz_localize("UTC").tz_convert("Europe/Berlin")
    an = ds["canopy_an_umol_m2_s"].values
    night = ds["sun_elevation_deg"].values < 0
    hours = local.hour + local.minute / 60
    noon = (hours >= 12.0) & (hours <= 14.0)
    blades = ds["is_blade"].values.astype(bool)
    lim = ds["limitation"].values[np.ix_(noon, blades)]
    n_night, n_noon = float(an[night].mean()), float(an[noon].mean())
    return {
        "photosynthesis": name,
        "optics": cfg.optics,
        "night_steps_local": [t.strftime("%H:%M") for t in local[night]],
        "night_canopy_an_umol_m2_s": an[night].round(3).tolist(),
        "night_mean_umol_m2_s": n_night,
        "night_tair_c": ds["tair_c"].values[night].round(2).tolist(),
        "noon_steps_local": [t.strftime("%H:%M") for t in local[noon]],
        "noon_canopy_an_umol_m2_s": an[noon].round(3).tolist(),
        "noon_mean_umol_m2_s": n_noon,
        "noon_fraction_rubisco_limited_blades": float((lim == ps.RUBISCO_LIMITED).mean()),
        "day_max_umol_m2_s": float(an.max()),
        "all_converged": bool(ds["converged"].values[:, blades].all()),
        "night_in_range": bool(NIGHT_RANGE[0] <= n_night <= NIGHT_RANGE[1]),
        "noon_in_range": bool(NOON_RANGE[0] <= n_noon <= NOON_RANGE[1]),
        "seconds": time.perf_counter() - t0,
    }


def main(full: bool = False, out_path: Path | None = None) -> dict:
    configs = {
        "quick": (ReplicationConfig.quick(), None),
        "quick, paper leaf": (ReplicationConfig.quick(), "paper"),
    }
    if full:
        configs["default"] = (ReplicationConfig(), None)
    out = {
        "ranges": {"night": NIGHT_RANGE, "noon": NOON_RANGE, "leaf_saturated": LEAF_SATURATED_RANGE},
        "leaf": {name: light_response(name) for name in SETS},
        "canopy": {k: {name: canopy(cfg, name, optics) for name in SETS} for k, (cfg, optics) in configs.items()},
    }
    print("| set | leaf Rd (25 °C) | leaf light-saturated An (25 °C, 400 ppm) |")
    print("|---|---:|---:|")
    for name, r in out["leaf"].items():
        print(f"| {name} | {-r['dark_an_umol_m2_s']:.2f} | {r['saturated_an_umol_m2_s']:.1f} |")
    print()
    print("| configuration | set | night canopy An | noon canopy An (12–14 h) | Rubisco-limited blades at noon |")
    print("|---|---|---:|---:|---:|")
    for k, by_set in out["canopy"].items():
        for name, r in by_set.items():
            print(
                f"| {k} | {name} | {r['night_mean_umol_m2_s']:.2f} | {r['noon_mean_umol_m2_s']:.1f} "
                f"| {100 * r['noon_fraction_rubisco_limited_blades']:.0f} % |"
            )
    path = ROOT / "experiments" / "results" / "photosynthesis_default_check.json" if out_path is None else out_path
    path.parent.mkdir(parents=True, exist_ok=True)
    write_result(path, out)
    print(f"\nwrote {path}")
    return out


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--full", action="store_true", help="also the main job's default configuration (slower)")
    ap.add_argument(
        "--out",
        dest="out_path",
        type=Path,
        default=None,
        help="JSON to write (default experiments/results/photosynthesis_default_check.json)",
    )
    main(**vars(ap.parse_args()))
