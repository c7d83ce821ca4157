"""Posterior pipeline: emulator → emcee → optimum, Fisher, profile, predictive, emulator-error check.

Everything a run produces goes into one HDF5 file: group ``mcmc`` (chains, written step by step,
resumable) and group ``analysis`` (summary, correlations, Fisher spectrum, profile likelihood,
posterior-predictive diurnal curves with the observations, emulator error relative to the
posterior width). ``notebooks/posterior_analysis.ipynb`` reads such a file.
"""

from __future__ import annotations

import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd

from lightfit.errors import InputError
from lightfit.inference.identifiability import fisher_information, profile_likelihood
from lightfit.inference.likelihood import MC_FORMS, USES, MCCorrelation, likelihood_form
from lightfit.inference.likelihood import mc_correlation as mc_correlation_of
from lightfit.inference.mcmc import (
    NOISE_SCALE,
    PRIOR_SETS,
    LogPosterior,
    Prior,
    StopRule,
    flat_samples,
    priors_table,
    sample,
    summarize,
    write_group,
)
from lightfit.inference.mcmc.backend import run_attrs, stored_run
from lightfit.inference.mcmc.priors import informed_priors
from lightfit.inference.multiday import MultiDayModel, days_of, joined, with_lights
from lightfit.inference.observations import SERIES, align, matched_as_by_stamp, observation_matching
from lightfit.model.coupled import CoupledModel
from lightfit.model.emulator import VALIDATED, FastObservables, PartsEmulator, validate
from lightfit.weather.timestamps import Timestamps


def prior_set(name: str, optics=None) -> dict[str, Prior]:
    """The prior set ``name`` of :data:`~lightfit.inference.mcmc.priors.PRIOR_SETS` for a run's leaf
    ``optics``: ``"informed"`` is :func:`~lightfit.inference.mcmc.priors.informed_priors` of that leaf
    (its subsurface prior spans PROSPECT-D's transmittance for the leaf's base colour: 0.31–1 for the
    default leaf, 0.04–0.17 for the reference paper's grey leaf); ``"wide"`` is the same for any leaf."""
    if name not in PRIOR_SETS:
        raise InputError(f"priors={name!r}", column="priors", expected=" or ".join(PRIOR_SETS))
    return informed_priors(optics) if name == "informed" else dict(PRIOR_SETS[name])


def log_posterior(
    model,
    obs: pd.DataFrame,
    forward,
    *,
    names=("specular", "roughness", "subsurface", "light_factor"),
    priors=None,
    fixed=None,
    use=USES,
    mc_correlation="model",
    mc_scale: float = 1.0,
    light_model=None,
) -> LogPosterior:
    """The :class:`~lightfit.inference.mcmc.LogPosterior` that :func:`run` samples, for the run's leaf.

    ``priors`` default: the informed priors of the run's leaf (:func:`prior_set` ``"informed"`` of
    ``model.scenario.optics``); unsampled model parameters: ``fixed`` completed with the run's own
    leaf (``model.theta(fixed)``), so a grey-leaf run (``--optics paper``) is sampled around the grey
    leaf with its prior; ``noise_scale`` from ``fixed`` (default 1). ``mc_correlation``: ``"model"`` —
    the model's Monte Carlo correlation at the centre of the priors, from ``light_model``'s parts
    (default ``model``'s; :func:`run` passes the emulated model, so no render); ``None`` — independent
    steps; or an :class:`~lightfit.inference.likelihood.MCCorrelation`. ``model`` may be a
    :class:`~lightfit.inference.multiday.MultiDayModel`."""
    form = likelihood_form(mc_correlation, mc_scale)
    priors = prior_set("informed", model.scenario.optics) if priors is None else priors
    fixed = dict(fixed or {})
    lam = fixed.pop(NOISE_SCALE, None)
    base = {**model.theta(fixed).to_dict(), **({} if lam is None else {NOISE_SCALE: lam})}
    stamps = model.timestamps
    lp = LogPosterior(forward, model.times, obs, names, priors, base, use, mc_scale=mc_scale, stamps=stamps)
    if isinstance(mc_correlation, MCCorrelation) or form["mc_correlation"] == "independent":
        corr = mc_correlation if isinstance(mc_correlation, MCCorrelation) else None
    else:
        theta_c, _ = lp.split(jnp.asarray(lp.center()))
        corr = mc_correlation_of(light_model or model, theta_c, lp.use)
    return LogPosterior(
        forward, model.times, obs, names, priors, base, lp.use, mc_correlation=corr, mc_scale=mc_scale, stamps=stamps
    )


