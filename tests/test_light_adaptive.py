"""Adaptive per-segment sampling (``render_adaptive``, ``AdaptiveEstimator``) and the standard error
of the absorbed total (sun–sky covariance), against fixed-K renders, seed-to-seed spread and
finite differences with common random numbers."""

import numpy as np
import pytest

import lightfit  # noqa: F401
from lightfit.errors import InputError
from lightfit.light.bridge import make_irradiance
from lightfit.light.estimator import DARK_FLOOR, PARTS, AdaptiveEstimator, SegmentEstimator, render_adaptive
from lightfit.light.scene import FieldScene, Optics
from lightfit.plant import Field, build


@pytest.fixture(scope="module")
def scene():
    g = build(Field(boundary="finite", n_plants=4, buffer_rows=1, seed=1))
    ids = g.segments.loc[g.segments.measured, "segment_id"].to_numpy()
    fs = FieldScene(g.mesh, Optics.preset("paper"))
    fs.set_sun(45, 180)
    return fs, ids


def test_continued_sequences_equal_one_longer_render(scene):
    fs, ids = scene
    whole = SegmentEstimator(fs, ids, samples=64, bounces=2, seed=3).render()
    a = SegmentEstimator(fs, ids, samples=32, bounces=2, seed=3).render()
    b = SegmentEstimator(fs, ids, samples=32, bounces=2, seed=3, first=4).render()
    for p in PARTS:
        joined = (a.meta["replicate_means"][p] + b.meta["replicate_means"][p]) / 2
        np.testing.assert_allclose(joined, whole.meta["replicate_means"][p], rtol=1e-12, atol=1e-15)


def test_standard_error_of_the_total_matches_the_seed_spread(scene):
    fs, ids = scene
    runs = [SegmentEstimator(fs, ids, samples=32, bounces=2, seed=s).render() for s in range(12)]
    tot = np.array([r.total("absorbed", 1.0, 0.3) for r in runs])
    spread = tot.var(0, ddof=1)  # per segment, over seeds
    # relative_se is inf where a render gave a segment no light at all (then its SE is 0): a segment
    # the wrapped sheaths enclose may see a sunfleck through the tube's open top in some seeds only.
    rse = [np.where(np.isfinite(r.relative_se()), r.relative_se(), 0.0) for r in runs]
    with_cov = np.array([(e * r.total("absorbed", 1.0, 0.3)) ** 2 for e, r in zip(rse, runs)]).mean(0)
    indep = np.array([r.se["absorbed_sun"] ** 2 + (0.3 * r.se["absorbed_sky"]) ** 2 for r in runs]).mean(0)
    ok = spread > 0
    # Mean over segments of the predicted ÷ observed variance: 1 for an unbiased SE (the ratio of
    # means over ~500 segments, each from 12 seeds, is within a few per cent of its expectation).
    ratio = with_cov[ok].sum() / spread[ok].sum()
    assert ratio == pytest.approx(1.0, abs=0.12), ratio
    # Without the covariance the SE of the total is too large (sky and scattered sun compete).
    assert indep[ok].sum() / spread[ok].sum() > ratio + 0.1


def test_adaptive_render_reaches_the_target_and_equals_fixed_renders(scene):
    fs, ids = scene
    r = render_adaptive(fs, ids, 0.08, bounces=2, seed=2, max_samples=512)
    again = render_adaptive(fs, ids, 0.08, bounces=2, seed=2, max_samples=512)
    K, rse = r.meta["samples_per_segment"], r.meta["reached_rse"]
    for p in PARTS:
        assert np.array_equal(getattr(r, p), getattr(again, p))
    assert ((rse <= 0.08) | (K == 512) | ~np.isfinite(rse) | r.meta["stopped_on_floor"]).all()
    assert len(np.unique(K)) >= 3 and K.min() == 32
    np.testing.assert_allclose(rse, r.relative_se(), rtol=1e-12)
    # A segment stopped at K has the estimate of a plain render with K samples.
    for k in np.unique(K)[:3]:
        sel = K == k
        fixed = SegmentEstimator(fs, ids[sel], samples=int(k), bounces=2, seed=2).render()
        for p in PARTS:
            np.testing.assert_allclose(getattr(r, p)[sel], getattr(fixed, p), rtol=1e-10, atol=1e-14)
            np.testing.assert_allclose(r.se[p][sel], fixed.se[p], rtol=1e-8, atol=1e-14)
    # Fewer evaluations than the fixed K the noisiest segments needed.
    assert r.meta["n_evaluations"] < 0.5 * SegmentEstimator(fs, ids, samples=512, bounces=2).n_evaluations


