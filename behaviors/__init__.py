"""Built-in behaviors (registered through the ``lokigraph.behaviors`` entry point)."""

from .air import AirDrag, WindField
from .collision.contacts import CollisionConstraint, CollisionDetect, PenetrationCheck
from .core import Gravity, HardPins, KinematicAnimation, RestSpringForce
from .materials import (AttachmentConstraint, BendConstraint, GoalConstraint,
                        PressureConstraint, PressureForce, RigidConstraint, ShearConstraint,
                        StitchConstraint, StretchConstraint, TetherConstraint,
                        TetVolumeConstraint)
from .fluid import FluidCoupling
from .nucleus import NucleusSolver
from .shapes import ShapeCollisionConstraint
from .strain_limit import StrainLimitConstraint

BUILTIN_BEHAVIORS = [WindField, AirDrag, Gravity, RestSpringForce, PressureForce, KinematicAnimation, HardPins,
                     StretchConstraint, TetherConstraint, ShearConstraint, BendConstraint, TetVolumeConstraint,
                     GoalConstraint, AttachmentConstraint, StitchConstraint, PressureConstraint,
                     RigidConstraint, ShapeCollisionConstraint, CollisionDetect, CollisionConstraint,
                     PenetrationCheck, FluidCoupling, StrainLimitConstraint, NucleusSolver]

__all__ = ["BUILTIN_BEHAVIORS"] + [c.__name__ for c in BUILTIN_BEHAVIORS]
