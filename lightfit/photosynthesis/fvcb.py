r"""C3 Farquhar–von Caemmerer–Berry biochemistry (Farquhar et al. 1980).

Rates are in µmol m⁻² s⁻¹ and CO2 mole fractions in µmol mol⁻¹ throughout, which keeps
float32 arithmetic well scaled.

.. math::
    V_c = V_{cmax}\frac{c - \Gamma^*}{c + K_c(1 + O/K_o)},\qquad
    V_j = \frac{J}{4}\frac{c - \Gamma^*}{c + 2\Gamma^*},\qquad
    A_n = \min(V_c, V_j) - R_d \quad (c > \Gamma^*;\ \max \text{ below it, see } :func:`limits`)

with :math:`c` the CO2 mole fraction at the carboxylation site (chloroplast; equal to the
intercellular value without mesophyll resistance).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax.typing import ArrayLike

from ..precision import power_of_two_scale, sqrt_or_zero
from .constants import GAMMA_STAR_REFERENCE_O2_MMOL_MOL, REFERENCE_PRESSURE_KPA, ZERO_CELSIUS_K
from .parameters import FvCBParams, TemperatureParams
from .temperature import arrhenius, deactivation, peaked_arrhenius


class LeafCapacities(NamedTuple):
    """Per-segment quantities fixed during the CO2 solve (all broadcast to one shape).

    Attributes:
        vcmax_umol_m2_s: Vcmax at leaf temperature [µmol m⁻² s⁻¹].
        jmax_umol_m2_s: Jmax at leaf temperature [µmol m⁻² s⁻¹].
        j_umol_m2_s: electron transport rate J [µmol m⁻² s⁻¹].
        rd_umol_m2_s: day respiration Rd [µmol m⁻² s⁻¹].
        gamma_star_umol_mol: Γ* [µmol mol⁻¹].
        km_umol_mol: effective Michaelis constant Kc(1 + O/Ko) [µmol mol⁻¹].
        gamma_rubisco_umol_mol: Rubisco-limited CO2 compensation point with Rd, Γ'
            (CPlantBox ``deltagco2``) [µmol mol⁻¹].
    """

    vcmax_umol_m2_s: object
    jmax_umol_m2_s: object
    j_umol_m2_s: object
    rd_umol_m2_s: object
    gamma_star_umol_mol: object
    km_umol_mol: object
    gamma_rubisco_umol_mol: object


def electron_transport_rate(
    par_abs_umol_m2_s: ArrayLike, jmax_umol_m2_s: ArrayLike, quantum_yield: ArrayLike, curvature: ArrayLike
) -> jax.Array:
    r"""Electron transport rate from the non-rectangular hyperbola [µmol m⁻² s⁻¹].

    Smaller root of :math:`\theta J^2 - (\alpha Q + J_{max}) J + \alpha Q J_{max} = 0`,
    written as :math:`J = 2\alpha Q J_{max} / (\alpha Q + J_{max} + \sqrt{\Delta})` with
    :math:`\Delta = (\alpha Q - J_{max})^2 + 4(1-\theta)\alpha Q J_{max}`: the usual
    :math:`(b - \sqrt{\Delta})/2\theta` cancels catastrophically in float32 at low light.

    Args:
        par_abs_umol_m2_s: absorbed PAR Q [µmol photons m⁻² s⁻¹].
        jmax_umol_m2_s: Jmax [µmol m⁻² s⁻¹].
        quantum_yield: alpha [-].
        curvature: theta in (0, 1] [-].

    Reference: von Caemmerer (2000), Biochemical models of leaf photosynthesis, eq. 2.14;
    CPlantBox ``photoC3_init``.
    """
    aq = quantum_yield * par_abs_umol_m2_s
    # J is homogeneous of degree one in (αQ, Jmax): taken on both times a power of two that brings
    # the larger near 1 (exact: the same numbers), so that its derivatives stay finite at any
    # capacity (in the dark with Jmax < 1e-154, a Vcmax scale below 1e-156, den² underflowed: dJ/dQ NaN).
    k = power_of_two_scale(jnp.maximum(aq, jmax_umol_m2_s))
    aq, jmax = k * aq, k * jmax_umol_m2_s
    disc = (aq - jmax) ** 2 + 4.0 * (1.0 - curvature) * aq * jmax
    # Double-where keeps the division differentiable where it degenerates (sqrt_or_zero: the root).
    root = sqrt_or_zero(disc)
    den = aq + jmax + root
    ok = den > 0
    return jnp.where(ok, 2.0 * aq * jmax / jnp.where(ok, den, 1.0), 0.0) / k


def rubisco_limited_rate(
    c_umol_mol: ArrayLike,
    vcmax_umol_m2_s: ArrayLike,
    gamma_star_umol_mol: ArrayLike,
    km_umol_mol: ArrayLike,
    clip: bool,
) -> jax.Array:
    """Rubisco-limited gross rate Vc (Fc) [µmol m⁻² s⁻¹] (Farquhar et al. 1980).

    With ``clip`` the rate is limited to [0, Vcmax] as in CPlantBox ``photoC3_loop``
    (Vc ≤ Vcmax holds anyway for c > −Km, so only the sign clip is active).
    """
    vc = vcmax_umol_m2_s * (c_umol_mol - gamma_star_umol_mol) / (c_umol_mol + km_umol_mol)
    # Clip on the sign of c − Γ*, not of the product: max(0·x, 0) would halve the
    # derivative with respect to Vcmax at Vcmax = 0 (ties split the gradient).
    return jnp.where(c_umol_mol > gamma_star_umol_mol, vc, 0.0) if clip else vc


def electron_limited_rate(
    c_umol_mol: ArrayLike, j_umol_m2_s: ArrayLike, gamma_star_umol_mol: ArrayLike, clip: bool
) -> jax.Array:
    """Electron-transport-limited gross rate Vj (Fj) [µmol m⁻² s⁻¹], J/4 per CO2.

    With ``clip`` the rate is kept ≥ 0 as in CPlantBox ``photoC3_loop``.
    """
    vj = 0.25 * j_umol_m2_s * (c_umol_mol - gamma_star_umol_mol) / (c_umol_mol + 2.0 * gamma_star_umol_mol)
    # Sign clip on c − Γ* keeps dVj/dJ exact at J = 0 (PAR = 0), see rubisco_limited_rate.
    return jnp.where(c_umol_mol > gamma_star_umol_mol, vj, 0.0) if clip else vj


def limits(c_umol_mol: ArrayLike, gamma_star_umol_mol: ArrayLike, rate: ArrayLike, other: ArrayLike) -> jax.Array:
    """Whether ``rate`` (Vc or Vj) limits assimilation against ``other``, strictly (ties: False).

    The limiting process is the slower carboxylation, W = min(Wc, Wj), and both rates are
    W·(1 − Γ*/c): above Γ* the smaller rate limits; below Γ* (unclipped rates) that factor is
    negative, so the limiting one is the *larger* rate (the smaller release).
    """
    return jnp.where(jnp.asarray(c_umol_mol) < gamma_star_umol_mol, rate > other, rate < other)


def assimilation(
    c_umol_mol: ArrayLike, leaf: LeafCapacities, clip: bool, tie_vc: ArrayLike | None = None
) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Net assimilation An = (1 − Γ*/c)·min(Wc, Wj) − Rd and the two gross rates Vc, Vj
    [µmol m⁻² s⁻¹], Wc and Wj the carboxylation rates (Farquhar et al. 1980): min(Vc, Vj) above
    Γ*, max(Vc, Vj) below it, where unclipped rates are negative (photorespiratory release).

    The minimum is taken with a deterministic tie rule instead of ``jnp.minimum``, whose
    derivative splits 50/50 where Vc = Vj. Ties that matter occur at zero capacity
    (Vcmax = Jmax = 0, e.g. a Vcmax scale of 0, the lower bound of its domain), where both
    rates are 0; the one-sided derivative into the domain is then the smaller of the two
    rates' derivatives, which no rule on the two rates alone (both 0) can pick: in the dark
    Vj stays 0 as capacity grows, in light it may grow faster or slower than Vc. ``tie_vc``
    says which branch to take at a tie (the solver passes :func:`.model` ``_tie_takes_vc``:
    the branch that is smaller at a small positive common scale of Vcmax_ref, i.e. the
    one-sided derivative with respect to Vcmax_ref, which scales Vcmax, Jmax and Rd together);
    by default ties take Vj, right in the dark.

    Args:
        c_umol_mol: CO2 at the carboxylation site [µmol mol⁻¹].
        leaf: :class:`LeafCapacities`.
        clip: clip the rates as CPlantBox (see :func:`rubisco_limited_rate`).
        tie_vc: where Vc = Vj, take Vc where True (default: Vj everywhere).

    Returns:
        ``(an, vc, vj)``.
    """
    vc = rubisco_limited_rate(c_umol_mol, leaf.vcmax_umol_m2_s, leaf.gamma_star_umol_mol, leaf.km_umol_mol, clip)
    vj = electron_limited_rate(c_umol_mol, leaf.j_umol_m2_s, leaf.gamma_star_umol_mol, clip)
    limiting = limits(c_umol_mol, leaf.gamma_star_umol_mol, vc, vj)
    take_vc = limiting if tie_vc is None else limiting | ((vc == vj) & tie_vc)
    return jnp.where(take_vc, vc, vj) - leaf.rd_umol_m2_s, vc, vj


