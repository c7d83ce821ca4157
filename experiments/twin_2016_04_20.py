"""Twin experiment on the 20 April 2016 configuration: where recovery fails, and why.

    python experiments/twin_2016_04_20.py [--quick] [--out results/twin] [--write-data]

1. Synthetic observations (PAR at the plants and canopy net CO2 uptake at every daytime step)
   from the model at known leaf parameters, rendered with another random seed, plus noise;
   written to OUT/twin_observations.csv (labelled synthetic). The bundled
   data/observations/twin_2016-04-20_synthetic.csv was made by this script with ``--write-data``
   on 2026-12-05 (today's defaults, a 9-plant cell: its header); it is replaced only with
   ``--write-data``, so that a later change of the defaults does not move it unsaid.
2. Calibrate specular alone (the others at their true values) from a different start: on the bundled
   series it ends on its bound (1.0) with a loss below the truth's (18.63 against 20.95): plant PAR
   moves 1.2 % from specular 0.7 to 1.0 against 3 % noise per step, so one day does not identify it
   (docs/calibration.md).
3. Calibrate specular, roughness and subsurface together: the fit is as good, the parameters are
   not recovered — the non-identifiability the reference paper warned about (see issue 7 for the
   posterior). Prints and writes a JSON summary, OUT/twin.json (the calibrations' steps in
   OUT/history_*.jsonl).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

import jax.numpy as jnp

import lightfit  # noqa: F401
from lightfit import replication as rep
from lightfit.inference.calibration import calibrate, make_loss
from lightfit.inference.observations import read_observations, write_observations
from lightfit.inference.twin import twin_observations
from lightfit.precision import use_float64

use_float64()  # lightfit's precision policy (lightfit.precision), before any JAX array exists

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from provenance import record, write_result  # noqa: E402  (commit, cores, load and command with every JSON)

ROOT = Path(__file__).resolve().parents[1]
TRUTH = {"specular": 0.7, "roughness": 0.4, "subsurface": 0.6}
DATA = ROOT / "data" / "observations" / "twin_2016-04-20_synthetic.csv"


def main(quick: bool = False, out: Path = ROOT / "results" / "twin", write_data: bool = False) -> dict:
    if write_data and quick:  # before the model is built and the twin rendered
        raise SystemExit("--write-data replaces the bundled twin series: not with --quick")
    out.mkdir(parents=True, exist_ok=True)
    cfg = (
        rep.ReplicationConfig.quick() if quick else dataclasses.replace(rep.ReplicationConfig(), n_plants=9, samples=32)
    )
    model = rep.model_for(cfg, rep.forcing())
    obs = twin_observations(model, TRUTH, render_seed=101, noise_seed=7)
    path = DATA if write_data else out / "twin_observations.csv"
    write_observations(obs, path, data_metadata(cfg))
    obs = read_observations(path)
    names_all = ("specular", "roughness", "subsurface")
    loss_all = make_loss(model, obs, names_all, at=TRUTH)  # the SDs held there: truth's own
    at_truth = float(loss_all.natural(jnp.asarray([TRUTH[n] for n in names_all])))
    one = calibrate(
        model,
        obs,
        names=("specular",),
        start={"specular": 0.3},
        fixed={k: v for k, v in TRUTH.items() if k != "specular"},
        history=out / "history_specular.jsonl",
        resume=False,
    )
    three = calibrate(
        model,
        obs,
        names=names_all,
        start={"specular": 0.3, "roughness": 0.7, "subsurface": 0.2},
        history=out / "history_three.jsonl",
        resume=False,
    )
    res = {
        "truth": TRUTH,
        "loss_at_truth": at_truth,
        "n_observations": loss_all.n_observations,
        "specular_only": _summary(one),
        "all_three": _summary(three),
        "config": dataclasses.asdict(cfg),
    }
    write_result(out / "twin.json", res)
    print(json.dumps(res, indent=2))
    return res


def data_metadata(cfg) -> dict:
    """The twin series' ``#`` header: what it is, its truth, configuration and seeds, and the command
    and lightfit commit that made it (``provenance.record``, as every result JSON has them)."""
    rec = record()
    return {
        "provenance": "synthetic",
        "title": "SYNTHETIC twin observations, 2016-04-20 configuration (not measured)",
        "generator": "experiments/twin_2016_04_20.py",
        "command": rec["command"],
        "lightfit_commit": str(rec["lightfit_commit"]),
        "uncommitted_changes": json.dumps({d: rec[f"{d}_uncommitted_changes"] for d in ("lightfit", "experiments")}),
        "truth": json.dumps(TRUTH),
        "config": json.dumps(dataclasses.asdict(cfg)),
        "render_seed": "101",
        "noise_seed": "7",
    }


def _summary(r) -> dict:
    keys = ("theta", "loss", "steps", "evaluations", "gradients", "stopped_by", "seconds")
    return {k: getattr(r, k) for k in keys}


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--out", type=Path, default=ROOT / "results" / "twin")
    ap.add_argument(
        "--write-data", action="store_true", help=f"replace the bundled {DATA.relative_to(ROOT)} (not with --quick)"
    )
    a = ap.parse_args()
    main(a.quick, a.out, a.write_data)
