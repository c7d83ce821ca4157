"""The result caches' keys, field by field: every setting that changes a cached result changes its key,
and a setting that cannot change it leaves the key alone (so the cache is shared). Keys only: nothing
is rendered."""

import dataclasses

import pandas as pd
import pytest

from lightfit import replication as rep
from lightfit.distributed.run import FieldRun, task_key, task_specs
from lightfit.light.scene import Optics
from lightfit.model.coupled import CoupledModel
from lightfit.model.emulator import render_key
from lightfit.model.scenario import Scenario
from lightfit.plant import Field, GrowthConfig

FIELD = Field(n_plants=4, seed=1)  # periodic: the projection's settings enter the key
FINITE = Field(n_plants=4, seed=1, boundary="finite", buffer_rows=1)


@pytest.fixture(scope="module")
def weather():
    return rep.forcing().iloc[[1, 5, 14]]  # 05:30 local (night), 07:30 (low sun), 12:00


def scenario(weather, **kw):
    return Scenario(weather=weather, **({"field": FIELD, "samples": 8, "bounces": 2} | kw))


def _sunnier(w):
    w = w.copy()
    w.iloc[2, w.columns.get_loc("sun_elevation_deg")] += 0.5
    return w


def _later(w):
    w = w.copy()
    w.index = w.index + pd.Timedelta("1min")
    return w


def _twilight_lit(w):
    """The night step (05:30 local, sun −17°) moved into civil twilight with diffuse light: rendered now."""
    w = w.copy()
    w.iloc[0, w.columns.get_loc("sun_elevation_deg")] = -5.0
    w.iloc[0, w.columns.get_loc("dhi_w_m2")] = 5.0
    return w


#: Settings that change a render, as Scenario keyword arguments (or a weather edit).
RENDER_CHANGES = {
    "samples": {"samples": 16},
    "bounces": {"bounces": 3},
    "seed": {"seed": 1},
    "target_rse": {"samples": 32, "target_rse": 0.1},
    "direct": {"direct": "paths"},
    "direct_rays_per_m2": {"direct_rays_per_m2": (1e6, 2e6)},
    "ceptometer_height_m": {"ceptometer_height_m": 0.2},
    "sky": {"sky": "overcast"},
    "tile": {"n_tiles": 2, "tile": 0},
    "optics.specular": {"optics": Optics(specular=0.4)},
    "optics.roughness": {"optics": Optics(roughness=0.4)},
    "optics.subsurface": {"optics": Optics(subsurface=0.4)},
    "optics.base_color": {"optics": Optics(base_color=0.1)},
    "optics.soil_albedo": {"optics": Optics(soil_albedo=0.2)},
    "field.n_plants": {"field": dataclasses.replace(FIELD, n_plants=9)},
    "field.row_spacing_m": {"field": dataclasses.replace(FIELD, row_spacing_m=0.15)},
    "field.plant_spacing_m": {"field": dataclasses.replace(FIELD, plant_spacing_m=0.04)},
    "field.row_direction_deg": {"field": dataclasses.replace(FIELD, row_direction_deg=0.0)},
    "field.seed": {"field": dataclasses.replace(FIELD, seed=2)},
    "field.sheaths": {"field": dataclasses.replace(FIELD, sheaths="rods")},
    "field.headings": {"field": dataclasses.replace(FIELD, headings="aligned")},
    "field.plants_per_row": {"field": dataclasses.replace(FIELD, plants_per_row=4)},
    "field.boundary": {"field": FINITE},
    "field.growth.target_date": {"field": dataclasses.replace(FIELD, growth=GrowthConfig(target_date="2016-04-25"))},
    "weather: a sun position": {"weather": _sunnier},
    "weather: the times": {"weather": _later},
    "weather: the daytime rule's twilight step": {"weather": _twilight_lit},
}

