"""Built-in behaviors (registered through the ``lokigraph.behaviors`` entry point).

Find a thing by asking what it is:

- ``materials/``: one module per physical effect of a material (stretch, shear, bend, volume,
  pressure, rigid, strain_limit), each holding its constraint behavior and its kernels;
- ``attachments/``: pins (hard and following), goals, point-to-surface attachments, stitches,
  tethers;
- ``forces.py`` (gravity, rest springs), ``animation.py`` (kinematic animation);
- ``solvers/``: one folder per solver (``nucleus/``: the solver and its shared XPBD primitives);
- ``collision/``: broad and narrow phase, contacts, intersection checks, analytic shape colliders;
- ``air/``: wind, drag and lift; ``coupling/``: one-way coupling to an external fluid;
- ``topology.py``: mesh topology shared by all of them.
"""

from .air import AirDrag, WindField
from .animation import KinematicAnimation
from .attachments import (AttachmentConstraint, GoalConstraint, HardPins, StitchConstraint,
                          TetherConstraint)
from .collision.contacts import CollisionConstraint, CollisionDetect, PenetrationCheck
from .collision.shapes import ShapeCollisionConstraint
from .coupling import FluidCoupling, FluidTwoWay
from .forces import Gravity, RestSpringForce
from .materials import (BendConstraint, PressureConstraint, PressureForce, RigidConstraint,
                        RodConstraint, ShearConstraint, StrainLimitConstraint, StretchConstraint,
                        TetVolumeConstraint)
from .solvers.nucleus import NucleusSolver
from .solvers.implicit import ImplicitSolver

BUILTIN_BEHAVIORS = [WindField, AirDrag, Gravity, RestSpringForce, PressureForce, KinematicAnimation, HardPins,
                     StretchConstraint, TetherConstraint, ShearConstraint, BendConstraint, TetVolumeConstraint,
                     GoalConstraint, AttachmentConstraint, StitchConstraint, PressureConstraint,
                     RigidConstraint, ShapeCollisionConstraint, CollisionDetect, CollisionConstraint,
                     PenetrationCheck, FluidCoupling, FluidTwoWay, StrainLimitConstraint, RodConstraint, NucleusSolver,
                     ImplicitSolver]

__all__ = ["BUILTIN_BEHAVIORS"] + [c.__name__ for c in BUILTIN_BEHAVIORS]
