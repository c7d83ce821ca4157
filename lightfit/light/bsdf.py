r"""The leaf BSDF: thin, two-sided, with the three parameters the reference paper calibrated.

Parameters, each in [0, 1] and differentiable (Mitsuba ``ParamFlags.Differentiable``):

- ``specular``: reflectance at normal incidence of the glossy lobe, :math:`F_0 = 0.08\,s`
  (the game-engine convention: specular 0.5 → 4 %, the measured upper-leaf-surface
  reflection of 3.7–5.9 %).
- ``roughness``: GGX microfacet roughness, :math:`\alpha = \max(r^2, \alpha_{min})` (Burley 2012).
- ``subsurface``: share of the diffuse (non-specular) light passed to the other side.

and a grey diffuse ``base_color`` c, not calibrated: the reference paper fixed it at 0.5 (preset
``paper``); the ``prospect`` preset derives it, with the default subsurface, from the PAR
reflectance and transmittance of leaf traits (PROSPECT-D, :mod:`lightfit.light.leaf_optics`).
With ω in the local frame of the side the light arrives on (cos θ_i > 0):

.. math::

    f_r(\omega_i, \omega_o) &= F_0\,\frac{D(h)\,G(\omega_i, \omega_o)}{4\cos\theta_i\cos\theta_o}
        + (1 - F_0)(1 - s_{ss})\frac{c}{\pi}, \qquad \cos\theta_o > 0 \\
    f_t(\omega_i, \omega_o) &= (1 - F_0)\,s_{ss}\,\frac{c}{\pi}, \qquad \cos\theta_o < 0

with GGX D and Smith G (Walter et al. 2007). Both terms are symmetric in ω_i and ω_o, so the
BSDF is **reciprocal**; its albedo is :math:`F_0 E_{GGX}(\theta_i) + (1 - F_0)c \le 1`, so it
**conserves energy** (white furnace: equality for c = 1, F_0 = 0). The glossy lobe's weight is
F_0 at every angle: Fresnel's rise towards grazing is deliberately not modelled, because with
it the diffuse weight would have to depend on direction to keep both properties. Absorptance
for light from ω_i is :math:`1 - F_0 E_{GGX}(\theta_i) - (1 - F_0)c`.
"""

from __future__ import annotations

import functools

import numpy as np

from lightfit.files import UNREADABLE_NPZ, replaced
from lightfit.light.backend import mitsuba

ALPHA_MIN = 1e-2  # α floor (r ≈ 0.1): leaf cuticles are not mirrors, and it bounds the variance
SPECULAR_F0_SCALE = 0.08
#: The leaf model's three parameters, in the order every leaf vector uses.
LEAF_PARAMETERS = ("specular", "roughness", "subsurface")


def lobe_weights(specular, subsurface, base_color):
    """The three lobes' weights (F_0, (1 − F_0)(1 − s_ss)c, (1 − F_0)s_ss c): glossy reflection,
    diffuse reflection, diffuse transmission. Plain arithmetic, so numpy floats and Dr.Jit arrays
    (differentiable) both go through this one formula."""
    f0 = SPECULAR_F0_SCALE * specular
    return f0, (1.0 - f0) * (1.0 - subsurface) * base_color, (1.0 - f0) * subsurface * base_color


def unit_clamp(x):
    """``x`` clamped to [0, 1] with the derivative of ``x`` itself (Dr.Jit, straight-through).

    The parameters are checked to lie in [0, 1] where they are set, so the clamp only guards
    against rounding; Dr.Jit's ``clip`` would send the whole derivative to the constant bound when
    a parameter sits exactly on it (the gradient at specular = 0 or subsurface = 0 came out 0, and
    an optimiser at a bound could not leave it)."""
    import drjit as dr

    return x + dr.detach(dr.clip(x, 0.0, 1.0) - x)