#: Settings that cannot change a render (photosynthesis, observables, the weather's drivers of
#: photosynthesis): the renders of one are the other's.
RENDER_SAME = {
    "photosynthesis": {"photosynthesis": "cplantbox"},
    "growth_temperature_c": {"growth_temperature_c": 12.0},
    "photosynthesis_overrides": {"photosynthesis_overrides": {"a1": 4.5}},
    "vcmax_profile": {"vcmax_profile": "uniform"},
    "par_kind": {"par_kind": "incident"},
    "an_per": {"an_per": "leaf"},
    "soil_respiration_umol_m2_s": {"soil_respiration_umol_m2_s": 1.0},
    "soil_respiration_q10": {"soil_respiration_q10": 3.0},
    "weather: air temperature": {"weather": lambda w: w.assign(tair_c=w["tair_c"] + 1)},
    "weather: DNI at a lit step": {"weather": lambda w: w.assign(dni_w_m2=w["dni_w_m2"] * 1.1)},
}


def _model(weather, change: dict) -> CoupledModel:
    kw = dict(change)
    if "weather" in kw:
        weather = kw.pop("weather")(weather)
    return CoupledModel(scenario(weather, **kw))


@pytest.fixture(scope="module")
def base_key(weather):
    return render_key(_model(weather, {}))


@pytest.mark.parametrize("name", RENDER_CHANGES)
def test_every_setting_that_changes_a_render_changes_the_render_key(weather, base_key, name):
    """The design cache (renders and fitted emulators) and the kept steps are keyed by render_key:
    another value of any of these settings renders other numbers, so it must name another entry."""
    key = render_key(_model(weather, RENDER_CHANGES[name]))
    assert key != base_key, name


@pytest.mark.parametrize("name", RENDER_SAME)
def test_settings_that_cannot_change_a_render_leave_the_render_key_alone(weather, base_key, name):
    """Renders are per unit DNI and DHI and know no photosynthesis: a calibration of another
    photosynthesis set reuses the design, as the design cache's docs promise."""
    assert render_key(_model(weather, RENDER_SAME[name])) == base_key, name


def test_adaptive_allocation_point_changes_the_render_key(weather):
    kw = {"samples": 32, "target_rse": 0.1}
    a = render_key(_model(weather, kw))
    b = render_key(_model(weather, kw | {"allocate_at": ((0.5, 0.5, 0.5), (40.0, 180.0), 1000.0, 200.0)}))
    assert a != b


@pytest.mark.parametrize("name", [*(n for n in RENDER_CHANGES if n != "tile"), *RENDER_SAME, "theta", "tiles"])
def test_every_setting_changes_a_field_run_task_key(weather, name):
    """field-run's kept tasks hold photosynthesis as well as light: every setting, and θ, names
    another task (the settings that leave the render key alone included)."""

    def first_key(change, **run):
        kw = dict(change)
        w = kw.pop("weather")(weather) if "weather" in kw else weather
        return task_key(task_specs(FieldRun(scenario(w, **kw), **run))[0])

    base = first_key({})
    if name in ("theta", "tiles"):  # FieldRun's own: θ, and how the field is split
        assert first_key({}, **{"theta": {"theta": {"vcmax_scale": 0.8}}, "tiles": {"tiles": 2}}[name]) != base
    else:
        assert first_key({**RENDER_CHANGES, **RENDER_SAME}[name]) != base


def test_every_growth_setting_and_the_seed_change_the_plant_cache_key(tmp_path):
    """The plant cache's key: the parameter file's contents (not its name), both dates, the roots and
    the seed each name another plant; the same dates written otherwise name the same one."""
    from lightfit.plant.cache import cache_key

    base = GrowthConfig()
    edited = tmp_path / "wheat.xml"
    edited.write_bytes(base.path.read_bytes().replace(b"</plant>", b"<!-- edited --></plant>", 1))
    assert edited.read_bytes() != base.path.read_bytes()
    same_name = tmp_path / "same" / base.path.name
    same_name.parent.mkdir()
    same_name.write_bytes(base.path.read_bytes())
    key = cache_key(base, 7)
    changed = {
        "seed": cache_key(base, 8),
        "parameter file's contents": cache_key(GrowthConfig(parameter_file=str(edited)), 7),
        "season_start": cache_key(dataclasses.replace(base, season_start="2016-03-06"), 7),
        "target_date": cache_key(dataclasses.replace(base, target_date="2016-04-21"), 7),
        "include_roots": cache_key(dataclasses.replace(base, include_roots=True), 7),
    }
    assert all(k != key for k in changed.values()), [n for n, k in changed.items() if k == key]
    assert len(set(changed.values())) == len(changed)
    assert cache_key(GrowthConfig(parameter_file=str(same_name)), 7) == key  # the contents, not the path
    assert cache_key(GrowthConfig(target_date="20160420", season_start="2016-03-05"), 7) == key


