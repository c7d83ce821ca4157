"""Data scene: labels, determinism, exposure/clipping, bad specs, CLI, field export.

The results file here is *synthetic* (``lightfit.dataset.synthetic_results``: values from a
formula, attrs ``synthetic = "true"``) on a real tiny field: 2×2 measured plants + 1 buffer row.
"""

import json

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from lightfit.cli import app
from lightfit.dataset import (
    MARGIN,
    ORGAN_CODES,
    Camera,
    DatasetSpec,
    Lighting,
    RenderSettings,
    Sweep,
    VisualMaterials,
    build_geometry,
    camera_sweep,
    clipped_fraction,
    load_cameras,
    make_dataset,
    meter,
    open_results,
    render,
    scene_arrays,
    synthetic_results,
    tone_map,
)
from lightfit.errors import InputError
from lightfit.plant import Field

TIMES = ["2016-04-20T08:00", "2016-04-20T11:00"]
SMALL = {"width_px": 64, "height_px": 64}
# Looks down on the field from the south-east at ~45°: leaves, stems and soil in view.
CAM = Camera(name="se", position_m=(0.45, -0.45, 0.75), look_at_m=(0.0, 0.0, 0.2), fov_deg=50.0, **SMALL)
SUN = Lighting(sun_elevation_deg=45.0, sun_azimuth_deg=160.0, dni_w_m2=700.0, dhi_w_m2=120.0)


@pytest.fixture(scope="module")
def results_file(tmp_path_factory):
    fld = Field(boundary="finite", n_plants=4, buffer_rows=1, seed=1)
    path = tmp_path_factory.mktemp("results") / "results.nc"
    synthetic_results(fld, TIMES, seed=3).to_netcdf(path, engine="h5netcdf")
    return path


@pytest.fixture(scope="module")
def geometry(results_file):
    return build_geometry(open_results(results_file))


@pytest.fixture(scope="module")
def mono_dataset(results_file, tmp_path_factory):
    out = tmp_path_factory.mktemp("ds_mono")
    spec = DatasetSpec(
        cameras=[CAM], times=["all"], settings=RenderSettings(spp=2, colour="mono", seed=5), gallery_images=1
    )
    return out, make_dataset(results_file, out, spec)


def _labels(out, entry):
    with np.load(out / entry["labels"]) as z:
        return {k: z[k] for k in z.files}


def test_labels_map_to_stored_segment_values(mono_dataset, results_file, geometry):
    out, meta = mono_dataset
    res = open_results(results_file)
    assert meta["synthetic_values"] is True
    for entry in meta["images"]:
        lab = _labels(out, entry)
        seg = lab["segment_id"]
        fg = seg >= 0
        assert fg.sum() > 100, "the camera should see plants"
        for q in ("absorbed_par", "an", "vc", "vj", "gs"):
            stored = res.values(q, entry["time_index"])
            known = np.isin(seg, stored.index)
            np.testing.assert_array_equal(lab[q][known], stored.reindex(seg[known]).to_numpy(np.float32))
            assert np.isnan(lab[q][~known]).all()
        lim = res.values("limitation", entry["time_index"])
        known = np.isin(seg, lim.index)
        np.testing.assert_array_equal(lab["limitation"][known], lim.reindex(seg[known]).to_numpy())
        assert (lab["limitation"][~known] == -1).all()
        np.testing.assert_array_equal(lab["valid"], known)
        margin = res.values(MARGIN, entry["time_index"])
        np.testing.assert_allclose(lab[MARGIN][known], margin.reindex(seg[known]).to_numpy(np.float32))
        # Stems and sheaths, which have no photosynthesis in a run's results nor in these: valid pixels
        # with their PAR and without leaf values.
        no_leaf = np.isin(seg, res.ds["segment"].values[~res.ds["is_blade"].values.astype(bool)])
        assert no_leaf.sum() > 10, "the camera should see stems or sheaths"
        assert np.isfinite(lab["absorbed_par"][no_leaf]).all()
        for q in ("an", "vc", "vj", "gs", MARGIN):
            assert np.isnan(lab[q][no_leaf]).all(), q
        assert (lab["limitation"][no_leaf] == -1).all()
        # Plant id and organ follow the segment table.
        table = geometry.segments.set_index("segment_id")
        np.testing.assert_array_equal(lab["plant_id"][fg], table["plant_id"].reindex(seg[fg]).to_numpy())
        organ = table["organ_type"].astype(str).reindex(seg[fg]).map({"stem": 2, "leaf": 3}).to_numpy()
        np.testing.assert_array_equal(lab["organ"][fg], organ)


def test_background_sentinels(mono_dataset):
    out, meta = mono_dataset
    lab = _labels(out, meta["images"][0])
    bg = lab["segment_id"] == -1
    assert bg.any()
    assert set(np.unique(lab["organ"][bg])) <= {ORGAN_CODES["sky"], ORGAN_CODES["soil"]}
    assert (lab["plant_id"][bg] == -1).all()
    assert np.isnan(lab["absorbed_par"][bg]).all() and not lab["valid"][bg].any()
    assert (lab["organ"][~bg] >= ORGAN_CODES["stem"]).all()
    assert np.isfinite(lab["depth_m"][lab["organ"] != ORGAN_CODES["sky"]]).all()


def test_labels_and_leaf_metering_of_a_hand_made_image(tmp_path):
    """A mutation audit: labels of a hand-made 2 × 4 image whose every pixel's class is known by
    construction. Faces 0–2 are plants (0: leaf segment 10 and 1: stem segment 11 of measured plant
    7, 2: leaf segment 12 of buffer plant 8, which has no results), faces 3–4 soil, −1 sky. The
    rendered tests' cameras never showed face 0 nor the sky together with soil, so labelling face 0
    soil, or sky and soil with each other's code, passed them; and their images' metering was not
    checked against the organ labels: metering on stems too passed. Here segment 10 is electron-
    transport limited (1), segment 11 Rubisco limited (0); the leaves are lit 2, 4 and 8 W m⁻² sr⁻¹
    in their brightest channel, the stem 100, the soil 1000: leaf metering at the 100th percentile
    gives the gain 1/8 and clips one leaf pixel of three."""
    from lightfit.dataset import geometric_labels
    from lightfit.dataset.dataset import _write_image
    from lightfit.plant.mesh import Mesh

    mesh = Mesh(
        vertices=np.zeros((3, 3)),
        faces=np.zeros((3, 3), np.int64),
        face_segment=np.array([10, 11, 12]),
        face_is_blade=np.array([True, False, True]),
    )
    segments = pd.DataFrame({"segment_id": [10, 11, 12], "plant_id": [7, 7, 8], "organ_type": ["leaf", "stem", "leaf"]})
    face = np.array([[-1, 0, 1, 3], [2, 4, 0, -1]])
    depth = np.where(face < 0, np.nan, 1.0)
    geo = geometric_labels(face, depth, mesh, segments)
    np.testing.assert_array_equal(geo["segment_id"], [[-1, 10, 11, -1], [12, -1, 10, -1]])
    np.testing.assert_array_equal(geo["plant_id"], [[-1, 7, 7, -1], [8, -1, 7, -1]])
    sky, soil, stem, leaf = (ORGAN_CODES[k] for k in ("sky", "soil", "stem", "leaf"))
    np.testing.assert_array_equal(geo["organ"], [[sky, leaf, stem, soil], [leaf, soil, leaf, sky]])

    values = {
        "limitation": pd.Series([1, 0], index=[10, 11], name="limitation"),
        "an": pd.Series([5.0, np.nan], index=[10, 11], name="leaf_an_umol_m2_s"),
    }
    radiance = np.zeros((2, 4, 3), np.float32)
    radiance[..., 1] = [[0.0, 2.0, 100.0, 1000.0], [4.0, 1000.0, 8.0, 0.0]]  # the brightest channel: green
    cam = Camera(name="hand", exposure_mode="leaf", meter_percentile=100.0, width_px=4, height_px=2)
    for d in ("images", "labels"):
        (tmp_path / d).mkdir()
    entry = _write_image(tmp_path, cam, pd.Timestamp("2016-04-20T11:00", tz="UTC"), 0, SUN, radiance, geo, values)
    lab = _labels(tmp_path, entry)
    valid = np.array([[0, 1, 1, 0], [0, 0, 1, 0]], bool)  # segments with results: not the buffer plant's 12
    np.testing.assert_array_equal(lab["valid"], valid)
    assert lab["limitation"].dtype == np.int8
    np.testing.assert_array_equal(lab["limitation"], [[-1, 1, 0, -1], [-1, -1, 1, -1]])
    np.testing.assert_array_equal(lab["an"], np.where([[0, 1, 0, 0], [0, 0, 1, 0]], 5.0, np.nan).astype(np.float32))
    e = entry["exposure"]
    assert (e["metering"], e["leaf_pixels"], e["gain"], e["metered_luminance"]) == ("leaf", 3, 1 / 8, 8.0)
    assert e["clipped_leaf_fraction"] == pytest.approx(1 / 3)
    assert entry["pixels"] == {"sky": 2, "soil": 2, "stem": 1, "leaf": 3, "valid": 3}


def test_sky_pixels_have_no_depth(geometry):
    """A camera looking at the horizon sees sky above it: organ 0 and depth NaN, exactly together."""
    cam = Camera(name="horizon", position_m=(0.0, -1.5, 0.3), look_at_m=(0.0, 0.0, 0.3), **SMALL)
    out = render(scene_arrays(geometry.mesh, geometry.segments), [cam], [SUN], RenderSettings(spp=1, colour="mono"))
    face, depth = out.face[0], out.depth_m[0]
    assert (face == -1).any() and (face >= 0).any()
    np.testing.assert_array_equal(face == -1, np.isnan(depth))
    assert (face[:10] == -1).all()  # the top rows are sky


def test_hit_points_lie_on_the_labelled_segment(geometry):
    """Independent check of the face → segment mapping: each pixel's hit point is inside the
    bounding box of the labelled segment's triangles."""
    from lightfit.dataset import geometric_labels

    out = render(scene_arrays(geometry.mesh, geometry.segments), [CAM], [SUN], RenderSettings(spp=1, colour="mono"))
    lab = geometric_labels(out.face[0], out.depth_m[0], geometry.mesh, geometry.segments)
    dirs = CAM.directions().reshape(CAM.height_px, CAM.width_px, 3)
    t = lab["depth_m"] / (dirs @ CAM.basis()[2])
    hit = np.asarray(CAM.position_m) + t[..., None] * dirs
    mesh = geometry.mesh
    rows, cols = np.nonzero(lab["segment_id"] >= 0)
    for r, c in list(zip(rows, cols))[::7]:
        v = mesh.vertices[mesh.faces[mesh.face_segment == lab["segment_id"][r, c]]].reshape(-1, 3)
        assert ((hit[r, c] >= v.min(0) - 2e-3) & (hit[r, c] <= v.max(0) + 2e-3)).all()
    soil = lab["organ"] == ORGAN_CODES["soil"]
    np.testing.assert_allclose(hit[soil][:, 2], 0.0, atol=1e-4)