def stored_likelihood(attrs: dict) -> dict:
    """The likelihood form (:func:`~lightfit.inference.likelihood.likelihood_form`) a stored posterior
    run was sampled with, from its attributes; runs stored before the form was recorded: independent
    steps (no ``likelihood`` attribute) or read from its sentence."""
    lk = attrs.get("likelihood")
    if not isinstance(lk, dict):
        return likelihood_form(None)
    mode = lk.get("mc_correlation")
    if mode not in MC_FORMS:  # written as a sentence: "independent steps" / "model Monte Carlo covariance at …"
        mode = "independent" if mode in (None, "independent steps") else "model"
    return {"mc_correlation": mode, "mc_scale": float(lk.get("mc_scale", 1.0))}


def check_likelihood(path: str | Path, form: dict) -> None:
    """Refuse to resume a posterior run in ``path`` sampled with another likelihood form (one chain
    would mix two posteriors): :class:`InputError` naming what changed."""
    if stored_run(Path(path), "mcmc") is None:
        return
    before = stored_likelihood(run_attrs(path))
    if before != form:
        changes = "; ".join(f"{k}: {before[k]!r} → {form[k]!r}" for k in form if before[k] != form[k])
        raise InputError(
            f"the posterior run there was sampled with another likelihood ({changes})",
            file=path,
            expected="the run's --mc-correlation and --mc-scale, --no-resume to start again, or another --out",
        )


def check_matching(path: str | Path, obs: pd.DataFrame, stamps: Timestamps) -> None:
    """Refuse to resume a posterior run in ``path`` whose observations met the steps otherwise
    (:class:`InputError`). Runs stored before the matching was recorded matched by stamp, which is
    the same only for instants on instants."""
    if stored_run(Path(path), "mcmc") is None:
        return
    now = observation_matching(obs, stamps)
    before = run_attrs(path).get("observation_matching")
    if before is None:
        if matched_as_by_stamp(obs, stamps):
            return
        before = "by stamp (before interval matching)"
    if before != now:
        raise InputError(
            f"the posterior run there matched observations {before}, this run {now}",
            file=path,
            expected="--no-resume to start again, or another --out",
        )


def optimum(lp: LogPosterior, start: np.ndarray, maxiter: int = 200) -> np.ndarray:
    """MAP estimate: L-BFGS-B on −log posterior within the prior support, from ``start``."""
    from scipy.optimize import minimize

    bounds = [lp.priors[n].support for n in lp.names]
    vg = jax.jit(jax.value_and_grad(lambda x: -(lp.log_prior(x) + lp.log_likelihood(x))))

    def fun(x):
        v, g = vg(jnp.asarray(x))
        return (float(v), np.asarray(g, float)) if np.isfinite(float(v)) else (1e30, np.zeros(len(x)))

    r = minimize(
        fun, np.asarray(start, float), jac=True, method="L-BFGS-B", bounds=bounds, options={"maxiter": maxiter}
    )
    return r.x if r.fun <= fun(start)[0] else np.asarray(start, float)