def _unbalance_header(path, member=""):
    """Damage a .npy/.npz written uncompressed as a flipped bit can: the closing brace of the header of
    array ``member`` (of the first array where ``""``) becomes a space. numpy then re-reads the header
    through tokenize, which raises TokenError. (The array must be over 4 KiB: zipfile reads a smaller
    member whole and finds its CRC wrong first.)"""
    b = bytearray(path.read_bytes())
    i = b.index(b"}", b.index(member.encode()))
    b[i : i + 1] = b" "
    path.write_bytes(bytes(b))


def test_a_render_file_with_a_damaged_array_header_is_rendered_again(tmp_path):
    """The design cache's render files: a damaged header is a miss (rendered again), not a tokenize
    traceback on every rerun."""
    import numpy as np

    from lightfit.model.emulator import _stored_render

    path = tmp_path / "render.npz"
    np.savez(path, values=np.ones((1, 4, 300)), se=np.zeros((1, 4, 300)), seconds=1.0, leaf=np.ones(3), key="k")
    assert _stored_render(path) is not None
    _unbalance_header(path, "values.npy")
    assert _stored_render(path) is None


def test_an_emulator_file_with_a_damaged_array_header_is_rebuilt(tmp_path):
    import numpy as np

    from lightfit.model.emulator import PartsEmulator

    path = tmp_path / "emulator.npz"
    np.savez(path, lo=np.zeros(3), hi=np.ones(3), degree=1, coef_values=np.ones((4, 1, 4, 300)))
    _unbalance_header(path, "coef_values.npy")
    said = []
    assert PartsEmulator.readable(path, said.append) is None
    assert len(said) == 1 and "TokenError" in said[0] and "rebuilding" in said[0]


def test_a_ggx_table_with_a_damaged_array_header_is_recomputed(tmp_path, monkeypatch):
    import numpy as np

    from lightfit.light import bsdf

    monkeypatch.setenv("LIGHTFIT_CACHE", str(tmp_path))
    fresh = bsdf._stored_table(256, 3)
    (path,) = (tmp_path / "tables").glob("*.npy")
    _unbalance_header(path)
    assert np.array_equal(bsdf._stored_table(256, 3), bsdf._compute_table(256, 3))
    assert np.array_equal(np.load(path), fresh)  # replaced


def test_a_single_array_under_a_cache_files_name_reads_as_unreadable(tmp_path):
    """``np.load`` of a ``.npy`` array saved under an ``.npz`` name returns the bare array, on which
    ``with`` stopped with a TypeError traceback: the caches that read their files back (calibration
    state, data-scene cameras, grown plants) take it as unreadable and start again."""
    import numpy as np

    from lightfit.dataset.render import load_camera
    from lightfit.files import UNREADABLE_NPZ, load_npz
    from lightfit.inference.calibration import _load_state
    from lightfit.plant.cache import load_or_grow

    foreign = tmp_path / "x.npz"
    with open(foreign, "wb") as f:
        np.save(f, np.arange(3))
    with pytest.raises(UNREADABLE_NPZ, match="single array"):
        load_npz(foreign)
    assert _load_state(foreign) is None
    assert load_camera(foreign, 1) is None
    config, seed = GrowthConfig(), 1
    grown, cached = load_or_grow(config, seed, directory=tmp_path / "plants")
    (entry,) = (tmp_path / "plants").glob("*.npz")
    with open(entry, "wb") as f:
        np.save(f, np.arange(3))
    again, cached = load_or_grow(config, seed, directory=tmp_path / "plants")
    assert not cached and again.equals(grown)