def test_light_floor_stops_dark_segments_on_an_absolute_error(scene):
    """The floor is dark_floor × the PAR on a horizontal surface above the canopy; a segment under
    it is done when its absolute SE is below target × floor; every other segment's allocation is
    the relative target's (dark_floor=0)."""
    fs, ids = scene
    kw = dict(bounces=2, seed=4, max_samples=512)
    plain = render_adaptive(fs, ids, 0.05, dark_floor=0.0, **kw)
    f = 0.05  # a high floor, so that this small field has segments under it
    r = render_adaptive(fs, ids, 0.05, dark_floor=f, **kw)
    mu = np.sin(np.radians(45.0))  # the fixture's sun elevation
    assert r.meta["floor_absorbed"] == pytest.approx(f * (1.0 * mu + 0.3), rel=1e-12)
    assert not plain.meta["stopped_on_floor"].any() and plain.meta["floor_absorbed"] == 0.0
    K0, K = plain.meta["samples_per_segment"], r.meta["samples_per_segment"]
    value = r.total("absorbed", 1.0, 0.3)
    abs_se = np.multiply(r.meta["reached_rse"], value, out=np.zeros_like(value), where=value > 0)
    floor = r.meta["stopped_on_floor"]
    assert floor.sum() >= 5 and (value[floor] < r.meta["floor_absorbed"]).all()
    # Exactly the segments that missed the relative target and met the absolute one, and those
    # without light after 3 / f points (the rule of three: their light is below the floor).
    rse = r.meta["reached_rse"]
    met_floor = np.isfinite(rse) & (rse > 0.05) & (abs_se <= 0.05 * r.meta["floor_absorbed"] * (1 + 1e-12))
    unlit = ~np.isfinite(rse)
    np.testing.assert_array_equal(floor, (met_floor | unlit) & (K >= 3 / f))
    # Without the floor a segment without light goes on to the cap (no SE to judge it by).
    assert (K[unlit] >= 3 / f).all() and (K0[~np.isfinite(plain.meta["reached_rse"])] == 512).all()
    # Fewer points where the floor stopped a segment, the same allocation and values elsewhere.
    assert (K[floor] <= K0[floor]).all() and (floor | (K == K0)).all() and (K[floor] < K0[floor]).any()
    same = K == K0
    assert same.sum() > 0.5 * len(ids)
    for p in PARTS:
        np.testing.assert_array_equal(getattr(r, p)[same], getattr(plain, p)[same])
    assert r.meta["n_evaluations"] < plain.meta["n_evaluations"]
    for bad in (-0.1, 1.0, True, float("nan")):
        with pytest.raises(InputError, match="dark_floor"):
            render_adaptive(fs, ids, 0.05, dark_floor=bad, **kw)
        with pytest.raises(InputError, match="dark_floor"):
            make_irradiance(fs, ids, target_rse=0.05, dark_floor=bad)
    # At night the floor is the sky's share alone (the sun below the horizon adds nothing).
    fs.set_sun(-5.0, 180.0)
    try:
        night = render_adaptive(fs, ids[:50], 0.05, dark_floor=f, bounces=1, seed=4, max_samples=32)
    finally:
        fs.set_sun(45.0, 180.0)
    assert night.meta["floor_absorbed"] == pytest.approx(f * 0.3, rel=1e-12)


