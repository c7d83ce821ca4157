r"""The coupled model's parameters: one typed PyTree with names, domains and defaults.

:class:`Theta` is an :class:`equinox.Module`, so it passes through ``jax.jit``, ``jax.grad`` and
``jax.vmap`` as a PyTree whose leaves are the five parameter values:

========================  ===========  =======  ===============================================
name                      domain       default  meaning
========================  ===========  =======  ===============================================
``specular``              [0, 1]       0.5      glossy-lobe strength, :math:`F_0 = 0.08\,s`
``roughness``             [0, 1]       0.5      GGX roughness of the cuticle
``subsurface``            [0, 1]       ≈ 0.596  share of diffuse light transmitted
``light_factor``          (0, ∞)       1.0      multiplies the weather's PAR (dimensionless)
``vcmax_scale``           (0, ∞)       1.0      multiplies the set's Vcmax_ref, and so Jmax_ref, Rd_ref
========================  ===========  =======  ===============================================

``vcmax_scale`` scales the leaf's photosynthetic capacity: every photosynthesis set gives Jmax_ref
and Rd_ref as ratios to Vcmax_ref (``jmax_to_vcmax``, ``rd_to_vcmax``), so all three move together
(at night and in low light, below ≈ 150 µmol m⁻² s⁻¹ absorbed, An moves mainly through Rd and falls
as the scale rises, since J ≈ αQ there whatever Jmax is; in stronger light it rises through Jmax and
Vcmax).

The leaf names come from :data:`lightfit.light.bsdf.LEAF_PARAMETERS` (the leaf model owns
them). The leaf defaults are the default leaf optics' (``Optics.preset("prospect")``: the
subsurface that, with the derived base colour ≈ 0.067, reproduces PROSPECT-D's PAR reflectance
0.061 and transmittance 0.038 of the default wheat leaf, :mod:`lightfit.light.leaf_optics`),
derived on first use rather than written down twice. A scenario with other optics (the
reference paper's grey leaf, preset ``paper``: subsurface 0.3; other leaf traits) has its own
leaf defaults: :meth:`Theta.for_optics`.

Change a value with ``theta.replace(roughness=0.3)``; build one from a vector over some names
(what optimisers and samplers hold) with ``Theta().with_vector(names, x)``.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from lightfit.errors import InputError, is_real
from lightfit.light.bsdf import LEAF_PARAMETERS

#: Domain (lower, upper) of every model parameter; ``math.inf``: unbounded above.
BOUNDS: dict[str, tuple[float, float]] = {
    "specular": (0.0, 1.0),
    "roughness": (0.0, 1.0),
    "subsurface": (0.0, 1.0),
    "light_factor": (0.0, math.inf),
    "vcmax_scale": (0.0, math.inf),
}
assert tuple(BOUNDS)[:3] == LEAF_PARAMETERS  # one order for the leaf vector everywhere

#: All model parameter names, in PyTree order.
NAMES: tuple[str, ...] = tuple(BOUNDS)


def _leaf_default(name: str):
    from lightfit.light.leaf_optics import default_leaf_parameters

    return eqx.field(default_factory=lambda: default_leaf_parameters()[name])


class Theta(eqx.Module):
    """Values of the coupled model's parameters (see the module docstring for units and domains)."""

    specular: float = _leaf_default("specular")
    roughness: float = _leaf_default("roughness")
    subsurface: float = _leaf_default("subsurface")
    light_factor: float = 1.0
    vcmax_scale: float = 1.0

    @classmethod
    def for_optics(cls, optics, **values) -> Theta:
        """Defaults whose leaf parameters are those of ``optics`` (a :class:`lightfit.light.scene.Optics`,
        e.g. ``Optics.preset("paper")`` → subsurface 0.3), with ``values`` replaced."""
        return cls(**{k: float(getattr(optics, k)) for k in LEAF_PARAMETERS}).replace(**values)

    @property
    def leaf(self):
        """(3,) leaf vector (specular, roughness, subsurface), float64 when x64 is on."""
        return jnp.stack([jnp.asarray(getattr(self, k), jnp.float64) for k in LEAF_PARAMETERS])

    def replace(self, **values) -> Theta:
        """A copy with some values changed; unknown names raise :class:`InputError`."""
        check_names(values)
        return dataclasses.replace(self, **values)

    def with_vector(self, names: Sequence[str], x) -> Theta:
        """A copy with ``names[i]`` set to ``x[i]`` (``x`` may be a traced JAX array)."""
        return self.replace(**{n: x[i] for i, n in enumerate(names)})

    def vector(self, names: Sequence[str]):
        """The values of ``names`` as a JAX vector."""
        return jnp.stack([jnp.asarray(getattr(self, n), jnp.float64) for n in names])

    def to_dict(self) -> dict[str, float]:
        """Plain floats, for JSON, netCDF attributes and tables."""
        return {n: float(getattr(self, n)) for n in NAMES}


def check_names(names, *, what: str = "parameters", fitted: bool = False) -> tuple[str, ...]:
    """``names`` as a tuple, or :class:`InputError` naming the unknown or repeated ones (one name
    as a string is one name, not its letters); ``fitted``: names to fit, so at least one."""
    names = (names,) if isinstance(names, str) else tuple(names)
    if fitted and not names:
        raise InputError("no parameter to fit", parameter=what, expected=f"one or more of {', '.join(NAMES)}")
    unknown = [n for n in names if n not in BOUNDS]
    if unknown:
        raise InputError(f"unknown parameter(s) {unknown}", parameter=what, expected=", ".join(NAMES))
    repeated = sorted({n for n in names if names.count(n) > 1})
    if repeated:
        raise InputError(f"parameter(s) {repeated} given more than once", parameter=what, expected="each name once")
    return names


