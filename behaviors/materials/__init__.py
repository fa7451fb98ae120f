"""Materials, one module per physical effect. Each module holds the effect's constraint behavior
for the Nucleus solver together with its kernels (the implicit solver's energy of the same effect
belongs beside them): ``stretch`` (stretch and compression, stretch damping), ``shear``,
``bend`` (surface dihedral and curve bend, angle dropoff), ``volume`` (tetrahedra),
``pressure`` (enclosed volume constraint and pressure force), ``rigid`` (shape matching) and
``strain_limit``. ``common`` has the packing they share."""

from .bend import BendConstraint
from .pressure import PressureConstraint, PressureForce
from .rigid import RigidConstraint
from .rod import RodConstraint
from .shear import ShearConstraint
from .strain_limit import StrainLimitConstraint
from .stretch import StretchConstraint
from .volume import TetVolumeConstraint

__all__ = ["BendConstraint", "PressureConstraint", "PressureForce", "RigidConstraint",
           "RodConstraint", "ShearConstraint", "StrainLimitConstraint", "StretchConstraint",
           "TetVolumeConstraint"]