def test_same_seed_same_images(geometry):
    arrays = scene_arrays(geometry.mesh, geometry.segments, seed=2)
    a = render(arrays, [CAM], [SUN], RenderSettings(spp=2, colour="mono", seed=11))
    b = render(
        scene_arrays(geometry.mesh, geometry.segments, seed=2),
        [CAM],
        [SUN],
        RenderSettings(spp=2, colour="mono", seed=11),
    )
    c = render(arrays, [CAM], [SUN], RenderSettings(spp=2, colour="mono", seed=12))
    np.testing.assert_array_equal(a.radiance[0][0], b.radiance[0][0])
    np.testing.assert_array_equal(a.face[0], b.face[0])
    assert not np.array_equal(a.radiance[0][0], c.radiance[0][0])
    np.testing.assert_array_equal(a.face[0], c.face[0])  # labels do not depend on the seed
    assert np.isfinite(a.radiance[0][0]).all() and (a.radiance[0][0] >= 0).all()


def test_dataset_is_deterministic(results_file, tmp_path):
    spec = DatasetSpec(
        cameras=[CAM], settings=RenderSettings(spp=1, colour="mono", seed=4), gallery_images=0, export="none"
    )
    m1, m2 = make_dataset(results_file, tmp_path / "a", spec), make_dataset(results_file, tmp_path / "b", spec)
    for e1, e2 in zip(m1["images"], m2["images"]):
        assert (tmp_path / "a" / e1["png"]).read_bytes() == (tmp_path / "b" / e2["png"]).read_bytes()
        l1, l2 = _labels(tmp_path / "a", e1), _labels(tmp_path / "b", e2)
        for k in l1:
            np.testing.assert_array_equal(l1[k], l2[k])
    assert m1["images"][0]["exposure"] == m2["images"][0]["exposure"]


def test_overexposed_image_clips_every_leaf_pixel(geometry):
    arrays = scene_arrays(geometry.mesh, geometry.segments)
    out = render(arrays, [CAM], [SUN], RenderSettings(spp=1, colour="mono"))
    from lightfit.dataset import geometric_labels

    lab = geometric_labels(out.face[0], out.depth_m[0], geometry.mesh, geometry.segments)
    leaf = lab["organ"] == ORGAN_CODES["leaf"]
    over = Camera(**{**CAM.to_dict(), "exposure_mode": "fixed", "exposure_ev": 30.0})
    rad = out.radiance[0][0]
    e = meter(rad, leaf, over)
    # Every lit leaf pixel clips; at 1 path per pixel a pixel's estimate is exactly 0 where its one
    # path found no light (a few per cent: leaf sheaths deep in the canopy, the culm's wrapping).
    lit = leaf & (rad.max(axis=-1) > 0)
    assert e.clipped_leaf_fraction == pytest.approx(lit.sum() / leaf.sum()) and e.clipped_leaf_fraction > 0.95
    assert e.leaf_pixels == leaf.sum()
    assert (tone_map(rad, e.gain)[lit] == 255).all()
    metered = meter(out.radiance[0][0], leaf, Camera(**{**CAM.to_dict(), "meter_percentile": 95.0}))
    assert 0.0 < metered.clipped_leaf_fraction <= 0.06
    under = meter(out.radiance[0][0], leaf, Camera(**{**CAM.to_dict(), "exposure_mode": "fixed", "exposure_ev": -30.0}))
    assert under.clipped_leaf_fraction == 0.0


def test_metering_on_known_arrays():
    rad = np.zeros((10, 10, 3))
    rad[..., 1] = np.arange(100).reshape(10, 10) + 1.0  # green channel 1 … 100
    leaf = np.zeros((10, 10), bool)
    leaf[:5] = True  # leaf pixels carry green 1 … 50
    e = meter(rad, leaf, Camera(exposure_mode="leaf", meter_percentile=90.0, width_px=10, height_px=10))
    assert e.metered_luminance == pytest.approx(np.percentile(np.arange(1, 51), 90))
    assert e.clipped_leaf_fraction == pytest.approx(5 / 50)
    assert clipped_fraction(rad, leaf, 1.0 / 25.0) == pytest.approx(26 / 50)
    assert np.isnan(clipped_fraction(rad, np.zeros_like(leaf), 1.0))
    dark = meter(np.zeros((4, 4, 3)), np.ones((4, 4), bool), Camera(width_px=4, height_px=4))
    assert dark.dark and dark.gain == 1.0 and dark.clipped_leaf_fraction == 0.0
    scene = meter(
        np.full((4, 4, 1), 2.0), np.zeros((4, 4), bool), Camera(exposure_mode="scene", width_px=4, height_px=4)
    )
    assert scene.gain == pytest.approx(0.18 / 2.0) and np.isnan(scene.clipped_leaf_fraction)
    # Leaf metering without a leaf in view (a camera on bare soil or the sky) meters the scene's
    # mean: it took a gain of 1 per W m⁻² sr⁻¹, a white image called dark (a review).
    soil = meter(np.full((4, 4, 3), 30.0), np.zeros((4, 4), bool), Camera(width_px=4, height_px=4))
    assert soil.metering == "scene (no leaf in view)" and not soil.dark
    assert soil.gain == pytest.approx(0.18 / 30.0) and np.isnan(soil.clipped_leaf_fraction)
    assert e.metering == "leaf" and scene.metering == "scene"


@pytest.mark.parametrize(
    "fields, column",
    [
        ({"width_px": 0}, "width_px"),
        ({"height_px": -5}, "height_px"),
        ({"width_px": 64.5}, "width_px"),
        ({"fov_deg": 0.0}, "fov_deg"),
        ({"fov_deg": 180.0}, "fov_deg"),
        ({"fov_deg": float("nan")}, "fov_deg"),
        ({"position_m": (0.0, float("nan"), 1.0)}, "position_m"),
        ({"position_m": (0.0, 0.0)}, "position_m"),
        ({"position_m": (0.0, 0.0, -1.0)}, "position_m"),
        ({"position_m": (0.0, 0.0, 1.0), "look_at_m": (0.0, 0.0, 1.0)}, "look_at_m"),
        ({"position_m": (0.0, 0.0, 1.0), "look_at_m": (0.0, 0.0, 0.0)}, "up"),
        ({"up": (0.0, 0.0, 0.0)}, "up"),
        ({"exposure_mode": "auto"}, "exposure_mode"),
        ({"meter_percentile": 0.0}, "meter_percentile"),
        ({"exposure_ev": float("inf")}, "exposure_ev"),
        ({"exposure_ev": 1100.0}, "exposure_ev"),  # 2.0**1100: an OverflowError after the renders
        ({"exposure_ev": -1100.0}, "exposure_ev"),  # a gain of 0: black images
        ({"name": "a/b"}, "name"),
    ],
)
def test_bad_camera_specs(fields, column):
    with pytest.raises(InputError) as err:
        Camera(**fields)
    assert err.value.column == column and column in str(err.value)


def test_bad_sweep_and_settings():
    for kw, col in (({"n": 0}, "n"), ({"distance_m": -1.0}, "distance_m"), ({"elevation_deg": 90.0}, "elevation_deg")):
        with pytest.raises(InputError, match=col):
            Sweep(**kw)
    for kw, col in (
        ({"spp": 0}, "spp"),
        ({"colour": "cmyk"}, "colour"),
        ({"max_depth": 1}, "max_depth"),
        ({"seed": -1}, "seed"),
    ):
        with pytest.raises(InputError, match=col):
            RenderSettings(**kw)


def test_camera_sweep_and_file(tmp_path):
    cams = camera_sweep(Sweep(n=3, distance_m=2.0, elevation_deg=30.0, camera=SMALL), canopy_height_m=0.6)
    assert [c.name for c in cams] == ["sweep000", "sweep001", "sweep002"]
    for c in cams:
        assert np.hypot(*c.position_m[:2]) == pytest.approx(2.0)
        assert c.look_at_m == (0.0, 0.0, 0.3) and c.width_px == 64
    p = tmp_path / "cams.json"
    p.write_text(json.dumps([CAM.to_dict(), {"position_m": [1, 1, 1]}]))
    loaded = load_cameras(p)
    assert loaded[0] == CAM and loaded[1].name == "cam001"
    p.write_text(json.dumps([{"positon_m": [1, 1, 1]}]))
    with pytest.raises(InputError, match="unknown key"):
        load_cameras(p)
    p.write_text(json.dumps({"name": "c"}))  # rendered from the default position before (a CLI review)
    with pytest.raises(InputError, match="camera #0 has no position_m"):
        load_cameras(p)
    p.write_text(json.dumps([CAM.to_dict(), CAM.to_dict()]))
    with pytest.raises(InputError, match="duplicate camera name") as err:
        load_cameras(p)
    assert str(err.value).startswith(str(p))
    # A camera's own check (a pinhole below the soil) names the file it came from, and the field.
    p.write_text(json.dumps([{"name": "low", "position_m": [1, 1, -0.2]}]))
    with pytest.raises(InputError, match="position_m") as err:
        load_cameras(p)
    assert str(err.value).startswith(f"{p}, column 'position_m': camera 'low'")


def test_unknown_quantity_and_time(results_file, tmp_path):
    with pytest.raises(InputError, match="unknown quantity 'photons'") as err:
        make_dataset(results_file, tmp_path, DatasetSpec(cameras=[CAM], quantities=("photons",)))
    assert "absorbed_par" in str(err.value)
    with pytest.raises(InputError, match="not a step of the results"):
        make_dataset(results_file, tmp_path, DatasetSpec(cameras=[CAM], times=["2016-04-20T09:17"]))
    for bad in (True, -1, 2.0):  # errors.check_integer: a bool is not a count of images
        with pytest.raises(InputError, match="gallery_images"):
            make_dataset(results_file, tmp_path, DatasetSpec(cameras=[CAM], gallery_images=bad))


def test_results_that_do_not_match_the_field(results_file, tmp_path):
    import xarray as xr

    ds = xr.load_dataset(results_file)
    bad = ds.assign_coords(segment=ds["segment"].values + 7)
    with pytest.raises(InputError, match="not in the field rebuilt"):
        make_dataset(bad, tmp_path, DatasetSpec(cameras=[CAM]))
    no_attrs = ds.copy()
    no_attrs.attrs = {}
    with pytest.raises(InputError, match="missing field attribute"):
        open_results(no_attrs)


def test_field_export_ply_has_per_face_values(mono_dataset, geometry):
    out, meta = mono_dataset
    info = meta["field_export"]
    head = (out / info["file"]).read_bytes().split(b"end_header")[0].decode()
    for q in ("absorbed_par", "an", "limitation", MARGIN):
        assert f"property double {q}" in head
    measured = geometry.segments.loc[geometry.segments["measured"], "segment_id"]
    assert info["faces"] == np.isin(geometry.mesh.face_segment, measured).sum()
    assert info["faces"] + info["faces_left_out"] == geometry.mesh.n_faces
    assert info["time_utc"] == meta["images"][0]["time_utc"]  # the first selected step's values
    assert meta["lighting"]["from"] in ("results", "weather")


