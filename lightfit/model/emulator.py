r"""A polynomial emulator of the rendered light parts, and fast observables for MCMC.

Why it is exact enough: the renderer uses fixed random numbers for a given ``Scenario.seed`` and
a *frozen* sampling distribution, so each rendered part (incident / absorbed, sun / sky, per unit
DNI / DHI, per segment and daytime step) is a deterministic, smooth function of the three leaf
parameters :math:`x = (\mathrm{specular}, \mathrm{roughness}, \mathrm{subsurface})`. Every path
throughput is a product of BSDF lobe weights that are polynomials of low degree in specular and
subsurface (:mod:`lightfit.light.bsdf`), and depends smoothly on the GGX roughness. The emulator
is a total-degree Legendre polynomial in :math:`x` rescaled to the prior box

.. math:: \hat p_{k}(x) = \sum_{|\alpha| \le d} c_{k\alpha}\,P_{\alpha_1}(u_1)P_{\alpha_2}(u_2)P_{\alpha_3}(u_3),
    \qquad u = 2\,\frac{x - lo}{hi - lo} - 1,

fitted by least squares to full renders at a scrambled-Sobol design (one coefficient vector per
step × part × segment; the same design for all outputs, so one pseudo-inverse). The degree is
chosen by leave-one-out cross-validation (closed form via the hat matrix).

:class:`FastObservables` turns emulated parts into the model's observables with the same
formulas as :meth:`lightfit.model.coupled.CoupledModel.observe`, with one more speed-up:
the leaf photosynthesis of step ``t`` depends on the segment only through its absorbed PAR (same
air temperature, CO2, humidity and pressure for all blades), so it is solved exactly on a grid of
``n_grid`` absorbed-PAR values (dense at low light, :math:`q_g = q_{max}(g/(G-1))^2`) and
interpolated linearly in :math:`\sqrt q` for every blade. The combined error of both
approximations is measured against full renders + the full photosynthesis by :func:`validate`.
"""

from __future__ import annotations

import itertools
import json
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from lightfit.errors import InputError
from lightfit.light.estimator import PARTS
from lightfit.model.coupled import CoupledModel
from lightfit.model.parameters import Theta, as_theta
from lightfit.photosynthesis import solve

LEAF = ("specular", "roughness", "subsurface")


def exponents(degree: int) -> np.ndarray:
    """Multi-indices α with |α| ≤ degree in 3 variables, shape (n_terms, 3)."""
    return np.array([a for a in itertools.product(range(degree + 1), repeat=3) if sum(a) <= degree], dtype=np.int64)


def legendre_basis(u, expo: np.ndarray):
    """Products of Legendre polynomials P_α(u) for u of shape (..., 3) in [-1, 1] → (..., n_terms)."""
    u = jnp.asarray(u)
    n = int(expo.max()) + 1
    cols = [jnp.ones_like(u), u]
    for k in range(1, n - 1):
        cols.append(((2 * k + 1) * u * cols[k] - k * cols[k - 1]) / (k + 1))
    p = jnp.stack(cols[:n], axis=-1)  # (..., 3, n)
    return p[..., 0, expo[:, 0]] * p[..., 1, expo[:, 1]] * p[..., 2, expo[:, 2]]


def sobol_design(n: int, lo, hi, seed: int) -> np.ndarray:
    """``n`` scrambled-Sobol points in the box [lo, hi] (3 leaf parameters), explicit seed."""
    import warnings

    from scipy.stats import qmc

    s = qmc.Sobol(d=3, scramble=True, seed=np.random.default_rng(seed))
    with warnings.catch_warnings():  # balance needs n = 2^k; any n is fine for a regression design
        warnings.simplefilter("ignore", UserWarning)
        pts = s.random(n)
    return qmc.scale(pts, np.asarray(lo, float), np.asarray(hi, float))