def rubisco_compensation_point(
    gamma_star_umol_mol: ArrayLike, km_umol_mol: ArrayLike, rd_over_vcmax: ArrayLike
) -> jax.Array:
    r"""CO2 compensation point of the Rubisco-limited rate with day respiration [µmol mol⁻¹].

    Solves :math:`V_c(\Gamma') = R_d`:
    :math:`\Gamma' = \max\left(0, (\Gamma^* + K_m R_d/V_{cmax}) / (1 - R_d/V_{cmax})\right)`,
    taking the ratio Rd/Vcmax directly so that Vcmax → 0 stays finite. Where
    :math:`R_d \ge V_{cmax}` (CPlantBox's temperature forms reach it at about 58.7 °C, inside
    the accepted range) the Rubisco-limited rate never exceeds Rd and there is no compensation
    point: Γ' = inf, so the ``"cplantbox"`` closure, which needs Γ', reports
    ``converged = False`` there (Γ' grows without bound as Rd/Vcmax → 1; returning 0, as before,
    made ci jump from 3.2e5 to 320 µmol mol⁻¹ between 58.6 and 58.7 °C).

    Reference: CPlantBox ``initVcVjRd`` (``deltagco2``), Giraud et al. (2023).
    """
    below = rd_over_vcmax < 1.0
    # Double where: the unused branch must not divide by zero (its gradient would be NaN).
    raw = (gamma_star_umol_mol + km_umol_mol * rd_over_vcmax) / jnp.where(below, 1.0 - rd_over_vcmax, 1.0)
    return jnp.where(below, jnp.maximum(raw, 0.0), jnp.inf)


