"""The coupled model's observation operator and the inference objectives at the extremes of the
weather and of the calibrated parameters (docs/photosynthesis.md, "Numerical stability at the
extremes", lists where every other layer's extremes are tested).

The light parts are synthetic (no render): the operator and the likelihood are what is tested, on
one compiled leaf solve (``winter_wheat``, the default set), with and without ``jax.jit``.
"""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd
import pytest

from lightfit.inference.calibration import Loss
from lightfit.inference.likelihood import GaussianLikelihood, plug_in
from lightfit.inference.mcmc.log_posterior import LogPosterior
from lightfit.inference.mcmc.priors import NOISE_SCALE, PRIORS_INFORMED
from lightfit.inference.observations import BY_NAME
from lightfit.light.estimator import PARTS
from lightfit.model import observe as O
from lightfit.model.parameters import Theta
from lightfit.model.scenario import Forcing, daytime
from lightfit.photosynthesis import parameter_set

R_GAS = 8.314462618
PAR, AN, NEE = BY_NAME["plant_par"], BY_NAME["canopy_an"], BY_NAME["nee"]

# One step per extreme: (name, sun elevation °, DNI, DHI (PAR, µmol m⁻² s⁻¹), air = leaf T °C, CO2 ppm, RH).
STEPS = [
    ("night, frost", -20.0, 0.0, 0.0, -10.0, 400.0, 0.9),
    ("grazing sun, frost", 1.0, 60.0, 25.0, -10.0, 400.0, 0.8),
    ("sun just below the horizon", -0.5, 0.0, 8.0, 5.0, 400.0, 1.0),
    ("full sun, heat, dry", 60.0, 2200.0, 300.0, 45.0, 400.0, 0.05),
    ("full sun, 50 °C, very dry", 60.0, 2200.0, 300.0, 50.0, 400.0, 0.02),
    ("full sun, CO2 below Γ*", 60.0, 2200.0, 300.0, 25.0, 20.0, 0.5),
    ("full sun, high CO2", 60.0, 2200.0, 300.0, 25.0, 2000.0, 0.5),
    ("low sun, saturated air", 2.0, 100.0, 60.0, 15.0, 400.0, 1.0),
]
NIGHT, BELOW_GAMMA, HIGH_CO2 = 0, 5, 6
ELEVATION, DNI, DHI, TAIR, CO2, RH = (np.array([s[i] for s in STEPS]) for i in range(1, 7))
AREA = np.array([1.0e-3, 2.0e-3, 1.5e-3, 5.0e-4])  # three blades and a stem
IS_BLADE = np.array([True, True, True, False])
GROUND = 0.01
# The informed priors' bounds of the two operator parameters, in every combination with the default.
THETAS = [(1.0, 1.0), (0.25, 0.25), (4.0, 4.0), (0.25, 4.0), (4.0, 0.25)]
assert PRIORS_INFORMED["light_factor"].support == PRIORS_INFORMED["vcmax_scale"].support == (0.25, 4.0)
# Just inside the domains' bound 0 (the calibration's log coordinates reach any of these) and a Vcmax
# scale far above the priors: no finite differences there (a step of 1e-6 leaves the domain).
EDGES = [(1e-300, 1.0), (1.0, 1e-300), (1e-12, 1e-12), (1e-300, 1e-300), (1.0, 1e6)]


