r"""Leaf photosynthesis per segment: FvCB + stomata + boundary layer, solved per segment.

For the coupled closures (``"tuzet"``, ``"leuning"``, ``"medlyn"``) the unknown is the chloroplast CO2
mole fraction :math:`c_c` (equal to :math:`c_i` without mesophyll resistance). Given
:math:`c_c` every other quantity is explicit:

.. math::
    A_n = \min(V_c(c_c), V_j(c_c)) - R_d \ (\text{above } \Gamma^*),\quad
    c_s = c_a - A_n/g_b,\quad g_s = g_s(A_n, c_s, D),\quad c_i = c_c + A_n/g_m,

and the segment is at steady state when the demand equals the diffusive supply through
the three conductances in series:

.. math:: r(c_c) = A_n(c_c) - g_{tot}(c_c)\,(c_a - c_c) = 0,\qquad
          g_{tot} = (1/g_s + 1/g_b + 1/g_m)^{-1}.

Because :math:`g_s \ge g_0 > 0` and :math:`A_n \ge -R_d` for :math:`c_c \ge \Gamma^*`,
:math:`r \le 0` at :math:`lo = \min(\Gamma^*, c_a)` and :math:`r \ge 0` at
:math:`hi = \max(\Gamma^*, c_a) + R_d / g_{tot,min}` with
:math:`g_{tot,min} = (1/g_0 + 1/g_b + 1/g_m)^{-1}`: a bracket exists for every input, and
:func:`.solver.bracketed_newton` converges on it. Derivatives of the root follow from the
implicit function theorem, :math:`dc_c/d\theta = -(\partial r/\partial c_c)^{-1}\partial
r/\partial\theta`, through optimistix's :class:`~optimistix.ImplicitAdjoint` with a
diagonal (per-segment) linear solve; the loop itself is never differentiated.

The ``"cplantbox"`` closure is CPlantBox's Tuzet variant, where ci follows in closed form
from the leaf-surface CO2 (see :func:`.stomata.cplantbox_intercellular_co2`); it needs no
iteration.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import optimistix as optx
from jax.typing import ArrayLike

from lightfit.defaults import DEFAULT_PARAMETER_SET
from lightfit.errors import InputError

from .constants import REFERENCE_PRESSURE_KPA, ZERO_CELSIUS_K
from .fvcb import LeafCapacities, assimilation, capacity_temperature_factors, leaf_capacities, limits
from .parameters import (
    OVERRIDABLE,
    PhotosynthesisParams,
    cast_params,
    check_params,
    parameter_set,
    params_in_domain,
    replaced,
    value_of,
)
from .solver import SolverConfig, bracketed_newton, fixed_point_iteration
from .stomata import (
    cplantbox_conductance,
    cplantbox_intercellular_co2,
    leuning_conductance,
    medlyn_conductance,
    tuzet_conductance,
    vapour_pressure_deficit_kpa,
)

#: Value of :attr:`PhotosynthesisResult.limitation` where Fc ≤ Fj (Rubisco-limited).
RUBISCO_LIMITED = 0
#: Value of :attr:`PhotosynthesisResult.limitation` where Fj < Fc (electron-transport-limited).
ELECTRON_TRANSPORT_LIMITED = 1


class Environment(NamedTuple):
    """Per-segment drivers after validation (arrays of one float dtype).

    Attributes:
        par_abs_umol_m2_s: absorbed PAR [µmol m⁻² s⁻¹].
        tleaf_c: leaf temperature [°C].
        co2_umol_mol: CO2 in air (or at the leaf surface without boundary layer) [µmol mol⁻¹].
        vpd_kpa: leaf-to-air vapour pressure deficit [kPa].
        pair_kpa: air pressure [kPa].
        gb_mol_m2_s: boundary-layer conductance to CO2 [mol m⁻² s⁻¹] (``inf`` = none).
        fw: water-stress factor [-].
        rh: relative humidity as given [0–1], ``None`` where not given; kept only for the
            range flag of :func:`solve` under ``jit`` (the model uses ``vpd_kpa``).
    """

    par_abs_umol_m2_s: jax.Array
    tleaf_c: jax.Array
    co2_umol_mol: jax.Array
    vpd_kpa: jax.Array
    pair_kpa: jax.Array
    gb_mol_m2_s: jax.Array
    fw: jax.Array
    rh: jax.Array | None = None


class PhotosynthesisResult(NamedTuple):
    """Per-segment outputs (arrays of the broadcast input shape).

    Attributes:
        an_umol_m2_s: net CO2 assimilation An [µmol m⁻² s⁻¹].
        gs_mol_m2_s: stomatal conductance to CO2 [mol m⁻² s⁻¹] (×1.6 for water vapour).
        ci_umol_mol: intercellular CO2 [µmol mol⁻¹].
        cs_umol_mol: CO2 at the leaf surface [µmol mol⁻¹].
        cc_umol_mol: chloroplast CO2 (= ci without mesophyll resistance) [µmol mol⁻¹].
        vc_umol_m2_s: Rubisco-limited gross rate Vc (CPlantBox "Fc") [µmol m⁻² s⁻¹].
        vj_umol_m2_s: electron-transport-limited gross rate Vj ("Fj") [µmol m⁻² s⁻¹].
        rd_umol_m2_s: day respiration Rd [µmol m⁻² s⁻¹].
        limitation: :data:`ELECTRON_TRANSPORT_LIMITED` (1) where Fj < Fc, else
            :data:`RUBISCO_LIMITED` (0).
        converged: True where the steady state was found to tolerance and all inputs and
            outputs are finite; never trust a value where this is False.
        iterations: solver iterations used (0 for the closed-form ``"cplantbox"`` closure).
    """

    an_umol_m2_s: jax.Array
    gs_mol_m2_s: jax.Array
    ci_umol_mol: jax.Array
    cs_umol_mol: jax.Array
    cc_umol_mol: jax.Array
    vc_umol_m2_s: jax.Array
    vj_umol_m2_s: jax.Array
    rd_umol_m2_s: jax.Array
    limitation: jax.Array
    converged: jax.Array
    iterations: jax.Array


# --------------------------------------------------------------------------- coupled closure


def _stomatal_conductance(an, cs, leaf: LeafCapacities, env: Environment, params: PhotosynthesisParams):
    s = params.stomata
    if s.model == "tuzet":
        return tuzet_conductance(an, cs, leaf.gamma_star_umol_mol, s.g0_mol_m2_s, s.a1, env.fw)
    if s.model == "leuning":
        return leuning_conductance(an, cs, leaf.gamma_star_umol_mol, env.vpd_kpa, s.g0_mol_m2_s, s.a1, s.d0_kpa, env.fw)
    if s.model == "medlyn":
        return medlyn_conductance(an, cs, env.vpd_kpa, s.g0_mol_m2_s, s.a1, env.fw)
    raise ValueError(f"stomatal model {s.model!r} has no coupled form")


def _tie_takes_vc(c, leaf: LeafCapacities, env: Environment, params: PhotosynthesisParams) -> jax.Array:
    """Which rate to take where Vc = Vj (at zero capacity, both 0; see :func:`.fvcb.assimilation`).

    At a small common scale s of Vcmax_ref, Vc ≈ s·Vcmax_ref·f_v·(c − Γ*)/(c + Km) and, in light
    (alpha·Q > 0, where J ≈ Jmax as Jmax → 0), Vj ≈ s·a3·Vcmax_ref·f_j/4·(c − Γ*)/(c + 2Γ*); in
    the dark Vj = 0. Take Vc where it is the smaller of the two.
    """
    f = params.fvcb
    f_v, f_j = capacity_temperature_factors(env.tleaf_c + ZERO_CELSIUS_K, params.temperature)
    lit = f.quantum_yield * env.par_abs_umol_m2_s > 0
    return lit & (4.0 * f_v * (c + 2.0 * leaf.gamma_star_umol_mol) <= f.jmax_to_vcmax * f_j * (c + leaf.km_umol_mol))


class _Fluxes(NamedTuple):
    an: jax.Array
    vc: jax.Array
    vj: jax.Array
    cs: jax.Array
    gs: jax.Array
    ci: jax.Array
    gtot: jax.Array


def _fluxes(cc, leaf: LeafCapacities, env: Environment, params: PhotosynthesisParams) -> _Fluxes:
    an, vc, vj = assimilation(cc, leaf, params.fvcb.clip_rates, _tie_takes_vc(cc, leaf, env, params))
    cs = env.co2_umol_mol - an / env.gb_mol_m2_s
    gs = _stomatal_conductance(an, cs, leaf, env, params)
    gtot = 1.0 / (1.0 / gs + 1.0 / env.gb_mol_m2_s + 1.0 / params.fvcb.gm_mol_m2_s)
    ci = cc + an / params.fvcb.gm_mol_m2_s
    return _Fluxes(an, vc, vj, cs, gs, ci, gtot)


def co2_balance_residual(
    cc_umol_mol: jax.Array, leaf: LeafCapacities, env: Environment, params: PhotosynthesisParams
) -> jax.Array:
    """Steady-state residual r(cc) = An − g_tot·(ca − cc) [µmol m⁻² s⁻¹] (see module doc)."""
    f = _fluxes(cc_umol_mol, leaf, env, params)
    return f.an - f.gtot * (env.co2_umol_mol - cc_umol_mol)


def _residual_fn(cc, args):
    leaf, env, params = args
    return co2_balance_residual(cc, leaf, env, params)


def _residual_scale(cc, args):
    """Flux scale of the residual [µmol m⁻² s⁻¹]: |An| + Rd + |g_tot·(ca − cc)|, the size of
    the terms whose difference is r (see :class:`.solver.SolverConfig`)."""
    leaf, env, params = args
    f = _fluxes(cc, leaf, env, params)
    return jnp.abs(f.an) + jnp.abs(leaf.rd_umol_m2_s) + jnp.abs(f.gtot * (env.co2_umol_mol - cc))


def _fixed_point_map(cc, args):
    leaf, env, params = args
    f = _fluxes(cc, leaf, env, params)
    return env.co2_umol_mol - f.an / f.gtot


def _bracket(leaf: LeafCapacities, env: Environment, params: PhotosynthesisParams):
    gamma = leaf.gamma_star_umol_mol
    ca = env.co2_umol_mol
    gtot_min = 1.0 / (1.0 / params.stomata.g0_mol_m2_s + 1.0 / env.gb_mol_m2_s + 1.0 / params.fvcb.gm_mol_m2_s)
    lo = jnp.minimum(gamma, ca)
    top = jnp.maximum(gamma, ca)
    # Slack guards the sign of r(hi) against rounding; it only widens the bracket.
    hi = top + 1.001 * jnp.maximum(leaf.rd_umol_m2_s, 0.0) / gtot_min + 1e-3 * (1.0 + top)
    x0 = jnp.where(ca > gamma, gamma + 0.7 * (ca - gamma), 0.5 * (lo + jnp.minimum(hi, 2.0 * top)))
    return lo, hi, x0


def _primal(inputs):
    leaf, env, params, config, _ = inputs
    lo, hi, x0 = _bracket(leaf, env, params)
    res = bracketed_newton(_residual_fn, x0, lo, hi, (leaf, env, params), config, _residual_scale)
    return res.x, (res.converged, res.iterations)


def _rewrite(root, aux, inputs):
    del aux
    leaf, env, params, _, _ = inputs
    return co2_balance_residual(root, leaf, env, params)


def _broadcast_leaf(leaf: LeafCapacities, env: Environment) -> LeafCapacities:
    shape = jnp.broadcast_shapes(*(jnp.shape(x) for x in (*leaf, *env) if x is not None))
    return LeafCapacities(*(jnp.broadcast_to(x, shape) for x in leaf))


def _in_range(env: Environment) -> jax.Array:
    """Elementwise: every driver inside the range :func:`prepare_environment` checks eagerly
    (:data:`INPUT_RANGES`); False for NaN. Under ``jit`` those checks cannot run."""
    ok = [(getattr(env, name) >= lo) & (getattr(env, name) <= hi) for name, (lo, hi, _) in INPUT_RANGES.items()]
    if env.rh is not None:
        lo, hi, _ = RH_RANGE
        ok.append((env.rh >= lo) & (env.rh <= hi))
    return jnp.all(jnp.stack(jnp.broadcast_arrays(*ok)), axis=0)


def _finish(
    cc,
    f: _Fluxes,
    leaf: LeafCapacities,
    env: Environment,
    params: PhotosynthesisParams,
    converged,
    iterations,
    check_gamma_rubisco: bool = True,
) -> PhotosynthesisResult:
    # Inputs too: under jit the range checks are skipped, and a NaN light falls through the
    # comparisons of the light response as darkness, giving a finite, "converged" An; a
    # finite out-of-range input (T = -300 °C, PAR < 0, rh > 1) is flagged by _in_range, and a
    # parameter outside its domain (a NaN quantum yield gave the dark An, converged) by
    # params_in_domain.
    # (gb = inf means no boundary layer; Γ' = inf where Rd ≥ Vcmax, which only the
    # "cplantbox" closure uses.)
    if not check_gamma_rubisco:
        leaf = leaf._replace(gamma_rubisco_umol_mol=0.0)
    drivers = env._replace(gb_mol_m2_s=1.0 / env.gb_mol_m2_s, rh=None)
    checked = (f.an, f.gs, f.ci, f.cs, cc, f.vc, f.vj, *leaf, *(d for d in drivers if d is not None))
    finite = jnp.all(jnp.stack([jnp.isfinite(o) for o in jnp.broadcast_arrays(*checked)]), axis=0)
    finite = finite & _in_range(env) & params_in_domain(params)
    vj_limits = limits(cc, leaf.gamma_star_umol_mol, f.vj, f.vc)  # ties: Rubisco, as always
    limitation = jnp.where(vj_limits, ELECTRON_TRANSPORT_LIMITED, RUBISCO_LIMITED).astype(jnp.int8)
    return PhotosynthesisResult(
        an_umol_m2_s=f.an,
        gs_mol_m2_s=f.gs,
        ci_umol_mol=f.ci,
        cs_umol_mol=f.cs,
        cc_umol_mol=cc,
        vc_umol_m2_s=f.vc,
        vj_umol_m2_s=f.vj,
        rd_umol_m2_s=leaf.rd_umol_m2_s + 0.0 * f.an,
        limitation=limitation,
        converged=converged & finite,
        iterations=iterations,
    )


def _solve_cplantbox(leaf: LeafCapacities, env: Environment, params: PhotosynthesisParams) -> PhotosynthesisResult:
    s = params.stomata
    # No compensation point where Rd >= Vcmax (Γ' = inf): those elements are NaN and flagged, and
    # the arithmetic runs on a finite Γ' so that their zero cotangents stay zero (inf made the
    # gradient of a parameter shared with other elements NaN, even with them masked out).
    has = jnp.isfinite(leaf.gamma_rubisco_umol_mol)
    safe = leaf._replace(gamma_rubisco_umol_mol=jnp.where(has, leaf.gamma_rubisco_umol_mol, 0.0))
    ci = cplantbox_intercellular_co2(env.co2_umol_mol, safe.gamma_rubisco_umol_mol, s.a1, env.fw)
    an, vc, vj = assimilation(ci, safe, params.fvcb.clip_rates, _tie_takes_vc(ci, safe, env, params))
    gs = cplantbox_conductance(an, safe.rd_umol_m2_s, ci, safe.gamma_rubisco_umol_mol, s.g0_mol_m2_s, s.a1, env.fw)
    an, vc, vj, gs, ci = (jnp.where(has, x, jnp.nan) for x in (an, vc, vj, gs, ci))
    cs = env.co2_umol_mol + 0.0 * an
    f = _Fluxes(an, vc, vj, cs, gs, ci, gs)
    zeros = jnp.zeros(jnp.shape(an), jnp.int32)
    return _finish(ci, f, leaf, env, params, jnp.ones(jnp.shape(an), bool), zeros)


#: The driver an element's solve runs on where its own is NaN, infinite or out of range
#: (:func:`_guarded`): inside every range of :data:`INPUT_RANGES`.
_STAND_IN = {
    "par_abs_umol_m2_s": 0.0,
    "tleaf_c": 25.0,
    "co2_umol_mol": 400.0,
    "vpd_kpa": 1.0,
    "pair_kpa": REFERENCE_PRESSURE_KPA,
    "gb_mol_m2_s": np.inf,
    "fw": 1.0,
}


#: Largest Vcmax_ref (µmol m⁻² s⁻¹) a solve takes as it is: beyond ≈ 1e153 Vcmax·ci overflows float64 in
#: the coupled closures, and the gradient through such a solve raised lineax's non-finite-input error
#: (an optimiser's exp(z) reaches it: a Vcmax scale of 1e200). Above it the elements are flagged
#: and solved at the stand-ins (:func:`_guarded`): 1e100 is 96 orders of magnitude above any leaf.
MAX_SOLVED_VCMAX_UMOL_M2_S = 1e100
#: The same limit for a float32 solve [µmol m⁻² s⁻¹]: Vcmax·ci overflows float32 from a Vcmax_ref of
#: ≈ 1e20 (the default set: converged at 1e19, NaN and a gradient that raised lineax's error at 1e25);
#: float32's own largest number (3.4e38), the limit before, let those through. 1e12 is 8 orders of
#: magnitude above any leaf and 2 below the overflow for a g0 as small as 1e-9 mol m⁻² s⁻¹
#: (ci ≈ Rd/g0: Vcmax·ci ≈ 0.015·Vcmax²/g0 reaches 3.4e38 at Vcmax ≈ 1.5e14).
MAX_SOLVED_VCMAX_FLOAT32_UMOL_M2_S = 1e12


@functools.cache
def _stand_in_values() -> dict[str, float]:
    """The numbers a parameter set's solve runs on where its own are outside their domain
    (:func:`_guarded`): the default set's, inside every domain whatever the closure."""
    ref = parameter_set(DEFAULT_PARAMETER_SET)
    return {n: float(value_of(ref, n)) for n in OVERRIDABLE}