def emulator_error_vs_width(lp: LogPosterior, x_map: np.ndarray, cov: np.ndarray, validation: dict) -> dict:
    """Translate the emulator's observable errors at held-out renders into parameter shifts.

    For each held-out point the error δm (emulated − full, ``validation["err_<observable>"]``) is
    whitened with the likelihood's variances at the optimum, δr = −δm/√v (the residual is y − m),
    and mapped to the linearised shift of the posterior mean, δx = Σ_post Jᵀ δr (J: Jacobian of the
    whitened residuals), reported relative to the posterior SD of each parameter. Also: ‖δr‖ (the
    error in units of the observation noise; the change of −log L is at most ≈ ‖r‖‖δr‖ + ½‖δr‖²).
    """
    J = np.asarray(jax.jacrev(lp.residuals)(jnp.asarray(x_map)), float)
    m, lam = lp.observables(jnp.asarray(x_map))
    sd = np.sqrt(np.diag(cov))
    n_test = len(validation[f"err_{SERIES[0].value}"])
    shifts, norms = [], []
    for i in range(n_test):
        delta = {s.name: -jnp.asarray(validation[f"err_{s.value}"][i]) for s in SERIES}
        dr = np.asarray(lp.likelihood.whiten(delta, m, lam))
        shifts.append(np.abs(cov @ J.T @ dr) / sd)
        norms.append(float(np.linalg.norm(dr)))
    shifts = np.asarray(shifts)
    rows = [
        {
            "parameter": n,
            "posterior_sd": float(sd[j]),
            "max_shift_over_sd": float(shifts[:, j].max()),
            "rms_shift_over_sd": float(np.sqrt((shifts[:, j] ** 2).mean())),
        }
        for j, n in enumerate(lp.names)
    ]
    return {
        "per_parameter": rows,
        "max_shift_over_sd": float(shifts.max()),
        "max_whitened_error_norm": max(norms),
        **{f"max_abs_error_{s.value}": float(np.abs(validation[f"err_{s.value}"]).max()) for s in SERIES},
        "parts_rms": validation["parts_rms"],
        "parts_max": validation["parts_max"],
        "n_test": int(n_test),
    }


def identifiability(lp: LogPosterior, x_map: np.ndarray, n_profile: int = 15) -> tuple[dict, dict]:
    """Fisher information of the model parameters at ``x_map`` (noise scale held there) and the profile
    likelihood along the sloppiest direction, ±2 widths; in log-parameters (relative changes) unless the
    optimum sits on a zero bound."""
    model_names = tuple(n for n in lp.names if n != NOISE_SCALE)
    idx = [lp.names.index(n) for n in model_names]

    def at(xm):
        return jnp.asarray(x_map).at[jnp.asarray(idx)].set(xm)

    scale = "log" if np.all(x_map[idx] > 1e-6) else "natural"
    fi = fisher_information(lambda xm: lp.residuals(at(xm)), x_map[idx], model_names, scale=scale)
    fisher = {
        "names": list(model_names),
        "matrix": fi.fisher,
        "eigenvalues": fi.eigenvalues,
        "eigenvectors": fi.eigenvectors,
        "table": fi.table(),
        "stiff": fi.stiff,
        "sloppy": fi.sloppy,
        "scale": fi.scale,
    }
    d = fi.eigenvectors[:, -1]
    width = float(min(fi.widths[-1], 1.0))
    ts = np.linspace(-2.0 * width, 2.0 * width, n_profile)
    ts, prof, slc = profile_likelihood(lambda xm: -lp.log_likelihood(at(xm)), x_map[idx], d, ts, scale=scale)
    to_x = (lambda t: np.exp(np.log(x_map[idx]) + t * d)) if scale == "log" else (lambda t: x_map[idx] + t * d)
    inside = np.array([lp.in_support(np.asarray(at(to_x(t)))) for t in ts])
    profile = {
        "t": ts,
        "profile_nll": prof,
        "slice_nll": slc,
        "direction": d,
        "in_prior_box": inside.astype(np.int8),
        "combination": fi.sloppy,
        "scale": scale,
    }
    return fisher, profile


def predictive(lp: LogPosterior, obs: pd.DataFrame, times: pd.DatetimeIndex, samples, n: int, seed: int) -> dict:
    """Observables (and their Monte Carlo SDs) at ``n`` random posterior samples, (n, T) each, with the
    observations on the run's steps (``obs_<column>``). ``time_utc``: the steps' stamps;
    ``instant_utc``: the instants they stand for (a mean's interval centre, where its sun was taken
    and where a plot draws it; the stamps for instants)."""
    rng = np.random.default_rng(seed)
    draws = samples[rng.choice(len(samples), size=min(n, len(samples)), replace=False)]
    pred = jax.jit(jax.vmap(lambda x: lp.observables(x)[0]))(jnp.asarray(draws))
    stamps = lp.likelihood.stamps
    utc = times.tz_convert("UTC")
    return {
        "time_utc": utc.strftime("%Y-%m-%dT%H:%M:%SZ").tolist(),
        "instant_utc": stamps.centres(utc).strftime("%Y-%m-%dT%H:%M:%SZ").tolist(),
        **{k: np.asarray(pred[k]) for s in SERIES for k in (s.value, s.mc_sd)},
        **{f"obs_{k}": np.asarray(v) for k, v in align(obs, times, lp.likelihood.stamps).items()},
    }