def test_adaptive_estimator_gradient_matches_common_random_number_differences(scene):
    fs, ids = scene
    # Roughness mid-way between two nodes of the GGX albedo table (bsdf.TABLE_R, 1/32 apart) and
    # differences inside that cell (the table is cubic in roughness there; while it was linear, a
    # difference across a node measured the mean of two cells' slopes, 5.4 % off at 0.5 ± 0.05).
    fs.set_optics(roughness=0.515)
    est = AdaptiveEstimator(fs, ids, 0.1, bounces=2, seed=5, max_samples=256)
    r = est.render()
    np.testing.assert_allclose(r.absorbed_sun, est.allocation.absorbed_sun, rtol=1e-10)
    ct = {"absorbed_sun": np.ones(len(ids)), "absorbed_sky": np.full(len(ids), 0.3)}
    grad = est.vjp(ct)
    h = 0.01
    for k in ("specular", "roughness", "subsurface"):
        base = getattr(fs.optics, k)
        vals = []
        for x in (base + h, base - h):
            fs.set_optics(**{k: x})
            q = est.render()
            vals.append(sum(np.sum(ct[p] * getattr(q, p)) for p in ct))
        fs.set_optics(**{k: base})
        fd = (vals[0] - vals[1]) / (2 * h)
        # Frozen sampling: AD and CRN differences see the same smooth function (O(h²) apart: 2e-5 here).
        assert grad[k] == pytest.approx(fd, rel=1e-3, abs=1e-4), (k, grad[k], fd)
    fs.set_optics(roughness=0.5)


def test_bad_adaptive_inputs(scene):
    fs, ids = scene
    for kw, name in ((dict(target_rse=0.0), "target_rse"), (dict(target_rse=0.1, pilot=8), "pilot")):
        with pytest.raises(InputError, match=name):
            render_adaptive(fs, ids, **kw)
    with pytest.raises(InputError, match="first"):
        SegmentEstimator(fs, ids, samples=8, first=-1)
    # Refused before the pilot: with no light to weigh, or NaN, every segment ran to the cap.
    for dni, dhi in ((0.0, 0.0), (float("nan"), 0.3), (-1.0, 0.3), (1.0, float("inf"))):
        with pytest.raises(InputError, match="dni"):
            render_adaptive(fs, ids, 0.1, dni=dni, dhi=dhi)
    with pytest.raises(InputError, match="finite field"):  # the scene fixture is finite
        render_adaptive(fs, ids, 0.1, direct="projection")
    # A sun below the horizon and no sky: the light floor was 0 and every segment ran to the cap
    # (a review); refused before the pilot, and the scene's sun put back for the other tests.
    fs.set_sun(-5, 180)
    try:
        with pytest.raises(InputError, match=r"dni=1 with the sun -5.0° high and dhi=0"):
            render_adaptive(fs, ids, 0.1, dni=1.0, dhi=0.0)
    finally:
        fs.set_sun(45, 180)


# -- the accuracy knob: Scenario.target_rse through the coupled model, the cache key and the CLI ----


@pytest.mark.parametrize("bad", [0.0, 1.0, -0.05, float("nan"), True, "0.05"])
def test_scenario_refuses_bad_target_rse(bad):
    from lightfit import replication as rep
    from lightfit.model.scenario import Scenario

    with pytest.raises(InputError, match="target_rse"):
        Scenario(weather=rep.forcing().iloc[[14]], target_rse=bad)


def test_one_check_of_target_rse_everywhere():
    """The scenario, the bridge, the estimators and the command line take target_rse through one
    check: numpy numbers pass, strings, bools, NaN and the ends of (0, 1) do not."""
    from lightfit.light.bridge import make_irradiance
    from lightfit.light.estimator import check_target_rse

    assert check_target_rse(np.float32(0.25)) == pytest.approx(0.25) and check_target_rse(0.1) == 0.1
    for bad in (0, 1, float("nan"), True, "0.1"):
        with pytest.raises(InputError, match="relative standard error in \\(0, 1\\)"):
            check_target_rse(bad)
        with pytest.raises(InputError, match="target_rse"):
            make_irradiance(None, [1], target_rse=bad)


@pytest.fixture(scope="module")
def adaptive_model():
    from lightfit import replication as rep
    from lightfit.model.coupled import CoupledModel
    from lightfit.model.scenario import Scenario

    w = rep.forcing().iloc[[5, 14]]  # 07:30 (low sun) and 12:00 local
    sc = Scenario(
        weather=w,
        field=Field(boundary="finite", n_plants=4, buffer_rows=1, seed=1),
        samples=32,
        bounces=1,
        target_rse=0.1,
    )
    return CoupledModel(sc, sensors=())


