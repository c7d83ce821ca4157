"""A series' own diffuse radiation (``diffuse_w_m2``) splits its light: checked against pvlib's
clear-sky model (the bundled reconstruction), the energy balance, and bad input."""

from pathlib import Path

import numpy as np
import pandas as pd
import pvlib
import pytest

from lightfit.errors import InputError
from lightfit.weather import add_solar, read_tereno, read_weather, resample
from lightfit.weather.bundled import DATA_DIR, bundled_path
from lightfit.weather.reconstruct import Anchor
from lightfit.weather.site import SELHAUSEN
from lightfit.weather.solar import par_direct_diffuse

RECON = bundled_path("2016-04-20")
FIXTURE = DATA_DIR / "fixtures" / "tereno_SE_EC_001_fixture.csv"


def _day(diffuse_share: float = 0.2, **edits) -> pd.DataFrame:
    """The bundled day with its diffuse column replaced by ``diffuse_share`` × global radiation,
    then ``edits`` (column → function of the frame)."""
    df = read_weather(RECON).copy()
    for col, f in edits.items():
        if col != "diffuse_w_m2":
            df[col] = f(df)
    df["diffuse_w_m2"] = edits.get("diffuse_w_m2", lambda d: diffuse_share * d["ghi_w_m2"])(df)
    return df


def test_reconstruction_is_split_as_its_clear_sky_model_splits_it():
    """The bundled day's DNI and DHI are pvlib's Ineichen–Perez clear sky (computed here, not read
    from the file) scaled by the file's one factor; its PAR-weighted diffuse share is ≈ 0.26, where
    Erbs on the same global radiation gives ≈ 0.40 (docs/weather.md)."""
    df = add_solar(read_weather(RECON))
    assert df.attrs["split_model"] == "diffuse"
    k = Anchor().par_umol_m2_s / (0.5 * 4.57 * float(_clear(pd.DatetimeIndex([Anchor().time_utc]))["ghi"].iloc[0]))
    clear = _clear(df.index)
    day = (df["sun_elevation_deg"] > 2.0).to_numpy()
    for ours, theirs in (("dhi_w_m2", "dhi"), ("dni_w_m2", "dni")):
        np.testing.assert_allclose(df[ours].to_numpy()[day], k * clear[theirs].to_numpy()[day], rtol=1e-6, atol=1e-4)

    def share(d):
        _, dhi_par = par_direct_diffuse(d.dni_w_m2, d.dhi_w_m2, d.sun_elevation_deg, d.par_umol_m2_s)
        return dhi_par.sum() / d["par_umol_m2_s"].sum()

    erbs = add_solar(read_weather(RECON), split_model="erbs")
    assert 0.24 < share(df) < 0.27 and 0.38 < share(erbs) < 0.41
    assert any(q["kind"] == "split" and "not used" in q["detail"] for q in erbs.attrs["qc"])
    # without a diffuse column the split is named too, with why it is that one (a review: a run on the
    # CPlantBox day printed no split at all)
    bare = read_weather(RECON).drop(columns=["diffuse_w_m2"])
    for given, why in ((None, "the default"), ("boland", "as asked")):
        out = add_solar(bare.copy(), split_model=given)
        # resampled (as every model run's window is), the series keeps its split and says why as before
        # (a review: the resample passed the split on and the note said "as asked" of the default)
        for series in (out, resample(out, "30min", "sample")):
            (note,) = (q["detail"] for q in series.attrs["qc"] if q["kind"] == "split")
            said = f"DNI and DHI split from global radiation by {out.attrs['split_model']} ({why}; the series has no"
            assert note == said + " diffuse radiation)", note


def _clear(times: pd.DatetimeIndex) -> pd.DataFrame:
    loc = pvlib.location.Location(SELHAUSEN.latitude_deg, SELHAUSEN.longitude_deg, altitude=SELHAUSEN.altitude_m)
    return loc.get_clearsky(times, model="ineichen")