def test_image_stems_keep_seconds_where_steps_have_them():
    """Steps less than a minute apart wrote one file (stems to the minute; a review)."""
    from lightfit.dataset.dataset import _stem

    cam = Camera(name="se")
    stems = [_stem(cam, pd.Timestamp(t)) for t in ("2016-04-20 10:00:00", "2016-04-20 10:00:30")]
    assert stems == ["se_20160420T1000Z", "se_20160420T100030Z"]


def test_metadata_contents(mono_dataset):
    out, meta = mono_dataset
    disk = json.loads((out / "metadata.json").read_text())
    assert disk["lightfit_version"] and disk["render"]["seed"] == 5 and len(disk["images"]) == len(TIMES)
    e = disk["images"][0]
    assert set(e["lighting"]) == {"sun_elevation_deg", "sun_azimuth_deg", "dni_w_m2", "dhi_w_m2"}
    assert e["lighting"]["dni_w_m2"] > 0 and 0.0 <= e["exposure"]["clipped_leaf_fraction"] <= 1.0
    assert pd.Timestamp(e["time_utc"]) == pd.Timestamp(TIMES[0], tz="UTC")
    assert (out / e["exr"]).read_bytes()[:4] == b"\x76\x2f\x31\x01"  # OpenEXR magic number
    assert (out / "gallery.png").exists()


def test_cli_renders_rgb_dataset(results_file, tmp_path):
    """End to end through the command, in colour: the rgb render runs in a child process."""
    from PIL import Image

    out = tmp_path / "ds"
    r = CliRunner().invoke(
        app,
        [
            "render-dataset",
            str(results_file),
            "--out",
            str(out),
            "--sweep",
            "2",
            "--width",
            "40",
            "--height",
            "32",
            "--spp",
            "1",
            "--time",
            TIMES[1],
            "-q",
            "absorbed_par",
            "-q",
            "vc",
            "-q",
            "vj",
            "-q",
            MARGIN,
            "--export",
            "vtk",
            "--gallery",
            "2",
        ],
    )
    assert r.exit_code == 0, r.output
    meta = json.loads((out / "metadata.json").read_text())
    assert meta["render"]["colour"] == "rgb" and [e["camera"] for e in meta["images"]] == ["sweep000", "sweep001"]
    png = np.asarray(Image.open(out / meta["images"][0]["png"]))
    assert png.shape == (32, 40, 3)
    assert not np.array_equal(png[..., 0], png[..., 1])  # colour, not grey
    assert b"SCALARS limitation_margin double 1" in (out / "field_values.vtk").read_bytes()
    lab = _labels(out, meta["images"][0])
    assert set(lab) == {"segment_id", "plant_id", "organ", "depth_m", "valid", "absorbed_par", "vc", "vj", MARGIN}
    assert (out / "gallery.png").exists() and "clipped leaf pixels" in r.output


@pytest.mark.parametrize(
    "args, text",
    [
        (["--fov-deg", "200"], "fov_deg"),
        (["--width", "0"], "width_px"),
        (["-q", "nope"], "unknown quantity"),
        (["--time", "2016-04-20T11:00", "--all-times"], "--all-times"),
        (["--colour", "cmyk"], "colour"),
    ],
)
def test_cli_bad_input(results_file, tmp_path, args, text):
    r = CliRunner().invoke(app, ["render-dataset", str(results_file), "--out", str(tmp_path / "x"), *args])
    assert r.exit_code == 2, r.output
    assert text in " ".join(r.stderr.split())


def test_cli_sweep_options_with_cameras_are_refused(results_file, tmp_path):
    """--exposure-mode scene with --cameras was silently ignored (the JSON cameras keep their own
    settings; the docs' own example did it): refused naming the options; --cameras alone renders."""
    cams = tmp_path / "cams.json"
    cams.write_text(
        json.dumps(
            [
                {
                    "name": "se",
                    **{k: list(v) for k, v in (("position_m", CAM.position_m), ("look_at_m", CAM.look_at_m))},
                    "width_px": 32,
                    "height_px": 32,
                }
            ]
        )
    )
    args = ["render-dataset", str(results_file), "--cameras", str(cams), "--spp", "1", "--colour", "mono"]
    r = CliRunner().invoke(app, [*args, "--out", str(tmp_path / "x"), "--exposure-mode", "scene", "--width", "64"])
    assert r.exit_code == 2 and "--width, --exposure-mode with --cameras" in " ".join(r.stderr.split())
    assert not (tmp_path / "x" / "images").exists()
    r = CliRunner().invoke(app, [*args, "--out", str(tmp_path / "y"), "--gallery", "0", "--export", "none"])
    assert r.exit_code == 0, r.output


def test_child_process_render_equals_in_process(geometry, tmp_path):
    """The rgb-in-a-child path gives the same arrays as rendering here, for one variant and seed."""
    from lightfit.dataset.render import _render_child, load_camera, render_here, variant_for
    from lightfit.dataset.scene import VisualMaterials

    arrays = scene_arrays(geometry.mesh, geometry.segments)
    cam = Camera(name="c", position_m=CAM.position_m, look_at_m=CAM.look_at_m, width_px=24, height_px=16)
    settings, mats = RenderSettings(spp=2, colour="mono", seed=9), VisualMaterials()
    variant, here = variant_for("mono")
    child = _render_child(arrays, [cam], [SUN], settings, mats, variant, [3], tmp_path)
    saved = load_camera(tmp_path / "camera_3.npz", 1)  # kept by the child as soon as rendered (resume)
    np.testing.assert_array_equal(saved[0][0], child.radiance[0][0])
    np.testing.assert_array_equal(saved[1], child.face[0])
    if here:
        rad, face, depth = render_here(arrays, [cam], [SUN], settings, mats, variant, [3])
        np.testing.assert_array_equal(child.radiance[0][0], rad[0][0])
        np.testing.assert_array_equal(child.face[0], face[0])
        np.testing.assert_array_equal(child.depth_m[0], depth[0])
    assert not child.in_process and child.radiance[0][0].shape == (16, 24, 1)


def test_night_renders_black_and_reports_dark(geometry):
    """No sun and no sky: a black image, no NaN, and metering falls back to gain 1 (dark)."""
    night = Lighting(sun_elevation_deg=-10.0, sun_azimuth_deg=0.0, dni_w_m2=0.0, dhi_w_m2=0.0)
    cam = Camera(name="n", position_m=CAM.position_m, look_at_m=CAM.look_at_m, width_px=16, height_px=16)
    out = render(scene_arrays(geometry.mesh, geometry.segments), [cam], [night], RenderSettings(spp=1, colour="mono"))
    rad = out.radiance[0][0]
    assert (rad == 0).all()
    e = meter(rad, out.face[0] >= 0, cam)
    assert e.dark and e.gain == 1.0 and e.clipped_leaf_fraction == 0.0
    with pytest.raises(InputError, match="dni_w_m2"):
        Lighting(sun_elevation_deg=10.0, sun_azimuth_deg=0.0, dni_w_m2=-1.0, dhi_w_m2=0.0)


def test_units_come_from_the_results_schema(results_file, mono_dataset):
    res = open_results(results_file)
    expect = {"absorbed_par": "umol m-2 s-1", "an": "umol m-2 s-1", "gs": "mol m-2 s-1", "limitation": "1", MARGIN: "1"}
    assert {q: res.units(q) for q in expect} == expect
    assert res.ds["leaf_gs_mol_m2_s"].attrs["units"] == "mol m-2 s-1"  # the file carries them too
    _, meta = mono_dataset
    assert meta["quantities"]["gs"] == {"variable": "leaf_gs_mol_m2_s", "units": "mol m-2 s-1"}
    renamed = open_results(res.ds.rename({"leaf_gs_mol_m2_s": "gs_in_some_unit"}))
    with pytest.raises(InputError, match="gs_in_some_unit"):  # no guessing from the name
        renamed.units("gs_in_some_unit")


@pytest.fixture(scope="module")
def periodic_results_file(tmp_path_factory):
    fld = Field(n_plants=4, seed=1, boundary="periodic")
    path = tmp_path_factory.mktemp("results_periodic") / "results.nc"
    synthetic_results(fld, TIMES[1:], seed=3).to_netcdf(path, engine="h5netcdf")
    return path


def test_cli_cautions_when_the_periodic_canopy_is_cut(periodic_results_file, tmp_path, monkeypatch):
    """A face budget that cuts the periodic canopy short of what the cameras see was said only in
    metadata.json (a newcomer's audit): the command cautions, naming the reach it covers."""
    import lightfit.dataset.dataset as D

    cut = D.periodic_canopy
    monkeypatch.setattr(D, "periodic_canopy", lambda mesh, cell, reach: cut(mesh, cell, reach, max_faces=mesh.n_faces))
    args = ["render-dataset", str(periodic_results_file), "-o", str(tmp_path / "x"), "--sweep", "1", "--width", "16"]
    r = CliRunner().invoke(app, [*args, "--height", "16", "--spp", "1", "--gallery", "0", "--export", "none"])
    assert r.exit_code == 0, r.output
    meta = json.loads((tmp_path / "x" / "metadata.json").read_text())["periodic_canopy"]
    said = " ".join(r.output.split())
    assert meta["copies"] == 1 and meta["reach_m"] >= 0  # the cell alone covers no distance beyond itself
    assert f"covers {meta['reach_m']:.2f} m of the {meta['requested_reach_m']:.2f} m" in said


def test_periodic_results_rebuild_the_periodic_cell(periodic_results_file, results_file):
    from lightfit.dataset.results import field_of

    fld = field_of(open_results(periodic_results_file))
    assert fld.boundary == "periodic" and fld.buffer_rows == 0 and fld.cell is not None
    assert build_geometry(open_results(periodic_results_file)).cell == fld.cell
    # Another seed turns the plants other ways with the same segment areas: the layout fingerprint
    # tells (a review's results file with seed edited passed the area check by rounding luck).
    turned = open_results(periodic_results_file).ds.copy()
    turned.attrs["seed"] = 2
    with pytest.raises(InputError, match="stood or faced otherwise") as e:
        build_geometry(open_results(turned))
    assert e.value.column == "layout_fingerprint"
    assert Field(n_plants=4, seed=2, boundary="periodic").layout_fingerprint() != fld.layout_fingerprint()
    assert Field(n_plants=4, seed=2, headings="aligned").layout_fingerprint() == (
        Field(n_plants=4, seed=1, headings="aligned").layout_fingerprint()
    )  # aligned plants do not depend on the seed's headings
    assert field_of(open_results(results_file)).boundary == "finite"
    # Files written before the periodic boundary carry no 'boundary' attr: they are finite fields.
    ds = open_results(results_file).ds.copy()
    del ds.attrs["boundary"]
    assert field_of(open_results(ds)) == field_of(open_results(results_file))
    ds.attrs["boundary"] = "toroidal"
    with pytest.raises(InputError, match="toroidal"):
        field_of(open_results(ds))
    # Attributes that are not the field's values name the file and the attribute (a review found a
    # ValueError traceback, and seed=-3 blamed on render-dataset's own --seed).
    ds.attrs["boundary"] = "finite"
    for key, bad, match in (
        ("n_plants", "abc", r"results, column 'n_plants': n_plants='abc' \(expected an integer\)"),
        ("row_spacing_m", "x", r"results, column 'row_spacing_m': row_spacing_m='x' \(expected a number\)"),
        ("seed", -3, r"results, column 'seed': seed=-3 \(expected an integer ≥ 0\)"),
        ("n_plants", 0, r"results, column 'n_plants': n_plants=0"),
    ):
        edited = ds.copy()
        edited.attrs[key] = bad
        with pytest.raises(InputError, match=match):
            field_of(open_results(edited))
    # Without 'headings' (written before plants faced their own ways): aligned plants.
    del ds.attrs["headings"]
    assert field_of(open_results(ds)).headings == "aligned"


