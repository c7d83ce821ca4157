r"""Leaf optics from leaf traits: PROSPECT-D PAR reflectance and transmittance, and the leaf presets.

One concept: leaf traits → the leaf's PAR-band reflectance R and transmittance T (PROSPECT-D,
Féret et al. 2017, through the ``xleaf`` package's bindings to the authors' Fortran code) → the
diffuse part of the leaf BSDF (:mod:`lightfit.light.bsdf`) that reproduces them.

**PAR band.** R and T are averaged over 400–700 nm weighted by the photon flux of a 5800 K
blackbody (the solar disc; photon spectral flux ∝ λ⁻⁴ / (exp(hc/λkT) − 1)), on PROSPECT's
1 nm grid (trapezoid rule).

**Mapping to the BSDF.** The three calibrated parameters keep their meanings: ``specular`` s
gives the glossy lobe's normal-incidence reflectance F0 = 0.08·s, ``roughness`` its GGX
roughness, ``subsurface`` the share of the diffuse light transmitted. PROSPECT's R contains the
surface (specular) reflection, so with :math:`\bar E(r) = 2\int_0^1 E_{GGX}(\mu, r)\,\mu\,d\mu`
the glossy lobe's albedo under a uniform sky (:func:`lightfit.light.bsdf.ggx_white_sky_albedo`),
the leaf's bi-hemispherical albedo is :math:`F_0\bar E + (1 - F_0)c` and its transmittance
:math:`(1 - F_0)\,ss\,c`. Matching them to R and T gives

.. math::

    c = \frac{R + T - F_0\bar E}{1 - F_0}, \qquad ss = \frac{T}{R + T - F_0\bar E}

so the leaf's absorptance is PROSPECT's :math:`1 - R - T` and its transmittance is T.

**Presets** (:data:`PRESETS`): ``prospect``, lightfit's default (:data:`DEFAULT_PRESET`: the
default traits :class:`LeafTraits` with the default specular 0.5 and roughness 0.5; base colour
≈ 0.067 and subsurface ≈ 0.596 derived) and ``paper`` (the reference paper's grey leaf: base
colour 0.5, the paper's §2.2; specular 0.5 and roughness 0.5, Unreal Engine's defaults; subsurface
0.3, lightfit's first leaf's: the paper prints no subsurface value and its §2.4 says the leaf
surface leaves subsurface scattering out).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from functools import lru_cache

import numpy as np

from lightfit.errors import InputError, check_fraction, check_real

PAR_BAND_NM = (400.0, 700.0)
#: Temperature of the blackbody whose photon spectrum weights the PAR band (the solar disc).
PAR_BLACKBODY_K = 5800.0
PRESETS = ("prospect", "paper")
#: The leaf optics of lightfit's credible default (``Scenario.optics``, ``Theta``'s leaf defaults).
DEFAULT_PRESET = "prospect"
#: Prior range of leaf chlorophyll a+b (µg cm⁻²) for wheat: genotype-mean SPAD 32–52 in 28 wheat
#: genotypes over several environments (Hamblin et al. 2014, PLoS ONE 9:e92529) through the SPAD
#: fit of :attr:`LeafTraits.Cab` (Qian et al. 2021; mg m⁻² / 10). The default 50.5 (SPAD 41) lies inside.
CHLOROPHYLL_PRIOR_UG_CM2 = (36.4, 70.3)
#: The reference paper's grey leaf (Baker et al. 2025; lightfit's defaults until the `prospect` preset):
#: base colour 0.5 is the paper's (§2.2, diffuse grey (0.5, 0.5, 0.5)); specular and roughness 0.5
#: are Unreal Engine's defaults; subsurface 0.3 is lightfit's own (the paper prints none, and its
#: §2.4 says the leaf surface leaves subsurface scattering out).
PAPER_LEAF = {"specular": 0.5, "roughness": 0.5, "subsurface": 0.3, "base_color": 0.5}

# Valid ranges of the traits (PROSPECT-D calibration and validation data span well inside them).
_TRAIT_RANGES = {
    "N": (1.0, 4.0, "leaf structure parameter (layers), 1–4"),
    "Cab": (0.0, 200.0, "chlorophyll a+b in µg cm⁻², 0–200"),
    "Car": (0.0, 50.0, "carotenoids in µg cm⁻², 0–50"),
    "Anth": (0.0, 50.0, "anthocyanins in µg cm⁻², 0–50"),
    "Cw": (0.0, 0.1, "equivalent water thickness in cm (g cm⁻²), 0–0.1"),
    "Cm": (0.0, 0.05, "dry matter (LMA) in g cm⁻², 0–0.05"),
}


@dataclass(frozen=True)
class LeafTraits:
    """PROSPECT-D leaf traits; defaults: a Selhausen-like winter wheat leaf at stem elongation.

    Attributes:
        N: leaf structure parameter (number of layers). 1.5: thin monocot leaves
            (Jacquemoud & Baret 1990: 1–1.5 for monocots; PROSPECT's usual default).
        Cab: chlorophyll a+b, µg cm⁻². 50.5: SPAD 41 (CPlantBox's Giraud et al. 2023 wheat
            file, which ``giraud2023`` takes; the reference paper prints no SPAD reading, and its
            own script set 56.5, docs/design.md §4) through the SPAD fit the paper's wheat photosynthesis uses (Qian et
            al. 2021, 0.114·SPAD² + 7.39·SPAD + 10.6 mg m⁻² = 505 mg m⁻²; Markwell et al. 1995
            gives 42 at the same SPAD).
        Car: carotenoids, µg cm⁻². 10: Car/Cab ≈ 0.2 of green leaves (Féret et al. 2017 data).
        Anth: anthocyanins, µg cm⁻². 0.5: green leaves hold almost none (PROSPECT-D ≈ 0–1).
        Cw: equivalent water thickness, cm (= g cm⁻² of water). 0.015: 75 % water in fresh
            mass with Cm 0.005, i.e. 3 × Cm.
        Cm: dry matter per area (LMA), g cm⁻². 0.005: 50 g m⁻², specific leaf area ≈ 20 m² kg⁻¹
            of wheat leaves at stem elongation.
    """

    N: float = 1.5
    Cab: float = 50.5
    Car: float = 10.0
    Anth: float = 0.5
    Cw: float = 0.015
    Cm: float = 0.005

    def __post_init__(self):
        for name, v in asdict(self).items():
            lo, hi, what = _TRAIT_RANGES[name]
            object.__setattr__(self, name, check_real(v, f"leaf trait {name}", lo, hi, parameter=name, expected=what))


@dataclass(frozen=True)
class LeafPAR:
    """PAR-band (400–700 nm, photon-weighted) leaf reflectance R and transmittance T."""

    R: float
    T: float

    @property
    def A(self) -> float:
        """Absorptance 1 − R − T."""
        return 1.0 - self.R - self.T


def prospect_d(traits: LeafTraits = LeafTraits()) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """PROSPECT-D spectra: wavelengths (nm, 400–2500 by 1), reflectance, transmittance."""
    import xleaf

    if not isinstance(traits, LeafTraits):
        raise InputError(f"leaf traits {traits!r}", parameter="traits", expected="a LeafTraits")
    t = traits
    r, tr = xleaf.simulate_leaf(
        chl=float(t.Cab),
        car=float(t.Car),
        antho=float(t.Anth),
        ewt=float(t.Cw),
        lma=float(t.Cm),
        N=float(t.N),
        transmittance=True,
    )
    return np.asarray(xleaf.wavelengths, float) * 1000.0, np.asarray(r, float), np.asarray(tr, float)


def par_photon_weights(wavelength_nm: np.ndarray) -> np.ndarray:
    """Photon spectral flux of a blackbody (relative), ∝ λ⁻⁴ / (exp(hc/λkT) − 1)."""
    hc_over_k = 1.438776877e7  # nm K (second radiation constant c2)
    lam = np.asarray(wavelength_nm, float)
    return lam**-4 / np.expm1(hc_over_k / (lam * PAR_BLACKBODY_K))


def band_average(wavelength_nm: np.ndarray, values: np.ndarray) -> float:
    """Photon-weighted mean of ``values`` over the PAR band (:data:`PAR_BAND_NM`; trapezoid rule on
    the given grid)."""
    m = (wavelength_nm >= PAR_BAND_NM[0]) & (wavelength_nm <= PAR_BAND_NM[1])
    w = par_photon_weights(wavelength_nm[m])
    return float(np.trapezoid(values[m] * w, wavelength_nm[m]) / np.trapezoid(w, wavelength_nm[m]))


def check_leaf(optics: str, chlorophyll_ug_cm2: float | None = None) -> None:
    """A known leaf preset (:data:`PRESETS`), and chlorophyll only for the ``prospect`` leaf, in
    PROSPECT-D's range; cheap (no spectra computed), so commands check it before plants grow."""
    if optics not in PRESETS:
        raise InputError(f"optics={optics!r}", parameter="optics", expected=" or ".join(PRESETS))
    if chlorophyll_ug_cm2 is None:
        return
    if optics != "prospect":
        raise InputError(
            f"chlorophyll_ug_cm2={chlorophyll_ug_cm2!r} with optics {optics!r}",
            parameter="chlorophyll_ug_cm2",
            expected="optics 'prospect' (the paper's grey leaf is not made from leaf traits)",
        )
    try:
        LeafTraits(Cab=chlorophyll_ug_cm2)
    except InputError as e:
        raise InputError(
            f"chlorophyll_ug_cm2={chlorophyll_ug_cm2!r}", parameter="chlorophyll_ug_cm2", expected=e.expected
        ) from None


