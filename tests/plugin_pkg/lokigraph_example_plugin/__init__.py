"""An example plugin: one component, one force behavior and one constraint type.

A plugin package registers its classes under the entry-point groups ``lokigraph.behaviors`` and
``lokigraph.components`` (see this package's pyproject.toml); lokigraph finds them at start-up.
"""

from dataclasses import dataclass

import numpy as np
from pydantic import Field

from lokigraph.behavior import Behavior, ConstraintBehavior
from lokigraph.component import Component
from lokigraph.components.core import Dynamic


class Thruster(Component):
    """A constant force on every vertex of the element."""

    force: tuple[float, float, float] = Field((0.0, 0.0, 0.0), description="Force per vertex [N].")
    floor: float | None = Field(None, description="Height of a floor the vertices stay above [m].")


@dataclass
class _Idx:
    idx: np.ndarray
    value: np.ndarray


class ThrusterForce(Behavior):
    stage = "forces"
    requires = (Dynamic, Thruster)
    accumulates = ("particle_f",)

    def bind(self, ctx, elements):
        idx = np.concatenate([np.arange(e.vertex_slice.start, e.vertex_slice.stop)
                              for e in elements])
        f = np.concatenate([np.tile(e.get(Thruster).force, (e.vertex_count, 1))
                            for e in elements])
        return _Idx(idx, f)

    def step(self, ctx, data):
        ctx.state.particle_f[data.idx] += data.value


class FloorConstraint(ConstraintBehavior):
    """Unilateral constraint y >= floor, as a custom constraint type (Nucleus Figure 13)."""

    requires = (Dynamic, Thruster)
    default_importance = 0.5
    default_order = 50

    def bind(self, ctx, elements):
        els = [e for e in elements if e.get(Thruster).floor is not None]
        if not els:
            return None
        idx = np.concatenate([np.arange(e.vertex_slice.start, e.vertex_slice.stop) for e in els])
        h = np.concatenate([np.full(e.vertex_count, e.get(Thruster).floor) for e in els])
        return _Idx(idx, h)

    def project(self, ctx, data, p):
        y = p[data.idx, 1]
        p[data.idx, 1] = np.maximum(y, data.value)
        ctx.stats["floor_projections"] = ctx.stats.get("floor_projections", 0) + 1


BEHAVIORS = [ThrusterForce, FloorConstraint]
COMPONENTS = [Thruster]
