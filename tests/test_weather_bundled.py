"""The bundled data: provenance stated, reconstruction reproducible and anchored."""

import re

import numpy as np
import pandas as pd
import pytest

from lightfit.errors import InputError
from lightfit.weather import Anchor, load, read_weather, reconstruct_day, write_lightfit_csv
from lightfit.weather.bundled import BUNDLED, DATA_DIR, bundled_path


def test_every_data_file_has_provenance_in_readme():
    readme = (DATA_DIR / "README.md").read_text(encoding="utf-8")
    files = [p for p in DATA_DIR.rglob("*") if p.is_file() and p.name != "README.md"]
    assert files
    for p in files:
        rel = p.relative_to(DATA_DIR).as_posix()
        assert f"`{rel}`" in readme, f"data/README.md does not describe {rel}"
        section = readme.split(f"`{rel}`", 1)[1].split("\n### ", 1)[0]
        assert re.search(r"\*\*(real measurement|reconstruction|synthetic)\*\*", section), f"{rel}: no provenance class"


def test_bundled_reconstruction_is_labelled_and_reproducible(tmp_path):
    df = read_weather(bundled_path("2016-04-20"))
    assert df.attrs["provenance"] == "reconstructed"
    assert "RECONSTRUCTED" in df.attrs["metadata"]["title"]
    fresh = reconstruct_day("2016-04-20")
    cols = list(df.columns)
    # The file stores 8 significant digits.
    assert np.allclose(df[cols].to_numpy(), fresh[cols].to_numpy(), rtol=1e-7, atol=1e-9)
    assert len(df) == 144 and df.index[0] == pd.Timestamp("2016-04-20", tz="UTC")