def capacity_temperature_factors(t_k: ArrayLike, temp: TemperatureParams) -> tuple[jax.Array, jax.Array]:
    """Temperature factors of Vcmax and Jmax, ``(f_v, f_j)`` [-] (Vcmax = Vcmax_ref·f_v).

    Args:
        t_k: leaf temperature [K].
        temp: :class:`TemperatureParams`.
    """
    t_ref = temp.t_ref_k
    if temp.form == "cplantbox":
        f_v = arrhenius(t_k, temp.ea_vcmax_j_mol, t_ref) * deactivation(
            t_k, temp.hd_vcmax_j_mol, temp.entropy_vcmax_j_mol_k
        )
        f_j = arrhenius(t_k, temp.ea_jmax_j_mol, t_ref) * deactivation(
            t_k, temp.hd_jmax_j_mol, temp.entropy_jmax_j_mol_k
        )
        # CPlantBox caps Jmax at its reference value (Photosynthesis.cpp, photoC3_init).
        f_j = jnp.minimum(f_j, 1.0)
    else:
        f_v = peaked_arrhenius(t_k, temp.ea_vcmax_j_mol, temp.hd_vcmax_j_mol, temp.entropy_vcmax_j_mol_k, t_ref)
        f_j = peaked_arrhenius(t_k, temp.ea_jmax_j_mol, temp.hd_jmax_j_mol, temp.entropy_jmax_j_mol_k, t_ref)
    return f_v, f_j


