"""The coupled model: weather → plants → light → photosynthesis → observables.

``parameters`` (the typed :class:`Theta`), ``coupled`` (:class:`Scenario`, :class:`CoupledModel`),
``emulator`` (a polynomial surrogate of the rendered light parts).
"""

from lightfit.model.parameters import BOUNDS, NAMES, Theta, as_theta

__all__ = ["BOUNDS", "NAMES", "Theta", "as_theta"]
