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

:class:`FastObservables` turns emulated parts into the model's observables through the model's
own observation operator (:mod:`lightfit.model.observe`), with one more speed-up: the leaf
photosynthesis is tabulated per step (:func:`lightfit.model.observe.tabulated_leaf`). The combined
error of both approximations is measured against full renders + the full photosynthesis by :func:`validate`.

Caching (:func:`cached_emulator`): every finished design render is kept on disk as soon as it is
done (one file per leaf-parameter point, named by a hash of :func:`render_key` and the point), so a
design killed half-way renders only its missing points when rerun. The fitted emulator is stored
with its :func:`emulator_key` — design size and seed, box, degrees and the render key (scene,
field geometry, optics, estimator settings, sun positions and times, lightfit/Mitsuba versions) —
and reused only when the key matches; otherwise it is refitted, saying which entries changed.

Shared design cache (:func:`lightfit.cache.cache_root`, :func:`design_dir`): ``lightfit calibrate`` and ``lightfit
posterior`` keep their design renders and fitted emulators in one directory per render key,
``<cache>/designs/<hash of render_key>/`` with ``<cache>`` = ``$LIGHTFIT_CACHE`` or
``~/.cache/lightfit``, so a calibration followed by a posterior of the same configuration renders
nothing new. :func:`restrict` cuts a model down to the steps that observations need, so that only
those sun positions are rendered (and keyed).
"""

from __future__ import annotations

import dataclasses
import hashlib
import itertools
import json
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from lightfit.cache import cache_root
from lightfit.defaults import DESIGN_SIZE
from lightfit.errors import InputError, check_integer
from lightfit.files import UNREADABLE_NPZ, load_npz, replace_text, replaced
from lightfit.killpoint import kill_point
from lightfit.light.backend import package_versions
from lightfit.light.bsdf import LEAF_PARAMETERS
from lightfit.light.estimator import ESTIMATOR_VERSION, PARTS
from lightfit.light.projection import PROJECTION_VERSION
from lightfit.light.sensors import DEFAULT_SENSOR_SAMPLES
from lightfit.model.coupled import CoupledModel
from lightfit.model.observe import CONVERGENCE_KEY, OBSERVABLES, exact_leaf, tabulated_leaf
from lightfit.model.parameters import Theta, as_theta
from lightfit.model.scenario import adaptive_limits, projected_rays
from lightfit.progress import progress_bar

#: Polynomial degrees tried by leave-one-out cross-validation (those with ≤ 0.8 n_design terms).
DEGREES = (1, 2, 3, 4, 5)
#: Scramble seed of the design's Sobol points, and of the posterior's held-out check points (another
#: scramble, so that they fall between the design's).
DESIGN_SEED, HELD_OUT_SEED = 0, 1
#: Progress labels of the design's renders and of the held-out ones (which the design's label made
#: read as the design's own).
DESIGN_LABEL, HELD_OUT_LABEL = "rendering design", "rendering held-out check"


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


def _digest(*arrays) -> str:
    h = hashlib.sha256()
    for a in arrays:
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()[:16]


def code_versions() -> dict[str, object]:
    """The versions a render's values depend on: lightfit's, the estimator's
    (:data:`~lightfit.light.estimator.ESTIMATOR_VERSION`), Mitsuba's and Dr.Jit's
    (:func:`package_versions`)."""
    from lightfit import __version__

    return {"lightfit": __version__, "estimator": ESTIMATOR_VERSION, **package_versions("mitsuba", "drjit")}


def run_versions() -> dict[str, object]:
    """The versions a run's results depend on: :func:`code_versions`, the projection's
    (:data:`~lightfit.light.projection.PROJECTION_VERSION`), JAX's and jaxlib's, CPlantBox's (the
    plants) and pvlib's (the sun and the direct/diffuse split). Results record them
    (``software_versions``), field-run's kept tasks are keyed by them."""
    return {
        **code_versions(),
        "projection": PROJECTION_VERSION,
        **package_versions("jax", "jaxlib", "cplantbox", "pvlib"),
    }


