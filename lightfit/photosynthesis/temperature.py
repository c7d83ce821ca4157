r"""Temperature responses of the FvCB kinetic constants and leaf capacities.

Two families are provided, selected by :attr:`TemperatureParams.form`:

``"peaked"``
    Normalised peaked Arrhenius (Medlyn et al. 2002, Plant Cell Environ. 25:1167, eq. 18) for
    :math:`V_{cmax}, J_{max}` (the default set, ``winter_wheat``, takes Kattge & Knorr 2007's
    activation and deactivation energies and entropies), and plain Arrhenius with Bernacchi et al.
    (2001, Plant Cell Environ. 24:253) activation energies for :math:`K_c, K_o, \Gamma^*, R_d`.

``"cplantbox"``
    The forms of CPlantBox's ``Photosynthesis::photoC3_init`` (Giraud et al. 2023): plain
    Arrhenius times an *un-normalised* deactivation term
    :math:`1/(1+\exp((S T - H_d)/(R T)))` for :math:`V_{cmax}` and :math:`J_{max}`,
    :math:`J_{max}` capped at its reference value, :math:`R_d` plain Arrhenius.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax.typing import ArrayLike

from .constants import GAS_CONSTANT_J_MOL_K


def arrhenius(t_leaf_k: ArrayLike, activation_energy_j_mol: ArrayLike, t_ref_k: ArrayLike) -> jax.Array:
    r"""Arrhenius factor relative to the reference temperature [-].

    .. math:: f(T) = \exp\!\left(\frac{E_a}{R\,T_{ref}}\left(1 - \frac{T_{ref}}{T}\right)\right)

    Args:
        t_leaf_k: leaf temperature [K].
        activation_energy_j_mol: activation energy :math:`E_a` [J mol⁻¹].
        t_ref_k: reference temperature [K] at which :math:`f = 1`.

    Reference: Arrhenius form as in Bernacchi et al. (2001), eq. 8.
    """
    return jnp.exp(activation_energy_j_mol / (GAS_CONSTANT_J_MOL_K * t_ref_k) * (1.0 - t_ref_k / t_leaf_k))


def deactivation(t_leaf_k: ArrayLike, deactivation_energy_j_mol: ArrayLike, entropy_j_mol_k: ArrayLike) -> jax.Array:
    r"""High-temperature deactivation term [-] (not normalised).

    .. math:: h(T) = \frac{1}{1 + \exp\!\left(\frac{S\,T - H_d}{R\,T}\right)}

    Args:
        t_leaf_k: leaf temperature [K].
        deactivation_energy_j_mol: :math:`H_d` [J mol⁻¹].
        entropy_j_mol_k: entropy term :math:`S` (often :math:`\Delta S`) [J mol⁻¹ K⁻¹].

    Reference: Medlyn et al. (2002), eq. 18 denominator; CPlantBox ``thermalBreakdown``.
    """
    # logaddexp form keeps the term finite and differentiable for extreme temperatures.
    x = (entropy_j_mol_k * t_leaf_k - deactivation_energy_j_mol) / (GAS_CONSTANT_J_MOL_K * t_leaf_k)
    return jnp.exp(-jnp.logaddexp(0.0, x))


def peaked_arrhenius(
    t_leaf_k: ArrayLike,
    activation_energy_j_mol: ArrayLike,
    deactivation_energy_j_mol: ArrayLike,
    entropy_j_mol_k: ArrayLike,
    t_ref_k: ArrayLike,
) -> jax.Array:
    r"""Peaked Arrhenius factor normalised to 1 at the reference temperature [-].

    .. math:: f(T) = \exp\!\left(\frac{E_a}{R T_{ref}}\left(1-\frac{T_{ref}}{T}\right)\right)
              \frac{1 + \exp\left((S T_{ref} - H_d)/(R T_{ref})\right)}
                   {1 + \exp\left((S T - H_d)/(R T)\right)}

    Reference: Medlyn et al. (2002), Plant Cell Environ. 25:1167, eq. 18.
    """
    return (
        arrhenius(t_leaf_k, activation_energy_j_mol, t_ref_k)
        * deactivation(t_leaf_k, deactivation_energy_j_mol, entropy_j_mol_k)
        / deactivation(t_ref_k, deactivation_energy_j_mol, entropy_j_mol_k)
    )