def _guarded(env: Environment, params: PhotosynthesisParams) -> tuple[Environment, PhotosynthesisParams, jax.Array]:
    """The drivers with a stand-in wherever an element's own is NaN, infinite or out of range, the
    parameters with the default set's numbers where any of theirs is outside its domain
    (:func:`~.parameters.params_in_domain`, traced values that :func:`~.parameters.check_params`
    could not refuse), and where both were in range. Those elements are solved at the stand-ins and
    flagged (:func:`_masked`): the ``where`` keeps their arithmetic, and so the implicit adjoint's
    linear solve, finite (a NaN or infinite light, or a NaN Vcmax, made ``jax.grad`` raise in
    lineax's check, though the value was flagged), and their cotangents 0. Their outputs stay the
    stand-in's, finite: a NaN output would poison the sums the likelihood takes before it masks
    unconverged steps (0 × NaN in the reverse pass, and lineax raised again). A Vcmax_ref above
    :data:`MAX_SOLVED_VCMAX_UMOL_M2_S` (float32: :data:`MAX_SOLVED_VCMAX_FLOAT32_UMOL_M2_S`), inside its
    domain but beyond the dtype's reach, counts as outside it."""
    ok = _in_range(env)
    safe = {k: jnp.where(ok, getattr(env, k), jnp.asarray(v, getattr(env, k).dtype)) for k, v in _STAND_IN.items()}
    vcmax = jnp.asarray(params.fvcb.vcmax_ref_umol_m2_s)
    # float32 holds no 1e100 (casting it overflowed with a RuntimeWarning) and overflows far below its largest number
    wide = jnp.finfo(vcmax.dtype).bits >= 64
    limit = MAX_SOLVED_VCMAX_UMOL_M2_S if wide else MAX_SOLVED_VCMAX_FLOAT32_UMOL_M2_S
    keep = params_in_domain(params) & (vcmax <= limit)
    mine = {name: jnp.asarray(value_of(params, name)) for name in OVERRIDABLE}
    stand_in = _stand_in_values()
    params = replaced(params, {n: jnp.where(keep, v, jnp.asarray(stand_in[n], v.dtype)) for n, v in mine.items()})
    return env._replace(**safe), params, ok & keep


