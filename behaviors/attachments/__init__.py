"""Attachments: what holds vertices to the world, to animation or to each other. ``pins`` (hard
pins and pins that follow a kinematic element), ``goal`` (goal attraction, soft pins),
``surface`` (point-to-surface attachments, fixed or sliding), ``stitch`` (stitches and welds),
``tether`` (long-range attachments to the pins), each with its kernels."""

from .goal import GoalConstraint
from .pins import HardPins
from .stitch import StitchConstraint
from .surface import AttachmentConstraint
from .tether import TetherConstraint

__all__ = ["AttachmentConstraint", "GoalConstraint", "HardPins", "StitchConstraint",
           "TetherConstraint"]