def _join_validations(vals: list[dict]) -> dict:
    """Several days' :func:`~lightfit.model.emulator.validate` results as one over the concatenated
    steps (errors and full values side by side in time; parts error: RMS over all, largest)."""
    if len(vals) == 1:
        return vals[0]
    out = {k: np.concatenate([v[k] for v in vals], axis=1) for o in VALIDATED for k in (f"err_{o}", f"full_{o}")}
    out["parts_rms"] = float(np.sqrt(np.mean([v["parts_rms"] ** 2 for v in vals])))
    out["parts_max"] = float(max(v["parts_max"] for v in vals))
    out["leaf_test"] = vals[0]["leaf_test"]
    return out


def run(
    model: CoupledModel | MultiDayModel,
    obs: pd.DataFrame,
    emulator: PartsEmulator | list[PartsEmulator],
    path: str | Path,
    *,
    names=("specular", "roughness", "subsurface", "light_factor"),
    priors=None,
    fixed=None,
    use=USES,
    nwalkers: int = 32,
    max_steps: int = 4000,
    seed: int = 0,
    stop: StopRule | None = StopRule(),
    resume: bool = True,
    progress: bool = True,
    validation_renders=None,
    n_predictive: int = 64,
    n_profile: int = 15,
    analysis: bool = True,
    max_seconds: float | None = None,
    n_grid: int = 64,
    attrs: dict | None = None,
    mc_correlation="model",
    mc_scale: float = 1.0,
) -> dict:
    """Sample the posterior into ``path`` and (``analysis=True``) write the analysis group.

    The log-posterior is :func:`log_posterior` (priors default: the informed priors of the run's leaf;
    unsampled parameters: the run's leaf defaults). ``validation_renders``: ``(leaf_test, (values,
    se))`` full renders at held-out points for the emulator-error report (skipped when None).
    ``mc_correlation``: ``"model"`` (default) — the likelihood covers the renderer's Monte Carlo error
    with its correlation across steps and series, computed once from the emulated parts at the centre
    of the priors (:func:`~lightfit.inference.likelihood.mc_correlation`); ``None`` — independent
    steps (the diagonal form before issue 15); or an
    :class:`~lightfit.inference.likelihood.MCCorrelation`. ``mc_scale``: 1 for measured observations,
    2 for twins rendered at the model's samples. Both are stored with the run, and a run stored with
    another form is not resumed (:func:`check_likelihood`).

    Several days: ``model`` a :class:`~lightfit.inference.multiday.MultiDayModel`, ``emulator`` and
    ``validation_renders`` one per day (lists, in date order).
    Returns a dict of the main numbers.
    """
    t0 = time.perf_counter()
    form = likelihood_form(mc_correlation, mc_scale)
    if resume:
        check_likelihood(path, form)
        check_matching(path, obs, model.timestamps)
    days = days_of(model)
    emus = list(emulator) if isinstance(emulator, (list, tuple)) else [emulator]
    fasts = [FastObservables(d, e, n_grid=n_grid) for d, e in zip(days, emus)]
    fast = joined(model, fasts)
    lp = log_posterior(
        model,
        obs,
        fast,
        names=names,
        priors=priors,
        fixed=fixed,
        use=use,
        mc_correlation=mc_correlation,
        mc_scale=mc_scale,
        light_model=with_lights(model, emus),
    )
    corr = lp.likelihood.mc_correlation
    emu_meta = [
        {
            "degree": e.degree,
            "n_design": int(len(e.design)),
            "lo": e.lo.tolist(),
            "hi": e.hi.tolist(),
            "render_seconds": e.render_seconds,
            "n_grid": n_grid,
        }
        for e in emus
    ]
    sc = model.scenario
    meta = {
        "priors": priors_table(lp.priors, lp.names),
        "use": list(lp.use),
        "fixed": {**lp.base.to_dict(), NOISE_SCALE: lp.noise_scale},
        "observations": {"source": str(obs.attrs.get("source", "")), "provenance": obs.attrs.get("provenance", "")},
        "scenario": {
            "n_segments": int(sum(len(d.segment_id) for d in days)),
            "samples": sc.samples,
            "bounces": sc.bounces,
            "direct": sc.direct,
            "render_seed": sc.seed,
            "n_plants": sc.field.n_plants,
            "par_kind": sc.par_kind,
            "an_per": sc.an_per,
            **({"dates": list(model.dates)} if isinstance(model, MultiDayModel) else {}),
        },
        "emulator": emu_meta[0] if len(emu_meta) == 1 else emu_meta,
        "likelihood": {**form, "correlation_at": None if corr is None else corr.theta},
        "observation_matching": observation_matching(obs, model.timestamps),
        **(attrs or {}),
    }
    res = sample(
        lp,
        lp.names,
        path,
        nwalkers=nwalkers,
        max_steps=max_steps,
        seed=seed,
        resume=resume,
        stop=stop,
        progress=progress,
        attrs=meta,
        max_seconds=max_seconds,
    )
    out = {
        "names": list(lp.names),
        "stopped_by": res.stopped_by,
        "seconds_sampling": res.seconds,
        "n_steps": int(res.diagnostics["n_steps"]),
        "tau": res.diagnostics["tau"].tolist(),
        "ess": res.diagnostics["ess"].tolist(),
        "acceptance_mean": res.diagnostics.get("acceptance_mean"),
        "refused": res.refused,
    }
    if not analysis or res.stopped_by == "interrupted":  # an interrupted chain is resumed, not analysed
        return out
    samples = flat_samples({"chain": res.chain})
    summ = summarize(samples, lp.names)
    cov = np.cov(samples.T).reshape(len(lp.names), len(lp.names))
    flat_lp = res.log_prob[int(0.25 * len(res.log_prob)) :].reshape(-1)
    x_map = optimum(lp, samples[np.argmax(flat_lp)])
    fisher, profile = identifiability(lp, x_map, n_profile)
    an: dict = {
        "summary": {k: np.asarray(v) for k, v in summ.items() if k != "names"},
        "x_map": x_map,
        "log_prob_map": float(lp(x_map[None])[0]),
        "fisher": fisher,
        "profile": profile,
        "predictive": predictive(lp, obs, model.times, samples, n_predictive, seed + 1),
    }
    if validation_renders is not None:
        per_day = validation_renders if isinstance(model, MultiDayModel) else [validation_renders]
        th_map, _ = lp.split(jnp.asarray(x_map))
        extra = {k: float(getattr(th_map, k)) for k in ("light_factor", "vcmax_scale")}
        vals = [
            validate(d, f, leaf_test, theta_extra=extra, full=full)
            for d, f, (leaf_test, full) in zip(days, fasts, per_day)
        ]
        val = _join_validations(vals)
        an["emulator_error"] = emulator_error_vs_width(lp, x_map, cov, val)
        out["emulator_error"] = an["emulator_error"]
    write_group(path, "analysis", an)
    out.update(
        {
            "x_map": dict(zip(lp.names, x_map.tolist())),
            "mean": dict(zip(lp.names, summ["mean"].tolist())),
            "sd": dict(zip(lp.names, summ["sd"].tolist())),
            "corr": summ["corr"].tolist(),
            "fisher": fisher["table"],
            "stiff": fisher["stiff"],
            "sloppy": fisher["sloppy"],
            "seconds_total": time.perf_counter() - t0,
        }
    )
    return out


__all__ = [
    "check_likelihood",
    "emulator_error_vs_width",
    "identifiability",
    "log_posterior",
    "optimum",
    "predictive",
    "prior_set",
    "run",
    "stored_likelihood",
]