def _domain(name: str) -> str:
    lo, hi = BOUNDS[name]
    return f"{name} {'in ' if math.isfinite(hi) else ''}{interval(lo, hi)}"


def interval(lo: float, hi: float) -> str:
    """A parameter's range as its checks take it: ``[lo, hi]`` (both ends in), or ``> lo`` where
    ``hi`` is infinite (the unbounded factors are strictly positive)."""
    return f"[{lo:g}, {hi:g}]" if math.isfinite(hi) else f"> {lo:g}"


def _outside(a, lo: float, hi: float, xp=np):
    """Where ``a`` (numpy or JAX, ``xp``) is NaN or outside the range :func:`interval` states: the one
    test behind :func:`check_theta`, :func:`check_concrete` and :func:`outside_domain`."""
    return ~xp.isfinite(a) | ((a <= lo) if math.isinf(hi) else (a < lo) | (a > hi))


def check_theta(values: Mapping[str, float], *, what: str = "theta") -> dict[str, float]:
    """``values`` (some parameter names → numbers) as floats, each inside its domain
    (:data:`BOUNDS`; the unbounded factors strictly positive), or :class:`InputError` naming
    ``what`` (e.g. the command line's ``theta``) and the parameter: a negative light factor
    would render negative PAR, a specular of 2 a leaf that reflects more than it receives."""
    check_names(values, what=what)
    out = {}
    for k, v in values.items():
        ok = is_real(v) and not _outside(np.float64(v), *BOUNDS[k])
        if not ok:
            raise InputError(f"{k}={v!r}", parameter=what, expected=_domain(k))
        out[k] = float(v)
    return out


def check_concrete(theta: Theta, *, what: str = "theta") -> Theta:
    """``theta`` itself if each of its concrete values lies inside its domain (:data:`BOUNDS`), else
    :class:`InputError` naming ``what`` and the parameter. Concrete: Python or numpy numbers and
    arrays (every element is checked) and JAX arrays outside a trace. Traced values (inside
    ``jax.jit``, ``grad`` or ``vmap``) cannot be read, so they pass as they are: the optimisers and
    samplers that trace a Theta keep their values in the domain themselves."""
    for name in NAMES:
        v = getattr(theta, name)
        if isinstance(v, jax.core.Tracer):
            continue
        lo, hi = BOUNDS[name]
        try:
            a = np.asarray(v)
        except (TypeError, ValueError):
            a = np.asarray(None)  # not a number at all: refused below
        if a.dtype.kind not in "iuf":  # bools, strings, objects
            raise InputError(f"{name}={v!r}", parameter=what, expected=_domain(name))
        bad = _outside(a, lo, hi)
        if bad.any():
            first = a if a.ndim == 0 else a.reshape(-1)[int(np.argmax(bad.reshape(-1)))]
            raise InputError(f"{name}={float(first)!r}", parameter=what, expected=_domain(name))
    return theta


def outside_domain(theta: Theta) -> jax.Array:
    """True where any value of ``theta`` is NaN or lies outside its domain (:data:`BOUNDS`; the
    unbounded factors strictly positive), as a JAX bool that traced values give too
    (:func:`check_concrete` refuses concrete ones but cannot read traced ones). The observation
    operator flags every blade of such a point unconverged, so that it has no likelihood: under
    ``jax.jit`` a light factor of −1 rendered negative PAR that the leaves took as dark, and a
    specular of 1.5 the leaf of specular 1 with a zero gradient, both finite and unflagged."""
    bad = jnp.asarray(False)
    for name in NAMES:
        bad = bad | jnp.any(_outside(jnp.asarray(getattr(theta, name)), *BOUNDS[name], xp=jnp))
    return bad


def as_theta(
    value: Theta | Mapping[str, float] | None = None, base: Theta | None = None, *, what: str = "theta"
) -> Theta:
    """A :class:`Theta` from a Theta, a mapping of some names (the rest from ``base`` or the
    defaults) or None (the defaults). Concrete values, given either way, are checked against their
    domains (:func:`check_theta`, :func:`check_concrete`; errors name ``what``): a Theta is built
    without checks (JAX rebuilds it inside traces), so ``Theta(specular=1.5)`` is caught here.
    Traced values (an optimiser's vector inside ``jax.jit``/``grad``) are taken as they are."""
    if isinstance(value, Theta):
        return check_concrete(value, what=what)
    value = dict(value or {})
    numbers = {k: v for k, v in value.items() if isinstance(v, (int, float))}
    numbers = check_theta(numbers, what=what)
    arrays = {k: v for k, v in value.items() if k not in numbers}
    check_names(arrays, what=what)
    # arrays in the mapping (numpy, concrete JAX) are checked like a Theta's values, with base's
    return check_concrete((base or Theta()).replace(**{**value, **numbers}), what=what)


__all__ = [
    "BOUNDS",
    "NAMES",
    "Theta",
    "as_theta",
    "check_concrete",
    "check_names",
    "check_theta",
    "interval",
    "outside_domain",
]
