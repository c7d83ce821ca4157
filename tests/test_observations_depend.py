"""What each observed series depends on (``Series.depends_on``) against the model's own gradients,
and the refusal to calibrate parameters that no observed series depends on."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from lightfit.errors import InputError
from lightfit.inference.likelihood import check_informed, uninformed
from lightfit.inference.observations import SERIES, dependencies
from lightfit.model.parameters import NAMES, Theta
from lightfit.precision import use_float64

use_float64()


RUNS = [{"bounces": 1, "par_kind": "absorbed"}, {"bounces": 0, "par_kind": "incident"}]


@pytest.fixture(scope="module", params=RUNS, ids=lambda r: f"bounces{r['bounces']}-{r['par_kind']}")
def gradients(request):
    """∂(series at noon)/∂θ for every series and parameter, by reverse mode through the render
    (light bridge) and the photosynthesis fixed point, on a small finite field with a ceptometer;
    with light scattered once, and without scattering (where the leaf acts only through what it
    absorbs) with incident PAR at the plants."""
    from lightfit import replication as rep
    from lightfit.model.coupled import CoupledModel
    from lightfit.model.scenario import Scenario
    from lightfit.plant import Field

    weather = rep.forcing().iloc[[1, 14]]  # 05:30 local (night), 12:00
    run = request.param
    fld = Field(boundary="finite", n_plants=4, buffer_rows=1, seed=1)
    sc = Scenario(weather=weather, field=fld, samples=8, bounces=run["bounces"], par_kind=run["par_kind"])
    m = CoupledModel(sc)
    # Not at the defaults: a light factor of exactly 1 would hide nothing, but values away from
    # any special point make an accidental zero unlikely.
    theta = m.theta(Theta(specular=0.6, roughness=0.4, subsurface=0.55, light_factor=1.1, vcmax_scale=0.9))
    x0 = jnp.asarray([getattr(theta, n) for n in NAMES], jnp.float64)

    def observed(x):
        out = m.observe(Theta().with_vector(NAMES, x))
        return {s.name: jnp.asarray(out[s.value]) for s in SERIES}

    values, pullback = jax.vjp(observed, x0)
    grads = {}
    for s in SERIES:
        cot = {k: jnp.zeros_like(v) for k, v in values.items()}
        cot[s.name] = cot[s.name].at[1].set(1.0)  # the noon step
        grads[s.name] = (float(values[s.name][1]), np.asarray(pullback(cot)[0]))
    return run, grads


@pytest.mark.parametrize("series", SERIES, ids=lambda s: s.name)
def test_each_series_depends_on_exactly_its_declared_parameters(gradients, series):
    """A declared dependence has a gradient (relative sensitivity |θ ∂y/∂θ / y| > 10⁻⁶); an undeclared
    one has none beyond rounding (< 10⁻¹⁰): the ratios' light factor cancels, the PAR series do not
    see Vcmax, the sensor above the canopy sees only the sky; without scattering incident light does
    not see the leaf, and nothing sees subsurface (it let a calibration "converge" at its start)."""
    run, grads = gradients
    value, g = grads[series.name]
    assert np.isfinite(value) and value != 0 and np.all(np.isfinite(g))
    x = np.asarray([0.6, 0.4, 0.55, 1.1, 0.9])
    relative = np.abs(g * x / value)
    declared = dependencies(series, **run)
    for i, name in enumerate(NAMES):
        if name in declared:
            assert relative[i] > 1e-6, (series.name, name, relative[i])
        else:
            assert relative[i] < 1e-10, (series.name, name, relative[i])


def test_parameters_no_series_depends_on_are_named():
    assert uninformed(["specular", "light_factor", "noise_scale"], ["above_canopy_par"]) == ("specular",)
    assert uninformed(["vcmax_scale", "light_factor"], ["plant_par", "fapar"]) == ("vcmax_scale",)
    assert uninformed(["vcmax_scale", "light_factor"], ["fapar", "nee"]) == ()
    with pytest.raises(InputError) as e:
        check_informed(["specular", "roughness"], ["above_canopy_par"])
    msg = str(e.value)
    assert "above_canopy_par" in msg and "specular, roughness" in msg and "light_factor" in msg
    check_informed(["light_factor"], ["above_canopy_par"])  # informed: no error
    # Without scattering: subsurface is informed by nothing, the leaf not by incident light.
    assert uninformed(["subsurface", "specular"], ["fapar", "nee"], bounces=0) == ("subsurface",)
    assert uninformed(["specular"], ["plant_par"], bounces=0, par_kind="incident") == ("specular",)
    assert uninformed(["specular"], ["plant_par"], bounces=0, par_kind="absorbed") == ()
    with pytest.raises(InputError, match="bounces 0") as e:
        check_informed(["subsurface"], ["nee"], bounces=0)
    assert "subsurface: none at bounces 0" in str(e.value)


def test_calibrate_refuses_parameters_the_observations_cannot_inform(tmp_path):
    """The chamber record (above-canopy PAR only) against the leaf parameters: refused naming
    --parameters before any plant grows; it ran, stopped at the start and listed every leaf
    parameter as '(calibrated)', converged (gradient exactly 0)."""
    from typer.testing import CliRunner

    from lightfit import replication as rep
    from lightfit.cli import app

    r = CliRunner().invoke(app, ["calibrate", str(rep.OBSERVATIONS), "--quick", "--out", str(tmp_path / "c")])
    assert r.exit_code == 2, r.output
    err = " ".join(r.stderr.split())
    assert "option --parameters:" in err and "do not depend on specular, roughness, subsurface" in err
    assert not (tmp_path / "c" / "settings.json").exists()
