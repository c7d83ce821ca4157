"""JAX bridge: per-segment irradiance as a differentiable JAX function.

``irradiance(leaf, sun_deg, seed)`` returns ``(values, se)``, two ``(4, S + P)`` arrays — incident
sun, incident sky, absorbed sun, absorbed sky (rows in :data:`~lightfit.light.estimator.PARTS`
order) for the S requested segments and P virtual sensors (:mod:`lightfit.light.sensors`; none
unless asked), per unit DNI / DHI, and their Monte Carlo standard errors
(no gradient flows through ``se``) — and is callable inside ``jax.jit``, ``jax.grad`` and
``jax.vmap``. Dr.Jit cannot be traced by JAX, so the forward and backward passes are
``jax.pure_callback``s into Mitsuba wrapped in a ``jax.custom_vjp`` (docs/design.md §4): the backward
callback runs the estimator's reverse-mode pass with the incoming cotangent. Purity: the result
depends only on the arguments (the seed is an argument; the scene and sampling settings are
fixed when the function is made). Under ``vmap`` the callbacks run sequentially.

The callbacks never call JAX. JAX hands a callback its arguments as ``jax.Array`` objects and runs
it on one of its own CPU threads; outside ``jax.jit`` (eager dispatch), new JAX work issued
from inside the callback — even indexing ``ct[i]`` — may be queued behind the callback that is
waiting for it, and ``jax.grad`` without ``jit`` then hung forever. So every callback converts
all its arguments to numpy once, on entry (:func:`_host`), and computes with numpy only.
"""

from __future__ import annotations

import threading
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np
from numpy.typing import ArrayLike

from lightfit.defaults import DARK_FLOOR, DEFAULT_RAYS_PER_M2, MAX_ADAPTIVE_SAMPLES
from lightfit.errors import InputError, check_integer
from lightfit.light.bsdf import LEAF_PARAMETERS
from lightfit.light.estimator import (
    CLEAR_DAY_DHI_PER_DNI,
    DEFAULT_BOUNCES,
    DEFAULT_SAMPLES,
    PARTS,
    AdaptiveEstimator,
    SegmentEstimator,
    adaptive_pilot,
    check_bounces,
    check_dark_floor,
    check_direct_light,
    check_samples,
    check_samples_fit,
    check_target_rse,
    checked_segment_ids,
    replicates_for,
)
from lightfit.light.keyed_random import check_seed
from lightfit.light.scene import FieldScene
from lightfit.light.sensors import DEFAULT_SENSOR_SAMPLES, Sensor, SensorEstimator


def _host(*args) -> tuple[np.ndarray, ...]:
    """The callback's arguments as numpy arrays (host copies; no JAX work is issued)."""
    return tuple(np.asarray(a) for a in args)


