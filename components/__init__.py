"""Built-in components (registered through the ``lokigraph.components`` entry point)."""

from .core import Dynamic, Kinematic, Pins, RestSpring

BUILTIN_COMPONENTS = [Dynamic, Kinematic, Pins, RestSpring]

__all__ = ["BUILTIN_COMPONENTS", "Dynamic", "Kinematic", "Pins", "RestSpring"]
