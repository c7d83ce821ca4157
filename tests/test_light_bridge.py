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
    g = build(Field(boundary="finite", n_plants=1, buffer_rows=1, seed=2))
    ids = g.segments.loc[g.segments.measured, "segment_id"].to_numpy()
    fs = FieldScene(g.mesh, Optics.preset("paper"))
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


# Eager (un-jitted) jax.grad used to hang forever in the backward callback: the callback indexed
# its jax.Array cotangent (new JAX work issued from a JAX callback thread, never run). The script
# below runs eager and jitted gradients through the bridge and through a tiny coupled model in a
# subprocess, so a regression fails on the timeout instead of hanging the suite. Inside every
# callback, host-to-device transfers are disallowed (a callback that indexes or computes on a
# jax.Array needs one), so a callback that calls JAX fails on any machine, even where the
# deadlock itself does not strike.
_EAGER_GRAD_SCRIPT = r"""
import json, os
os.environ["JAX_PLATFORMS"] = "cpu"
import jax, jax.numpy as jnp, numpy as np
jax.config.update("jax_enable_x64", True)

calls = {"n": 0}
_pure_callback = jax.pure_callback


def guarded_pure_callback(callback, result_shape_dtypes, *args, **kwargs):
    def guarded(*a):
        calls["n"] += 1
        with jax.transfer_guard_host_to_device("disallow"):
            out = callback(*a)
        for leaf in jax.tree.leaves(out):
            assert isinstance(leaf, np.ndarray), f"callback returned {type(leaf).__name__}, not numpy"
        return out

    return _pure_callback(guarded, result_shape_dtypes, *args, **kwargs)


jax.pure_callback = guarded_pure_callback

import lightfit
from lightfit import weather
from lightfit.light.bridge import make_irradiance
from lightfit.light.estimator import PARTS
from lightfit.light.scene import FieldScene, Optics
from lightfit.model.coupled import CoupledModel
from lightfit.model.scenario import Scenario
from lightfit.plant import Field, build

out = {}
# 1. The bridge alone.
g = build(Field(boundary="finite", n_plants=1, buffer_rows=1, seed=2))
ids = g.segments.loc[g.segments.measured, "segment_id"].to_numpy()
f = make_irradiance(FieldScene(g.mesh, Optics.preset("paper")), ids, samples=8, bounces=2)
sun = jnp.array([40.0, 170.0])
w = jnp.asarray(np.linspace(0.5, 1.5, len(ids)))


def bridge_loss(leaf):
    r, _ = f(leaf, sun, 3)
    return jnp.sum(w * r[PARTS.index("absorbed_sun")]) + 0.3 * jnp.sum(r[PARTS.index("incident_sky")])


leaf = jnp.array([0.4, 0.6, 0.2])
out["bridge_eager"] = np.asarray(jax.grad(bridge_loss)(leaf)).tolist()
out["bridge_jit"] = np.asarray(jax.jit(jax.grad(bridge_loss))(leaf)).tolist()

# 2. A tiny coupled model: one plant, three steps around noon.
src = weather.add_solar(weather.read_weather(weather.bundled_path("2016-04-20")))
wx = weather.window(src, "2016-04-20 12:00", 1, "30min")
fld = Field(boundary="finite", n_plants=1, buffer_rows=1, seed=2)
m = CoupledModel(Scenario(weather=wx, field=fld, samples=8, bounces=2))
NAMES = ("specular", "roughness", "subsurface", "light_factor", "vcmax_scale")


def model_loss(x):
    o = m.observe({n: x[i] for i, n in enumerate(NAMES)})
    return 1e-3 * jnp.sum(o["plant_par_umol_m2_s"]) + jnp.sum(o["canopy_an_umol_m2_s"])


x = jnp.array([0.5, 0.5, 0.3, 1.0, 1.0])
out["model_eager"] = np.asarray(jax.grad(model_loss)(x)).tolist()
out["model_jit"] = np.asarray(jax.jit(jax.grad(model_loss))(x)).tolist()
out["callbacks"] = calls["n"]
print("RESULT", json.dumps(out))
"""


