"""Twins rendered at other seeds than the model's: does the posterior recover their truth? (issue 15 item 3)

    .venv/bin/python experiments/twin_seeds.py [--out results/twin_seeds] [--n-design 32] [--walkers 32]
        [--max-steps 2000]

Quick field (4 plants, K = 16, 2 bounces), model render seed 0, emulator over the informed prior box
(one design for all points). At three leaf-parameter points that no test uses, twin observations
(PAR at the plants, SD 3 % ≥ 1 µmol m⁻² s⁻¹; canopy An, SD 1 µmol m⁻² s⁻¹; daytime steps) are rendered
at another seed (301, 302, 303) plus noise, and the posterior over specular, roughness, subsurface and
light factor is sampled twice: with independent steps (the likelihood before issue 15) and with the
model's Monte Carlo covariance (``mc_correlation="model"``, ``mc_scale=2``: the twin's observations
carry a second copy of the render error).

Criterion, per point and likelihood: every parameter's truth lies in its 90 % central posterior
interval; or else the miss δ = posterior mean − truth (log-parameters, the Fisher report's scale) lies
along the sloppy directions: along every stiff eigenvector v_i of the Fisher information (eigenvalue
λ_i ≥ 1, i.e. 1σ width ≤ 1 in log units) |v_iᵀδ|·√λ_i ≤ 1.645. Also reported: δᵀFδ against the χ²_p
90 % quantile. Writes OUT/twin_seeds.json and prints a table.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from lightfit.precision import use_float64

use_float64()  # lightfit's precision policy, before any JAX array exists

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import h5py  # noqa: E402
import numpy as np  # noqa: E402
from provenance import write_result  # noqa: E402  (commit, cores, load and command with every JSON)
from scipy.stats import chi2  # noqa: E402

from lightfit.inference import mcmc as P  # noqa: E402
from lightfit.inference import posterior as A  # noqa: E402
from lightfit.inference.twin import twin_observations  # noqa: E402
from lightfit.model import emulator as E  # noqa: E402
from lightfit.model.parameters import Theta  # noqa: E402
from lightfit.replication import ReplicationConfig, forcing, model_for  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]

NAMES = ("specular", "roughness", "subsurface", "light_factor")
#: Leaf-parameter points no test uses (inside the informed priors), and their twin render seeds.
POINTS = (
    (Theta(specular=0.50, roughness=0.45, subsurface=0.50, light_factor=1.05), 301),
    (Theta(specular=0.68, roughness=0.80, subsurface=0.85, light_factor=0.95), 302),
    (Theta(specular=0.58, roughness=0.62, subsurface=0.40, light_factor=1.00), 303),
)


def verdict(path: Path, truth: Theta) -> dict:
    """Coverage of the truth and the sloppy-direction criterion of a finished run."""
    run = P.load_run(path)
    samples = P.flat_samples(run)
    x_true = np.array([getattr(truth, n) for n in NAMES])
    lo, hi = np.percentile(samples, [5, 95], axis=0)
    inside = (lo <= x_true) & (x_true <= hi)
    with h5py.File(path, "r") as f:
        F = f["analysis/fisher/matrix"][:]
        lam = f["analysis/fisher/eigenvalues"][:]
        vec = f["analysis/fisher/eigenvectors"][:]
        scale = json.loads(f["analysis/fisher"].attrs["scale"])
    mean = samples.mean(0)
    delta = np.log(mean) - np.log(x_true) if scale == "log" else mean - x_true
    stiff = lam >= 1.0
    along = np.abs(vec.T @ delta) * np.sqrt(np.maximum(lam, 0.0))
    return {
        "mean": dict(zip(NAMES, mean.tolist())),
        "interval_90": {n: [float(a), float(b)] for n, a, b in zip(NAMES, lo, hi)},
        "inside": dict(zip(NAMES, inside.tolist())),
        "all_inside": bool(inside.all()),
        "delta_F_delta": float(delta @ F @ delta),
        "chi2_90": float(chi2.ppf(0.9, len(NAMES))),
        "stiff_z": along[stiff].tolist(),
        "miss_along_sloppy": bool(np.all(along[stiff] <= 1.645)),
        "passes": bool(inside.all() or np.all(along[stiff] <= 1.645)),
    }


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=ROOT / "results" / "twin_seeds")
    ap.add_argument("--n-design", type=int, default=32)
    ap.add_argument("--walkers", type=int, default=32)
    ap.add_argument("--max-steps", type=int, default=2000)
    a = ap.parse_args(argv)
    a.out.mkdir(parents=True, exist_ok=True)
    model = model_for(ReplicationConfig.quick(), forcing())
    box = [P.PRIORS_INFORMED[n].support for n in ("specular", "roughness", "subsurface")]
    lo, hi = np.array(box).T
    emu = E.cached_emulator(model, a.out / "emulator.npz", lo, hi, n_design=a.n_design, seed=0, progress=True)
    res: dict = {"config": "ReplicationConfig.quick()", "model_seed": model.scenario.seed, "points": []}
    for truth, seed in POINTS:
        obs = twin_observations(model, truth, render_seed=seed, noise_seed=seed)
        row = {"truth": truth.to_dict(), "render_seed": seed}
        for label, kw in (("independent", {"mc_correlation": None}), ("mc_covariance", {"mc_scale": 2.0})):
            path = a.out / f"twin_{seed}_{label}.h5"
            t = time.perf_counter()
            r = A.run(
                model,
                obs,
                emu,
                path,
                names=NAMES,
                fixed={"vcmax_scale": truth.vcmax_scale},
                use=("plant_par", "canopy_an"),
                nwalkers=a.walkers,
                max_steps=a.max_steps,
                seed=0,
                progress=False,
                **kw,
            )
            row[label] = {**verdict(path, truth), "seconds": time.perf_counter() - t, "sloppy": r["sloppy"]}
        res["points"].append(row)
        write_result(a.out / "twin_seeds.json", res)
    print(f"{'seed':>5} {'likelihood':>14} " + " ".join(f"{n[:10]:>18}" for n in NAMES) + "  δᵀFδ  stiff z  pass")
    for row in res["points"]:
        for label in ("independent", "mc_covariance"):
            v = row[label]
            cells = " ".join(
                f"{row['truth'][n]:.3f}{'∈' if v['inside'][n] else '∉'}[{lo_:.2f},{hi_:.2f}]"
                for n in NAMES
                for lo_, hi_ in [v["interval_90"][n]]
            )
            z = max(v["stiff_z"]) if v["stiff_z"] else 0.0
            print(f"{row['render_seed']:>5} {label:>14} {cells} {v['delta_F_delta']:6.1f} {z:6.2f}  {v['passes']}")
    return res


if __name__ == "__main__":
    main()
