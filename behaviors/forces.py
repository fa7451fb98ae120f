"""Forces that add into ``particle_f``: gravity and rest springs. (The pressure force sits with its
material in :mod:`lokigraph.behaviors.materials.pressure`, lift with the air model.)"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from lokigraph.behavior import Behavior, vertex_indices
from lokigraph.component import resolve_paintable
from lokigraph.components.core import Dynamic, RestSpring
from lokigraph.keys import Keyed, step_frame


@dataclass
class _Indexed:
    idx: np.ndarray  # global vertex indices
    values: np.ndarray = field(default_factory=lambda: np.zeros(0))


@dataclass
class _Spring(_Indexed):
    anchor: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    #: keyed stiffness: (slice of ``values``, Keyed), re-evaluated every substep
    keyed: list = field(default_factory=list)


class Gravity(Behavior):
    """Adds m g to every dynamic vertex (gravity vector from the scene, [m/s^2])."""

    stage = "forces"
    requires = (Dynamic,)
    accumulates = ("particle_f",)

    def bind(self, ctx, elements):
        idx = vertex_indices(elements)
        return _Indexed(idx, ctx.model.particle_mass[idx].copy())

    def step(self, ctx, data):
        ctx.state.particle_f[data.idx] += data.values[:, None] * ctx.model.gravity[None, :]

    def describe(self, data):
        return f"{len(data.idx)} vertices"


class RestSpringForce(Behavior):
    """Linear spring to the rest position, f = -k (x - x_rest) [N] (RestSpring component)."""

    stage = "forces"
    requires = (Dynamic, RestSpring)
    accumulates = ("particle_f",)

    def bind(self, ctx, elements):
        idx = vertex_indices(elements)
        parts, keyed, at = [], [], 0
        for e in elements:
            k = e.get(RestSpring).stiffness
            if isinstance(k, Keyed):  # scalar keys: filled per substep (lokigraph.keys)
                keyed.append((slice(at, at + e.vertex_count), k))
                parts.append(np.zeros(e.vertex_count))
            else:
                parts.append(resolve_paintable(k, e, "RestSpring.stiffness"))
            at += e.vertex_count
        k = np.concatenate(parts)
        anchor = np.concatenate([
            np.tile(e.get(RestSpring).anchor, (e.vertex_count, 1)) if e.get(RestSpring).anchor
            is not None else ctx.model.particle_rest[e.vertex_slice] for e in elements])
        return _Spring(idx, k, anchor, keyed)

    def step(self, ctx, data):
        if data.keyed:
            f = step_frame(ctx)
            for sl, key in data.keyed:
                data.values[sl] = key.evaluate(f)
        x = ctx.state.particle_q[data.idx]
        ctx.state.particle_f[data.idx] -= data.values[:, None] * (x - data.anchor)
