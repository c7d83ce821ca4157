r"""Stomatal conductance closures and the water-stress factor.

All conductances are to CO2 [mol m⁻² s⁻¹] (for water vapour multiply stomatal conductance
by 1.6 and boundary-layer conductance by 1.37). Net assimilation enters the coupled
closures as :math:`A_n^+ = \max(A_n, 0)`, so that gs never falls below g0 when the leaf
respires; the floor on :math:`c_s - \Gamma^*` only acts away from the solution (where
:math:`A_n > 0` implies :math:`c_s > c_i > \Gamma^*`).

:math:`A_n^+` is ``where(An > 0, An, 0)`` (:func:`positive_part`), not ``jnp.maximum``, whose
derivative splits 50/50 at An = 0. An = 0 exactly happens at zero capacity (Vcmax scale 0,
where Rd = 0 too); there the derivative of :math:`A_n^+` is taken as 0, the right one-sided
value in the dark (An falls as capacity grows: Rd). In light An rises with capacity and the
one-sided derivative of gs (and so of ci, cs) at exactly zero capacity is missed; that of An
itself is right in both cases, since at zero capacity An does not depend on ci.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax.typing import ArrayLike

#: Floor on cs − Γ* in the Tuzet / Leuning denominators [µmol mol⁻¹].
_CS_GAMMA_FLOOR_UMOL_MOL = 1e-3


def positive_part(an_umol_m2_s: ArrayLike) -> jax.Array:
    """max(An, 0) with derivative 0 at An = 0 (see the module docstring)."""
    return jnp.where(an_umol_m2_s > 0, an_umol_m2_s, 0.0)


def saturation_vapour_pressure_tetens_kpa(t_c: ArrayLike) -> jax.Array:
    r"""Saturation vapour pressure over water [kPa], Tetens form of FAO-56 (eq. 11).

    .. math:: e_s(T) = 0.61078 \exp\left(\frac{17.27\,T}{T + 237.3}\right)

    Args:
        t_c: temperature [°C].

    Reference: Allen et al. (1998), FAO Irrigation and Drainage Paper 56; CPlantBox ``get_es``.
    The weather's humidity conversions take Alduchov & Eskridge's Magnus form
    (:func:`lightfit.weather.units.saturation_vapour_pressure_alduchov_kpa`), at most 0.21 % apart from 0 to 40 °C;
    this one is kept here so that the leaf's VPD is CPlantBox's (tests/test_photosynthesis_peer.py).
    """
    return 0.61078 * jnp.exp(17.27 * t_c / (t_c + 237.3))


def vapour_pressure_deficit_kpa(t_c: ArrayLike, rh: ArrayLike) -> jax.Array:
    """Vapour pressure deficit [kPa] of air at temperature ``t_c`` [°C] and relative
    humidity ``rh`` [0–1]: e_s(T)·(1 − RH)."""
    return saturation_vapour_pressure_tetens_kpa(t_c) * (1.0 - rh)


def water_stress_factor(
    psi_leaf_cm: ArrayLike,
    fwr: ArrayLike = 9.308e-2,
    sh_per_cm: ArrayLike = 3.765e-4,
    p_crit_cm: ArrayLike = -7500.0,
    cutoff: ArrayLike = 0.0,
) -> jax.Array:
    r"""Stomatal water-stress factor fw [-] from leaf water potential.

    .. math:: f_w = f_{wr} + \max\left(0, (1 - f_{wr})
              \frac{1 + e^{s_h p_{crit}}}{1 + e^{s_h (p_{crit} - \psi_l)}} - f_{cut}\right)

    fw = 1 at ψ_l = 0 (no water limitation, the reference paper's assumption). A positive ψ_l (not
    a leaf water potential) counts as 0, so fw ≤ 1; the logistic is taken in its stable form, so
    that value and gradient stay finite at any ψ_l (the exponential overflowed below ≈ −1.9e6 cm,
    a NaN gradient).

    Args:
        psi_leaf_cm: leaf (guard-cell) water potential as pressure head [cm of water], ≤ 0, as
            CPlantBox gives it (1 cm ≈ 0.981 hPa).
        fwr: residual opening under water stress [-] (Corso et al. 2020 fit).
        sh_per_cm: sensitivity s_h [cm⁻¹].
        p_crit_cm: water potential of half closure p_crit [cm of water].
        cutoff: f_cut [-].

    Reference: Tuzet et al. (2003), Plant Cell Environ. 26:1097, eq. 6; parameters and
    residual term of CPlantBox ``loopCalcs``.
    """
    psi = jnp.minimum(psi_leaf_cm, 0.0)
    # 1 / (1 + e^{s(p_crit - ψ)}) = sigmoid(s(ψ - p_crit))
    shape = (1.0 + jnp.exp(sh_per_cm * p_crit_cm)) * jax.nn.sigmoid(sh_per_cm * (psi - p_crit_cm))
    return fwr + jnp.maximum(0.0, (1.0 - fwr) * shape - cutoff)


def tuzet_conductance(
    an_umol_m2_s: ArrayLike,
    cs_umol_mol: ArrayLike,
    gamma_umol_mol: ArrayLike,
    g0_mol_m2_s: ArrayLike,
    a1: ArrayLike,
    fw: ArrayLike,
) -> jax.Array:
    r"""Stomatal conductance to CO2 of Tuzet et al. (2003) [mol m⁻² s⁻¹].

    .. math:: g_s = g_0 + a_1 f_w \frac{A_n^+}{c_s - \Gamma}

    Args:
        an_umol_m2_s: net assimilation [µmol m⁻² s⁻¹].
        cs_umol_mol: CO2 at the leaf surface [µmol mol⁻¹].
        gamma_umol_mol: CO2 compensation point Γ (here Γ*) [µmol mol⁻¹].
        g0_mol_m2_s: residual conductance [mol m⁻² s⁻¹].
        a1: slope [-].
        fw: water-stress factor [-].

    Reference: Tuzet, Perrier & Leuning (2003), Plant Cell Environ. 26:1097, eq. 5.
    """
    denom = jnp.maximum(cs_umol_mol - gamma_umol_mol, _CS_GAMMA_FLOOR_UMOL_MOL)
    return g0_mol_m2_s + a1 * fw * positive_part(an_umol_m2_s) / denom


def leuning_conductance(
    an_umol_m2_s: ArrayLike,
    cs_umol_mol: ArrayLike,
    gamma_umol_mol: ArrayLike,
    vpd_kpa: ArrayLike,
    g0_mol_m2_s: ArrayLike,
    a1: ArrayLike,
    d0_kpa: ArrayLike,
    fw: ArrayLike,
) -> jax.Array:
    r"""Stomatal conductance to CO2 of Leuning (1995) [mol m⁻² s⁻¹].

    .. math:: g_s = g_0 + a_1 f_w \frac{A_n^+}{(c_s - \Gamma)(1 + D_s/D_0)}

    Args:
        vpd_kpa: vapour pressure deficit at the leaf surface D_s [kPa] (approximated by the
            leaf-to-air deficit, :func:`vapour_pressure_deficit_kpa` at leaf temperature).
        d0_kpa: D0 [kPa].
        (others as :func:`tuzet_conductance`)

    Reference: Leuning (1995), Plant Cell Environ. 18:339, eq. 11.
    """
    denom = jnp.maximum(cs_umol_mol - gamma_umol_mol, _CS_GAMMA_FLOOR_UMOL_MOL) * (1.0 + vpd_kpa / d0_kpa)
    return g0_mol_m2_s + a1 * fw * positive_part(an_umol_m2_s) / denom


#: Floor on the leaf-to-air VPD in the Medlyn closure [kPa] (CLM5 ``PhotosynthesisMod``
#: floors it at 50 Pa): g1/√D diverges at saturation (RH = 1, e.g. dew at dawn).
MEDLYN_VPD_FLOOR_KPA = 0.05


def medlyn_conductance(
    an_umol_m2_s: ArrayLike,
    cs_umol_mol: ArrayLike,
    vpd_kpa: ArrayLike,
    g0_mol_m2_s: ArrayLike,
    g1_kpa05: ArrayLike,
    fw: ArrayLike,
) -> jax.Array:
    r"""Stomatal conductance to CO2 of Medlyn et al. (2011) [mol m⁻² s⁻¹].

    .. math:: g_s = g_0 + f_w \left(1 + \frac{g_1}{\sqrt{\max(D, D_{min})}}\right)\frac{A_n^+}{c_s}

    i.e. the unified stomatal optimisation model, whose water-vapour form
    :math:`g_{sw} = g_{0w} + 1.6 (1 + g_1/\sqrt{D}) A_n/c_s` is divided by 1.6;
    :math:`D_{min}` = :data:`MEDLYN_VPD_FLOOR_KPA`.

    Args:
        vpd_kpa: leaf-to-air vapour pressure deficit D [kPa].
        g1_kpa05: slope g1 [kPa^0.5].
        (others as :func:`tuzet_conductance`)

    Reference: Medlyn et al. (2011), Global Change Biol. 17:2134, eq. 11 (corrigendum 2012).
    """
    d = jnp.maximum(vpd_kpa, MEDLYN_VPD_FLOOR_KPA)
    cs = jnp.maximum(cs_umol_mol, _CS_GAMMA_FLOOR_UMOL_MOL)
    return g0_mol_m2_s + fw * (1.0 + g1_kpa05 / jnp.sqrt(d)) * positive_part(an_umol_m2_s) / cs


def cplantbox_intercellular_co2(
    cs_umol_mol: ArrayLike, gamma_rubisco_umol_mol: ArrayLike, a1: ArrayLike, fw: ArrayLike
) -> jax.Array:
    r"""Intercellular CO2 of CPlantBox's Tuzet variant, in closed form [µmol mol⁻¹].

    .. math:: c_i = \max\left(\frac{a_1 f_w c_s + \Gamma'}{1 + a_1 f_w}, \Gamma'\right)

    i.e. :math:`(c_i - \Gamma') = a_1 f_w (c_s - c_i)`; equivalent to Tuzet's closure
    with g0 = 0 and slope 1 + a1·fw. Reference: CPlantBox ``Photosynthesis::loopCalcs``
    (Giraud et al. 2023).
    """
    k = a1 * fw
    return jnp.maximum((k * cs_umol_mol + gamma_rubisco_umol_mol) / (1.0 + k), gamma_rubisco_umol_mol)


def cplantbox_conductance(
    an_umol_m2_s: ArrayLike,
    rd_umol_m2_s: ArrayLike,
    ci_umol_mol: ArrayLike,
    gamma_rubisco_umol_mol: ArrayLike,
    g0_mol_m2_s: ArrayLike,
    a1: ArrayLike,
    fw: ArrayLike,
) -> jax.Array:
    r"""Diagnostic stomatal conductance of CPlantBox's Tuzet variant [mol m⁻² s⁻¹].

    .. math:: g_s = \max\left(g_0 + f_w a_1 \frac{A_n + R_d}{c_i - \Gamma'}, 0\right)

    Where cs ≤ Γ' (so ci = Γ') CPlantBox divides by zero; there the leaf cannot gain
    carbon and we return g0 instead. Reference: CPlantBox ``loopCalcs`` ("tuzet2003").
    """
    d = ci_umol_mol - gamma_rubisco_umol_mol
    ok = d > 0
    gs = g0_mol_m2_s + fw * a1 * (an_umol_m2_s + rd_umol_m2_s) / jnp.where(ok, d, 1.0)
    return jnp.where(ok, jnp.maximum(gs, 0.0), g0_mol_m2_s + 0.0 * gs)