def _classes():
    mi = mitsuba()
    import drjit as dr

    class LeafBSDF(mi.BSDF):
        """Thin two-sided leaf: GGX glossy reflection + Lambertian reflection and transmission."""

        def __init__(self, props):
            mi.BSDF.__init__(self, props)
            # No defaults: a leaf is the four values of an Optics (lightfit.light.scene), its one home.
            self.specular, self.roughness, self.subsurface, self.base_color = (
                mi.Float(props[k]) for k in ("specular", "roughness", "subsurface", "base_color")
            )
            flags = (
                mi.BSDFFlags.GlossyReflection
                | mi.BSDFFlags.DiffuseReflection
                | mi.BSDFFlags.DiffuseTransmission
                | mi.BSDFFlags.FrontSide
                | mi.BSDFFlags.BackSide
            )
            self.m_components = [
                mi.BSDFFlags.GlossyReflection | mi.BSDFFlags.FrontSide | mi.BSDFFlags.BackSide,
                mi.BSDFFlags.DiffuseReflection | mi.BSDFFlags.FrontSide | mi.BSDFFlags.BackSide,
                mi.BSDFFlags.DiffuseTransmission | mi.BSDFFlags.FrontSide | mi.BSDFFlags.BackSide,
            ]
            self.m_flags = flags
            # Frozen sampling (see ``freeze_sampling``): lobe probabilities and GGX α used to draw
            # directions, independent of the parameters being differentiated. None: follow them.
            self.sampling = None

        def freeze_sampling(self, specular: float, roughness: float, subsurface: float):
            """Draw directions from a fixed mixture instead of the current parameters.

            With frozen sampling, the estimate for fixed random numbers is a smooth function of
            the parameters (no discrete lobe choice or microfacet sample moves with them), so its
            derivative *is* the estimate of the derivative: finite differences with common random
            numbers and gradient-based optimisers see a consistent, smooth objective. The lobe
            probabilities are those of the reference parameters mixed with 20 % of a
            uniform choice (defensive sampling), so that every lobe keeps a non-zero probability (unbiasedness).
            """
            w = np.array(lobe_weights(float(specular), float(subsurface), float(self.base_color[0])))
            p = w / w.sum() if w.sum() > 0 else np.full(3, 1 / 3)
            p = 0.8 * p + 0.2 / 3
            self.sampling = (float(p[0]), float(p[1]), float(p[2]), max(float(roughness) ** 2, 0.05))

        # -- helpers ---------------------------------------------------------------------
        def _weights(self):
            return lobe_weights(*(unit_clamp(p) for p in (self.specular, self.subsurface, self.base_color)))

        def _distr(self):
            r = unit_clamp(self.roughness)
            return mi.MicrofacetDistribution(mi.MicrofacetType.GGX, dr.maximum(r * r, ALPHA_MIN), True)

        def _sampling_distr(self):
            if self.sampling is None:
                return self._distr()
            return mi.MicrofacetDistribution(mi.MicrofacetType.GGX, self.sampling[3], True)

        def _lobe_probs(self):
            if self.sampling is not None:
                return tuple(mi.Float(p) for p in self.sampling[:3])
            w_s, w_d, w_t = (dr.detach(w) for w in self._weights())
            total = w_s + w_d + w_t
            safe = dr.select(total > 0, total, 1.0)
            p_s = dr.select(total > 0, w_s / safe, 0.0)
            p_d = dr.select(total > 0, w_d / safe, 1.0)
            return p_s, p_d, dr.select(total > 0, w_t / safe, 0.0)

        @staticmethod
        def _flip(v, s):
            return mi.Vector3f(v.x, v.y, v.z * s)

        def _eval_local(self, wi, wo, active):
            """f·|cos θ_o| in the frame where cos θ_i > 0."""
            w_s, w_d, w_t = self._weights()
            cos_i, cos_o = mi.Frame3f.cos_theta(wi), mi.Frame3f.cos_theta(wo)
            refl = active & (cos_i > 0) & (cos_o > 0)
            trans = active & (cos_i > 0) & (cos_o < 0)
            h = dr.normalize(wi + wo)
            distr = self._distr()
            spec = w_s * distr.eval(h) * distr.G(wi, wo, h) / (4.0 * dr.maximum(cos_i, 1e-8))
            diff = w_d * dr.inv_pi * cos_o
            value = dr.select(refl, spec + diff, 0.0)
            value = dr.select(trans, w_t * dr.inv_pi * -cos_o, value)
            return dr.select(refl | trans, value, 0.0)

        def _pdf_local(self, wi, wo, active):
            p_s, p_d, p_t = self._lobe_probs()
            cos_i, cos_o = mi.Frame3f.cos_theta(wi), mi.Frame3f.cos_theta(wo)
            h = dr.normalize(wi + wo)
            distr = self._sampling_distr()
            pdf_spec = distr.pdf(wi, h) / (4.0 * dr.maximum(dr.abs(dr.dot(wo, h)), 1e-8))
            refl = p_s * pdf_spec + p_d * dr.inv_pi * cos_o
            trans = p_t * dr.inv_pi * -cos_o
            pdf = dr.select(cos_o > 0, refl, trans)
            return dr.select(active & (cos_i > 0) & (cos_o != 0), dr.detach(pdf), 0.0)

        # -- Mitsuba interface -----------------------------------------------------------
        def sample_direction(self, wi_local, sample1, sample2, active):
            """The sampling half of :meth:`sample`: with frozen sampling it does not depend on the
            leaf parameters, so a path's geometry can be traced once and weighed at many parameter
            points (:meth:`weight`; ``SegmentEstimator.render_many``).

            ``wi_local``: incoming direction in the shading frame (either side). Returns ``(s, wi,
            wo, pdf, ok, pick_s, pick_d)``: the side sign s, ω_i and the sampled ω_o in the frame
            flipped to the side of ω_i, the (detached) pdf of ω_o, whether the sample is usable,
            and the lobe chosen.
            """
            s = dr.sign(mi.Frame3f.cos_theta(wi_local))
            wi = self._flip(wi_local, s)
            p_s, p_d, p_t = self._lobe_probs()
            distr = self._sampling_distr()
            pick_s = sample1 < p_s
            pick_d = ~pick_s & (sample1 < p_s + p_d)
            m, _ = distr.sample(dr.detach(wi), sample2)
            wo_s = mi.reflect(wi, m)
            wo_d = mi.warp.square_to_cosine_hemisphere(sample2)
            wo = dr.select(pick_s, wo_s, wo_d)
            wo = dr.select(~pick_s & ~pick_d, mi.Vector3f(wo_d.x, wo_d.y, -wo_d.z), wo)
            wo = dr.detach(wo)  # PRB convention: sampling is detached, the weight carries the gradient
            pdf = self._pdf_local(wi, wo, active)
            # A glossy sample reflected below the surface is lost; counting it as transmission
            # would add the glossy lobe's density to the transmission pdf and bias the estimate.
            ok = active & (pdf > 0) & (s != 0) & ~(pick_s & (mi.Frame3f.cos_theta(wo) <= 0))
            return s, wi, wo, pdf, ok, pick_s, pick_d

        def weight(self, wi, wo, pdf, ok, active):
            """The weighing half of :meth:`sample`: f·|cos θ_o|/pdf at the current parameters for a
            sample of :meth:`sample_direction` (0 where it is not ``ok``)."""
            value = self._eval_local(wi, wo, active)
            return dr.select(ok, value / dr.select(ok, pdf, 1.0), 0.0)

        def sample(self, ctx, si, sample1, sample2, active=True):
            s, wi, wo, pdf, ok, pick_s, pick_d = self.sample_direction(si.wi, sample1, sample2, active)
            bs = dr.zeros(mi.BSDFSample3f)
            bs.wo = self._flip(wo, s)
            bs.eta = 1.0
            bs.sampled_component = dr.select(pick_s, mi.UInt32(0), dr.select(pick_d, mi.UInt32(1), mi.UInt32(2)))
            bs.sampled_type = dr.select(
                pick_s,
                mi.UInt32(+mi.BSDFFlags.GlossyReflection),
                dr.select(
                    pick_d, mi.UInt32(+mi.BSDFFlags.DiffuseReflection), mi.UInt32(+mi.BSDFFlags.DiffuseTransmission)
                ),
            )
            weight = self.weight(wi, wo, pdf, ok, active)
            bs.pdf = dr.select(ok, pdf, 0.0)
            return bs, mi.Spectrum(weight)

        def eval(self, ctx, si, wo, active=True):
            s = dr.sign(mi.Frame3f.cos_theta(si.wi))
            return mi.Spectrum(self._eval_local(self._flip(si.wi, s), self._flip(wo, s), active & (s != 0)))

        def pdf(self, ctx, si, wo, active=True):
            s = dr.sign(mi.Frame3f.cos_theta(si.wi))
            return self._pdf_local(self._flip(si.wi, s), self._flip(wo, s), active & (s != 0))

        def eval_pdf(self, ctx, si, wo, active=True):
            s = dr.sign(mi.Frame3f.cos_theta(si.wi))
            wi, wo_ = self._flip(si.wi, s), self._flip(wo, s)
            ok = active & (s != 0)
            return mi.Spectrum(self._eval_local(wi, wo_, ok)), self._pdf_local(wi, wo_, ok)

        def traverse(self, cb):
            for name in LEAF_PARAMETERS:
                cb.put(name, getattr(self, name), mi.ParamFlags.Differentiable)
            cb.put("base_color", self.base_color, mi.ParamFlags.Differentiable)

        def parameters_changed(self, keys):
            pass

        def to_string(self):
            return "LeafBSDF[specular, roughness, subsurface, base_color]"

    return LeafBSDF