def _masked(res: PhotosynthesisResult, ok: jax.Array) -> PhotosynthesisResult:
    """``res`` with ``converged = False`` where the drivers were not in range (their values are the
    stand-in's, :func:`_guarded`: finite and meaningless)."""
    return res._replace(converged=res.converged & ok)


def _solve_impl(env: Environment, params: PhotosynthesisParams, config: SolverConfig) -> PhotosynthesisResult:
    env, params, ok = _guarded(env, params)
    return _masked(_solve_in_range(env, params, config), ok)


def _solve_in_range(env: Environment, params: PhotosynthesisParams, config: SolverConfig) -> PhotosynthesisResult:
    leaf = _capacities(env.par_abs_umol_m2_s, env, params)
    if params.stomata.model == "cplantbox":
        return _solve_cplantbox(leaf, env, params)
    adjoint = optx.ImplicitAdjoint(linear_solver=lx.Diagonal())
    cc, (converged, iterations) = adjoint.apply(
        _primal, _rewrite, (leaf, env, params, config), frozenset({lx.diagonal_tag})
    )
    f = _fluxes(cc, leaf, env, params)
    return _finish(cc, f, leaf, env, params, converged, iterations, check_gamma_rubisco=False)


def _plain_impl(env: Environment, params: PhotosynthesisParams, config: SolverConfig) -> PhotosynthesisResult:
    env, params, ok = _guarded(env, params)
    leaf = _capacities(env.par_abs_umol_m2_s, env, params)
    _, _, x0 = _bracket(leaf, env, params)
    res = fixed_point_iteration(_fixed_point_map, x0, (leaf, env, params), config)
    f = _fluxes(res.x, leaf, env, params)
    return _masked(_finish(res.x, f, leaf, env, params, res.converged, res.iterations, check_gamma_rubisco=False), ok)