def leaf_traits(optics: str, chlorophyll_ug_cm2: float | None = None) -> LeafTraits | None:
    """The traits a leaf preset is made from: the ``prospect`` leaf's, with ``chlorophyll_ug_cm2``
    where given, else :class:`LeafTraits`' defaults; ``None`` for a leaf not made from traits (the
    paper's grey leaf). Checked as :func:`check_leaf`."""
    check_leaf(optics, chlorophyll_ug_cm2)
    if optics != "prospect":
        return None
    return LeafTraits() if chlorophyll_ug_cm2 is None else LeafTraits(Cab=chlorophyll_ug_cm2)


@lru_cache(maxsize=256)
def par_optics(traits: LeafTraits = LeafTraits()) -> LeafPAR:
    """The leaf's PAR reflectance and transmittance from its traits (PROSPECT-D)."""
    wl, r, t = prospect_d(traits)
    return LeafPAR(band_average(wl, r), band_average(wl, t))


#: The glossy lobe of lightfit's leaves unless given: Unreal Engine's defaults, as the reference paper's
#: material had them; F0 = 0.08 × 0.5 = 4 %, within the measured 3.7–5.9 % upper-surface reflection
#: (docs/light.md, "Leaf optics"), and GGX α = 0.25.
DEFAULT_SPECULAR = 0.5
DEFAULT_ROUGHNESS = 0.5


