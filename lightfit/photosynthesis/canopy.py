r"""Photosynthetic capacity through the canopy: leaves deeper in it have less.

Leaves acclimate to the light they grow in: nitrogen, and with it Rubisco and the electron
transport chain, goes where the light is. The standard description (de Pury & Farquhar 1997,
Plant Cell Environ. 20:537; CLM4.5/CLM5, Lawrence et al. 2019) is an exponential in the leaf
area above a leaf,

.. math::

    V_{cmax,25}(L) = V_{cmax,25}^{top}\, e^{-k_n L},

with :math:`L` the one-sided blade area above the leaf per ground area (m² m⁻²). Jmax and Rd
keep their ratios to Vcmax (every parameter set ties them to it), so the whole leaf's capacity
per area scales by :math:`m = e^{-k_n L}`. lightfit applies :math:`m` to every per-area rate and
conductance of the leaf (Vcmax, Jmax, Rd, g0 and a finite gm): with no leaf boundary layer in the
coupled model (cs = ca) such a leaf at absorbed PAR q has exactly

.. math::

    A_n(q;\, m) = m\, A_n(q/m;\, 1),

gs likewise times m, ci unchanged (every closure: the non-rectangular hyperbola, the FvCB rates
and the stomatal slopes are homogeneous of degree one in those quantities). That identity is how
:func:`lightfit.model.observe.with_capacity` evaluates profiled blades with any leaf evaluator,
tabulated ones included (the lowest capacity as the base leaf, so no
blade's light is scaled up); g0 scaling with the leaf is lightfit's choice (CLM keeps it fixed) and
matters only where An is near zero (measured in docs/photosynthesis.md, "Capacity through the
canopy").

Units: heights m, areas m², Vcmax µmol m⁻² s⁻¹, :math:`k_n` per unit leaf area index (m² m⁻²)⁻¹.
"""

from __future__ import annotations

import math

import numpy as np

from lightfit.errors import InputError

from .constants import T25_K
from .fvcb import capacity_temperature_factors
from .parameters import PhotosynthesisParams

#: Lloyd et al. (2010, Biogeosciences 7:1833, eq. A2 and Fig. 10), as CLM4.5/CLM5 use it for every
#: plant type: ln kn = a·Vcmax25_top + b, a in (µmol m⁻² s⁻¹)⁻¹.
LLOYD2010_SLOPE = 0.00963
LLOYD2010_INTERCEPT = -2.43
#: Named profiles (besides a number, kn itself): ``"auto"`` is each parameter set's own
#: (:data:`SET_PROFILES`), resolved by :func:`profile_for`.
PROFILES = ("auto", "lloyd2010", "depury1997", "uniform")
#: kn of de Pury & Farquhar's (1997, Plant Cell Environ. 20:537) wheat canopy, per unit LAI: a
#: crop's own value, three times as steep as Lloyd et al.'s at Vcmax25 = 100 (as the Daisy crop model
#: takes it for its wheat; the paper's own profile may be per relative depth l/Lc: docs/photosynthesis.md).
DEPURY1997_KN = 0.713
#: The profile ``"auto"`` gives a set: Lloyd et al.'s for the literature set; the CPlantBox-derived
#: sets (the reference paper's among them) model none, and giraud2023's Vcmax lies far outside Lloyd's fit.
SET_PROFILES = {"winter_wheat": "lloyd2010"}
#: Vcmax25 above which Lloyd et al.'s fit is not extrapolated (kn would exceed 0.6: the lowest
#: leaves of an LAI-4 canopy with a tenth of the top's capacity). The reference paper's
#: ``giraud2023`` set (Vcmax ≈ 970 at 25 °C) lies far above it.
LLOYD2010_MAX_VCMAX25 = 200.0
#: The steepest kn taken (per unit LAI): capacity falling e-fold within half a unit of leaf area,
#: beyond the profiles of crop and forest canopies in the sources above; the lowest blades of an
#: LAI-4 canopy would keep e⁻⁸ = 3·10⁻⁴ of the top's, near where the solver's tolerances act.
MAX_KN = 2.0


def kn_lloyd2010(vcmax25_top_umol_m2_s: float) -> float:
    """Extinction coefficient of photosynthetic capacity, kn = exp(0.00963·Vcmax25,top − 2.43)
    per unit LAI (Lloyd et al. 2010, eq. A2; CLM5 technical note, Lawrence et al. 2019).
    ``vcmax25_top_umol_m2_s``: Vcmax at 25 °C of the top leaves, µmol m⁻² s⁻¹ (100 → 0.231)."""
    return math.exp(LLOYD2010_SLOPE * float(vcmax25_top_umol_m2_s) + LLOYD2010_INTERCEPT)


def vcmax25(params: PhotosynthesisParams) -> float:
    """The set's Vcmax at 25 °C, µmol m⁻² s⁻¹ (its ``vcmax_ref`` holds at its own T_ref: 20 °C for
    CPlantBox's sets)."""
    temp = params.temperature
    if temp.form != "cplantbox" and float(temp.t_ref_k) == T25_K:
        # The peaked form is 1 at its reference by construction: no JAX call (a command line checks
        # its options with this before anything runs, and JAX would fill its compilation cache).
        return float(params.fvcb.vcmax_ref_umol_m2_s)
    f_v, _ = capacity_temperature_factors(T25_K, temp)
    return float(params.fvcb.vcmax_ref_umol_m2_s) * float(f_v)


def profile_for(profile: str | float, set_name: str) -> str | float:
    """``profile`` with ``"auto"`` replaced by the set's own (:data:`SET_PROFILES`, else
    ``"uniform"``); anything else checked (:func:`check_profile`) and returned."""
    profile = check_profile(profile)
    return SET_PROFILES.get(set_name, "uniform") if profile == "auto" else profile