def render_parts(model: CoupledModel, leaf, progress: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Full renders at each row of ``leaf`` (n, 3): values and SE, each (n, T_day, 4, S)."""
    leaf = np.atleast_2d(np.asarray(leaf, float))
    vals, ses = [], []
    bar = None
    if progress:
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

        bar = Progress(TextColumn("rendering design"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn())
        task = bar.add_task("r", total=len(leaf))
        bar.start()
    try:
        for x in leaf:
            v, s = model.parts(dict(zip(LEAF, x)))
            vals.append(np.asarray(v))
            ses.append(np.asarray(s))
            if bar:
                bar.update(task, advance=1)
    finally:
        if bar:
            bar.stop()
    return np.stack(vals), np.stack(ses)


@dataclass
class PartsEmulator:
    """Polynomial emulator of ``model.parts`` over the leaf-parameter box [lo, hi].

    Attributes:
        lo, hi: (3,) box of (specular, roughness, subsurface), the prior support.
        degree: total polynomial degree; ``expo`` its multi-indices.
        coef_values, coef_se: (n_terms, T_day, 4, S) coefficients of the parts and their MC SE
            (per unit DNI / DHI, dimensionless irradiance ratios).
        design: (n, 3) leaf parameters rendered; ``loo_rms``: leave-one-out RMS error of the
            parts per degree tried (per unit DNI/DHI), ``render_seconds`` the design's cost.
    """

    lo: np.ndarray
    hi: np.ndarray
    degree: int
    coef_values: np.ndarray
    coef_se: np.ndarray
    design: np.ndarray
    loo_rms: dict = field(default_factory=dict)
    render_seconds: float = float("nan")
    render_seed: int = 0

    @property
    def expo(self) -> np.ndarray:
        return exponents(self.degree)

    def basis(self, leaf):
        u = 2.0 * (jnp.asarray(leaf) - self.lo) / (self.hi - self.lo) - 1.0
        return legendre_basis(u, self.expo)

    def __call__(self, theta: Theta | Mapping[str, float]):
        """Emulated ``(values, se)``, each (T_day, 4, S) — a drop-in for ``model.parts``."""
        leaf = as_theta(theta).leaf
        b = self.basis(leaf)
        v = jnp.tensordot(b, jnp.asarray(self.coef_values), axes=1)
        s = jnp.tensordot(b, jnp.asarray(self.coef_se), axes=1)
        return v, jax.lax.stop_gradient(jnp.maximum(s, 0.0))

    # -- persistence -------------------------------------------------------------------
    def save(self, path: str | Path) -> Path:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        np.savez_compressed(
            path,
            lo=self.lo,
            hi=self.hi,
            degree=self.degree,
            coef_values=self.coef_values,
            coef_se=self.coef_se,
            design=self.design,
            render_seconds=self.render_seconds,
            render_seed=self.render_seed,
            loo_rms=json.dumps({str(k): v for k, v in self.loo_rms.items()}),
        )
        return path

    @staticmethod
    def load(path: str | Path) -> PartsEmulator:
        with np.load(path) as z:
            return PartsEmulator(
                lo=z["lo"],
                hi=z["hi"],
                degree=int(z["degree"]),
                coef_values=z["coef_values"],
                coef_se=z["coef_se"],
                design=z["design"],
                render_seconds=float(z["render_seconds"]),
                render_seed=int(z["render_seed"]),
                loo_rms={int(k): v for k, v in json.loads(str(z["loo_rms"])).items()},
            )


def fit_emulator(
    design, values, se, lo, hi, degrees=(1, 2, 3, 4, 5), render_seconds: float = float("nan"), render_seed: int = 0
) -> PartsEmulator:
    """Least-squares fit at the design; degree by leave-one-out RMS (degrees with ≤ 0.8 n terms)."""
    design = np.asarray(design, float)
    n = len(design)
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    y = np.asarray(values).reshape(n, -1)
    u = 2.0 * (design - lo) / (hi - lo) - 1.0
    loo, best = {}, None
    for d in degrees:
        expo = exponents(d)
        if len(expo) > 0.8 * n:
            continue
        phi = np.asarray(legendre_basis(u, expo))
        pinv = np.linalg.pinv(phi)
        h = np.einsum("ij,ji->i", phi, pinv)
        resid = y - phi @ (pinv @ y)
        loo[d] = float(np.sqrt(np.mean((resid / (1.0 - h)[:, None]) ** 2)))
        if best is None or loo[d] < loo[best]:
            best = d
    if best is None:
        raise InputError(f"n_design={n} is too small", column="n_design", expected="at least 5 design points")
    phi = np.asarray(legendre_basis(u, exponents(best)))
    pinv = np.linalg.pinv(phi)
    shape = np.asarray(values).shape[1:]
    cv = (pinv @ y).reshape((-1,) + shape)
    cs = (pinv @ np.asarray(se).reshape(n, -1)).reshape((-1,) + shape)
    return PartsEmulator(lo, hi, best, cv, cs, design, loo, render_seconds, render_seed)


def build_emulator(
    model: CoupledModel,
    lo=(0.0, 0.0, 0.0),
    hi=(1.0, 1.0, 1.0),
    *,
    n_design: int = 40,
    degrees=(1, 2, 3, 4, 5),
    seed: int = 0,
    progress: bool = False,
) -> PartsEmulator:
    """Render ``n_design`` Sobol points (seed ``seed``) of the box [lo, hi] and fit the emulator."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    if lo.shape != (3,) or hi.shape != (3,) or np.any(hi <= lo) or np.any(lo < 0) or np.any(hi > 1):
        raise InputError(
            f"emulator box lo={lo.tolist()}, hi={hi.tolist()}",
            column="specular, roughness, subsurface",
            expected="0 ≤ lo < hi ≤ 1 for each of the 3 leaf parameters",
        )
    design = sobol_design(n_design, lo, hi, seed)
    t0 = time.perf_counter()
    v, s = render_parts(model, design, progress)
    return fit_emulator(design, v, s, lo, hi, degrees, time.perf_counter() - t0, model.scenario.seed)


class FastObservables:
    """The observables of :meth:`CoupledModel.observe` from emulated parts; jit- and vmap-able.

    ``fast(theta)`` → dict of the :data:`~lightfit.model.coupled.OBSERVABLES` (each (T,)), as
    ``observe``. ``n_grid=None`` solves the photosynthesis of every blade (exact, slow for large
    fields); an integer tabulates it per step on that many absorbed-PAR values (see the module
    docstring).
    """

    def __init__(self, model: CoupledModel, emulator: PartsEmulator, n_grid: int | None = 64):
        self.model, self.emulator, self.n_grid = model, emulator, n_grid
        m = model
        self.day = np.flatnonzero(m.day)
        self.T = len(m.times)
        self.blades = np.flatnonzero(m.is_blade)
        kind = m.scenario.par_kind
        self.par_rows = (PARTS.index(f"{kind}_sun"), PARTS.index(f"{kind}_sky"))
        self.abs_rows = (PARTS.index("absorbed_sun"), PARTS.index("absorbed_sky"))
        rows = sorted(set(self.par_rows + self.abs_rows))
        self.rows = rows
        e = emulator
        if e.coef_values.shape[1:] != (len(self.day), len(PARTS), len(m.segment_id)):
            raise InputError(
                f"emulator shape {e.coef_values.shape[1:]} does not match the model "
                f"({len(self.day)} daytime steps, {len(m.segment_id)} segments)",
                column="emulator",
                expected="an emulator built for this model",
            )
        # Coefficients of the needed rows, flattened: (n_terms, T_day * n_rows * S).
        self._cv = jnp.asarray(e.coef_values[:, :, rows, :].reshape(len(e.coef_values), -1))
        self._cs = jnp.asarray(e.coef_se[:, :, rows, :].reshape(len(e.coef_se), -1))
        self._shape = (len(self.day), len(rows), len(m.segment_id))
        self._ri = {r: i for i, r in enumerate(rows)}

    def parts(self, theta: Theta | Mapping[str, float]):
        leaf = as_theta(theta).leaf
        b = self.emulator.basis(leaf)
        v = (b @ self._cv).reshape(self._shape)
        s = jax.lax.stop_gradient(jnp.maximum((b @ self._cs).reshape(self._shape), 0.0))
        return v, s

    def __call__(self, theta: Theta | Mapping[str, float]) -> dict:
        m = self.model
        th = as_theta(theta)
        v, s = self.parts(th)
        f = jnp.asarray(th.light_factor, jnp.float64)
        dni = f * jnp.asarray(m.dni_par[self.day])[:, None]
        dhi = f * jnp.asarray(m.dhi_par[self.day])[:, None]
        ri = self._ri

        def field(rows, arr):
            return dni * arr[:, ri[rows[0]]] + dhi * arr[:, ri[rows[1]]]

        def se(rows):
            return jnp.sqrt((dni * s[:, ri[rows[0]]]) ** 2 + (dhi * s[:, ri[rows[1]]]) ** 2)

        day = self.day
        w = jnp.asarray(m.area_m2 / m.area_m2.sum())
        par_d, par_se_d = field(self.par_rows, v), se(self.par_rows)
        par_mean = jnp.zeros(self.T).at[day].set(par_d @ w)
        par_sd = jnp.zeros(self.T).at[day].set(jnp.sqrt(jnp.maximum((par_d - (par_d @ w)[:, None]) ** 2 @ w, 0.0)))
        par_mc_var = jnp.zeros(self.T).at[day].set((par_se_d**2) @ (w**2))
        b = self.blades
        q = jnp.zeros((self.T, len(b))).at[day].set(jnp.maximum(field(self.abs_rows, v)[:, b], 0.0))
        q_se = jnp.zeros((self.T, len(b))).at[day].set(se(self.abs_rows)[:, b])
        params = eqx.tree_at(
            lambda p: p.fvcb.vcmax_ref_umol_m2_s,
            m.params,
            m.params.fvcb.vcmax_ref_umol_m2_s * jnp.asarray(th.vcmax_scale, jnp.float64),
        )
        an_leaf, dan = self._leaf(q, params)
        a_leaf = jnp.asarray(m.area_m2[b])
        denom = a_leaf.sum() if m.scenario.an_per == "leaf" else m.ground_area_m2
        an = an_leaf @ a_leaf / denom
        an_mc_var = (jax.lax.stop_gradient(dan) * q_se) ** 2 @ (a_leaf / denom) ** 2
        return {
            "plant_par_umol_m2_s": par_mean,
            "plant_par_spread_umol_m2_s": par_sd,
            "plant_par_mc_sd_umol_m2_s": jax.lax.stop_gradient(jnp.sqrt(par_mc_var)),
            "canopy_an_umol_m2_s": an,
            "canopy_an_mc_sd_umol_m2_s": jax.lax.stop_gradient(jnp.sqrt(an_mc_var)),
        }

    def _env(self, shape):
        m = self.model
        return [jnp.broadcast_to(jnp.asarray(x)[:, None], shape) for x in (m.tair_c, m.co2_ppm, m.rh, m.pair_kpa)]

    def _leaf(self, q, params):
        """Per-blade net assimilation and dAn/dq (T, B): exact, or tabulated per step."""
        if self.n_grid is None:
            t_c, co2, rh, p = self._env(q.shape)
            res = solve(q, t_c, co2, rh, p, params)
            _, dan = jax.jvp(lambda x: solve(x, t_c, co2, rh, p, params).an_umol_m2_s, (q,), (jnp.ones_like(q),))
            return res.an_umol_m2_s, dan
        G = self.n_grid
        qmax = jnp.maximum(jnp.max(q, axis=1), 1e-6) * (1.0 + 1e-9)  # (T,)
        g = jnp.linspace(0.0, 1.0, G)
        qg = qmax[:, None] * g[None, :] ** 2
        t_c, co2, rh, p = self._env(qg.shape)
        an_g = solve(qg, t_c, co2, rh, p, params).an_umol_m2_s
        _, dan_g = jax.jvp(lambda x: solve(x, t_c, co2, rh, p, params).an_umol_m2_s, (qg,), (jnp.ones_like(qg),))
        x = jnp.sqrt(jnp.clip(q / qmax[:, None], 0.0, 1.0)) * (G - 1)
        i = jnp.clip(jnp.floor(x).astype(jnp.int32), 0, G - 2)
        frac = x - i
        take = jax.vmap(lambda a, j: a[j])
        an = (1 - frac) * take(an_g, i) + frac * take(an_g, i + 1)
        dan = (1 - frac) * take(dan_g, i) + frac * take(dan_g, i + 1)
        return an, dan


#: Observables whose emulation error :func:`validate` reports (``err_<name>``, ``full_<name>``).
VALIDATED = ("plant_par_umol_m2_s", "canopy_an_umol_m2_s")


def validate(
    model: CoupledModel,
    fast: FastObservables,
    leaf_test,
    theta_extra: dict | None = None,
    full: tuple[np.ndarray, np.ndarray] | None = None,
    progress: bool = False,
) -> dict:
    """Error of ``fast`` against full renders + exact photosynthesis at held-out leaf parameters.

    Args:
        leaf_test: (n, 3) held-out (specular, roughness, subsurface).
        theta_extra: values of light_factor / vcmax_scale used for the comparison.
        full: precomputed ``render_parts(model, leaf_test)`` (else rendered here).

    Returns a dict with, per observable, the (n, T) errors ``err_<obs>`` (emulated − full, in the
    observable's unit) and the full values ``full_<obs>``, and ``parts_rms``/``parts_max``
    (per unit DNI/DHI).
    """
    leaf_test = np.atleast_2d(np.asarray(leaf_test, float))
    if full is None:
        full = render_parts(model, leaf_test, progress)
    out = {k: [] for k in ("err_" + o for o in VALIDATED)}
    out.update({"full_" + o: [] for o in VALIDATED})
    parts_err = []
    fast_j = jax.jit(fast)
    for x, v, s in zip(leaf_test, *full):
        th = as_theta(theta_extra).replace(**dict(zip(LEAF, x)))
        # exact observables from the full render (observe with the render replaced by its result)
        ref = _observe_with_parts(model, th, v, s)
        emu = fast_j(th)
        ev, _ = fast.emulator(th)
        parts_err.append(np.asarray(ev) - v)
        for o in VALIDATED:
            out["err_" + o].append(np.asarray(emu[o]) - np.asarray(ref[o]))
            out["full_" + o].append(np.asarray(ref[o]))
    res = {k: np.asarray(v) for k, v in out.items()}
    pe = np.asarray(parts_err)
    res["parts_rms"] = float(np.sqrt(np.mean(pe**2)))
    res["parts_max"] = float(np.max(np.abs(pe)))
    res["leaf_test"] = leaf_test
    return res


class _PartsModel(CoupledModel):
    """A CoupledModel whose ``parts`` come from a callable (emulator or stored renders)."""

    def __init__(self, model: CoupledModel, parts_fn):  # noqa: D107 — no geometry rebuild
        self.__dict__.update(model.__dict__)
        self._parts_fn = parts_fn

    def parts(self, theta):
        return self._parts_fn(theta)


def emulated_model(model: CoupledModel, emulator: PartsEmulator) -> CoupledModel:
    """``model`` with its renders replaced by the emulator.

    ``observe`` / ``simulate`` / ``make_loss`` work unchanged.
    """
    return _PartsModel(model, emulator)


def _observe_with_parts(model: CoupledModel, theta: dict, values, se) -> dict:
    return _PartsModel(model, lambda th: (jnp.asarray(values), jnp.asarray(se))).observe(theta)


__all__ = [
    "FastObservables",
    "LEAF",
    "PartsEmulator",
    "build_emulator",
    "emulated_model",
    "exponents",
    "fit_emulator",
    "legendre_basis",
    "render_parts",
    "sobol_design",
    "validate",
    "VALIDATED",
]
