"""The `lightfit` command line, end to end in-process."""

import pandas as pd
from typer.testing import CliRunner

from lightfit.cli import app
from lightfit.weather import read_weather
from lightfit.weather.bundled import DATA_DIR

runner = CliRunner()
FIXTURE = DATA_DIR / "fixtures" / "tereno_SE_EC_001_fixture.csv"


def test_info_names_variant_and_llvm():
    r = runner.invoke(app, ["info"])
    assert r.exit_code == 0, r.output
    assert "mitsuba variant" in r.output and "_ad_mono" in r.output
    assert "libLLVM" in r.output


def test_weather_show_file_with_plot_and_csv(tmp_path):
    png, csv = tmp_path / "w.png", tmp_path / "w.csv"
    r = runner.invoke(
        app, ["weather", "show", str(FIXTURE), "--resample", "30min", "--plot", str(png), "--csv", str(csv)]
    )
    assert r.exit_code == 0, r.output
    assert "clamped" in r.output  # night PAR offsets are reported, not hidden
    assert png.stat().st_size > 10_000
    back = read_weather(csv)
    assert (back.index[1:] - back.index[:-1] == pd.Timedelta("30min")).all()


def test_weather_show_bad_input_exits_2_with_message(tmp_path):
    bad = tmp_path / "bad.csv"
    bad.write_text(FIXTURE.read_text(encoding="utf-8").replace("[mbar]", "[psi]"), encoding="utf-8")
    r = runner.invoke(app, ["weather", "show", str(bad)])
    assert r.exit_code == 2
    assert "bad.csv" in r.output and "psi" in r.output
    r = runner.invoke(app, ["weather", "show", "selhausen-cplantbox-day"])
    assert r.exit_code == 2 and "date" in r.output


def test_replicate_writes_labelled_forcing(tmp_path):
    r = runner.invoke(app, ["replicate", "--quick", "--out", str(tmp_path)])
    assert r.exit_code == 0, r.output
    assert "RECONSTRUCTED" in r.output
    f = read_weather(tmp_path / "forcing.csv")
    assert len(f) == 29 and f.attrs["provenance"] == "reconstructed"
    assert (tmp_path / "forcing.png").stat().st_size > 10_000


def test_replicate_with_a_tereno_export(tmp_path):
    r = runner.invoke(app, ["replicate", "--quick", "--out", str(tmp_path), "--weather", str(FIXTURE)])
    assert r.exit_code == 0, r.output
    f = read_weather(tmp_path / "forcing.csv")
    assert len(f) == 29 and f.attrs["provenance"] == "measured"


def test_field_command_reports_exports_and_previews(tmp_path, monkeypatch):
    monkeypatch.setenv("LIGHTFIT_CACHE", str(tmp_path / "cache"))
    ply, png = tmp_path / "f.ply", tmp_path / "f.png"
    r = runner.invoke(
        app,
        [
            "field",
            "--n-plants",
            "4",
            "--buffer-rows",
            "1",
            "--tiles",
            "2",
            "--export",
            str(ply),
            "--preview",
            str(png),
            "--segments",
            str(tmp_path / "seg.csv"),
        ],
    )
    assert r.exit_code == 0, r.output
    assert "triangles" in r.output and "16 (4 / 12)" in r.output
    assert ply.stat().st_size > 0 and png.stat().st_size > 10_000
    seg = pd.read_csv(tmp_path / "seg.csv")
    assert seg["measured"].sum() > 0 and set(seg["organ_type"]) == {"leaf", "stem"}
    r = runner.invoke(app, ["field", "--row-spacing", "-1"])
    assert r.exit_code == 2 and "row_spacing_m" in r.output
    r = runner.invoke(app, ["field", "--n-plants", "4", "--season-start", "2016-05-01"])
    assert r.exit_code == 2 and "not after season_start" in r.output