_REGISTERED: set[str] = set()


def register() -> None:
    """Register the ``leaf`` BSDF plugin with Mitsuba (once per variant)."""
    mi = mitsuba()
    if mi.variant() in _REGISTERED:
        return
    cls = _classes()
    mi.register_bsdf("leaf", lambda props: cls(props))
    _REGISTERED.add(mi.variant())


def leaf_bsdf_dict(specular: float, roughness: float, subsurface: float, base_color: float) -> dict:
    """Mitsuba scene-dict entry of a leaf material; raises on parameters outside [0, 1]."""
    from lightfit.errors import InputError

    for name, v in (
        ("specular", specular),
        ("roughness", roughness),
        ("subsurface", subsurface),
        ("base_color", base_color),
    ):
        if not (0.0 <= float(v) <= 1.0):
            raise InputError(f"leaf {name}={v!r}", parameter=name, expected="a value in [0, 1]")
    register()
    return {
        "type": "leaf",
        "specular": float(specular),
        "roughness": float(roughness),
        "subsurface": float(subsurface),
        "base_color": float(base_color),
    }


#: Bump when :func:`_compute_table` changes what it estimates: stored tables are then not read.
#: 2: midpoint quadrature instead of Monte Carlo (16 384 samples per cell: errors up to 8e-3 and
#: roughness slopes up to 14 % off).
_TABLE_FORMAT = 2
TABLE_MU = np.linspace(0.0, 1.0, 33)
TABLE_R = np.linspace(0.0, 1.0, 33)  # roughness r; α = max(r², ALPHA_MIN)
#: Quadrature nodes (θ_m, φ_m over [0, π]) per (μ, r) cell of :func:`ggx_albedo_table`: measured
#: within 1.2e-5 of an adaptive quadrature over ω_o at 7 nodes (``tests/test_light_bsdf.py``, which
#: allows 1e-4).
TABLE_QUADRATURE = (400, 64)


