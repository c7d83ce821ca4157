"""Which emcee moves mix lightfit's posteriors, and is the ESS the stop rule reports honest?

    python experiments/mcmc_moves.py [--seeds 24] [--targets flat,ridge,banana,gaussian]
        [--out experiments/results/mcmc_moves.json]

Four analytic stand-ins for lightfit's posteriors over (specular, roughness, subsurface,
light_factor) with the informed priors' boxes (``PRIORS_INFORMED``) and the light factor's
lognormal prior times the chamber reading's Gaussian likelihood (1549.31 ± 77.5 against a model
of 1546.15): the leaf parameters

- ``flat``: uninformed, as in the default configuration's posterior (the record is above-canopy
  PAR, which no leaf parameter changes; ``benchmarks/bench_posterior.py``);
- ``ridge``: a narrow straight ridge, specular and subsurface trading off (what a PAR-at-the-plants
  series gives: only the leaf's absorptance is identified);
- ``banana``: a narrow curved ridge between the same two;
- ``gaussian``: all three identified, correlated (ρ = 0.9 between specular and subsurface).

Each target's posterior means are computed by quadrature (they are separable: a 2-D grid over
specular × subsurface, roughness and the light factor apart). Each move set (emcee's stretch move, its
default and lightfit's before; differential evolution alone; differential evolution 0.8 and the
stretch move 0.2, lightfit's default since) runs
``lightfit.inference.mcmc.sample`` with the posterior's stop rule (``StopRule(target_ess=50)``, 32
walkers) from ``--seeds`` seeds (walkers from the prior, as ``LogPosterior.initial`` draws them);
reported: the steps to the stop, the reported ESS, the acceptance, and whether the reported
standard error of each posterior mean, SD/√ESS, is honest: the RMS of the seeds' means about the
quadrature's, divided by the RMS reported SE (1 if honest; > 1: the ESS is overstated by that
ratio squared; with 24 seeds the ratio itself is uncertain by ≈ ±15 %).

Last, a long run (20 000 steps) of each move on a 4-D Gaussian: the sample variances ÷ the truth,
which shows why emcee's snooker move (``DESnookerMove``) is not offered.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

from lightfit.precision import use_float64

use_float64()  # lightfit's precision policy (lightfit.precision), before any JAX array exists

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import emcee  # noqa: E402
import numpy as np  # noqa: E402
from provenance import write_result  # noqa: E402  (commit, cores, load and command with every JSON)

from lightfit.inference.mcmc import PRIORS_INFORMED, StopRule, sample  # noqa: E402
from lightfit.inference.mcmc.sampler import describe_moves  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
NAMES = ("specular", "roughness", "subsurface", "light_factor")
BOX = np.array([PRIORS_INFORMED[n].support for n in NAMES[:3]])  # (3, 2)
READING, MODEL, READING_SD = 1549.31, 1546.15, 77.5  # µmol m⁻² s⁻¹: the chamber record at 12:13:48


def _leaf_log_lik(target: str, u1, u3):
    """Log-likelihood of the leaf parameters, u = position in the prior box ∈ [0, 1]."""
    if target == "flat":
        return np.zeros(np.broadcast(u1, u3).shape)
    if target == "ridge":
        return -0.5 * ((0.6 * u1 + u3 - 0.8) / 0.03) ** 2
    if target == "banana":
        return -0.5 * ((u3 - 2.0 * (u1 - 0.5) ** 2 - 0.3) / 0.03) ** 2
    if target == "gaussian":
        z1, z3 = (u1 - 0.5) / 0.1, (u3 - 0.55) / 0.1
        return -0.5 * (z1**2 - 1.8 * z1 * z3 + z3**2) / (1 - 0.81)
    raise ValueError(target)


def _light_log_post(f):
    """Lognormal prior (median 1, 0.5 in log) times the reading's Gaussian likelihood, up to a constant."""
    with np.errstate(divide="ignore", invalid="ignore"):
        lf = np.log(f)
        out = -(lf**2) / (2 * 0.5**2) - lf - 0.5 * ((f * MODEL - READING) / READING_SD) ** 2
    lo, hi = PRIORS_INFORMED["light_factor"].support
    return np.where((f > lo) & (f < hi), out, -np.inf)


class Target:
    """Vectorised log-posterior (n, 4) → (n,) of one stand-in, with draws from the prior."""

    def __init__(self, name: str):
        self.name = name

    def __call__(self, xs):
        xs = np.atleast_2d(xs)
        u = (xs[:, :3] - BOX[:, 0]) / (BOX[:, 1] - BOX[:, 0])
        inside = np.all((u >= 0) & (u <= 1), axis=1)
        lp = _leaf_log_lik(self.name, u[:, 0], u[:, 2]) + _light_log_post(xs[:, 3])
        return np.where(inside, lp, -np.inf)

    def initial(self, nwalkers: int, seed: int) -> np.ndarray:
        rng = np.random.default_rng(seed)
        return np.column_stack([PRIORS_INFORMED[n].sample(rng, nwalkers) for n in NAMES])

    def truth(self) -> tuple[np.ndarray, np.ndarray]:
        """Posterior means and SDs by quadrature (midpoint rule)."""
        n = 1200
        u = (np.arange(n) + 0.5) / n
        w = np.exp(_leaf_log_lik(self.name, u[:, None], u[None, :]))
        w /= w.sum()
        m1, m3 = (w.sum(1) * u).sum(), (w.sum(0) * u).sum()
        s1 = np.sqrt((w.sum(1) * (u - m1) ** 2).sum())
        s3 = np.sqrt((w.sum(0) * (u - m3) ** 2).sum())
        f = np.linspace(0.5, 1.5, 200001)
        p = np.exp(_light_log_post(f) - np.max(_light_log_post(f)))
        mf = (p * f).sum() / p.sum()
        sf = np.sqrt((p * (f - mf) ** 2).sum() / p.sum())
        span = BOX[:, 1] - BOX[:, 0]
        mean = np.array([BOX[0, 0] + span[0] * m1, BOX[1].mean(), BOX[2, 0] + span[2] * m3, mf])
        sd = np.array([span[0] * s1, span[1] / np.sqrt(12), span[2] * s3, sf])
        return mean, sd


