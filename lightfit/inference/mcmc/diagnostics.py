r"""Convergence diagnostics of an ensemble chain, the stop rule, and posterior summaries.

Stop rule (checked every ``check_every`` steps, on the chain after discarding the first
``burn_fraction``): integrated autocorrelation time τ_j per parameter (emcee's estimator),
effective sample size ESS_j = n_walkers · n_kept / τ_j, and the run stops when for every parameter
n_kept ≥ ``tau_multiple`` · τ_j (τ reliable), τ changed by < ``tau_rtol`` since the last check,
ESS_j ≥ ``target_ess`` and the walkers agree, split-R̂_j < ``rhat_max``. Acceptance fractions
outside [0.1, 0.8] are flagged.

τ is estimated per walker about the walker's own mean, so it cannot see walkers that sit in
separate modes: the stretch move rarely carries a walker from one well-separated mode to another,
and the modes then keep the shares of walkers they started with (the default moves' differential
evolution does carry them, :func:`~lightfit.inference.mcmc.sampler.default_moves`). Split-R̂ (Gelman et al. 2013,
BDA3 §11.4: each walker's kept half-chains as chains, √(var⁺/W)) compares the walkers with each
other and is ≫ 1 then (≈ 14 for a two-mode target with walkers stuck apart, 1.07–1.10 for a
unimodal one when the other criteria are met). It cannot see a mode that no walker found.
"""

from __future__ import annotations

from dataclasses import dataclass

import emcee
import numpy as np

from lightfit.errors import InputError, check_integer, check_real

#: Acceptance fractions outside which the walkers move badly (flagged): 0.15–0.8 for the stretch
#: move (Foreman-Mackey et al. 2013); the default moves (differential evolution 0.8, stretch 0.2)
#: accept 0.13 on a narrow curved ridge while needing 5× fewer steps there than the stretch move
#: (experiments/mcmc_moves.py), so the lower bound is 0.1.
ACCEPTANCE_OK = (0.1, 0.8)


#: Share of a chain's first steps discarded as burn-in, unless a rule says otherwise.
BURN_FRACTION = 0.25


def burn_in(n_steps: int, burn_fraction: float) -> int:
    """Steps discarded from the start of a chain of ``n_steps``: the one rule for the diagnostics,
    the stop rule and the samples an analysis uses."""
    return int(burn_fraction * n_steps)