@functools.cache
def ggx_albedo_table() -> np.ndarray:
    r"""Directional albedo :math:`E(\mu, r)` of the unit-weight GGX lobe (F = 1), tabulated.

    :math:`E(\mu) = \int D\,G / (4\mu)\,d\omega_o` over the upper hemisphere (GGX D, separable
    Smith G as Mitsuba's ``MicrofacetDistribution``), computed by midpoint quadrature over the
    microfacet normals (:func:`_compute_table`, to about 1e-5) on a 33 × 33 grid of incidence cosine
    μ and roughness r. E = 1 at normal incidence for smooth surfaces and falls at grazing incidence
    and high roughness (shadowing-masking).
    """
    return _stored_table(*TABLE_QUADRATURE)


def _stored_table(n_theta: int, n_phi: int) -> np.ndarray:
    """:func:`ggx_albedo_table` kept on disk (``<cache root>/tables``, :mod:`lightfit.cache`): it
    costs about a second of CPU in every process. The file name carries everything the table
    depends on (format, grid, quadrature nodes; a numpy quadrature, the same in every Mitsuba
    variant), so a stale file is never read; a file that does not load as the expected finite
    table is recomputed and replaced."""
    from lightfit.cache import cache_root

    shape = (len(TABLE_MU), len(TABLE_R))
    path = cache_root() / "tables" / f"ggx_albedo_v{_TABLE_FORMAT}_{shape[0]}x{shape[1]}_{n_theta}_{n_phi}.npy"
    try:
        table = np.load(path)
        if table.shape == shape and table.dtype == np.float64 and np.isfinite(table).all():
            return table
    except UNREADABLE_NPZ:
        pass
    table = _compute_table(n_theta, n_phi)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with replaced(path) as tmp:  # another process reads the whole table or none
            np.save(tmp, table)
    except OSError:
        pass  # a read-only cache costs time, not results
    return table


