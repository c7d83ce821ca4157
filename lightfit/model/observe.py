r"""The observation operator: what the instruments (quantum sensors, a gas-exchange chamber) see of the coupled model.

Every path that produces observables goes through this module: full renders
(:meth:`lightfit.model.coupled.CoupledModel.observe`), emulated light parts
(:class:`lightfit.model.emulator.FastObservables`) and per-segment results gathered from Dask
tiles (:func:`lightfit.distributed.run.gather`, on numpy arrays).

**Light at the segments.** For daytime step :math:`t` and measured segment :math:`s` the renderer
gives parts :math:`i^{\odot}_{s,t}, i^{sky}_{s,t}` per unit DNI / DHI with Monte Carlo standard
errors :math:`\sigma^{\odot}, \sigma^{sky}`; with the light factor :math:`f`

.. math::

    I_{s,t} = f\,(\mathrm{DNI}^{PAR}_t i^{\odot}_{s,t} + \mathrm{DHI}^{PAR}_t i^{sky}_{s,t}),\qquad
    \sigma_{I,s,t} = f\,\sqrt{(\mathrm{DNI}^{PAR}_t\sigma^{\odot}_{s,t})^2 + (\mathrm{DHI}^{PAR}_t\sigma^{sky}_{s,t})^2}

for incident and absorbed PAR (µmol m⁻² s⁻¹ per one-sided area). Night steps are not rendered:
:math:`I = \sigma = 0`.

**Plant PAR** (:func:`plant_par`), with area weights :math:`w_s = a_s / \sum a`:
mean :math:`\bar I_t = \sum_s w_s I_{s,t}`, spread :math:`\sqrt{\sum_s w_s (I_{s,t} - \bar I_t)^2}`
and Monte Carlo SD :math:`\sqrt{\sum_s w_s^2 \sigma_{I,s,t}^2}`, the segments' errors taken as
independent: exact for the paths (each segment has its own sample streams), an upper bound with
the projected direct light, whose rays are shared (a ray that lands on one segment cannot land on
another; 2.3–4.3× the replicates' SE of a canopy total, docs/model.md).

**Canopy net CO2 uptake** (:func:`canopy_an`): leaf photosynthesis gives :math:`A_{b,t}` of every
leaf blade :math:`b` from its absorbed PAR :math:`q_{b,t}`;
:math:`A_t = \sum_b a_b A_{b,t} / D` with :math:`D = \sum_b a_b` (per leaf area) or the ground
area of the measured plants (per ground area). Its Monte Carlo SD propagates the absorbed-PAR
error linearly, :math:`\sigma_{A,b,t} = |\partial A_{b,t}/\partial q|\,\sigma_{q,b,t}` and
:math:`\sqrt{\sum_b (a_b \sigma_{A,b,t} / D)^2}`.

**Instrument operators.** Each observable is what one instrument measures, in the instrument's
own terms (:data:`OBSERVABLES`; the observations CSV names them, :mod:`lightfit.inference.observations`):

- :func:`above_canopy_par` — a horizontal quantum sensor above the canopy (a station's or a
  chamber's PAR sensor): :math:`f\,(\mathrm{DNI}^{PAR}_t \sin\beta_t + \mathrm{DHI}^{PAR}_t)`,
  β the sun elevation. The weather contract's DNI and DHI split the series' global radiation
  (by its own diffuse radiation or a decomposition model, :func:`lightfit.weather.add_solar`;
  DNI sin β + DHI = GHI), so at
  f = 1 this is the global radiation in PAR units — the model's light field, analytic and exact
  (no Monte Carlo error).
- :func:`canopy_apar` — PAR absorbed by all measured segments per unit ground area of the
  measurement area, :math:`\mathrm{APAR}_t = \sum_s a_s\,q_{s,t} / G` (a: one-sided area, q:
  absorbed PAR, G: ground area; Monte Carlo SD :math:`\sqrt{\sum_s (a_s\sigma_{q,s,t}/G)^2}`).
- :func:`fapar` — fraction of the PAR incident on a horizontal plane above the canopy that the
  canopy absorbs, :math:`\mathrm{APAR}_t / \mathrm{PAR}^{above}_t` (0 at night); the usual
  definition of fAPAR (e.g. Gobron et al. 2006, Remote Sens. Environ. 101, 176; stems and
  sheaths count, as in a canopy's radiation balance).
- :func:`ceptometer_transmittance` — a line quantum sensor (ceptometer) on the soil under the
  canopy, rendered like the segments (:mod:`lightfit.light.sensors`: direct sun with shadow rays,
  sky, light scattered by leaves and soil, periodic wrapping; per unit DNI / DHI, so the light
  factor and the weather scale it as they scale the segments): transmitted PAR
  :math:`E^{soil}_t = f\,(\mathrm{DNI}^{PAR}_t e^{\odot}_t + \mathrm{DHI}^{PAR}_t e^{sky}_t)`
  (``transmitted_par_umol_m2_s``, mean over the bar's placements) and the transmittance
  :math:`\tau_t = E^{soil}_t / \mathrm{PAR}^{above}_t` (f cancels).
- :func:`ceptometer_fapar` — fAPAR as a single ceptometer estimates it, :math:`1 - \tau_t` (the
  one-sensor approximation; it neglects reflected PAR). :func:`fapar` is the canopy's own
  absorbed share; for black leaves on black soil the two agree (tests/test_sensors.py).
- :func:`chamber_nee` — net ecosystem CO2 exchange of the chamber footprint (the measurement
  area), per ground area, in the micrometeorological sign convention (positive: CO2 released to
  the atmosphere): :math:`\mathrm{NEE}_t = -A^{ground}_t + R_{soil}`, with the canopy net uptake
  per ground area :math:`A^{ground}_t` (leaf dark respiration included) and the soil's
  respiration :math:`R_{soil,t} = R_{10} Q_{10}^{(T_t - 10)/10}` (µmol m⁻² ground s⁻¹,
  :func:`soil_respiration`; R₁₀ default :data:`SOIL_RESPIRATION_UMOL_M2_S` = 0: lightfit does not
  model soil or root respiration, so a user comparing with a chamber on soil gives R₁₀, e.g. from
  bare-soil readings, or from night readings *minus* the leaves' modelled dark respiration, which
  those readings include and the model adds itself; either brought to 10 °C, R₁₀ = R / Q₁₀^((T - 10)/10)
  for a reading R at air temperature T; Q₁₀ default 2).

Absorbed PAR per segment stays an output (``absorbed_par_umol_m2_s``, results.nc) for users who
compare leaf by leaf.

Monte Carlo SDs carry no gradient (``jax.lax.stop_gradient``): they weight the likelihood, they
are not fitted; the optimisers hold them at a reference θ (:func:`lightfit.inference.likelihood.plug_in`),
since their values still move with θ. The aggregate functions accept numpy arrays (computed in numpy, float64) or JAX
arrays (computed in JAX, differentiable).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd

from lightfit.errors import InputError
from lightfit.light.estimator import PARTS
from lightfit.model.parameters import Theta, outside_domain
from lightfit.model.scenario import SOIL_RESPIRATION_Q10, SOIL_RESPIRATION_T_REF_C, SOIL_RESPIRATION_UMOL_M2_S, Forcing
from lightfit.model.schema import OBSERVABLES
from lightfit.photosynthesis import (
    MAX_PAR_ABS_UMOL_M2_S,
    PhotosynthesisParams,
    PhotosynthesisResult,
    solve_with_par_slope,
)
from lightfit.precision import power_of_two_scale, sqrt_or_zero
from lightfit.weather.solar import horizontal_irradiance


def _numpy(*arrays) -> bool:
    """True when every input is a numpy array or scalar: compute in numpy (float64, no tracing)."""
    return all(isinstance(a, (np.ndarray, np.generic, float, int)) for a in arrays)


def _no_grad(x):
    return x if isinstance(x, np.ndarray) else jax.lax.stop_gradient(x)


def plant_par(par, par_mc_sd, area_m2) -> tuple:
    """Area-weighted mean, spread and Monte Carlo SD of PAR over the segments.

    Args:
        par, par_mc_sd: (T, S) PAR of every measured segment and its Monte Carlo SD, µmol m⁻² s⁻¹.
        area_m2: (S,) one-sided segment areas (the weights).

    Returns ``(mean, spread, mc_sd)``, each (T,), µmol m⁻² s⁻¹.
    """
    xp = np if _numpy(par, par_mc_sd, area_m2) else jnp
    w = area_m2 / area_m2.sum()
    mean = par @ w
    var = (par - mean[:, None]) ** 2 @ w
    spread = sqrt_or_zero(var, xp)  # 0 with PAR equal everywhere, e.g. at night: a finite gradient
    mc_sd = xp.sqrt(_no_grad((par_mc_sd**2) @ (w**2)))
    return mean, spread, mc_sd


def area_total(x, x_mc_sd, area_m2, denominator_m2) -> tuple:
    r"""Area-weighted sum of a per-area flux over segments per ``denominator_m2``, and its Monte Carlo SD.

    :math:`\sum_s a_s x_{s,t} / D` and :math:`\sqrt{\sum_s (a_s \sigma_{s,t} / D)^2}` (segments
    taken as independent: an upper bound with the projected direct light, see the module
    docstring). Args: ``x, x_mc_sd`` (T, S) in any unit per m² of segment, ``area_m2`` (S,)
    one-sided areas, ``denominator_m2`` m². Returns two (T,) arrays.
    """
    xp = np if _numpy(x, x_mc_sd, area_m2) else jnp
    return x @ area_m2 / denominator_m2, xp.sqrt(_no_grad(x_mc_sd**2 @ (area_m2 / denominator_m2) ** 2))


def canopy_an(an, an_mc_sd, blade_area_m2, denominator_m2) -> tuple:
    """Net CO2 uptake of the blades per ``denominator_m2`` and its Monte Carlo SD.

    Args:
        an, an_mc_sd: (T, B) leaf net assimilation of every blade and its Monte Carlo SD,
            µmol m⁻² s⁻¹ per one-sided leaf area.
        blade_area_m2: (B,) one-sided blade areas.
        denominator_m2: leaf area (Σ blade area) or ground area, m² (:func:`an_denominator`).

    Returns ``(canopy_an, canopy_an_mc_sd)``, each (T,), µmol m⁻² s⁻¹ per m² of ``denominator_m2``.
    """
    return area_total(an, an_mc_sd, blade_area_m2, denominator_m2)


def canopy_apar(absorbed, absorbed_mc_sd, area_m2, ground_area_m2) -> tuple:
    """Canopy APAR: PAR absorbed by all measured segments per unit ground area, and its Monte Carlo SD.

    Args:
        absorbed, absorbed_mc_sd: (T, S) absorbed PAR per one-sided segment area, µmol m⁻² s⁻¹.
        area_m2: (S,) one-sided segment areas (blades, and the lateral surface of stems/sheaths).
        ground_area_m2: ground area of the measured plants, m².

    Returns ``(apar, apar_mc_sd)``, each (T,), µmol m⁻² ground s⁻¹.
    """
    return area_total(absorbed, absorbed_mc_sd, area_m2, ground_area_m2)


def above_canopy_par(dni_par, dhi_par, sun_elevation_deg, light_factor=1.0):
    r"""PAR on a horizontal quantum sensor above the canopy, µmol m⁻² s⁻¹ (T,).

    :math:`f\,(\mathrm{DNI}^{PAR} \sin^+\beta + \mathrm{DHI}^{PAR})`
    (:func:`lightfit.weather.solar.horizontal_irradiance`, times the light factor).

    Args:
        dni_par, dhi_par: (T,) direct-normal and diffuse-horizontal PAR, µmol m⁻² s⁻¹.
        sun_elevation_deg: (T,) sun elevation β, degrees (below the horizon the beam counts 0).
        light_factor: f, the model's multiplier of the forcing's light (dimensionless).
    """
    xp = np if _numpy(dni_par, dhi_par, sun_elevation_deg, light_factor) else jnp
    return light_factor * horizontal_irradiance(dni_par, dhi_par, sun_elevation_deg, xp)


def _ratio(x, x_mc_sd, above_par) -> tuple:
    """``x / above_par`` and ``x_mc_sd / above_par`` where there is light above the canopy, 0 at night."""
    xp = np if _numpy(x, x_mc_sd, above_par) else jnp
    lit = above_par > 0
    safe = xp.where(lit, above_par, 1.0)  # double-where: no NaN gradient from 0/0 at night
    # Both times a power of two that brings the light near 1 (exact): the quotient rule squares the
    # divisor, which underflowed below 1e-154 µmol m-2 s-1 (a light factor below 1e-156: an infinite gradient).
    k = power_of_two_scale(safe, xp)
    return xp.where(lit, (k * x) / (k * safe), 0.0), xp.where(lit, (k * x_mc_sd) / (k * safe), 0.0)


def fapar(apar, apar_mc_sd, above_par) -> tuple:
    """Fraction of absorbed PAR, APAR / PAR above the canopy (dimensionless), and its Monte Carlo SD.

    Args:
        apar, apar_mc_sd: (T,) canopy APAR per ground area and its SD (:func:`canopy_apar`).
        above_par: (T,) PAR on a horizontal plane above the canopy (:func:`above_canopy_par`).

    Steps without light above the canopy (night) give 0 (and SD 0), not 0/0.
    """
    return _ratio(apar, apar_mc_sd, above_par)


def ceptometer_transmittance(transmitted, transmitted_mc_sd, above_par) -> tuple:
    r"""Canopy PAR transmittance read by a ceptometer, :math:`\tau = E_{soil} / E_{above}`, and its SD.

    Args:
        transmitted, transmitted_mc_sd: (T,) PAR on the line sensor on the soil (mean over its
            placements, :class:`lightfit.light.sensors.Sensor`) and its Monte Carlo SD, µmol m⁻² s⁻¹.
        above_par: (T,) PAR above the canopy (:func:`above_canopy_par`; analytic, no error).

    0 at night (as :func:`fapar`). A real ceptometer takes the above-canopy reading with the same
    bar or a reference sensor; here it is the model's above-canopy sensor, exact.
    """
    return _ratio(transmitted, transmitted_mc_sd, above_par)


def ceptometer_fapar(transmittance, transmittance_mc_sd, above_par) -> tuple:
    r"""fAPAR from a ceptometer in the one-sensor approximation :math:`1 - \tau`, and its SD.

    The full radiation balance of the canopy, :math:`1 - \tau - \rho_c + \tau\rho_s`
    (reflection of canopy and soil; measured with an upward and a downward sensor above and
    below), needs the upwelling PAR; the common single-bar protocol neglects it (Gallo & Daughtry
    1986, Agron. J. 78, 752; the AccuPAR manual), overestimating fAPAR by the canopy's PAR
    reflectance minus what the soil returns (a few percent for green cereals). ``above_par``
    marks the night (0 there).
    """
    xp = np if _numpy(transmittance, transmittance_mc_sd, above_par) else jnp
    lit = above_par > 0
    return xp.where(lit, 1.0 - transmittance, 0.0), transmittance_mc_sd


def soil_respiration(r_ref_umol_m2_s, q10, temperature_c, xp=np):
    r"""Soil (and root) respiration, µmol m⁻² ground s⁻¹, at ``temperature_c`` (°C):
    :math:`R = R_{10}\,Q_{10}^{(T - 10)/10}` (the Q₁₀ model; e.g. Lloyd & Taylor 1994, Funct.
    Ecol. 8:315, who also discuss its limits) with ``r_ref_umol_m2_s`` = R₁₀ at
    :data:`SOIL_RESPIRATION_T_REF_C`. The air temperature stands in for the soil's, which lags it
    and swings less (a documented simplification: on the main job's day ≈ +3 % over the day and
    −20 … +26 % per step against the soil at 5 cm; docs/model.md, "Soil respiration on air
    temperature", which also sets the law against Lloyd & Taylor's). ``xp``: numpy or ``jax.numpy``."""
    return r_ref_umol_m2_s * q10 ** ((xp.asarray(temperature_c) - SOIL_RESPIRATION_T_REF_C) / 10.0)


def chamber_nee(canopy_an_ground, canopy_an_ground_mc_sd, soil_respiration_umol_m2_s=SOIL_RESPIRATION_UMOL_M2_S):
    """Net ecosystem CO2 exchange of a chamber footprint per ground area, µmol m⁻² s⁻¹, and its SD.

    NEE = −A + R_soil, micrometeorological sign convention (positive: CO2 released to the air;
    Baldocchi 2003, Global Change Biol. 9, 479): ``canopy_an_ground`` (T,) is the canopy's net CO2
    uptake per ground area (leaf dark respiration included, :func:`canopy_an`),
    ``soil_respiration_umol_m2_s`` the soil's respiration, a number or one per step
    (:func:`soil_respiration`). The Monte Carlo SD is the canopy's.
    """
    return soil_respiration_umol_m2_s - canopy_an_ground, canopy_an_ground_mc_sd


def an_denominator(blade_area_m2, an_per: str, ground_area_m2: float):
    """Area canopy An refers to: Σ blade area (``an_per="leaf"``) or the measured ground area."""
    return blade_area_m2.sum() if an_per == "leaf" else ground_area_m2


def observables(
    par,
    par_mc_sd,
    area_m2,
    an,
    an_mc_sd,
    blade_area_m2,
    denominator_m2,
    *,
    absorbed,
    absorbed_mc_sd,
    ground_area_m2: float,
    above_par,
    soil_respiration_umol_m2_s: float | np.ndarray = SOIL_RESPIRATION_UMOL_M2_S,
    transmitted=None,
    transmitted_mc_sd=None,
    rendered=None,
) -> dict:
    """The :data:`OBSERVABLES` (each (T,)) from per-segment PAR (T, S), per-blade leaf An (T, B),
    per-segment absorbed PAR (T, S), PAR above the canopy (T,) (:func:`above_canopy_par`) and
    PAR on the ceptometer on the soil (T,) with its SD (``None``: no ceptometer rendered, its
    observables are NaN).

    ``rendered`` (T,) bool marks the steps whose light was rendered (``None``: every step); the
    others are night to the ceptometer, whose τ and fAPAR are 0 there as at night. A step with
    light above that is not rendered (diffuse light with the sun below
    :data:`~lightfit.model.scenario.TWILIGHT_SUN_MIN_DEG`, a sensor's offset; a beam alone with the
    sun below −1°, :func:`~lightfit.model.scenario.daytime`) has transmitted PAR 0, and 1 − τ gave
    a ceptometer fAPAR of 1 there beside a canopy fAPAR of 0.

    ``par``/``par_mc_sd`` are the plant-PAR kind (incident or absorbed); canopy An is per
    ``denominator_m2``, APAR and NEE per ``ground_area_m2``. Units: every PAR and An in
    µmol m⁻² s⁻¹ (PAR per one-sided segment area, An per one-sided blade area), areas in m²; the
    observables likewise (fractions dimensionless), as :data:`OBSERVABLES` names them.
    """
    xp = np if _numpy(par, an, above_par) else jnp
    mean, spread, par_sd = plant_par(par, par_mc_sd, area_m2)
    can, can_sd = canopy_an(an, an_mc_sd, blade_area_m2, denominator_m2)
    if denominator_m2 == ground_area_m2:
        an_ground, an_ground_sd = can, can_sd
    else:
        an_ground, an_ground_sd = canopy_an(an, an_mc_sd, blade_area_m2, ground_area_m2)
    apar, apar_sd = canopy_apar(absorbed, absorbed_mc_sd, area_m2, ground_area_m2)
    fa, fa_sd = fapar(apar, apar_sd, above_par)
    nee, nee_sd = chamber_nee(an_ground, an_ground_sd, soil_respiration_umol_m2_s)
    if transmitted is None:  # no ceptometer: none of its readings, at night either (its 0 there is a convention)
        transmitted = transmitted_mc_sd = tau = tau_sd = cf = cf_sd = xp.full_like(above_par, xp.nan)
    else:
        read = above_par if rendered is None else xp.where(xp.asarray(rendered), above_par, 0.0)
        tau, tau_sd = ceptometer_transmittance(transmitted, transmitted_mc_sd, read)
        cf, cf_sd = ceptometer_fapar(tau, tau_sd, read)
    values = (mean, spread, par_sd, can, can_sd, above_par, xp.zeros_like(above_par), apar, apar_sd, fa, fa_sd)
    values += (nee, nee_sd, transmitted, transmitted_mc_sd, tau, tau_sd, cf, cf_sd)
    return dict(zip(OBSERVABLES, values, strict=True))


# -- leaf photosynthesis --------------------------------------------------------------------

#: Key of the operator's (T,) count of blades whose photosynthesis did not converge; forward
#: functions (``observe``, :class:`~lightfit.model.emulator.FastObservables`) pass it on beside the
#: :data:`OBSERVABLES`, and the likelihood has no value where it is not 0 (:func:`unconverged`,
#: :class:`~lightfit.inference.likelihood.GaussianLikelihood`).
CONVERGENCE_KEY = "unconverged_blades"


def unconverged(outputs: Mapping) -> jax.Array:
    """Blades whose photosynthesis did not converge, summed over the steps of a forward's
    ``outputs`` (0 where it has no :data:`CONVERGENCE_KEY`: a forward that solves nothing)."""
    n = outputs.get(CONVERGENCE_KEY)
    return jnp.asarray(0) if n is None else jnp.sum(jnp.asarray(n))


class LeafResponse(NamedTuple):
    """Leaf photosynthesis of the blades: net assimilation and dAn/dq, each (T, B), µmol m⁻² s⁻¹
    and mol mol⁻¹; ``converged`` (T, B) bool, False where the solve behind a blade's value did not
    converge (:attr:`PhotosynthesisResult.converged`); ``result`` the full solution (conductance,
    Ci, limitation…) where computed."""

    an: jax.Array
    dan_dq: jax.Array
    converged: jax.Array
    result: PhotosynthesisResult | None = None


#: ``leaf(q, forcing, params)``: absorbed PAR (T, B) → :class:`LeafResponse`.
LeafPhotosynthesis = Callable[[jax.Array, Forcing, PhotosynthesisParams], LeafResponse]


def _environment(forcing: Forcing, shape):
    return [
        jnp.broadcast_to(jnp.asarray(x)[:, None], shape)
        for x in (forcing.tair_c, forcing.co2_ppm, forcing.rh, forcing.pair_kpa)
    ]


def _solve_with_slope(q, forcing: Forcing, params: PhotosynthesisParams):
    t_c, co2, rh, p = _environment(forcing, q.shape)
    # One compiled solve gives An and every blade's dAn/dq (elementwise implicit function theorem).
    return solve_with_par_slope(q, t_c, co2, rh, p, params)


def exact_leaf(q, forcing: Forcing, params: PhotosynthesisParams) -> LeafResponse:
    """The photosynthesis solved for every blade at absorbed PAR ``q`` (µmol m⁻² s⁻¹, per blade), with
    the full result (net assimilation µmol m⁻² s⁻¹ per one-sided leaf area)."""
    res, dan = _solve_with_slope(q, forcing, params)
    return LeafResponse(res.an_umol_m2_s, dan, res.converged, res)


def with_capacity(leaf: LeafPhotosynthesis, capacity, base: float | None = None) -> LeafPhotosynthesis:
    r"""``leaf`` for blades whose per-area capacity is ``capacity`` (B,) times the parameter set's
    (:mod:`lightfit.photosynthesis.canopy`; ``None``: ``leaf`` itself).

    A leaf with every per-area rate and conductance (Vcmax, Jmax, Rd, g0, gm) times r at absorbed
    PAR q (scaled here through Vcmax, gm and g0: Jmax and Rd are ratios to Vcmax in every parameter
    set, :class:`~lightfit.photosynthesis.parameters.FvCBParams`) is that leaf at q/r with its
    fluxes times r: An = r·A(q/r), dAn/dq = A'(q/r); gs, Vc, Vj and Rd times r, ci, cs, cc and the
    limitation unchanged (exact with cs = ca, the coupled model's leaf without a boundary layer).
    The base leaf has capacity m₀ = ``base`` (default the blades' lowest; at most every blade's):
    the set's parameters scaled once, shared by all, so a tabulated leaf still tabulates one leaf
    per step, and r = m/m₀ ≥ 1, so q/r ≤ q stays within the range the solver accepts.
    """
    if capacity is None:
        return leaf
    m = np.asarray(capacity, np.float64)
    m0 = float(m.min()) if base is None else float(base)
    if not 0 < m0 <= m.min():
        raise InputError(f"capacity base {m0!r}", parameter="capacity_base", expected=f"in (0, {m.min():g}]")
    # Two multiplications, no division: XLA may turn a division by a constant into a product with
    # its reciprocal depending on the shapes it fuses, which would make tiles and time chunks of
    # one run differ in the last bit.
    r, shrink = jnp.asarray(m / m0), jnp.asarray(m0 / m)

    def profiled(q, forcing: Forcing, params: PhotosynthesisParams) -> LeafResponse:
        bottom = eqx.tree_at(
            lambda p: (p.fvcb.vcmax_ref_umol_m2_s, p.fvcb.gm_mol_m2_s, p.stomata.g0_mol_m2_s),
            params,
            (params.fvcb.vcmax_ref_umol_m2_s * m0, params.fvcb.gm_mol_m2_s * m0, params.stomata.g0_mol_m2_s * m0),
        )
        out = leaf(q * shrink, forcing, bottom)
        # The base leaf sees q/r ≤ q: the blade's own light is held to the solver's range here.
        within = q <= MAX_PAR_ABS_UMOL_M2_S
        res = out.result
        if res is not None:
            res = res._replace(
                an_umol_m2_s=r * res.an_umol_m2_s,
                gs_mol_m2_s=r * res.gs_mol_m2_s,
                vc_umol_m2_s=r * res.vc_umol_m2_s,
                vj_umol_m2_s=r * res.vj_umol_m2_s,
                rd_umol_m2_s=r * res.rd_umol_m2_s,
                converged=res.converged & within,
            )
        return LeafResponse(r * out.an, out.dan_dq, out.converged & within, res)

    return profiled


def an_noise_bias(
    q,
    q_mc_sd,
    forcing: Forcing,
    params: PhotosynthesisParams,
    leaf: LeafPhotosynthesis = exact_leaf,
    nodes: int = 9,
) -> jax.Array:
    r"""Expected shift of leaf An caused by Monte Carlo noise in its absorbed PAR, µmol m⁻² s⁻¹, (T, B).

    A blade's rendered PAR is :math:`\hat q = q + \varepsilon` with :math:`\varepsilon \sim
    N(0, \sigma^2)`; An is concave in q (light saturation), so by Jensen's inequality the
    rendered An is low on average: :math:`E[A(q + \varepsilon)] - A(q) \approx \tfrac12 A''(q)
    \sigma^2 < 0`. Estimated at :math:`\hat q` by Gauss–Hermite quadrature over the noise,

    .. math::

        b = \sum_i w_i\,A(\min(\max(\hat q + x_i\sigma, 0), q_{max})) - A(\hat q),

    with the ``nodes`` probabilists' Gauss–Hermite nodes :math:`x_i` and weights :math:`w_i`
    (normalised to sum 1) and :math:`q_{max}` the leaf solve's upper limit,
    :data:`~lightfit.photosynthesis.MAX_PAR_ABS_UMOL_M2_S` (a light-saturated leaf). Nine nodes,
    not three: where the noise straddles the switch from electron-transport to Rubisco
    limitation, An has a kink and a three-point rule overstates the bias (−0.19 against −0.14
    µmol m⁻² s⁻¹ brute-force at 1 600 ± 400 µmol m⁻² s⁻¹; nine nodes: −0.13; tests/test_model.py).
    The bias falls as 1/K with K samples per segment, while the
    canopy's Monte Carlo SD, the spread of a sum over many blades, falls only as 1/√K and is much
    smaller: summed over the blades the bias can exceed it (docs/model.md, "Monte Carlo bias of
    canopy An"). :math:`A(\hat q) - b` removes it to second order.

    Args:
        q, q_mc_sd: (T, B) absorbed PAR of every blade and its Monte Carlo SD, µmol m⁻² s⁻¹.
        forcing, params: the steps' weather and the photosynthesis parameters.
        leaf: the leaf photosynthesis (:func:`exact_leaf` or :func:`tabulated_leaf`).
        nodes: quadrature nodes (odd: the middle one is :math:`\hat q` itself).
    """
    x, w = np.polynomial.hermite_e.hermegauss(int(nodes))
    w = w / w.sum()
    q = jnp.maximum(jnp.asarray(q, jnp.float64), 0.0)
    sd = jax.lax.stop_gradient(jnp.asarray(q_mc_sd, jnp.float64))
    at_q = leaf(q, forcing, params).an
    # The middle node of an odd rule is q itself: solved once.
    # The nodes are held to the leaf solve's range [0, MAX_PAR_ABS_UMOL_M2_S]: a noisy blade (few
    # projected rays per m²) put its top node q + 4.5σ above 1e4 and a rendered run then failed here,
    # naming the solver's internal par_abs_umol_m2_s; the leaf is light-saturated up there.
    mean = sum(
        float(wi)
        * (at_q if xi == 0 else leaf(jnp.clip(q + float(xi) * sd, 0.0, MAX_PAR_ABS_UMOL_M2_S), forcing, params).an)
        for xi, wi in zip(x, w)
    )
    return mean - at_q


def tabulated_leaf(n_grid: int = 64) -> LeafPhotosynthesis:
    r"""Leaf photosynthesis tabulated per step on ``n_grid`` absorbed-PAR values.

    Within a step all blades share air temperature, CO2, humidity and pressure, so An depends on
    the blade only through q. It is solved exactly at :math:`q_g = q_{max}(g/(G-1))^2` (dense at
    low light) and interpolated linearly in :math:`\sqrt q`, as is dAn/dq. A step's blades count
    as converged only where every grid point of the step did (and their own light is finite).
    """

    def leaf(q, forcing: Forcing, params: PhotosynthesisParams) -> LeafResponse:
        G = n_grid
        qmax = jnp.maximum(jnp.max(q, axis=1), 1e-6) * (1.0 + 1e-9)  # (T,)
        g = jnp.linspace(0.0, 1.0, G)
        # The top point stays in the solver's range when the brightest blade is at its limit (the
        # factor above would put it 1e-9 beyond); blades beyond the limit are not converged.
        q_grid = jnp.minimum(qmax[:, None] * g[None, :] ** 2, MAX_PAR_ABS_UMOL_M2_S)
        res, dan_g = _solve_with_slope(q_grid, forcing, params)
        r = jnp.clip(q / qmax[:, None], 0.0, 1.0)
        # sqrt has an infinite slope at 0: dark blades (night steps, q = 0) would send inf·0 = NaN
        # into the cotangent of qmax and from there into the implicit solve. Their interpolation
        # coordinate is constant 0, so it gets a zero derivative.
        x = sqrt_or_zero(r) * (G - 1)
        i = jnp.clip(jnp.floor(x).astype(jnp.int32), 0, G - 2)
        frac = x - i
        take = jax.vmap(lambda a, j: a[j])

        def interp(table):
            return (1 - frac) * take(table, i) + frac * take(table, i + 1)

        step_converged = jnp.all(res.converged, axis=1, keepdims=True)  # (T, 1)
        within = jnp.isfinite(q) & (q <= MAX_PAR_ABS_UMOL_M2_S)
        return LeafResponse(interp(res.an_umol_m2_s), interp(dan_g), step_converged & within)

    return leaf


# -- the operator -------------------------------------------------------------------------


@dataclass(frozen=True)
class ObservationOperator:
    """The fixed inputs of one model's observation operator; call it on light parts and θ.

    Attributes:
        forcing: per-step weather (:class:`~lightfit.model.scenario.Forcing`).
        area_m2: (S,) one-sided areas of the measured segments; ``is_blade`` (S,) leaf blades.
        par_kind: ``"incident"`` or ``"absorbed"`` PAR for the plant-PAR observables.
        denominator_m2: area canopy An refers to (:func:`an_denominator`).
        params: the photosynthesis parameter set (Vcmax scaled by θ's ``vcmax_scale``).
        ground_area_m2: ground area of the measured plants (APAR, NEE), m².
        sun_elevation_deg: (T,) sun elevation of every step (the above-canopy sensor), degrees.
        soil_respiration_umol_m2_s, soil_respiration_q10: the soil's respiration at 10 °C (R₁₀,
            µmol m⁻² ground s⁻¹) and its Q₁₀, added at each step's air temperature to the chamber
            NEE (:func:`soil_respiration`, :func:`chamber_nee`).
        sensors: names of the virtual sensors (:mod:`lightfit.light.sensors`) whose parts follow the
            S segments' as the last columns of the light parts (the first, a ceptometer on the
            soil, gives the ``transmitted_par`` and ``ceptometer_*`` observables). Parts without
            those columns (e.g. zero daytime steps) give NaN there (0 when no step is lit).
        capacity: (B,) each blade's photosynthetic capacity per area relative to the parameter
            set's (:mod:`lightfit.photosynthesis.canopy`, dimensionless); ``None``: every blade the
            set's. Applied to whatever leaf evaluator the operator is called with (:meth:`leaf`).
        capacity_base: the base leaf's capacity of :func:`with_capacity` (≤ every blade's; the
            whole canopy's bottom, so that tiles measuring other blades compute alike).
        segment_id: (S,) the measured segments' ids (results' ``segment``) and ``times`` (T,) the
            steps' instants: where a refusal of a blade's light says which blade and step (``None``:
            their indices).
    """

    forcing: Forcing
    area_m2: np.ndarray
    is_blade: np.ndarray
    par_kind: str
    denominator_m2: float
    params: PhotosynthesisParams
    ground_area_m2: float
    sun_elevation_deg: np.ndarray
    soil_respiration_umol_m2_s: float = SOIL_RESPIRATION_UMOL_M2_S
    soil_respiration_q10: float = SOIL_RESPIRATION_Q10
    sensors: tuple[str, ...] = ()
    capacity: np.ndarray | None = None
    capacity_base: float | None = None
    segment_id: np.ndarray | None = None
    times: pd.DatetimeIndex | None = None

    @property
    def blades(self) -> np.ndarray:
        return np.flatnonzero(self.is_blade)

    def light(self, values, se, kind: str, light_factor, rows: Sequence[str] = PARTS):
        """PAR of ``kind`` at every segment and step and its Monte Carlo SD, each (T, S).

        ``values``/``se``: (T_day, len(rows), S) parts per unit DNI / DHI named by ``rows`` (S: every
        column, segments and sensors).
        """
        fc = self.forcing
        day = np.flatnonzero(fc.day)
        f = jnp.asarray(light_factor, jnp.float64)
        dni, dhi = (f * jnp.asarray(x[day])[:, None] for x in (fc.dni_par, fc.dhi_par))
        sun, sky = rows.index(f"{kind}_sun"), rows.index(f"{kind}_sky")
        x = dni * values[:, sun] + dhi * values[:, sky]
        # The parts' errors taken as independent: with the direct light projected (the default) sun and
        # sky come from separate rays, and their replicate correlation has median 0.000 over segments
        # (25-plant cell, K = 32, suns at 50° and 15°); the estimated covariance would add only its noise.
        sd = sqrt_or_zero((dni * se[:, sun]) ** 2 + (dhi * se[:, sky]) ** 2)  # 0: a segment without error
        zeros = jnp.zeros((len(fc.day), values.shape[-1]))
        return zeros.at[day].set(x), zeros.at[day].set(sd)

    def leaf(self, leaf: LeafPhotosynthesis = exact_leaf) -> LeafPhotosynthesis:
        """``leaf`` evaluated for these blades' capacities (:func:`with_capacity`)."""
        return with_capacity(leaf, self.capacity, self.capacity_base)

    def photosynthesis_params(self, vcmax_scale) -> PhotosynthesisParams:
        p = self.params
        scaled = p.fvcb.vcmax_ref_umol_m2_s * jnp.asarray(vcmax_scale, jnp.float64)
        return eqx.tree_at(lambda q: q.fvcb.vcmax_ref_umol_m2_s, p, scaled)

    def __call__(
        self, values, se, theta: Theta, *, rows: Sequence[str] = PARTS, leaf: LeafPhotosynthesis = exact_leaf
    ) -> dict:
        """Observables and per-segment fields from light parts at ``theta``.

        Returns the :data:`OBSERVABLES` (T,), per segment (T, S) ``<kind>_par_umol_m2_s`` and
        ``<kind>_par_mc_sd_umol_m2_s`` for each kind whose parts are in ``rows``, per blade (T, B)
        ``leaf_an_umol_m2_s`` and ``leaf_an_mc_sd_umol_m2_s``, ``blade_index`` (B,),
        ``unconverged_blades`` (T,) int, the blades whose photosynthesis did not converge
        (:data:`CONVERGENCE_KEY`; nonzero: never trust that step's An; every blade where a traced
        ``theta`` lies outside its domain, :func:`~lightfit.model.parameters.outside_domain`), and ``photosynthesis``
        (the full result on the blades, or None for a tabulated ``leaf``).
        """
        kinds = [k for k in ("incident", "absorbed") if f"{k}_sun" in rows and f"{k}_sky" in rows]
        out = {}
        S = len(self.area_m2)
        with_sensors = bool(self.sensors) and values.shape[-1] == S + len(self.sensors)
        sensor = None
        for k in kinds:
            x, sd = self.light(values, se, k, theta.light_factor, rows)
            out[f"{k}_par_umol_m2_s"], out[f"{k}_par_mc_sd_umol_m2_s"] = x[:, :S], sd[:, :S]
            if k == "incident" and with_sensors:
                sensor = (x[:, S], sd[:, S])  # the ceptometer: a sensor reads incident PAR
        if sensor is None and not (self.sensors and values.shape[0] == 0):
            sensor = (None, None)  # no ceptometer columns: NaN observables
        elif sensor is None:  # no daytime step: nothing lit, nothing read
            sensor = (jnp.zeros(len(self.forcing.day)),) * 2
        b = self.blades
        q = jnp.maximum(out["absorbed_par_umol_m2_s"][:, b], 0.0)
        _check_leaf_light(
            q,
            theta.light_factor,
            out["absorbed_par_mc_sd_umol_m2_s"][:, b],
            segment_id=None if self.segment_id is None else np.asarray(self.segment_id)[b],
            times=self.times,
        )
        r = self.leaf(leaf)(q, self.forcing, self.photosynthesis_params(theta.vcmax_scale))
        an_sd = jax.lax.stop_gradient(jnp.abs(r.dan_dq)) * out["absorbed_par_mc_sd_umol_m2_s"][:, b]
        f = jnp.asarray(theta.light_factor, jnp.float64)
        above = above_canopy_par(
            jnp.asarray(self.forcing.dni_par), jnp.asarray(self.forcing.dhi_par), jnp.asarray(self.sun_elevation_deg), f
        )
        out |= observables(
            out[f"{self.par_kind}_par_umol_m2_s"],
            out[f"{self.par_kind}_par_mc_sd_umol_m2_s"],
            self.area_m2,
            r.an,
            an_sd,
            self.area_m2[b],
            self.denominator_m2,
            absorbed=out["absorbed_par_umol_m2_s"],
            absorbed_mc_sd=out["absorbed_par_mc_sd_umol_m2_s"],
            ground_area_m2=self.ground_area_m2,
            above_par=above,
            soil_respiration_umol_m2_s=soil_respiration(
                self.soil_respiration_umol_m2_s, self.soil_respiration_q10, self.forcing.tair_c
            ),
            transmitted=sensor[0],
            transmitted_mc_sd=None if sensor[1] is None else jax.lax.stop_gradient(sensor[1]),
            rendered=self.forcing.day,
        )
        out |= {
            "leaf_an_umol_m2_s": r.an,
            "leaf_an_mc_sd_umol_m2_s": an_sd,
            "blade_index": b,
            # a traced θ outside its domain (concrete ones are refused): no blade's value holds
            CONVERGENCE_KEY: jnp.where(outside_domain(theta), max(len(b), 1), jnp.sum(~r.converged, axis=1)),
            "photosynthesis": r.result,
        }
        return out


def _check_leaf_light(q, light_factor, sd=None, segment_id=None, times=None) -> None:
    """Concrete blade light above what a leaf solve accepts (:data:`MAX_PAR_ABS_UMOL_M2_S`) is refused
    naming the light factor, the run's one multiplier of light (``--theta light_factor=9`` ended in a
    traceback from the photosynthesis's range check); or, where the light at light factor 1 is itself
    above it, naming the render's Monte Carlo noise (``sd``: the blades' SD, µmol m-2 s-1, as ``q``)
    and the options that reduce it: few projected rays put one ray's flux on a small blade, named by
    its segment id (``segment_id``: (B,) the blades', as results' ``segment``) and its step's
    instant (``times``: (T,), told in UTC as results' ``time``), not by its index among the blade
    columns. Traced values (calibration, sampling) are flagged unconverged there instead, which
    gives them no likelihood."""
    if isinstance(q, jax.core.Tracer) or isinstance(light_factor, jax.core.Tracer) or not q.size:
        return
    top = float(jnp.max(q))
    factor = float(light_factor)
    if top > MAX_PAR_ABS_UMOL_M2_S and top / factor > MAX_PAR_ABS_UMOL_M2_S:
        at = np.unravel_index(int(jnp.argmax(q)), q.shape)
        noise = "" if sd is None else f" ± {float(np.asarray(sd)[at]):.0f} (its Monte Carlo SD)"
        step = f"step {at[0]}"
        if times is not None and len(times) == q.shape[0]:
            t = pd.DatetimeIndex(times)[at[0]]
            t = t.tz_convert("UTC").tz_localize(None) if t.tzinfo is not None else t
            step += f", time {t.isoformat()} UTC"
        blade = f"blade column {at[1]}" if segment_id is None else f"segment {int(np.asarray(segment_id)[at[1]])}"
        raise InputError(
            f"the render gives a blade {top / factor:.0f}{noise} µmol m-2 s-1 of absorbed PAR at light_factor=1"
            f" ({step}, {blade}): Monte Carlo noise, one ray's flux on a small blade",
            parameter="direct_rays_per_m2",
            expected=f"at most {MAX_PAR_ABS_UMOL_M2_S:g} µmol m-2 s-1 (about 4x full sun): a less noisy render,"
            " more projected rays (--direct-rays-per-m2) or more points per segment (--samples)",
        )
    if top > MAX_PAR_ABS_UMOL_M2_S:
        raise InputError(
            f"light_factor={float(light_factor):g} gives the blades up to {top:.0f} µmol m-2 s-1 of absorbed PAR",
            parameter="theta",
            expected=f"at most {MAX_PAR_ABS_UMOL_M2_S:g} µmol m-2 s-1 (about 4x full sun): a smaller light_factor",
        )


def mc_covariance(
    operator: ObservationOperator,
    values,
    se,
    theta: Theta,
    keys: Sequence[str],
) -> np.ndarray:
    r"""Monte Carlo covariance of the observables ``keys`` across time steps and across each other.

    The renderer draws the same random numbers for a segment at every time step (frozen
    sampling, :class:`~lightfit.light.estimator.SegmentEstimator`), so its errors are not
    independent in time. Measured on the quick field (6 render seeds, 500 segments; docs/posterior.md
    "Monte Carlo covariance"): a segment's sky parts are *identical* at every step (isotropic sky,
    same rays), so their error is one number per segment for the whole day; its sun-part errors
    at different steps are nearly uncorrelated (pooled correlation 0.12 at 30 min, 0.06 at 1 h,
    < 0.02 beyond: ignored here), sun and sky errors are taken as uncorrelated (a segment's are
    mostly negatively correlated, median −0.1 with the projected direct light, −0.3 with the paths'
    in a finite field, :attr:`~lightfit.light.estimator.Irradiance.cov`: so this covariance and
    the ``*_mc_sd_*`` overstate the error a little), and incident and absorbed
    parts of a segment err together (correlation 1.000). Segments have independent streams. With
    :math:`g_{k,t,s}` the derivative of observable k at step t by the parts of segment s (one
    reverse-mode pass per key; an observable at step t depends on that step's parts only), the
    linearised errors are :math:`e_{k,t} = \sum_s G_{k,t,s} z_s + \sum_s H_{k,t,s} z'_{s,t}`
    with independent standard normal z, sky loadings :math:`G = \sum_{sky\ rows} g\,se` and sun
    loadings :math:`H = \sum_{sun\ rows} g\,se`, hence

    .. math::

        \Sigma^{MC}_{(k,t),(l,t')} = \sum_s G_{k,t,s} G_{l,t',s}
            + \delta_{tt'} \sum_s H_{k,t,s} H_{l,t,s}.

    Its diagonal is the square of the observables' ``*_mc_sd_*`` (same linearisation of the leaf
    photosynthesis, the exact leaf's). Args: the operator, light parts ``values``/``se``
    (T_day, len(PARTS), S) in the order of :data:`PARTS`, θ, observable names ``keys`` (e.g.
    ``"plant_par_umol_m2_s"``). Returns a numpy array
    (len(keys)·T, len(keys)·T), blocks of T steps in the order of ``keys`` (night rows zero).
    """
    se = np.asarray(se, np.float64)
    sej = jnp.asarray(se)

    def f(v):
        o = operator(v, sej, theta)
        return jnp.stack([jnp.asarray(o[k], jnp.float64) for k in keys])

    out, pullback = jax.vjp(f, jnp.asarray(values, jnp.float64))
    sky = [i for i, r in enumerate(PARTS) if r.endswith("_sky")]
    sun = [i for i, r in enumerate(PARTS) if r.endswith("_sun")]
    day = np.flatnonzero(operator.forcing.day)
    n, T, S = len(keys), len(operator.forcing.day), se.shape[-1]
    G, H = np.zeros((n, T, S)), np.zeros((n, T, S))
    for i in range(n):
        (g,) = pullback(jnp.zeros_like(out).at[i].set(1.0))
        g = np.asarray(g) * se
        G[i, day], H[i, day] = g[:, sky].sum(1), g[:, sun].sum(1)
    Gm = G.reshape(n * T, S)
    cov = Gm @ Gm.T
    for t in day:
        block = H[:, t] @ H[:, t].T
        idx = np.arange(n) * T + t
        cov[np.ix_(idx, idx)] += block
    return cov


__all__ = [
    "CONVERGENCE_KEY",
    "OBSERVABLES",
    "SOIL_RESPIRATION_UMOL_M2_S",
    "LeafPhotosynthesis",
    "LeafResponse",
    "ObservationOperator",
    "above_canopy_par",
    "an_denominator",
    "area_total",
    "canopy_an",
    "canopy_apar",
    "ceptometer_fapar",
    "ceptometer_transmittance",
    "chamber_nee",
    "exact_leaf",
    "with_capacity",
    "fapar",
    "mc_covariance",
    "observables",
    "plant_par",
    "tabulated_leaf",
    "unconverged",
]
