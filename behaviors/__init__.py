"""Built-in behaviors (registered through the ``lokigraph.behaviors`` entry point)."""

from .core import Gravity, HardPins, KinematicAnimation, RestSpringForce
from .materials import (AttachmentConstraint, BendConstraint, GoalConstraint,
                        PressureConstraint, PressureForce, RigidConstraint, ShearConstraint,
                        StitchConstraint, StretchConstraint, TetVolumeConstraint)
from .nucleus import NucleusSolver

BUILTIN_BEHAVIORS = [Gravity, RestSpringForce, PressureForce, KinematicAnimation, HardPins,
                     StretchConstraint, ShearConstraint, BendConstraint, TetVolumeConstraint,
                     GoalConstraint, AttachmentConstraint, StitchConstraint, PressureConstraint,
                     RigidConstraint, NucleusSolver]

__all__ = ["BUILTIN_BEHAVIORS"] + [c.__name__ for c in BUILTIN_BEHAVIORS]