def _compute_table(n_theta: int, n_phi: int) -> np.ndarray:
    r""":func:`ggx_albedo_table` by midpoint quadrature over microfacet normals m (numpy, float64).

    :math:`E(\mu) = \int D(m)\,G_1(\omega_i)\,G_1(\omega_o)\,(\omega_i\cdot m)/\mu\,d\omega_m` with
    :math:`\omega_o` the mirror of :math:`\omega_i` about m (:math:`d\omega_o = 4(\omega_o\cdot m)\,d\omega_m`),
    on ``n_theta`` nodes of s, :math:`\tan\theta_m = \alpha s/(1 - s)` (dense where D is, at every
    α), times ``n_phi`` of φ_m over [0, π] (the integrand is even in φ_m). It was a Monte Carlo
    estimate (16 384 samples per cell, said to be within 0.1 %): off by up to 8e-3 (1.3 %), and
    the roughness slopes taken from it (the roughness gradient of absorbed light) by up to 14 %.
    """
    s = (np.arange(n_theta) + 0.5) / n_theta
    cos_p = np.cos((np.arange(n_phi) + 0.5) / n_phi * np.pi)
    table = np.empty((len(TABLE_MU), len(TABLE_R)))
    for j, r in enumerate(TABLE_R):
        a = max(r * r, ALPHA_MIN)

        def g1(cos, a=a):
            cos = np.maximum(cos, 1e-12)  # masked below 0; tends to 0 at the horizon
            return 2.0 / (1.0 + np.sqrt(1.0 + a * a * np.maximum(1.0 - cos * cos, 0.0) / (cos * cos)))

        tan_t = a * s / (1.0 - s)
        cos_t = 1.0 / np.sqrt(1.0 + tan_t**2)
        sin_t = tan_t * cos_t
        d = 1.0 / (np.pi * a * a * cos_t**4 * (1.0 + (tan_t / a) ** 2) ** 2)  # GGX D(m)
        # dω_m = sin θ dθ dφ, dθ = cos²θ d(tan θ), d(tan θ) = α / (1 − s)² ds; φ over [0, π], doubled
        dw = d * sin_t * cos_t**2 * a / (1.0 - s) ** 2 / n_theta * (2.0 * np.pi / n_phi)
        mx, mz = sin_t[:, None] * cos_p, cos_t[:, None]
        for i, mu in enumerate(np.maximum(TABLE_MU, 1e-3)):
            c = mx * np.sqrt(1.0 - mu * mu) + mz * mu  # ω_i·m
            cos_o = 2.0 * c * mz - mu
            value = np.where((c > 0) & (cos_o > 0), g1(mu) * g1(cos_o) * c / mu, 0.0)
            table[i, j] = float(np.sum(value * dw[:, None]))
    return table


def catmull_rom_weights(t):
    r"""Weights of the nodes j − 1, j, j + 1, j + 2 for a point a fraction ``t`` ∈ [0, 1] of the way
    from node j to j + 1 (Catmull–Rom, the cubic Hermite spline with central-difference slopes):

    .. math:: w = \tfrac12\,(-t^3 + 2t^2 - t,\; 3t^3 - 5t^2 + 2,\; -3t^3 + 4t^2 + t,\; t^3 - t^2).

    They sum to 1 and are (0, 1, 0, 0) at t = 0: the nodes are reproduced exactly, and the
    derivative is continuous across them (linear interpolation's jumps there, by 4 % of the
    roughness gradient at the default leaf's 0.5, a node). Plain arithmetic: numpy or Dr.Jit."""
    return (
        t * (-0.5 + t * (1.0 - 0.5 * t)),
        1.0 + t * t * (-2.5 + 1.5 * t),
        t * (0.5 + t * (2.0 - 1.5 * t)),
        t * t * (-0.5 + 0.5 * t),
    )