def test_coupled_run_reaches_the_target_per_segment(adaptive_model, monkeypatch):
    import lightfit.model.scenario as scenario

    cap = 256  # instead of 8192: keeps the test to seconds; segments at the cap are reported as such
    monkeypatch.setattr(scenario, "MAX_ADAPTIVE_SAMPLES", cap)
    m = adaptive_model
    m.__dict__.pop("irradiance", None)  # built with the cap above
    ds = m.simulate()
    K, rse = ds["samples_per_segment"].values, ds["reached_rse"].values
    assert ds["samples_per_segment"].attrs["units"] == "1" and "relative" in ds["reached_rse"].attrs["long_name"]
    assert ds.attrs["target_rse"] == 0.1 and ds.attrs["max_samples"] == cap
    assert K.min() == 32 and K.max() <= cap and len(np.unique(K)) >= 2
    on_floor = ds["stopped_on_floor"].values.astype(bool)
    assert ds.attrs["dark_floor"] == DARK_FLOOR and ds["stopped_on_floor"].attrs["flag_meanings"] == "no yes"
    assert ((rse <= 0.1) | (K == cap) | ~np.isfinite(rse) | on_floor).all()
    # The renders use the allocation: at the allocation point (highest sun, default leaf) the
    # coupled parts of the segments given the most samples equal an independent fixed-K render.
    leaf, sun, dni, dhi = m.allocation_point
    i = int(np.flatnonzero(m.day)[np.argmax(m.sun_deg[m.day, 0])])
    vals, _ = m.irradiance(leaf, sun, m.scenario.seed)
    assert np.array_equal(sun, m.sun_deg[i])
    # The results name where reached_rse holds: that step's sun and PAR weighting.
    at = [ds.attrs[f"allocation_{k}"] for k in ("sun_elevation_deg", "sun_azimuth_deg")]
    assert at == list(sun) and ds.attrs["allocation_dni_par_umol_m2_s"] == dni > 0
    assert ds.attrs["allocation_dhi_par_umol_m2_s"] == dhi > 0
    k = int(K.max())
    sel = K == k
    fs = FieldScene(m.geometry.mesh, m.scenario.optics, sky=m.scenario.sky, cell=m.geometry.cell)
    fs.set_optics(**dict(zip(("specular", "roughness", "subsurface"), (float(x) for x in leaf))))
    fs.set_sun(*(float(x) for x in sun))
    fixed = SegmentEstimator(fs, m.segment_id[sel], samples=k, bounces=1, seed=m.scenario.seed).render()
    for j, p in enumerate(PARTS):
        np.testing.assert_allclose(np.asarray(vals)[j, sel], getattr(fixed, p), rtol=1e-10, atol=1e-14)


def test_render_key_names_the_target(adaptive_model):
    import copy
    import dataclasses

    from lightfit.model.emulator import render_key

    fixed = copy.copy(adaptive_model)
    fixed.scenario = dataclasses.replace(adaptive_model.scenario, target_rse=None)
    other = copy.copy(adaptive_model)
    other.scenario = dataclasses.replace(adaptive_model.scenario, target_rse=0.05)
    keys = [render_key(x) for x in (adaptive_model, fixed, other)]
    assert keys[0]["target_rse"] == 0.1 and "target_rse" not in keys[1]  # fixed-K keys unchanged
    assert keys[0] != keys[1] and keys[0] != keys[2]
    assert "allocated_at" not in keys[1] and "dark_floor" not in keys[1]
    # Renders allocated under another light floor are not reused.
    assert keys[0]["dark_floor"] == DARK_FLOOR and keys[0]["max_samples"] == 8192


def test_render_key_names_where_the_allocation_was_chosen(adaptive_model):
    """The same times, target and field under another sky at the highest sun: another allocation
    (each segment's K weighs its sun and sky parts by that step's PAR), so another key."""
    import dataclasses

    from lightfit.model.coupled import CoupledModel
    from lightfit.model.emulator import render_key

    w = adaptive_model.scenario.weather.copy()
    w.iloc[1, w.columns.get_loc("dhi_w_m2")] *= 0.5
    other = CoupledModel(dataclasses.replace(adaptive_model.scenario, weather=w), sensors=())
    a, b = adaptive_model.allocation_point, other.allocation_point
    assert np.array_equal(a[1], b[1]) and a[3] != b[3]  # same sun, another diffuse PAR
    ka, kb = render_key(adaptive_model), render_key(other)
    assert ka["allocated_at"]["dni_dhi_par"] == [a[2], a[3]]
    assert ka != kb and {k: v for k, v in ka.items() if k != "allocated_at"} == {
        k: v for k, v in kb.items() if k != "allocated_at"
    }