def test_split_closes_the_energy_balance_and_cuts_what_no_sun_gives():
    """GHI = DNI sin β + DHI at every step; diffuse a little above global (two instruments) is cut
    to it; near the horizon the beam is cut as pvlib.irradiance.dni cuts it (none beyond 88°
    zenith, ≤ 1.1 × clear sky beyond 80°), the rest counted diffuse, both reported; at night all
    light is diffuse."""
    df = _day(0.2)
    noon = pd.Timestamp("2016-04-20 12:00", tz="UTC")
    below_88 = pd.Timestamp("2016-04-20 04:40", tz="UTC")  # sun 1.2°: zenith 88.8°
    low = pd.Timestamp("2016-04-20 04:50", tz="UTC")  # sun 2.6°
    df.loc[noon, "diffuse_w_m2"] = 1.05 * df.loc[noon, "ghi_w_m2"]
    df.loc[[below_88, low], "ghi_w_m2"] = [20.0, 50.0]  # two instruments' mismatch at dawn
    df.loc[[below_88, low], "diffuse_w_m2"] = 0.0
    out = add_solar(df)
    sin_b = np.sin(np.radians(out["sun_elevation_deg"].clip(lower=0.0)))
    np.testing.assert_allclose(out["dni_w_m2"] * sin_b + out["dhi_w_m2"], out["ghi_w_m2"], rtol=1e-12, atol=1e-9)
    assert out.loc[noon, "dhi_w_m2"] == out.loc[noon, "ghi_w_m2"] and out.loc[noon, "dni_w_m2"] == 0
    assert out.loc[below_88, "dni_w_m2"] == 0 and out.loc[below_88, "dhi_w_m2"] == 20.0
    clear_dni = _clear(pd.DatetimeIndex([low]))["dni"].iloc[0]  # ≈ 10 W m⁻², where 50 / sin 2.6° = 1 100
    assert out.loc[low, "dni_w_m2"] == pytest.approx(1.1 * clear_dni, rel=0.01)
    assert 0 < out.loc[low, "dni_w_m2"] < 20
    assert (out["dhi_w_m2"] >= 0).all()
    note = next(q["detail"] for q in out.attrs["qc"] if q["kind"] == "split")
    assert "diffuse cut to its total at 1 step" in note and "beam cut near the horizon at" in note
    dark = (out["sun_elevation_deg"] <= 0).to_numpy()
    assert (out["dni_w_m2"].to_numpy()[dark] == 0).all()
    np.testing.assert_array_equal(out["dhi_w_m2"].to_numpy()[dark], out["ghi_w_m2"].to_numpy()[dark])


def test_a_negative_global_radiation_built_in_code_is_no_light():
    """The readers clamp a dark offset to 0; a series built in code may keep a negative total, which the
    split now takes as 0 (no beam, no sky), as a negative PAR is: the closure clipped DHI alone before."""
    df = _day(0.2)
    noon = pd.Timestamp("2016-04-20 11:00", tz="UTC")
    df.loc[noon, "ghi_w_m2"] = -5.0
    out = add_solar(df)
    assert out.loc[noon, "dni_w_m2"] == 0.0 and out.loc[noon, "dhi_w_m2"] == 0.0


def test_a_diffuse_reading_of_zero_gives_no_negative_sky_and_the_model_takes_it():
    """A lit step whose diffuse reads 0 (a dark offset the reader clamps) and whose beam is not cut:
    the closure DHI = GHI − DNI sin β left ≈ −1e-13 W m⁻² on about a fifth of such steps, which the
    scenario's weather check then refused as a negative sky (a review). Now exactly ≥ 0, closure kept."""
    from lightfit.model.scenario import Scenario

    df = _day(0.2)
    zero = (df.index.hour >= 7) & (df.index.hour < 16)  # sun above ≈ 20°: no beam cut
    df.loc[zero, "diffuse_w_m2"] = 0.0
    out = add_solar(df)
    lit = zero & (out["sun_elevation_deg"] > 10).to_numpy()
    assert lit.sum() > 40
    assert (out["dhi_w_m2"] >= 0).all() and (out["dhi_w_m2"].to_numpy()[lit] < 1e-9).all()
    sin_b = np.sin(np.radians(out["sun_elevation_deg"].clip(lower=0.0)))
    np.testing.assert_allclose(out["dni_w_m2"] * sin_b + out["dhi_w_m2"], out["ghi_w_m2"], rtol=1e-12, atol=1e-9)
    Scenario(weather=out)


@pytest.mark.parametrize(
    "edit, words",
    [
        (lambda d: 3.0 * d["ghi_w_m2"], "steps have more diffuse than global radiation"),  # swapped columns
        (lambda d: 0.2e-3 * d["ghi_w_m2"], "the unit is wrong"),  # kW m⁻² under a W m⁻² header
    ],
    ids=["above global", "kW"],
)
def test_impossible_diffuse_radiation_is_refused_naming_the_column(edit, words):
    with pytest.raises(InputError, match="diffuse_w_m2") as e:
        add_solar(_day(diffuse_w_m2=edit))
    assert words in str(e.value)


