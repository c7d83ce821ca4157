"""The JAX bridge: jit, grad and vmap through Mitsuba callbacks."""

import jax
import jax.numpy as jnp
import numpy as np

import lightfit  # noqa: F401
from lightfit.light.bridge import make_irradiance
from lightfit.light.estimator import PARTS, SegmentEstimator
from lightfit.light.scene import FieldScene, Optics
from lightfit.plant import Field, build


def test_bridge_matches_estimator_under_jit_grad_and_vmap():
    g = build(Field(n_plants=1, buffer_rows=1, seed=2))
    ids = g.segments.loc[g.segments.measured, "segment_id"].to_numpy()
    fs = FieldScene(g.mesh, Optics())
    f = make_irradiance(fs, ids, samples=8, bounces=2)
    leaf = jnp.array([0.4, 0.6, 0.2])
    sun = jnp.array([40.0, 170.0])
    weights = jnp.asarray(np.linspace(0.5, 1.5, len(ids)))

    @jax.jit
    def loss(leaf, seed):
        r, se = f(leaf, sun, seed)
        return jnp.sum(weights * r[PARTS.index("absorbed_sun")]) + 0.3 * jnp.sum(r[PARTS.index("absorbed_sky")])

    value, grad = jax.value_and_grad(loss)(leaf, 3)
    # The same numbers straight from the estimator.
    fs.set_optics(specular=0.4, roughness=0.6, subsurface=0.2)
    fs.set_sun(40.0, 170.0)
    est = SegmentEstimator(fs, ids, samples=8, bounces=2, seed=3)
    r = est.render()
    ref = np.sum(np.asarray(weights) * r.absorbed_sun) + 0.3 * np.sum(r.absorbed_sky)
    assert np.isclose(float(value), ref, rtol=1e-5)
    ref_g = est.vjp({"absorbed_sun": np.asarray(weights), "absorbed_sky": np.full(len(ids), 0.3)})
    assert np.allclose(np.asarray(grad), [ref_g[k] for k in ("specular", "roughness", "subsurface")], rtol=1e-4)
    # Pure: same seed, same value; vmap over seeds runs the callbacks one by one.
    assert float(loss(leaf, 3)) == float(value)
    many = jax.vmap(lambda s: loss(leaf, s))(jnp.arange(3))
    assert many.shape == (3,) and np.isclose(float(many[2]), float(loss(leaf, 2)))
    assert len(set(np.asarray(many).tolist())) == 3
