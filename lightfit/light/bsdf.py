r"""The leaf BSDF: thin, two-sided, with the three parameters the reference paper calibrated.

Parameters, each in [0, 1] and differentiable (Mitsuba ``ParamFlags.Differentiable``):

- ``specular``: reflectance at normal incidence of the glossy lobe, :math:`F_0 = 0.08\,s`
  (the game-engine convention: specular 0.5 → 4 %, the measured upper-leaf-surface
  reflection of 3.7–5.9 %).
- ``roughness``: GGX microfacet roughness, :math:`\alpha = \max(r^2, \alpha_{min})` (Burley 2012).
- ``subsurface``: share of the diffuse (non-specular) light passed to the other side.

and a fixed grey ``base_color`` c (the reference paper used 0.5). With ω in the local frame of
the side the light arrives on (cos θ_i > 0):

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

from lightfit.light.backend import mitsuba

ALPHA_MIN = 1e-3
SPECULAR_F0_SCALE = 0.08
PARAMETERS = ("specular", "roughness", "subsurface")


def _classes():
    mi = mitsuba()
    import drjit as dr

    class LeafBSDF(mi.BSDF):
        """Thin two-sided leaf: GGX glossy reflection + Lambertian reflection and transmission."""

        def __init__(self, props):
            mi.BSDF.__init__(self, props)
            self.specular = mi.Float(props.get("specular", 0.5))
            self.roughness = mi.Float(props.get("roughness", 0.5))
            self.subsurface = mi.Float(props.get("subsurface", 0.0))
            self.base_color = mi.Float(props.get("base_color", 0.5))
            flags = (mi.BSDFFlags.GlossyReflection | mi.BSDFFlags.DiffuseReflection | mi.BSDFFlags.DiffuseTransmission
                     | mi.BSDFFlags.FrontSide | mi.BSDFFlags.BackSide)
            self.m_components = [mi.BSDFFlags.GlossyReflection | mi.BSDFFlags.FrontSide | mi.BSDFFlags.BackSide,
                                 mi.BSDFFlags.DiffuseReflection | mi.BSDFFlags.FrontSide | mi.BSDFFlags.BackSide,
                                 mi.BSDFFlags.DiffuseTransmission | mi.BSDFFlags.FrontSide | mi.BSDFFlags.BackSide]
            self.m_flags = flags

        # -- helpers ---------------------------------------------------------------------
        def _weights(self):
            f0 = SPECULAR_F0_SCALE * dr.clip(self.specular, 0.0, 1.0)
            ss = dr.clip(self.subsurface, 0.0, 1.0)
            c = dr.clip(self.base_color, 0.0, 1.0)
            return f0, (1.0 - f0) * (1.0 - ss) * c, (1.0 - f0) * ss * c

        def _distr(self):
            r = dr.clip(self.roughness, 0.0, 1.0)
            return mi.MicrofacetDistribution(mi.MicrofacetType.GGX, dr.maximum(r * r, ALPHA_MIN), True)

        def _lobe_probs(self):
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
            distr = self._distr()
            pdf_spec = distr.pdf(wi, h) / (4.0 * dr.maximum(dr.abs(dr.dot(wo, h)), 1e-8))
            refl = p_s * pdf_spec + p_d * dr.inv_pi * cos_o
            trans = p_t * dr.inv_pi * -cos_o
            pdf = dr.select(cos_o > 0, refl, trans)
            return dr.select(active & (cos_i > 0) & (cos_o != 0), dr.detach(pdf), 0.0)

        # -- Mitsuba interface -----------------------------------------------------------
        def sample(self, ctx, si, sample1, sample2, active=True):
            s = dr.sign(mi.Frame3f.cos_theta(si.wi))
            wi = self._flip(si.wi, s)
            p_s, p_d, p_t = self._lobe_probs()
            distr = self._distr()
            pick_s = sample1 < p_s
            pick_d = ~pick_s & (sample1 < p_s + p_d)
            pick_t = ~pick_s & ~pick_d
            m, _ = distr.sample(dr.detach(wi), sample2)
            wo_s = mi.reflect(wi, m)
            wo_d = mi.warp.square_to_cosine_hemisphere(sample2)
            wo = dr.select(pick_s, wo_s, wo_d)
            wo = dr.select(pick_t, mi.Vector3f(wo_d.x, wo_d.y, -wo_d.z), wo)
            wo = dr.detach(wo)  # PRB convention: sampling is detached, the weight carries the gradient
            bs = dr.zeros(mi.BSDFSample3f)
            bs.wo = self._flip(wo, s)
            bs.pdf = self._pdf_local(wi, wo, active)
            bs.eta = 1.0
            bs.sampled_component = dr.select(pick_s, mi.UInt32(0), dr.select(pick_d, mi.UInt32(1), mi.UInt32(2)))
            bs.sampled_type = dr.select(pick_s, mi.UInt32(+mi.BSDFFlags.GlossyReflection),
                                        dr.select(pick_d, mi.UInt32(+mi.BSDFFlags.DiffuseReflection),
                                                  mi.UInt32(+mi.BSDFFlags.DiffuseTransmission)))
            value = self._eval_local(wi, wo, active)
            # A glossy sample reflected below the surface is lost; counting it as transmission
            # would add the glossy lobe's density to the transmission pdf and bias the estimate.
            ok = active & (bs.pdf > 0) & (s != 0) & ~(pick_s & (mi.Frame3f.cos_theta(wo) <= 0))
            weight = dr.select(ok, value / dr.select(ok, bs.pdf, 1.0), 0.0)
            bs.pdf = dr.select(ok, bs.pdf, 0.0)
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
            for name in PARAMETERS:
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


def leaf_bsdf_dict(specular: float = 0.5, roughness: float = 0.5, subsurface: float = 0.0, base_color: float = 0.5) -> dict:
    """Mitsuba scene-dict entry of a leaf material; raises on parameters outside [0, 1]."""
    from lightfit.errors import InputError

    for name, v in (("specular", specular), ("roughness", roughness), ("subsurface", subsurface), ("base_color", base_color)):
        if not (0.0 <= float(v) <= 1.0):
            raise InputError(f"leaf {name}={v!r}", column=name, expected="a value in [0, 1]")
    register()
    return {"type": "leaf", "specular": float(specular), "roughness": float(roughness),
            "subsurface": float(subsurface), "base_color": float(base_color)}