def test_asking_for_the_diffuse_split_without_the_column_is_refused():
    with pytest.raises(InputError, match=r"diffuse_w_m2.*erbs or boland"):
        add_solar(read_weather(RECON).drop(columns="diffuse_w_m2"), split_model="diffuse")
    with pytest.raises(InputError, match="erbs or boland or diffuse"):
        add_solar(read_weather(RECON), split_model="perez")


def test_resampling_keeps_the_diffuse_split():
    """The 30-minute means split their own mean diffuse radiation (sun angles recomputed)."""
    out = resample(add_solar(_day(0.3)), "30min", "mean")
    assert out.attrs["split_model"] == "diffuse"
    lit = (out["sun_elevation_deg"] > 10).to_numpy()  # below, the beam may be cut (zenith > 80°)
    np.testing.assert_allclose((out["dhi_w_m2"] / out["ghi_w_m2"]).to_numpy()[lit], 0.3, rtol=1e-9)


def _tereno_with_diffuse(tmp_path: Path, factor: float, blank=()) -> Path:
    """The TERENO fixture with a RadiationDiffuse column of ``factor`` × its global radiation,
    empty in the data rows ``blank``."""
    lines = FIXTURE.read_text(encoding="utf-8").splitlines()
    hdr = next(i for i, ln in enumerate(lines) if ln.startswith("Timestamp"))
    ghi = lines[hdr].split(",").index("RadiationGlobal_Avg10min [W*m-2]")
    rows = [lines[hdr] + ",RadiationDiffuse_Avg10min [W*m-2]"]
    for i, ln in enumerate(lines[hdr + 1 :]):
        cell = ln.split(",")[ghi]
        rows.append(ln + "," + (f"{factor * float(cell):.4f}" if cell.strip() and i not in blank else ""))
    p = tmp_path / "with_diffuse.csv"
    p.write_text("\n".join(lines[:hdr] + rows) + "\n", encoding="utf-8")
    return p


def test_tereno_diffuse_column_is_read_and_used(tmp_path):
    df = add_solar(read_tereno(_tereno_with_diffuse(tmp_path, 0.25)))
    assert df.attrs["split_model"] == "diffuse"
    lit = (df["sun_elevation_deg"] > 10).to_numpy()
    np.testing.assert_allclose((df["dhi_w_m2"] / df["ghi_w_m2"]).to_numpy()[lit], 0.25, rtol=1e-3)
    with pytest.raises(InputError, match=r"RadiationDiffuse_Avg10min \[W\*m-2\]"):
        add_solar(read_tereno(_tereno_with_diffuse(tmp_path, 1.35)))  # inside its bounds, above global


def test_a_dark_days_diffuse_in_kw_is_refused_too():
    """A dim overcast day never reaches 50 W m⁻²: the share over the whole lit day still catches
    kW m⁻² (an overcast sky is all diffuse; in kW it would read as beam)."""
    dim = lambda d: 0.05 * d["ghi_w_m2"]  # noqa: E731  peak ≈ 36 W m⁻²
    with pytest.raises(InputError, match="the unit is wrong"):
        add_solar(
            _day(
                1.0,
                ghi_w_m2=dim,
                par_umol_m2_s=lambda d: 2.285 * d["ghi_w_m2"],
                diffuse_w_m2=lambda d: 1e-3 * d["ghi_w_m2"],
            )
        )
    ok = add_solar(_day(1.0, ghi_w_m2=dim, par_umol_m2_s=lambda d: 2.285 * d["ghi_w_m2"]))
    assert (ok["dni_w_m2"] == 0).all()


def test_missing_values_through_the_api_are_refused_naming_the_column():
    df = _day(0.2)
    df.loc["2016-04-20 11:40", "diffuse_w_m2"] = np.nan
    with pytest.raises(InputError, match=r"diffuse_w_m2.*lack its diffuse part"):
        add_solar(df)


def test_estimated_global_radiation_is_called_so():
    """With PAR alone the diffuse check compares with PAR / 2.285 and says it is an estimate."""
    df = _day(1.0).drop(columns="ghi_w_m2")
    df["diffuse_w_m2"] = 1.4 * df["par_umol_m2_s"] / 2.285
    with pytest.raises(InputError, match=r"global radiation \(estimated from PAR\)"):
        add_solar(df)


def test_a_diffuse_column_with_a_long_gap_is_dropped_not_the_series(tmp_path):
    """The column is optional: a gap that cannot be interpolated drops it (recorded) and the
    split falls back to Erbs; before, the whole file was refused, even for --split erbs."""
    path = _tereno_with_diffuse(tmp_path, 0.25, blank=range(40, 60))
    df = add_solar(read_tereno(path))
    assert "diffuse_w_m2" not in df.columns and df.attrs["split_model"] == "erbs"
    assert any(q["kind"] == "dropped" and "RadiationDiffuse" in q["detail"] for q in df.attrs["qc"])