def _capacities(par, env: Environment, params: PhotosynthesisParams) -> LeafCapacities:
    return _broadcast_leaf(leaf_capacities(par, env.tleaf_c, env.pair_kpa, params.fvcb, params.temperature), env)


def _par_slope(res: PhotosynthesisResult, env: Environment, params: PhotosynthesisParams) -> jax.Array:
    r"""dAn/dq of every segment at its steady state [mol mol⁻¹], q the absorbed PAR.

    Segments are independent, so the implicit function theorem is elementwise: with
    :math:`r(c_c, q) = 0` at the root, :math:`dc_c/dq = -(\partial r/\partial q)/(\partial r/\partial c_c)`
    and :math:`dA_n/dq = \partial A_n/\partial q + \partial A_n/\partial c_c\,dc_c/dq`. Three forward
    products of explicit functions at the root: no linear solver (whose error checks are host
    callbacks, which keep a compiled function out of JAX's persistent compilation cache) and no
    second compilation of the solve. The closed-form ``"cplantbox"`` closure is differentiated
    directly.
    """
    shape = jnp.shape(res.an_umol_m2_s)
    par = jnp.broadcast_to(env.par_abs_umol_m2_s, shape)
    ones = jnp.ones(shape, par.dtype)
    if params.stomata.model == "cplantbox":
        closed = lambda x: _solve_cplantbox(_capacities(x, env, params), env, params).an_umol_m2_s  # noqa: E731
        return jax.jvp(closed, (par,), (ones,))[1]
    cc = res.cc_umol_mol

    def residual(c, x):
        return co2_balance_residual(c, _capacities(x, env, params), env, params)

    _, r_cc = jax.jvp(lambda c: residual(c, par), (cc,), (ones,))
    _, r_q = jax.jvp(lambda x: residual(cc, x), (par,), (ones,))
    dcc_dq = -r_q / r_cc
    an = lambda c, x: _fluxes(c, _capacities(x, env, params), env, params).an  # noqa: E731
    return jax.jvp(an, (cc, par), (dcc_dq, ones))[1]