def split_rhat(kept: np.ndarray) -> np.ndarray:
    """Split-R̂ per parameter of an ensemble's kept chain (n_kept, n_walkers, ndim): each walker's
    two halves as chains, √(((n − 1)/n · W + B/n) / W) with W the mean within-chain variance and B
    n times the variance of the chain means (Gelman et al. 2013, BDA3 §11.4); NaN below 4 steps."""
    n = len(kept) // 2
    if n < 2:
        return np.full(kept.shape[-1], np.nan)
    halves = np.concatenate([kept[:n], kept[n : 2 * n]], axis=1)
    within = halves.var(axis=0, ddof=1).mean(axis=0)
    between = n * halves.mean(axis=0).var(axis=0, ddof=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.sqrt(((n - 1) / n * within + between / n) / within)


#: Kept steps from which a walker that never moved counts as stuck: a healthy walker at an
#: acceptance of 0.1 stands still over 50 steps with probability 0.9⁵⁰ ≈ 0.005, over 10 with 0.35
#: (a short chain's walkers would be called stuck, and told that a longer chain does not help).
STUCK_MIN_KEPT_STEPS = 50


def diagnostics(
    chain: np.ndarray,
    accepted: np.ndarray | None = None,
    *,
    burn_fraction: float = BURN_FRACTION,
    names=None,
    c: float = 5.0,
    tau_multiple: float = 50.0,
) -> dict:
    """Convergence diagnostics of an ensemble chain of shape (n_steps, n_walkers, ndim).

    Returns a dict: ``n_steps``, ``n_kept`` (after discarding ``burn_fraction``), ``tau`` (integrated
    autocorrelation time per parameter, in steps; emcee's estimator with window constant ``c``),
    ``ess`` (n_walkers · n_kept / τ), ``rhat`` (:func:`split_rhat`), ``acceptance`` (per walker, if
    ``accepted`` is given) with its mean and ``acceptance_steps``, the steps it is over: ``"kept"``
    (after the burn-in, as τ and ESS) where ``accepted`` holds each step's flags (n_steps, n_walkers),
    ``"all"`` where it holds only each walker's count over the run (n_walkers,); ``tau_reliable``
    (n_kept ≥ ``tau_multiple`` τ: 50 is emcee's rule of thumb; a run's stop rule passes its own,
    ``tau_multiple`` records which), ``stuck`` (indices of the walkers that never moved over the kept
    steps, judged from :data:`STUCK_MIN_KEPT_STEPS` kept steps on: each repeats one point n_kept
    times in the samples, and emcee's τ, hence the ESS, is NaN for every parameter while one does)
    and ``names``.
    """
    chain = np.asarray(chain)
    if chain.ndim != 3:
        raise InputError(f"chain shape {chain.shape}", parameter="chain", expected="(n_steps, n_walkers, ndim)")
    n, w, d = chain.shape
    burn = burn_in(n, burn_fraction)
    kept = chain[burn:]
    if len(kept) < 2:
        tau = np.full(d, np.nan)
    else:
        with np.errstate(invalid="ignore", divide="ignore"):
            tau = emcee.autocorr.integrated_time(kept, c=c, tol=0, quiet=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        ess = w * len(kept) / tau
    out = {
        "names": list(names) if names is not None else [f"x{i}" for i in range(d)],
        "n_steps": n,
        "n_walkers": w,
        "n_kept": len(kept),
        "burn": burn,
        "tau": tau,
        "ess": ess,
        "rhat": split_rhat(kept),
        "stuck": np.flatnonzero(np.all(kept == kept[:1], axis=(0, 2))).tolist()
        if len(kept) >= STUCK_MIN_KEPT_STEPS
        else [],
        "tau_multiple": float(tau_multiple),
        "tau_reliable": bool(np.all(len(kept) >= tau_multiple * tau)),
    }
    if accepted is not None:
        # No step yet (a run read before its first step): no acceptance to judge, not a rate of 0.
        accepted = np.asarray(accepted, float)
        if accepted.ndim == 2:  # each step's flags: over the kept steps, as τ and ESS (the burn-in counted before)
            acc = accepted[burn:n].mean(0) if n else np.full(w, np.nan)
            out["acceptance_steps"] = "kept"
        else:
            acc = accepted / n if n else np.full(w, np.nan)
            out["acceptance_steps"] = "all"
        out["acceptance"] = acc
        out["acceptance_mean"] = float(acc.mean())
        out["acceptance_ok"] = not n or bool(ACCEPTANCE_OK[0] <= acc.mean() <= ACCEPTANCE_OK[1])
    return out


@dataclass
class StopRule:
    """When to stop: every parameter has n_kept ≥ tau_multiple·τ, |Δτ/τ| < tau_rtol, ESS ≥ target_ess
    and split-R̂ < rhat_max (module docstring). Once n_kept ≥ tau_multiple·τ, ESS ≥ tau_multiple ·
    n_walkers (640 with the defaults and 32 walkers), so ``target_ess`` binds only above that."""

    target_ess: float = 50.0
    tau_multiple: float = 20.0
    tau_rtol: float = 0.05
    check_every: int = 50
    burn_fraction: float = BURN_FRACTION
    min_steps: int = 100
    rhat_max: float = 1.2

    def __post_init__(self):
        if not self.target_ess > 0:  # 0 or less: the first check would stop any chain
            raise InputError(
                f"target_ess={self.target_ess!r}", parameter="target_ess", expected="> 0 effective samples"
            )
        # burn_fraction 1 kept no step (every τ, ESS and summary NaN); check_every 0 divided by zero
        check_real(self.burn_fraction, "burn_fraction", 0.0, 1.0, open_hi=True, expected="a fraction in [0, 1)")
        check_integer(self.check_every, "check_every", 1, expected="an integer ≥ 1 (steps between checks)")
        check_integer(self.min_steps, "min_steps", 0)
        check_real(self.tau_multiple, "tau_multiple", 0.0, open_lo=True, expected="> 0 (kept steps per τ)")
        check_real(self.tau_rtol, "tau_rtol", 0.0, open_lo=True, expected="> 0 (relative change of τ)")
        check_real(self.rhat_max, "rhat_max", 1.0, open_lo=True, expected="> 1 (split-R̂ is ≥ 1 up to noise)")

    def check(self, d: dict, tau_prev) -> bool:
        """Whether diagnostics ``d`` (and τ at the previous check, None at the first) meet the rule."""
        tau = d["tau"]
        if d["n_steps"] < self.min_steps or not np.all(np.isfinite(tau)) or tau_prev is None:
            return False
        stable = np.all(np.abs(tau - tau_prev) / tau < self.tau_rtol)
        agree = np.all(np.asarray(d["rhat"]) < self.rhat_max)
        return bool(
            stable and agree and np.all(d["n_kept"] >= self.tau_multiple * tau) and np.all(d["ess"] >= self.target_ess)
        )

    def diagnostics(self, chain: np.ndarray, accepted: np.ndarray | None = None, names=None) -> dict:
        """:func:`diagnostics` with this rule's burn-in and τ multiple (and its ``rhat_max``)."""
        d = diagnostics(chain, accepted, burn_fraction=self.burn_fraction, names=names, tau_multiple=self.tau_multiple)
        return d | {"rhat_max": self.rhat_max}


def flat_samples(run, burn_fraction: float | None = None) -> np.ndarray:
    """Post-burn-in samples of a run (from ``load_run`` or a ``SamplerResult``), shape (n, ndim).
    ``burn_fraction`` None: the burn-in of the rule the run was sampled under (``load_run``'s
    ``stop_rule``, which its stored diagnostics and analysis discarded), else :data:`BURN_FRACTION`."""
    if burn_fraction is None:
        rule = run.get("stop_rule") if isinstance(run, dict) else None
        burn_fraction = BURN_FRACTION if rule is None else rule.burn_fraction
    chain = run["chain"] if isinstance(run, dict) else run.chain
    return chain[burn_in(len(chain), burn_fraction) :].reshape(-1, chain.shape[-1])


def summarize(samples: np.ndarray, names) -> dict:
    """Mean, SD, 5/50/95 % quantiles per parameter and the correlation matrix."""
    q = np.percentile(samples, [5, 50, 95], axis=0)
    return {
        "names": list(names),
        "mean": samples.mean(0),
        "sd": samples.std(0, ddof=1),
        "q05": q[0],
        "q50": q[1],
        "q95": q[2],
        "corr": np.corrcoef(samples.T) if samples.shape[1] > 1 else np.ones((1, 1)),
    }


__all__ = ["ACCEPTANCE_OK", "StopRule", "burn_in", "diagnostics", "flat_samples", "split_rhat", "summarize"]