def test_the_split_a_csv_was_written_with_is_kept(tmp_path):
    """`weather show --split erbs --csv` writes Erbs' DNI/DHI beside the diffuse column; reading
    it back keeps Erbs (its `split_model` line) instead of splitting by the column again."""
    from typer.testing import CliRunner

    from lightfit.cli import app

    out = tmp_path / "erbs.csv"
    r = CliRunner().invoke(app, ["weather", "show", "2016-04-20", "--split", "erbs", "--csv", str(out)])
    assert r.exit_code == 0, r.output
    assert "# split_model: erbs" in out.read_text()
    back = add_solar(read_weather(out))
    assert back.attrs["split_model"] == "erbs"
    assert not any(q["kind"] == "recomputed" for q in back.attrs["qc"])
    assert add_solar(read_weather(out), split_model="diffuse").attrs["split_model"] == "diffuse"


def test_measured_diffuse_par_is_the_canopys_diffuse_par():
    """With a diffuse PAR column (a BF5's) the light model's diffuse PAR is that column (at steps
    the horizon cut does not touch), whatever the global radiation's split would have been; it
    goes through global radiation's diffuse fraction by the inverse of Spitters et al. (1986)."""
    from lightfit.model.scenario import Forcing
    from lightfit.weather.solar import global_diffuse_fraction, par_diffuse_fraction

    k = np.linspace(0.0, 1.0, 101)
    for el in (2.0, 20.0, 39.0, 60.0):
        np.testing.assert_allclose(par_diffuse_fraction(global_diffuse_fraction(k, el), el), k, atol=1e-12)
    df = _day(0.2)  # a diffuse_w_m2 column too: the PAR one wins
    df["par_diffuse_umol_m2_s"] = 0.35 * df["par_umol_m2_s"]
    out = add_solar(df)
    assert out.attrs["split_model"] == "diffuse"
    note = next(q["detail"] for q in out.attrs["qc"] if q["kind"] == "split")
    assert "diffuse PAR" in note and "diffuse_w_m2 not used" in note
    f = Forcing.of(out)
    high = (out["sun_elevation_deg"] > 10).to_numpy()
    np.testing.assert_allclose(f.dhi_par[high], out["par_diffuse_umol_m2_s"].to_numpy()[high], rtol=1e-9)
    sin_b = np.sin(np.radians(out["sun_elevation_deg"].to_numpy()))
    np.testing.assert_allclose((f.dni_par * sin_b + f.dhi_par)[high], out["par_umol_m2_s"].to_numpy()[high], rtol=1e-9)
    with pytest.raises(InputError, match="par_diffuse_umol_m2_s"):
        add_solar(df.assign(par_diffuse_umol_m2_s=3.0 * df["par_umol_m2_s"]))  # above PAR: swapped or in other units


def test_a_csv_whose_diffuse_column_is_dropped_falls_back_to_erbs(tmp_path):
    """A lightfit CSV written with the split 'diffuse' (its split_model line) whose diffuse column has
    a gap at its start: the column is dropped (recorded) and the split falls back to Erbs, where the
    file was refused as asking for a split it no longer had the column for."""
    from typer.testing import CliRunner

    from lightfit.cli import app

    out = tmp_path / "d.csv"
    assert CliRunner().invoke(app, ["weather", "show", "2016-04-20", "--csv", str(out)]).exit_code == 0
    lines = out.read_text().splitlines()
    head = next(i for i, ln in enumerate(lines) if ln.startswith("time_utc"))
    col = lines[head].split(",").index("diffuse_w_m2")
    cells = lines[head + 1].split(",")
    cells[col] = ""
    lines[head + 1] = ",".join(cells)
    out.write_text("\n".join(lines) + "\n")
    df = add_solar(read_weather(out))
    assert "diffuse_w_m2" not in df.columns and df.attrs["split_model"] == "erbs"
    assert any(q["kind"] == "dropped" for q in df.attrs["qc"])


def test_a_night_offset_or_a_missing_global_value_is_told_apart():
    """Diffuse above global at night (sensor offsets, no light to split) is not refused; a missing
    global radiation at a daylight step is named as such, not as a missing diffuse value."""
    df = _day(0.2)
    night = (df["ghi_w_m2"] == 0).to_numpy()
    df.loc[night, "diffuse_w_m2"] = 15.0  # above 1.15 × 0 + 10 W m⁻² at every night step
    assert add_solar(df).attrs["split_model"] == "diffuse"
    df = _day(0.2)
    df.loc["2016-04-20 11:40", "ghi_w_m2"] = np.nan
    with pytest.raises(InputError, match=r"1 missing value\(s\) \(first at 2016-04-20 11:40") as e:
        add_solar(df)
    assert e.value.column == "ghi_w_m2"


