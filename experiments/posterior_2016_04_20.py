"""Posterior and identifiability study for the 20 April 2016 configuration (twin experiments).

    .venv/bin/python experiments/posterior_2016_04_20.py [--out results/posterior] [--n-design 64] [--n-test 8]
        [--walkers 32] [--max-steps 3000] [--tiny PATH]

1. Emulator of the renders over the wide prior box (specular, subsurface ∈ [0, 1], roughness ∈
   [0.3, 1]) from a Sobol design of full renders; its error measured on held-out full renders.
2. **Synthetic** observations (twin experiment): the coupled model at known parameters with a
   DIFFERENT render seed (7) than the calibrated model (0), plus Gaussian noise (seed 0): PAR at
   every daytime step, SD 5 % + 5 µmol m⁻² s⁻¹; net CO2 uptake at every step, SD 1 µmol m⁻² s⁻¹.
   Written to OUT/synthetic_observations.csv with provenance ``synthetic`` and a ``truth`` line.
3. Posteriors with PAR only, CO2 only and both (wide priors): posterior SD per parameter and the
   tightening ratios; Fisher spectrum and profile likelihood of each; emulator error relative to
   the posterior width.
4. Equal-fit parameter sets: the two most distant (in prior-scaled units) posterior samples whose
   log-likelihood is within 0.5 of the best, re-evaluated with FULL renders.
5. The real single-point record (bundled chamber observation) with informed priors.
Results: OUT/*.h5 (runs, each with the command and lightfit commit that made it), OUT/summary.json.
``--tiny`` writes the notebook fixture (the same record).
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import time
from pathlib import Path

from lightfit.precision import use_float64

use_float64()  # lightfit's precision policy (lightfit.precision), before any JAX array exists

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import numpy as np  # noqa: E402
from provenance import record, write_result  # noqa: E402  (commit, cores, load and command with every JSON)

from lightfit.inference import mcmc as P  # noqa: E402
from lightfit.inference import posterior as A  # noqa: E402
from lightfit.inference.multiday import with_lights  # noqa: E402
from lightfit.inference.observations import read_observations, write_observations  # noqa: E402
from lightfit.inference.twin import twin_observations  # noqa: E402
from lightfit.model import emulator as E  # noqa: E402
from lightfit.model.parameters import Theta  # noqa: E402
from lightfit.replication import OBSERVATIONS, ReplicationConfig, forcing, model_for  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]

TRUTH = Theta(specular=0.6, roughness=0.6, subsurface=0.1, light_factor=1.0, vcmax_scale=1.0)
NAMES = ("specular", "roughness", "subsurface", "light_factor", "vcmax_scale")
WIDE_BOX = ([0.0, 0.3, 0.0], [1.0, 1.0, 1.0])
#: The twin is rendered with another seed than the model: its Monte Carlo error is a second,
#: independent copy of the model's (docs/posterior.md, "mc_scale"); sampled and re-evaluated alike.
MC_SCALE = 2.0


def run_attrs(experiment: str) -> dict:
    """What each run's HDF5 (and the ``--tiny`` notebook fixture) stores beside the sampler's seed:
    the experiment, and the command and lightfit commit that made it (``provenance.record``)."""
    rec = record()
    keep = ("command", "lightfit_commit", "lightfit_uncommitted_changes", "experiments_uncommitted_changes")
    return {"experiment": experiment, **{k: rec[k] for k in keep}}


def observations_metadata() -> dict:
    """The ``# key: value`` lines of OUT/synthetic_observations.csv: provenance, a description and
    the twin's ``truth`` (JSON), which notebooks/posterior_analysis.ipynb draws on the corner plot."""
    return {
        "provenance": "synthetic",
        "description": "twin experiment: lightfit coupled model (quick field, render "
        f"seed 7) at {json.dumps(TRUTH.to_dict())} + Gaussian noise (seed 0)",
        "truth": json.dumps(TRUTH.to_dict()),
    }


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=ROOT / "results" / "posterior")
    ap.add_argument("--n-design", type=int, default=64)
    ap.add_argument("--n-test", type=int, default=8)
    ap.add_argument("--walkers", type=int, default=32)
    ap.add_argument("--max-steps", type=int, default=3000)
    ap.add_argument("--tiny", type=Path, default=None, help="also write a tiny run (notebook fixture) here")
    args = ap.parse_args(argv)
    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    cfg = ReplicationConfig.quick()  # CI-sized field; the default field costs ~80 s per render pass
    model = model_for(cfg, forcing())
    summary: dict = {"config": "ReplicationConfig.quick()", "truth": TRUTH.to_dict()}
    emu_path = out / "emulator_quick_wide.npz"
    val_path = out / "validation_quick_wide.npz"
    if emu_path.exists():
        emu = E.PartsEmulator.load(emu_path)
    else:
        emu = E.build_emulator(model, *WIDE_BOX, n_design=args.n_design, seed=0, progress=True)
        emu.save(emu_path)
    if val_path.exists():
        z = np.load(val_path)
        leaf_test, full = z["leaf_test"], (z["values"], z["se"])
    else:
        leaf_test = E.sobol_design(16, *WIDE_BOX, seed=1)[: args.n_test]
        full = E.render_parts(model, leaf_test, progress=True, label=E.HELD_OUT_LABEL)
        np.savez_compressed(val_path, leaf_test=leaf_test, values=full[0], se=full[1])
    summary["emulator"] = {
        "degree": emu.degree,
        "n_design": len(emu.design),
        "loo_rms": emu.loo_rms,
        "render_seconds": emu.render_seconds,
    }
    obs_path = out / "synthetic_observations.csv"
    syn = twin_observations(
        model, TRUTH, render_seed=7, noise_seed=0, par_sd=lambda par: 0.05 * par + 5.0, an_at_night=True
    )
    write_observations(syn, obs_path, observations_metadata())
    obs = read_observations(obs_path)
    wide = P.PRIORS_WIDE
    runs = {}
    for label, use in (("par", ("par",)), ("an", ("an",)), ("both", ("par", "an"))):
        t = time.perf_counter()
        r = A.run(
            model,
            obs,
            emu,
            out / f"twin_{label}.h5",
            names=NAMES,
            priors=wide,
            use=use,
            nwalkers=args.walkers,
            max_steps=args.max_steps,
            seed=0,
            mc_scale=MC_SCALE,
            validation_renders=(leaf_test, full),
            progress=True,
            attrs=run_attrs(f"twin, {label}"),
        )
        r["wall_seconds"] = time.perf_counter() - t
        runs[label] = r
        print(label, json.dumps({k: r[k] for k in ("stopped_by", "n_steps", "sd", "sloppy")}, default=str))
    summary["twin"] = runs
    summary["tightening"] = {
        n: {
            "sd_par": runs["par"]["sd"][n],
            "sd_an": runs["an"]["sd"][n],
            "sd_both": runs["both"]["sd"][n],
            "both_over_par": runs["both"]["sd"][n] / runs["par"]["sd"][n],
            "both_over_an": runs["both"]["sd"][n] / runs["an"]["sd"][n],
        }
        for n in NAMES
    }
    # equal-fit parameter sets from the 'both' posterior, checked with full renders
    run = P.load_run(out / "twin_both.h5")
    s = P.flat_samples(run)
    fast = E.FastObservables(model, emu)
    # the likelihood the 'both' run sampled (A.run's: the model's MC correlation, MC_SCALE)
    lp = A.log_posterior(
        model,
        obs,
        fast,
        names=NAMES,
        priors=wide,
        use=("par", "an"),
        mc_scale=MC_SCALE,
        light_model=with_lights(model, [emu]),
    )
    ll = lp.loglike_batch(s)
    good = s[ll >= ll.max() - 0.5]
    good = good[np.random.default_rng(0).permutation(len(good))[:2000]]
    lo = np.array([wide[n].support[0] for n in NAMES])
    hi = np.array([min(wide[n].support[1], 4.0) for n in NAMES])
    z = (good - lo) / (hi - lo)
    dist = np.linalg.norm(z[:, None] - z[None], axis=-1)
    i, j = np.unravel_index(np.argmax(dist), dist.shape)
    exact = A.log_posterior(
        model,
        obs,
        model.observe,
        names=NAMES,
        priors=wide,
        use=("par", "an"),
        mc_correlation=lp.likelihood.mc_correlation,
        mc_scale=MC_SCALE,
    )
    pairs = []
    for x in (good[i], good[j]):
        pairs.append(
            {
                "theta": dict(zip(NAMES, x.tolist())),
                "loglike_emulator": float(lp.loglike_batch(x[None])[0]),
                "loglike_full_render": float(exact.log_likelihood(x)),
                "chi2_full_render": float(np.sum(np.asarray(exact.residuals(x)) ** 2)),
                "n_observations": exact.n_observations,
            }
        )
    summary["equal_fit"] = {"sets": pairs, "prior_scaled_distance": float(dist[i, j])}
    # the real single-point record, informed priors, emulator over the wide box
    real = read_observations(OBSERVATIONS)
    r = A.run(
        model,
        real,
        emu,
        out / "record_informed.h5",
        names=("specular", "roughness", "subsurface", "light_factor"),
        priors=P.PRIORS_INFORMED,
        nwalkers=args.walkers,
        max_steps=args.max_steps,
        seed=0,
        validation_renders=(leaf_test, full),
        progress=True,
        attrs=run_attrs("real single PAR record"),
    )
    summary["record_informed"] = r
    write_result(out / "summary.json", P.jsonable(summary), default=str)
    if args.tiny:
        args.tiny.parent.mkdir(parents=True, exist_ok=True)
        tmp = out / "tiny.h5"
        A.run(
            model,
            obs,
            emu,
            tmp,
            names=NAMES,
            priors=wide,
            nwalkers=12,
            max_steps=150,
            seed=0,
            mc_scale=MC_SCALE,
            stop=None,
            resume=False,
            validation_renders=(leaf_test[:3], (full[0][:3], full[1][:3])),
            progress=False,
            n_predictive=32,
            n_profile=9,
            attrs=run_attrs("tiny twin run (notebook fixture)"),
        )
        shutil.copy(tmp, args.tiny)
        print("tiny run", args.tiny, args.tiny.stat().st_size, "bytes")
    print(json.dumps(P.jsonable({"tightening": summary["tightening"], "equal_fit": summary["equal_fit"]}), indent=1))


if __name__ == "__main__":
    main()