def test_render_key_names_the_projection_and_its_version(adaptive_model):
    """Renders kept on disk are not reused across a change of the projection (its version is in
    the key); keys with the paths' direct light stay as they were before the projection."""
    import dataclasses

    from lightfit import replication as rep
    from lightfit.light.projection import PROJECTION_VERSION
    from lightfit.model.coupled import CoupledModel
    from lightfit.model.emulator import render_key
    from lightfit.model.scenario import Scenario

    w = rep.forcing().iloc[[14]]
    sc = Scenario(weather=w, field=Field(n_plants=4, boundary="periodic", seed=1), samples=8, bounces=1)
    projected = render_key(CoupledModel(sc, sensors=()))
    paths = render_key(CoupledModel(dataclasses.replace(sc, direct="paths"), sensors=()))
    assert projected["direct"] == "projection" and projected["projection_version"] == PROJECTION_VERSION >= 2
    assert "direct" not in paths and "projection_version" not in paths
    assert "direct" not in render_key(adaptive_model)  # a finite field: the paths


def test_a_restricted_adaptive_model_allocates_at_its_own_point(adaptive_model, monkeypatch):
    """Restricted to the 07:30 step after the whole run's irradiance was built, an adaptive model
    builds its own, allocated where its render key says (the kept step's sun): the same samples per
    segment as a model restricted before anything was built (what a Dask worker does)."""
    import lightfit.model.scenario as scenario
    from lightfit.model.emulator import render_key, restrict

    monkeypatch.setattr(scenario, "MAX_ADAPTIVE_SAMPLES", 256)  # seconds, not minutes
    m = adaptive_model
    whole = m.__dict__.pop("irradiance", None)
    try:
        keep = np.zeros(len(m.day), bool)
        keep[np.flatnonzero(m.day)[0]] = True
        fresh = restrict(m, keep)  # nothing built yet
        m.irradiance  # noqa: B018 (built at the whole run's point)
        sub = restrict(m, keep)
        assert sub.irradiance is not m.irradiance and render_key(sub) == render_key(fresh)
        assert fresh.allocation_point[1][0] < m.allocation_point[1][0]
        seed = m.scenario.seed
        k_sub, k_fresh = (x.irradiance.allocation(seed).meta["samples_per_segment"] for x in (sub, fresh))
        np.testing.assert_array_equal(k_sub, k_fresh)
    finally:
        m.__dict__.pop("irradiance", None)
        if whole is not None:
            m.__dict__["irradiance"] = whole


@pytest.mark.parametrize("value", ["0", "1.5"])
def test_cli_refuses_bad_target_rse_in_one_line(value, tmp_path):
    from typer.testing import CliRunner

    from lightfit.cli import app

    r = CliRunner().invoke(app, ["replicate", "--quick", "--target-rse", value, "--out", str(tmp_path)])
    assert r.exit_code == 2, r.output
    assert isinstance(r.exception, SystemExit), r.exception
    err = " ".join(r.stderr.split())
    assert err.startswith("error:") and "target" in err and "(0, 1)" in err, err
    assert "Traceback" not in r.output and len(r.stderr.strip().splitlines()) == 1, r.stderr


@pytest.mark.parametrize(
    "bad",
    [((0.5, 0.5), (50.0, 180.0), 1.0, 0.3), ((0.5, 0.5, 1.5), (50.0, 180.0), 1.0, 0.3), ((0.5,) * 3, (50.0,), 1, 0)]
    + [((0.5,) * 3, (float("nan"), 180.0), 1.0, 0.3), ((0.5,) * 3, (50.0, 180.0), -1.0, 0.3), "noon"]
    + [((0.5,) * 3, (50.0, 180.0), 0.0, 0.0)],  # no light to weigh the error by
)
def test_scenario_refuses_a_bad_allocation_point(bad):
    from lightfit import replication as rep
    from lightfit.model.scenario import Scenario

    with pytest.raises(InputError, match="allocate_at"):
        Scenario(weather=rep.forcing().iloc[[14]], target_rse=0.1, allocate_at=bad)
    good = Scenario(weather=rep.forcing().iloc[[14]], target_rse=0.1, allocate_at=((0.5,) * 3, (50, 180), 1, 0.3))
    assert good.allocate_at == ((0.5, 0.5, 0.5), (50.0, 180.0), 1.0, 0.3)


