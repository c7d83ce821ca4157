"""Direct light by projection (lightfit.light.projection; SegmentEstimator(direct="projection")).

References: analytic values for a leaf that covers the whole periodic cell (every ray lands on
it: the direct sun is exactly sin β per unit DNI, the sky exactly 1 per unit DHI, and the
absorbed parts the leaf's absorptance at the sun's incidence and integrated over the cosine-
weighted sky, from ``leaf_albedo``, itself checked against the sampled leaf BSDF in
test_light_bsdf.py); the path estimator's own direct light (same expectation, independent random
numbers: canopy totals and per-segment z-scores); the paths' scattered light, which must be the
same random numbers in both modes; finite differences with common random numbers for the
gradient; and bitwise repeatability.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from test_periodic import canopy, leaf_ids, square

from lightfit.errors import InputError
from lightfit.light.backend import mitsuba
from lightfit.light.bsdf import leaf_albedo
from lightfit.light.estimator import SegmentEstimator
from lightfit.light.scene import FieldScene, Optics, sun_vector
from lightfit.plant.periodic import PeriodicCell

OPTICS = Optics.preset("prospect")


def _albedo(fs, mu):
    mi = mitsuba()
    return np.asarray(leaf_albedo(fs.bsdf, mi.Float(np.asarray(mu, np.float32))), dtype=np.float64)


def test_a_leaf_covering_the_cell_gets_the_analytic_direct_light():
    cell = PeriodicCell(0.2, 0.3, row_direction_deg=70.0, center_xy=(0.05, -0.1))
    mesh = square([0.0, 0.0, 0.4], [0, 0, 1], 1.0, 1)
    # The square spans the cell exactly: its corners at the cell's.
    mesh.vertices[:, :2] = cell.corners_xy
    fs = FieldScene(mesh, OPTICS, cell=cell)
    el = 35.0
    fs.set_sun(el, 120.0)
    est = SegmentEstimator(fs, [1], samples=8, bounces=0, seed=3, direct="projection", direct_rays_per_m2=2e6)
    r = est.render()
    s = math.sin(math.radians(el))
    assert r.incident_sun[0] == pytest.approx(s, rel=1e-6)
    assert r.incident_sky[0] == pytest.approx(1.0, rel=1e-6)
    assert r.front("incident_sun")[0] == pytest.approx(s, rel=1e-6)  # the upper side is lit
    assert r.absorbed_sun[0] == pytest.approx(s * (1 - _albedo(fs, [s])[0]), rel=1e-5)
    assert r.se["incident_sun"][0] < 1e-6 and r.se["incident_sky"][0] < 1e-6
    # Sky: absorptance averaged over the cosine-weighted hemisphere, ∫ (1 − ρ(μ)) 2μ dμ.
    mu = (np.arange(20000) + 0.5) / 20000
    expected = np.sum((1 - _albedo(fs, mu)) * 2 * mu) / len(mu)
    assert r.absorbed_sky[0] == pytest.approx(expected, abs=4 * r.se["absorbed_sky"][0] + 1e-5)
    proj = r.meta["direct_projection"]
    assert proj["sun"]["hits"] == proj["sun"]["rays"] and proj["sky"]["hits"] == proj["sky"]["rays"]


@pytest.fixture(scope="module")
def field():
    cell = PeriodicCell(0.3, 0.3, row_direction_deg=90.0)
    mesh, _ = canopy(cell, 2.0, "spherical", np.random.default_rng(5), leaf=0.03, z=(0.05, 0.5), sensors=2)
    fs = FieldScene(mesh, OPTICS, cell=cell)
    fs.set_sun(40.0, 150.0)
    return fs, leaf_ids(mesh)


@pytest.mark.parametrize(
    ("bounces", "soil_albedo", "sky"),
    [(0, None, "isotropic"), (2, None, "isotropic"), (1, 0.6, "isotropic"), (0, None, "overcast")],
)
def test_projection_estimates_what_the_paths_estimate(field, bounces, soil_albedo, sky):
    """Same expectation, independent random numbers (0 bounces: the direct light; 2: also the
    light scattered once by a leaf or the soil, forward, and the rest by the paths; 1 over a
    bright soil: the soil's share large; the CIE overcast sky, whose radiance the projection's sky
    rays weigh by their own direction and the paths by theirs): canopy totals within 4 combined SE
    and per-segment z-scores centred on 0 with unit spread."""
    fs, ids = field
    if soil_albedo is not None or sky != "isotropic":
        optics = OPTICS if soil_albedo is None else Optics.preset("prospect", soil_albedo=soil_albedo)
        fs = FieldScene(fs.mesh, optics, cell=fs.cell, sky=sky)
        fs.set_sun(40.0, 150.0)
    z_all = {}
    for seed in (1, 2):
        paths = SegmentEstimator(fs, ids, samples=64, bounces=bounces, seed=seed).render()
        proj = SegmentEstimator(fs, ids, samples=64, bounces=bounces, seed=seed, direct="projection").render()
        area = paths.meta["area_m2"]
        for part in ("incident_sun", "incident_sky", "absorbed_sun", "absorbed_sky"):
            a, b = getattr(paths, part), getattr(proj, part)
            sa, sb = paths.se[part], proj.se[part]
            ta, tb = (a * area).sum(), (b * area).sum()
            st = math.hypot(math.sqrt(((sa * area) ** 2).sum()), math.sqrt(((sb * area) ** 2).sum()))
            assert abs(ta - tb) <= 4 * st, (seed, part, ta, tb, st)
            ok = (sa > 0) & (sb > 0)
            z_all.setdefault(part, []).append((a[ok] - b[ok]) / np.hypot(sa[ok], sb[ok]))
        # The projection is the less noisy of the two (the reason it exists).
        assert np.median(proj.relative_se()) < 0.6 * np.median(paths.relative_se())
    for part, z in z_all.items():
        z = np.concatenate(z)
        assert abs(z.mean()) < 0.15 and 0.7 < z.std() < 1.4, (part, z.mean(), z.std())


def test_reported_standard_errors_match_the_seed_spread(field):
    """Each render's per-segment SE (from its R = 4 replicates, projection and paths, the sun–sky
    covariance included) against the spread of 12 seeds' values of absorbed PAR (sun + 0.3·sky):
    per segment, spread ÷ mean SE² is F(11, 36)-distributed, expectation 36/34; its mean over the
    field's 200 segments must be within ±0.15 of that (measured 0.99–1.08 for seed sets 0–11 …
    36–47); SEs 20 % too small would put it near 1.65. The milder effect of 4 TEA rounds (1.06–1.16
    here) is caught by the test of the random words above, and measured on the 100-plant cell by
    ``benchmarks/bench_se_calibration.py``."""
    fs, ids = field
    ests = [SegmentEstimator(fs, ids, samples=16, bounces=2, seed=s, direct="projection") for s in range(12)]
    assert ests[0].replicates == 4
    runs = [e.render() for e in ests]
    tot = np.array([r.total("absorbed", 1.0, 0.3) for r in runs])
    se2 = np.array([r.total_se() ** 2 for r in runs])
    ok = np.all(np.isfinite(se2) & (se2 > 0), axis=0)
    assert ok.sum() > 0.8 * len(ids)
    ratio = tot.var(0, ddof=1)[ok] / se2.mean(0)[ok]
    assert ratio.mean() == pytest.approx(36 / 34, abs=0.15), ratio.mean()


def test_with_a_projection_the_paths_carry_only_light_scattered_twice_and_more(field):
    """The projection has the direct light and the light scattered once by a leaf or the soil
    (a bright soil here): with one bounce nothing is left to the paths (exactly 0), with two
    bounces only the second order is (a few per cent of the scattered light)."""
    fs0, ids = field
    bright_soil = FieldScene(fs0.mesh, Optics.preset("prospect", soil_albedo=0.5), cell=fs0.cell)
    bright_soil.set_sun(40.0, 150.0)
    for bounces in (1, 2):
        est = SegmentEstimator(bright_soil, ids, samples=16, bounces=bounces, seed=4, direct="projection")
        r = est.render()
        d = est._direct_values()
        paths = {p: getattr(r, p) - d[p].mean(1) for p in ("incident_sun", "absorbed_sun", "incident_sky")}
        none = SegmentEstimator(bright_soil, ids, samples=16, bounces=bounces, seed=4, direct="none").render()
        for p, v in paths.items():
            np.testing.assert_allclose(v, getattr(none, p), rtol=1e-5, atol=1e-7)
            if bounces == 1:
                assert np.all(getattr(none, p) == 0), p
            else:
                assert 0 < v.sum() < 0.2 * d[p].mean(1).sum(), p
        soil = [h for h in est._direct.hits("sun") if h.part == "via_soil"]
        assert all(h.soil for h in soil) and sum(int(np.asarray(h.index).size) for h in soil) > 0
    # The soil's share is the projection's, and it scales with the soil's albedo: the same rays over
    # a black soil (albedo 0) and one of half the albedo (0.25) leave the projection's via-soil part
    # v(a) = d(a) − d(0) with v(0.5) = 2·v(0.25), segment by segment (measured to 3e-14 relative;
    # the per-hit fixed point sums are exact to ~1e-16 here), and that part is not negligible
    # (≈ 9 % of the projected light over this bright soil).
    d = {0.5: est._direct_values()}
    for a in (0.0, 0.25):
        fs = FieldScene(fs0.mesh, Optics.preset("prospect", soil_albedo=a), cell=fs0.cell)
        fs.set_sun(40.0, 150.0)
        d[a] = SegmentEstimator(fs, ids, samples=16, bounces=2, seed=4, direct="projection")._direct_values()
    for p in ("incident_sun", "absorbed_sun", "incident_sky", "absorbed_sky"):
        v = {a: d[a][p].mean(1) - d[0.0][p].mean(1) for a in (0.25, 0.5)}
        assert v[0.5].sum() > 0.05 * d[0.5][p].mean(1).sum(), p
        np.testing.assert_allclose(v[0.5], 2 * v[0.25], rtol=1e-9, atol=1e-12, err_msg=p)


def test_renders_are_repeatable_and_keep_across_suns(field):
    fs, ids = field
    kw = dict(samples=8, bounces=1, seed=7, direct="projection", direct_rays_per_m2=3e6)
    a = SegmentEstimator(fs, ids, **kw).render()
    est = SegmentEstimator(fs, ids, **kw)
    b = est.render()
    for part in ("incident_sun", "incident_sky", "absorbed_sun", "absorbed_sky"):
        assert np.array_equal(getattr(a, part), getattr(b, part))
        assert np.array_equal(a.se[part], b.se[part])
    fs.set_sun(10.0, 250.0)
    try:
        low = est.render()
        fs.set_sun(-5.0, 250.0)
        night = est.render()
    finally:
        fs.set_sun(40.0, 150.0)
    assert np.array_equal(est.render().absorbed_sun, b.absorbed_sun)
    assert not np.array_equal(low.absorbed_sun, b.absorbed_sun)
    assert np.all(night.incident_sun == 0) and np.all(night.absorbed_sun == 0)
    assert np.array_equal(night.incident_sky, b.incident_sky)  # the sky does not depend on the sun
    # render_many weighs the kept hits: bitwise a render at each point and sun.
    many = list(est.render_many([[0.2, 0.7, 0.4]], [[40.0, 150.0], [10.0, 250.0]]))[0]
    fs.set_optics(specular=0.2, roughness=0.7, subsurface=0.4)
    try:
        ref = est.render()
    finally:
        fs.set_optics(**{k: getattr(OPTICS, k) for k in ("specular", "roughness", "subsurface")})
    assert np.array_equal(many[0].absorbed_sun, ref.absorbed_sun)
    assert np.array_equal(many[0].absorbed_sky, ref.absorbed_sky)


def test_suns_are_kept_within_the_memory_budget(field, monkeypatch):
    """A render at a sun seen before reuses its projected hits (no cast; bitwise the same values);
    past the budget the least recently used sun is dropped, after a render and when a
    render_many ends or is closed early (with budget 0: the scene's sun only)."""
    from lightfit.light import projection

    fs, ids = field
    suns = [(40.0, 150.0), (10.0, 250.0), (25.0, 200.0)]
    vec = {s: tuple(float(v) for v in sun_vector(*s)) for s in suns}
    est = SegmentEstimator(fs, ids, samples=8, bounces=1, seed=9, direct="projection", direct_rays_per_m2=2e6)
    proj = est._direct
    casts = []
    cast = proj._cast
    monkeypatch.setattr(proj, "_cast", lambda kind: casts.append(kind) or cast(kind))
    first = {}
    try:
        for s in suns + suns[:1]:
            fs.set_sun(*s)
            first.setdefault(s, est.render())
        assert casts.count("sun") == 3 and proj.kept_suns() == [vec[s] for s in (suns[1], suns[2], suns[0])]
        again = est.render()  # (40°, 150°) once more: kept, the same bits
        assert casts.count("sun") == 3 and np.array_equal(again.absorbed_sun, first[suns[0]].absorbed_sun)
        # A budget for about two suns: the least recently used, (10°, 250°), goes.
        per_sun = max(proj.kept_sun_bytes().values())
        monkeypatch.setattr(projection, "SUN_HITS_BUDGET_BYTES", 2.5 * per_sun)
        est.render()
        assert proj.kept_suns() == [vec[suns[2]], vec[suns[0]]]
        fs.set_sun(*suns[1])  # a reverse pass at a dropped sun casts it, and trims as a render does
        est.vjp({"absorbed_sun": np.ones(len(ids))})
        assert proj.kept_suns() == [vec[suns[0]], vec[suns[1]]]
        fs.set_sun(*suns[0])
        # render_many keeps all its suns while it runs; done or closed early, it trims them.
        monkeypatch.setattr(projection, "SUN_HITS_BUDGET_BYTES", 0)
        many = est.render_many([[0.2, 0.7, 0.4], [0.3, 0.6, 0.5]], [list(s) for s in suns])
        next(many)
        assert sorted(proj.kept_suns()) == sorted(vec.values())
        many.close()
        assert proj.kept_suns() == [vec[suns[0]]]  # the scene's sun
        list(est.render_many([[0.2, 0.7, 0.4]], [list(s) for s in suns]))
        assert proj.kept_suns() == [vec[suns[0]]]
    finally:
        fs.set_sun(40.0, 150.0)


def test_a_pass_where_no_ray_goes_on_gives_empty_scattered_hits(field, monkeypatch):
    """A pass none of whose rays is continued (a short last pass can have none; a benchmark with
    other random words met one) used to fail inside Dr.Jit (an empty array divided by a scalar).
    Now its scattered hit sets are empty: the direct hits are those of a normal render, bit for
    bit, and the values and gradient are finite."""
    import drjit as dr

    from lightfit.light import projection

    fs, ids = field
    kw = dict(samples=8, bounces=2, seed=5, direct="projection", direct_rays_per_m2=(1e6, 2e6))
    ct = {"absorbed_sun": np.ones(len(ids)), "absorbed_sky": np.full(len(ids), 0.3)}
    normal = SegmentEstimator(fs, ids, **kw)
    normal.render()
    monkeypatch.setattr(projection, "CONTINUED_SHARE", {"sun": 1e-12, "sky": 1e-12})
    est = SegmentEstimator(fs, ids, **kw)
    r, g = est.render(), est.vjp(ct)
    for kind in ("sun", "sky"):
        direct, via_leaf, via_soil = est._direct.hits(kind)
        assert dr.width(via_leaf.mu) == dr.width(via_soil.mu) == 0, kind
        ref = normal._direct.hits(kind)[0]
        assert np.array_equal(np.asarray(direct.index), np.asarray(ref.index)), kind
        assert np.array_equal(np.asarray(direct.mu), np.asarray(ref.mu)), kind
    for part in ("incident_sun", "incident_sky", "absorbed_sun", "absorbed_sky"):
        assert np.isfinite(getattr(r, part)).all() and (getattr(r, part) >= 0).all(), part
    assert all(np.isfinite(v) for v in g.values()), g


def test_casting_in_passes_gives_the_same_values_and_counts(field, monkeypatch):
    """The rays are keyed by their index and summed in fixed point: cast in many small passes
    (:data:`CAST_CHUNK`) they give one pass's values and SEs to the bit and the summary's counts
    add up; the gradient, summed per pass in float64, agrees to rounding."""
    from lightfit.light import projection

    fs, ids = field
    kw = dict(samples=8, bounces=2, seed=5, direct="projection", direct_rays_per_m2=(1e6, 2e6))
    ct = {"absorbed_sun": np.ones(len(ids)), "incident_sky": np.full(len(ids), 0.3)}
    one = SegmentEstimator(fs, ids, **kw)
    a, ga = one.render(), one.vjp(ct)
    assert len(one._direct.hits("sky")) == 3  # the default CAST_CHUNK: one pass here
    n_rays = a.meta["direct_projection"]["sky"]["rays"]
    monkeypatch.setattr(projection, "CAST_CHUNK", n_rays // 7 + 1)  # 7 passes, the last shorter
    many = SegmentEstimator(fs, ids, **kw)
    b, gb = many.render(), many.vjp(ct)
    assert len(many._direct.hits("sky")) == 3 * 7
    for part in ("incident_sun", "incident_sky", "absorbed_sun", "absorbed_sky"):
        assert np.array_equal(getattr(a, part), getattr(b, part)), part
        assert np.array_equal(a.se[part], b.se[part]), part
    assert a.meta["direct_projection"] == b.meta["direct_projection"]
    assert gb == pytest.approx(ga, rel=1e-6)


def test_gradient_matches_finite_differences_with_common_random_numbers(field):
    fs, ids = field
    ct = {"absorbed_sun": np.ones(len(ids)), "absorbed_sky": np.full(len(ids), 0.3)}

    def J(r):
        return sum(np.sum(ct[p] * getattr(r, p)) for p in ct)

    # The albedo is a cubic (Catmull–Rom) in roughness between table nodes 1/32 apart: a step of
    # 0.002 keeps the central difference's truncation (h² × the third derivative / 6) below the
    # float32 noise; 0.01 was 1.4e-3 off (exact while the table was linear in a cell).
    x = {"specular": 0.5, "roughness": 0.515, "subsurface": 0.45}
    h = {"specular": 0.1, "roughness": 0.002, "subsurface": 0.1}
    est = SegmentEstimator(fs, ids, samples=8, bounces=1, seed=2, direct="projection", direct_rays_per_m2=3e6)
    try:
        fs.set_optics(**x)
        g = est.vjp(ct)
        for k, step in h.items():
            fs.set_optics(**{k: x[k] + step})
            jp = J(est.render())
            fs.set_optics(**{k: x[k] - step})
            jm = J(est.render())
            fs.set_optics(**{k: x[k]})
            fd = (jp - jm) / (2 * step)
            assert np.isfinite(g[k])
            # Measured: specular 3.5e-7, roughness 5.6e-5 (2.5e-4 at h = 0.004), subsurface 1.4e-6
            # relative; 1e-3 leaves a 4-fold margin over the worst step tried.
            assert g[k] == pytest.approx(fd, rel=1e-3), (k, g[k], fd)
    finally:
        fs.set_optics(**{k: getattr(OPTICS, k) for k in x})


def test_bad_settings_are_refused(field):
    fs, ids = field
    with pytest.raises(InputError, match="direct"):
        SegmentEstimator(fs, ids, direct="rasterised")
    # "12" is not the pair (1, 2); 1e12 per m² is a typo for 1e7 that would cast for days
    for bad in (0, "12", (1e6,), (1e6, float("nan")), True, 1e12, (1e7, 1.1e10)):
        with pytest.raises(InputError, match="direct_rays_per_m2"):
            SegmentEstimator(fs, ids, direct="projection", direct_rays_per_m2=bad)
    with pytest.raises(InputError, match="first"):
        SegmentEstimator(fs, ids, direct="projection", first=8)
    finite = FieldScene(fs.mesh, OPTICS)
    with pytest.raises(InputError, match="periodic"):
        SegmentEstimator(finite, ids, direct="projection")


def test_adaptive_rounds_add_paths_to_one_projection(field, monkeypatch):
    """render_adaptive with a projection: a segment stopped at K has the estimate of a plain
    projection render with K samples, or — where the projected part alone was above the target —
    of a plain render with the paths' direct light; the AdaptiveEstimator keeps it (render,
    render_many, vjp)."""
    from lightfit.light.estimator import PARTS, AdaptiveEstimator, render_adaptive

    fs, ids = field
    kw = dict(bounces=1, seed=3, max_samples=256, direct="projection", direct_rays_per_m2=3e5)
    r = render_adaptive(fs, ids, 0.05, **kw)
    K, rse, projected = r.meta["samples_per_segment"], r.meta["reached_rse"], r.meta["projected"]
    assert len(np.unique(K)) >= 2 and projected.any() and not projected.all()
    assert ((rse <= 0.05) | (K == 256) | ~np.isfinite(rse) | r.meta["stopped_on_floor"]).all()
    for proj in (True, False):
        for k in np.unique(K[projected == proj])[:2]:
            sel = (K == k) & (projected == proj)
            mode = dict(direct="projection", direct_rays_per_m2=3e5) if proj else {}
            fixed = SegmentEstimator(fs, ids[sel], samples=int(k), bounces=1, seed=3, **mode).render()
            # Switched segments: a plain render adds each evaluation's direct and scattered light
            # in float32, the switch adds their means in float64 (rounding, ~1e-9).
            rtol = 1e-10 if proj else 1e-7
            for p in PARTS:
                np.testing.assert_allclose(getattr(r, p)[sel], getattr(fixed, p), rtol=rtol, atol=1e-14)
                np.testing.assert_allclose(r.se[p][sel], fixed.se[p], rtol=100 * rtol, atol=1e-12)
    est = AdaptiveEstimator(fs, ids, 0.05, **kw)
    again = est.render()
    for p in PARTS:  # switched segments: to float32 rounding, as above
        np.testing.assert_allclose(getattr(again, p), getattr(r, p), rtol=1e-7, atol=1e-14)
    from lightfit.light import projection

    with monkeypatch.context() as m:  # no budget: render_many trims to the scene's sun when done
        m.setattr(projection, "SUN_HITS_BUDGET_BYTES", 0)
        many = list(est.render_many([[0.3, 0.6, 0.5]], [[40.0, 150.0], [25.0, 200.0]]))[0]
        assert est._direct.kept_suns() == [tuple(float(v) for v in fs.sun)]
    state = fs.optics
    try:
        fs.set_optics(specular=0.3, roughness=0.6, subsurface=0.5)
        fs.set_sun(25.0, 200.0)
        ref = est.render()
    finally:
        fs.set_optics(**{k: getattr(state, k) for k in ("specular", "roughness", "subsurface")})
        fs.set_sun(40.0, 150.0)
    np.testing.assert_allclose(many[1].absorbed_sun, ref.absorbed_sun, rtol=1e-10, atol=1e-14)
    np.testing.assert_allclose(many[1].absorbed_sky, ref.absorbed_sky, rtol=1e-10, atol=1e-14)
    ct = {"absorbed_sun": np.ones(len(ids))}
    g = est.vjp(ct)
    step = 0.1
    vals = []
    for x in (0.5 + step, 0.5 - step):
        fs.set_optics(specular=x)
        vals.append(est.render().absorbed_sun.sum())
    fs.set_optics(specular=state.specular)
    # Frozen sampling, common random numbers, the render polynomial in specular: measured 4e-7 relative.
    assert g["specular"] == pytest.approx((vals[0] - vals[1]) / (2 * step), rel=1e-3)


@pytest.mark.parametrize("elevation", [0.2, 90.0])
def test_extreme_suns_and_parameter_bounds_stay_finite(field, elevation):
    """Grazing and zenith sun, every leaf parameter at its bounds: finite values and gradients, and
    at grazing sun the canopy (no gap at 0.2°) intercepts exactly the cell's beam, A_c·sin β."""
    fs, ids = field
    all_ids = np.unique(fs.mesh.face_segment)
    est = SegmentEstimator(fs, all_ids, samples=8, bounces=1, seed=1, direct="projection", direct_rays_per_m2=3e6)
    ct = {"absorbed_sun": np.ones(len(all_ids)), "absorbed_sky": np.ones(len(all_ids))}
    fs.set_sun(elevation, 80.0)
    try:
        for x in ((0.0, 0.0, 0.0), (1.0, 1.0, 1.0), (0.0, 1.0, 0.0), (1.0, 0.0, 1.0)):
            fs.set_optics(**dict(zip(("specular", "roughness", "subsurface"), x)))
            r = est.render()
            for p in ("incident_sun", "absorbed_sun", "incident_sky", "absorbed_sky"):
                assert np.isfinite(getattr(r, p)).all() and np.isfinite(r.se[p]).all(), (x, p)
                assert (getattr(r, p) >= 0).all()
            assert all(np.isfinite(v) for v in est.vjp(ct).values()), x
        if elevation < 1:  # the direct sun alone (0 bounces: nothing scattered)
            kw = dict(samples=8, bounces=0, seed=1, direct="projection", direct_rays_per_m2=3e6)
            d = SegmentEstimator(fs, all_ids, **kw).render()
            beam = fs.cell.area_m2 * math.sin(math.radians(elevation))
            assert (d.incident_sun * d.meta["area_m2"]).sum() == pytest.approx(beam, rel=1e-6)
    finally:
        fs.set_optics(**{k: getattr(OPTICS, k) for k in ("specular", "roughness", "subsurface")})
        fs.set_sun(40.0, 150.0)


def test_a_segment_without_area_gets_zero_light_not_nan():
    """A segment whose faces are all degenerate has no area: the projection gives it 0 (as the paths
    do), with a finite SE and gradient, and its neighbour's light is unchanged."""
    from lightfit.plant.mesh import Mesh

    cell = PeriodicCell(0.3, 0.3, row_direction_deg=90.0)
    leaf = square([0.0, 0.0, 0.4], [0, 0, 1], 0.1, 7)
    flat = Mesh(
        np.array([[0, 0, 0.2], [0.05, 0, 0.2], [0.1, 0, 0.2]]), np.array([[0, 1, 2]]), np.array([9]), np.array([True])
    )
    kw = dict(samples=8, bounces=1, seed=2, direct="projection", direct_rays_per_m2=2e6)
    ests, rs = [], []
    for mesh, ids in ((Mesh.concatenate([leaf, flat]), [7, 9]), (leaf, [7])):
        fs = FieldScene(mesh, OPTICS, cell=cell)
        fs.set_sun(50.0, 180.0)
        ests.append(SegmentEstimator(fs, ids, **kw))
        rs.append(ests[-1].render())
    r = rs[0]
    assert r.meta["area_m2"][1] == 0.0
    for p in ("incident_sun", "absorbed_sun", "incident_sky", "absorbed_sky"):
        assert getattr(r, p)[1] == 0.0 and r.se[p][1] == 0.0, p
        assert getattr(r, p)[0] == getattr(rs[1], p)[0], p
    assert r.front("incident_sun")[0] == pytest.approx(math.sin(math.radians(50.0)), rel=0.02)  # nothing above
    grad = ests[0].vjp({"absorbed_sun": np.ones(2), "absorbed_sky": np.ones(2)})
    assert all(np.isfinite(v) for v in grad.values())


def test_gradient_of_incident_light_includes_the_projected_scattering(field):
    """With a projection the light scattered once by a leaf reaches a segment through the leaf's
    BSDF weight, so even incident light depends on the leaf parameters: its gradient equals
    common-random-number differences (subsurface moves reflection against transmission)."""
    fs, ids = field
    ct = {"incident_sun": np.ones(len(ids)), "incident_sky": np.full(len(ids), 0.3)}

    def J(r):
        return sum(np.sum(ct[p] * getattr(r, p)) for p in ct)

    est = SegmentEstimator(fs, ids, samples=8, bounces=1, seed=2, direct="projection", direct_rays_per_m2=3e6)
    x0, step = OPTICS.subsurface, 0.1
    g = est.vjp(ct)["subsurface"]
    try:
        fs.set_optics(subsurface=x0 + step)
        jp = J(est.render())
        fs.set_optics(subsurface=x0 - step)
        jm = J(est.render())
    finally:
        fs.set_optics(subsurface=x0)
    fd = (jp - jm) / (2 * step)
    assert abs(fd) > 0
    assert g == pytest.approx(fd, rel=1e-3), (g, fd)  # measured 1.2e-6 relative


def test_adaptive_projection_follows_the_bounces(field):
    """With 0 bounces there is no scattered light to project: an adaptive render's segments equal
    a plain projection render at their K (the projection is built from the bounces in one place)."""
    from lightfit.light.estimator import PARTS, render_adaptive

    fs, ids = field
    kw = dict(bounces=0, seed=6, direct="projection", direct_rays_per_m2=3e5)
    r = render_adaptive(fs, ids, 0.2, max_samples=64, **kw)
    K, projected = r.meta["samples_per_segment"], r.meta["projected"]
    sel = projected & (K == K[projected].min())
    fixed = SegmentEstimator(fs, ids[sel], samples=int(K[sel][0]), **kw).render()
    for p in PARTS:
        np.testing.assert_allclose(getattr(r, p)[sel], getattr(fixed, p), rtol=1e-10, atol=1e-14)


def test_light_floor_leaves_the_other_segments_as_they_were():
    """With the projection, the light floor stops dark segments and changes nothing else: every
    segment it does not stop keeps its K, its projected-or-own direct light and its values (the
    default 4-plant cell, whose culms inside their sheaths are dark)."""
    from lightfit.light.estimator import PARTS, render_adaptive
    from lightfit.light.scene import Optics
    from lightfit.plant import Field, build

    g = build(Field(n_plants=4, seed=1), progress=False)
    ids = g.segments.loc[g.segments.measured, "segment_id"].to_numpy()
    fs = FieldScene(g.mesh, Optics.preset("paper"), cell=g.cell)
    fs.set_sun(50.0, 180.0)
    kw = dict(bounces=2, seed=1, max_samples=256, direct="projection")
    plain = render_adaptive(fs, ids, 0.1, dark_floor=0.0, **kw)
    # A floor of 5 % (judged from 3 / f = 60 points on, below the cap of 256; the default 0.5 %
    # waits for 600).
    r = render_adaptive(fs, ids, 0.1, dark_floor=0.05, **kw)
    on = r.meta["stopped_on_floor"]
    assert on.sum() >= 3 and not plain.meta["stopped_on_floor"].any()
    keep = ~on
    np.testing.assert_array_equal(r.meta["samples_per_segment"][keep], plain.meta["samples_per_segment"][keep])
    np.testing.assert_array_equal(r.meta["projected"][keep], plain.meta["projected"][keep])
    for p in PARTS:
        np.testing.assert_array_equal(getattr(r, p)[keep], getattr(plain, p)[keep])
    assert (r.meta["samples_per_segment"][on] <= plain.meta["samples_per_segment"][on]).all()
    assert r.meta["n_evaluations"] < plain.meta["n_evaluations"]
    # A segment without light goes on until 3 / f points (the rule of three puts its light under
    # the floor): 64 for f = 0.05; without the floor, to the cap.
    for run, k in ((r, 64), (plain, 256)):
        unlit = ~np.isfinite(run.meta["reached_rse"])
        assert unlit.sum() >= 3 and (run.meta["samples_per_segment"][unlit] == k).all()
        assert run.meta["stopped_on_floor"][unlit].all() == (run is r)


@pytest.mark.parametrize("direct", ["paths", "projection"])
def test_light_transmitted_by_a_layer_is_absorbed_as_white_sky_light(direct):
    """Two horizontal leaf layers covering a periodic cell, the sun at 5°, black soil, one bounce.
    The lower layer is in full shade: all its sunlight is the upper layer's diffuse transmission, exactly
    Lambertian in this BSDF (w_t/π), so it receives w_t·sin β of the sun and absorbs it with the
    white-sky absorptance ∫(1 − ρ(μ)) 2μ dμ, not the absorptance at the sun's grazing
    direction, which a mutation audit showed the scattered sun could take unnoticed. Only the glossy
    lobe depends on angle, and its energy loss at grazing only when rough (specular 1, roughness 1:
    0.418 against 0.403 at 5°)."""
    from lightfit.light.bsdf import lobe_weights
    from lightfit.plant.mesh import Mesh

    cell = PeriodicCell(0.2, 0.3, row_direction_deg=90.0)
    layers = []
    for z, seg in ((0.4, 1), (0.2, 2)):
        m = square([0.0, 0.0, z], [0, 0, 1], 1.0, seg)
        m.vertices[:, :2] = cell.corners_xy  # each layer spans the cell exactly
        layers.append(m)
    optics = Optics(specular=1.0, roughness=1.0, subsurface=0.5, base_color=0.6, soil_albedo=0.0)
    fs = FieldScene(Mesh.concatenate(layers), optics, cell=cell)
    el = 5.0
    fs.set_sun(el, 200.0)
    r = SegmentEstimator(
        fs, [1, 2], samples=256, bounces=1, seed=4, direct=direct, direct_rays_per_m2=(2e6, 2e6)
    ).render()
    w_t = lobe_weights(optics.specular, optics.subsurface, optics.base_color)[2]
    s = math.sin(math.radians(el))
    mu = (np.arange(20000) + 0.5) / 20000
    white = float(np.sum((1 - _albedo(fs, mu)) * 2 * mu) / len(mu))
    grazing = float(1 - _albedo(fs, [s])[0])
    assert grazing < white - 0.01  # the test can tell the two apart
    lower = 1  # (the paths' value is exact, the projection's a Monte Carlo estimate)
    assert r.incident_sun[lower] == pytest.approx(w_t * s, abs=4 * r.se["incident_sun"][lower] + 1e-6 * s)
    ratio = r.absorbed_sun[lower] / r.incident_sun[lower]
    assert ratio == pytest.approx(white, abs=4 * r.se["absorbed_sun"][lower] / r.incident_sun[lower] + 1e-3)


def test_standard_errors_and_covariance_are_those_of_the_replicate_means(field):
    """The value is the mean of the R replicate means, its SE their sample standard deviation
    (ddof 1) ÷ √R, the sun–sky covariance their sample covariance ÷ R, and the SE of a total
    dni·sun + dhi·sky that of the replicate totals — computed here by hand from the replicates,
    for a plain render (paths and projection) and an adaptive one (rows at several K)."""
    from lightfit.light.estimator import PARTS, render_adaptive

    fs, ids = field
    runs = [
        SegmentEstimator(fs, ids, samples=16, bounces=1, seed=8).render(),
        SegmentEstimator(fs, ids, samples=16, bounces=1, seed=8, direct="projection", direct_rays_per_m2=1e6).render(),
        render_adaptive(fs, ids, 0.1, bounces=1, seed=8, max_samples=128),
    ]
    assert len(np.unique(runs[2].meta["samples_per_segment"])) >= 2
    for r in runs:
        reps = r.meta["replicate_means"]
        R = reps["incident_sun"].shape[1]
        assert R in (4, 8)
        for p in PARTS:
            x = reps[p]
            np.testing.assert_allclose(getattr(r, p), x.mean(1), rtol=1e-12, atol=1e-15, err_msg=p)
            d = x - x.mean(1, keepdims=True)
            se = np.sqrt((d**2).sum(1) / (R - 1) / R)
            np.testing.assert_allclose(r.se[p], se, rtol=1e-10, atol=1e-15, err_msg=p)
        for part, (dni, dhi) in (("absorbed", (1.0, 0.3)), ("incident", (0.7, 1.8))):
            a, b = reps[f"{part}_sun"], reps[f"{part}_sky"]
            da, db = a - a.mean(1, keepdims=True), b - b.mean(1, keepdims=True)
            np.testing.assert_allclose(r.cov[part], (da * db).sum(1) / (R - 1) / R, rtol=1e-10, atol=1e-15)
            t = dni * a + dhi * b  # the total of each replicate
            dt = t - t.mean(1, keepdims=True)
            se_t = np.sqrt((dt**2).sum(1) / (R - 1) / R)
            assert (se_t > 0).sum() > 0.5 * len(ids)
            np.testing.assert_allclose(r.total_se(part, dni, dhi), se_t, rtol=1e-6, atol=1e-12, err_msg=part)


@pytest.mark.parametrize("direct", ["paths", "projection"])
def test_sky_transmitted_by_a_layer_reaches_the_layer_below(direct):
    """The two layers of the test above, under the sky: the upper layer intercepts all of it
    (1 per unit DHI) and transmits w_t of it, Lambertian, to the lower layer (black soil, one
    bounce), which therefore receives w_t per unit DHI and absorbs it with the white-sky
    absorptance. With the projection this light is carried by the continued sky rays (Russian
    roulette, share 1/4, each carrying 4× the flux), so their weight is checked too."""
    from lightfit.light.bsdf import lobe_weights
    from lightfit.plant.mesh import Mesh

    cell = PeriodicCell(0.2, 0.3, row_direction_deg=90.0)
    layers = []
    for z, seg in ((0.4, 1), (0.2, 2)):
        m = square([0.0, 0.0, z], [0, 0, 1], 1.0, seg)
        m.vertices[:, :2] = cell.corners_xy
        layers.append(m)
    optics = Optics(specular=0.5, roughness=0.6, subsurface=0.5, base_color=0.6, soil_albedo=0.0)
    fs = FieldScene(Mesh.concatenate(layers), optics, cell=cell)
    fs.set_sun(40.0, 200.0)
    r = SegmentEstimator(
        fs, [1, 2], samples=256, bounces=1, seed=4, direct=direct, direct_rays_per_m2=(2e6, 2e6)
    ).render()
    w_t = lobe_weights(optics.specular, optics.subsurface, optics.base_color)[2]
    upper, lower = 0, 1
    assert r.incident_sky[upper] == pytest.approx(1.0, abs=4 * r.se["incident_sky"][upper] + 1e-6)
    assert 0 < r.se["incident_sky"][lower] < 0.1 * w_t  # an estimate fine enough to tell w_t from w_t / 2
    assert r.incident_sky[lower] == pytest.approx(w_t, abs=4 * r.se["incident_sky"][lower] + 1e-6)
    mu = (np.arange(20000) + 0.5) / 20000
    white = float(np.sum((1 - _albedo(fs, mu)) * 2 * mu) / len(mu))
    ratio = r.absorbed_sky[lower] / r.incident_sky[lower]
    assert ratio == pytest.approx(white, abs=4 * r.se["absorbed_sky"][lower] / r.incident_sky[lower] + 1e-3)


def test_rays_cast_are_the_requested_density_over_all_replicates(field):
    """``direct_rays_per_m2`` counts the rays of all replicates together: a render casts that many
    rays per m² of the cell (to the rounding of the grid), not that many per replicate."""
    fs, ids = field
    for samples in (8, 64):  # R = 2 and R = 8
        est = SegmentEstimator(
            fs, ids, samples=samples, bounces=0, seed=1, direct="projection", direct_rays_per_m2=(1e6, 2e6)
        )
        s = est.render().meta["direct_projection"]
        area = fs.cell.area_m2
        for kind, rho in (("sun", 1e6), ("sky", 2e6)):
            assert s[kind]["rays"] == pytest.approx(rho * area, rel=0.02), (samples, kind)
            assert s[kind]["rays_per_m2"] == pytest.approx(rho, rel=0.02), (samples, kind)


def test_more_rays_of_a_kind_than_32_bits_can_number_are_refused_before_casting():
    """A ray's index (UInt32) keys its random numbers and its replicate: past 2³² rays of a kind on
    one render they wrapped (rays repeated, light put in the wrong replicate) or Dr.Jit stopped on a
    pass starting beyond 2³². On a 2 m × 2 m cell (4 m²), 1.1 × 10⁹ sun rays per m² are 4.4 × 10⁹
    > 2³² ≈ 4.295 × 10⁹ rays: refused by name, before anything renders; 10⁹ per m² (4 × 10⁹) is not."""
    from lightfit.light.estimator import render_adaptive

    cell = PeriodicCell(2.0, 2.0, row_direction_deg=90.0)
    fs = FieldScene(square([0.0, 0.0, 0.3], [0, 0, 1], 0.5, 1), OPTICS, cell=cell)
    fs.set_sun(50.0, 180.0)
    kw = dict(samples=8, bounces=0, seed=0, direct="projection")
    est = SegmentEstimator(fs, [1], direct_rays_per_m2=(1.0e9, 1.0e6), **kw)  # built, not cast
    assert est._direct.grid["sun"][0] * est._direct.grid["sun"][1] * est.replicates <= 2**32
    for rays in ((1.1e9, 1.0e6), (1.0e6, 1.1e9)):
        with pytest.raises(InputError, match="direct_rays_per_m2") as info:
            SegmentEstimator(fs, [1], direct_rays_per_m2=rays, **kw)
        assert "4.4e+09 rays" in str(info.value), str(info.value)
        with pytest.raises(InputError, match="direct_rays_per_m2"):
            render_adaptive(fs, [1], 0.1, bounces=0, direct="projection", direct_rays_per_m2=rays)


def test_adaptive_segments_no_projected_ray_met_take_their_own_direct_light(field):
    """At 3 000 rays per m² (≈ 34 per replicate over the 0.09 m² cell) some of the 200 leaves of
    9 cm² meet no projected ray. Their projected part was 0 with SE 0, which more points cannot
    change, yet they stayed projected: 19 of them ended at 0 light, "stopped on the floor" after
    1 024 points each, where an independent path render (K = 256) gives them up to 0.26 per unit
    DNI. Such a segment now takes its direct light from its own points, as a stem the projection
    reaches too rarely does: no segment lit in the reference is left dark, and the per-segment
    z-scores against it are centred with about unit spread."""
    from lightfit.light.estimator import render_adaptive

    fs, ids = field
    a = render_adaptive(fs, ids, 0.1, bounces=1, seed=1, direct="projection", direct_rays_per_m2=3e3)
    ref = SegmentEstimator(fs, ids, samples=256, bounces=1, seed=7).render()
    v, vr = a.total("absorbed", 1.0, 0.3), ref.total("absorbed", 1.0, 0.3)
    lit = vr > 5 * ref.total_se()
    assert lit.sum() > 0.9 * len(ids)
    assert (v[lit] > 0).all(), ids[lit & (v == 0)]
    assert not a.meta["stopped_on_floor"][lit].any()
    z = (v - vr) / np.hypot(a.total_se(), ref.total_se())
    assert abs(z.mean()) < 0.3 and 0.7 < z.std() < 1.5, (z.mean(), z.std())


def test_fewer_rays_than_one_per_replicate_are_refused_not_raised_unsaid(field):
    """10⁻³ rays per m² over the 0.09 m² cell are 9 × 10⁻⁵ rays: the grid was raised to one ray per
    replicate (8 rays, ≈ 89 per m²) with only the render's meta saying so. Refused naming the option and
    the least that casts one ray per replicate, R / A_c = 8 / 0.09 = 88.9 per m²; that many are taken."""
    fs, ids = field
    assert fs.cell.area_m2 == pytest.approx(0.09)
    kw = dict(samples=32, bounces=0, seed=0, direct="projection")
    for rays in (1e-3, (1e7, 80.0), (80.0, 1e7)):
        with pytest.raises(InputError, match=r"direct_rays_per_m2.*fewer than one ray.*at least 88\.9 per m²"):
            SegmentEstimator(fs, ids, direct_rays_per_m2=rays, **kw)
    est = SegmentEstimator(fs, ids, direct_rays_per_m2=(89.0, 1e6), **kw)
    assert est._direct.grid["sun"][0] * est._direct.grid["sun"][1] == 1
