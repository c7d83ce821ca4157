"""Posterior pipeline: emulator → emcee → optimum, Fisher, profile, predictive, emulator-error check.

Everything a run produces goes into one HDF5 file: group ``mcmc`` (chains, written step by step,
resumable) and group ``analysis`` (summary, correlations, Fisher spectrum, profile likelihood,
posterior-predictive diurnal curves with the observations, emulator error relative to the
posterior width). ``notebooks/posterior_analysis.ipynb`` reads such a file.
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd

from lightfit.errors import InputError
from lightfit.inference.identifiability import fisher_information, offsets_in_box, profile_likelihood
from lightfit.inference.likelihood import (
    MC_FORMS,
    USES,
    GaussianLikelihood,
    MCCorrelation,
    likelihood_form,
    observations_digest,
    resolve_use,
)
from lightfit.inference.likelihood import mc_correlation as mc_correlation_of
from lightfit.inference.mcmc import (
    NOISE_SCALE,
    PRIOR_SETS,
    LogPosterior,
    Prior,
    StopRule,
    check_sampled,
    flat_samples,
    priors_table,
    sample,
    summarize,
    write_group,
)
from lightfit.inference.mcmc.backend import drop_group, run_attrs, stored_run
from lightfit.inference.mcmc.diagnostics import burn_in
from lightfit.inference.mcmc.priors import informed_priors
from lightfit.inference.mcmc.sampler import MAX_STEPS, WALKERS
from lightfit.inference.multiday import MultiDayModel, days_of, joined, with_lights
from lightfit.inference.observations import SERIES, align, matched_as_by_stamp, observation_matching, read_offsets_s
from lightfit.light.bsdf import LEAF_PARAMETERS
from lightfit.model.coupled import CoupledModel
from lightfit.model.emulator import VALIDATED, FastObservables, PartsEmulator, in_box, validate
from lightfit.weather.timestamps import Timestamps

#: What a posterior samples unless told: the leaf's three surface parameters and the light factor.
SAMPLED_BY_DEFAULT = (*LEAF_PARAMETERS, "light_factor")


def prior_set(name: str, optics=None) -> dict[str, Prior]:
    """The prior set ``name`` of :data:`~lightfit.inference.mcmc.priors.PRIOR_SETS` for a run's leaf
    ``optics``: ``"informed"`` is :func:`~lightfit.inference.mcmc.priors.informed_priors` of that leaf
    (its subsurface prior spans PROSPECT-D's transmittance for the leaf's base colour: 0.31–1 for the
    default leaf, 0.04–0.17 for the reference paper's grey leaf); ``"wide"`` is the same for any leaf."""
    if name not in PRIOR_SETS:
        raise InputError(f"priors={name!r}", parameter="priors", expected=" or ".join(PRIOR_SETS))
    return informed_priors(optics) if name == "informed" else dict(PRIOR_SETS[name])


def log_posterior(
    model,
    obs: pd.DataFrame,
    forward,
    *,
    names=SAMPLED_BY_DEFAULT,
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
    for e in _emulators(forward):  # emulated forwards: inside their box only (no silent extrapolation)
        check_emulator_box(e.lo, e.hi, check_sampled(names, priors), priors, base)
    lp = LogPosterior.of_model(forward, model, obs, names, priors, base, use, mc_scale=mc_scale)
    if isinstance(mc_correlation, MCCorrelation) or form["mc_correlation"] == "independent":
        corr = mc_correlation if isinstance(mc_correlation, MCCorrelation) else None
    else:
        theta_c, _ = lp.split(jnp.asarray(lp.center()))
        corr = mc_correlation_of(light_model or model, theta_c, lp.use)
    return LogPosterior.of_model(
        forward, model, obs, names, priors, base, lp.use, mc_correlation=corr, mc_scale=mc_scale
    )


def _emulators(forward) -> list:
    """The emulators behind ``forward`` (a :class:`~lightfit.model.emulator.FastObservables` or several
    days' of them joined); none for an exact forward such as ``model.observe``."""
    days = getattr(forward, "forwards", None) or (forward,)
    return [f.emulator for f in days if hasattr(getattr(f, "emulator", None), "lo")]


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


def check_matching(
    path: str | Path,
    obs: pd.DataFrame,
    times: pd.DatetimeIndex,
    stamps: Timestamps,
    step: pd.Timedelta | None = None,
    use: Sequence[str] | None = None,
) -> None:
    """Refuse to resume a posterior run in ``path`` whose observations (of the used series ``use``)
    met the steps ``times`` (of the run's ``step``) otherwise (:class:`InputError`). Runs stored
    before the matching was recorded matched by stamp, which is the same only for instants on
    instants, none between steps."""
    if stored_run(Path(path), "mcmc") is None:
        return
    now = observation_matching(obs, times, stamps, step, use)
    before = run_attrs(path).get("observation_matching")
    if before is None:
        if matched_as_by_stamp(obs, times, stamps, step, use):
            return
        before = "by stamp (before interval matching)"
    if before != now:
        raise InputError(
            f"the posterior run there matched observations {before}, this run {now}",
            file=path,
            expected="--no-resume to start again, or another --out",
        )


#: What a resumed posterior run must share with the stored one, besides the checks above (names and
#: walkers: the sampler; model settings and emulator: the command line), as :func:`resume_key` gives it.
RESUME_ENTRIES = ("seed", "use", "priors", "fixed", "observations_sha256")
#: Largest linearised shift of the posterior mean, in posterior SDs, that the emulator's measured error
#: (:func:`emulator_error_vs_width`) may cause before a run is cautioned: a Gaussian 90 % interval
#: moved by 0.5 of its SD covers 86 % (by 1: 74 %).
EMULATOR_SHIFT_CAUTION_SD = 0.5
#: Draws (seed 0) from which a prior's SD is taken for ``sd_over_prior_sd``: its SE ≈ 0.5 %.
PRIOR_SD_DRAWS = 20_000
#: A parameter whose posterior SD is at least this share of its prior's is called barely informed
#: (``lightfit posterior``'s caution): the data narrowed it by less than a tenth.
UNINFORMED_SD_RATIO = 0.9
_EXPECTED_RESUME = "the run's own settings to resume it, --no-resume to start again, or another --out"
_STORED_AS = {"seed": int, "use": list, "priors": list, "fixed": dict, "observations_sha256": str}


def resume_key(
    model,
    obs: pd.DataFrame,
    *,
    names=SAMPLED_BY_DEFAULT,
    priors=None,
    fixed=None,
    use=USES,
    seed: int = 0,
) -> dict:
    """The entries of :data:`RESUME_ENTRIES` for a run of :func:`run` with these arguments, as they
    are stored with it (``seed`` by the sampler, the rest in the run's attributes) and compared on
    resume (:func:`check_resume`): ``use`` the series that enter the likelihood, ``priors`` the
    sampled parameters' priors (:func:`~lightfit.inference.mcmc.priors_table`), ``fixed`` every model
    parameter's value outside the sampled ones (the run's leaf completed with ``fixed``) and the
    noise scale, ``observations_sha256`` :func:`observations_digest`. Cheap: no forward model."""
    priors = prior_set("informed", model.scenario.optics) if priors is None else priors
    names = check_sampled(names, priors)
    fixed = dict(fixed or {})
    lam = float(fixed.pop(NOISE_SCALE, 1.0))
    lik = GaussianLikelihood.of_model(model, obs, use)
    return {
        "seed": seed,
        "use": list(lik.use),
        "priors": priors_table(priors, names),
        "fixed": {**model.theta(fixed).to_dict(), NOISE_SCALE: lam},
        "observations_sha256": observations_digest(lik, model.times),
    }


def _prior_fields(table) -> dict:
    """A priors table by parameter, without the sources (a reworded source is the same prior)."""
    return {r["parameter"]: {k: v for k, v in r.items() if k not in ("parameter", "source")} for r in table}


def _stored_use(use) -> tuple:
    try:  # runs may have stored aliases; compared as the series they name
        return resolve_use(tuple(use))
    except InputError:
        return tuple(use)


def _absolute(source) -> str:
    """A file's path made absolute (as given where it names no file here, e.g. a table built in memory)."""
    return str(Path(source).resolve()) if source and Path(str(source)).exists() else str(source)


def check_resume(path: str | Path, key: Mapping) -> tuple[str, ...]:
    """Refuse to resume the posterior run in ``path`` with other settings than it was started with:
    an :class:`InputError` naming the file and the first entry of ``key`` (:func:`resume_key`, or
    some of its entries) that differs. The chain would otherwise continue one posterior with steps of
    another, and the file's attributes (written when the run starts) would describe the first.

    Returns the entries of ``key`` the stored run has no record of (written before lightfit stored
    them): those are not checked, and the run resumes as before they were recorded."""
    path = Path(path)
    if stored_run(path, "mcmc") is None:
        return ()
    before = run_attrs(path)
    sampled = {r["parameter"] for r in key.get("priors", ())} or set(before.get("names", ()))
    unchecked = []
    for entry in (e for e in RESUME_ENTRIES if e in key):
        was, now = before.get(entry), key[entry]
        if not isinstance(was, _STORED_AS[entry]):  # not recorded (older file), or in a form not read here
            unchecked.append(entry)
            continue
        if entry == "seed":
            if int(was) != int(now):
                _refuse(path, f"was sampled with seed {int(was)} (--sampler-seed), this run asks for seed {int(now)}")
        elif entry == "use":
            if _stored_use(was) != tuple(now):
                _refuse(path, f"was sampled on the series use={list(_stored_use(was))}, this run on use={list(now)}")
        elif entry == "priors":
            a, b = _prior_fields(was), _prior_fields(now)
            # other sampled names are the sampler's refusal (names and walkers); here: the shared ones
            changed = [f"{n}: {a[n]} → {b[n]}" for n in b if n in a and a[n] != b[n]]
            if changed:
                _refuse(path, f"was sampled with other priors ({'; '.join(changed)})")
        elif entry == "fixed":
            # a sampled parameter's entry is unused (its sampled value replaces it): only the others count
            changed = [
                f"{n}: {was[n]!r} → {now[n]!r}" for n in now if n in was and n not in sampled and was[n] != now[n]
            ]
            if changed:
                _refuse(path, f"was sampled with other fixed values ({'; '.join(changed)})")
        elif was != now:
            _refuse(
                path,
                "was sampled on other observations (their values, SDs or missing entries on the run's steps, "
                f"or the steps, differ: observations_sha256 {str(was)[:12]}… → {str(now)[:12]}…)",
            )
    return tuple(unchecked)


def _refuse(path: Path, what: str) -> None:
    raise InputError(f"the posterior run there {what}", file=path, expected=_EXPECTED_RESUME)


def check_emulator_box(
    lo: Sequence[float], hi: Sequence[float], names: Sequence[str], priors: Mapping[str, Prior], fixed: Mapping
) -> None:
    """Refuse a posterior whose leaf parameters can leave the emulator's box [``lo``, ``hi``] (per
    :data:`~lightfit.light.bsdf.LEAF_PARAMETERS`): a sampled one whose prior support reaches outside
    it, or an unsampled one whose fixed value (``fixed``: the run's leaf completed with the fixed
    values) lies outside. The polynomial emulator would extrapolate there without any warning
    (e.g. ``--optics paper`` fixes subsurface at the grey leaf's 0.3, outside its informed box
    0.04–0.17). :class:`InputError` naming the parameter."""
    for i, n in enumerate(LEAF_PARAMETERS):
        low, high = float(lo[i]), float(hi[i])
        box = f"[{low:.6g}, {high:.6g}]"
        if n in names:
            a, b = priors[n].support
            if not in_box([a, b], low, high).all():
                raise InputError(
                    f"the prior of {n} spans [{a:.6g}, {b:.6g}], beyond the emulator's box {box}",
                    parameter=n,
                    expected=f"an emulator fitted on a box that holds the prior of {n} (or a narrower prior)",
                )
        elif not in_box(fixed[n], low, high):
            raise InputError(
                f"{n} is not sampled and stays at {fixed[n]:.6g} (the run's leaf, or its fixed value), outside "
                f"the emulator's box {box}, where the emulated light would be an extrapolation",
                parameter=n,
                expected=f"{n} sampled (add it to --parameters), or fixed inside the box; lightfit posterior "
                f"builds the box from the priors, so priors whose {n} support holds {fixed[n]:.6g} (--priors wide)",
            )


def optimum(lp: LogPosterior, start: np.ndarray, maxiter: int = 200, info: dict | None = None) -> np.ndarray:
    """MAP estimate: L-BFGS-B on −log posterior within the prior support, from ``start``, the Monte
    Carlo SDs held at ``start`` (a plug-in: the objective's gradient is its derivative;
    :mod:`lightfit.inference.likelihood`); ``start`` is kept where the sampled log posterior (each
    point's own SDs, as emcee evaluates it) is no lower than at the optimiser's end. ``info``, if
    given, receives ``converged`` (the optimiser's own success flag), its ``message`` and
    ``kept_start``, so that a MAP the optimiser did not reach is said so."""
    from scipy.optimize import minimize

    bounds = [lp.priors[n].support for n in lp.names]
    mc = lp.plug_in(start)
    vg = jax.jit(jax.value_and_grad(lambda x: -(lp.log_prior(x) + lp.log_likelihood(x, mc))))

    def fun(x):
        v, g = vg(jnp.asarray(x))
        return (float(v), np.asarray(g, float)) if np.isfinite(float(v)) else (1e30, np.zeros(len(x)))

    r = minimize(
        fun, np.asarray(start, float), jac=True, method="L-BFGS-B", bounds=bounds, options={"maxiter": maxiter}
    )
    improved = float(lp.log_prob(jnp.asarray(r.x))) > float(lp.log_prob(jnp.asarray(start, jnp.float64)))
    if info is not None:
        info.update(converged=bool(r.success), message=str(r.message), kept_start=not improved)
    return r.x if improved else np.asarray(start, float)


def chi2_as_given(lp, x) -> float:
    """χ² = rᵀΣ⁻¹r of the whitened residuals at ``x`` with the observations' SDs as given (noise scale
    λ = 1): where λ is sampled, the MAP's λ absorbs the misfit and the whitened χ² is ≈ n whatever
    the data (a review), so the fit is judged against the SDs the file states."""
    m, _ = lp.observables(jnp.asarray(x, jnp.float64))
    return float(jnp.sum(lp.likelihood.whitened(m, 1.0) ** 2))


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
    per_point = shifts.max(axis=1)
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
        #: per held-out point (rows of ``validation["leaf_test"]``), the largest shift over posterior SD
        "shift_over_sd_per_point": per_point.tolist(),
        **{f"max_abs_error_{s.value}": float(np.abs(validation[f"err_{s.value}"]).max()) for s in SERIES},
        "parts_rms": validation["parts_rms"],
        "parts_max": validation["parts_max"],
        #: per held-out point, the median emulated ÷ rendered Monte Carlo SE of the parts
        "se_ratio_per_point": np.asarray(validation["se_ratio"]).tolist(),
        "n_test": int(n_test),
    }


def identifiability(lp: LogPosterior, x_map: np.ndarray, n_profile: int = 15) -> tuple[dict, dict]:
    """Fisher information of the model parameters at ``x_map`` (noise scale held there) and the profile
    likelihood along the sloppiest direction, ±2 widths where the priors' box reaches
    (:func:`~lightfit.inference.identifiability.offsets_in_box`), the Monte Carlo SDs held at ``x_map`` (as the
    MAP search holds them at its start); in log-parameters (relative changes) unless the optimum sits on
    a zero bound."""
    model_names = tuple(n for n in lp.names if n != NOISE_SCALE)
    idx = [lp.names.index(n) for n in model_names]

    def at(xm):
        return jnp.asarray(x_map).at[jnp.asarray(idx)].set(xm)

    scale = "log" if np.all(x_map[idx] > 1e-6) else "natural"
    mc = lp.plug_in(x_map)
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
    # The other directions are optimised inside the priors' support (the emulator's box): outside
    # it the emulator would extrapolate (a review found the optimiser at specular 60).
    box = tuple(np.array([lp.priors[n].support[k] for n in model_names]) for k in (0, 1))
    # ±2 widths where the box reaches: beyond, the profile is +∞ (the informed box spans 0.47 in log
    # specular; 10 of 15 offsets of ±2 widths were outside it, a review), a hair inside its far
    # corners, where an offset's plane meets the box in one point; 0, the MAP's own, among them
    t_lo, t_hi = offsets_in_box(x_map[idx], d, box, scale)
    lo, hi = max(-2.0 * width, t_lo + 1e-3 * width), min(2.0 * width, t_hi - 1e-3 * width)
    ts = np.linspace(min(lo, 0.0), max(hi, 0.0), n_profile)
    ts[np.argmin(np.abs(ts))] = 0.0
    ts, prof, slc = profile_likelihood(
        lambda xm: -lp.log_likelihood(at(xm), mc), x_map[idx], d, ts, scale=scale, box=box
    )
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
    observations on the run's steps (``obs_<column>``; ``obs_<series>_time_offset_s``: where the
    model is read for them, s from the step, :func:`~lightfit.inference.observations.read_offsets_s`).
    Series the likelihood does not compare are NaN: the run renders only what its observations need
    (a record of above-canopy PAR renders nothing), so their draws would be zeros, not predictions.
    ``time_utc``: the steps' stamps; ``instant_utc``: the instants they stand for (a mean's interval
    centre, where its sun was taken and where a plot draws it; the stamps for instants)."""
    rng = np.random.default_rng(seed)
    draws = samples[rng.choice(len(samples), size=min(n, len(samples)), replace=False)]
    pred = jax.jit(jax.vmap(lambda x: lp.observables(x)[0]))(jnp.asarray(draws))
    stamps = lp.likelihood.stamps
    utc = times.tz_convert("UTC")
    used = set(lp.likelihood.use)

    def drawn(s, k):  # a series the likelihood does not compare may not have been rendered: not shown
        return np.asarray(pred[k]) if s.name in used else np.full(np.shape(pred[k]), np.nan)

    return {
        "time_utc": utc.strftime("%Y-%m-%dT%H:%M:%SZ").tolist(),
        "instant_utc": stamps.centres(utc).strftime("%Y-%m-%dT%H:%M:%SZ").tolist(),
        **{k: drawn(s, k) for s in SERIES for k in (s.value, s.mc_sd)},
        **{f"obs_{k}": np.asarray(v) for k, v in align(obs, times, lp.likelihood.stamps).items()},
        **{
            f"obs_{k}_time_offset_s": v
            for k, v in read_offsets_s(obs, times, lp.likelihood.stamps, lp.likelihood.step).items()
        },
    }


def _join_validations(vals: list[dict]) -> dict:
    """Several days' :func:`~lightfit.model.emulator.validate` results as one over the concatenated
    steps (errors and full values side by side in time; parts error: RMS over all, largest)."""
    if len(vals) == 1:
        return vals[0]
    out = {k: np.concatenate([v[k] for v in vals], axis=1) for o in VALIDATED for k in (f"err_{o}", f"full_{o}")}
    out["parts_rms"] = float(np.sqrt(np.mean([v["parts_rms"] ** 2 for v in vals])))
    out["parts_max"] = float(max(v["parts_max"] for v in vals))
    out["se_ratio"] = np.min([v["se_ratio"] for v in vals], axis=0)  # per point, the day furthest below 1
    out["leaf_test"] = vals[0]["leaf_test"]
    return out


def run(
    model: CoupledModel | MultiDayModel,
    obs: pd.DataFrame,
    emulator: PartsEmulator | list[PartsEmulator],
    path: str | Path,
    *,
    names=SAMPLED_BY_DEFAULT,
    priors=None,
    fixed=None,
    use=USES,
    nwalkers: int = WALKERS,
    max_steps: int = MAX_STEPS,
    seed: int = 0,
    stop: StopRule | None = StopRule(),
    resume: bool = True,
    progress: bool = True,
    validation_renders=None,
    render_at=None,
    n_predictive: int = 64,
    n_profile: int = 15,
    analysis: bool = True,
    max_seconds: float | None = None,
    n_grid: int = 64,
    attrs: dict | None = None,
    mc_correlation="model",
    mc_scale: float = 1.0,
    say=None,
) -> dict:
    """Sample the posterior into ``path`` and (``analysis=True``) write the analysis group.

    The log-posterior is :func:`log_posterior` (priors default: the informed priors of the run's leaf;
    unsampled parameters: the run's leaf defaults). ``validation_renders``: ``(leaf_test, (values,
    se))`` full renders at held-out points for the emulator-error report (skipped when None).
    ``render_at(day_model, leaf (n, 3)) -> (values, se)``: full renders elsewhere; given with
    ``validation_renders``, the MAP's own leaf is rendered and checked too (``at_map_*``): the
    held-out points are inside the box, where the emulator is best, and the MAP may sit on its edge.
    ``mc_correlation``: ``"model"`` (default) — the likelihood covers the renderer's Monte Carlo error
    with its correlation across steps and series, computed once from the emulated parts at the centre
    of the priors (:func:`~lightfit.inference.likelihood.mc_correlation`); ``None`` — independent
    steps (the diagonal form before issue 15); or an
    :class:`~lightfit.inference.likelihood.MCCorrelation`. ``say(line)``: told as each stage of the
    analysis starts (tens of seconds after the sampling's progress bar; ``None``: nothing said).
    ``mc_scale``: 1 for measured observations,
    2 for twins rendered at the model's samples. Both are stored with the run, and a run stored with
    another form is not resumed (:func:`check_likelihood`); nor is one started with another ``seed``,
    ``use``, ``priors``, ``fixed`` values or observations (:func:`check_resume`). Leaf parameters the
    emulators' box does not hold (a prior reaching beyond it, a fixed value outside) are refused
    (:func:`check_emulator_box`).

    Several days: ``model`` a :class:`~lightfit.inference.multiday.MultiDayModel`, ``emulator`` and
    ``validation_renders`` one per day (lists, in date order).
    Returns a dict of the main numbers.
    """
    t0 = time.perf_counter()
    form = likelihood_form(mc_correlation, mc_scale)
    if resume:
        check_likelihood(path, form)
    days = days_of(model)
    emus = list(emulator) if isinstance(emulator, (list, tuple)) else [emulator]
    priors = prior_set("informed", model.scenario.optics) if priors is None else priors
    key = resume_key(model, obs, names=names, priors=priors, fixed=fixed, use=use, seed=seed)
    how = (model.times, model.timestamps, model.step, key["use"])  # how the observations meet the steps
    if resume:
        check_matching(path, obs, *how)
    for e in emus:  # before anything is computed on the emulators
        check_emulator_box(e.lo, e.hi, names, priors, key["fixed"])
    if resume:
        check_resume(path, key)
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
    # What check_resume compares on resume: stored once, when the run starts (the sampler stores the seed).
    meta = {
        **{k: v for k, v in key.items() if k != "seed"},
        # absolute, as calibration.json stores it: the notebook may read the run from another folder
        "observations": {
            "source": _absolute(obs.attrs.get("source", "")),
            "provenance": obs.attrs.get("provenance", ""),
        },
        "scenario": {
            "n_segments": int(sum(len(d.segment_id) for d in days)),
            "samples": sc.samples,
            "bounces": sc.bounces,
            "direct": sc.direct,
            "render_seed": sc.seed,
            "n_plants": sc.field.n_plants,
            **({} if sc.field.plants_per_row is None else {"plants_per_row": sc.field.plants_per_row}),
            "par_kind": sc.par_kind,
            "an_per": sc.an_per,
            **({"dates": list(model.dates)} if isinstance(model, MultiDayModel) else {}),
        },
        "emulator": emu_meta[0] if len(emu_meta) == 1 else emu_meta,
        "likelihood": {**form, "correlation_at": None if corr is None else corr.theta},
        "observation_matching": observation_matching(obs, *how),
        **(attrs or {}),
    }
    if not resume and Path(path).exists():  # a new chain: an analysis stored with the old one is not its
        drop_group(path, "analysis")
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
        "seconds_sampling": res.seconds,  # this call's: a resumed or re-analysed chain's earlier steps not counted
        "steps_this_call": int(res.steps_this_call),
        "n_steps": int(res.diagnostics["n_steps"]),
        "tau": res.diagnostics["tau"].tolist(),
        "ess": res.diagnostics["ess"].tolist(),
        "rhat": res.diagnostics["rhat"].tolist(),
        "rhat_max": res.diagnostics["rhat_max"],
        "tau_reliable": bool(res.diagnostics.get("tau_reliable", False)),
        "tau_multiple": res.diagnostics.get("tau_multiple"),
        "n_walkers": int(res.diagnostics["n_walkers"]),
        "stuck": res.diagnostics["stuck"],  # walkers that never moved over the kept steps
        "acceptance_mean": res.diagnostics.get("acceptance_mean"),
        "acceptance_steps": res.diagnostics.get("acceptance_steps"),  # "kept": after the burn-in, as τ and ESS
        "acceptance_ok": res.diagnostics.get("acceptance_ok", True),
        "refused": res.refused,
        # every seed the run used: the sampler's, the renders' and the emulator designs' (None: not keyed)
        "seeds": {
            "sampler": int(seed),
            "render": int(sc.seed),
            "emulator_design": [e.key.get("design_seed") for e in emus],
        },
    }
    if res.steps_this_call > 0:  # an analysis stored with the run is of a shorter chain now
        drop_group(path, "analysis")
    if not analysis or res.stopped_by == "interrupted":  # an interrupted chain is resumed, not analysed
        return out
    burn = (stop or StopRule()).burn_fraction  # the burn-in the diagnostics discarded
    samples = flat_samples({"chain": res.chain}, burn)
    summ = summarize(samples, lp.names)
    cov = np.cov(samples.T).reshape(len(lp.names), len(lp.names))
    flat_lp = res.log_prob[burn_in(len(res.log_prob), burn) :].reshape(-1)
    say = say or (lambda line: None)
    say("analysis: the MAP (L-BFGS-B from the best sample) …")
    map_info: dict = {}
    x_map = optimum(lp, samples[np.argmax(flat_lp)], info=map_info)
    # How well the MAP fits (χ² of the whitened residuals) and how much the data narrowed each prior:
    # the posterior's SDs describe the model, and mean little where it does not fit or the prior stays.
    chi2_map = chi2_as_given(lp, x_map)
    prior_sd = {n: float(np.std(lp.priors[n].sample(np.random.default_rng(0), PRIOR_SD_DRAWS))) for n in lp.names}
    say(f"analysis: Fisher information and profile likelihoods ({n_profile} points each) …")
    fisher, profile = identifiability(lp, x_map, n_profile)
    # what lightfit posterior and posterior-status caution from (the MAP's fit, the priors' say)
    fit = {
        "chi2_map": chi2_map,
        "n_observations": int(lp.n_observations),
        "x_map": dict(zip(lp.names, np.asarray(x_map, float).tolist())),
        "sd_over_prior_sd": {n: float(v) / prior_sd[n] for n, v in zip(lp.names, summ["sd"].tolist())},
        "prior_support": {n: [float(b) for b in lp.priors[n].support] for n in lp.names},
    }
    draws_seed = seed + 1  # the predictive draws' generator, recorded with the run's other seeds
    say(f"analysis: posterior predictive ({n_predictive} draws) …")
    an: dict = {
        "fit": fit,
        "summary": {k: np.asarray(v) for k, v in summ.items() if k != "names"},
        "x_map": x_map,
        "log_prob_map": float(lp(x_map[None])[0]),
        "map_search": map_info,  # posterior-status reads it: whether L-BFGS-B converged
        "fisher": fisher,
        "profile": profile,
        "predictive": predictive(lp, obs, model.times, samples, n_predictive, draws_seed),
    }
    out["seeds"]["predictive_draws"] = draws_seed
    if validation_renders is not None:
        per_day = validation_renders if isinstance(model, MultiDayModel) else [validation_renders]
        n_held = sum(len(lt) for lt, _ in per_day)
        at_map = " and a render at the MAP's leaf" if render_at is not None else ""
        say(f"analysis: the emulator's error at {n_held} held-out full renders{at_map} …")
        th_map, _ = lp.split(jnp.asarray(x_map))
        extra = {k: float(getattr(th_map, k)) for k in ("light_factor", "vcmax_scale")}
        if render_at is not None:  # the MAP's leaf, the last held-out point of every day
            leaf_map = np.asarray(th_map.leaf, np.float64)[None]
            per_day = [
                (np.vstack([lt, leaf_map]), tuple(np.concatenate([a, b]) for a, b in zip(full, render_at(d, leaf_map))))
                for d, (lt, full) in zip(days, per_day)
            ]
        vals = [
            validate(d, f, leaf_test, theta_extra=extra, full=full)
            for d, f, (leaf_test, full) in zip(days, fasts, per_day)
        ]
        val = _join_validations(vals)
        an["emulator_error"] = emulator_error_vs_width(lp, x_map, cov, val)
        if render_at is not None:
            err = an["emulator_error"]
            err["at_map_shift_over_sd"] = err["shift_over_sd_per_point"][-1]
            err["at_map_leaf"] = leaf_map[0].tolist()
        out["emulator_error"] = an["emulator_error"]
    write_group(path, "analysis", an)
    out.update(
        {
            "x_map": fit["x_map"],
            "map_converged": map_info["converged"],
            "map_message": map_info["message"],
            "map_kept_start": map_info["kept_start"],
            "mean": dict(zip(lp.names, summ["mean"].tolist())),
            "sd": dict(zip(lp.names, summ["sd"].tolist())),
            # the 5/50/95 % quantiles after the burn-in, as run.h5's analysis/summary and corner.png mark them
            **{q: dict(zip(lp.names, summ[q].tolist())) for q in ("q05", "q50", "q95")},
            **{k: fit[k] for k in ("sd_over_prior_sd", "prior_support", "chi2_map", "n_observations")},
            "corr": summ["corr"].tolist(),
            "fisher": fisher["table"],
            "stiff": fisher["stiff"],
            "sloppy": fisher["sloppy"],
            "seconds_total": time.perf_counter() - t0,
        }
    )
    return out


__all__ = [
    "RESUME_ENTRIES",
    "SAMPLED_BY_DEFAULT",
    "check_emulator_box",
    "check_likelihood",
    "check_resume",
    "emulator_error_vs_width",
    "identifiability",
    "log_posterior",
    "optimum",
    "predictive",
    "prior_set",
    "resume_key",
    "run",
    "stored_likelihood",
]
