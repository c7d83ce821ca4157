r"""Bayesian posteriors of the leaf-optics (and light, Vcmax, noise) parameters with emcee.

Likelihood (Gaussian, as :func:`lightfit.inference.calibration.make_loss`, plus the normalisation that a
free noise scale needs): for every observed step k of PAR and net CO2 uptake

.. math:: \log L(\theta) = -\tfrac12 \sum_k \Big[\frac{(y_k - m_k(\theta))^2}{v_k} + \log(2\pi v_k)\Big],
    \qquad v_k = (\lambda\,\sigma_k)^2 + s_k^2(\theta),

with the measurement SD σ_k, the optional ``noise_scale`` λ (1 when not sampled) and the model's
Monte Carlo variance s_k². With λ = 1 it equals ``−make_loss(...) − ½Σ log(2π v_k)`` (tested).
The model m(θ) is :class:`lightfit.model.emulator.FastObservables` — emulated renders and
tabulated photosynthesis, whose error against full renders is measured and reported relative to
the posterior width (:func:`emulator_error_vs_width`).

Sampler: :class:`emcee.EnsembleSampler` (affine-invariant stretch move), vectorised over the
walkers (one ``jax.vmap`` call per half-ensemble), storing every step in HDF5 through
:class:`ResumableHDFBackend`: each step's row holds the chain, log-probabilities, acceptance
flags *and the generator state after that step*, and the step counter is written last, so a run
killed at any moment resumes from the last complete step and continues exactly as an
uninterrupted run with the same seed would (tested bit for bit). A partly written step is
overwritten. (HDF5 itself has no journal: a kill in the middle of a metadata write can in
principle corrupt the file; h5py/HDF5 give no stronger guarantee.)

Stop rule (checked every ``check_every`` steps, on the chain after discarding the first
``burn_fraction``): integrated autocorrelation time τ_j per parameter (emcee's estimator),
effective sample size ESS_j = n_walkers · n_kept / τ_j, and the run stops when for every parameter
n_kept ≥ ``tau_multiple`` · τ_j (τ reliable), τ changed by < ``tau_rtol`` since the last check,
and ESS_j ≥ ``target_ess``. Acceptance fractions outside [0.15, 0.8] are flagged.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import emcee
import h5py
import jax
import jax.numpy as jnp
import numpy as np

from lightfit.errors import InputError
from lightfit.inference.observations import align
from lightfit.model.coupled import DEFAULT_THETA, PARAMETERS

#: Everything the posterior can sample: the model parameters plus a measurement-noise scale.
SAMPLED = (*PARAMETERS, "noise_scale")


# ----------------------------------------------------------------------------------------------
# Priors
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Prior:
    """A one-dimensional prior with its source.

    kinds: ``uniform`` (a = lower, b = upper), ``loguniform`` (a, b > 0), ``lognormal`` (a = median,
    b = SD of the natural log, truncated to [lo, hi]).
    """

    kind: str
    a: float
    b: float
    source: str
    lo: float | None = None
    hi: float | None = None

    def __post_init__(self):
        if self.kind not in ("uniform", "loguniform", "lognormal"):
            raise InputError(f"prior kind {self.kind!r}", column="prior", expected="uniform, loguniform or lognormal")
        if self.kind in ("uniform", "loguniform") and not self.a < self.b:
            raise InputError(f"prior bounds a={self.a}, b={self.b}", column="prior", expected="a < b")
        if self.kind in ("loguniform", "lognormal") and not (self.a > 0 and self.b > 0):
            raise InputError(f"prior a={self.a}, b={self.b}", column="prior", expected="a > 0 and b > 0")

    @property
    def support(self) -> tuple[float, float]:
        if self.kind in ("uniform", "loguniform"):
            return (self.a, self.b)
        return (self.lo if self.lo is not None else 0.0, self.hi if self.hi is not None else math.inf)

    def logpdf(self, x):
        """Log density (up to a constant) at x; −inf outside the support. JAX-traceable."""
        lo, hi = self.support
        inside = (x >= lo) & (x <= hi)
        if self.kind == "uniform":
            val = jnp.zeros_like(x)
        elif self.kind == "loguniform":
            val = -jnp.log(jnp.where(inside, x, 1.0))
        else:
            lx = jnp.log(jnp.where(inside, x, 1.0))
            val = -lx - 0.5 * ((lx - math.log(self.a)) / self.b) ** 2
        return jnp.where(inside, val, -jnp.inf)

    def sample(self, rng: np.random.Generator, n: int) -> np.ndarray:
        lo, hi = self.support
        if self.kind == "uniform":
            return rng.uniform(lo, hi, n)
        if self.kind == "loguniform":
            return np.exp(rng.uniform(math.log(lo), math.log(hi), n))
        out = np.exp(math.log(self.a) + self.b * rng.standard_normal(n))
        return np.clip(out, lo, hi)


_F0 = "F0 = 0.08·specular (lightfit.light.bsdf)"
_T = "leaf transmittance = (1 − F0)·subsurface·base_color, base_color 0.5"
#: Priors informed by leaf optics (docs/design.md §6) — the default.
PRIORS_INFORMED: dict[str, Prior] = {
    "specular": Prior(
        "uniform",
        0.4625,
        0.7375,
        f"upper leaf surface reflection 3.7–5.9 % (docs/design.md §6), {_F0}: 0.037/0.08 … 0.059/0.08",
    ),
    "roughness": Prior(
        "uniform",
        0.3,
        1.0,
        "no measurement; lower bound 0.3 (GGX α ≥ 0.09) excludes mirror-like cuticles, for which the "
        "frozen-sampling estimator's per-segment variance explodes (glints)",
    ),
    "subsurface": Prior(
        "uniform", 0.04, 0.18, f"PROSPECT-D wheat PAR transmittance 0.02–0.08 (docs/design.md §6), {_T}: ≈ 0.04 … 0.17"
    ),
    "light_factor": Prior(
        "lognormal",
        1.0,
        0.5,
        "broad: median 1 (PAR = 0.5 × 4.57 µmol/J × radiation), ±1 SD in log covers the reference paper's fitted 1.637",
        lo=0.25,
        hi=4.0,
    ),
    "vcmax_scale": Prior(
        "lognormal", 1.0, 0.25, "Vcmax varies ≈ ±25 % with cultivar and leaf age (1 SD in log)", lo=0.25, hi=4.0
    ),
    "noise_scale": Prior(
        "loguniform",
        0.3,
        3.0,
        "scale-invariant (Jeffreys) prior on the factor multiplying the reported measurement SDs",
    ),
}
#: Wide priors over the whole leaf-parameter box (roughness ≥ 0.3 as above): lets the posterior reach the
#: biophysically unrealistic combinations the reference paper warns about.
PRIORS_WIDE: dict[str, Prior] = {
    **PRIORS_INFORMED,
    "specular": Prior("uniform", 0.0, 1.0, "whole parameter range (uninformative)"),
    "subsurface": Prior("uniform", 0.0, 1.0, "whole parameter range (uninformative)"),
}
PRIOR_SETS = {"informed": PRIORS_INFORMED, "wide": PRIORS_WIDE}


def check_names(names, priors: dict[str, Prior]) -> tuple[str, ...]:
    names = tuple(names)
    unknown = [n for n in names if n not in SAMPLED]
    if unknown:
        raise InputError(f"unknown parameter(s) {unknown}", column="parameters", expected=", ".join(SAMPLED))
    if len(set(names)) != len(names):
        raise InputError(f"duplicate parameter names {list(names)}", column="parameters", expected="each name once")
    missing = [n for n in names if n not in priors]
    if missing:
        raise InputError(f"no prior for {missing}", column="priors", expected="a Prior for every sampled parameter")
    for n in names:
        if n in PARAMETERS:
            lo, hi = priors[n].support
            plo, phi = PARAMETERS[n]
            if lo < plo or (phi is not None and hi > phi):
                raise InputError(
                    f"prior support of {n} is [{lo}, {hi}]",
                    column=n,
                    expected=f"within the parameter's domain [{plo}, {phi}]",
                )
    return names


# ----------------------------------------------------------------------------------------------
# Log-probability
# ----------------------------------------------------------------------------------------------
class LogPosterior:
    """Vectorised log-posterior over ``names`` for observations ``obs`` and a forward function.

    Args:
        forward: ``forward(theta: dict) -> dict`` of observables (``FastObservables`` or
            ``model.observe``); must be JAX-traceable for the vectorised/jitted use.
        times: the model's time steps (``model.times``) — observations are aligned to them.
        obs: observations DataFrame (:func:`read_observations`); ``use``: which series enter
            the likelihood, ``("par", "an")`` or one of them (twin experiments).
        fixed: values of non-sampled model parameters (default :data:`DEFAULT_THETA`).
    """

    def __init__(
        self,
        forward,
        times,
        obs,
        names,
        priors: dict[str, Prior] | None = None,
        fixed: dict | None = None,
        use=("par", "an"),
    ):
        self.priors = dict(priors or PRIORS_INFORMED)
        self.names = check_names(names, self.priors)
        bad = [u for u in use if u not in ("par", "an")]
        if bad or not use:
            raise InputError(f"use={tuple(use)!r}", column="use", expected="a non-empty subset of ('par', 'an')")
        unknown = [k for k in (fixed or {}) if k not in SAMPLED]
        if unknown:
            raise InputError(f"unknown fixed parameter(s) {unknown}", column="fixed", expected=", ".join(SAMPLED))
        self.forward, self.use = forward, tuple(use)
        self.base = {**DEFAULT_THETA, "noise_scale": 1.0, **(fixed or {})}
        target = align(obs, times)
        self.y, self.sd, self.mask = {}, {}, {}
        for u, v, sd in (("par", "par_umol_m2_s", "par_sd_umol_m2_s"), ("an", "an_umol_m2_s", "an_sd_umol_m2_s")):
            have = ~np.isnan(target[v]) & (u in self.use)
            self.y[u], self.sd[u] = (
                jnp.asarray(np.nan_to_num(target[v])),
                jnp.asarray(np.nan_to_num(target[sd], nan=1.0)),
            )
            self.mask[u] = jnp.asarray(have)
        self.n_observations = int(sum(np.asarray(m).sum() for m in self.mask.values()))
        if self.n_observations == 0:
            raise InputError(
                "no observation of the used series falls on a simulated step",
                file=obs.attrs.get("source"),
                column="use",
                expected="PAR or net CO2 observations within the run",
            )
        self._batch = jax.jit(jax.vmap(self.log_prob))
        self._batch_ll = jax.jit(jax.vmap(self.log_likelihood))

    def theta_of(self, x) -> dict:
        return {**self.base, **{n: x[i] for i, n in enumerate(self.names)}}

    def log_prior(self, x):
        return sum(self.priors[n].logpdf(x[i]) for i, n in enumerate(self.names))

    def log_likelihood(self, x):
        th = self.theta_of(x)
        m = self.forward({k: v for k, v in th.items() if k != "noise_scale"})
        lam = jnp.asarray(th["noise_scale"], jnp.float64)
        total = 0.0
        for u, v, mc in (("par", "par_umol_m2_s", "par_mc_var"), ("an", "an_umol_m2_s", "an_mc_var")):
            var = jnp.where(self.mask[u], (lam * self.sd[u]) ** 2 + m[mc], 1.0)
            term = (self.y[u] - m[v]) ** 2 / var + jnp.log(2 * jnp.pi * var)
            total = total - 0.5 * jnp.sum(jnp.where(self.mask[u], term, 0.0))
        return total

    def residuals(self, x):
        """Whitened residuals (y − m)/√v of the used observations (zeros elsewhere), shape (2T,)."""
        th = self.theta_of(x)
        m = self.forward({k: v for k, v in th.items() if k != "noise_scale"})
        lam = jnp.asarray(th["noise_scale"], jnp.float64)
        out = []
        for u, v, mc in (("par", "par_umol_m2_s", "par_mc_var"), ("an", "an_umol_m2_s", "an_mc_var")):
            var = jnp.where(self.mask[u], (lam * self.sd[u]) ** 2 + m[mc], 1.0)
            out.append(jnp.where(self.mask[u], (self.y[u] - m[v]) / jnp.sqrt(var), 0.0))
        return jnp.concatenate(out)

    def in_support(self, x) -> bool:
        return bool(np.isfinite(float(self.log_prior(jnp.asarray(x, jnp.float64)))))

    def log_prob(self, x):
        x = jnp.asarray(x, jnp.float64)
        lp = self.log_prior(x)
        # evaluate the likelihood at a safe point outside the support (no NaN from the model)
        safe = jnp.where(jnp.isfinite(lp), x, jnp.asarray(self.center()))
        return jnp.where(jnp.isfinite(lp), lp + self.log_likelihood(safe), -jnp.inf)

    def center(self) -> np.ndarray:
        out = []
        for n in self.names:
            p = self.priors[n]
            out.append(
                0.5 * (p.a + p.b) if p.kind == "uniform" else (math.sqrt(p.a * p.b) if p.kind == "loguniform" else p.a)
            )
        return np.asarray(out)

    def __call__(self, xs: np.ndarray) -> np.ndarray:
        """emcee's vectorised log-probability: (n, ndim) → (n,)."""
        return np.asarray(self._batch(jnp.asarray(np.atleast_2d(xs), jnp.float64)), dtype=np.float64)

    def loglike_batch(self, xs: np.ndarray, chunk: int = 64) -> np.ndarray:
        """Log-likelihood of many points, evaluated ``chunk`` at a time (bounded memory)."""
        xs = np.atleast_2d(xs)
        return np.concatenate(
            [
                np.asarray(self._batch_ll(jnp.asarray(xs[i : i + chunk], jnp.float64)), dtype=np.float64)
                for i in range(0, len(xs), chunk)
            ]
        )

    def initial(self, nwalkers: int, seed: int) -> np.ndarray:
        """Walkers drawn from the prior (generator seeded with ``seed``)."""
        rng = np.random.default_rng(seed)
        return np.column_stack([self.priors[n].sample(rng, nwalkers) for n in self.names])