def render_key(model: CoupledModel) -> dict:
    """Everything a full render of ``model`` depends on besides the three leaf parameters: estimator
    settings (samples, bounces, seed; when adaptive the target, the cap and the allocation point; the projection and its
    rays when the direct light is projected), sky, optics, the field
    (plants, growth parameter file, boundary) and its geometry (hash of the segment table), the
    measured segments, the rendered (daytime) steps' times and sun positions, and the lightfit, estimator
    (:data:`~lightfit.light.estimator.ESTIMATOR_VERSION`), Mitsuba and Dr.Jit versions. JSON-ready."""
    import pandas as pd

    sc = model.scenario
    day = np.asarray(model.day, bool)
    # Not the Mitsuba variant nor the CPU target: the client keys renders its workers make, in
    # their own variant (docs/light.md, "CPU targets": what a GPU's renders differ by).
    return {
        **code_versions(),
        "samples": int(sc.samples),
        "bounces": int(sc.bounces),
        "render_seed": int(sc.seed),
        "sky": sc.sky,
        "n_tiles": int(sc.n_tiles),
        "tile": sc.tile,
        "optics": repr(sc.optics),
        "field": repr(sc.field),
        "growth": sc.field.growth.fingerprint(),
        "geometry": _digest(pd.util.hash_pandas_object(model.geometry.segments, index=True).to_numpy()),
        "segments": _digest(np.asarray(model.segment_id, np.int64)),
        "sensors": [[x.name, _digest(np.concatenate(x.lines()))] for x in model.sensors],
        "sensor_samples": DEFAULT_SENSOR_SAMPLES,
        # The rendered steps only: a render is one array per daytime step, each a function of its
        # sun alone; steps kept but not rendered (night, or the above-canopy sensor's) made a
        # second design of the same renders (a review).
        "times_utc": [str(x) for x in model.times.tz_convert("UTC")[day]],
        "sun": _digest(np.asarray(model.sun_deg, np.float64)[day]),
        # Adaptive sampling only: absent at a fixed K, so the keys of fixed-K caches stay as they were.
        **({} if sc.target_rse is None else _allocation_key(model)),
        # Projected direct light only: absent with the paths' (the keys of earlier caches); the
        # projection's version from its second on (keys made with the first lack it).
        **(
            {}
            if (rays := projected_rays(sc.direct, sc.direct_rays_per_m2)) is None
            else {"direct": sc.direct, "direct_rays_per_m2": rays, "projection_version": PROJECTION_VERSION}
        ),
    }


def _allocation_key(model: CoupledModel) -> dict:
    """What fixes an adaptive allocation (``Scenario.target_rse``): the target, the cap, and the
    point it is chosen at (:attr:`CoupledModel.allocation_point`: leaf, sun, the PAR weighting the
    sun and sky parts), so renders made under another allocation are not reused."""
    leaf, sun, dni, dhi = model.allocation_point
    return {
        "target_rse": float(model.scenario.target_rse),
        **adaptive_limits(),
        "allocated_at": {
            "leaf": [float(x) for x in leaf],
            "sun_deg": [float(x) for x in sun],
            "dni_dhi_par": [dni, dhi],
        },
    }


#: Renders done by this process (``"rendered"``: new full renders; ``"cached"``: read from a render
#: cache instead) and fitted emulators loaded whole (``"reused"``: :func:`cached_emulator` found one
#: of the same key). Counted, so that tests and the command line can say what a design cost.
COUNTS = {"rendered": 0, "cached": 0, "reused": 0}


def render_file(cache: str | Path, key: dict, leaf) -> Path:
    """The file in which :func:`render_parts` keeps the render at ``leaf`` (3,) of a model whose
    :func:`render_key` is ``key``, in the render directory ``cache`` (whether or not it exists yet).
    Another process that fills the cache (:mod:`lightfit.distributed.design`) finds it here."""
    text = json.dumps(key, sort_keys=True)
    return Path(cache) / f"{_digest(text.encode(), np.asarray(leaf, np.float64))}.npz"


#: Signature of the ``render_points`` hook of :func:`build_emulator`: ``(model, leaf (n, 3), render
#: directory, render_key(model)) -> Any``, and by keyword ``label=`` (its progress line's: the
#: posterior's held-out renders pass :data:`HELD_OUT_LABEL`); it makes sure each point's render is in
#: the directory (e.g. :func:`lightfit.distributed.design.render_design` on a Dask cluster).
RenderPoints = Callable[..., object]


def render_parts(
    model: CoupledModel,
    leaf,
    progress: bool = False,
    cache: str | Path | None = None,
    key: dict | None = None,
    label: str = DESIGN_LABEL,
) -> tuple[np.ndarray, np.ndarray]:
    """Full renders at each row of ``leaf`` (n, 3): values and SE, each (n, T_day, 4, S).

    ``cache``: a directory keeping each finished render (``<hash>.npz``, written atomically): points
    already there are read instead of rendered. ``key``: :func:`render_key` of ``model`` if already
    computed. ``label``: the progress line's, for renders that are not a design's.
    """
    v, s, _ = _render_parts(model, leaf, progress, cache, key, label)
    return v, s