def _operator():
    weather = pd.DataFrame({"dni_w_m2": DNI, "dhi_w_m2": DHI, "sun_elevation_deg": ELEVATION})
    day = daytime(weather)
    assert day.tolist() == [False] + [True] * 7  # −0.5° is daytime (the sky still lights the canopy)
    forcing = Forcing(
        day=day, dni_par=DNI, dhi_par=DHI, tair_c=TAIR, co2_ppm=CO2, rh=RH, pair_kpa=np.full(len(STEPS), 101.325)
    )
    op = O.ObservationOperator(
        forcing=forcing, area_m2=AREA, is_blade=IS_BLADE, par_kind="absorbed", denominator_m2=AREA[IS_BLADE].sum(),
        params=parameter_set("winter_wheat"), ground_area_m2=GROUND, sun_elevation_deg=ELEVATION,
    )  # fmt: skip
    rng = np.random.default_rng(4)
    values = rng.uniform(0.05, 0.9, (int(day.sum()), len(PARTS), len(AREA)))
    for kind in ("sun", "sky"):  # a leaf absorbs 85 % of what reaches it (PAR absorptance)
        values[:, PARTS.index(f"absorbed_{kind}")] = 0.85 * values[:, PARTS.index(f"incident_{kind}")]
    se = 0.02 * values
    return op, jnp.asarray(values), jnp.asarray(se)


@pytest.fixture(scope="module")
def operator():
    return _operator()


def _rd(t_c, scale):
    """winter_wheat's dark respiration: Rd25 = 0.015 × Vcmax25 (100 × scale), Bernacchi et al. (2001)'s
    Arrhenius with Ea = 46.39 kJ mol⁻¹ (written out here, not read from the package)."""
    return 1.5 * scale * np.exp(46390.0 / R_GAS * (1 / 298.15 - 1 / (t_c + 273.15)))