def test_eager_grad_does_not_deadlock_and_matches_jit():
    import json
    import os
    import subprocess
    import sys

    env = {**os.environ, "JAX_PLATFORMS": "cpu"}
    try:
        p = subprocess.run(
            [sys.executable, "-c", _EAGER_GRAD_SCRIPT], capture_output=True, text=True, timeout=180, env=env
        )
    except subprocess.TimeoutExpired as e:
        raise AssertionError(f"eager jax.grad through the bridge hung (> {e.timeout} s)") from None
    assert p.returncode == 0, p.stderr[-4000:]
    line = next(ln for ln in p.stdout.splitlines() if ln.startswith("RESULT "))
    r = json.loads(line[len("RESULT ") :])
    assert r["callbacks"] > 0  # the guard saw the callbacks
    for k in ("bridge", "model"):
        eager, jitted = np.asarray(r[f"{k}_eager"]), np.asarray(r[f"{k}_jit"])
        assert np.isfinite(eager).all() and np.abs(eager).max() > 0, (k, eager)
        assert np.allclose(eager, jitted, rtol=1e-6, atol=1e-9 * np.abs(jitted).max()), (k, eager, jitted)


def test_bridge_refuses_bad_settings_and_shapes_and_is_flat_outside_the_box():
    import pytest

    from lightfit.errors import InputError

    g = build(Field(boundary="finite", n_plants=1, buffer_rows=1, seed=2))
    ids = g.segments.loc[g.segments.measured, "segment_id"].to_numpy()[:6]
    fs = FieldScene(g.mesh, Optics.preset("paper"))
    # Refused when the function is made, not at its first call inside a JAX callback.
    for kw, name in (
        (dict(samples=-3), "samples"),
        (dict(bounces=-1), "bounces"),
        (dict(direct="bogus"), "direct"),
        (dict(direct="projection"), "finite field"),
        (dict(target_rse=0.1, max_samples=8), "max_samples"),
    ):
        with pytest.raises(InputError, match=name):
            make_irradiance(fs, ids, **kw)
    with pytest.raises(InputError, match="segment_ids"):
        make_irradiance(fs, ids[:0])
    f = make_irradiance(fs, ids, samples=8, bounces=1)
    sun = jnp.array([40.0, 170.0])
    # A short leaf would keep the previous call's subsurface; refused at trace time, also under jit.
    for bad in (jnp.array([0.5, 0.5]), jnp.array([0.5, 0.5, 0.5, 0.5])):
        with pytest.raises(InputError, match="leaf of shape"):
            f(bad, sun, 1)
        with pytest.raises(InputError, match="leaf of shape"):
            jax.jit(f)(bad, sun, 1)
    with pytest.raises(InputError, match="sun_deg of shape"):
        f(jnp.array([0.5, 0.5, 0.5]), jnp.array([40.0, 170.0, 1.0]), 1)
    # NaN eagerly: the InputError itself, not 'INTERNAL: CpuCallback error' around it (a review)
    with pytest.raises(InputError, match=r"leaf=\[nan, 0.5, 0.5\]"):
        f(jnp.array([np.nan, 0.5, 0.5]), sun, 1)
    with pytest.raises(InputError, match=r"sun_deg=\[nan, 170.0\].*finite \(elevation, azimuth\)"):
        f(jnp.array([0.5, 0.5, 0.5]), jnp.array([np.nan, 170.0]), 1)
    # traced, it cannot be refused: NaN out, and a NaN gradient, not a crash inside the callback (a review)
    nan_leaf = jnp.array([np.nan, 0.5, 0.5])
    values, se = jax.jit(f)(nan_leaf, sun, 1)
    assert np.isnan(np.asarray(values)).all() and np.isnan(np.asarray(se)).all()
    assert np.isnan(np.asarray(jax.jit(jax.grad(lambda x: jnp.sum(f(x, sun, 1)[0])))(nan_leaf))).all()

    def loss(leaf):
        return jnp.sum(f(leaf, sun, 1)[0][PARTS.index("absorbed_sun")])

    # Outside [0, 1] the leaf is clamped: the same value as on the bound and no gradient there;
    # on the bound itself the (one-sided) gradient stays.
    out, edge = jnp.array([1.5, 0.5, 0.5]), jnp.array([1.0, 0.5, 0.5])
    assert float(loss(out)) == float(loss(edge))
    g_out, g_edge = np.asarray(jax.grad(loss)(out)), np.asarray(jax.grad(loss)(edge))
    assert g_out[0] == 0.0 and g_edge[0] != 0.0
    assert np.array_equal(g_out[1:], g_edge[1:])


