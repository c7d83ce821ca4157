"""JAX bridge: per-segment irradiance as a differentiable JAX function.

``irradiance(leaf, sun_deg, seed)`` returns ``(values, se)``, two ``(4, S)`` arrays — incident
sun, incident sky, absorbed sun, absorbed sky (rows in :data:`~lightfit.light.estimator.PARTS`
order) for the S requested segments, per unit DNI / DHI, and their Monte Carlo standard errors
(no gradient flows through ``se``) — and is callable inside ``jax.jit``, ``jax.grad`` and
``jax.vmap``. Dr.Jit cannot be traced by JAX, so the forward and backward passes are
``jax.pure_callback``s into Mitsuba wrapped in a ``jax.custom_vjp`` (docs/design.md §4): the backward
callback runs the estimator's reverse-mode pass with the incoming cotangent. Purity: the result
depends only on the arguments (the seed is an argument; the scene and sampling settings are
fixed when the function is made). Under ``vmap`` the callbacks run sequentially.
"""

from __future__ import annotations

import threading

import jax
import jax.numpy as jnp
import numpy as np

from lightfit.light.estimator import LEAF_PARAMETERS, PARTS, SegmentEstimator
from lightfit.light.scene import FieldScene


def make_irradiance(field_scene: FieldScene, segment_ids, *, samples: int = 64, bounces: int = 3):
    """Build ``irradiance(leaf, sun_deg, seed) -> (values, se)``, each (4, S), for fixed segments and sampling.

    Args:
        field_scene: scene whose leaf parameters and sun the function sets on every call.
        segment_ids: segments measured (their order is ``np.unique(segment_ids)``).
        samples, bounces: estimator settings (see :class:`SegmentEstimator`).

    The returned function's arguments: ``leaf`` — (3,) specular, roughness, subsurface in
    [0, 1]; ``sun_deg`` — (2,) sun elevation and azimuth, degrees; ``seed`` — integer.
    Gradients flow to ``leaf`` only.
    """
    ids = np.unique(np.asarray(segment_ids, dtype=np.int64))
    n_seg = len(ids)
    lock = threading.Lock()
    cache: dict[int, SegmentEstimator] = {}

    def estimator(leaf, sun_deg, seed) -> SegmentEstimator:
        field_scene.set_optics(**{k: float(np.clip(v, 0.0, 1.0)) for k, v in zip(LEAF_PARAMETERS, np.asarray(leaf))})
        el, az = (float(x) for x in np.asarray(sun_deg))
        field_scene.set_sun(el, az)
        s = int(np.asarray(seed))
        if s not in cache:
            cache.clear()  # keep one: sampling arrays are large
            cache[s] = SegmentEstimator(field_scene, ids, samples=samples, bounces=bounces, seed=s)
        return cache[s]

    def forward_cb(leaf, sun_deg, seed):
        dtype = np.asarray(leaf).dtype
        with lock:
            r = estimator(leaf, sun_deg, seed).render()
        return (
            np.stack([getattr(r, p) for p in PARTS]).astype(dtype),
            np.stack([r.se[p] for p in PARTS]).astype(dtype),
        )

    def backward_cb(leaf, sun_deg, seed, ct):
        dtype = np.asarray(leaf).dtype
        with lock:
            g = estimator(leaf, sun_deg, seed).vjp(
                {p: np.asarray(ct[i], dtype=np.float64) for i, p in enumerate(PARTS)}
            )
        return np.array([g[k] for k in LEAF_PARAMETERS], dtype=dtype)

    @jax.custom_vjp
    def irradiance(leaf, sun_deg, seed):
        leaf = jnp.asarray(leaf)
        out = jax.ShapeDtypeStruct((len(PARTS), n_seg), leaf.dtype)
        return jax.pure_callback(
            forward_cb, (out, out), leaf, jnp.asarray(sun_deg, leaf.dtype), jnp.asarray(seed), vmap_method="sequential"
        )

    def fwd(leaf, sun_deg, seed):
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

    irradiance.defvjp(fwd, bwd)
    irradiance.segment_id = ids
    return irradiance