def _solve_slope_impl(env: Environment, params: PhotosynthesisParams, config: SolverConfig):
    env, params, ok = _guarded(env, params)
    res = _solve_in_range(env, params, config)
    return _masked(res, ok), _par_slope(res, env, params)


_solve_jit = eqx.filter_jit(_solve_impl)
_solve_slope_jit = eqx.filter_jit(_solve_slope_impl)
_plain_jit = eqx.filter_jit(_plain_impl)


# --------------------------------------------------------------------------- input handling


#: Most absorbed PAR a leaf solve accepts, µmol m⁻² s⁻¹ (≈ 4× full sun: beyond it a unit or scale slip).
MAX_PAR_ABS_UMOL_M2_S = 1e4

#: Accepted range of each driver in :class:`Environment`: ``(lo, hi, description)``, checked
#: eagerly by :func:`prepare_environment` and, elementwise into ``converged``, by :func:`solve`
#: (so also under ``jit``, ``vmap`` and ``grad``).
INPUT_RANGES = {
    "par_abs_umol_m2_s": (0.0, MAX_PAR_ABS_UMOL_M2_S, "absorbed PAR in [0, 1e4] µmol m-2 s-1"),
    "tleaf_c": (-50.0, 60.0, "leaf temperature in [-50, 60] °C"),
    "co2_umol_mol": (1e-3, 1e5, "CO2 mole fraction in [1e-3, 1e5] µmol mol-1 (ppm)"),
    "vpd_kpa": (0.0, 20.0, "vapour pressure deficit in [0, 20] kPa"),
    "pair_kpa": (10.0, 200.0, "air pressure in [10, 200] kPa"),
    "gb_mol_m2_s": (1e-9, np.inf, "boundary-layer conductance > 0 mol m-2 s-1 (inf: none)"),
    "fw": (0.0, 1.0, "water-stress factor in [0, 1]"),
}
RH_RANGE = (0.0, 1.0, "relative humidity in [0, 1] (a fraction, not %)")