def test_periodic_field_images_show_an_endless_canopy(periodic_results_file, results_file, tmp_path):
    """Near the image edges an oblique view of a periodic field sees canopy, where the finite block shows soil."""
    from lightfit.dataset.results import field_of

    cam = Camera(
        name="obl", position_m=(0.35, -0.35, 0.7), look_at_m=(0.0, 0.0, 0.0), fov_deg=50.0, width_px=48, height_px=48
    )
    spec = DatasetSpec(
        cameras=[cam],
        times=[TIMES[1]],
        settings=RenderSettings(spp=1, colour="mono"),
        materials=VisualMaterials(periodic_max_reach_m=1.0),
        gallery_images=0,
        export="none",
    )
    border = {}
    for name, path in (("finite", results_file), ("periodic", periodic_results_file)):
        meta = make_dataset(path, tmp_path / name, spec)
        lab = _labels(tmp_path / name, meta["images"][0])
        o = lab["organ"]
        edge = np.concatenate([o[0], o[-1], o[:, 0], o[:, -1]])
        border[name] = np.isin(edge, [ORGAN_CODES["leaf"], ORGAN_CODES["stem"]]).mean()
        assert meta["field_boundary"] == name
        assert meta["field_headings"] == field_of(open_results(path)).headings
        if name == "periodic":
            pc = meta["periodic_canopy"]
            assert pc["copies"] > 100 and not pc["capped_by_max_faces"] and 0.5 < pc["reach_m"] <= 1.0
            # Copies keep their segment ids: canopy pixels anywhere carry the stored values.
            assert lab["valid"][lab["segment_id"] >= 0].all()
            assert (lab["segment_id"][[0, -1]] >= 0).mean() > 0.8
    assert border["finite"] < 0.3 and border["periodic"] > 0.9, border


def test_periodic_canopy_copies_and_budget():
    from lightfit.dataset import periodic_canopy, view_reach_m
    from lightfit.plant import Mesh
    from lightfit.plant.periodic import PeriodicCell

    cell = PeriodicCell(along_m=0.3, across_m=0.5)
    tri = Mesh(
        np.array([[0, 0, 0.1], [0.1, 0, 0.1], [0, 0.1, 0.2]], float),
        np.array([[0, 1, 2]]),
        np.array([7]),
        np.array([True]),
    )
    m, info = periodic_canopy(tri, cell, reach_m=1.0)
    assert np.array_equal(m.vertices[:3], tri.vertices)  # the original first, unchanged
    assert (m.face_segment == 7).all() and m.n_faces == info["copies"]
    shifts = m.vertices[::3, :2] - tri.vertices[0, :2]
    assert np.abs(np.linalg.norm(shifts, axis=1)).max() <= 1.0 + 0.5 * np.hypot(0.3, 0.5) + 1e-9
    small, info2 = periodic_canopy(tri, cell, reach_m=1.0, max_faces=5)
    assert small.n_faces == 5 and info2["capped_by_max_faces"] and info2["reach_m"] < 1.0
    # A camera looking straight down sees the ground within tan(fov/2)·height (corners: √2 of it).
    down = Camera(position_m=(0, 0, 1.0), look_at_m=(0, 0, 0), up=(0, 1, 0), fov_deg=90.0)
    assert view_reach_m([down]) == pytest.approx(np.sqrt(2), rel=1e-6)
    assert view_reach_m([down], max_reach_m=0.5) == 0.5
    sky = Camera(position_m=(0, 0, 1.0), look_at_m=(1, 0, 2.0), fov_deg=30.0)
    assert view_reach_m([sky]) == 0.0


def test_sun_of_results_from_another_site(results_file):
    """Results of a run elsewhere (attrs from lightfit.replication.when_attrs) are lit by that
    site's sun: compared with pvlib's solar position called directly at the same coordinates."""
    import pvlib

    from lightfit.dataset.results import _sun

    res = open_results(results_file)
    res.ds.attrs |= {
        "site": "Cape Town",
        "site_latitude_deg": -33.92,
        "site_longitude_deg": 18.42,
        "site_altitude_m": 10.0,
        "site_timezone": "Africa/Johannesburg",
    }
    want = pvlib.solarposition.get_solarposition(res.times, -33.92, 18.42, altitude=10.0)
    got = _sun(res)
    np.testing.assert_allclose(got["sun_elevation_deg"], want["apparent_elevation"], atol=1e-9)
    np.testing.assert_allclose(got["sun_azimuth_deg"], want["azimuth"], atol=1e-9)
    # And not Selhausen's sun: at the same instants Cape Town sees it to the north, Selhausen to the south-east/south.
    here = _sun(open_results(results_file))["sun_azimuth_deg"].to_numpy()
    assert np.abs(got["sun_azimuth_deg"].to_numpy() - here).min() > 60


def test_results_with_their_own_sun_and_sky_refuse_another_weather(results_file, tmp_path, monkeypatch):
    """Results that carry the sun and sky that lit their labels are imaged under that sky; a
    --weather for them used to be ignored without a word, and is now refused."""
    import xarray as xr

    from lightfit.dataset.results import LIGHT_VARS, lighting

    with xr.open_dataset(results_file, engine="h5netcdf") as ds:
        lit = ds.load()
    own = dict(zip(LIGHT_VARS, (41.0, 170.0, 650.0, 120.0), strict=True))
    for v, x in own.items():
        lit[v] = ("time", np.full(lit.sizes["time"], x))
    path = tmp_path / "lit.nc"
    lit.to_netcdf(path, engine="h5netcdf")
    assert lighting(open_results(path), [0])[0] == Lighting(*own.values())
    from lightfit.dataset.results import lighting_provenance

    assert lighting_provenance(open_results(path)) == {"from": "results", "variables": list(LIGHT_VARS)}
    # Results without sun and sky are lit by a weather series: the metadata names it (it named only
    # the model run's weather); bundled here, with its documented provenance.
    from lightfit import weather

    reads, read_source = [], weather.read_source
    monkeypatch.setattr(weather, "read_source", lambda *a, **k: reads.append(a) or read_source(*a, **k))
    unlit = open_results(results_file)
    told = lighting_provenance(unlit, "selhausen-cplantbox-day")
    lighting(unlit, [0], "selhausen-cplantbox-day")
    monkeypatch.undo()
    assert told["from"] == "weather" and told["source"].endswith("selhausen_cplantbox_day.txt")
    assert told["provenance"] == "measured"
    # the undated day file is placed on the results' target date, and the metadata says on which
    assert told["placed_on_date"] == str(unlit.ds.attrs["target_date"])
    assert "placed_on_date" not in lighting_provenance(unlit, "2016-04-20")  # a dated series is not placed
    assert len(reads) == 1  # one read for both (it was read twice per dataset)
    with pytest.raises(InputError, match="carry their own sun and sky") as e:
        lighting(open_results(path), [0], "2016-04-20")
    assert e.value.column == "weather"
    r = CliRunner().invoke(app, ["render-dataset", str(path), "-o", str(tmp_path / "x"), "--weather", "2016-04-20"])
    assert r.exit_code == 2 and "carry their own sun and sky" in " ".join(r.stderr.split())
    assert not (tmp_path / "x" / "images").exists()


def test_an_output_folder_holding_a_dataset_is_refused(mono_dataset, results_file):
    """A second dataset written into the first's folder would mix its images with the first's while
    metadata.json listed only its own (a newcomer's review found three runs' images in one folder)."""
    out, meta = mono_dataset
    before = sorted(p.name for p in (out / "images").iterdir())
    with pytest.raises(InputError, match="already holds a dataset") as e:
        make_dataset(results_file, out, DatasetSpec(cameras=[CAM], quantities=("photons",)))
    assert e.value.file == out
    assert sorted(p.name for p in (out / "images").iterdir()) == before  # nothing written


def test_an_interrupted_dataset_resumes(results_file, tmp_path, monkeypatch):
    """Interrupted in its second camera, a dataset keeps the first camera's render: the same call
    takes it over, renders only the second camera, and ends bitwise as an uninterrupted run (each
    image's random numbers follow its camera's and time's index). The marker of another job (here
    another spp) starts the folder again; a finished dataset stays refused. Before, every image was
    rendered again."""
    import sys

    import lightfit.dataset.dataset as D

    R = sys.modules["lightfit.dataset.render"]  # the package's `render` attribute is the function

    cams = [CAM, Camera(name="nw", position_m=(-0.45, 0.45, 0.75), look_at_m=(0.0, 0.0, 0.2), fov_deg=50.0, **SMALL)]
    spec = DatasetSpec(
        cameras=cams, times=["all"], settings=RenderSettings(spp=1, colour="mono", seed=4), gallery_images=0
    )
    ref = make_dataset(results_file, tmp_path / "ref", spec)
    hits, calls = R._primary_hits, []

    def interrupted_in_second_camera(*args, **kw):
        calls.append(1)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return hits(*args, **kw)

    def interrupt(out, spec):
        calls.clear()
        monkeypatch.setattr(R, "_primary_hits", interrupted_in_second_camera)
        with pytest.raises(KeyboardInterrupt):
            make_dataset(results_file, out, spec)
        monkeypatch.setattr(R, "_primary_hits", hits)
        assert (out / D.UNFINISHED / "camera_0.npz").exists() and not (out / "metadata.json").exists()

    out = tmp_path / "run"
    interrupt(out, spec)
    rendered = []
    real_render = D.render

    def counted(arrays, cams, *a, **kw):
        rendered.extend(c.name for c in cams)
        return real_render(arrays, cams, *a, **kw)

    monkeypatch.setattr(D, "render", counted)
    meta = make_dataset(results_file, out, spec)
    assert rendered == ["nw"] and meta["cameras_taken_over"] == 1 and meta["cameras_discarded"] == 0
    assert not (out / D.UNFINISHED).exists() and len(meta["images"]) == len(ref["images"]) == 4
    for a, b in zip(ref["images"], meta["images"]):
        assert a["name"] == b["name"] and a["exposure"] == b["exposure"]
        for k in ("exr", "png", "labels"):
            assert (out / b[k]).read_bytes() == (tmp_path / "ref" / a[k]).read_bytes(), (b["name"], k)
    with pytest.raises(InputError, match="already holds a dataset"):
        make_dataset(results_file, out, spec)
    # Another job's unfinished folder: nothing is taken over.
    other = tmp_path / "other"
    interrupt(other, spec)
    rendered.clear()
    spp2 = DatasetSpec(**{**spec.__dict__, "settings": RenderSettings(spp=2, colour="mono", seed=4)})
    again = make_dataset(results_file, other, spp2)
    assert rendered == ["se", "nw"] and again["cameras_taken_over"] == 0
    assert again["cameras_discarded"] == 1  # said (it was dropped without a word; a review)
    # Options that change only what is written from the renders do not discard them.
    third = tmp_path / "third"
    interrupt(third, spec)
    rendered.clear()
    written = DatasetSpec(**{**spec.__dict__, "export": "none", "gallery_images": 1, "depth": False})
    assert make_dataset(results_file, third, written)["cameras_taken_over"] == 1 and rendered == ["nw"]


