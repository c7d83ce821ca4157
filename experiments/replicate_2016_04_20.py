"""The 20 April 2016 Selhausen replication (the README's first command runs this via the CLI).

    python experiments/replicate_2016_04_20.py [--quick] [--preset default|paper] [--boundary periodic|finite]
        [--out results/2016-04-20] [--weather TERENO.csv]
    python experiments/replicate_2016_04_20.py --quick --write-reference tests/reference/replication_quick.json
    python experiments/replicate_2016_04_20.py --quick --preset paper \
        --write-reference tests/reference/replication_quick_finite.json

``--preset``: ``default`` (lightfit's credible default) or ``paper`` (the reference paper's setup:
finite field with 2 buffer rows, grey 0.5 leaf, giraud2023; ``ReplicationConfig.with_preset``).
``--boundary``: overrides the preset's field, ``periodic`` (one cell of an infinite field) or
``finite`` (2 buffer rows on bare soil).

``--write-reference`` deliberately regenerates a stored regression curve (absorbed PAR and canopy
net CO2 uptake per time step, with their Monte Carlo SDs) that tests/test_replication.py compares
against: replication_quick.json for the periodic default, replication_quick_finite.json for the
``paper`` preset. The file records how and with which versions it was made.
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib.metadata as md
import json
import sys
from pathlib import Path

import lightfit
from lightfit import replication as rep
from lightfit.precision import use_float64

use_float64()  # lightfit's precision policy (lightfit.precision), before any JAX array exists

ROOT = Path(__file__).resolve().parents[1]


def reference_curve(ds) -> dict:
    return {
        "time_utc": [str(t) for t in ds["time"].values],
        "plant_par_umol_m2_s": ds["plant_par_umol_m2_s"].values.tolist(),
        "plant_par_mc_sd_umol_m2_s": ds["plant_par_mc_sd_umol_m2_s"].values.tolist(),
        "canopy_an_umol_m2_s": ds["canopy_an_umol_m2_s"].values.tolist(),
        "canopy_an_mc_sd_umol_m2_s": ds["canopy_an_mc_sd_umol_m2_s"].values.tolist(),
    }


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--out", type=Path, default=ROOT / "results" / "2016-04-20")
    ap.add_argument("--weather", type=Path, default=None)
    ap.add_argument("--preset", choices=rep.PRESETS, default="default")
    ap.add_argument("--boundary", choices=("periodic", "finite"), default=None)
    ap.add_argument("--write-reference", type=Path, default=None)
    a = ap.parse_args(argv)
    cfg = (rep.ReplicationConfig.quick() if a.quick else rep.ReplicationConfig()).with_preset(a.preset)
    if a.boundary == "finite" and cfg.boundary != "finite":
        cfg = cfg.finite()  # the reference paper's 2 buffer rows
    elif a.boundary == "periodic":
        cfg = dataclasses.replace(cfg, boundary="periodic", buffer_rows=None, buffer_along=None)
    ds, _ = rep.run(cfg, weather_file=a.weather, out=a.out, progress=True)
    print(rep.summary(ds).round(3).to_string())
    if a.write_reference:
        ref = {
            "made_by": "python experiments/replicate_2016_04_20.py "
            + " ".join(
                [
                    *(["--quick"] if a.quick else []),
                    "--preset",
                    a.preset,
                    *(["--boundary", a.boundary] if a.boundary else []),
                ]
            )
            + " --write-reference "
            + str(a.write_reference),
            "config": dataclasses.asdict(cfg),
            "theta": {k.removeprefix("theta_"): v for k, v in ds.attrs.items() if k.startswith("theta_")},
            "weather": ds.attrs["weather_source"],
            "weather_provenance": ds.attrs["weather_provenance"],
            "versions": {p: md.version(p) for p in ("mitsuba", "drjit", "jax", "cplantbox", "numpy")}
            | {"lightfit": lightfit.__version__},
            "python": sys.version.split()[0],
            "curve": reference_curve(ds),
        }
        a.write_reference.parent.mkdir(parents=True, exist_ok=True)
        a.write_reference.write_text(json.dumps(ref, indent=1))
        print(f"wrote {a.write_reference}")


if __name__ == "__main__":
    main()