def test_grazing_suns_and_the_leaf_boxs_corners_under_jit_and_eagerly():
    """The bridge with the sun at 0.5°, 1e-6°, exactly on the horizon and 0.5° below it, at the
    corners of the leaf box and a hair inside them: every part and standard error finite and ≥ 0,
    absorbed ≤ incident, the sun's parts exactly 0 with the sun not above the horizon (the sky's
    still lit), and a finite gradient; jit and eager give the same numbers."""
    g = build(Field(boundary="finite", n_plants=1, buffer_rows=1, seed=2))
    ids = g.segments.loc[g.segments.measured, "segment_id"].to_numpy()
    f = make_irradiance(FieldScene(g.mesh, Optics.preset("paper")), ids, samples=4, bounces=2)

    def loss(leaf, sun):
        values, se = f(leaf, sun, 1)
        return jnp.sum(values), (values, se)

    eager = jax.value_and_grad(loss, has_aux=True)
    jitted = jax.jit(eager)
    leaves = [(0.0, 0.0, 0.0), (1.0, 1.0, 1.0), (1.0, 0.0, 1.0), (1e-9,) * 3, (1 - 1e-9,) * 3]
    for elevation in (0.5, 1e-6, 0.0, -0.5):
        for leaf in leaves:
            args = (jnp.array(leaf), jnp.array([elevation, 200.0]))
            (_, (values, se)), grad = jitted(*args)
            (_, (values_e, se_e)), grad_e = eager(*args)
            values, se, grad = np.asarray(values), np.asarray(se), np.asarray(grad)
            assert np.isfinite(values).all() and np.isfinite(se).all() and np.isfinite(grad).all(), (elevation, leaf)
            assert (values >= 0).all() and (se >= 0).all()
            for kind in ("sun", "sky"):
                i, a = PARTS.index(f"incident_{kind}"), PARTS.index(f"absorbed_{kind}")
                assert (values[a] <= values[i] * (1 + 1e-6) + 1e-12).all(), (elevation, leaf, kind)
            lit = [PARTS.index("incident_sun"), PARTS.index("absorbed_sun")]
            assert (values[lit].max() > 0) == (elevation > 0), (elevation, leaf)
            assert values[PARTS.index("incident_sky")].max() > 0
            np.testing.assert_array_equal(np.asarray(values_e), values)
            np.testing.assert_allclose(np.asarray(grad_e), grad, rtol=1e-12, atol=1e-12)


def test_bridge_refuses_a_sun_beyond_the_zenith_and_a_bad_seed_by_name():
    """Eagerly, a sun elevation outside [−90, 90] and a seed outside [0, 2³²) are the InputError
    naming them, not 'INTERNAL: CpuCallback error' around the estimator's; a float seed (any
    dtype but an integer's) is refused when traced, not truncated (1.5 rendered seed 1); a
    traced sun beyond the zenith renders NaN, as a traced NaN does."""
    import pytest

    from lightfit.errors import InputError

    g = build(Field(boundary="finite", n_plants=1, buffer_rows=1, seed=2))
    ids = g.segments.loc[g.segments.measured, "segment_id"].to_numpy()[:3]
    f = make_irradiance(FieldScene(g.mesh, Optics.preset("paper")), ids, samples=8, bounces=1)
    leaf, sun = jnp.array([0.5, 0.5, 0.5]), jnp.array([40.0, 170.0])
    for el in (95.0, -90.5):
        with pytest.raises(InputError, match=r"sun_deg=.*elevation in \[−90, 90\]"):
            f(leaf, jnp.array([el, 170.0]), 1)
    for seed in (-1, 2**33):
        with pytest.raises(InputError, match="seed"):
            f(leaf, sun, seed)
    for seed in (1.5, jnp.array(1.0), True):
        with pytest.raises(InputError, match="seed of dtype"):
            f(leaf, sun, seed)
        with pytest.raises(InputError, match="seed of dtype"):
            jax.jit(f)(leaf, sun, seed)
    values, _ = jax.jit(f)(leaf, jnp.array([95.0, 170.0]), 1)
    assert np.isnan(np.asarray(values)).all()
    assert np.isfinite(np.asarray(f(leaf, jnp.array([90.0, 170.0]), 1)[0])).all()