# ----------------------------------------------------------------------------------------------
# Resumable HDF5 backend
# ----------------------------------------------------------------------------------------------
class ResumableHDFBackend(emcee.backends.HDFBackend):
    """HDFBackend whose generator state and acceptance flags are stored per step (see module doc)."""

    def reset(self, nwalkers, ndim):
        super().reset(nwalkers, ndim)
        with self.open("a") as f:
            g = f[self.name]
            g.create_dataset("rng_key", (0, 624), maxshape=(None, 624), dtype=np.uint32)
            g.create_dataset("rng_meta", (0, 3), maxshape=(None, 3), dtype=np.float64)
            g.create_dataset("accepted_step", (0, nwalkers), maxshape=(None, nwalkers), dtype=bool)

    def grow(self, ngrow, blobs):
        super().grow(ngrow, blobs)
        with self.open("a") as f:
            g = f[self.name]
            n = g["chain"].shape[0]
            for k in ("rng_key", "rng_meta", "accepted_step"):
                g[k].resize(n, axis=0)

    def save_step(self, state, accepted):
        self._check(state, accepted)
        with self.open("a") as f:
            g = f[self.name]
            i = int(g.attrs["iteration"])
            g["chain"][i, :, :] = state.coords
            g["log_prob"][i, :] = state.log_prob
            if state.blobs is not None:
                g["blobs"][i, :] = state.blobs
            _, key, pos, has_gauss, cached = state.random_state
            g["rng_key"][i, :] = np.asarray(key, np.uint32)
            g["rng_meta"][i, :] = (pos, has_gauss, cached)
            g["accepted_step"][i, :] = accepted
            g["accepted"][:] = g["accepted_step"][: i + 1].sum(axis=0)
            g.attrs["iteration"] = i + 1  # last: commits the step

    @property
    def random_state(self):
        with self.open() as f:
            g = f[self.name]
            i = int(g.attrs["iteration"])
            if i == 0 or "rng_key" not in g:
                return None
            pos, has_gauss, cached = g["rng_meta"][i - 1]
            return ("MT19937", np.asarray(g["rng_key"][i - 1], np.uint32), int(pos), int(has_gauss), float(cached))