def test_model_commands_take_the_split(tmp_path):
    """`replicate --split erbs` runs the bundled day split by Erbs instead of its own diffuse column:
    results.nc records the split, and the sky's share differs (Erbs puts more light in the sky)."""
    import xarray as xr
    from typer.testing import CliRunner

    from lightfit.cli import app

    runs = {}
    for split in (None, "erbs"):
        out = tmp_path / str(split)
        args = ["replicate", "--quick", "--start-time", "11:00", "--hours", "1", "--out", str(out)]
        r = CliRunner().invoke(app, args + ([] if split is None else ["--split", split]))
        assert r.exit_code == 0, r.output
        with xr.open_dataset(out / "results.nc", engine="h5netcdf") as ds:
            runs[split] = (ds.attrs["weather_split_model"], ds["dhi_w_m2"].values.copy(), ds["dni_w_m2"].values.copy())
    assert runs[None][0] == "diffuse" and runs["erbs"][0] == "erbs"
    assert (runs["erbs"][1] > 1.2 * runs[None][1]).all() and (runs["erbs"][2] < runs[None][2]).all()


@pytest.mark.parametrize("model", ["erbs", "boland"])
def test_a_negative_global_radiation_is_no_light_for_erbs_and_boland_too(model):
    """A series built in code with a dark offset left in its global radiation (−5 W m⁻² at 11:00 with
    the sun 50° up, −2 at 01:00 in the night) and no diffuse column: split by Erbs or Boland, those
    steps have no light, DNI = DHI = 0, as the split by a diffuse column gives (the test above) and as
    a negative PAR is; a negative irradiance is no physical sky. A mutation audit found it: Erbs and
    Boland gave a beam of −5 / sin 50° = −6.5 W m⁻² at noon and a sky of −2 W m⁻² at night, and the
    scenario then refused the series as a negative DNI or DHI."""
    from lightfit.model.scenario import Scenario

    df = read_weather(RECON).drop(columns="diffuse_w_m2")
    steps = pd.DatetimeIndex(["2016-04-20 11:00", "2016-04-20 01:00"], tz="UTC")
    df.loc[steps, "ghi_w_m2"] = [-5.0, -2.0]
    out = add_solar(df, split_model=model)
    assert out.attrs["split_model"] == model
    np.testing.assert_array_equal(out.loc[steps, ["dni_w_m2", "dhi_w_m2"]].to_numpy(), 0.0)
    assert (out["dni_w_m2"] >= 0).all() and (out["dhi_w_m2"] >= 0).all()
    Scenario(weather=out)


def test_the_measured_split_worked_by_hand_with_its_counts():
    """split_from_diffuse on three steps of 20 April 2016 worked by hand: at 11:30 (sun 50.9°) 600 W m⁻²
    with 150 diffuse leave a beam of 450 / sin β along the sun (below the 775 W m⁻² clear-sky beam, the
    zenith below 80°: not cut); at 12:00 a diffuse reading 5 % above global radiation is cut to it, all
    diffuse and no beam; at 04:40 (sun 1.2°: zenith 88.8°, beyond the 88° where pvlib.irradiance.dni
    allows no beam) 20 W m⁻² with no diffuse reading give no beam, all 20 diffuse. The counts record
    one step of each cut (a mutation audit: a beam_cut that counted every lit step passed, as the tests
    read only the note's words)."""
    from lightfit.weather.solar import split_from_diffuse

    t = pd.DatetimeIndex(["2016-04-20 11:30", "2016-04-20 12:00", "2016-04-20 04:40"], tz="UTC")
    el = pd.Series([50.896809, 50.522423, 1.217998], index=t)  # SPA's apparent sun at Selhausen
    ghi = pd.Series([600.0, 600.0, 20.0], index=t)
    diffuse = pd.Series([150.0, 630.0, 0.0], index=t)
    split, counts = split_from_diffuse(ghi, diffuse, el, check=False)
    beam = 450.0 / np.sin(np.radians(50.896809))
    np.testing.assert_allclose(split["dni_w_m2"], [beam, 0.0, 0.0], rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(split["dhi_w_m2"], [150.0, 600.0, 20.0], rtol=1e-12)
    assert counts == {"diffuse_above_global": 1, "beam_cut": 1}