MOVES = {
    "stretch": emcee.moves.StretchMove(),
    "differential evolution": emcee.moves.DEMove(),
    "DE 0.8 + stretch 0.2": [(emcee.moves.DEMove(), 0.8), (emcee.moves.StretchMove(), 0.2)],
}


def variance_check(steps: int = 20000, burn: int = 2000) -> dict:
    """Each move's sample variance on a 4-D Gaussian (SDs 1, 0.1, 3, 0.5) after a long run, ÷ the
    truth: any move that leaves its target invariant gives 1 up to Monte Carlo error (≈ ±0.03 here).
    emcee's DESnookerMove is in this check to show why it is not offered: its projection divides by
    √|x − z| instead of |x − z| (emcee 3.1.6, ``de_snooker.py``), so the move is not reversible."""
    sd = np.array([1.0, 0.1, 3.0, 0.5])
    out = {}
    moves = {**MOVES, "DE snooker (emcee 3.1.6)": emcee.moves.DESnookerMove()}
    for label, move in moves.items():
        s = emcee.EnsembleSampler(32, 4, lambda x: -0.5 * (((x - 1.0) / sd) ** 2).sum(-1), vectorize=True, moves=move)
        s.random_state = np.random.RandomState(2).get_state()
        s.run_mcmc(1.0 + sd * np.random.default_rng(1).normal(size=(32, 4)), steps, progress=False)
        x = s.get_chain(discard=burn).reshape(-1, 4)
        out[label] = (x.var(0) / sd**2).tolist()
    return out


def run(target: Target, moves, seeds: int, folder: Path) -> dict:
    steps, ess, means, ses, secs, acc = [], [], [], [], [], []
    for seed in range(seeds):
        t = time.perf_counter()
        res = sample(
            target,
            NAMES,
            folder / f"{target.name}_{seed}.h5",
            nwalkers=32,
            max_steps=20000,
            seed=seed,
            resume=False,
            stop=StopRule(target_ess=50),
            progress=False,
            moves=moves,
        )
        secs.append(time.perf_counter() - t)
        d = res.diagnostics
        kept = res.chain[d["burn"] :].reshape(-1, len(NAMES))
        steps.append(d["n_steps"])
        acc.append(d["acceptance_mean"])
        ess.append(d["ess"])
        means.append(kept.mean(0))
        ses.append(kept.std(0) / np.sqrt(d["ess"]))
    mean, sd = target.truth()
    means, ses = np.array(means), np.array(ses)
    return {
        "steps_to_stop_median": float(np.median(steps)),
        "steps_to_stop_range": [int(min(steps)), int(max(steps))],
        "reported_ess_median": np.median(ess, 0).tolist(),
        "rms_error_of_mean_over_reported_se": (
            np.sqrt(((means - mean) ** 2).mean(0)) / np.sqrt((ses**2).mean(0))
        ).tolist(),
        "rms_error_of_mean_over_posterior_sd": (np.sqrt(((means - mean) ** 2).mean(0)) / sd).tolist(),
        "seconds_per_run_median": float(np.median(secs)),
        "acceptance_median": float(np.median(acc)),
        "true_mean": mean.tolist(),
        "true_sd": sd.tolist(),
    }


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=24)
    ap.add_argument("--targets", default="flat,ridge,banana,gaussian")
    ap.add_argument("--out", type=Path, default=ROOT / "experiments" / "results" / "mcmc_moves.json")
    args = ap.parse_args(argv)
    out = {"command": "python experiments/mcmc_moves.py", "seeds": args.seeds, "walkers": 32, "results": {}}
    with tempfile.TemporaryDirectory() as tmp:
        for name in args.targets.split(","):
            for label, moves in MOVES.items():
                r = run(Target(name), moves, args.seeds, Path(tmp))
                r["moves"] = describe_moves(moves)
                out["results"][f"{name} | {label}"] = r
                err = " ".join(f"{v:.2f}" for v in r["rms_error_of_mean_over_reported_se"])
                print(
                    f"{name:9s} {label:22s} steps {r['steps_to_stop_median']:6.0f}  "
                    f"ESS {min(r['reported_ess_median']):5.0f}–{max(r['reported_ess_median']):5.0f}  "
                    f"acc {r['acceptance_median']:.2f}  "
                    f"error / reported SE {err}",
                    flush=True,
                )
    out["variance_over_truth_4d_gaussian"] = variance_check()
    for label, v in out["variance_over_truth_4d_gaussian"].items():
        print(f"4-D Gaussian, {label:26s} sample variance / truth {' '.join(f'{x:.3f}' for x in v)}")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    write_result(args.out, out)


if __name__ == "__main__":
    main()