def leaf_capacities(
    par_abs_umol_m2_s: ArrayLike, tleaf_c: ArrayLike, pair_kpa: ArrayLike, fvcb: FvCBParams, temp: TemperatureParams
) -> LeafCapacities:
    """Temperature- and light-dependent capacities of a leaf segment.

    Kc and Ko are tabulated as mole fractions at 101.325 kPa; being Michaelis constants
    of partial pressures they scale as 101.325/P at pressure P. Γ* (an O2/CO2 ratio) and
    the O2 mole fraction do not. Γ* = 0.5·O / S_c/o is proportional to the O2 mole fraction
    (von Caemmerer 2000, eq. 2.16), tabulated at 210 mmol mol⁻¹; CPlantBox's forms
    (``temp.form == "cplantbox"``) keep it fixed, as CPlantBox does (its Γ* does not move with
    its ``oi``: checked against ``cplantbox_peer`` at 20–210 mmol mol⁻¹).

    Args:
        par_abs_umol_m2_s: absorbed PAR [µmol m⁻² s⁻¹].
        tleaf_c: leaf temperature [°C].
        pair_kpa: air pressure [kPa].
        fvcb: :class:`FvCBParams`.
        temp: :class:`TemperatureParams`.
    """
    t_k = tleaf_c + ZERO_CELSIUS_K
    t_ref = temp.t_ref_k
    vref = fvcb.vcmax_ref_umol_m2_s
    jref = fvcb.jmax_to_vcmax * vref
    f_rd = arrhenius(t_k, temp.ea_rd_j_mol, t_ref)
    f_v, f_j = capacity_temperature_factors(t_k, temp)
    vcmax = vref * f_v
    jmax = jref * f_j
    rd = fvcb.rd_to_vcmax * vref * f_rd
    p_scale = REFERENCE_PRESSURE_KPA / pair_kpa
    kc = temp.kc_ref_umol_mol * arrhenius(t_k, temp.ea_kc_j_mol, t_ref) * p_scale
    ko = temp.ko_ref_mmol_mol * arrhenius(t_k, temp.ea_ko_j_mol, t_ref) * p_scale
    gamma_star = temp.gamma_star_ref_umol_mol * arrhenius(t_k, temp.ea_gamma_star_j_mol, t_ref)
    if temp.form != "cplantbox":
        gamma_star = gamma_star * (fvcb.o2_mmol_mol / GAMMA_STAR_REFERENCE_O2_MMOL_MOL)
    km = kc * (1.0 + fvcb.o2_mmol_mol / ko)
    j = electron_transport_rate(par_abs_umol_m2_s, jmax, fvcb.quantum_yield, fvcb.curvature)
    # f_v underflows only far outside the validated temperature range.
    safe_fv = jnp.where(f_v > 0, f_v, 1.0)
    rd_over_vcmax = jnp.where(f_v > 0, fvcb.rd_to_vcmax * f_rd / safe_fv, jnp.inf)
    gamma_rubisco = rubisco_compensation_point(gamma_star, km, rd_over_vcmax)
    return LeafCapacities(vcmax, jmax, j, rd, gamma_star, km, gamma_rubisco)