# ----------------------------------------------------------------------------------------------
# Diagnostics
# ----------------------------------------------------------------------------------------------
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

    def check(self, d: dict, tau_prev) -> bool:
        tau = d["tau"]
        if d["n_steps"] < self.min_steps or not np.all(np.isfinite(tau)) or tau_prev is None:
            return False
        stable = np.all(np.abs(tau - tau_prev) / tau < self.tau_rtol)
        return bool(stable and np.all(d["n_kept"] >= self.tau_multiple * tau) and np.all(d["ess"] >= self.target_ess))


@dataclass
class SamplerResult:
    """What :func:`sample` returns. ``chain``: (n_steps, n_walkers, ndim); ``stopped_by``:
    ``"rule"`` (stop rule met), ``"max_steps"`` or ``"interrupted"``."""

    names: tuple
    chain: np.ndarray
    log_prob: np.ndarray
    diagnostics: dict
    path: Path
    stopped_by: str
    seconds: float
    steps_this_call: int


def sample(
    log_prob,
    names,
    path: str | Path,
    *,
    nwalkers: int = 32,
    max_steps: int = 5000,
    seed: int = 0,
    initial: np.ndarray | None = None,
    resume: bool = True,
    stop: StopRule | None = None,
    progress: bool = True,
    group: str = "mcmc",
    attrs: dict | None = None,
    max_seconds: float | None = None,
    moves=None,
) -> SamplerResult:
    """Run (or resume) an emcee ensemble over ``names`` with the vectorised ``log_prob`` into HDF5 ``path``.

    Args:
        log_prob: ``f(xs: (n, ndim)) -> (n,)`` (e.g. :class:`LogPosterior`).
        nwalkers: even, ≥ 2·ndim. ``seed``: seeds the sampler's RandomState (and the initial
            positions when ``initial`` is None and ``log_prob`` has ``.initial``).
        max_steps: total steps (including those already stored).
        resume: continue an existing run in ``path`` (same names/walkers required); False starts over.
        stop: :class:`StopRule` (None: run to ``max_steps``).
        attrs: JSON-serialisable metadata stored with the run.
    """
    names = tuple(names)
    ndim = len(names)
    if ndim == 0:
        raise InputError("no parameters to sample", column="names", expected="at least one parameter")
    if nwalkers < 2 * ndim or nwalkers % 2:
        raise InputError(f"nwalkers={nwalkers}", column="nwalkers", expected=f"an even number ≥ 2·ndim = {2 * ndim}")
    if max_steps < 1:
        raise InputError(f"max_steps={max_steps}", column="max_steps", expected="≥ 1")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    backend = ResumableHDFBackend(str(path), name=group)
    fresh = True
    if resume and path.exists():
        with h5py.File(path, "r") as f:
            if group in f and int(f[group].attrs.get("iteration", 0)) > 0:
                g = f[group]
                stored = tuple(json.loads(g.attrs.get("names", "[]")))
                if stored != names or int(g.attrs["nwalkers"]) != nwalkers:
                    raise InputError(
                        f"{path} holds a run over {list(stored)} with {int(g.attrs['nwalkers'])} walkers",
                        file=path,
                        column="names",
                        expected=f"the same names {list(names)} and nwalkers={nwalkers}, or resume=False",
                    )
                fresh = False
    if fresh:
        backend.reset(nwalkers, ndim)
        with h5py.File(path, "a") as f:
            g = f[group]
            g.attrs["names"] = json.dumps(list(names))
            g.attrs["seed"] = seed
            for k, v in (attrs or {}).items():
                g.attrs[k] = json.dumps(v)
        if initial is None:
            if not hasattr(log_prob, "initial"):
                raise InputError("no initial positions", column="initial", expected="an (nwalkers, ndim) array")
            initial = log_prob.initial(nwalkers, seed)
        initial = np.asarray(initial, float)
        if initial.shape != (nwalkers, ndim):
            raise InputError(f"initial shape {initial.shape}", column="initial", expected=f"({nwalkers}, {ndim})")
        state = emcee.State(initial, random_state=np.random.RandomState(seed).get_state())
    else:
        state = backend.get_last_sample()
    sampler = emcee.EnsembleSampler(nwalkers, ndim, log_prob, vectorize=True, backend=backend, moves=moves)
    sampler.random_state = np.random.RandomState(seed).get_state()  # overwritten by state.random_state
    done = backend.iteration
    todo = max_steps - done
    t0 = time.perf_counter()
    stopped_by = "max_steps"
    tau_prev = None
    bar = None
    if progress and todo > 0:
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

        bar = Progress(
            TextColumn("sampling"),
            BarColumn(),
            MofNCompleteColumn(),
            TimeElapsedColumn(),
            TextColumn("{task.fields[info]}"),
        )
        task = bar.add_task("mcmc", total=max_steps, completed=done, info="")
        bar.start()
    k = 0
    try:
        if todo > 0:
            for _ in sampler.sample(state, iterations=todo, store=True, progress=False):
                k += 1
                it = backend.iteration
                if bar:
                    bar.update(task, completed=it)
                if stop is not None and it % stop.check_every == 0:
                    d = diagnostics(
                        backend.get_chain(), backend.accepted, burn_fraction=stop.burn_fraction, names=names
                    )
                    if bar:
                        bar.update(
                            task,
                            info=f"τ max {np.nanmax(d['tau']):.1f}  ESS min {np.nanmin(d['ess']):.0f}  "
                            f"acc {d['acceptance_mean']:.2f}",
                        )
                    if stop.check(d, tau_prev):
                        stopped_by = "rule"
                        break
                    tau_prev = d["tau"]
                if max_seconds is not None and time.perf_counter() - t0 > max_seconds:
                    stopped_by = "max_seconds"
                    break
    except KeyboardInterrupt:
        stopped_by = "interrupted"
    finally:
        if bar:
            bar.stop()
    chain = backend.get_chain()
    d = diagnostics(chain, backend.accepted, burn_fraction=(stop or StopRule()).burn_fraction, names=names)
    d["rule_met"] = stopped_by == "rule"
    with h5py.File(path, "a") as f:
        f[group].attrs["diagnostics"] = json.dumps(_jsonable(d))
        f[group].attrs["stopped_by"] = stopped_by
    return SamplerResult(names, chain, backend.get_log_prob(), d, path, stopped_by, time.perf_counter() - t0, k)