def test_gallery_colour_bars_carry_the_quantities_units(mono_dataset, results_file, monkeypatch):
    """Each label panel's colour bar says its units (from the results schema, as the metadata does)."""
    from matplotlib.figure import Figure

    from lightfit.dataset.gallery import gallery, quantity_title

    out, meta = mono_dataset
    quantities = list(meta["quantities"])
    units = {q: meta["quantities"][q]["units"] for q in quantities}
    seen = []
    monkeypatch.setattr(Figure, "savefig", lambda fig, *a, **k: seen.append(fig))
    gallery(out, meta["images"][:1], quantities, units)
    labels = {ax.get_ylabel() for ax in seen[0].axes}
    shown = [q for q in quantities if any(quantity_title(q) == ax.get_title() for ax in seen[0].axes)]
    assert any(units[q] != "1" for q in shown)
    # in the project's figure style, not UDUNITS' ASCII (every other figure writes µmol m⁻² s⁻¹)
    assert units["absorbed_par"] == "umol m-2 s-1" and "µmol m⁻² s⁻¹" in labels
    assert not any("m-2" in label for label in labels)
    # the margin's unit "1" (CF for a ratio) stood on its bar as a lone number; its title named no
    # limitation, only Fj>Fc, which a reader must look up to learn that red is Rubisco limited
    margin = next(ax for ax in seen[0].axes if "(Vj−Vc)/(Vj+Vc)" in ax.get_title())
    assert units["limitation_margin"] == "1" and "dimensionless" in labels and "1" not in labels
    assert "red Fj>Fc, Rubisco limited" in margin.get_title() and "blue Fj<Fc, electron-transport" in margin.get_title()


def test_results_it_cannot_label_or_place_are_refused(results_file, tmp_path):
    """Results with none of the label quantities (images with geometry labels only passed for a
    labelled dataset, every buffer pixel 'valid'), results of several days (one field per day;
    it failed on the joined date), a quantity the results lack (it was listed as valid), and a
    time given twice (one image listed twice)."""
    import xarray as xr

    from lightfit.dataset.dataset import DEFAULT_QUANTITIES, resolve_quantities
    from lightfit.dataset.results import QUANTITIES, field_of, select_times

    with xr.open_dataset(results_file) as ds:
        bare = ds.drop_vars([QUANTITIES[q] for q in DEFAULT_QUANTITIES if q in QUANTITIES]).load()
        two_days = ds.load().assign_attrs(target_date="2016-04-20; 2016-04-27")
    bare.to_netcdf(tmp_path / "bare.nc", engine="h5netcdf")
    with pytest.raises(InputError, match="none of the label quantities"):
        make_dataset(tmp_path / "bare.nc", tmp_path / "out", DatasetSpec(cameras=[CAM]))
    with pytest.raises(InputError, match=r"quantity 'vc': the results have no variable leaf_vc_umol_m2_s"):
        resolve_quantities(open_results(tmp_path / "bare.nc"), ["vc"])
    two_days.to_netcdf(tmp_path / "days.nc", engine="h5netcdf")
    with pytest.raises(InputError, match="several days"):
        field_of(open_results(tmp_path / "days.nc"))
    res = open_results(results_file)
    assert select_times(res, [TIMES[1], TIMES[1]]) == select_times(res, [TIMES[1]])
    # A bare clock time is the site's local time on the results' day (CEST, UTC+2, on 20 April), as the
    # tables and figures label the steps; pandas had read it as today's date in UTC (a newcomer's audit).
    assert select_times(res, ["10:00", "13:00:00"]) == select_times(res, TIMES)
    for bad in ("9:5", "10:00+02:00", "noon"):  # no date and not HH:MM: pandas would date them today
        with pytest.raises(InputError, match="has no date and is not HH:MM"):
            select_times(res, [bad])
    assert select_times(res, ["2016-04-20T10:00+02:00"]) == select_times(res, [TIMES[0]])
    with pytest.raises(InputError, match=r"is not a step of the results \(expected one of .* 10:00 … 13:00 local"):
        select_times(res, ["08:00"])
    with xr.open_dataset(results_file) as ds:
        t = ds["time"].values
        ds.load().assign_coords(time=[t[0], t[1] + np.timedelta64(1, "D")]).to_netcdf(tmp_path / "2d.nc")
    with pytest.raises(InputError, match="has no date and the results span 2 days"):
        select_times(open_results(tmp_path / "2d.nc"), ["10:00"])
    # a step without a time (NaT) is left out of the clock's day and of the message (raw errors)
    with xr.open_dataset(results_file) as ds:
        ds.load().assign_coords(time=[t[0], np.datetime64("NaT")]).to_netcdf(tmp_path / "nat.nc")
    nat = open_results(tmp_path / "nat.nc")
    assert select_times(nat, ["10:00"]) == [0]
    with pytest.raises(InputError, match=r"not a step of the results \(expected one of .* \(1 steps\)"):
        select_times(nat, ["2016-04-20T11:00"])


def test_field_export_keeps_stems_whose_leaf_quantities_are_nan(tmp_path):
    """A stem has absorbed PAR but no An: its faces stay in field_values (every stem was left out);
    a segment without any value (a buffer plant) does not."""
    from lightfit.dataset.dataset import export_field
    from lightfit.plant.mesh import Mesh

    tri = np.array([[0, 1, 2]])
    verts = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
    mesh = Mesh(verts, np.repeat(tri, 3, axis=0), np.array([1, 2, 3]), np.array([True, False, False]))
    values = {
        "absorbed_par": pd.Series({1: 100.0, 2: 40.0}),  # segment 3: a buffer plant, no results
        "an": pd.Series({1: 12.0, 2: np.nan}),  # segment 2: a stem
    }
    meta = export_field(mesh, values, tmp_path / "f.ply")
    assert (meta["faces"], meta["faces_left_out"]) == (2, 1)


def test_results_of_another_field_size_are_refused(results_file, tmp_path):
    """Attrs saying 9 plants on results of 4: every segment id exists in the 3 x 3 field, so only the
    plant count tells (it rendered the other field silently)."""
    import xarray as xr

    from lightfit.dataset import build_geometry

    with xr.open_dataset(results_file) as ds:
        bigger = ds.load().assign_attrs(n_plants=9)
    with pytest.raises(InputError, match="stood or faced otherwise"):  # the layout fingerprint tells first
        build_geometry(open_results(bigger))
    del bigger.attrs["layout_fingerprint"]  # files written before it: the plant count
    bigger.to_netcdf(tmp_path / "nine.nc", engine="h5netcdf")
    with pytest.raises(InputError, match="the results hold 4 plants, the field rebuilt from its attrs measures 9"):
        build_geometry(open_results(tmp_path / "nine.nc"))


def test_results_of_other_plants_are_refused(results_file, tmp_path):
    """The same segment ids and plant count, other plants: an edited plant file or another CPlantBox
    version (growth fingerprint), and for files without it, segment areas that differ."""
    import xarray as xr

    from lightfit.dataset import build_geometry

    with xr.open_dataset(results_file) as ds:
        ds = ds.load()
    other = ds.assign_attrs(growth_fingerprint="0123456789abcdef")
    other.to_netcdf(tmp_path / "other.nc", engine="h5netcdf")
    with pytest.raises(InputError, match="grown from another plant file or CPlantBox version"):
        build_geometry(open_results(tmp_path / "other.nc"))
    old = ds.copy()
    del old.attrs["growth_fingerprint"]
    area = old["area_m2"].values.copy()
    area[3] *= 1.5
    old = old.assign_coords(area_m2=("segment", area))
    old.to_netcdf(tmp_path / "old.nc", engine="h5netcdf")
    with pytest.raises(InputError, match=r"1 segment\(s\) have another area"):
        build_geometry(open_results(tmp_path / "old.nc"))
    same = ds.copy()
    del same.attrs["growth_fingerprint"]
    same.to_netcdf(tmp_path / "same.nc", engine="h5netcdf")
    assert len(build_geometry(open_results(tmp_path / "same.nc")).segments)


def test_cli_a_results_file_that_is_not_netcdf_is_refused_by_name(tmp_path):
    """The run's forcing.csv given as results passed on xarray's list of backends and their web
    pages (a CLI review); a folder is said to be one (it was "results file not found", though there)."""
    csv = tmp_path / "forcing.csv"
    csv.write_text("time_utc,par_umol_m2_s\n2016-04-20T10:00:00Z,1500\n")
    missing = tmp_path / "no-such.nc"
    for source, text in (
        (csv, "not a netCDF file"),
        (tmp_path, "a folder, not a file"),
        (missing, "results file not found"),
    ):
        r = CliRunner().invoke(app, ["render-dataset", str(source), "--out", str(tmp_path / "x")])
        err = " ".join(r.stderr.split())
        assert r.exit_code == 2 and err.startswith(f"error: {source}: {text}") and "http" not in err, err


@pytest.mark.parametrize("sky", ["isotropic", "overcast"])
def test_the_images_sky_is_the_runs_own(sky, results_file):
    """render-dataset lit every image with an isotropic sky, also for a run rendered under the CIE
    overcast one (a review): its sky is now the results'. Peer: Mitsuba's irradiancemeter under the
    data scene's sky emitter, on a horizontal plane (DHI) and on a vertical one above a black ground
    (the closed forms the light model is tested against in test_light_irradiance.py: 0.5 DHI under the
    isotropic sky, 9/(7π)·(π/2 + 4/3)/3 ≈ 0.396 DHI under the overcast one)."""
    import math

    import xarray as xr

    from lightfit.dataset.render import _emitters
    from lightfit.dataset.results import lighting
    from lightfit.light import backend

    mi = backend.mitsuba()
    dhi = 100.0
    light = Lighting(30.0, 180.0, 0.0, dhi, sky=sky)
    wall = 0.5 if sky == "isotropic" else 9 / (7 * math.pi) * (math.pi / 2 + 4 / 3) / 3
    ground = {"type": "rectangle", "to_world": mi.ScalarTransform4f().translate([0, 0, -0.02]).scale(1000)}
    ground["bsdf"] = {"type": "diffuse", "reflectance": {"type": "rgb", "value": 0.0}}
    for turn, expected in ((0, dhi), (90, wall * dhi)):
        meter = {
            "type": "rectangle",
            "to_world": mi.ScalarTransform4f().rotate([1, 0, 0], turn).scale(0.01),
            "sensor": {
                "type": "irradiancemeter",
                "film": {"type": "hdrfilm", "width": 1, "height": 1, "rfilter": {"type": "box"}},
                "sampler": {"type": "independent", "sample_count": 2**18},
            },
        }
        scene = mi.load_dict(
            {"type": "scene", **_emitters(light), "ground": ground, "meter": meter, "integrator": {"type": "direct"}}
        )
        e = float(np.mean(np.asarray(mi.render(scene, seed=1))))
        assert e == pytest.approx(expected, rel=0.005), (sky, turn, e, expected)
    # The results' sky reaches the lights a dataset renders with.
    with xr.open_dataset(results_file) as ds:
        path = results_file.parent / f"{sky}.nc"
        ds.assign_attrs(sky=sky).to_netcdf(path)
    (lt,) = lighting(open_results(path), [1])
    assert lt.sky == sky and ("sky" in lt.to_dict()) == (sky == "overcast")


