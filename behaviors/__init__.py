"""Built-in behaviors (registered through the ``lokigraph.behaviors`` entry point)."""

from .core import Gravity, HardPins, KinematicAnimation, RestSpringForce
from .nucleus import NucleusSolver

BUILTIN_BEHAVIORS = [Gravity, RestSpringForce, KinematicAnimation, HardPins, NucleusSolver]

__all__ = ["BUILTIN_BEHAVIORS"] + [c.__name__ for c in BUILTIN_BEHAVIORS]