def make_irradiance(
    field_scene: FieldScene,
    segment_ids: ArrayLike,
    *,
    samples: int = DEFAULT_SAMPLES,
    bounces: int = DEFAULT_BOUNCES,
    sensors: tuple[Sensor, ...] = (),
    sensor_samples: int = DEFAULT_SENSOR_SAMPLES,
    target_rse: float | None = None,
    allocate_at: tuple[ArrayLike, ArrayLike, float, float] | None = None,
    max_samples: int = MAX_ADAPTIVE_SAMPLES,
    dark_floor: float = DARK_FLOOR,
    direct: str = "paths",
    direct_rays_per_m2: float | tuple[float, float] = DEFAULT_RAYS_PER_M2,
) -> Callable[[ArrayLike, ArrayLike, ArrayLike], tuple[jax.Array, jax.Array]]:
    """Build ``irradiance(leaf, sun_deg, seed) -> (values, se)``, each (4, S + P), for fixed segments and sampling.

    Args:
        field_scene: scene whose leaf parameters and sun the function sets on every call.
        segment_ids: segments measured, in increasing order, each once (:func:`checked_segment_ids`).
        samples, bounces: estimator settings (see :class:`SegmentEstimator`).
        sensors: P virtual horizontal sensors (:mod:`lightfit.light.sensors`), rendered with the
            same scene, bounces and seed, ``sensor_samples`` points each; their parts are the
            last P columns (incident parts: the sensor's reading).
        target_rse: ``None`` (default): every segment gets ``samples`` points. A number in (0, 1):
            the per-segment relative standard error of absorbed PAR to reach; segments are
            rendered with an :class:`~lightfit.light.estimator.AdaptiveEstimator`: ``samples``
            is then the *starting* count (the pilot round, raised to 32 if smaller: the stopping
            rule needs 8 replicates), ``max_samples`` the cap and ``dark_floor`` the light floor
            (:func:`~lightfit.light.estimator.render_adaptive`). Sensors keep ``sensor_samples``.
        allocate_at: ``(leaf, sun_deg, dni, dhi)`` at which the adaptive allocation is chosen
            (once per seed, then kept for every sun and leaf: common random numbers, gradients
            equal to finite differences); ``dni``/``dhi`` weight the sun and sky parts of the
            absorbed PAR whose error is targeted. ``None``: the first call's leaf and sun with a
            clear day's DHI/DNI = 0.3 — then the values depend on which call came first, so
            callers wanting a pure function (:class:`~lightfit.model.coupled.CoupledModel`) give it.
        direct, direct_rays_per_m2: the segments' unscattered light from the paths or by
            projection (:class:`SegmentEstimator`); sensors always use their own paths.

    The returned function's arguments: ``leaf`` — (3,) specular, roughness, subsurface in
    [0, 1] (a value outside is clamped to it: the function is flat there, its gradient 0);
    ``sun_deg`` — (2,) sun elevation in [−90, 90] and azimuth, degrees; ``seed`` — integer in [0, 2³²).
    Gradients flow to ``leaf`` only. Wrong shapes are refused when the function is traced.
    """
    ids = checked_segment_ids(segment_ids)
    # Checked here, once: inside the callbacks an error reaches the caller wrapped in JAX's.
    check_samples_fit(samples, len(ids))
    check_bounces(bounces)
    k = samples if target_rse is None else adaptive_pilot(samples)  # the projection's replicates are the paths'
    check_direct_light(field_scene, direct, direct_rays_per_m2, replicates_for(int(k)))
    if sensors:
        check_samples(sensor_samples)
    if target_rse is not None:
        check_target_rse(target_rse)
        check_dark_floor(dark_floor)
        check_integer(max_samples, "max_samples", adaptive_pilot(samples), why="the adaptive cap, at least the pilot")
    n_seg = len(ids)
    n_out = n_seg + len(sensors)
    lock = threading.Lock()
    cache: dict[int, tuple] = {}

    def set_state(leaf, sun_deg):
        # Clamped: the function is flat outside [0, 1] and backward_cb gives it no gradient there.
        field_scene.set_optics(**{k: float(np.clip(v, 0.0, 1.0)) for k, v in zip(LEAF_PARAMETERS, leaf, strict=True)})
        el, az = (float(x) for x in sun_deg)
        field_scene.set_sun(el, az)

    def segment_estimator(leaf, sun_deg, s: int):
        direct_kw = dict(direct=direct, direct_rays_per_m2=direct_rays_per_m2)
        if target_rse is None:
            return SegmentEstimator(field_scene, ids, samples=samples, bounces=bounces, seed=s, **direct_kw)
        a_leaf, a_sun, dni, dhi = (leaf, sun_deg, 1.0, CLEAR_DAY_DHI_PER_DNI) if allocate_at is None else allocate_at
        set_state(np.asarray(a_leaf, np.float64), np.asarray(a_sun, np.float64))
        est = AdaptiveEstimator(
            field_scene,
            ids,
            float(target_rse),
            bounces=bounces,
            seed=s,
            pilot=adaptive_pilot(samples),
            max_samples=int(max_samples),
            dark_floor=dark_floor,
            dni=float(dni),
            dhi=float(dhi),
            **direct_kw,
        )
        set_state(leaf, sun_deg)
        return est

    def estimators(leaf: np.ndarray, sun_deg: np.ndarray, seed: np.ndarray) -> tuple:
        # numpy arguments only (see the module docstring).
        set_state(leaf, sun_deg)
        s = int(seed)
        if s not in cache:
            cache.clear()  # keep one: sampling arrays are large
            est = [segment_estimator(leaf, sun_deg, s)]
            if sensors:
                est.append(SensorEstimator(field_scene, sensors, samples=sensor_samples, bounces=bounces, seed=s))
            cache[s] = tuple(est)
        return cache[s]

    def stacked(rs, dtype):
        """(values, se), each (4, S + P), of the estimators' renders ``rs`` (segments, then sensors)."""
        return (
            np.concatenate([np.stack([getattr(r, p) for p in PARTS]) for r in rs], axis=1).astype(dtype),
            np.concatenate([np.stack([r.se[p] for p in PARTS]) for r in rs], axis=1).astype(dtype),
        )

    def finite(leaf, sun_deg) -> bool:  # host arrays in a callback: a traced NaN (eager ones are refused)
        # A traced sun beyond the zenith is no sun either: set_state's error would reach the
        # caller wrapped as 'INTERNAL: CpuCallback error'.
        return bool(np.isfinite(leaf).all() and np.isfinite(sun_deg).all() and abs(sun_deg[0]) <= 90)

    def forward_cb(leaf, sun_deg, seed):
        leaf, sun_deg, seed = _host(leaf, sun_deg, seed)
        if not finite(leaf, sun_deg):
            nan = np.full((len(PARTS), n_out), np.nan, leaf.dtype)
            return nan, nan
        with lock:
            rs = [e.render() for e in estimators(leaf, sun_deg, seed)]
        return stacked(rs, leaf.dtype)

    def render_many(leaf_points, suns_deg, seed):
        """The forward values at many leaf points and suns, tracing the paths once
        (:meth:`~lightfit.light.estimator.SegmentEstimator.render_many`): yields, per row of
        ``leaf_points`` (N, 3) as soon as it is done, ``(values, se)``, each (T, 4, S + P), what
        ``irradiance(leaf, sun, seed)`` returns at each row of ``suns_deg`` (T, 2) — bitwise, when
        both arrays have the dtype the JAX function would hand its callback (that of ``leaf``).
        Not differentiable; numpy in and out."""
        leaf_points, suns_deg = np.atleast_2d(np.asarray(leaf_points)), np.atleast_2d(np.asarray(suns_deg))
        dtype = leaf_points.dtype
        with lock:
            ests = estimators(leaf_points[0], suns_deg[0], np.asarray(seed))
        # set_state's clipping and float conversion, for every point and sun at once
        leaf64 = np.clip(leaf_points.astype(np.float64), 0.0, 1.0)
        gens = [e.render_many(leaf64, suns_deg.astype(np.float64)) for e in ests]
        while True:
            with lock:
                per_est = [next(g, None) for g in gens]
            if per_est[0] is None:
                return
            v, s = zip(*(stacked(rs, dtype) for rs in zip(*per_est)))
            yield np.stack(v), np.stack(s)

    def backward_cb(leaf, sun_deg, seed, ct):
        leaf, sun_deg, seed, ct = _host(leaf, sun_deg, seed, ct)
        if not finite(leaf, sun_deg):
            return np.full(leaf.shape, np.nan, leaf.dtype)
        g = dict.fromkeys(LEAF_PARAMETERS, 0.0)
        with lock:
            for e, cols in zip(estimators(leaf, sun_deg, seed), (slice(0, n_seg), slice(n_seg, n_out))):
                c = ct[:, cols].astype(np.float64)
                if c.any():
                    for k, v in e.vjp({p: c[i] for i, p in enumerate(PARTS)}).items():
                        g[k] += v
        inside = (leaf >= 0.0) & (leaf <= 1.0)  # outside, the render is that of the clamped leaf: flat
        return np.where(inside, [g[k] for k in LEAF_PARAMETERS], 0.0).astype(leaf.dtype)

    def check_shapes(leaf, sun_deg, seed):
        """At trace time (shapes are static): a short leaf would keep the previous call's last
        parameters, a long one drop its tail."""
        for name, a, shape, what in (
            ("leaf", leaf, (3,), "(specular, roughness, subsurface)"),
            ("sun_deg", sun_deg, (2,), "(elevation, azimuth) in degrees"),
            ("seed", seed, (), "one integer"),
        ):
            if jnp.shape(a) != shape:
                raise InputError(f"{name} of shape {jnp.shape(a)}", parameter=name, expected=f"shape {shape}: {what}")
        # A float seed was truncated by int() in the callback (1.5 rendered seed 1), a bool taken as 0/1.
        if jnp.result_type(seed).kind not in "iu":
            raise InputError(
                f"seed of dtype {jnp.result_type(seed)}", parameter="seed", expected="an integer in [0, 2³²)"
            )

    def check_finite(leaf, sun_deg, seed):
        """Concrete (eager) values that are not finite, a sun beyond the zenith (|elevation| > 90°) and a
        seed outside [0, 2³²), refused here: raised inside the callback the
        error reached the caller as 'INTERNAL: CpuCallback error' (a review). Traced ones cannot be
        read: their render is NaN, and the model flags them (:func:`lightfit.model.parameters.outside_domain`)."""
        for name, a, what in (
            ("leaf", leaf, "finite (specular, roughness, subsurface)"),
            ("sun_deg", sun_deg, "a finite (elevation, azimuth) in degrees, elevation in [−90, 90]"),
        ):
            if isinstance(a, jax.core.Tracer):
                continue
            v = np.asarray(a, dtype=np.float64)
            if not np.isfinite(v).all() or (name == "sun_deg" and abs(v[0]) > 90):
                raise InputError(f"{name}={np.asarray(a).tolist()}", parameter=name, expected=what)
        # Likewise a concrete seed outside [0, 2³²), refused by the estimator inside the callback.
        if not isinstance(seed, jax.core.Tracer):
            check_seed(np.asarray(seed).item())

    @jax.custom_vjp
    def irradiance(leaf, sun_deg, seed):
        check_shapes(leaf, sun_deg, seed)
        check_finite(leaf, sun_deg, seed)
        leaf = jnp.asarray(leaf)
        out = jax.ShapeDtypeStruct((len(PARTS), n_out), leaf.dtype)
        return jax.pure_callback(
            forward_cb, (out, out), leaf, jnp.asarray(sun_deg, leaf.dtype), jnp.asarray(seed), vmap_method="sequential"
        )

    def fwd(leaf, sun_deg, seed):
        check_shapes(leaf, sun_deg, seed)
        return irradiance(leaf, sun_deg, seed), (
            jnp.asarray(leaf),
            jnp.asarray(sun_deg, jnp.asarray(leaf).dtype),
            jnp.asarray(seed),
        )

    def bwd(res, ct):
        leaf, sun_deg, seed = res
        ct = ct[0]  # the standard errors carry no gradient
        g = jax.pure_callback(
            backward_cb, jax.ShapeDtypeStruct(leaf.shape, leaf.dtype), leaf, sun_deg, seed, ct, vmap_method="sequential"
        )
        return g, jnp.zeros_like(sun_deg), None

    def allocation(seed: int):
        """The adaptive allocation (an :class:`~lightfit.light.estimator.Irradiance` whose meta has
        ``samples_per_segment``, ``reached_rse``, ``target_rse``) used for ``seed``; ``None`` at fixed K."""
        if target_rse is None:
            return None
        leaf, sun = (allocate_at[0], allocate_at[1]) if allocate_at is not None else (None, None)
        with lock:
            if int(seed) not in cache:
                if leaf is None:
                    raise InputError(
                        "the adaptive allocation is made on the first call",
                        parameter="allocate_at",
                        expected="a call of the irradiance function first, or allocate_at",
                    )
                estimators(np.asarray(leaf, np.float64), np.asarray(sun, np.float64), np.asarray(seed))
            return cache[int(seed)][0].allocation

    irradiance.defvjp(fwd, bwd)
    irradiance.segment_id = ids
    irradiance.sensors = tuple(sensors)
    irradiance.target_rse = None if target_rse is None else float(target_rse)
    irradiance.allocation = allocation
    irradiance.render_many = render_many
    return irradiance
