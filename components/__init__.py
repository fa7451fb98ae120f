"""Built-in components (registered through the ``lokigraph.components`` entry point)."""

from .air import Drag, Wind
from .colliders import ShapeCollider
from .collision import Collider, CollisionGroup, CollisionResponse
from .fluid import FluidDomain
from .core import Dynamic, Kinematic, Pins, RestSpring
from .materials import (Attachment, DiscreteShell, Goal, Pressure, Rigid, Rod, Stitch,
                        Volume)

BUILTIN_COMPONENTS = [Dynamic, Kinematic, Pins, RestSpring, DiscreteShell, Rod, Volume, Goal,
                      Attachment, Stitch, Pressure, Rigid, ShapeCollider, Wind, Drag,
                      Collider, CollisionGroup, CollisionResponse, FluidDomain]

__all__ = ["BUILTIN_COMPONENTS"] + [c.__name__ for c in BUILTIN_COMPONENTS]