def test_the_bias_line_names_the_target_of_an_adaptive_run():
    """With --target-rse the pilot's K is not what sets the noise: the line names the target and
    the K range per segment; a fixed-K run keeps its K, a canopy taking up nothing gets no line."""
    import xarray as xr

    from lightfit.cli.replicate import mc_bias_line

    def run(an, **attrs):
        k = xr.DataArray(np.array([32, 96, 8192]), dims="segment")
        return xr.Dataset(
            {
                "canopy_an_umol_m2_s": ("time", np.array([0.0, an])),
                "canopy_an_mc_bias_umol_m2_s": ("time", np.array([0.0, -0.02 * an])),
                "samples_per_segment": k,
            },
            attrs={"samples": 32, "direct": "projection", **attrs},
        )

    fixed = mc_bias_line(run(40.0))
    assert "-2.00% at K=32, falling with K and the projection's rays" in fixed
    adaptive = mc_bias_line(run(40.0, target_rse=0.05))
    assert "-2.00% at a target of 0.05 (K 32–8192 per segment), falling with the target" in adaptive
    assert mc_bias_line(run(-1.0)) == ""


def test_segments_left_above_the_target_are_cautioned():
    """A target below what the cap of points can reach (--target-rse 1e-9: every segment at 8192
    points, reached SEs 2.6e-4–0.42) said only 'at a target of 1e-09' (a review). Segments above the
    target and not done by the light floor are counted, with how far they got; none: no line."""
    import xarray as xr

    from lightfit.cli.replicate import target_shortfall

    def run(reached, floor, target=0.05):
        return xr.Dataset(
            {
                "reached_rse": ("segment", np.array(reached, float)),
                "stopped_on_floor": ("segment", np.array(floor, np.int8)),
                "samples_per_segment": ("segment", np.where(np.array(reached) > (target or 0), 8192, 64)),
            },
            attrs={"target_rse": target} if target is not None else {},
        )

    line = target_shortfall(run([0.04, 0.09, 0.2, np.inf, 0.3], [0, 0, 0, 1, 1]))
    # 0.09 and 0.2 missed it; inf (no light) and 0.3 were done by the floor's rule
    assert line.startswith("2 of 5 segments did not reach --target-rse 0.05: they stopped at 8192 points")
    assert "relative SEs of 0.145 (median) up to 0.2" in line and "reached_rse" in line
    assert target_shortfall(run([0.04, 0.05, np.inf], [0, 0, 1])) == ""
    assert target_shortfall(run([0.04, 0.09], [0, 0], target=None)) == ""


def test_several_days_of_an_adaptive_run_keep_each_days_allocation():
    """`replicate` with several dates concatenates the days (replication.concat_days): each day
    allocated at its own highest sun, so the allocation_* attributes list every day's in order,
    and the bias line's K range spans the days (samples_per_segment has NaN between them)."""
    import pandas as pd
    import xarray as xr

    from lightfit.cli.replicate import mc_bias_line
    from lightfit.replication import concat_days

    def day(date, k, elevation):
        s = len(k)
        per_step = (("time", "segment"), np.ones((2, s)))
        return xr.Dataset(
            {
                "absorbed_par_umol_m2_s": per_step,
                "limitation": (("time", "segment"), np.zeros((2, s), np.int8)),
                "converged": (("time", "segment"), np.ones((2, s), bool)),
                "canopy_an_umol_m2_s": ("time", [10.0, 10.0]),
                "canopy_an_mc_bias_umol_m2_s": ("time", [-0.2, -0.2]),
                "samples_per_segment": ("segment", np.array(k, np.int64)),
            },
            coords={
                "time": pd.date_range(f"{date} 10:00", periods=2, freq="30min").values,
                "segment": np.arange(s),
                "plant_id": ("segment", np.zeros(s, int)),
                "organ_type": ("segment", np.array(["leaf"] * s)),
                "area_m2": ("segment", np.ones(s)),
                "is_blade": ("segment", np.ones(s, bool)),
            },
            attrs={"date": date, "window": "w", "target_date": date, "samples": 32, "target_rse": 0.05}
            | {"direct": "projection", "allocation_sun_elevation_deg": elevation},
        )

    out = concat_days([day("2016-04-20", [32, 64], 46.0), day("2016-06-23", [32, 128], 61.0)])
    assert out.attrs["allocation_sun_elevation_deg"] == "46.0; 61.0"
    assert "at a target of 0.05 (K 32–128 per segment)" in mc_bias_line(out)


