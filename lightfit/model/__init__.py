"""The coupled model: weather → plants → light → photosynthesis → observables.

``parameters`` (the typed :class:`Theta`), ``scenario`` (:class:`Scenario`, the per-step
:class:`Forcing`), ``observe`` (the one observation operator), ``coupled`` (:class:`CoupledModel`
with an injectable source of light parts), ``emulator`` (a polynomial surrogate of the rendered
light parts) and ``schema`` (names, units and meanings of every results variable).
"""

from lightfit.model.parameters import BOUNDS, NAMES, Theta, as_theta

__all__ = ["BOUNDS", "NAMES", "Theta", "as_theta"]