def _render_parts(model, leaf, progress, cache, key, label) -> tuple[np.ndarray, np.ndarray, float]:
    """:func:`render_parts` and the summed render time of the points, s (stored with each render, so
    it is the same whether a point was rendered now or read from the cache)."""
    leaf = np.atleast_2d(np.asarray(leaf, float))
    if len(leaf) == 0:
        raise InputError(
            "no points to render", parameter="leaf", expected="at least one (specular, roughness, subsurface)"
        )
    if not np.asarray(model.day).any():  # no step needs the light at the plants (see restrict): nothing to render
        empty = np.zeros((len(leaf), 0, len(PARTS), model.n_columns))
        return empty, empty.copy(), 0.0
    cache = None if cache is None else Path(cache)
    rkey = json.dumps(key or render_key(model), sort_keys=True) if cache is not None else ""
    key = key or render_key(model) if cache is not None else None
    files = [None if cache is None else render_file(cache, key, x) for x in leaf]
    vals, ses, secs = [None] * len(leaf), [None] * len(leaf), [0.0] * len(leaf)
    todo, first = [], {}  # points to render; the first index of each cache file among them
    cached = 0
    for i, file in enumerate(files):
        if file is not None and (stored := _stored_render(file)) is not None:
            vals[i], ses[i], secs[i] = stored
            COUNTS["cached"] += 1
            cached += 1
        elif file is None or file not in first:
            todo.append(i)
            first[file] = i
    done = len(leaf) - len(todo)  # a point repeated in ``leaf`` is done with its first
    label += f" ({cached} of {len(leaf)} from the cache)" if cached else ""  # a rerun says so
    with progress_bar(label, len(leaf), completed=done, show=progress) as bar:
        # All missing points in one batch (CoupledModel.render_many: the paths are traced once and
        # weighed at every point); each point is stored as soon as it is done, so a design killed
        # half-way keeps its finished renders. A point's seconds are the time since the previous
        # one (the first carries the shared tracing).
        t0 = time.perf_counter()
        renders = model.render_many([dict(zip(LEAF_PARAMETERS, leaf[i])) for i in todo]) if todo else ()
        for fresh, (i, (v, s)) in enumerate(zip(todo, renders), start=1):
            dt = time.perf_counter() - t0
            file = files[i]
            if file is not None:
                file.parent.mkdir(parents=True, exist_ok=True)
                with replaced(file) as tmp:  # a kill leaves the render either whole or absent
                    np.savez(tmp, values=v, se=s, seconds=dt, leaf=leaf[i], key=rkey)
            COUNTS["rendered"] += 1
            kill_point("render", fresh)
            vals[i], ses[i], secs[i] = v, s, dt
            bar.update(completed=done + fresh)
            t0 = time.perf_counter()
    for i, file in enumerate(files):  # a point repeated in ``leaf``: its render, as if read from the cache
        if vals[i] is None:
            j = first[file]
            vals[i], ses[i], secs[i] = vals[j], ses[j], secs[j]
            COUNTS["cached"] += 1
    seconds = float(sum(secs))
    return np.stack(vals), np.stack(ses), seconds


def _stored_render(file: Path) -> tuple[np.ndarray, np.ndarray, float] | None:
    """The render kept in ``file`` (values, SE, seconds), or None if there is none or it cannot be
    read: a file damaged outside lightfit (a cut copy, a full disk, a byte flipped) is rendered
    again and replaced, as the plant cache's and a fitted emulator's are; it stopped every rerun
    with a BadZipFile or EOFError traceback."""
    if not file.exists():
        return None
    try:
        with load_npz(file) as z:
            return z["values"], z["se"], float(z["seconds"])
    except UNREADABLE_NPZ:
        return None