def test_the_shortfall_line_gives_the_median_and_counts_only_the_segments_there():
    """target_shortfall against a hand count (a mutation audit: the median taken as the mean, and
    NaN segments, absent on a day of several, counted, both survived): missed 0.09, 0.1 and 0.5 of
    target 0.05 → median 0.1 (mean 0.23); 4 segments there (the NaN one is not)."""
    import xarray as xr

    from lightfit.cli.replicate import target_shortfall

    reached = np.array([0.09, 0.1, 0.5, np.nan, 0.04])
    ds = xr.Dataset(
        {
            "reached_rse": ("segment", reached),
            "stopped_on_floor": ("segment", np.zeros(5, np.int8)),
            "samples_per_segment": ("segment", np.array([8192, 8192, 8192, np.nan, 64])),
        },
        attrs={"target_rse": 0.05},
    )
    line = target_shortfall(ds)
    assert line.startswith("3 of 4 segments did not reach --target-rse 0.05: they stopped at 8192 points"), line
    assert "relative SEs of 0.1 (median) up to 0.5" in line, line


def test_no_bias_line_for_a_canopy_that_took_up_nothing():
    """A run of night steps only: canopy An sums to ≤ 0, exactly 0 with no respiration at all, and the
    bias line is empty, not a division by zero (a mutation audit: "an <= 0" as "an < 0" survived)."""
    import xarray as xr

    from lightfit.cli.replicate import mc_bias_line

    zero = xr.Dataset(
        {"canopy_an_umol_m2_s": ("time", np.zeros(3)), "canopy_an_mc_bias_umol_m2_s": ("time", np.zeros(3))},
        attrs={"samples": 32, "direct": "projection"},
    )
    assert mc_bias_line(zero) == ""


def test_adaptive_vjp_refuses_a_cotangent_of_the_wrong_shape_by_name(scene):
    """AdaptiveEstimator.vjp checks its cotangent as SegmentEstimator.vjp does: a shape other than
    (), (1,) or (S,) is the InputError naming the output, not numpy's broadcast error; a scalar
    and a missing part give the gradient of the full arrays."""
    fs, ids = scene
    est = AdaptiveEstimator(fs, ids[:4], 0.3, bounces=1, seed=2, max_samples=64)
    for bad in (np.ones(5), np.ones((2, 2))):
        with pytest.raises(InputError, match=r"cotangent\['absorbed_sun'\] of shape"):
            est.vjp({"absorbed_sun": bad})
    with pytest.raises(InputError, match="unknown output"):
        est.vjp({"bogus": np.ones(4)})
    full = est.vjp({"absorbed_sun": np.ones(4), "incident_sky": np.zeros(4)})
    assert est.vjp({"absorbed_sun": 1.0}) == pytest.approx(full, rel=1e-12)


@pytest.mark.parametrize(("pilot", "max_samples", "reached"), [(32, 40, 32), (33, 100, 80), (32, 100, 96)])
def test_a_cap_the_rounds_do_not_reach_by_doubling_is_not_a_broadcast_error(scene, pilot, max_samples, reached):
    """Each round renders its new points with 8 replicates, which takes ≥ 32 of them
    (replicates_for). A last round up to a cap of 40 added 8 points with 2 replicates and stopped
    on numpy's "operands could not be broadcast together with shapes (n,8) (n,2)". By hand, points
    per replicate: pilot 32 → 4, cap 40 → 5: a step of 1 is not taken, K = 32; pilot 33 → 5, 10,
    cap 100 → 12: a step of 2 is not taken, K = 80; pilot 32, cap 100 → 4, 8, 12 (steps of 4,
    32 points each), K = 96. A 0.1 % target keeps every segment going, so each ends at that K, with
    the estimate of one fixed render of K points."""
    fs, ids = scene
    ids = ids[:20]
    a = render_adaptive(fs, ids, 0.001, bounces=1, seed=4, pilot=pilot, max_samples=max_samples, dark_floor=0.0)
    assert (a.meta["samples_per_segment"] == reached).all()
    fixed = SegmentEstimator(fs, ids, samples=reached, bounces=1, seed=4).render()
    for p in PARTS:
        np.testing.assert_allclose(getattr(a, p), getattr(fixed, p), rtol=1e-9, atol=1e-12)