def _jsonable(d):
    if isinstance(d, dict):
        return {k: _jsonable(v) for k, v in d.items()}
    if isinstance(d, (list, tuple)):
        return [_jsonable(v) for v in d]
    if isinstance(d, np.ndarray):
        return d.tolist()
    if isinstance(d, (np.floating, np.integer, np.bool_)):
        return d.item()
    return d


def load_run(path: str | Path, group: str = "mcmc") -> dict:
    """Read a stored run: ``names``, ``chain`` (n, walkers, ndim), ``log_prob``, ``accepted``, ``attrs``
    (JSON-decoded), ``diagnostics`` (recomputed) and any analysis groups written next to it."""
    path = Path(path)
    if not path.exists():
        raise InputError("file not found", file=path, expected="an HDF5 file written by lightfit.inference.mcmc")
    with h5py.File(path, "r") as f:
        if group not in f:
            raise InputError(f"no group {group!r}", file=path, expected="a posterior run")
        g = f[group]
        n = int(g.attrs["iteration"])
        out = {
            "names": tuple(json.loads(g.attrs["names"])),
            "chain": g["chain"][:n],
            "log_prob": g["log_prob"][:n],
            "accepted": g["accepted"][:],
            "attrs": {},
        }
        for k, v in g.attrs.items():
            try:
                out["attrs"][k] = json.loads(v) if isinstance(v, str) else (v.item() if hasattr(v, "item") else v)
            except (json.JSONDecodeError, TypeError):
                out["attrs"][k] = v
        for name in ("analysis",):
            if name in f:
                out[name] = _read_group(f[name])
    out["diagnostics"] = diagnostics(out["chain"], out["accepted"], names=out["names"])
    return out


