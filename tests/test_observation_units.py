"""CO2 fluxes in mg CO2 m⁻² s⁻¹ and light at the plants in W m⁻² under the µmol columns of an
observations file: cautioned, naming the file and column, before the plants grow (from the forcing)
and against the model's own values where a run has them (replicate)."""

import numpy as np
import pandas as pd
from typer.testing import CliRunner

from lightfit import replication as rep
from lightfit.cli import app
from lightfit.inference.observations import observation_cautions, read_observations
from lightfit.weather.bundled import DATA_DIR

runner = CliRunner()
TWIN = DATA_DIR / "observations" / "twin_2016-04-20_synthetic.csv"
CHAMBER = DATA_DIR / "observations" / "chamber_2016-04-20_record.csv"
MG_PER_UMOL = 44.01e-3  # molar mass of CO2, g mol⁻¹ → mg µmol⁻¹


def scaled(tmp_path, name, column, factor, rename=None, negate=False):
    """The bundled twin with ``column`` (and its SD) × ``factor`` (negated: NEE's sign), the column
    renamed ``rename`` where given, written as ``name``."""
    lines = TWIN.read_text().splitlines()
    k = next(i for i, ln in enumerate(lines) if ln.startswith("time,"))
    head = lines[k].split(",")
    j = head.index(column)
    out = []
    for ln in lines[k + 1 :]:
        c = ln.split(",")
        for i in (j, j + 1):
            if c[i]:
                c[i] = f"{(-1 if negate and i == j else 1) * float(c[i]) * factor:.6g}"
        out.append(",".join(c))
    if rename:
        head[j], head[j + 1] = rename, rename.replace("_umol", "_sd_umol")
    f = tmp_path / name
    f.write_text("\n".join([*lines[:k], ",".join(head), *out]) + "\n")
    return f


def test_co2_flux_in_mg_is_cautioned_from_the_forcing(tmp_path):
    """The twin's canopy An (28–40 µmol m⁻² s⁻¹ at the 15 readings with forcing PAR ≥ 1000) in mg
    CO2 m⁻² s⁻¹ reads 1.23–1.75, below the reader's bound of 100, and passed unsaid; it is now named
    with the file, the column, its largest value (39.8313 × 0.04401 = 1.753) and the factor. So is
    NEE (the twin's An negated) in mg. The twin and the chamber record as they are, and a sparse
    canopy's real 5 µmol m⁻² s⁻¹, say nothing."""
    w = rep.forcing()
    assert observation_cautions(read_observations(TWIN), w) == []
    assert observation_cautions(read_observations(CHAMBER), w) == []
    mg = scaled(tmp_path, "twin_mg.csv", "canopy_an_umol_m2_s", MG_PER_UMOL)
    (said,) = observation_cautions(read_observations(mg), w)
    assert "twin_mg.csv, column 'canopy_an_umol_m2_s'" in said, said
    assert f"at most {39.8313 * MG_PER_UMOL:.3g} µmol" in said and "at the 15 reading(s)" in said, said
    assert "divide it by 0.04401" in said and "1 / 22.7" in said, said
    nee = scaled(tmp_path, "nee_mg.csv", "canopy_an_umol_m2_s", MG_PER_UMOL, "nee_umol_m2_s", negate=True)
    (said,) = observation_cautions(read_observations(nee), w)
    assert "nee_mg.csv, column 'nee_umol_m2_s'" in said and "|NEE| is at most 1.75" in said, said
    nee_umol = scaled(tmp_path, "nee.csv", "canopy_an_umol_m2_s", 1.0, "nee_umol_m2_s", negate=True)
    assert observation_cautions(read_observations(nee_umol), w) == []
    sparse = scaled(tmp_path, "sparse.csv", "canopy_an_umol_m2_s", 5.0 / 39.8313)  # at most 5 in full light
    assert observation_cautions(read_observations(sparse), w) == []


def test_unit_slips_are_judged_against_the_models_values(tmp_path):
    """Where the model's values are known, the fit factor k = Σ m·y / Σ y² over the readings in full
    light says the slip: readings that are the model's (the twin read against itself) × 0.04401 give
    k = 1 / 0.04401 = 22.72, plant PAR / 4.57 (W m⁻²) gives 4.57; the twin itself k = 1, nothing."""
    w = rep.forcing()
    obs = read_observations(TWIN)
    model = {c: obs[c] for c in ("canopy_an_umol_m2_s", "plant_par_umol_m2_s")}
    assert observation_cautions(obs, w, model) == []
    mg = read_observations(scaled(tmp_path, "twin_mg.csv", "canopy_an_umol_m2_s", MG_PER_UMOL))
    (said,) = observation_cautions(mg, w, model)
    assert f"the model's canopy_an is {1 / MG_PER_UMOL:.3g} × the readings" in said, said
    assert "twin_mg.csv, column 'canopy_an_umol_m2_s'" in said and "divide it by 0.04401" in said
    w_m2 = read_observations(scaled(tmp_path, "twin_w.csv", "plant_par_umol_m2_s", 1 / 4.57))
    (said,) = observation_cautions(w_m2, w, model)
    assert "column 'plant_par_umol_m2_s': the model's plant_par is 4.57 × the readings" in said, said
    assert "multiply it by 4.57" in said
    assert observation_cautions(w_m2, w) == []  # 0.17 × the forcing's PAR: a dense canopy's own, unsaid
    # a model indexed by naive UTC times (as results.nc keeps them) reads the same
    naive = {c: pd.Series(v.to_numpy(), index=v.index.tz_localize(None)) for c, v in model.items()}
    assert observation_cautions(mg, w, naive) == observation_cautions(mg, w, model)
    assert np.isclose(1 / MG_PER_UMOL, 22.72, atol=0.01)


def test_replicate_cautions_canopy_an_in_mg(tmp_path):
    """replicate compares the readings with its model: canopy An in mg CO2 m⁻² s⁻¹ (the twin × 0.04401)
    is named with the model's factor ≈ 22.7 under the comparison (it said only a χ² of 5e5)."""
    mg = scaled(tmp_path, "twin_mg.csv", "canopy_an_umol_m2_s", MG_PER_UMOL)
    args = ["replicate", "--quick", "--steps", "12:14", "--observations", str(mg), "--out", str(tmp_path / "o")]
    r = runner.invoke(app, args)
    text = " ".join(r.output.split())
    assert r.exit_code == 0, text
    assert "twin_mg.csv, column 'canopy_an_umol_m2_s': the model's canopy_an is" in text, text
    assert "divide it by 0.04401" in text