def test_the_reconstruction_script_writes_the_bundled_files_header(tmp_path):
    """experiments/reconstruct_forcing_2016_04_20.py writes the bundled file's header exactly (a line
    the writer had gained, ``time_label``, was missing from the file) and its values (the test above
    compares them to 8 significant digits, which other pvlib or numpy versions may move in the last)."""
    import subprocess
    import sys

    script = DATA_DIR.parent / "experiments" / "reconstruct_forcing_2016_04_20.py"
    out = tmp_path / "forcing.csv"
    r = subprocess.run([sys.executable, str(script), "--out", str(out)], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr

    def header(path):  # the # lines and the column names
        lines = path.read_text(encoding="utf-8").splitlines()
        n = next(i for i, line in enumerate(lines) if not line.startswith("#"))
        return lines[: n + 1]

    assert header(out) == header(bundled_path("2016-04-20"))
    fresh, bundled = read_weather(out), read_weather(bundled_path("2016-04-20"))
    assert np.allclose(fresh.to_numpy(float), bundled.to_numpy(float), rtol=1e-7, atol=1e-9)


def test_reconstruction_reproduces_the_anchor():
    a = Anchor()
    t = a.time_utc
    idx = pd.date_range("2016-04-20", periods=1440 * 60 // 6, freq="6s", tz="UTC")
    fine = reconstruct_day("2016-04-20", step="6s")
    assert fine["par_umol_m2_s"].loc[t] == pytest.approx(a.par_umol_m2_s, rel=1e-9)
    assert fine["tair_c"].loc[t] == pytest.approx(a.tair_c, abs=1e-9)
    assert len(fine) == len(idx)
    # Physically sane: no light at night, RH within 0–1, PAR peak near solar noon.
    assert (fine.loc[fine["sun_elevation_deg"] < -1, "par_umol_m2_s"] == 0).all()
    assert fine["rh"].between(0, 1).all()
    peak = fine["par_umol_m2_s"].idxmax()
    assert abs((peak - pd.Timestamp("2016-04-20 11:33", tz="UTC")).total_seconds()) < 600


def test_load_bundled_names():
    assert set(BUNDLED) == {"2016-04-20", "selhausen-cplantbox-day"}
    df = load("2016-04-20")
    assert {"dni_w_m2", "dhi_w_m2", "sun_elevation_deg", "sun_azimuth_deg"} <= set(df.columns)
    real = load("selhausen-cplantbox-day", date="2016-04-27")
    assert real.attrs["provenance"] == "measured"
    with pytest.raises(InputError, match="date"):
        load("selhausen-cplantbox-day")
    with pytest.raises(InputError, match="no bundled weather"):
        load("2016-04-21")


def test_write_requires_provenance(tmp_path):
    df = load("2016-04-20", solar=False)
    with pytest.raises(InputError, match="provenance"):
        write_lightfit_csv(df, tmp_path / "x.csv", {"title": "no provenance"})
    p = write_lightfit_csv(df, tmp_path / "x.csv", {"provenance": "synthetic"})
    back = read_weather(p)
    assert back.attrs["provenance"] == "synthetic"
    assert np.allclose(back.to_numpy(), df.to_numpy(), rtol=1e-5)
    # every column's meaning and unit in the header (a review: weather show --csv wrote none), and the
    # site a series' sun columns were computed for
    from lightfit.weather import add_solar
    from lightfit.weather.series import COLUMNS

    p = write_lightfit_csv(add_solar(df), tmp_path / "sun.csv", {"provenance": "synthetic"})
    meta = read_weather(p).attrs["metadata"]
    for c in add_solar(df).columns:
        assert f"{c}: {COLUMNS[c]}" in meta["columns"], c
    assert meta["sun_site"] == "Selhausen, 50.865 N, 6.447 E"


def test_a_lightfit_csv_is_written_whole_or_not_at_all(tmp_path, monkeypatch):
    """A write cut half-way (a kill, a full disk) leaves the file there before untouched: a run killed
    while writing its forcing.csv left a cut one beside its results."""
    from pathlib import Path

    df = load("2016-04-20")
    path = write_lightfit_csv(df, tmp_path / "forcing.csv", {"provenance": "reconstructed"})
    before = path.read_bytes()
    real = Path.write_text

    def cut(self, text, *args, **kw):
        real(self, text[: len(text) // 2], *args, **kw)
        raise OSError("No space left on device")

    monkeypatch.setattr(Path, "write_text", cut)
    with pytest.raises(OSError, match="No space"):
        write_lightfit_csv(df.iloc[:3], path, {"provenance": "reconstructed"})
    monkeypatch.undo()
    assert path.read_bytes() == before and sorted(p.name for p in tmp_path.iterdir()) == ["forcing.csv"]


def _script_module(name):
    """An experiments/ script imported as a module (its ``main`` not run)."""
    import importlib.util

    path = DATA_DIR.parent / "experiments" / f"{name}.py"
    spec = importlib.util.spec_from_file_location(f"experiment_{name}", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _head_commit():
    import subprocess

    return subprocess.run(
        ["git", "rev-parse", "--short", "HEAD"], cwd=DATA_DIR.parent, capture_output=True, text=True
    ).stdout.strip()


def test_the_tereno_fixture_script_records_how_it_was_made(tmp_path, monkeypatch):
    """experiments/make_tereno_fixture.py wrote its command nowhere and no commit (a review): its
    header now says both, and the file still reads as the bundled fixture does, row for row."""
    from lightfit.weather import read_tereno

    script = _script_module("make_tereno_fixture")
    monkeypatch.setattr(script, "OUT", tmp_path / "fixture.csv")
    text = script.main().read_text(encoding="utf-8")
    made = [line for line in text.splitlines() if line.startswith("Made by:")]
    commit = _head_commit()
    assert commit and len(made) == 1
    assert "python experiments/make_tereno_fixture.py" in made[0] and f"commit {commit} " in made[0]
    fresh, bundled = (
        read_tereno(tmp_path / "fixture.csv"),
        read_tereno(DATA_DIR / "fixtures" / "tereno_SE_EC_001_fixture.csv"),
    )
    assert fresh.attrs["provenance"] == "synthetic"
    pd.testing.assert_frame_equal(fresh, bundled)


def test_the_twin_series_records_the_command_and_commit_that_made_it(tmp_path):
    """experiments/twin_2016_04_20.py wrote the twin series (data/observations/, ``--write-data``)
    with its seeds and configuration but no command and no commit (a review): its header has both."""
    from lightfit import replication as rep
    from lightfit.inference.observations import read_observations, write_observations

    script = _script_module("twin_2016_04_20")
    obs = pd.DataFrame(
        {"plant_par_umol_m2_s": [100.0, 200.0], "plant_par_sd_umol_m2_s": [3.0, 6.0]},
        index=pd.DatetimeIndex(["2016-04-20T10:00Z", "2016-04-20T10:30Z"]),
    )
    path = write_observations(obs, tmp_path / "twin.csv", script.data_metadata(rep.ReplicationConfig.quick()))
    head = dict(
        line[2:].split(": ", 1) for line in path.read_text(encoding="utf-8").splitlines() if line.startswith("# ")
    )
    assert head["lightfit_commit"] == _head_commit() != ""
    assert head["command"] and (head["render_seed"], head["noise_seed"]) == ("101", "7")
    assert read_observations(path).attrs["provenance"] == "synthetic"