# --- Mutation audit of lightfit.dataset: behaviour the tests above left open. ---


def test_pixel_rays_follow_the_pinhole_geometry():
    """A camera at (0, −2, 1) looking north along the horizontal, fov 90°, 4 × 2 px: the right edge of
    the image is 45° east of north (tan 45° = 1), the top edge atan(0.5) up (the aspect ratio 2 / 4),
    pixel (0, 0) top-left. Hand-worked rays of the pinhole: x right = east, y up = z."""
    cam = Camera(
        name="n", position_m=(0.0, -2.0, 1.0), look_at_m=(0.0, 0.0, 1.0), fov_deg=90.0, width_px=4, height_px=2
    )
    corner = np.zeros((2, 4, 2))
    corner[0, 3] = (1.0, 0.0)  # top-right pixel, its top-right corner
    corner[1, 0] = (0.0, 1.0)  # bottom-left pixel, its bottom-left corner
    d = cam.directions(corner).reshape(2, 4, 3)
    np.testing.assert_allclose(d[0, 3], np.array([1.0, 1.0, 0.5]) / 1.5, atol=1e-12)
    np.testing.assert_allclose(d[1, 0], np.array([-1.0, 1.0, -0.5]) / 1.5, atol=1e-12)
    # Pixel centres: x = ±0.25, ±0.75 (tan of the angle from the axis), y = ±0.25.
    c = cam.directions().reshape(2, 4, 3)
    np.testing.assert_allclose(c[..., 0] / c[..., 1], [[-0.75, -0.25, 0.25, 0.75]] * 2, atol=1e-12)
    np.testing.assert_allclose(c[..., 2] / c[..., 1], [[0.25] * 4, [-0.25] * 4], atol=1e-12)


def test_sweep_places_cameras_by_compass_azimuth_and_elevation():
    """Azimuth clockwise from north starting at 180° (south), n evenly spaced; the line of sight to
    the target (half the canopy height) rises at elevation_deg: z = target + d·tan(elevation)."""
    cams = camera_sweep(Sweep(n=4, distance_m=2.0, elevation_deg=30.0, camera=SMALL), canopy_height_m=0.6)
    z = 0.3 + 2.0 * np.tan(np.radians(30.0))
    want = [(0.0, -2.0), (-2.0, 0.0), (0.0, 2.0), (2.0, 0.0)]  # south, west, north, east
    for c, (x, y) in zip(cams, want, strict=True):
        np.testing.assert_allclose(c.position_m, (x, y, z), atol=1e-12)
        view = np.subtract(c.look_at_m, c.position_m)
        assert np.degrees(np.arctan2(-view[2], np.hypot(view[0], view[1]))) == pytest.approx(30.0)
    east = camera_sweep(Sweep(n=1, distance_m=1.0, start_azimuth_deg=90.0), centre_m=(5.0, 7.0))[0]
    np.testing.assert_allclose(east.position_m[:2], (6.0, 7.0), atol=1e-12)


def test_camera_bounds_are_as_documented():
    """z > 0 (a pinhole on the soil plane is refused) and meter_percentile in (0, 100]: 100 meters
    the brightest leaf pixel, so exactly that one pixel reaches white."""
    with pytest.raises(InputError) as err:
        Camera(position_m=(1.0, 0.0, 0.0))
    assert err.value.column == "position_m"
    rad = np.zeros((10, 10, 3))
    rad[..., 1] = np.arange(100).reshape(10, 10) + 1.0
    leaf = np.zeros((10, 10), bool)
    leaf[:5] = True  # green 1 … 50
    e = meter(rad, leaf, Camera(meter_percentile=100.0, width_px=10, height_px=10))
    assert e.metered_luminance == 50.0 and e.gain == pytest.approx(1 / 50) and e.clipped_leaf_fraction == 1 / 50


def test_exposure_gain_and_srgb_encoding_against_hand_values():
    """Gain per stop is 2^EV; scene metering maps the mean Rec. 709 luminance to 0.18; the sRGB curve
    of IEC 61966-2-1 puts linear 0.5 at 188, 18 % grey at 118, 0.002 (linear segment, 12.92·x) at 7."""
    from lightfit.dataset.exposure import srgb_encode

    px = {"width_px": 2, "height_px": 2}
    red = np.zeros((2, 2, 3))
    red[..., 0] = 1.0
    none = np.zeros((2, 2), bool)
    assert meter(red, none, Camera(exposure_mode="fixed", exposure_ev=1.0, **px)).gain == 2.0
    assert meter(red, none, Camera(exposure_mode="fixed", exposure_ev=-3.0, **px)).gain == 0.125
    assert meter(red, none, Camera(exposure_mode="scene", **px)).gain == pytest.approx(0.18 / 0.2126)
    blue = red[..., ::-1]
    assert meter(blue, none, Camera(exposure_mode="scene", exposure_ev=1.0, **px)).gain == pytest.approx(0.36 / 0.0722)
    grey = np.array([1.0, 1.0, 1.0, 5.0]).reshape(2, 2, 1)  # mean 2 (the median would be 1)
    assert meter(grey, none, Camera(exposure_mode="scene", **px)).metered_luminance == pytest.approx(2.0)
    leaf = np.ones((2, 2), bool)
    assert meter(red * 4.0, leaf, Camera(exposure_ev=-1.0, **px)).gain == pytest.approx(0.5 / 4.0)
    lin = np.array([0.5, 0.18, 0.002, 0.0, 1.0, 1.5, -0.1]).reshape(1, 7, 1)
    assert tone_map(lin, 1.0).ravel().tolist() == [188, 118, 7, 0, 255, 255, 0]
    assert srgb_encode(np.array([0.0031308]))[0] == pytest.approx(12.92 * 0.0031308, abs=1e-9)