def test_the_operator_is_finite_physical_and_differentiable_at_the_extremes(operator):
    """Night frost, grazing and set sun, full sun in heat and very dry air, CO2 below Γ* and at
    2 000 ppm, saturated air, each at the informed priors' bounds of the light factor and the Vcmax
    scale and at the EDGES of their domains: every observable finite and converged (with and without
    jit at the default θ, equal), with a finite gradient, and physical:

    * above-canopy PAR is f·(DNI sin⁺β + DHI) (no beam with the sun below the horizon), fAPAR the
      same at every f;
    * at night canopy An per leaf area is −Rd(T), Bernacchi's Arrhenius, and NEE its negative per
      ground area (no soil respiration);
    * below Γ* (20 ppm at 25 °C, Γ* = 42.75) every blade releases CO2 in full sun;
    * at 2 000 ppm every blade's An + Rd lies between 0.85 and 1 × J/4, J from the non-rectangular
      hyperbola with Jmax25 = 206.5 × scale (electron transport limits, nearly saturated in CO2);
    * the gradient in (light factor, Vcmax scale) equals central differences (jit; eager at the default θ).

    At the EDGES a Vcmax scale of 1e-300 gave NaN Monte Carlo SDs of An (the leaves' dAn/dq, NaN in
    the dark below a scale of ≈ 1e-156) and a NaN gradient, a light factor of 1e-300 an infinite
    gradient of fAPAR (APAR / above-canopy PAR, the quotient rule squaring 1e-297)."""
    op, values, se = operator
    area_b = AREA[IS_BLADE]
    keys = ("canopy_an_umol_m2_s", "nee_umol_m2_s", "plant_par_umol_m2_s", "above_canopy_par_umol_m2_s", "fapar")

    def observe(f, s):
        return op(values, se, Theta(light_factor=f, vcmax_scale=s))

    def total(f, s):
        o = observe(f, s)
        return sum(jnp.sum(o[k]) for k in keys)

    def both(f, s):  # one compilation for values and gradient
        return observe(f, s), jax.grad(total, (0, 1))(f, s)

    both_jit = jax.jit(both)

    def total_jit(f, s):
        o = both_jit(f, s)[0]
        return sum(float(np.sum(o[k])) for k in keys)

    fapar = np.asarray(both_jit(1.0, 1.0)[0]["fapar"])
    for n, (f, s) in enumerate(THETAS + EDGES):
        edge = n >= len(THETAS)
        outs = {how: fn(f, s) for how, fn in [("jit", both_jit)] + ([("eager", both)] if n == 0 else [])}
        grads = {how: [float(x) for x in out[1]] for how, out in outs.items()}
        outs = {how: out[0] for how, out in outs.items()}
        o = outs["jit"]
        for k in keys + ("canopy_an_mc_sd_umol_m2_s", "leaf_an_umol_m2_s", "absorbed_par_umol_m2_s"):
            assert np.all(np.isfinite(np.asarray(o[k]))), (f, s, k)
            if "eager" in outs:
                np.testing.assert_allclose(np.asarray(outs["eager"][k]), np.asarray(o[k]), rtol=1e-10, atol=1e-12)
        assert np.asarray(o[O.CONVERGENCE_KEY]).tolist() == [0] * len(STEPS), (f, s)
        assert np.all(np.asarray(o["photosynthesis"].converged))

        sin_up = np.maximum(np.sin(np.radians(ELEVATION)), 0.0)
        np.testing.assert_allclose(np.asarray(o["above_canopy_par_umol_m2_s"]), f * (DNI * sin_up + DHI), rtol=1e-12)
        np.testing.assert_allclose(np.asarray(o["fapar"]), fapar, rtol=1e-12)
        an = np.asarray(o["canopy_an_umol_m2_s"])
        assert an[NIGHT] == pytest.approx(-_rd(TAIR[NIGHT], s), rel=1e-9)
        an_ground = an * area_b.sum() / GROUND
        np.testing.assert_allclose(np.asarray(o["nee_umol_m2_s"]), -an_ground, rtol=1e-12, atol=1e-12)
        leaf = np.asarray(o["leaf_an_umol_m2_s"])
        assert np.all(leaf[BELOW_GAMMA] < 0), (f, s, leaf[BELOW_GAMMA])

        for how, g in grads.items():
            assert all(np.isfinite(g)), (how, f, s)
        if edge:  # below: An + Rd and differences of An at ±1e-6, which rounding swamps here
            continue
        q = np.asarray(o["absorbed_par_umol_m2_s"])[HIGH_CO2, IS_BLADE]
        aq, jmax, th = 0.352 * q, 206.5 * s, 0.7
        j = ((aq + jmax) - np.sqrt((aq + jmax) ** 2 - 4 * th * aq * jmax)) / (2 * th)
        gross = leaf[HIGH_CO2] + _rd(25.0, s)
        assert np.all(gross <= j / 4 * (1 + 1e-12)) and np.all(gross >= 0.85 * j / 4), (f, s, gross, j / 4)

        h = 1e-6
        fd = [
            (total_jit(f + h, s) - total_jit(f - h, s)) / (2 * h),
            (total_jit(f, s + h) - total_jit(f, s - h)) / (2 * h),
        ]
        for how, g in grads.items():
            # measured agreement ≤ 2e-7 relative: a 6-fold margin
            assert g == pytest.approx(fd, rel=1e-6), (how, f, s, g, fd)


def _twin(op, values, se):
    """Observations of plant PAR, canopy An and NEE: the operator at the default θ, shifted by hand
    (5 % more light, 0.4 µmol m⁻² s⁻¹ more uptake), with SDs of 3 % and 0.5."""
    m = op(values, se, Theta(light_factor=1.0, vcmax_scale=1.0))
    times = pd.date_range("2016-04-20 00:00", periods=len(STEPS), freq="3h", tz="UTC")
    par, an, nee = (np.asarray(m[s.value]) for s in (PAR, AN, NEE))
    obs = pd.DataFrame(
        {
            PAR.value: 1.05 * par, PAR.sd: np.maximum(0.03 * par, 1.0),
            AN.value: an + 0.4, AN.sd: 0.5, NEE.value: nee - 0.4, NEE.sd: 0.5,
        },
        index=times,
    )  # fmt: skip
    return obs, times