def in_box(x, lo, hi) -> np.ndarray:
    """Elementwise: ``x`` inside [``lo``, ``hi``] up to round-off (10⁻⁹ of the box's width: a point
    computed on a face may lie a hair outside). The one test of "may the emulator be evaluated
    there" (:meth:`PartsEmulator.check_in_box`, the posterior's priors and fixed values)."""
    x, lo, hi = (np.asarray(v, np.float64) for v in (x, lo, hi))
    tol = 1e-9 * (hi - lo)
    return (x >= lo - tol) & (x <= hi + tol)


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
    key: dict = field(default_factory=dict)

    @property
    def expo(self) -> np.ndarray:
        return exponents(self.degree)

    def basis(self, leaf):
        self.check_in_box(leaf)
        u = 2.0 * (jnp.asarray(leaf) - self.lo) / (self.hi - self.lo) - 1.0
        return legendre_basis(u, self.expo)

    def check_in_box(self, leaf) -> None:
        """Refuse concrete leaf parameters outside [lo, hi]: the polynomial would extrapolate
        silently (far outside, the emulated light goes negative). Traced values (inside
        ``jax.jit``/``grad``) cannot be checked here; their callers keep them in the box (the
        priors' support, bounded optimisers)."""
        if isinstance(leaf, jax.core.Tracer):
            return
        x = np.asarray(leaf, np.float64)
        out = np.argwhere(~in_box(x, self.lo, self.hi))  # points (n, 3) too: a flat index named no parameter
        if len(out):
            at, i = tuple(out[0]), int(out[0][-1])
            raise InputError(
                f"{LEAF_PARAMETERS[i]}={x[at]:.6g} outside the emulator's box [{self.lo[i]:.6g}, {self.hi[i]:.6g}]"
                + (f" (point {out[0][0]})" if x.ndim > 1 else ""),
                parameter=LEAF_PARAMETERS[i],
                expected="leaf parameters inside the box the emulator was fitted on (or an emulator fitted on a "
                "box that holds them)",
            )

    def __call__(self, theta: Theta | Mapping[str, float]):
        """Emulated ``(values, se)``, each (T_day, 4, S) — a drop-in for ``model.parts``.

        Both are irradiance ratios, ≥ 0: the polynomial can dip below 0 near the box's corners
        for a dim segment (a part of 0.031 ± 0.0004 per unit DNI emulated as −0.053 at specular 0,
        roughness 1, subsurface 1; 1 plant, K = 8, degree 3 on [0, 1]³), and is cut at 0 there."""
        leaf = as_theta(theta).leaf
        b = self.basis(leaf)
        v = jnp.tensordot(b, jnp.asarray(self.coef_values), axes=1)
        s = jnp.tensordot(b, jnp.asarray(self.coef_se), axes=1)
        return jnp.maximum(v, 0.0), jax.lax.stop_gradient(jnp.maximum(s, 0.0))

    # -- persistence -------------------------------------------------------------------
    def save(self, path: str | Path) -> Path:
        """Write the emulator at ``path`` (``.npz`` added if the name lacks it, as numpy does);
        return the path written."""
        path = Path(path)
        if path.suffix != ".npz":
            path = path.with_name(path.name + ".npz")
        path.parent.mkdir(parents=True, exist_ok=True)
        with replaced(path) as tmp:
            self._write(tmp)
        return path

    def _write(self, path: Path) -> None:
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
            key=json.dumps(self.key, sort_keys=True),
        )

    @staticmethod
    def readable(path: str | Path, say: Callable[[str], None]) -> PartsEmulator | None:
        """The emulator at ``path``, or None (said) if the file cannot be read: an older lightfit
        wrote emulators in place, so a run killed while saving left a cut file that stopped every
        rerun with a BadZipFile; such a file is rebuilt like one of other settings."""
        try:
            return PartsEmulator.load(path)
        except UNREADABLE_NPZ as err:
            say(f"emulator {path} cannot be read ({type(err).__name__}: {err}): rebuilding")
            return None

    @staticmethod
    def load(path: str | Path) -> PartsEmulator:
        with load_npz(path) as z:
            key = json.loads(str(z["key"])) if "key" in z else {}
            if not isinstance(key, dict):  # a foreign file's: key_changes stopped with an AttributeError
                raise ValueError(f"{path}: its key is a JSON {type(key).__name__}, not an object")
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
                key=key,
            )


def fit_emulator(
    design, values, se, lo, hi, degrees=DEGREES, render_seconds: float = float("nan"), render_seed: int = 0
) -> PartsEmulator:
    """Least-squares fit at the design; degree by leave-one-out RMS (degrees with ≤ 0.8 n terms)."""
    degrees = check_degrees(degrees)
    design = np.asarray(design, float)
    n = len(design)
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    y = np.asarray(values).reshape(n, -1)
    bad = ~(np.isfinite(y).all(1) & np.isfinite(np.asarray(se).reshape(n, -1)).all(1))
    if bad.any():  # every leave-one-out RMS was NaN and the first degree was kept unsaid (a review)
        i = int(np.flatnonzero(bad)[0])
        raise InputError(
            f"{int(bad.sum())} design render(s) not finite, the first at point {i} {design[i].tolist()}",
            parameter="values",
            expected="finite rendered parts and SEs at every design point",
        )
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
        check_design_size(n)  # too few for any degree
        raise InputError(
            f"n_design={n}: no polynomial degree fits", parameter="n_design", expected="more design points"
        )
    phi = np.asarray(legendre_basis(u, exponents(best)))
    pinv = np.linalg.pinv(phi)
    shape = np.asarray(values).shape[1:]
    cv = (pinv @ y).reshape((-1,) + shape)
    cs = (pinv @ np.asarray(se).reshape(n, -1)).reshape((-1,) + shape)
    return PartsEmulator(lo, hi, best, cv, cs, design, loo, render_seconds, render_seed)