def _is_traced(x) -> bool:
    return isinstance(x, jax.core.Tracer)


def _check_range(name, value, lo, hi, expected):
    if value is None or _is_traced(value):
        return
    v = np.asarray(value)
    if not np.issubdtype(v.dtype, np.number) or np.iscomplexobj(v):
        raise TypeError(f"{name} must be a real number or array, got dtype {v.dtype}")
    v = v.astype(float)
    bad = ~(~np.isnan(v) & (v >= lo) & (v <= hi))  # as the traced check: inf passes only where hi is inf
    if np.any(bad):
        first = v[bad].ravel()[0] if v.ndim else float(v)
        n = int(np.count_nonzero(bad))
        raise InputError(f"{name}={first!r} ({n} bad value(s))", parameter=name, expected=expected)


def prepare_environment(
    par_abs_umol_m2_s: ArrayLike,
    tleaf_c: ArrayLike,
    co2_ppm: ArrayLike,
    rh: ArrayLike | None = None,
    pair_kpa: ArrayLike = REFERENCE_PRESSURE_KPA,
    params: PhotosynthesisParams | None = None,
    *,
    vpd_kpa: ArrayLike | None = None,
    gb_mol_m2_s: ArrayLike | None = None,
    fw: ArrayLike = 1.0,
) -> tuple[Environment, PhotosynthesisParams]:
    """Validate, broadcast and cast the drivers of :func:`solve` (Python side, before jit).

    Value checks run only on concrete inputs; under ``jit``/``grad`` traced values are
    passed through and only shapes are checked; :func:`solve` then flags out-of-range
    elements (the same ranges, :data:`INPUT_RANGES`) with ``converged = False``.
    """
    if params is None:
        params = parameter_set(DEFAULT_PARAMETER_SET)
    check_params(params)
    named = {
        "par_abs_umol_m2_s": par_abs_umol_m2_s,
        "tleaf_c": tleaf_c,
        "co2_ppm": co2_ppm,
        "rh": rh,
        "pair_kpa": pair_kpa,
        "vpd_kpa": vpd_kpa,
        "gb_mol_m2_s": gb_mol_m2_s,
        "fw": fw,
    }
    for name, value in named.items():
        if (
            value is not None
            and not hasattr(value, "shape")
            and not isinstance(value, (int, float, np.number, list, tuple))
        ):
            raise TypeError(f"{name} must be a number or array, got {type(value).__name__}")
    for name in ("par_abs_umol_m2_s", "tleaf_c", "co2_ppm", "pair_kpa"):
        if named[name] is None:  # reached jnp.asarray(None): "None is not a valid value for jnp.array"
            raise InputError(f"{name}=None", parameter=name, expected="a number or array (it has no default of None)")
    present = {k: v for k, v in named.items() if v is not None}
    try:
        shape = np.broadcast_shapes(*(np.shape(v) for v in present.values()))
    except ValueError:
        shapes = ", ".join(f"{k}{tuple(np.shape(v))}" for k, v in present.items())
        raise InputError(
            f"input shapes do not broadcast together: {shapes}", expected="shapes that broadcast (numpy's rules)"
        ) from None
    # Parameter leaves may be per-segment arrays: one that does not broadcast with the drivers (and
    # the leaves before it) stopped inside the jit-compiled solve with JAX's TypeError, naming nothing.
    for name, label in OVERRIDABLE.items():
        leaf_shape = np.shape(value_of(params, name))
        try:
            shape = np.broadcast_shapes(shape, leaf_shape)
        except ValueError:
            raise InputError(
                f"params.{label} of shape {leaf_shape} does not broadcast with the inputs' shape {shape}",
                parameter=f"params.{label}",
                expected="a scalar or an array that broadcasts with the drivers (numpy's rules)",
            ) from None
    r = INPUT_RANGES
    _check_range("par_abs_umol_m2_s", par_abs_umol_m2_s, *r["par_abs_umol_m2_s"])
    _check_range("tleaf_c", tleaf_c, *r["tleaf_c"])
    _check_range("co2_ppm", co2_ppm, *r["co2_umol_mol"])
    _check_range("rh", rh, *RH_RANGE)
    _check_range("pair_kpa", pair_kpa, *r["pair_kpa"])
    _check_range("vpd_kpa", vpd_kpa, *r["vpd_kpa"])
    _check_range("gb_mol_m2_s", gb_mol_m2_s, *r["gb_mol_m2_s"])
    _check_range("fw", fw, *r["fw"])
    if params.stomata.model in ("leuning", "medlyn") and rh is None and vpd_kpa is None:
        raise InputError(
            f"the {params.stomata.model.capitalize()} closure needs humidity",
            parameter="rh",
            expected="rh (0-1) or vpd_kpa",
        )
    if params.stomata.model == "cplantbox" and gb_mol_m2_s is not None:
        raise InputError(
            "the 'cplantbox' closure takes co2_ppm at the leaf surface (as CPlantBox does)",
            parameter="gb_mol_m2_s",
            expected="no gb_mol_m2_s, or the 'tuzet', 'leuning' or 'medlyn' closure for a boundary layer",
        )

    floats = [v for v in present.values() if hasattr(v, "dtype") and jnp.issubdtype(v.dtype, jnp.floating)]
    dtype = jnp.result_type(*floats) if floats else jnp.result_type(float)
    if jnp.finfo(dtype).bits < 32:  # float16/bfloat16: solved with float32's tolerances, unconverged unsaid
        raise InputError(f"inputs of dtype {jnp.dtype(dtype).name}", parameter="dtype", expected="float32 or float64")

    def arr(x):
        return jnp.asarray(x, dtype)

    tleaf = arr(tleaf_c)
    if vpd_kpa is not None:
        vpd = arr(vpd_kpa)
    elif rh is not None:
        # From stand-ins where T or rh is out of range (those elements are flagged, _guarded), so
        # that a NaN temperature's cotangent stays 0 rather than 0 × NaN.
        lo, hi, _ = INPUT_RANGES["tleaf_c"]
        t_in = jnp.where((tleaf >= lo) & (tleaf <= hi), tleaf, _STAND_IN["tleaf_c"])
        rh_in = jnp.where((arr(rh) >= RH_RANGE[0]) & (arr(rh) <= RH_RANGE[1]), arr(rh), 0.5)
        vpd = vapour_pressure_deficit_kpa(t_in, rh_in)
    else:
        vpd = jnp.zeros((), dtype)
    gb = jnp.asarray(jnp.inf, dtype) if gb_mol_m2_s is None else arr(gb_mol_m2_s)
    env = Environment(
        par_abs_umol_m2_s=arr(par_abs_umol_m2_s),
        tleaf_c=tleaf,
        co2_umol_mol=arr(co2_ppm),
        vpd_kpa=vpd,
        pair_kpa=arr(pair_kpa),
        gb_mol_m2_s=gb,
        fw=arr(fw),
        rh=None if rh is None else arr(rh),
    )
    del shape
    return env, cast_params(params, dtype)


