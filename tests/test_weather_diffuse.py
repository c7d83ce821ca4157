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
    df["diffuse_w_m2"] = diffuse_share * df["ghi_w_m2"]
    for col, f in edits.items():
        df[col] = f(df)
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


def _clear(times: pd.DatetimeIndex) -> pd.DataFrame:
    loc = pvlib.location.Location(SELHAUSEN.latitude_deg, SELHAUSEN.longitude_deg, altitude=SELHAUSEN.altitude_m)
    return loc.get_clearsky(times, model="ineichen")


def test_split_closes_the_energy_balance_and_cuts_what_no_sun_gives():
    """GHI = DNI sin β + DHI at every step; diffuse a little above global (two instruments) is cut
    to it, and a low-sun beam above the extraterrestrial one is cut with the rest counted diffuse,
    both reported; at night all light is diffuse."""
    df = _day(0.2)
    low = df.index[(df["ghi_w_m2"] > 0).to_numpy()][0]  # the first lit step, sun near the horizon
    noon = pd.Timestamp("2016-04-20 12:00", tz="UTC")
    df.loc[noon, "diffuse_w_m2"] = 1.05 * df.loc[noon, "ghi_w_m2"]
    df.loc[low, "diffuse_w_m2"] = 0.0
    out = add_solar(df)
    sin_b = np.sin(np.radians(out["sun_elevation_deg"].clip(lower=0.0)))
    np.testing.assert_allclose(out["dni_w_m2"] * sin_b + out["dhi_w_m2"], out["ghi_w_m2"], rtol=1e-12, atol=1e-9)
    assert out.loc[noon, "dhi_w_m2"] == out.loc[noon, "ghi_w_m2"] and out.loc[noon, "dni_w_m2"] == 0
    beam_max = pvlib.irradiance.get_extra_radiation(out.index)
    assert (out["dni_w_m2"] <= beam_max + 1e-9).all() and (out["dhi_w_m2"] >= 0).all()
    note = next(q["detail"] for q in out.attrs["qc"] if q["kind"] == "split")
    assert "diffuse cut to global radiation at 1 step" in note
    if out.loc[low, "ghi_w_m2"] / np.sin(np.radians(out.loc[low, "sun_elevation_deg"])) > beam_max[low]:
        assert "extraterrestrial" in note and out.loc[low, "dni_w_m2"] == pytest.approx(beam_max[low])
    dark = (out["sun_elevation_deg"] <= 0).to_numpy()
    assert (out["dni_w_m2"].to_numpy()[dark] == 0).all()
    np.testing.assert_array_equal(out["dhi_w_m2"].to_numpy()[dark], out["ghi_w_m2"].to_numpy()[dark])


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
    lit = (out["sun_elevation_deg"] > 5).to_numpy()
    np.testing.assert_allclose((out["dhi_w_m2"] / out["ghi_w_m2"]).to_numpy()[lit], 0.3, rtol=1e-9)


def _tereno_with_diffuse(tmp_path: Path, factor: float) -> Path:
    """The TERENO fixture with a RadiationDiffuse column of ``factor`` × its global radiation."""
    lines = FIXTURE.read_text(encoding="utf-8").splitlines()
    hdr = next(i for i, ln in enumerate(lines) if ln.startswith("Timestamp"))
    ghi = lines[hdr].split(",").index("RadiationGlobal_Avg10min [W*m-2]")
    rows = [lines[hdr] + ",RadiationDiffuse_Avg10min [W*m-2]"]
    for ln in lines[hdr + 1 :]:
        cell = ln.split(",")[ghi]
        rows.append(ln + "," + (f"{factor * float(cell):.4f}" if cell.strip() else ""))
    p = tmp_path / "with_diffuse.csv"
    p.write_text("\n".join(lines[:hdr] + rows) + "\n", encoding="utf-8")
    return p


def test_tereno_diffuse_column_is_read_and_used(tmp_path):
    df = add_solar(read_tereno(_tereno_with_diffuse(tmp_path, 0.25)))
    assert df.attrs["split_model"] == "diffuse"
    lit = (df["sun_elevation_deg"] > 5).to_numpy()
    np.testing.assert_allclose((df["dhi_w_m2"] / df["ghi_w_m2"]).to_numpy()[lit], 0.25, rtol=1e-3)
    with pytest.raises(InputError, match=r"RadiationDiffuse_Avg10min \[W\*m-2\]"):
        add_solar(read_tereno(_tereno_with_diffuse(tmp_path, 1.35)))  # inside its bounds, above global
