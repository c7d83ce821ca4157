"""Priors of the sampled parameters (the model's five and the inference-only noise scale), with sources."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import jax
import jax.numpy as jnp
import numpy as np

from lightfit.errors import InputError
from lightfit.light.bsdf import SPECULAR_F0_SCALE, lobe_weights
from lightfit.light.scene import Optics
from lightfit.model.parameters import BOUNDS, NAMES

#: The inference-only parameter: factor λ on the reported measurement SDs (see
#: :mod:`lightfit.inference.likelihood`); not a model parameter, so not part of ``Theta``.
NOISE_SCALE = "noise_scale"
#: Everything the posterior can sample: the model parameters plus the noise scale.
SAMPLED = (*NAMES, NOISE_SCALE)


@dataclass(frozen=True)
class Prior:
    """A one-dimensional prior with its source.

    kinds: ``uniform`` (a = lower, b = upper), ``loguniform`` (a, b > 0), ``lognormal`` (a = median,
    b = SD of the natural log, truncated to [lo, hi]).
    """

    kind: str
    a: float
    b: float
    source: str
    lo: float | None = None
    hi: float | None = None

    def __post_init__(self):
        if self.kind not in ("uniform", "loguniform", "lognormal"):
            raise InputError(
                f"prior kind {self.kind!r}", parameter="prior", expected="uniform, loguniform or lognormal"
            )
        if self.kind in ("uniform", "loguniform") and not self.a < self.b:
            raise InputError(f"prior bounds a={self.a}, b={self.b}", parameter="prior", expected="a < b")
        if self.kind in ("loguniform", "lognormal") and not (self.a > 0 and self.b > 0):
            raise InputError(f"prior a={self.a}, b={self.b}", parameter="prior", expected="a > 0 and b > 0")
        if not (math.isfinite(self.a) and math.isfinite(self.b)):  # an infinite SD drew 0 and inf
            raise InputError(f"prior a={self.a}, b={self.b}", parameter="prior", expected="finite a and b")
        if self.kind != "lognormal":
            if self.lo is not None or self.hi is not None:  # were ignored: the support is [a, b]
                raise InputError(
                    f"{self.kind} prior with lo={self.lo}, hi={self.hi}",
                    parameter="prior",
                    expected=f"no lo / hi for a {self.kind} prior (its support is [a, b])",
                )
            return
        lo, hi = self.support
        # lo > hi was a numpy traceback when sampled; a median outside [lo, hi] made the centre (the
        # walkers' fallback point, the Monte Carlo correlation's reference) a point of zero density
        if not (lo >= 0 and lo < hi and lo <= self.a <= hi):
            raise InputError(
                f"log-normal prior of median {self.a} truncated to [{lo}, {hi}]",
                parameter="prior",
                expected="0 <= lo < hi with the median a in [lo, hi]",
            )

    @property
    def support(self) -> tuple[float, float]:
        if self.kind in ("uniform", "loguniform"):
            return (self.a, self.b)
        return (self.lo if self.lo is not None else 0.0, self.hi if self.hi is not None else math.inf)

    @property
    def center(self) -> float:
        """A point well inside the support: midpoint, geometric midpoint or median."""
        if self.kind == "uniform":
            return 0.5 * (self.a + self.b)
        return math.sqrt(self.a * self.b) if self.kind == "loguniform" else self.a

    def logpdf(self, x) -> jax.Array:
        """Log density (up to a constant) at x; −inf outside the support. JAX-traceable."""
        lo, hi = self.support
        inside = (x >= lo) & (x <= hi)
        if self.kind != "uniform":  # densities in log x: 0 itself is outside (the log-normal gave NaN there)
            inside = inside & (x > 0)
        if self.kind == "uniform":
            val = jnp.zeros_like(x)
        elif self.kind == "loguniform":
            val = -jnp.log(jnp.where(inside, x, 1.0))
        else:
            lx = jnp.log(jnp.where(inside, x, 1.0))
            val = -lx - 0.5 * ((lx - math.log(self.a)) / self.b) ** 2
        return jnp.where(inside, val, -jnp.inf)

    def sample(self, rng: np.random.Generator, n: int) -> np.ndarray:
        lo, hi = self.support
        if self.kind == "uniform":
            return rng.uniform(lo, hi, n)
        if self.kind == "loguniform":
            return np.exp(rng.uniform(math.log(lo), math.log(hi), n))
        # Truncated, not clipped: clipping piled the draws outside the support onto its bounds (a
        # quarter of the walkers at each bound of a wide log-normal), which the density has not.
        # Inverse CDF of the normal in log space between the bounds' quantiles.
        from scipy.stats import norm

        mu, sd = math.log(self.a), self.b
        q = [norm.cdf((math.log(v) - mu) / sd) if 0 < v < math.inf else float(v > 0) for v in (lo, hi)]
        u = rng.uniform(q[0], q[1], n)
        return np.clip(np.exp(mu + sd * norm.ppf(u)), lo, hi)  # the clip only rounds the ends


_F0 = "F0 = 0.08·specular (lightfit.light.bsdf)"
_T = (
    "leaf transmittance T = (1 − F0)·subsurface·base_color with the default (PROSPECT-D) leaf's "
    "base_color 0.0667 and F0 0.04: subsurface = T / 0.0640"
)
#: PROSPECT-D's wheat leaf PAR transmittance range (docs/design.md §6) that the informed
#: subsurface prior spans, whatever the leaf's base colour.
TRANSMITTANCE_RANGE = (0.02, 0.08)
#: Reflection of the upper leaf surface (docs/design.md §6) that the informed specular prior spans.
SURFACE_REFLECTION_RANGE = (0.037, 0.059)


def subsurface_range(optics: Optics) -> tuple[float, float]:
    r"""Subsurface range (2 decimals, capped at the domain's 1) over which leaves of ``optics``
    transmit :data:`TRANSMITTANCE_RANGE`: :math:`T = (1 - F_0)\,s\,c` (base colour :math:`c`,
    :math:`F_0` at the optics' specular)."""
    per_unit = lobe_weights(optics.specular, 1.0, optics.base_color)[2]  # T per unit subsurface
    lo, hi = (round(min(1.0, t / per_unit), 2) for t in TRANSMITTANCE_RANGE)
    return lo, hi


#: Subsurface range of the default leaf (``Optics.preset("prospect")``): 0.02/0.0640 = 0.31 …
#: 0.08/0.0640 = 1.25, capped at 1 (T ≤ 0.064). (The reference paper's grey leaf, base colour 0.5,
#: would need 0.04–0.17.) A literal, equal to ``subsurface_range`` of that leaf
#: (tests/test_leaf_optics.py): computing it here started the renderer whenever the posterior's
#: modules were imported, also to read a stored run where no renderer can start.
SUBSURFACE_INFORMED = (0.31, 1.0)
#: Priors informed by leaf optics (docs/design.md §6) for the default leaf optics — the default.
PRIORS_INFORMED: dict[str, Prior] = {
    "specular": Prior(
        "uniform",
        # 4 decimals, the bounds' own (0.037/0.08 is 0.46249999999999997 in floating point)
        *(round(r / SPECULAR_F0_SCALE, 4) for r in SURFACE_REFLECTION_RANGE),
        f"upper leaf surface reflection 3.7–5.9 % (docs/design.md §6), {_F0}: 0.037/0.08 … 0.059/0.08",
    ),
    "roughness": Prior(
        "uniform",
        0.3,
        1.0,
        "no measurement; lower bound 0.3 (GGX α ≥ 0.09) excludes mirror-like cuticles, for which the "
        "frozen-sampling estimator's per-segment variance explodes (glints)",
    ),
    "subsurface": Prior(
        "uniform",
        *SUBSURFACE_INFORMED,
        f"PROSPECT-D wheat PAR transmittance 0.02–0.08 (docs/design.md §6), {_T}: 0.31 … 1 (capped)",
    ),
    "light_factor": Prior(
        "lognormal",
        1.0,
        0.5,
        "broad: median 1 (the weather's PAR: measured, else 0.5 × 4.57 µmol/J × radiation), "
        "±1 SD in log covers 1.637, the reference paper's light scaling as lightfit's first notes give it "
        "(not in the paper's text: unverified)",
        lo=0.25,
        hi=4.0,
    ),
    "vcmax_scale": Prior(
        "lognormal", 1.0, 0.25, "Vcmax varies ≈ ±25 % with cultivar and leaf age (1 SD in log)", lo=0.25, hi=4.0
    ),
    NOISE_SCALE: Prior(
        "loguniform",
        0.3,
        3.0,
        "scale-invariant (Jeffreys) prior on the factor multiplying the reported measurement SDs",
    ),
}
#: Wide priors over the whole leaf-parameter box (roughness ≥ 0.3 as above): lets the posterior reach the
#: biophysically unrealistic combinations the reference paper warns about.
PRIORS_WIDE: dict[str, Prior] = {
    **PRIORS_INFORMED,
    "specular": Prior("uniform", 0.0, 1.0, "whole parameter range (uninformative)"),
    "subsurface": Prior("uniform", 0.0, 1.0, "whole parameter range (uninformative)"),
}
PRIOR_SETS = {"informed": PRIORS_INFORMED, "wide": PRIORS_WIDE}


def informed_priors(optics=None) -> dict[str, Prior]:
    r""":data:`PRIORS_INFORMED` for a run's leaf optics (``None``: the default PROSPECT-D leaf).

    The subsurface prior is the one that depends on the leaf: it spans PROSPECT-D's wheat PAR
    transmittance :data:`TRANSMITTANCE_RANGE` through :math:`T = (1 - F_0)\,s\,c` (base colour
    :math:`c`, :math:`F_0` at the optics' specular), capped at 1 — 0.31–1 for the default leaf,
    0.04–0.17 for the reference paper's grey leaf (``Optics.preset("paper")``).
    """
    if optics is None:
        return dict(PRIORS_INFORMED)
    lo, hi = subsurface_range(optics)
    if lo >= 1.0:
        raise InputError(
            f"base_color={optics.base_color!r}",
            parameter="base_color",
            expected="a leaf that can transmit PROSPECT-D's 2–8 % of PAR (subsurface ≤ 1)",
        )
    note = (
        f"PROSPECT-D wheat PAR transmittance {TRANSMITTANCE_RANGE[0]}–{TRANSMITTANCE_RANGE[1]} (docs/design.md §6), "
        f"T = (1 − F0)·subsurface·base_color with base_color {optics.base_color:.4g}: {lo} … {hi}"
    )
    return {**PRIORS_INFORMED, "subsurface": Prior("uniform", lo, hi, note)}


def check_sampled(names, priors: dict[str, Prior]) -> tuple[str, ...]:
    """``names`` as a tuple if each is sampleable, given once, has a prior, and its prior's support lies
    in the parameter's domain (:data:`lightfit.model.parameters.BOUNDS`); else :class:`InputError`."""
    names = tuple(names)
    unknown = [n for n in names if n not in SAMPLED]
    if unknown:
        raise InputError(f"unknown parameter(s) {unknown}", parameter="parameters", expected=", ".join(SAMPLED))
    if len(set(names)) != len(names):
        raise InputError(f"duplicate parameter names {list(names)}", parameter="parameters", expected="each name once")
    if not set(names) - {NOISE_SCALE}:  # a posterior of the noise alone answers no question about the model
        raise InputError(
            f"no model parameter among {list(names)}",
            parameter="parameters",
            expected=f"one or more of {', '.join(NAMES)}",
        )
    missing = [n for n in names if n not in priors]
    if missing:
        raise InputError(f"no prior for {missing}", parameter="priors", expected="a Prior for every sampled parameter")
    for n in names:
        if n in BOUNDS:
            (lo, hi), (plo, phi) = priors[n].support, BOUNDS[n]
            if lo < plo or hi > phi:
                raise InputError(
                    f"prior support of {n} is [{lo}, {hi}]",
                    parameter=n,
                    expected=f"within the parameter's domain [{plo}, {phi}]",
                )
    return names


def priors_table(priors: dict[str, Prior], names) -> list[dict]:
    """One row per name: the prior's fields (JSON-ready), for run metadata and reports."""
    return [{"parameter": n, **{k: v for k, v in asdict(priors[n]).items() if v is not None}} for n in names]


__all__ = [
    "NOISE_SCALE",
    "PRIORS_INFORMED",
    "PRIORS_WIDE",
    "PRIOR_SETS",
    "Prior",
    "SUBSURFACE_INFORMED",
    "SAMPLED",
    "check_sampled",
    "informed_priors",
    "priors_table",
]
