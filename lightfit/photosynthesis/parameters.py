"""Typed parameter PyTrees and the named parameter sets.

All parameters are :class:`equinox.Module` PyTrees: float fields are leaves (differentiable,
may be arrays broadcastable to the segment shape, e.g. a per-segment ``vcmax``); model
choices are static fields. Units are in the field names.

Named sets (:func:`parameter_set`; :data:`~lightfit.defaults.DEFAULT_PARAMETER_SET` = ``"winter_wheat"``):

``"winter_wheat"`` (default)
    Winter wheat upper/flag leaves from the literature (values at 25 °C; docs/photosynthesis.md,
    "Parameter sets", has the table with the published ranges they were checked against):

    * Vcmax25 = 100 µmol m⁻² s⁻¹: mid-range of gas-exchange Vcmax25 of field- and
      glasshouse-grown wheat flag leaves (≈ 80–150; Silva-Pérez et al. 2020, J. Exp. Bot.
      71:2299; Silva-Pérez et al. 2017, Plant Cell Environ. 40:1552; Theobald et al. 1998,
      Plant Physiol. 118:945).
    * Jmax25/Vcmax25 = 2.065 = 2.59 − 0.035·T_growth at T_growth = 15 °C (Kattge & Knorr
      2007, Plant Cell Environ. 30:1176; the same growth temperature as the entropy terms of
      the temperature response) → Jmax25 = 206.5 µmol m⁻² s⁻¹; wheat ratios of 1.6–2.1 are
      reported in the papers above.
    * Rd25 = 0.015·Vcmax25 = 1.5 µmol m⁻² s⁻¹ (Collatz et al. 1991, Agric. For. Meteorol.
      54:107); Arrhenius with Ea = 46.39 kJ mol⁻¹ (Bernacchi et al. 2001). The model has no
      light inhibition of day respiration: Rd in light is the dark value (an upper bound).
    * Kc, Ko, Γ* and the Rd temperature response: Bernacchi et al. (2001, Plant Cell
      Environ. 24:253); Vcmax and Jmax: peaked form of Medlyn et al. (2002) with Kattge &
      Knorr's (2007) Ha, Hd and ΔS at T_growth = 15 °C
      (:meth:`TemperatureParams.kattge_knorr2007`).
    * alpha = 0.352 electrons per absorbed photon = 4 × 0.088, the maximum photon yield of C3
      leaves without photorespiration (0.088 mol CO2 mol⁻¹ photons; Evans 2013, Plant Physiol.
      162:1780, Fig. 2), since J/4 is the CO2 rate at no photorespiration; at 25 °C and
      400 ppm this gives a low-light yield of 0.063 (0.058 in normal air in the same
      figure). theta = 0.7, the wheat-leaf convexity of the same figure (Evans & Farquhar 1991
      data, Ögren & Evans 1993 equation).
    * Stomata: Medlyn et al. (2011) unified optimal model (``"medlyn"``) with g1 = 5.79
      kPa^0.5, the C3-crop value of Lin et al. (2015, Nature Clim. Change 5:459) that CLM5
      uses for wheat; g0 = 0.01 mol H2O m⁻² s⁻¹ = 6.25e-3 mol CO2 m⁻² s⁻¹, the low end
      of night-time conductances of C3 crop leaves (Caird et al. 2007, Plant Physiol.
      143:4); it sets only ci in the dark (ci = ca + Rd/g0), not An.
``"cplantbox"``
    Defaults of CPlantBox 2.1.1 ``Photosynthesis.h`` (C3, Tuzet closure as CPlantBox
    implements it, CPlantBox temperature forms, Chl = 55 µg cm⁻², VcmaxrefChl1/2 =
    0.64/4.165, a1 = 4, a3 = 1.7, alpha = 0.2, theta = 0.9, g0 = 3e-4 mol m⁻² s⁻¹).
``"giraud2023"``
    The reference paper's preset, kept for exact replication (Vcmax_ref ≈ 655, Rd ≈ 10 µmol
    m⁻² s⁻¹ at 20 °C: not physiologically credible, see docs/design.md §4). Wheat values of
    Giraud et al. (2023) as the reference paper used them through
    CPlantBox (``plant_photosynthesis/wheat_FcVB_Giraud2023adapted.py`` and docs/design.md §4):
    VcmaxrefChl1/2 = 1.28/8.33, Chl from SPAD 41 (Qian et al. 2021 formula, value passed
    to CPlantBox unchanged; SPAD 41 is that file's, the reference paper's own script set 56.5,
    docs/design.md §4), a1 = 1.5, a3 = 1.5, alpha = 0.4, theta = 0.6, g0 = 8e-3.
``"giraud2023_coupled"``
    The same leaf, but CO2 at the leaf surface, ci, gs and An solved as one coupled fixed
    point with the Tuzet (2003) conductance (``a1_tuzet = 1 + a1_cplantbox = 2.5``, which
    comes close to CPlantBox's ci/cs as g0 → 0 without a boundary layer; not equal, as CPlantBox
    anchors ci on Γ′, with Rd, and Tuzet on Γ*: docs/photosynthesis.md).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.typing import ArrayLike, DTypeLike

from lightfit.errors import InputError, is_real

from .constants import AIR_O2_MMOL_MOL, T25_K

TEMPERATURE_FORMS = ("cplantbox", "peaked")
STOMATAL_MODELS = ("cplantbox", "tuzet", "leuning", "medlyn")


class TemperatureParams(eqx.Module):
    """Temperature-response parameters.

    Attributes:
        t_ref_k: reference temperature [K] at which the ``*_ref`` values hold.
        kc_ref_umol_mol: Michaelis constant of Rubisco for CO2 at ``t_ref_k`` [µmol mol⁻¹].
        ko_ref_mmol_mol: Michaelis constant of Rubisco for O2 at ``t_ref_k`` [mmol mol⁻¹].
        gamma_star_ref_umol_mol: CO2 compensation point without day respiration, Γ*,
            at ``t_ref_k`` [µmol mol⁻¹].
        ea_kc_j_mol, ea_ko_j_mol, ea_gamma_star_j_mol, ea_vcmax_j_mol, ea_jmax_j_mol,
            ea_rd_j_mol: activation energies [J mol⁻¹].
        hd_vcmax_j_mol, hd_jmax_j_mol: deactivation energies [J mol⁻¹].
        entropy_vcmax_j_mol_k, entropy_jmax_j_mol_k: entropy terms [J mol⁻¹ K⁻¹].
        form: ``"cplantbox"`` or ``"peaked"`` (see :mod:`.temperature`).
    """

    t_ref_k: jax.Array | float
    kc_ref_umol_mol: jax.Array | float
    ko_ref_mmol_mol: jax.Array | float
    gamma_star_ref_umol_mol: jax.Array | float
    ea_kc_j_mol: jax.Array | float
    ea_ko_j_mol: jax.Array | float
    ea_gamma_star_j_mol: jax.Array | float
    ea_vcmax_j_mol: jax.Array | float
    ea_jmax_j_mol: jax.Array | float
    ea_rd_j_mol: jax.Array | float
    hd_vcmax_j_mol: jax.Array | float
    hd_jmax_j_mol: jax.Array | float
    entropy_vcmax_j_mol_k: jax.Array | float
    entropy_jmax_j_mol_k: jax.Array | float
    form: str = eqx.field(static=True, default="peaked")

    def __check_init__(self):
        if self.form not in TEMPERATURE_FORMS:
            raise ValueError(f"TemperatureParams.form must be one of {TEMPERATURE_FORMS}, got {self.form!r}")

    @classmethod
    def cplantbox(cls) -> TemperatureParams:
        """CPlantBox 2.1.1 ``Photosynthesis.h`` values (T_ref = 293.2 K; Γ* = 42.75 µmol mol⁻¹ is
        Bernacchi et al. 2001's value at 25 °C, used at 20.05 °C as CPlantBox does; Kc 302 µmol
        mol⁻¹ and Ko 256 mmol mol⁻¹ are CPlantBox's own, not Bernacchi's 404.9 and 278.4)."""
        return cls(
            t_ref_k=293.2,
            kc_ref_umol_mol=302.0,
            ko_ref_mmol_mol=256.0,
            gamma_star_ref_umol_mol=42.75,
            ea_kc_j_mol=59430.0,
            ea_ko_j_mol=36000.0,
            ea_gamma_star_j_mol=37830.0,
            ea_vcmax_j_mol=58520.0,
            ea_jmax_j_mol=37000.0,
            ea_rd_j_mol=53000.0,
            hd_vcmax_j_mol=220000.0,
            hd_jmax_j_mol=220000.0,
            entropy_vcmax_j_mol_k=700.0,
            entropy_jmax_j_mol_k=700.0,
            form="cplantbox",
        )

    @classmethod
    def kattge_knorr2007(cls, t_growth_c: float | None = None) -> TemperatureParams:
        r"""Vcmax and Jmax as Kattge & Knorr (2007, Plant Cell Environ. 30, 1176) fitted them, on
        Bernacchi et al. (2001, Plant Cell Environ. 24, 253) kinetics and Rd.

        Vcmax, Jmax: the peaked form of Medlyn et al. (2002, eq. 18) with K&K's own activation
        energies Ha = 71.513 / 49.884 kJ mol⁻¹, Hd = 200 kJ mol⁻¹ and the entropy terms of their
        acclimation fit, :math:`\Delta S = 668.39 - 1.07\,T_g` and :math:`659.70 - 0.75\,T_g`
        J mol⁻¹ K⁻¹ (T_g the growth temperature, °C). Kc, Ko, Γ* at 25 °C and their activation
        energies, and Rd's (46.39 kJ mol⁻¹): Bernacchi et al. (2001). The pairing of land models
        such as CLM5 (Lawrence et al. 2019), which take K&K's Ha, Hd and ΔS with these kinetics.

        T_g is taken within :data:`KATTGE_KNORR_RANGE_C` (11–35 °C), as CLM4.5 and CLM5 clamp it
        (``PhotosynthesisMod``: ``min(max(T_g, 11), 35)`` in ΔS and in Jmax25/Vcmax25): a colder
        month acts as 11 °C instead of extrapolating the linear fits (at T_g = 0 °C they would give
        Jmax25/Vcmax25 2.59, beyond wheat's 1.6–2.1, and An at 20 °C 31 % above the 11 °C set's).

        Ha belongs with ΔS: the entropy terms were fitted with these Ha, and Bernacchi's Vcmax Ha
        (65.33 kJ mol⁻¹) with K&K's ΔS (this set until the change that introduced this method)
        gives +9 % Vcmax at 15 °C and −8 % at 35 °C against K&K's curve.

        ``t_growth_c`` ``None``: the ``winter_wheat`` set's :data:`WINTER_WHEAT_GROWTH_TEMPERATURE_C`.
        """
        t_growth_c = kattge_knorr_growth_temperature(
            WINTER_WHEAT_GROWTH_TEMPERATURE_C if t_growth_c is None else t_growth_c
        )
        return cls(
            t_ref_k=T25_K,
            kc_ref_umol_mol=404.9,
            ko_ref_mmol_mol=278.4,
            gamma_star_ref_umol_mol=42.75,
            ea_kc_j_mol=79430.0,
            ea_ko_j_mol=36380.0,
            ea_gamma_star_j_mol=37830.0,
            ea_vcmax_j_mol=71513.0,
            ea_jmax_j_mol=49884.0,
            ea_rd_j_mol=46390.0,
            hd_vcmax_j_mol=200000.0,
            hd_jmax_j_mol=200000.0,
            entropy_vcmax_j_mol_k=668.39 - 1.07 * t_growth_c,
            entropy_jmax_j_mol_k=659.70 - 0.75 * t_growth_c,
            form="peaked",
        )


#: Growth temperatures (°C) within which Kattge & Knorr's (2007) linear acclimation is applied; a
#: T_g outside acts as the nearer end (CLM4.5 / CLM5's clamp, Oleson et al. 2013; Lawrence et al. 2019).
KATTGE_KNORR_RANGE_C = (11.0, 35.0)


def kattge_knorr_growth_temperature(t_growth_c: float) -> float:
    """The growth temperature (°C) that Kattge & Knorr's fits take: ``t_growth_c`` clamped to
    :data:`KATTGE_KNORR_RANGE_C`."""
    low, high = KATTGE_KNORR_RANGE_C
    return min(max(float(t_growth_c), low), high)


def kattge_knorr_jmax_to_vcmax(t_growth_c: float) -> float:
    """Jmax25 / Vcmax25 = 2.59 − 0.035·T_g (Kattge & Knorr 2007, T_g the growth temperature, °C,
    within :data:`KATTGE_KNORR_RANGE_C`)."""
    return 2.59 - 0.035 * kattge_knorr_growth_temperature(t_growth_c)


class FvCBParams(eqx.Module):
    """Farquhar–von Caemmerer–Berry C3 leaf parameters.

    Attributes:
        vcmax_ref_umol_m2_s: maximum carboxylation rate at the temperature reference
            [µmol m⁻² s⁻¹]; see :func:`vcmax_ref_from_chlorophyll`.
        jmax_to_vcmax: a3 = Jmax_ref / Vcmax_ref [-].
        rd_to_vcmax: Rd_ref / Vcmax_ref [-] (0.015 after Bonan 2019, as CPlantBox).
        quantum_yield: alpha, electrons per absorbed photon in the light response [-].
        curvature: theta, curvature of the non-rectangular light response (0, 1] [-].
        o2_mmol_mol: intercellular O2 mole fraction [mmol mol⁻¹].
        gm_mol_m2_s: mesophyll conductance to CO2 [mol m⁻² s⁻¹]; ``inf`` = none. Used by
            the coupled closures only (CPlantBox uses its gm in the water path only).
        clip_rates: clip Vc to [0, Vcmax] and Vj to ≥ 0 as CPlantBox does; without it
            the rates turn negative below Γ* (photorespiratory CO2 release).
    """

    vcmax_ref_umol_m2_s: jax.Array | float
    jmax_to_vcmax: jax.Array | float
    rd_to_vcmax: jax.Array | float
    quantum_yield: jax.Array | float
    curvature: jax.Array | float
    o2_mmol_mol: jax.Array | float = AIR_O2_MMOL_MOL
    gm_mol_m2_s: jax.Array | float = float("inf")
    clip_rates: bool = eqx.field(static=True, default=True)


class StomataParams(eqx.Module):
    """Stomatal-conductance closure. Conductances are to CO2 (×1.6 for water vapour).

    Attributes:
        g0_mol_m2_s: residual stomatal conductance [mol m⁻² s⁻¹], > 0 for the coupled
            closures (with g0 = 0 a respiring leaf in the dark has no steady state).
        a1: slope. Its meaning depends on ``model``: for ``"cplantbox"`` it is
            (ci − Γ')/(cs − ci) (Giraud et al. 2023) [-]; for ``"tuzet"`` and ``"leuning"`` it
            is the slope of gs against An/(cs − Γ*) (Tuzet et al. 2003; Leuning 1995) [-];
            for ``"medlyn"`` it is g1 [kPa^0.5] of gs = g0 + (1 + g1/√D)·An/cs (Medlyn
            et al. 2011, conductance to CO2).
        d0_kpa: VPD sensitivity D0 of the Leuning model [kPa].
        model: ``"cplantbox"`` (ci in closed form as CPlantBox), ``"tuzet"``,
            ``"leuning"`` or ``"medlyn"`` (coupled fixed point).
    """

    g0_mol_m2_s: jax.Array | float
    a1: jax.Array | float
    d0_kpa: jax.Array | float = 1.5
    model: str = eqx.field(static=True, default="tuzet")

    def __check_init__(self):
        if self.model not in STOMATAL_MODELS:
            raise ValueError(f"StomataParams.model must be one of {STOMATAL_MODELS}, got {self.model!r}")


class PhotosynthesisParams(eqx.Module):
    """All leaf photosynthesis parameters, with provenance.

    Attributes:
        fvcb: :class:`FvCBParams`.
        temperature: :class:`TemperatureParams`.
        stomata: :class:`StomataParams`.
        name: set name (informative).
        source: literature / software source of the values.
    """

    fvcb: FvCBParams
    temperature: TemperatureParams
    stomata: StomataParams
    name: str = eqx.field(static=True, default="custom")
    source: str = eqx.field(static=True, default="")


def vcmax_ref_from_chlorophyll(
    chl_ug_cm2: ArrayLike, slope: float = 1.28, intercept_umol_m2_s: float = 8.33
) -> ArrayLike:
    r"""Vcmax at the reference temperature from leaf chlorophyll [µmol m⁻² s⁻¹].

    .. math:: V_{cmax,ref} = \mathrm{VcmaxrefChl1}\cdot \mathrm{Chl} + \mathrm{VcmaxrefChl2}

    Args:
        chl_ug_cm2: leaf chlorophyll content as CPlantBox takes it [µg cm⁻²].
        slope: VcmaxrefChl1 [µmol m⁻² s⁻¹ per µg cm⁻²].
        intercept_umol_m2_s: VcmaxrefChl2 [µmol m⁻² s⁻¹].

    Reference: Qian et al. (2021), doi:10.1029/2020JG006076; CPlantBox
    ``Photosynthesis::initVcVjRd``.
    """
    return slope * chl_ug_cm2 + intercept_umol_m2_s


def chlorophyll_from_spad_qian2021(spad: ArrayLike) -> ArrayLike:
    """Leaf chlorophyll from a SPAD reading, 0.114·SPAD² + 7.39·SPAD + 10.6.

    Returns the number CPlantBox scripts pass as ``Chl`` [µg cm⁻² by CPlantBox's
    convention]. The fit of Qian et al. (2021, eq. 1) is in mg m⁻², i.e. ten times the
    µg cm⁻² value; CPlantBox's own docstring notes the values "seem 10 times too high".
    The ``giraud2023`` set keeps the value as the reference paper's scripts used it.
    """
    return 0.114 * spad**2 + 7.39 * spad + 10.6


def _cplantbox() -> PhotosynthesisParams:
    return PhotosynthesisParams(
        fvcb=FvCBParams(
            vcmax_ref_umol_m2_s=vcmax_ref_from_chlorophyll(55.0, 0.64, 4.165),
            jmax_to_vcmax=1.7,
            rd_to_vcmax=0.015,
            quantum_yield=0.2,
            curvature=0.9,
            o2_mmol_mol=AIR_O2_MMOL_MOL,
            clip_rates=True,
        ),
        temperature=TemperatureParams.cplantbox(),
        stomata=StomataParams(g0_mol_m2_s=3e-4, a1=4.0, model="cplantbox"),
        name="cplantbox",
        source="CPlantBox 2.1.1 src/functional/Photosynthesis.h defaults (Giraud et al. 2023, "
        "doi:10.1093/insilicoplants/diad013)",
    )


def _giraud_fvcb() -> FvCBParams:
    return FvCBParams(
        vcmax_ref_umol_m2_s=vcmax_ref_from_chlorophyll(chlorophyll_from_spad_qian2021(41.0), 1.28, 8.33),
        jmax_to_vcmax=1.5,
        rd_to_vcmax=0.015,
        quantum_yield=0.4,
        curvature=0.6,
        o2_mmol_mol=AIR_O2_MMOL_MOL,
        clip_rates=True,
    )


def _giraud2023() -> PhotosynthesisParams:
    return PhotosynthesisParams(
        fvcb=_giraud_fvcb(),
        temperature=TemperatureParams.cplantbox(),
        stomata=StomataParams(g0_mol_m2_s=8e-3, a1=1.5, model="cplantbox"),
        name="giraud2023",
        source="Giraud et al. (2023) wheat, as used by Baker et al. (2025) through CPlantBox "
        "(wheat_FcVB_Giraud2023adapted.py; a1 = 0.6/0.4 as in Giraud's scripts; SPAD 41)",
    )


def _giraud2023_coupled() -> PhotosynthesisParams:
    return PhotosynthesisParams(
        fvcb=_giraud_fvcb(),
        temperature=TemperatureParams.cplantbox(),
        stomata=StomataParams(g0_mol_m2_s=8e-3, a1=2.5, model="tuzet"),
        name="giraud2023_coupled",
        source="giraud2023 leaf with the Tuzet et al. (2003) conductance solved as a coupled "
        "fixed point (a1_tuzet = 1 + a1_cplantbox)",
    )


#: Vcmax at 25 °C of the ``winter_wheat`` set [µmol m⁻² s⁻¹] (module docstring).
WINTER_WHEAT_VCMAX25_UMOL_M2_S = 100.0
#: Medlyn g1 of the ``winter_wheat`` set [kPa^0.5] (Lin et al. 2015, C3 crops).
WINTER_WHEAT_G1_KPA05 = 5.79
#: Growth temperature of the ``winter_wheat`` set's Kattge & Knorr (2007) acclimation [°C].
WINTER_WHEAT_GROWTH_TEMPERATURE_C = 15.0


def _winter_wheat(t_growth_c: float = WINTER_WHEAT_GROWTH_TEMPERATURE_C) -> PhotosynthesisParams:
    t_g = kattge_knorr_growth_temperature(t_growth_c)
    growth = f"{t_g:g} °C growth" + ("" if t_g == t_growth_c else f", {t_growth_c:g} °C given")
    return PhotosynthesisParams(
        fvcb=FvCBParams(
            vcmax_ref_umol_m2_s=WINTER_WHEAT_VCMAX25_UMOL_M2_S,
            jmax_to_vcmax=kattge_knorr_jmax_to_vcmax(t_growth_c),
            rd_to_vcmax=0.015,
            quantum_yield=4 * 0.088,  # Evans (2013), C3 photon yield without photorespiration
            curvature=0.7,
            o2_mmol_mol=AIR_O2_MMOL_MOL,
            clip_rates=True,
        ),
        temperature=TemperatureParams.kattge_knorr2007(t_growth_c),
        stomata=StomataParams(g0_mol_m2_s=0.01 / 1.6, a1=WINTER_WHEAT_G1_KPA05, model="medlyn"),
        name="winter_wheat",
        source="Winter wheat from the literature at 25 °C: Vcmax25 100 (Silva-Pérez et al. 2017, 2020; "
        f"Theobald et al. 1998), Jmax25/Vcmax25 {kattge_knorr_jmax_to_vcmax(t_growth_c):.4g} (Kattge & Knorr 2007 at "
        f"{growth}), "
        "Rd25 0.015 Vcmax25 (Collatz et al. 1991), Bernacchi et al. (2001) kinetics and Rd(T), Kattge & "
        f"Knorr (2007) Vcmax(T), Jmax(T) at {growth}, alpha 4 x 0.088 and theta 0.7 (Evans 2013, "
        "Fig. 2), "
        "Medlyn et al. (2011) stomata with "
        "g1 5.79 kPa^0.5 (Lin et al. 2015, C3 crops) and g0 0.01 mol H2O m-2 s-1 (Caird et al. 2007)",
    )


_SETS: dict[str, Callable[[], PhotosynthesisParams]] = {
    "winter_wheat": _winter_wheat,
    "cplantbox": _cplantbox,
    "giraud2023": _giraud2023,
    "giraud2023_coupled": _giraud2023_coupled,
}

#: Names accepted by :func:`parameter_set`.
PARAMETER_SET_NAMES = tuple(_SETS)


#: Sets whose Vcmax(T), Jmax(T) and Jmax/Vcmax acclimate to the growth temperature (Kattge & Knorr
#: 2007), with the growth temperature they take where none is given, °C.
ACCLIMATING_SETS = {"winter_wheat": WINTER_WHEAT_GROWTH_TEMPERATURE_C}
#: Growth temperatures taken (°C): monthly mean air temperatures of a growing season (below 11 °C
#: they act as 11: :data:`KATTGE_KNORR_RANGE_C`).
GROWTH_TEMPERATURE_RANGE_C = (0.0, 35.0)


def growth_temperature(name: str, growth_temperature_c: float | None = None) -> float | None:
    """The growth temperature (°C) the set ``name`` takes given ``growth_temperature_c``: that, or for
    ``None`` the set's own; ``None`` for a set that does not acclimate."""
    if name not in ACCLIMATING_SETS:
        return None
    return ACCLIMATING_SETS[name] if growth_temperature_c is None else float(growth_temperature_c)


def growth_temperature_setting(name: str, growth_temperature_c):
    """``growth_temperature_c`` as settings keep it: ``None`` where it is the set ``name``'s own (one
    model, one setting: an explicit 15 °C for ``winter_wheat`` is its default), else unchanged."""
    own = ACCLIMATING_SETS.get(name)
    if is_real(growth_temperature_c) and own is not None and float(growth_temperature_c) == own:
        return None
    return growth_temperature_c


def parameter_set(name: str, growth_temperature_c: float | None = None) -> PhotosynthesisParams:
    """Return a named parameter set (see the module docstring for values and sources).

    ``growth_temperature_c``: T_g of Kattge & Knorr (2007), the mean air temperature of the month
    before (°C), for the sets in :data:`ACCLIMATING_SETS`; ``None``: the set's own (15 °C for
    ``winter_wheat``). It sets Jmax25/Vcmax25 = 2.59 − 0.035·T_g and the entropy terms of Vcmax(T)
    and Jmax(T).

    Raises:
        InputError: ``name`` is not one of :data:`PARAMETER_SET_NAMES` (a ValueError, as before).
        InputError: a growth temperature for a set that does not acclimate, or outside
            :data:`GROWTH_TEMPERATURE_RANGE_C`.
    """
    try:
        factory = _SETS[name]
    except (KeyError, TypeError):
        raise InputError(
            f"parameter_set: unknown name {name!r}", parameter="name", expected=f"one of {list(PARAMETER_SET_NAMES)}"
        ) from None
    if growth_temperature_c is None:
        return factory()
    return factory(check_growth_temperature(name, growth_temperature_c))


def check_acclimates(name: str, growth_temperature_c) -> None:
    """:class:`InputError` naming ``growth_temperature_c`` where one is given (any value, e.g. one
    still to be read) for a set ``name`` that does not acclimate (:data:`ACCLIMATING_SETS`)."""
    if growth_temperature_c is not None and name not in ACCLIMATING_SETS:
        raise InputError(
            f"growth_temperature_c={growth_temperature_c!r} with the {name!r} set",
            parameter="growth_temperature_c",
            expected="a set whose temperature responses acclimate (" + ", ".join(ACCLIMATING_SETS) + "), or none",
        )


def check_growth_temperature(name: str, growth_temperature_c, *, problem: str | None = None, file=None) -> float:
    """``growth_temperature_c`` (°C) for the set ``name`` as a float: refused (:class:`InputError`)
    for a set that does not acclimate and outside :data:`GROWTH_TEMPERATURE_RANGE_C`; ``problem``
    and ``file`` say where a value read from data came from."""
    check_acclimates(name, growth_temperature_c)
    lo, hi = GROWTH_TEMPERATURE_RANGE_C
    if not (is_real(growth_temperature_c) and lo <= growth_temperature_c <= hi):
        raise InputError(
            problem or f"growth_temperature_c={growth_temperature_c!r}",
            file=file,
            parameter="growth_temperature_c",
            expected=f"the mean air temperature of the month before, a number in [{lo:g}, {hi:g}] °C"
            + ("" if problem is None else "; give a number instead"),
        )
    return float(growth_temperature_c)


def cast_params(params: PhotosynthesisParams, dtype: DTypeLike) -> PhotosynthesisParams:
    """Cast every float leaf of ``params`` to ``dtype`` (static fields are untouched)."""
    return jax.tree.map(lambda leaf: jnp.asarray(leaf, dtype), params)


def _finite_nonnegative(v, xp):
    return (v >= 0) & xp.isfinite(v)


def _finite_positive(v, xp):
    return (v > 0) & xp.isfinite(v)


#: Domains of the parameters: (field path, predicate(value, xp), expected, applies to the stomatal
#: model or ``None`` for all). One table for the eager refusal (:func:`check_params`) and the traced
#: mask (:func:`params_in_domain`), which under ``jit`` flags the results of values outside it.
_DOMAINS: tuple[tuple[str, Callable, str, Callable[[str], bool] | None], ...] = (
    ("fvcb.vcmax_ref_umol_m2_s", _finite_nonnegative, "finite and >= 0", None),
    ("fvcb.jmax_to_vcmax", _finite_nonnegative, "finite and >= 0", None),
    ("fvcb.rd_to_vcmax", _finite_nonnegative, "finite and >= 0", None),
    ("fvcb.quantum_yield", _finite_nonnegative, "finite and >= 0", None),
    ("fvcb.curvature", lambda v, xp: (v > 0) & (v <= 1), "in (0, 1]", None),
    ("fvcb.o2_mmol_mol", _finite_nonnegative, "finite and >= 0", None),
    ("fvcb.gm_mol_m2_s", lambda v, xp: v > 0, "> 0 (inf for no mesophyll limitation)", None),
    ("stomata.a1", _finite_nonnegative, "finite and >= 0", None),
    ("stomata.d0_kpa", _finite_positive, "finite and > 0", None),
    ("stomata.g0_mol_m2_s", _finite_nonnegative, "finite and >= 0", lambda model: model == "cplantbox"),
    (
        "stomata.g0_mol_m2_s",
        _finite_positive,
        "finite and > 0 for the coupled closures",
        lambda model: model != "cplantbox",
    ),
    ("temperature.t_ref_k", _finite_positive, "finite and > 0 K", None),
    ("temperature.kc_ref_umol_mol", _finite_positive, "finite and > 0", None),
    ("temperature.ko_ref_mmol_mol", _finite_positive, "finite and > 0", None),
    ("temperature.gamma_star_ref_umol_mol", _finite_nonnegative, "finite and >= 0", None),
    *(
        (f"temperature.{name}", lambda v, xp: xp.isfinite(v), "finite", None)
        for name in (
            "ea_kc_j_mol",
            "ea_ko_j_mol",
            "ea_gamma_star_j_mol",
            "ea_vcmax_j_mol",
            "ea_jmax_j_mol",
            "ea_rd_j_mol",
            "hd_vcmax_j_mol",
            "hd_jmax_j_mol",
            "entropy_vcmax_j_mol_k",
            "entropy_jmax_j_mol_k",
        )
    ),
)


def _domains(params: PhotosynthesisParams):
    """(label, value, predicate, expected) of every domain rule that applies to ``params``."""
    for label, ok, expected, applies in _DOMAINS:
        if applies is None or applies(params.stomata.model):
            group, field = label.split(".")
            yield label, getattr(getattr(params, group), field), ok, expected


def check_params(params: PhotosynthesisParams) -> None:
    """Raise ``ValueError`` for physically impossible parameter values.

    Only concrete (non-traced) leaves are checked; under ``jit`` :func:`params_in_domain` flags the
    results instead (the solver's ``converged`` is False there).
    """
    if not isinstance(params, PhotosynthesisParams):
        raise TypeError(f"params must be a PhotosynthesisParams, got {type(params).__name__}")
    for label, value, ok, expected in _domains(params):
        if isinstance(value, jax.core.Tracer):
            continue
        v = np.asarray(value, dtype=float)
        if not np.all(ok(v, np)):
            raise InputError(f"params.{label}={v!r}", parameter=f"params.{label}", expected=str(expected))


def params_in_domain(params: PhotosynthesisParams) -> jax.Array:
    """True where every parameter lies in its domain (:func:`check_params`'s rules, traced or not;
    False for NaN), broadcast over the parameters' shapes (a scalar for scalar parameters)."""
    ok = jnp.asarray(True)
    for _, value, rule, _ in _domains(params):
        ok = ok & rule(jnp.asarray(value), jnp)
    return ok


#: The parameters a run may set over its named set (:func:`with_overrides`), by their field name →
#: ``"group.field"``: every number with a domain rule. Each field name is unique across the groups.
OVERRIDABLE: dict[str, str] = {label.split(".")[1]: label for label, *_ in _DOMAINS}


_EA = (0.0, 300e3, "activation energies of C3 kinetics and capacities are ≈ 35–120 kJ mol⁻¹")
#: Credible ranges of the numbers a run sets over its set (:func:`with_overrides`), name → (low, high,
#: why), both ends taken: typo guards, each well beyond the parameter's published range and holding
#: every named set's own value. The domains (:data:`_DOMAINS`) say only what the solver can do: a1,
#: Vcmax or Rd/Vcmax of 1e30 gave "converged" fluxes of −1e28 µmol m⁻² s⁻¹, 1e308 NaN. Checked on the
#: concrete overrides only; under ``jit`` (calibration) the domains alone apply.
OVERRIDE_RANGES: dict[str, tuple[float, float, str]] = {
    # leaf Vcmax25 of C3 crops ≈ 20–200 (wheat flag leaves 80–150, Silva-Pérez et al. 2020); the
    # giraud2023 set's 655 at 20 °C must stay possible
    "vcmax_ref_umol_m2_s": (0.0, 1000.0, "leaf Vcmax of C3 crops is ≈ 20–200 µmol m⁻² s⁻¹"),
    # 1.4–2.6 (Wullschleger 1993; Kattge & Knorr 2007 give 2.2–1.4 over 0–35 °C growth)
    "jmax_to_vcmax": (0.0, 5.0, "Jmax/Vcmax of C3 leaves is ≈ 1.4–2.6"),
    # 0.01–0.03 (Collatz et al. 1991: 0.015; Atkin et al. 2015)
    "rd_to_vcmax": (0.0, 0.2, "Rd/Vcmax of C3 leaves is ≈ 0.01–0.03"),
    # linear electron transport takes two photons per electron (PSII and PSI): at most 0.5
    "quantum_yield": (0.0, 0.5, "at most 0.5 electrons per absorbed photon (two photosystems); leaves ≈ 0.2–0.4"),
    # a mole fraction: air 210 mmol mol⁻¹, pure O2 1000
    "o2_mmol_mol": (0.0, 1000.0, "a mole fraction: 210 in air, 1000 in pure O2"),
    # Medlyn g1 1.6–7.2 kPa^0.5 across plant types (Lin et al. 2015); Leuning / Tuzet a1 ≈ 5–20;
    # CPlantBox's ratio 1.5–4
    "a1": (0.0, 50.0, "stomatal slopes are ≈ 1–20 (Medlyn g1 1.6–7.2 kPa^0.5, Lin et al. 2015)"),
    # Leuning (1995) D0 ≈ 0.35–3 kPa; air seldom reaches a VPD of 7 kPa
    "d0_kpa": (0.0, 20.0, "Leuning's D0 is ≈ 0.35–3 kPa"),
    # night conductances ≈ 0.01–0.1 mol H2O m⁻² s⁻¹ (Caird et al. 2007); a fully open leaf ≈ 1 mol
    # H2O (0.6 CO2)
    "g0_mol_m2_s": (0.0, 1.0, "residual conductances to CO2 are ≈ 0.0003–0.06 mol m⁻² s⁻¹"),
    "t_ref_k": (273.15, 323.15, "a reference temperature of 0–50 °C (sets: 20.05 or 25 °C)"),
    # at 25 °C: Kc ≈ 260–460 µmol mol⁻¹, Ko ≈ 150–500 mmol mol⁻¹, Γ* ≈ 35–45 µmol mol⁻¹ (von
    # Caemmerer 2000; Bernacchi et al. 2001); ≈ 12×, 2× and 3× that at a 50 °C reference
    "kc_ref_umol_mol": (0.0, 10e3, "Kc is ≈ 260–460 µmol mol⁻¹ at 25 °C"),
    "ko_ref_mmol_mol": (0.0, 5e3, "Ko is ≈ 150–500 mmol mol⁻¹ at 25 °C"),
    "gamma_star_ref_umol_mol": (0.0, 500.0, "Γ* is ≈ 35–45 µmol mol⁻¹ at 25 °C"),
    **{f"ea_{n}_j_mol": _EA for n in ("kc", "ko", "gamma_star", "vcmax", "jmax", "rd")},
    # Hd ≈ 150–220 kJ mol⁻¹, ΔS ≈ 480–720 J mol⁻¹ K⁻¹ (Medlyn et al. 2002; Kattge & Knorr 2007; CPlantBox 700)
    **{f"hd_{n}_j_mol": (0.0, 500e3, "deactivation energies are ≈ 150–220 kJ mol⁻¹") for n in ("vcmax", "jmax")},
    **{f"entropy_{n}_j_mol_k": (400.0, 900.0, "entropy terms are ≈ 480–720 J mol⁻¹ K⁻¹") for n in ("vcmax", "jmax")},
}


def _group(name: str) -> str:
    """The parameter group (``fvcb``, ``stomata``, …) holding the number ``name`` (:data:`OVERRIDABLE`)."""
    return OVERRIDABLE[name].split(".")[0]


def value_of(params: PhotosynthesisParams, name: str):
    """The number ``name`` (:data:`OVERRIDABLE`) of ``params``, as it is stored (traced or not)."""
    return getattr(getattr(params, _group(name)), name)


def replaced(params: PhotosynthesisParams, values: Mapping, **fields) -> PhotosynthesisParams:
    """``params`` with the numbers ``values`` (field name → value, names from :data:`OVERRIDABLE`)
    put in their groups, and its own ``fields`` (e.g. ``source``) replaced. Works on traced values."""
    groups: dict[str, dict] = {}
    for name, value in values.items():
        groups.setdefault(_group(name), {})[name] = value
    return dataclasses.replace(
        params, **{g: dataclasses.replace(getattr(params, g), **kw) for g, kw in groups.items()}, **fields
    )


def check_overrides(overrides, *, parameter: str = "photosynthesis_overrides") -> tuple[tuple[str, float], ...]:
    """``overrides`` (a mapping name → value, or (name, value) pairs as read back from JSON; ``None``:
    none) as (name, float) pairs sorted by name, one form whatever it came from. :class:`InputError`
    naming ``parameter`` for a name not in :data:`OVERRIDABLE`, a name given twice or a value that is
    not a real number; the domains, some of which depend on the set's stomatal model, are
    :func:`with_overrides`'s."""
    if overrides is None:
        return ()
    expected = (
        "(name, value) pairs with names from: "
        + ", ".join(OVERRIDABLE)
        + " (a1: the stomatal slope, Medlyn's g1 in kPa^0.5 for winter_wheat)"
    )
    try:
        pairs = [tuple(p) for p in (overrides.items() if isinstance(overrides, Mapping) else overrides)]
    except TypeError:
        raise InputError(f"{parameter}={overrides!r}", parameter=parameter, expected=expected) from None
    out: dict[str, float] = {}
    for pair in pairs:
        if len(pair) != 2 or not isinstance(pair[0], str):
            raise InputError(repr(pair), parameter=parameter, expected=expected)
        name, value = pair
        if name not in OVERRIDABLE:
            raise InputError(f"unknown parameter {name!r}", parameter=parameter, expected=expected)
        if name in out:
            raise InputError(f"{name!r} given more than once", parameter=parameter, expected="each once")
        if not is_real(value):
            raise InputError(f"{name}={value!r}", parameter=parameter, expected=f"{name} a number")
        out[name] = float(value)
    return tuple(sorted(out.items()))


def with_overrides(
    params: PhotosynthesisParams, overrides, *, parameter: str = "photosynthesis_overrides"
) -> PhotosynthesisParams:
    """``params`` with some of its numbers replaced (``overrides``: :func:`check_overrides`), e.g.
    ``with_overrides(parameter_set("winter_wheat"), {"a1": 4.5, "vcmax_ref_umol_m2_s": 85})`` for a
    leaf's own measured Vcmax at the set's reference temperature and Medlyn's g1. They are applied
    last: an override of ``jmax_to_vcmax`` wins over the growth temperature's. The set keeps its
    name; its ``source`` lists what was set. :class:`InputError` naming ``parameter`` where a value
    lies outside its domain (:func:`check_params`'s rules for the set's stomatal model) or its
    credible range (:data:`OVERRIDE_RANGES`)."""
    given = dict(check_overrides(overrides, parameter=parameter))
    if not given:
        return params
    said = ", ".join(f"{n}={v:g}" for n, v in given.items())
    out = replaced(params, given, source=f"{params.source}; set by the run: {said}")
    for label, value, ok, expected in _domains(out):
        name = label.split(".")[1]
        if name in given and not np.all(ok(np.asarray(value, float), np)):
            raise InputError(f"{name}={value!r}", parameter=parameter, expected=f"{name} {expected}")
    for name, value in given.items():
        lo, hi, why = OVERRIDE_RANGES.get(name, (-np.inf, np.inf, ""))
        if not lo <= value <= hi:
            raise InputError(f"{name}={value!r}", parameter=parameter, expected=f"{name} in [{lo:g}, {hi:g}]: {why}")
    return out