def _read_group(g) -> dict:
    out = {}
    for k, v in g.items():
        out[k] = _read_group(v) if isinstance(v, h5py.Group) else v[()]
    for k, v in g.attrs.items():
        out[k] = json.loads(v) if isinstance(v, str) else v
    return out


def write_group(path: str | Path, name: str, data: dict) -> None:
    """Write (replace) HDF5 group ``name`` with arrays (datasets) and other values (JSON attrs)."""
    with h5py.File(path, "a") as f:
        if name in f:
            del f[name]
        _write(f.create_group(name), data)


def _write(g, data: dict):
    for k, v in data.items():
        if isinstance(v, dict):
            _write(g.create_group(k), v)
        elif isinstance(v, np.ndarray) and v.dtype.kind in "fiub":
            g.create_dataset(k, data=v)
        else:
            g.attrs[k] = json.dumps(_jsonable(v))


def flat_samples(run: dict, burn_fraction: float = 0.25, thin: int = 1) -> np.ndarray:
    """Post-burn-in samples of a run (from :func:`load_run` or a SamplerResult), shape (n, ndim)."""
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


def priors_table(priors: dict[str, Prior], names) -> list[dict]:
    return [{"parameter": n, **{k: v for k, v in asdict(priors[n]).items() if v is not None}} for n in names]


__all__ = [
    "LogPosterior",
    "PRIORS_INFORMED",
    "PRIORS_WIDE",
    "PRIOR_SETS",
    "Prior",
    "ResumableHDFBackend",
    "SAMPLED",
    "SamplerResult",
    "StopRule",
    "diagnostics",
    "flat_samples",
    "load_run",
    "priors_table",
    "sample",
    "summarize",
    "write_group",
]