def test_scene_arrays_colour_each_organ_and_the_soil():
    """Leaf faces get leaf_rgb and leaf_transmission, stems stem_rgb and no transmission, the two
    soil triangles soil_rgb at z = 0; with colour_variation s each organ's factor lies in [1 − s, 1 + s]
    and spans it (uniform draws), the same for every face of one organ."""
    from lightfit.plant.mesh import Mesh

    n = 200  # one face per organ: 100 leaves then 100 stems
    verts = np.array([[0.0, 0.0, 0.1], [0.1, 0.0, 0.1], [0.0, 0.1, 0.2]])
    mesh = Mesh(verts, np.zeros((n + 2, 3), int) + [0, 1, 2], np.r_[np.arange(n), 0, 100], np.zeros(n + 2, bool))
    segments = pd.DataFrame(
        {
            "segment_id": np.arange(n),
            "plant_id": np.zeros(n, int),
            "organ_id": np.arange(n),
            "organ_type": ["leaf"] * (n // 2) + ["stem"] * (n // 2),
        }
    )
    mats = VisualMaterials(colour_variation=0.0, leaf_transmission=0.3)
    a = scene_arrays(mesh, segments, mats)
    leaf, stem = np.r_[np.arange(n) < n // 2, True, False], np.r_[np.arange(n) >= n // 2, False, True]
    np.testing.assert_allclose(a.face_rgb[: n + 2][leaf], np.tile(mats.leaf_rgb, (leaf.sum(), 1)), rtol=1e-6)
    np.testing.assert_allclose(a.face_rgb[: n + 2][stem], np.tile(mats.stem_rgb, (stem.sum(), 1)), rtol=1e-6)
    np.testing.assert_allclose(a.face_rgb[-2:], [mats.soil_rgb] * 2, rtol=1e-6)
    np.testing.assert_allclose(a.face_transmission, np.r_[np.where(leaf, 0.3, 0.0), 0.0, 0.0], rtol=1e-6)
    assert a.n_plant_faces == n + 2 and (a.vertices[a.faces[-2:]][..., 2] == 0).all()
    s = 0.2
    v = scene_arrays(mesh, segments, VisualMaterials(colour_variation=s), seed=3)
    f = v.face_rgb[:n, 1] / np.where(np.arange(n) < n // 2, mats.leaf_rgb[1], mats.stem_rgb[1])
    assert (f >= 1 - s - 1e-6).all() and (f <= 1 + s + 1e-6).all()
    assert f.min() < 1 - 0.8 * s and f.max() > 1 + 0.8 * s
    assert v.face_rgb[n, 1] == v.face_rgb[0, 1] and v.face_rgb[n + 1, 1] == v.face_rgb[100, 1]  # per organ


def test_periodic_copies_cover_every_point_within_the_reach():
    """Every ground point within reach_m of the centre lies in a kept copy's cell: the nearest point
    of the (whole) lattice to it, whose cell is the rectangle around it, is one of the copies."""
    from lightfit.dataset import periodic_canopy
    from lightfit.plant import Mesh
    from lightfit.plant.periodic import PeriodicCell

    cell = PeriodicCell(along_m=0.3, across_m=0.5)
    marker = Mesh(
        np.array([[0.0, 0, 0], [0.01, 0, 0], [0, 0.01, 0]]), np.array([[0, 1, 2]]), np.array([1]), np.array([1])
    )
    m, info = periodic_canopy(marker, cell, reach_m=1.0)
    kept = m.vertices[::3, :2]
    i, j = np.meshgrid(np.arange(-12, 13), np.arange(-12, 13), indexing="ij")
    lattice = cell.lattice_shift(i.ravel(), j.ravel())
    ang = np.linspace(0, 2 * np.pi, 720, endpoint=False)
    r = np.r_[0.0, 0.25, 0.5, 0.75, 0.9, 0.999]
    pts = (r[:, None, None] * np.stack([np.cos(ang), np.sin(ang)], -1)[None]).reshape(-1, 2)
    nearest = lattice[np.argmin(np.linalg.norm(pts[:, None] - lattice[None], axis=-1), axis=1)]
    dist_to_kept = np.linalg.norm(nearest[:, None] - kept[None], axis=-1).min(axis=1)
    assert dist_to_kept.max() < 1e-9 and info["reach_m"] == 1.0


def test_the_sun_lights_the_scene_from_its_position():
    """Peer: Mitsuba's own direct integrator under the data scene's sun alone (DNI 100 W m⁻², elevation
    30°, azimuth 180° = south), seen on a white Lambertian square (radiance ρE/π): irradiance
    DNI·sin 30° = 50 W m⁻² on a horizontal square, DNI·cos 30° on one facing south, 0 facing north."""
    from lightfit.dataset.render import _emitters
    from lightfit.light import backend

    mi = backend.mitsuba()
    light = Lighting(30.0, 180.0, 100.0, 0.0)
    rho = 0.5
    for turn, normal, expected in (
        (0, (0, 0, 1), 50.0),
        (90, (0, -1, 0), 100.0 * np.cos(np.radians(30.0))),  # rotating +z by 90° about x gives −y
        (-90, (0, 1, 0), 0.0),
    ):
        square = {
            "type": "rectangle",
            "to_world": mi.ScalarTransform4f().rotate([1, 0, 0], turn),
            "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": rho}},
        }
        eye = [2.0 * c for c in normal]
        sensor = {
            "type": "perspective",
            "fov": 2.0,
            "to_world": mi.ScalarTransform4f().look_at(
                origin=eye, target=[0, 0, 0], up=[0, 1, 0] if turn == 0 else [0, 0, 1]
            ),
            "film": {"type": "hdrfilm", "width": 2, "height": 2, "rfilter": {"type": "box"}},
            "sampler": {"type": "independent", "sample_count": 4},
        }
        scene = mi.load_dict(
            {"type": "scene", **_emitters(light), "square": square, "sensor": sensor, "integrator": {"type": "direct"}}
        )
        radiance = float(np.mean(np.asarray(mi.render(scene, seed=1))))
        assert radiance * np.pi / rho == pytest.approx(expected, rel=1e-3, abs=1e-3), (turn, radiance, expected)


def test_an_image_is_the_mean_of_its_passes_and_each_image_has_its_own_noise(geometry):
    """A camera outside the field looking up sees only the isotropic sky: DHI/π in every pixel, at any
    spp (a sum of the passes would show spp × it). Two cameras at the same place under two equal
    lightings give four images whose noise differs pairwise: each (camera, time) has its own random
    numbers."""
    up = Camera(
        name="up", position_m=(0.0, -3.0, 0.3), look_at_m=(0.0, -3.0, 2.0), up=(0, 1, 0), width_px=8, height_px=8
    )
    cam = Camera(name="h", position_m=(0.0, -1.5, 0.3), look_at_m=(0.0, 0.0, 0.3), width_px=16, height_px=16)
    twin = Camera(**{**cam.to_dict(), "name": "h2"})
    sky = Lighting(sun_elevation_deg=-10.0, sun_azimuth_deg=0.0, dni_w_m2=0.0, dhi_w_m2=100.0)
    arrays = scene_arrays(geometry.mesh, geometry.segments)
    out = render(arrays, [up, cam, twin], [sky, sky], RenderSettings(spp=3, colour="mono"))
    assert (out.face[0] == -1).all()
    np.testing.assert_allclose(out.radiance[0][0], 100.0 / np.pi, rtol=1e-5)
    imgs = [out.radiance[c][t] for c in (1, 2) for t in (0, 1)]
    for a in range(4):
        for b in range(a + 1, 4):
            assert not np.array_equal(imgs[a], imgs[b]), (a, b)


def test_limitation_margin_is_vj_minus_vc_over_their_sum(results_file):
    """(Vj − Vc)/(Vj + Vc) from the file's own variables, and its sign is the limitation's: < 0 where
    Fj < Fc (limitation 1, electron-transport limited)."""
    import xarray as xr

    res = open_results(results_file)
    with xr.open_dataset(results_file) as ds:
        for t in range(ds.sizes["time"]):
            vc, vj = (ds[v].values[t].astype(float) for v in ("leaf_vc_umol_m2_s", "leaf_vj_umol_m2_s"))
            lim = ds["limitation"].values[t]
            got = res.values(MARGIN, t).reindex(ds["segment"].values).to_numpy()
            np.testing.assert_allclose(got, (vj - vc) / (vj + vc), rtol=1e-12)
            np.testing.assert_array_equal(got < 0, lim == 1)
            assert (lim == 1).any() or (lim == 0).any()


def test_default_time_is_the_highest_sun(results_file):
    """Without --time: the step with the highest sun. At Selhausen (50.9° N, 6.4° E) on 20 April the sun
    stands higher at 11:00 UTC (near solar noon) than at 08:00; results that carry their own
    sun_elevation_deg are taken at their word."""
    from lightfit.dataset.results import select_times

    res = open_results(results_file)
    assert select_times(res, None) == [1]
    own = open_results(res.ds.assign(sun_elevation_deg=("time", [60.0, 20.0])))
    assert select_times(own, None) == [0]


def test_a_date_with_unpadded_month_and_day_is_a_date(results_file):
    """2016-4-20T11:00 is the step 2016-04-20T11:00 (UTC), as pandas reads it: it was refused as
    "has no date and is not HH:MM" (a review); a clock time is still not a date."""
    from lightfit.dataset.results import select_times

    res = open_results(results_file)
    assert select_times(res, ["2016-4-20T11:00", "2016-4-20 08:00"]) == [1, 0]
    with pytest.raises(InputError, match="has no date and is not HH:MM"):
        select_times(res, ["11:00 UTC"])


def test_weather_irradiance_is_interpolated_linearly_between_records(results_file):
    """Results without their own sun and sky at 08:05 UTC, halfway between two 10-min records of the
    bundled 2016-04-20 series: DNI and DHI are the records' mean."""
    from lightfit import weather
    from lightfit.dataset.results import lighting

    ds = open_results(results_file).ds
    shifted = ds.assign_coords(time=pd.to_datetime(["2016-04-20T08:05", "2016-04-20T11:00"]).to_numpy())
    (lt,) = lighting(open_results(shifted), [0])
    wx = weather.load("2016-04-20")
    rec = wx.loc[pd.Timestamp("2016-04-20T08:00", tz="UTC") : pd.Timestamp("2016-04-20T08:10", tz="UTC")]
    assert len(rec) == 2 and rec["dni_w_m2"].iloc[0] != rec["dni_w_m2"].iloc[1]
    assert lt.dni_w_m2 == pytest.approx(rec["dni_w_m2"].mean(), rel=1e-9)
    assert lt.dhi_w_m2 == pytest.approx(rec["dhi_w_m2"].mean(), rel=1e-9)


def test_job_key_changes_with_what_renders_and_not_with_threads(geometry):
    """An interrupted run's cameras are taken over only by the same job: another seed, spp, path depth,
    colour, camera, lighting or material renders other images; the thread count does not."""
    from dataclasses import replace

    from lightfit.dataset.dataset import _job_key

    arrays = scene_arrays(geometry.mesh, geometry.segments)
    base = dict(
        cams=[CAM], lights=[SUN], settings=RenderSettings(spp=2, colour="mono", seed=4), materials=VisualMaterials()
    )

    def key(**kw):
        a = {**base, **kw}
        return _job_key(arrays, a["cams"], a["lights"], a["settings"], a["materials"])

    k0 = key()
    assert key(settings=replace(base["settings"], threads=3)) == k0
    others = [
        key(settings=replace(base["settings"], seed=5)),
        key(settings=replace(base["settings"], spp=3)),
        key(settings=replace(base["settings"], max_depth=3)),
        key(settings=replace(base["settings"], colour="rgb")),
        key(cams=[replace(CAM, fov_deg=40.0)]),
        key(lights=[replace(SUN, dhi_w_m2=121.0)]),
        key(materials=VisualMaterials(roughness=0.4)),
    ]
    assert k0 not in others and len(set(others)) == len(others)
    # a renderer that renders the same arrays otherwise (diff_trans = 2τ) takes over no kept camera
    from lightfit.dataset import dataset as D

    D.RENDER_REVISION += 1
    try:
        assert key() != k0
    finally:
        D.RENDER_REVISION -= 1


def test_field_export_carries_the_first_selected_steps_values(mono_dataset, results_file):
    """field_values.ply's per-face values are those of the first selected step (the metadata says so),
    each face's value its segment's in the results (the PLY read by trimesh, an independent reader)."""
    import trimesh

    out, meta = mono_dataset
    res = open_results(results_file)
    raw = trimesh.load(out / meta["field_export"]["file"], process=False).metadata["_ply_raw"]["face"]["data"]
    seg = raw["segment_id"].ravel().astype(np.int64)
    first = res.values("absorbed_par", meta["images"][0]["time_index"]).reindex(seg).to_numpy(float)
    last = res.values("absorbed_par", 1).reindex(seg).to_numpy(float)
    assert meta["images"][0]["time_index"] == 0 and not np.allclose(first, last)
    np.testing.assert_allclose(raw["absorbed_par"].ravel(), first, rtol=1e-6)
    # The file alone says which step, whose values and their units (PLY comments, read by hand: the
    # header is ASCII lines up to end_header); it said only "units m", the vertices'.
    head = (out / meta["field_export"]["file"]).read_bytes().split(b"end_header")[0].decode("ascii")
    notes = dict(line[8:].split(": ", 1) for line in head.splitlines() if line.startswith("comment ") and ": " in line)
    assert notes["time_utc"] == meta["images"][0]["time_utc"] == "2016-04-20T08:00:00+00:00"
    assert notes["values"].startswith("SYNTHETIC") and notes["results_file"] == "results.nc"
    assert notes["units of absorbed_par"] == "umol m-2 s-1"  # µmol photons m⁻² s⁻¹, UDUNITS spelling


def test_gallery_columns_absorbed_par_and_margin_or_the_next_quantity():
    from lightfit.dataset.gallery import _columns

    assert _columns(["an", "absorbed_par", MARGIN]) == ["absorbed_par", MARGIN]
    assert _columns(["absorbed_par", "an", "gs"]) == ["absorbed_par", "an"]
    assert _columns(["an", "gs", "vc"]) == ["an", "gs"]


def test_results_in_other_units_or_without_values_are_refused(results_file, tmp_path):
    """The labels take their units from the schema: a results file saying W m-2 for absorbed PAR was
    labelled µmol m-2 s-1 all the same, and a quantity of NaN alone gave images whose labels were all
    NaN (a review of bad input). Both are refused naming the variable and what was expected."""
    import xarray as xr

    ds = xr.load_dataset(results_file)
    var = "absorbed_par_umol_m2_s"
    assert ds[var].attrs["units"] == "umol m-2 s-1"
    other = ds.copy()
    other[var].attrs["units"] = "W m-2"
    other.to_netcdf(tmp_path / "wm2.nc", engine="h5netcdf")
    with pytest.raises(InputError, match=r"variable absorbed_par_umol_m2_s in units 'W m-2'.*'umol m-2 s-1'"):
        open_results(tmp_path / "wm2.nc")
    empty = ds.copy()
    empty[var] = empty[var] * np.nan
    empty[var].attrs = ds[var].attrs
    empty.to_netcdf(tmp_path / "nan.nc", engine="h5netcdf")
    spec = DatasetSpec(quantities=("absorbed_par",), gallery_images=0, export="none")
    with pytest.raises(InputError, match="quantity absorbed_par has no finite value at"):
        make_dataset(tmp_path / "nan.nc", tmp_path / "out", spec)


def test_leaves_transmit_the_documented_share_of_their_diffuse_light():
    """VisualMaterials.leaf_transmission is the share of a leaf's diffuse light sent to its other side
    (docs: 40 % diffuse transmission). Hand values for a large horizontal grey leaf (albedo ρ = 0.5,
    transmission τ) under a zenith sun of DNI E and no sky, direct light only: radiance τ·ρ·E/π seen
    from below, (1 − τ)·ρ·E/π from above (Lambertian lobes; the glossy lobe lies off these views).
    Mitsuba's principledthin takes diff_trans in [0, 2] and halves it: passed τ as is, the leaf sent
    τ/2 through and reflected 1 − τ/2."""
    from lightfit.dataset import SceneArrays

    h, z, rho, tau, dni = 5.0, 0.5, 0.5, 0.4, 1000.0
    verts = np.array(
        [[-h, -h, z], [h, -h, z], [h, h, z], [-h, h, z], [-h, -h, 0], [h, -h, 0], [h, h, 0], [-h, h, 0]], np.float32
    )
    arrays = SceneArrays(
        vertices=verts,
        faces=np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]], np.uint32),
        face_rgb=np.array([[rho] * 3, [rho] * 3, [0.0] * 3, [0.0] * 3], np.float32),  # black soil
        face_transmission=np.array([tau, tau, 0.0, 0.0], np.float32),
        n_plant_faces=2,
    )
    sun = Lighting(sun_elevation_deg=90.0, sun_azimuth_deg=180.0, dni_w_m2=dni, dhi_w_m2=0.0)
    px = {"width_px": 4, "height_px": 4, "fov_deg": 10.0}
    below = Camera(name="below", position_m=(0.02, 0.0, 0.2), look_at_m=(0.0, 0.0, z), **px)
    above = Camera(name="above", position_m=(0.02, 0.0, 0.8), look_at_m=(0.0, 0.0, z), **px)
    out = render(arrays, [below, above], [sun], RenderSettings(spp=1, max_depth=2, colour="mono", seed=0))
    seen_below, seen_above = (float(out.radiance[c][0].mean()) for c in (0, 1))
    assert seen_below == pytest.approx(tau * rho * dni / np.pi, rel=0.01)
    assert seen_above == pytest.approx((1 - tau) * rho * dni / np.pi, rel=0.01)
    # the default leaf reflects the documented green-leaf reflectance (≈ 5 / 12 / 3 %)
    m = VisualMaterials()
    np.testing.assert_allclose((1 - m.leaf_transmission) * np.asarray(m.leaf_rgb), (0.05, 0.12, 0.03), rtol=1e-12)