def test_the_log_posterior_and_the_loss_at_the_parameters_bounds(operator):
    """The log-posterior over (light factor, Vcmax scale, noise scale) at every corner of the informed
    priors' box (0.25–4, 0.25–4, 0.3–3), as the MAP search takes it (Monte Carlo SDs held): finite,
    with a finite gradient equal to finite differences there (one-sided inward, the box being
    closed), under jit (eagerly: the operator's test above and test_likelihood.py); a hair outside
    the box emcee's log-probability is −inf with a zero gradient, never NaN. The calibration loss
    (SDs held at the start, as calibrate holds them) on its unconstrained coordinates (log f, log s)
    at z = ±log 4 (the priors' bounds): finite and its gradient the central difference; as z → −∞
    (f, s → 0, down to e⁻⁷⁰⁰) still finite."""
    op, values, se = operator
    obs, times = _twin(op, values, se)

    def forward(theta):
        return op(values, se, theta)

    names = ("light_factor", "vcmax_scale", NOISE_SCALE)
    lp = LogPosterior(forward, times, obs, names, use=("plant_par", "an", "nee"))
    support = np.array([PRIORS_INFORMED[n].support for n in names])
    # The MAP search's objective (lightfit.inference.posterior): Monte Carlo SDs held at a reference
    # point, so that its gradient is its derivative; emcee's log_prob takes each point's own SDs.
    mc = lp.plug_in(lp.center())

    def log_prob(x):
        return lp.log_prior(x) + lp.log_likelihood(x, mc)

    jit_value_and_grad = jax.jit(jax.value_and_grad(log_prob))
    refused = jax.jit(jax.value_and_grad(lp.log_prob))
    h = 1e-6
    for corner in np.array(np.meshgrid(*support, indexing="ij")).reshape(3, -1).T:
        x = jnp.asarray(corner)
        value, g = jit_value_and_grad(x)
        value, g = float(value), np.asarray(g)
        assert np.isfinite(value) and np.all(np.isfinite(g)), corner
        inward = np.where(corner == support[:, 0], 1.0, -1.0) * h
        fd = [(float(jit_value_and_grad(x.at[i].add(inward[i]))[0]) - value) / inward[i] for i in range(3)]
        # one-sided, an O(h) error: measured ≤ 3e-6 relative
        np.testing.assert_allclose(g, fd, rtol=1e-4, err_msg=str(corner))
        for i in range(3):  # just outside: refused, no NaN anywhere
            out = x.at[i].set(support[i, 0] * (1 - 1e-9) if corner[i] == support[i, 0] else support[i, 1] * (1 + 1e-9))
            v, g = refused(out)
            assert float(v) == -np.inf and np.all(np.asarray(g) == 0.0), (corner, i)

    lik = GaussianLikelihood(obs, times, ("plant_par", "an", "nee"))
    loss = Loss(forward, lik, ("light_factor", "vcmax_scale"), Theta(), mc=plug_in(lik, forward(Theta())))
    value_and_grad = jax.jit(jax.value_and_grad(lambda z: loss(z)[0]))
    for z in np.array(np.meshgrid(*[[-math.log(4.0), math.log(4.0)]] * 2)).reshape(2, -1).T:
        z = jnp.asarray(z)
        v, g = value_and_grad(z)
        fd = [
            (float(value_and_grad(z.at[i].add(1e-6))[0]) - float(value_and_grad(z.at[i].add(-1e-6))[0])) / 2e-6
            for i in range(2)
        ]
        assert np.isfinite(float(v)) and np.all(np.isfinite(np.asarray(g))), z
        np.testing.assert_allclose(np.asarray(g), fd, rtol=1e-5, err_msg=str(z))
    for far in ([-40.0, -40.0], [0.0, -360.0], [-700.0, -700.0]):  # f, s down to 1e-304: no light, no leaf
        v, g = value_and_grad(jnp.asarray(far))
        assert np.isfinite(float(v)) and np.all(np.isfinite(np.asarray(g))), far  # s < 1e-156: NaN before
    assert math.isclose(float(loss.to_natural(jnp.asarray(far))[0]), math.exp(-700.0), rel_tol=1e-12)
