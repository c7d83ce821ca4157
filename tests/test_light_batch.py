"""Batch renders (``render_many``): the paths traced once and weighed at many leaf-parameter points
must give, at every point and sun, the values of separate renders by fresh estimators.

Reference: one fresh :class:`SegmentEstimator` (own paths, own shadow rays) per point and sun. The
required agreement is a relative difference ≤ 1e-5 (float32 round-off) on every part and segment;
the test asks for bitwise equality, which holds on this platform because each point's arithmetic is
the same and a path whose weight vanishes at a point contributes exactly +0 afterwards. Points
include the parameter bounds, where weights vanish (subsurface 0: no transmission; specular 0: no
glossy lobe) and a separate render stops the path.
"""

import numpy as np
import pytest

import lightfit  # noqa: F401
from lightfit import replication as rep
from lightfit.errors import InputError
from lightfit.light.bsdf import LEAF_PARAMETERS
from lightfit.light.estimator import PARTS, AdaptiveEstimator, SegmentEstimator
from lightfit.light.scene import FieldScene
from lightfit.light.sensors import SensorEstimator

POINTS = np.array([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0], [0.3, 0.7, 0.5], [1.0, 0.2, 0.0]])
SUNS = np.array([[45.0, 150.0], [12.0, 95.0], [-3.0, 80.0]])  # the last below the horizon


@pytest.fixture(scope="module", params=["periodic", "finite"])
def quick(request):
    """The quick replication field (periodic default, or the paper preset's finite field) on 2 steps."""
    cfg = rep.ReplicationConfig.quick()
    if request.param == "finite":
        cfg = cfg.with_preset("paper")
    w = rep.forcing().loc["2016-04-20 11:00+00:00":"2016-04-20 11:30+00:00"]
    m = rep.model_for(cfg, w)
    fs = FieldScene(m.geometry.mesh, m.scenario.optics, sky=m.scenario.sky, cell=m.geometry.cell)
    return m, fs


def assert_same(a, b):
    for p in PARTS:
        np.testing.assert_array_equal(getattr(a, p), getattr(b, p), err_msg=p)
        np.testing.assert_array_equal(a.se[p], b.se[p], err_msg=p)
        np.testing.assert_array_equal(a.front(p), b.front(p), err_msg=p)
    for part in ("incident", "absorbed"):
        np.testing.assert_array_equal(a.cov[part], b.cov[part])
    np.testing.assert_array_equal(a.sun_vector, b.sun_vector)
    assert a.meta.get("periodic") == b.meta.get("periodic")


@pytest.mark.parametrize("kind", ["segments", "sensors"])
def test_render_many_equals_separate_renders(quick, kind):
    m, fs = quick
    sc = m.scenario

    def estimator():
        if kind == "sensors":
            return SensorEstimator(fs, m.sensors, bounces=sc.bounces, seed=3)
        return SegmentEstimator(fs, m.segment_id, samples=sc.samples, bounces=sc.bounces, seed=3)

    fs.set_optics(specular=0.5, roughness=0.5, subsurface=0.3)
    fs.set_sun(30.0, 120.0)
    before = (fs.optics, fs.sun.copy())
    est = estimator()
    est.render()  # geometry kept from an earlier render must not leak into the batch
    batch = list(est.render_many(POINTS, SUNS))
    assert (fs.optics, list(fs.sun)) == (before[0], list(before[1]))  # the scene as the caller left it
    assert len(batch) == len(POINTS) and all(len(b) == len(SUNS) for b in batch)
    worst = 0.0
    for x, per_sun in zip(POINTS, batch):
        for sun, r in zip(SUNS, per_sun):
            fs.set_optics(**dict(zip(LEAF_PARAMETERS, x)))
            fs.set_sun(*sun)
            ref = estimator().render()
            for p in PARTS:
                a, b = getattr(r, p), getattr(ref, p)
                worst = max(worst, float(np.max(np.abs(a - b) / np.maximum(np.abs(b), 1e-30))))
            assert_same(r, ref)
    assert worst <= 1e-5
    # The bounds exercise the case a separate render treats differently: paths followed on with
    # zero throughput (at subsurface 0 every sampled transmission weighs 0).
    geo = est._geometry()
    fs.set_optics(**dict(zip(LEAF_PARAMETERS, POINTS[0])))
    betas, _ = est._weigh(geo)
    reached = [np.asarray(g["hit_leaf"] | g["hit_soil"]) & (np.asarray(b) == 0) for g, b in zip(geo[1:], betas[1:])]
    assert any(r.any() for r in reached)


def test_render_many_of_the_adaptive_estimator(quick):
    m, fs = quick
    fs.set_optics(specular=0.5, roughness=0.5, subsurface=0.3)
    fs.set_sun(40.0, 160.0)
    ids = m.segment_id[:60]
    est = AdaptiveEstimator(fs, ids, 0.3, bounces=1, seed=2, pilot=32, max_samples=64)
    assert len(est.groups) >= 1
    for x, per_sun in zip(POINTS[:2], est.render_many(POINTS[:2], SUNS[:2])):
        for sun, r in zip(SUNS[:2], per_sun):
            fs.set_optics(**dict(zip(LEAF_PARAMETERS, x)))
            fs.set_sun(*sun)
            ref = est.render()
            for p in PARTS:
                np.testing.assert_array_equal(getattr(r, p), getattr(ref, p))
                np.testing.assert_array_equal(r.se[p], ref.se[p])