def checked_extra(extra, lo, hi) -> np.ndarray:
    """``extra`` design points as an (m, 3) float array, each inside the box [lo, hi], else
    :class:`InputError` naming ``extra``: a point outside was rendered and fitted, bending the
    polynomial to a place it is never evaluated (a review)."""
    try:
        x = np.asarray(extra, float).reshape(-1, 3)
    except (TypeError, ValueError):
        raise InputError(
            f"extra of shape {np.shape(extra)}", parameter="extra", expected="(m, 3) leaf parameters"
        ) from None
    out = ~(np.isfinite(x) & in_box(x, lo, hi)).all(1)  # a trust region's optimum on a face may lie a hair out
    if out.any():
        raise InputError(
            f"extra point {x[out][0].tolist()}",
            parameter="extra",
            expected=f"inside the emulator's box [{lo.tolist()}, {hi.tolist()}]",
        )
    return x


def build_emulator(
    model: CoupledModel,
    lo=(0.0, 0.0, 0.0),
    hi=(1.0, 1.0, 1.0),
    *,
    n_design: int = DESIGN_SIZE,
    degrees=DEGREES,
    seed: int = DESIGN_SEED,
    progress: bool = False,
    cache: str | Path | None = None,
    extra=None,
    render_points: RenderPoints | None = None,
) -> PartsEmulator:
    """Render ``n_design`` Sobol points (seed ``seed``) of the box [lo, hi] and fit the emulator.
    ``cache``: directory keeping each finished render (see :func:`render_parts`); the emulator's
    :attr:`~PartsEmulator.key` is then its :func:`emulator_key`. ``extra``: (m, 3) further points
    rendered and fitted after the Sobol design (the trust-region calibration's renders at its
    candidate optima, :mod:`lightfit.inference.trust_region`). ``render_points``: renders the design
    into ``cache`` elsewhere first (:data:`RenderPoints`; needs ``cache``); the fit then reads every
    point from the cache, and renders here only what the hook left missing."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    # written as what must hold: a NaN bound fails it (NaN compares false both ways; it reached scipy's
    # "Bounds are not consistent" ValueError)
    if lo.shape != (3,) or hi.shape != (3,) or not np.all((0 <= lo) & (lo < hi) & (hi <= 1)):
        raise InputError(
            f"emulator box lo={lo.tolist()}, hi={hi.tolist()}",
            parameter="specular, roughness, subsurface",
            expected="0 ≤ lo < hi ≤ 1 for each of the 3 leaf parameters",
        )
    degrees = check_degrees(degrees)  # before any render
    n_design = check_design_size(n_design)
    design = sobol_design(n_design, lo, hi, seed)
    if extra is not None and len(extra):
        design = np.concatenate([design, checked_extra(extra, lo, hi)])
    rkey = render_key(model) if cache is not None else None
    if render_points is not None:
        if cache is None:
            raise InputError(
                "render_points without a cache", parameter="cache", expected="the render directory the hook fills"
            )
        render_points(model, design, Path(cache), rkey)  # with its own progress: reading them back is not news
    v, s, seconds = _render_parts(model, design, progress and render_points is None, cache, rkey, DESIGN_LABEL)
    if v.shape[1] == 0:  # nothing rendered (no step needs it): the constant zero, exact
        z = np.zeros((1, *v.shape[1:]))
        emu = PartsEmulator(lo, hi, 0, z, z.copy(), design, {}, 0.0, model.scenario.seed)
    else:
        emu = fit_emulator(design, v, s, lo, hi, degrees, seconds, model.scenario.seed)
    if rkey is not None:
        emu.key = emulator_key(rkey, lo, hi, n_design, seed, degrees, extra)
    return emu


def emulator_key(render: dict, lo, hi, n_design: int, seed: int, degrees, extra=None) -> dict:
    """What a fitted emulator depends on: the :func:`render_key` of its model, the box, the design
    size and seed, the degrees tried and the extra design points if any (JSON-ready)."""
    key = {
        "n_design": int(n_design),
        "design_seed": int(seed),
        "lo": [float(v) for v in np.asarray(lo, float)],
        "hi": [float(v) for v in np.asarray(hi, float)],
        "degrees": [int(d) for d in degrees],
        **render,
    }
    if extra is not None and len(extra):  # absent when none: keys of plain Sobol designs stay as they were
        key["extra"] = [[float(v) for v in x] for x in np.asarray(extra, float).reshape(-1, 3)]
    return key


def key_changes(before: dict, now: dict) -> list[str]:
    """``"entry: before → now"`` for each entry of two cache keys that differs (long values shortened,
    from where they differ when their first characters are the same: the optics' or the field's
    repr cut at 37 characters read the same on both sides, naming no change; a review)."""

    def short(v, start=0):
        s = repr(v)
        s = s if start == 0 else "…" + s[start:]
        return s if len(s) <= 40 else s[:37] + "…"

    def change(a, b):
        if short(a) != short(b):
            return f"{short(a)} → {short(b)}"
        ra, rb = repr(a), repr(b)
        common = next((i for i, (x, y) in enumerate(zip(ra, rb)) if x != y), min(len(ra), len(rb)))
        start = max(ra.rfind(" ", 0, common) + 1, common - 24, 1)  # from the word that differs
        return f"{short(a, start)} → {short(b, start)}"

    return [f"{k}: {change(before.get(k), now.get(k))}" for k in now if before.get(k) != now.get(k)] + [
        f"{k}: {short(before[k])} → None" for k in before if k not in now
    ]


def cached_emulator(
    model: CoupledModel,
    path: str | Path,
    lo,
    hi,
    *,
    n_design: int = DESIGN_SIZE,
    degrees=DEGREES,
    seed: int = DESIGN_SEED,
    progress: bool = False,
    say: Callable[[str], None] = print,
    renders: str | Path | None = None,
    extra=None,
    render_points: RenderPoints | None = None,
) -> PartsEmulator:
    """The emulator stored at ``path`` if its key is this model's and these settings'
    (:func:`emulator_key`), else built (renders kept in ``renders``, default ``<path's
    folder>/renders``, so an interrupted design continues where it stopped) and stored. A stored
    emulator that does not match is reported through ``say`` (one line naming the changed entries)
    before the rebuild. ``extra``, ``render_points``: see :func:`build_emulator`."""
    path = Path(path)
    rkey = render_key(model)
    key = emulator_key(rkey, lo, hi, n_design, seed, degrees, extra)
    old = PartsEmulator.readable(path, say) if path.exists() else None
    if old is not None:
        if old.key == key:
            COUNTS["reused"] += 1  # fitted before: neither rendered nor read, said by the caller
            return old
        changes = key_changes(old.key, key) if old.key else ["no key (written by an older lightfit)"]
        say(f"emulator {path} was built for other settings ({'; '.join(changes)}): rebuilding")
    emu = build_emulator(
        model,
        lo,
        hi,
        n_design=n_design,
        degrees=degrees,
        seed=seed,
        progress=progress,
        cache=Path(renders) if renders is not None else path.parent / "renders",
        extra=extra,
        render_points=render_points,
    )
    emu.save(path)
    return emu


#: Fewest design renders an emulator is fitted from (the smallest polynomial degree needs them).
MIN_DESIGN_SIZE = 5


def check_degrees(degrees) -> tuple[int, ...]:
    """The polynomial degrees to try: a non-empty sequence of integers ≥ 0, checked before any
    render (:func:`build_emulator`) and by :func:`fit_emulator`."""
    expected = "a non-empty sequence of integers ≥ 0 (total polynomial degrees to try, e.g. (1, 2, 3))"
    items = None if isinstance(degrees, (str, bytes)) or not hasattr(degrees, "__iter__") else list(degrees)
    if not items:
        raise InputError(f"degrees={degrees!r}", parameter="degrees", expected=expected)
    return tuple(check_integer(d, "degrees", 0, expected=expected) for d in items)


def check_design_size(n) -> int:
    """Design renders: an integer ≥ :data:`MIN_DESIGN_SIZE`, checked before any is rendered."""
    return check_integer(n, "n_design", MIN_DESIGN_SIZE, why="design points an emulator is fitted from")


def design_dir(model: CoupledModel, cache: str | Path | None = None, key: dict | None = None) -> Path:
    """``<cache>/designs/<hash of render_key(model)>``: where every render and fitted emulator of
    this configuration is kept, whichever command made it. The key itself is written next to them
    (``render_key.json``) so that a directory can be told apart by reading it."""
    key = key or render_key(model)
    text = json.dumps(key, sort_keys=True)
    d = cache_root(cache) / "designs" / _digest(text.encode())
    if not (d / "render_key.json").exists():
        d.mkdir(parents=True, exist_ok=True)
        replace_text(d / "render_key.json", json.dumps(key, indent=2, sort_keys=True))
    return d


def shared_emulator(
    model: CoupledModel,
    lo,
    hi,
    *,
    n_design: int = DESIGN_SIZE,
    degrees=DEGREES,
    seed: int = DESIGN_SEED,
    extra=None,
    cache: str | Path | None = None,
    progress: bool = False,
    say: Callable[[str], None] = print,
    render_points: RenderPoints | None = None,
) -> PartsEmulator:
    """:func:`cached_emulator` in the shared cache: renders in ``design_dir(model)/renders``, the fitted
    emulator in ``design_dir(model)/emulator-<hash of its key>.npz`` (one file per design, so the
    calibration's refined design and the posterior's plain one do not overwrite each other)."""
    rkey = render_key(model)
    d = design_dir(model, cache, rkey)
    key = emulator_key(rkey, lo, hi, n_design, seed, degrees, extra)
    path = d / f"emulator-{_digest(json.dumps(key, sort_keys=True).encode())}.npz"
    return cached_emulator(
        model,
        path,
        lo,
        hi,
        n_design=n_design,
        degrees=degrees,
        seed=seed,
        progress=progress,
        say=say,
        renders=d / "renders",
        extra=extra,
        render_points=render_points,
    )


def restrict(model: CoupledModel, keep, rendered=None) -> CoupledModel:
    """``model`` on the steps ``keep`` (T,) bool only, rendering only the steps ``rendered`` of them.

    Observations need only some steps: a step without any observation needs nothing, and a step
    whose observed series do not depend on the light at the plants (the above-canopy sensor,
    :func:`~lightfit.model.observe.above_canopy_par`, is analytic) needs no render. The returned
    model (geometry, scene and photosynthesis shared) has ``times``, forcing and sun positions of the
    kept steps, and its daytime mask ``day`` is ``day & rendered``: steps kept but not rendered get
    zero light at the plants, like the night, so *their* plant observables are not the model's
    (they are not observed). Its :func:`render_key` names only the rendered sun positions, so
    renders are cached per set of needed steps. ``rendered=None``: every kept daytime step.
    """
    keep = np.asarray(keep, bool)
    if keep.shape != model.day.shape or not keep.any():
        raise InputError(
            f"steps to keep: {int(keep.sum())} of shape {keep.shape}",
            parameter="steps",
            expected=f"a boolean mask over the run's {len(model.day)} steps with at least one step",
        )
    rendered = keep if rendered is None else np.asarray(rendered, bool) & keep
    day = (model.day & rendered)[keep]
    fc = model.forcing
    forcing = dataclasses.replace(
        fc,
        day=day,
        **{f.name: np.asarray(getattr(fc, f.name))[keep] for f in dataclasses.fields(fc) if f.name != "day"},
    )
    other = model.with_light(model.light)
    other.times = model.times[keep]
    other.forcing = forcing
    other.day = day
    other.sun_deg = model.sun_deg[keep]
    other.operator = dataclasses.replace(
        model.operator,
        forcing=forcing,
        sun_elevation_deg=np.asarray(model.operator.sun_elevation_deg)[keep],
        times=None if model.operator.times is None else model.operator.times[keep],
    )
    if model.light == model.render:  # a bound method of the original: render the kept steps instead
        other.light = other.render
    if model.scenario.target_rse is not None:
        # An adaptive allocation is chosen at the kept steps' highest sun (allocation_point, and so
        # render_key, of ``other``), as a fresh model of these steps would choose it: the original's
        # irradiance, if built, was allocated at the whole run's.
        other.__dict__.pop("irradiance", None)
    return other


class FastObservables:
    """The observables of :meth:`CoupledModel.observe` from emulated parts; jit- and vmap-able.

    ``fast(theta)`` → dict of the :data:`~lightfit.model.observe.OBSERVABLES` (each (T,)) and the
    count of unconverged blades per step (:data:`~lightfit.model.observe.CONVERGENCE_KEY`), from
    the model's own observation operator with two speed-ups: only the needed parts are emulated,
    and ``n_grid`` (an integer) tabulates the leaf photosynthesis per step
    (:func:`~lightfit.model.observe.tabulated_leaf`); ``n_grid=None`` solves it for every blade
    (exact, slow for large fields).
    """

    def __init__(self, model: CoupledModel, emulator: PartsEmulator, n_grid: int | None = 64):
        self.model, self.emulator, self.n_grid = model, emulator, n_grid
        self.leaf = exact_leaf if n_grid is None else tabulated_leaf(n_grid)
        n_day, n_seg = int(model.day.sum()), model.n_columns  # segments, then virtual sensors
        e = emulator
        if e.coef_values.shape[1:] != (n_day, len(PARTS), n_seg):
            raise InputError(
                f"emulator shape {e.coef_values.shape[1:]} does not match the model "
                f"({n_day} daytime steps, {n_seg} segments)",
                parameter="emulator",
                expected="an emulator built for this model",
            )
        kinds = {model.scenario.par_kind, "absorbed"} | ({"incident"} if model.sensors else set())
        self.rows = tuple(p for p in PARTS if p.rsplit("_", 1)[0] in kinds)
        idx = [PARTS.index(p) for p in self.rows]
        # Coefficients of the needed rows, flattened: (n_terms, T_day * n_rows * S).
        self._cv = jnp.asarray(e.coef_values[:, :, idx, :].reshape(len(e.coef_values), -1))
        self._cs = jnp.asarray(e.coef_se[:, :, idx, :].reshape(len(e.coef_se), -1))
        self._shape = (n_day, len(idx), n_seg)

    def parts(self, theta: Theta | Mapping[str, float]):
        """Emulated parts of :attr:`rows` only: values and SE, each (T_day, len(rows), S)."""
        b = self.emulator.basis(self.model.theta(theta).leaf)
        v = jnp.maximum((b @ self._cv).reshape(self._shape), 0.0)  # ratios ≥ 0, as PartsEmulator's
        s = jax.lax.stop_gradient(jnp.maximum((b @ self._cs).reshape(self._shape), 0.0))
        return v, s

    def __call__(self, theta: Theta | Mapping[str, float]) -> dict:
        th = self.model.theta(theta)  # names not given: the scenario's (its optics' leaf), as observe()
        o = self.model.operator(*self.parts(th), th, rows=self.rows, leaf=self.leaf)
        return {k: o[k] for k in (*OBSERVABLES, CONVERGENCE_KEY)}


#: Observables whose emulation error :func:`validate` reports (``err_<name>``, ``full_<name>``): every
#: observable quantity (not its spread or Monte Carlo SD), so any observed series can be checked.
VALIDATED = tuple(k for k in OBSERVABLES if "_mc_sd" not in k and "_spread" not in k)


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
    observable's unit) and the full values ``full_<obs>``, ``parts_rms``/``parts_max`` (per unit
    DNI/DHI), and ``se_ratio`` (n,): per point the median over the parts with Monte Carlo error of
    emulated ÷ rendered SE (the likelihood weighs by it; a review found 0.4–0.65 at the box's corners).
    """
    leaf_test = np.atleast_2d(np.asarray(leaf_test, float))
    if full is None:
        full = render_parts(model, leaf_test, progress, label=HELD_OUT_LABEL)
    out = {k: [] for k in ("err_" + o for o in VALIDATED)}
    out.update({"full_" + o: [] for o in VALIDATED})
    parts_err, se_ratio = [], []
    fast_j = jax.jit(fast)
    for x, v, s in zip(leaf_test, *full):
        th = as_theta(theta_extra).replace(**dict(zip(LEAF_PARAMETERS, x)))
        # exact observables from the full render (observe with the render replaced by its result)
        ref = model.with_light(lambda _, v=v, s=s: (jnp.asarray(v), jnp.asarray(s))).observe(th)
        emu = fast_j(th)
        ev, es = fast.emulator(th)
        parts_err.append(np.asarray(ev) - v)
        noisy = np.asarray(s) > 0
        se_ratio.append(float(np.median(np.asarray(es)[noisy] / np.asarray(s)[noisy])) if noisy.any() else 1.0)
        for o in VALIDATED:
            out["err_" + o].append(np.asarray(emu[o]) - np.asarray(ref[o]))
            out["full_" + o].append(np.asarray(ref[o]))
    res = {k: np.asarray(v) for k, v in out.items()}
    pe = np.asarray(parts_err)
    res["parts_rms"] = float(np.sqrt(np.mean(pe**2)))
    res["parts_max"] = float(np.max(np.abs(pe)))
    res["se_ratio"] = np.asarray(se_ratio)
    res["leaf_test"] = leaf_test
    return res


def emulated_model(model: CoupledModel, emulator: PartsEmulator) -> CoupledModel:
    """``model`` with its renders replaced by the emulator (``model.with_light(emulator)``)."""
    return model.with_light(emulator)


__all__ = [
    "COUNTS",
    "DESIGN_SIZE",
    "MIN_DESIGN_SIZE",
    "check_degrees",
    "check_design_size",
    "code_versions",
    "run_versions",
    "FastObservables",
    "PartsEmulator",
    "design_dir",
    "restrict",
    "shared_emulator",
    "build_emulator",
    "cached_emulator",
    "DEGREES",
    "emulated_model",
    "emulator_key",
    "exponents",
    "fit_emulator",
    "legendre_basis",
    "RenderPoints",
    "render_file",
    "render_key",
    "render_parts",
    "sobol_design",
    "validate",
    "VALIDATED",
]