def _prepared(config: SolverConfig | None, *args, **kwargs):
    """:func:`prepare_environment` of ``args``/``kwargs``, and ``config`` or, if ``None``, the
    default :class:`SolverConfig` for the inputs' dtype: what every solver entry point starts with."""
    env, params = prepare_environment(*args, **kwargs)
    if config is not None and not isinstance(config, SolverConfig):  # "fast" was an AttributeError in the solve
        raise InputError(f"config={config!r}", parameter="config", expected="a SolverConfig or None (the dtype's)")
    return env, params, SolverConfig.for_dtype(env.par_abs_umol_m2_s.dtype) if config is None else config


def solve(
    par_abs_umol_m2_s: ArrayLike,
    tleaf_c: ArrayLike,
    co2_ppm: ArrayLike,
    rh: ArrayLike | None = None,
    pair_kpa: ArrayLike = REFERENCE_PRESSURE_KPA,
    params: PhotosynthesisParams | None = None,
    *,
    vpd_kpa: ArrayLike | None = None,
    gb_mol_m2_s: ArrayLike | None = None,
    fw: ArrayLike = 1.0,
    config: SolverConfig | None = None,
) -> PhotosynthesisResult:
    """Net CO2 assimilation, stomatal conductance and CO2 mole fractions per segment.

    All array arguments broadcast together (e.g. ``(time, segment)``); parameter leaves may
    be arrays broadcastable to that shape. The computation is jit-compiled, runs in the
    dtype of the float inputs (float32 or float64), and is differentiable with respect to
    every float input and parameter (implicit differentiation through the solve).

    Args:
        par_abs_umol_m2_s: absorbed PAR [µmol photons m⁻² s⁻¹], ≥ 0.
        tleaf_c: leaf temperature [°C].
        co2_ppm: CO2 mole fraction [µmol mol⁻¹]; in the air outside the boundary layer if
            ``gb_mol_m2_s`` is given, else at the leaf surface.
        rh: relative humidity of the air [0–1]: the deficit is taken as D = e_s(T_leaf)·(1 − rh),
            the leaf-to-air deficit when the leaf is at air temperature (as in lightfit's coupled
            model); for a leaf warmer or cooler than the air pass ``vpd_kpa`` instead.
        pair_kpa: air pressure [kPa].
        params: :class:`PhotosynthesisParams`; default
            ``parameter_set(DEFAULT_PARAMETER_SET)`` (``"winter_wheat"``).
        vpd_kpa: leaf-to-air vapour pressure deficit [kPa]; overrides ``rh``.
        gb_mol_m2_s: boundary-layer conductance to CO2 [mol m⁻² s⁻¹], in series with gs.
        fw: water-stress factor [0–1]; 1 = no soil water limitation (default, as the
            reference paper), see :func:`.stomata.water_stress_factor`.
        config: :class:`SolverConfig`; default tolerances depend on the dtype.

    Returns:
        :class:`PhotosynthesisResult`.

    Raises:
        InputError (a ValueError) / TypeError: inputs of the wrong shape or range / type (checked before
            jit on concrete values). Traced values (under ``jit``, ``vmap``, ``grad``) cannot
            be checked there: a NaN, infinite or out-of-range element gives
            ``converged = False`` instead (its outputs those of in-range stand-in drivers, finite
            and meaningless) and gradients of 0 (the other elements' are unaffected). A traced
            parameter outside its domain (NaN, infinite, a curvature of 1.5; shared by all
            elements) flags every element, solved at the default set's numbers, with gradients of
            0; so does a Vcmax_ref above :data:`MAX_SOLVED_VCMAX_UMOL_M2_S` (1e100; 1e12 in float32,
            :data:`MAX_SOLVED_VCMAX_FLOAT32_UMOL_M2_S`), concrete or traced. A gradient through an
            infinite cotangent still raises lineax's "non-finite input" error from the implicit
            adjoint's linear solve.
    """
    env, params, config = _prepared(
        config,
        par_abs_umol_m2_s,
        tleaf_c,
        co2_ppm,
        rh,
        pair_kpa,
        params,
        vpd_kpa=vpd_kpa,
        gb_mol_m2_s=gb_mol_m2_s,
        fw=fw,
    )
    return _solve_jit(env, params, config)