def leaf_bsdf_parameters(
    traits: LeafTraits = LeafTraits(), *, specular: float = DEFAULT_SPECULAR, roughness: float = DEFAULT_ROUGHNESS
) -> dict:
    """BSDF parameters (specular, roughness, subsurface, base_color) that reproduce the traits' R and T.

    The glossy lobe (``specular``, ``roughness``) is given; base colour c and subsurface ss
    follow from R, T and the lobe's white-sky albedo (module docstring). Raises if PROSPECT's
    reflectance is below what the glossy lobe alone reflects.
    """
    from lightfit.light.bsdf import SPECULAR_F0_SCALE, ggx_white_sky_albedo

    for name, v in (("specular", specular), ("roughness", roughness)):
        check_fraction(v, f"leaf {name}", parameter=name)
    par = par_optics(traits)
    f0 = SPECULAR_F0_SCALE * float(specular)
    diffuse = par.R + par.T - f0 * ggx_white_sky_albedo(float(roughness))
    if diffuse <= 0 or par.R < f0 * ggx_white_sky_albedo(float(roughness)):
        raise InputError(
            f"leaf specular={specular!r}: the glossy lobe alone reflects more than PROSPECT-D's R = {par.R:.4f}",
            parameter="specular",
            expected="a smaller specular for these traits",
        )
    base_color = diffuse / (1.0 - f0)
    if base_color > 1:  # Optics would refuse a base_color the user never gave (a review)
        raise InputError(
            f"leaf traits {traits}: PROSPECT-D's PAR R + T = {par.R + par.T:.4f}, a leaf that absorbs (almost) "
            f"nothing, which the BSDF's diffuse lobe (base colour ≤ 1) cannot reproduce beside specular={specular!r}",
            parameter="traits",
            expected="traits with some absorption in PAR (e.g. Cab ≥ 0.5 µg cm⁻²)",
        )
    return {
        "specular": float(specular),
        "roughness": float(roughness),
        "subsurface": float(par.T / diffuse),
        "base_color": float(base_color),
    }


def preset_parameters(name: str) -> dict:
    """Leaf BSDF parameters of a named preset (``prospect`` or ``paper``)."""
    if name == "paper":
        return dict(PAPER_LEAF)
    if name == "prospect":
        return leaf_bsdf_parameters(leaf_traits(name))
    raise InputError(f"unknown leaf optics preset {name!r}", parameter="preset", expected=" or ".join(PRESETS))


@lru_cache(maxsize=1)
def _default_parameters() -> tuple[tuple[str, float], ...]:
    return tuple(preset_parameters(DEFAULT_PRESET).items())


def default_leaf_parameters() -> dict:
    """The default preset's leaf BSDF parameters (:data:`DEFAULT_PRESET`), computed once (PROSPECT-D
    and the GGX table): the defaults of :class:`~lightfit.light.scene.Optics` and of ``Theta``."""
    return dict(_default_parameters())
