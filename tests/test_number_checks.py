"""The one check of a number option (:func:`lightfit.errors.check_real`) at each place that takes one:
numpy's scalars are numbers there (copies testing ``isinstance(v, (int, float))`` refused float32),
bools, text, NaN and infinities are not."""

from dataclasses import replace

import numpy as np
import pytest

from lightfit.errors import InputError
from lightfit.light.estimator import check_dark_floor, check_target_rse
from lightfit.light.keyed_random import check_seed
from lightfit.light.leaf_optics import LeafTraits, leaf_bsdf_parameters
from lightfit.light.scene import Optics
from lightfit.model.parameters import check_theta
from lightfit.model.scenario import check_ceptometer_height, check_soil_respiration
from lightfit.plant.field import Field
from lightfit.replication import ReplicationConfig
from lightfit.weather.site import Site, Window

# (the check, a good float, a good integer): each site that takes a real number
SITES = {
    "check_theta": (lambda v: check_theta({"specular": v}), 0.5, 1),
    "ceptometer_height_m": (check_ceptometer_height, 0.5, 1),
    "soil_respiration_umol_m2_s": (lambda v: check_soil_respiration(v, 2.0), 1.5, 2),
    "soil_respiration_q10": (lambda v: check_soil_respiration(0.0, v), 1.8, 2),
    "Site.latitude_deg": (lambda v: Site(latitude_deg=v), 40.5, 40),
    "Window.hours": (lambda v: Window(hours=v), 10.5, 10),
    "LeafTraits.N": (lambda v: LeafTraits(N=v), 1.5, 2),
    "leaf specular": (lambda v: leaf_bsdf_parameters(specular=v), 0.5, 0),
    "Optics.soil_albedo": (lambda v: Optics(soil_albedo=v), 0.2, 0),
    "ReplicationConfig.soil_albedo": (lambda v: replace(ReplicationConfig.quick(), soil_albedo=v), 0.2, 0),
    "Field.row_spacing_m": (lambda v: Field(row_spacing_m=v), 0.125, 1),
    "Field.row_direction_deg": (lambda v: Field(row_direction_deg=v), 90.5, 90),
    "target_rse": (check_target_rse, 0.1, None),
    "dark_floor": (check_dark_floor, 0.01, 0),
}


@pytest.mark.parametrize("name", SITES)
def test_numpy_scalars_are_numbers_and_the_rest_is_refused(name):
    check, good, good_int = SITES[name]
    for v in (np.float32(good), np.float64(good)) + (() if good_int is None else (np.int64(good_int), good_int)):
        check(v)
    for bad in (True, str(good), float("nan"), float("inf"), -float("inf")):
        with pytest.raises(InputError):
            check(bad)


def test_soil_respiration_has_an_upper_bound():
    """R₁₀ had no upper bound: 1e308 µmol m⁻² s⁻¹ was taken and the chamber NEE came out infinite.
    Arable soils respire ≈ 0.5–10 µmol m⁻² s⁻¹ at 10 °C; 100 is taken, above it is refused, naming
    the parameter and the range."""
    assert check_soil_respiration(100, 2.0) == (100.0, 2.0)
    for bad in (100.5, 1e6, 1e308):
        with pytest.raises(InputError, match=r"soil_respiration_umol_m2_s=.*\[0, 100\]") as e:
            check_soil_respiration(bad, 2.0)
        assert e.value.parameter == "soil_respiration_umol_m2_s"


def test_seed_takes_numpy_integers_below_2_to_32():
    assert check_seed(np.int64(3)) == 3 and check_seed(np.uint32(2**32 - 1)) == 2**32 - 1
    for bad in (True, "3", 1.5, np.float32(3), -1, 2**32):
        with pytest.raises(InputError, match=r"seed=.*expected an integer in \[0, 2³²\)"):
            check_seed(bad)


def test_a_configuration_given_numpy_scalars_is_stored_as_json():
    """numpy's scalars pass the checks, and the configuration that holds them is written into every
    results file as JSON: stored as they came, json.dumps raised TypeError at the end of a run (a
    review of the change that let them through)."""
    import json
    from dataclasses import asdict

    cfg = replace(
        ReplicationConfig.quick(),
        window=Window(hours=np.float32(10.5)),
        site=Site(latitude_deg=np.float64(50.5), altitude_m=np.int64(103)),
        soil_albedo=np.float32(0.25),
        n_plants=np.int64(9),
    )
    back = json.loads(json.dumps(asdict(cfg)))
    assert back["window"]["hours"] == 10.5 and back["site"]["altitude_m"] == 103.0 and back["n_plants"] == 9
    assert back["soil_albedo"] == pytest.approx(0.25) and type(LeafTraits(N=np.float32(1.5)).N) is float
    assert type(Field(row_direction_deg=np.float32(90)).row_direction_deg) is float  # as the spacings