def _roughness_nodes(j, n: int, minimum, maximum):
    """The four node indices :func:`catmull_rom_weights` weighs for cell ``j`` (from node j to
    j + 1) of an ``n``-node axis, the ends repeated."""
    return maximum(j, 1) - 1, j, j + 1, minimum(j + 2, n - 1)


def ggx_white_sky_albedo(roughness: float) -> float:
    r"""Albedo of the unit-weight GGX lobe under a uniform sky, :math:`\bar E(r) = 2\int_0^1 E(\mu, r)\,\mu\,d\mu`.

    From :func:`ggx_albedo_table` (trapezoid rule in μ; in r as :func:`leaf_albedo` takes it,
    :func:`catmull_rom_weights`). The glossy lobe of a leaf reflects :math:`F_0 \bar E` of uniform
    diffuse light (≈ 0.88 F0 at roughness 0.5).
    """
    table = ggx_albedo_table()
    per_r = 2.0 * np.trapezoid(table * TABLE_MU[:, None], TABLE_MU, axis=0)
    y = min(max(float(roughness), 0.0), 1.0) * (len(TABLE_R) - 1)
    j = min(int(np.floor(y)), len(TABLE_R) - 2)
    nodes = _roughness_nodes(j, len(TABLE_R), min, max)
    return float(sum(w * per_r[k] for w, k in zip(catmull_rom_weights(y - j), nodes)))


_ALBEDO_TABLE_DR: dict = {}


def _albedo_table_drjit():
    """The albedo table as one Dr.Jit array per variant: made once, so every kernel that reads it
    sees the same memory (and alignment) and compiled kernels are reused."""
    mi = mitsuba()
    if mi.variant() not in _ALBEDO_TABLE_DR:
        import drjit as dr

        t = ggx_albedo_table().ravel()
        out = dr.empty(mi.Float, len(t))
        dr.scatter(out, mi.Float(t.astype(np.float32)), dr.arange(mi.UInt32, len(t)))
        dr.eval(out)
        _ALBEDO_TABLE_DR[mi.variant()] = out
    return _ALBEDO_TABLE_DR[mi.variant()]


def leaf_albedo(bsdf, cos_i):
    """Directional albedo ρ(θ_i) = F0·E_GGX(μ, r) + (1 − F0)·c of a leaf BSDF (Dr.Jit, differentiable).

    From the tabulated E (:func:`ggx_albedo_table`): linear in μ, Catmull–Rom in roughness
    (:func:`catmull_rom_weights`: the roughness gradient is continuous across the table's nodes,
    where linear interpolation made it one-sided); ``cos_i`` of either sign (the leaf is
    two-sided). Absorptance is 1 − ρ.
    """
    mi = mitsuba()
    import drjit as dr

    table = _albedo_table_drjit()
    nm, nr = len(TABLE_MU), len(TABLE_R)
    x = dr.clip(dr.abs(cos_i), 0.0, 1.0) * (nm - 1)
    y = unit_clamp(bsdf.roughness) * (nr - 1)
    x0 = dr.minimum(mi.UInt32(dr.floor(dr.detach(x))), nm - 2)
    fx = x - mi.Float(x0)
    y0 = dr.minimum(mi.UInt32(dr.floor(dr.detach(y))), nr - 2)
    nodes = _roughness_nodes(y0, nr, dr.minimum, dr.maximum)
    t = y - mi.Float(y0)

    def at(i, j):
        return dr.gather(mi.Float, table, i * nr + j)

    e = sum(w * ((1 - fx) * at(x0, k) + fx * at(x0 + 1, k)) for w, k in zip(catmull_rom_weights(t), nodes))
    f0 = SPECULAR_F0_SCALE * unit_clamp(bsdf.specular)
    return f0 * e + (1.0 - f0) * unit_clamp(bsdf.base_color)