def test_coupled_model_render_many_equals_render(quick):
    m, _ = quick
    thetas = [dict(zip(LEAF_PARAMETERS, x)) for x in POINTS[:3]]
    for th, (v, s) in zip(thetas, m.render_many(thetas)):
        rv, rs = m.render(th)
        assert v.dtype == np.asarray(rv).dtype and v.shape == rv.shape == (int(m.day.sum()), len(PARTS), m.n_columns)
        np.testing.assert_array_equal(v, np.asarray(rv))
        np.testing.assert_array_equal(s, np.asarray(rs))


def test_render_many_bad_input(quick):
    m, fs = quick
    est = SensorEstimator(fs, m.sensors, bounces=1, seed=0)
    with pytest.raises(InputError, match="leaf"):
        next(est.render_many([[0.5, 1.5, 0.2]]))
    with pytest.raises(InputError, match="suns"):
        next(est.render_many([[0.5, 0.5, 0.2]], [[30.0, 100.0, 1.0]]))


def test_a_sun_rendered_before_reuses_its_shadow_rays(quick, monkeypatch):
    """A render at a sun rendered before weighs the shadow rays kept from then (no new ones) and
    gives the bits of that first render, ray counts included; past the memory budget the least
    recently rendered sun's shadow rays are dropped, never the current sun's."""
    from lightfit.light import projection

    m, fs = quick
    sc = m.scenario
    fs.set_optics(specular=0.5, roughness=0.5, subsurface=0.3)
    est = SegmentEstimator(fs, m.segment_id, samples=sc.samples, bounces=sc.bounces, seed=3)
    cast = []
    sun_rays = est._sun_rays
    monkeypatch.setattr(est, "_sun_rays", lambda geo: cast.append(tuple(fs.sun)) or sun_rays(geo))
    renders = []
    for sun in (SUNS[0], SUNS[1], SUNS[0]):
        fs.set_sun(*sun)
        renders.append(est.render())
    assert len(cast) == 2
    assert_same(renders[2], renders[0])
    monkeypatch.setattr(projection, "SUN_HITS_BUDGET_BYTES", 1.5 * est.n_evaluations * (4 + est.bounces))
    fs.set_sun(*SUNS[1])
    again = est.render()
    assert len(cast) == 2 and list(est._suns_kept) == [est._sun_key()]
    assert_same(again, renders[1])
    monkeypatch.setattr(projection, "SUN_HITS_BUDGET_BYTES", 0)
    fs.set_sun(*SUNS[0])
    est.render()  # dropped above: cast again, and kept alone even with no budget
    assert len(cast) == 3 and list(est._suns_kept) == [est._sun_key()]


def test_shadow_rays_past_the_budget_drop_the_least_recently_rendered_sun(monkeypatch):
    """A budget for two suns' shadow rays; suns rendered A, B, A, C: B is the least recently
    rendered (A was rendered again after it), so C's rays push out B's, and a render at A then
    casts no new ray while one at B does. Counted by the rays cast per sun, on a small
    periodic canopy."""
    from test_periodic import canopy, leaf_ids

    from lightfit.light import projection
    from lightfit.light.scene import Optics
    from lightfit.plant.periodic import PeriodicCell

    cell = PeriodicCell(0.3, 0.3, row_direction_deg=90.0)
    mesh, _ = canopy(cell, 2.0, "spherical", np.random.default_rng(5), leaf=0.03, z=(0.05, 0.5), sensors=2)
    fs = FieldScene(mesh, Optics.preset("prospect"), cell=cell)
    est = SegmentEstimator(fs, leaf_ids(mesh), samples=8, bounces=1, seed=3)
    monkeypatch.setattr(projection, "SUN_HITS_BUDGET_BYTES", 2.5 * est.n_evaluations * (4 + est.bounces))
    cast = []
    sun_rays = est._sun_rays
    monkeypatch.setattr(est, "_sun_rays", lambda geo: cast.append(tuple(fs.sun)) or sun_rays(geo))
    a, b, c = (40.0, 150.0), (20.0, 100.0), (60.0, 250.0)
    first = {}
    for sun in (a, b, a, c):
        fs.set_sun(*sun)
        first.setdefault(sun, est.render())
    assert len(cast) == 3  # A's second render weighed its kept rays
    fs.set_sun(*a)
    again = est.render()
    assert len(cast) == 3  # A kept: rendered more recently than B
    np.testing.assert_array_equal(again.absorbed_sun, first[a].absorbed_sun)
    fs.set_sun(*b)
    est.render()
    assert len(cast) == 4  # B dropped when C came


def test_bridge_render_many_renders_a_leaf_outside_the_box_as_the_clamped_leaf(quick):
    """The light bridge renders a leaf outside [0, 1] as the clamped leaf (its forward rule: the render
    is flat outside the box), in render_many as in the callback: the values at (1.3, 0.5, −0.1) are
    bitwise those at (1, 0.5, 0) (a mutation audit: render_many without the clamp survived)."""
    m, _ = quick
    days = np.flatnonzero(m.day)[:2]
    suns = np.stack([np.asarray(m.sun_deg[i], np.float64) for i in days])
    outside, clamped = np.array([[1.3, 0.5, -0.1]]), np.array([[1.0, 0.5, 0.0]])
    (v_out, s_out), (v_in, s_in) = (
        next(m.irradiance.render_many(x, suns, m.scenario.seed)) for x in (outside, clamped)
    )
    assert v_out.shape == (len(days), len(PARTS), m.n_columns) and np.isfinite(v_out).all()
    np.testing.assert_array_equal(v_out, v_in)
    np.testing.assert_array_equal(s_out, s_in)
