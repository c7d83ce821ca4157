r"""Convergence diagnostics of an ensemble chain, the stop rule, and posterior summaries.

Stop rule (checked every ``check_every`` steps, on the chain after discarding the first
``burn_fraction``): integrated autocorrelation time τ_j per parameter (emcee's estimator),
effective sample size ESS_j = n_walkers · n_kept / τ_j, and the run stops when for every parameter
n_kept ≥ ``tau_multiple`` · τ_j (τ reliable), τ changed by < ``tau_rtol`` since the last check,
and ESS_j ≥ ``target_ess``. Acceptance fractions outside [0.15, 0.8] are flagged.
"""

from __future__ import annotations

from dataclasses import dataclass

import emcee
import numpy as np

from lightfit.errors import InputError


def diagnostics(
    chain: np.ndarray, accepted: np.ndarray | None = None, *, burn_fraction: float = 0.25, names=None, c: float = 5.0
) -> dict:
    """Convergence diagnostics of an ensemble chain of shape (n_steps, n_walkers, ndim).

    Returns a dict: ``n_steps``, ``n_kept`` (after discarding ``burn_fraction``), ``tau`` (integrated
    autocorrelation time per parameter, in steps; emcee's estimator with window constant ``c``),
    ``ess`` (n_walkers · n_kept / τ), ``acceptance`` (per walker, if given) with its mean,
    ``tau_reliable`` (n_kept ≥ 50 τ, emcee's recommendation) and ``names``.
    """
    chain = np.asarray(chain)
    if chain.ndim != 3:
        raise InputError(f"chain shape {chain.shape}", column="chain", expected="(n_steps, n_walkers, ndim)")
    n, w, d = chain.shape
    burn = int(burn_fraction * n)
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
        "tau_reliable": bool(np.all(len(kept) >= 50 * tau)),
    }
    if accepted is not None:
        acc = np.asarray(accepted, float) / max(n, 1)
        out["acceptance"] = acc
        out["acceptance_mean"] = float(acc.mean())
        out["acceptance_ok"] = bool(0.15 <= acc.mean() <= 0.8)
    return out


@dataclass
class StopRule:
    """When to stop: every parameter has n_kept ≥ tau_multiple·τ, |Δτ/τ| < tau_rtol and ESS ≥ target_ess."""

    target_ess: float = 50.0
    tau_multiple: float = 20.0
    tau_rtol: float = 0.05
    check_every: int = 50
    burn_fraction: float = 0.25
    min_steps: int = 100

    def __post_init__(self):
        if not self.target_ess > 0:  # 0 or less: the first check would stop any chain
            raise InputError(f"target_ess={self.target_ess!r}", column="target_ess", expected="> 0 effective samples")

    def check(self, d: dict, tau_prev) -> bool:
        """Whether diagnostics ``d`` (and τ at the previous check, None at the first) meet the rule."""
        tau = d["tau"]
        if d["n_steps"] < self.min_steps or not np.all(np.isfinite(tau)) or tau_prev is None:
            return False
        stable = np.all(np.abs(tau - tau_prev) / tau < self.tau_rtol)
        return bool(stable and np.all(d["n_kept"] >= self.tau_multiple * tau) and np.all(d["ess"] >= self.target_ess))


def flat_samples(run, burn_fraction: float = 0.25, thin: int = 1) -> np.ndarray:
    """Post-burn-in samples of a run (from ``load_run`` or a ``SamplerResult``), shape (n, ndim)."""
    chain = run["chain"] if isinstance(run, dict) else run.chain
    return chain[int(burn_fraction * len(chain)) :: thin].reshape(-1, chain.shape[-1])


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


__all__ = ["StopRule", "diagnostics", "flat_samples", "summarize"]
