r"""The coupled model's parameters: one typed PyTree with names, domains and defaults.

:class:`Theta` is an :class:`equinox.Module`, so it passes through ``jax.jit``, ``jax.grad`` and
``jax.vmap`` as a PyTree whose leaves are the five parameter values:

========================  ===========  =======  ===============================================
name                      domain       default  meaning
========================  ===========  =======  ===============================================
``specular``              [0, 1]       0.5      glossy-lobe strength, :math:`F_0 = 0.08\,s`
``roughness``             [0, 1]       0.5      GGX roughness of the cuticle
``subsurface``            [0, 1]       0.3      share of diffuse light transmitted
``light_factor``          (0, ∞)       1.0      multiplies the weather's PAR (dimensionless)
``vcmax_scale``           (0, ∞)       1.0      multiplies the photosynthesis set's Vcmax
========================  ===========  =======  ===============================================

The leaf names come from :data:`lightfit.light.bsdf.LEAF_PARAMETERS` (the leaf model owns
them). Change a value with ``theta.replace(roughness=0.3)``; build one from a vector over some
names (what optimisers and samplers hold) with ``Theta().with_vector(names, x)``.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence

import equinox as eqx
import jax.numpy as jnp

from lightfit.errors import InputError
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


class Theta(eqx.Module):
    """Values of the coupled model's parameters (see the module docstring for units and domains)."""

    specular: float = 0.5
    roughness: float = 0.5
    subsurface: float = 0.3
    light_factor: float = 1.0
    vcmax_scale: float = 1.0

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


def check_names(names, *, what: str = "parameters") -> tuple[str, ...]:
    """``names`` as a tuple, or :class:`InputError` naming the unknown ones."""
    names = tuple(names)
    unknown = [n for n in names if n not in BOUNDS]
    if unknown:
        raise InputError(f"unknown parameter(s) {unknown}", column=what, expected=", ".join(NAMES))
    return names


def as_theta(value: Theta | Mapping[str, float] | None = None, base: Theta | None = None) -> Theta:
    """A :class:`Theta` from a Theta, a mapping of some names (the rest from ``base`` or the
    defaults) or None (the defaults)."""
    if isinstance(value, Theta):
        return value
    return (base or Theta()).replace(**dict(value or {}))


__all__ = ["BOUNDS", "NAMES", "Theta", "as_theta", "check_names"]