def test_gallery_shows_no_class_where_a_class_label_has_no_value(mono_dataset, monkeypatch):
    """A class label's "no value" (−1: soil, sky, stems, buffer plants) is no class: the gallery's
    limitation panel painted it as a third class over the whole background, on a colour bar from
    −1 to 1. Now those pixels are left out (the panel's background), as NaN is for float labels, and
    the two classes keep their codes."""
    from matplotlib.figure import Figure

    from lightfit.dataset.gallery import gallery

    out, meta = mono_dataset
    entry = meta["images"][0]
    lim = _labels(out, entry)["limitation"]
    assert (lim == -1).any() and ((lim == 0) | (lim == 1)).any()
    seen = []
    monkeypatch.setattr(Figure, "savefig", lambda fig, *a, **k: seen.append(fig))
    gallery(out, [entry], ["absorbed_par", "limitation"], {"absorbed_par": "umol m-2 s-1", "limitation": "1"})
    (ax,) = [a for a in seen[0].axes if a.get_title().startswith("limiting process")]
    shown = np.ma.masked_invalid(ax.images[0].get_array())
    np.testing.assert_array_equal(np.ma.getmaskarray(shown), lim == -1)
    np.testing.assert_array_equal(shown.compressed(), lim[lim != -1])


def test_a_results_variable_outside_the_schema_is_refused_before_rendering(results_file, tmp_path):
    """The labels' units come from the schema (metadata.json's quantities), so a per-segment variable
    outside it has none: it was accepted as a quantity, every image rendered and written, and the run
    then failed on its units, leaving a half-written folder. Now it is refused before anything is
    written, naming the file and the variable; the variables it may name are the schema's."""
    ds = open_results(results_file).ds.copy()
    ds["my_index"] = ds["absorbed_par_umol_m2_s"] / 1000.0
    res = open_results(ds)
    out = tmp_path / "d"
    spec = DatasetSpec(cameras=[CAM], quantities=("my_index",), settings=RenderSettings(spp=1, colour="mono"))
    with pytest.raises(InputError, match="my_index") as err:
        make_dataset(res, out, spec)
    assert "schema" in str(err.value) and "my_index" not in err.value.expected
    assert not out.exists() or not any(out.iterdir())
    with pytest.raises(InputError, match="absorbed_par_umol_m2_s"):  # listed among what it may name
        res.variable("my_index")


def test_a_camera_file_that_cannot_be_read_as_text_is_refused_by_name(tmp_path):
    """A --cameras file in another encoding (or a folder) ended in a UnicodeDecodeError traceback
    (a bare "Is a directory"): each is an InputError naming the file and what was expected."""
    p = tmp_path / "cams.json"
    p.write_bytes(b"\xff\xfe[\x00{\x00")  # UTF-16, as some editors save JSON
    for path in (p, tmp_path):
        with pytest.raises(InputError) as err:
            load_cameras(path)
        assert str(err.value).startswith(str(path)) and "camera objects" in err.value.expected
    args = ["render-dataset", str(tmp_path / "r.nc"), "-o", str(tmp_path / "o"), "--cameras", str(p)]
    result = CliRunner().invoke(app, args)
    assert result.exit_code != 0 and isinstance(result.exception, SystemExit), result.exception
    assert "error:" in result.output and "cams.json" in result.output


def test_gallery_title_says_what_data_it_shows_and_when(results_file, tmp_path, monkeypatch):
    """The gallery had no title: it named no results file, not that the values are synthetic, nor
    the provenance of the weather that lit the images, and its images were named by UTC times
    ("Z") alone. Now the title says them and the site's local date and time zone, and each image
    its local time: 08:00 UTC on 2016-04-20 is 10:00 in Selhausen (CEST, UTC+2)."""
    from matplotlib.figure import Figure

    from lightfit.dataset.gallery import gallery_title

    seen = []
    monkeypatch.setattr(Figure, "savefig", lambda fig, *a, **k: seen.append(fig))
    spec = DatasetSpec(
        cameras=[CAM], times=[TIMES[0]], settings=RenderSettings(spp=1, colour="mono"), gallery_images=1, export="none"
    )
    make_dataset(results_file, tmp_path / "d", spec)
    title = seen[0]._suptitle.get_text()
    assert "results.nc" in title and "SYNTHETIC values" in title
    # the bundled 2016-04-20 series that lit the images is a reconstruction (data/weather)
    assert "RECONSTRUCTED weather (selhausen_2016-04-20_reconstructed.csv)" in title
    assert "2016-04-20" in title and "Europe/Berlin" in title
    assert "2016-04-20 10:00 local time" in seen[0].axes[0].get_title()
    # a model run's results name their forcing's provenance and file
    res = open_results(results_file)
    res.ds.attrs.pop("synthetic")
    res.ds.attrs |= {"weather_provenance": "measured", "weather_source": "/x/selhausen.csv"}
    title = gallery_title(res, {"from": "results"}, [pd.Timestamp("2016-04-20T22:30", tz="UTC")])
    assert "model output; MEASURED forcing (selhausen.csv)" in title and "results' own sun and sky" in title
    assert "2016-04-21, local time (Europe/Berlin)" in title  # 00:30 local, the next day


def test_unit_label_writes_udunits_as_the_figures_do():
    """The gallery's colour bars read "umol m-2 s-1" (the schema's UDUNITS) while every other figure
    writes µmol m⁻² s⁻¹: :func:`lightfit.figure.unit_label` turns one into the other."""
    from lightfit.figure import unit_label

    assert unit_label("umol m-2 s-1") == "µmol m⁻² s⁻¹"
    assert unit_label("mol m-2 s-1") == "mol m⁻² s⁻¹"
    assert unit_label("W m-2 sr-1") == "W m⁻² sr⁻¹"
    assert unit_label("umol mol-1") == "µmol mol⁻¹"
    assert unit_label("1") == "dimensionless" and unit_label("ppm") == "ppm"


def test_gallery_panels_name_their_quantity_in_words(mono_dataset, monkeypatch):
    """A label panel was titled by its variable name (``absorbed_par``), and the limitation panel did
    not say which of its two colours is which process. Now each names its quantity as the results
    schema does, and a class map its codes."""
    from matplotlib.figure import Figure

    from lightfit.dataset.gallery import gallery

    out, meta = mono_dataset
    seen = []
    monkeypatch.setattr(Figure, "savefig", lambda fig, *a, **k: seen.append(fig))
    gallery(
        out, meta["images"][:1], ["absorbed_par", "limitation"], {"absorbed_par": "umol m-2 s-1", "limitation": "1"}
    )
    titles = [a.get_title() for a in seen[0].axes]
    assert "PAR absorbed by the segment" in titles and "absorbed_par" not in titles
    assert "limiting process of leaf photosynthesis\n0 Rubisco limited, 1 electron transport limited" in titles


def test_gallery_class_map_has_one_colour_per_class_named_on_its_bar(mono_dataset, monkeypatch):
    """The limitation panel (codes 0 Rubisco limited, 1 electron transport limited) was drawn on a
    continuous viridis scale whose colour bar ran 0.0 … 1.0 with fractional ticks and read
    "dimensionless". Now each class has one colour (red Rubisco limited, blue electron-transport
    limited, as on the margin's scale) and the bar's two ticks name the classes, as the schema's
    flag meanings do."""
    from matplotlib.colors import to_rgba
    from matplotlib.figure import Figure

    from lightfit.dataset.gallery import gallery

    out, meta = mono_dataset
    entry = meta["images"][0]
    lim = _labels(out, entry)["limitation"]
    seen = []
    monkeypatch.setattr(Figure, "savefig", lambda fig, *a, **k: seen.append(fig))
    gallery(out, [entry], ["absorbed_par", "limitation"], {"absorbed_par": "umol m-2 s-1", "limitation": "1"})
    (ax,) = [a for a in seen[0].axes if a.get_title().startswith("limiting process")]
    im = ax.images[0]
    bar = im.colorbar
    assert list(bar.get_ticks()) == [0, 1]
    names = [" ".join(t.get_text().split()) for t in bar.ax.get_yticklabels()]
    assert names == ["Rubisco limited", "electron transport limited"]
    assert bar.ax.get_ylabel() == ""  # a class has no unit ("dimensionless" said nothing)
    # exactly two colours, one per class: red for code 0, blue for code 1
    rgba = im.to_rgba(im.get_array())
    drawn = {tuple(c) for c in rgba[lim >= 0].reshape(-1, 4)}
    assert drawn == {tuple(to_rgba(im.cmap(0))), tuple(to_rgba(im.cmap(1)))}
    r0, _, b0, _ = im.cmap(0)
    r1, _, b1, _ = im.cmap(1)
    assert r0 > b0 and b1 > r1