def resolve_kn(profile: str | float, params: PhotosynthesisParams) -> float:
    """kn (per unit LAI) of a resolved capacity profile (:func:`profile_for`) for the parameter set
    ``params``: ``"uniform"`` → 0 (every leaf the set's capacity, as the reference paper),
    ``"depury1997"`` → :data:`DEPURY1997_KN`, ``"lloyd2010"`` → :func:`kn_lloyd2010`
    of the set's Vcmax at 25 °C, a number in [0, :data:`MAX_KN`] (or its text) → itself. :class:`InputError` naming
    ``vcmax_profile`` otherwise, and for Lloyd's fit beyond :data:`LLOYD2010_MAX_VCMAX25`."""
    if profile == "uniform":
        return 0.0
    if profile == "depury1997":
        return DEPURY1997_KN
    if profile == "lloyd2010":
        v25 = vcmax25(params)
        if not v25 <= LLOYD2010_MAX_VCMAX25:
            raise InputError(
                f"vcmax_profile='lloyd2010' with a Vcmax of {v25:.0f} µmol m-2 s-1 at 25 °C",
                parameter="vcmax_profile",
                expected=f"Lloyd et al.'s fit within its leaves' range (Vcmax25 ≤ {LLOYD2010_MAX_VCMAX25:g}): "
                f"'uniform' or a kn of your own (a number in [0, {MAX_KN:g}])",
            )
        return kn_lloyd2010(v25)
    return _kn_number(profile)


def _kn_number(profile) -> float:
    try:
        kn = float(profile)
    except (TypeError, ValueError):
        kn = math.nan
    if not 0 <= kn <= MAX_KN:  # NaN fails too
        raise InputError(
            f"vcmax_profile={profile!r}",
            parameter="vcmax_profile",
            expected=" or ".join(map(repr, PROFILES)) + f", or kn itself: a number in [0, {MAX_KN:g}] per unit LAI",
        )
    return kn


def check_profile(profile: str | float) -> str | float:
    """``profile`` as stored in settings: a name of :data:`PROFILES` or a float kn in (0, MAX_KN]
    (text taken as its number; kn = 0 is ``"uniform"``, one name for one model); :class:`InputError`
    otherwise. The set-dependent check is :func:`resolve_kn`'s."""
    if profile in PROFILES:
        return profile
    kn = _kn_number(profile)
    return "uniform" if kn == 0 else kn


def leaf_area_above(height_m, area_m2, ground_area_m2: float) -> np.ndarray:
    """Cumulative leaf area index above each leaf element, m² m⁻²: the one-sided area of the
    elements whose height is greater than its own, per ``ground_area_m2`` (elements at one height
    do not count each other). ``height_m``, ``area_m2``: (B,) heights (m) and one-sided areas (m²)
    of the canopy's leaf elements (lightfit: blade segments, so one leaf's base and tip differ), all
    of those the ground area holds. A height that is not finite or an area that is not finite and
    ≥ 0 is refused (:class:`InputError` naming ``height_m`` or ``area_m2``): a NaN height was
    counted below every leaf and a negative area subtracted from the leaves beneath it."""
    z = np.asarray(height_m, np.float64)
    a = np.asarray(area_m2, np.float64)
    if z.shape != a.shape or z.ndim != 1:
        raise InputError(f"heights {z.shape} and areas {a.shape}", parameter="area_m2", expected="two (B,) arrays")
    if not np.isfinite(z).all():
        bad = np.flatnonzero(~np.isfinite(z))
        raise InputError(
            f"height_m[{bad[0]}] = {z[bad[0]]!r} ({len(bad)} of {len(z)} not finite)",
            parameter="height_m",
            expected="finite heights of the leaf elements, m",
        )
    if not (np.isfinite(a) & (a >= 0)).all():
        bad = np.flatnonzero(~(np.isfinite(a) & (a >= 0)))
        raise InputError(
            f"area_m2[{bad[0]}] = {a[bad[0]]!r} ({len(bad)} of {len(a)} not finite and ≥ 0)",
            parameter="area_m2",
            expected="finite one-sided areas ≥ 0 of the leaf elements, m²",
        )
    if not (np.isfinite(ground_area_m2) and ground_area_m2 > 0):
        raise InputError(f"ground_area_m2={ground_area_m2!r}", parameter="ground_area_m2", expected="a finite area > 0")
    order = np.argsort(-z, kind="stable")
    zs, cum = z[order], np.cumsum(a[order])
    # Leaves strictly higher: the cumulative area before the first leaf at each one's height.
    first = np.searchsorted(-zs, -zs, side="left")
    above = np.where(first > 0, cum[np.maximum(first - 1, 0)], 0.0)
    out = np.empty_like(z)
    out[order] = above / float(ground_area_m2)
    return out


def capacity_factor(lai_above, kn: float) -> np.ndarray:
    """m = exp(−kn·L): a leaf's capacity per area relative to the top leaves' (dimensionless)."""
    return np.exp(-float(kn) * np.asarray(lai_above, np.float64))


__all__ = [
    "DEPURY1997_KN",
    "LLOYD2010_INTERCEPT",
    "LLOYD2010_MAX_VCMAX25",
    "LLOYD2010_SLOPE",
    "MAX_KN",
    "PROFILES",
    "SET_PROFILES",
    "capacity_factor",
    "check_profile",
    "kn_lloyd2010",
    "leaf_area_above",
    "profile_for",
    "resolve_kn",
    "vcmax25",
]