def solve_with_par_slope(
    par_abs_umol_m2_s: ArrayLike,
    tleaf_c: ArrayLike,
    co2_ppm: ArrayLike,
    rh: ArrayLike | None = None,
    pair_kpa: ArrayLike = REFERENCE_PRESSURE_KPA,
    params: PhotosynthesisParams | None = None,
    *,
    vpd_kpa: ArrayLike | None = None,
    gb_mol_m2_s: ArrayLike | None = None,
    fw: ArrayLike = 1.0,
    config: SolverConfig | None = None,
) -> tuple[PhotosynthesisResult, jax.Array]:
    """:func:`solve` and, from the same compiled function, dAn/dq of every segment.

    Arguments as :func:`solve`. Returns ``(result, dan_dpar)``: ``dan_dpar`` is the derivative of
    the net assimilation by the absorbed PAR at each segment's steady state [mol CO2 per mol
    photons], by the implicit function theorem, elementwise (``_par_slope``). It equals a forward
    product of :func:`solve` with a tangent of ones in ``par_abs_umol_m2_s`` (to round-off), at
    the cost of one compilation instead of two and one solve instead of two. Its output is
    differentiable like :func:`solve`'s.
    """
    env, params, config = _prepared(
        config,
        par_abs_umol_m2_s,
        tleaf_c,
        co2_ppm,
        rh,
        pair_kpa,
        params,
        vpd_kpa=vpd_kpa,
        gb_mol_m2_s=gb_mol_m2_s,
        fw=fw,
    )
    return _solve_slope_jit(env, params, config)


def solve_plain_iteration(
    par_abs_umol_m2_s: ArrayLike,
    tleaf_c: ArrayLike,
    co2_ppm: ArrayLike,
    rh: ArrayLike | None = None,
    pair_kpa: ArrayLike = REFERENCE_PRESSURE_KPA,
    params: PhotosynthesisParams | None = None,
    *,
    vpd_kpa: ArrayLike | None = None,
    gb_mol_m2_s: ArrayLike | None = None,
    fw: ArrayLike = 1.0,
    config: SolverConfig | None = None,
) -> PhotosynthesisResult:
    """Baseline: the same steady state by plain fixed-point iteration cc ← ca − An/g_tot.

    Not robust (it oscillates or diverges where gs ≈ g0 and An ≈ 0); kept to test the robust
    solver against (``benchmarks/bench_photosynthesis.py`` times its kernel). Not differentiable by design.
    Coupled closures only.
    """
    env, params, config = _prepared(
        config,
        par_abs_umol_m2_s,
        tleaf_c,
        co2_ppm,
        rh,
        pair_kpa,
        params,
        vpd_kpa=vpd_kpa,
        gb_mol_m2_s=gb_mol_m2_s,
        fw=fw,
    )
    if params.stomata.model == "cplantbox":
        raise ValueError("params.stomata.model: 'cplantbox' is closed-form; plain iteration needs a coupled closure")
    return _plain_jit(env, params, config)
