"""Core behaviors: gravity, rest springs, kinematic animation, hard pins."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from lokigraph.behavior import Behavior, vertex_indices
from lokigraph.component import resolve_paintable
from lokigraph.geometry import MeshReadError, rotation_matrix_xyz
from lokigraph.scene import _load_geometry
from lokigraph.components.core import Dynamic, Kinematic, Pins, RestSpring


@dataclass
class _Indexed:
    idx: np.ndarray  # global vertex indices
    values: np.ndarray = field(default_factory=lambda: np.zeros(0))


@dataclass
class _Spring(_Indexed):
    anchor: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))


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
        k = np.concatenate([resolve_paintable(e.get(RestSpring).stiffness, e,
                                              "RestSpring.stiffness") for e in elements])
        anchor = np.concatenate([
            np.tile(e.get(RestSpring).anchor, (e.vertex_count, 1)) if e.get(RestSpring).anchor
            is not None else ctx.model.particle_rest[e.vertex_slice] for e in elements])
        return _Spring(idx, k, anchor)

    def step(self, ctx, data):
        x = ctx.state.particle_q[data.idx]
        ctx.state.particle_f[data.idx] -= data.values[:, None] * (x - data.anchor)


@dataclass
class _Anim:
    slices: list  # per element: (slice, rest points (n,3), keys arrays or None, sequence)
    start_frame: float
    fps: float
    cache: dict = field(default_factory=dict)  # sequence frame -> points (file memo, not state)


def _sequence_frame(e, frame: int):
    """Geometry of frame ``frame`` of element ``e``'s mesh sequence (units and transform applied)."""
    spec = e.spec.model_copy(update={"file": None, "generator": None})
    return _load_geometry(spec, Path(e.base_dir), frame)


class KinematicAnimation(Behavior):
    """Moves kinematic elements to their animated pose at the end of each substep.

    Rigid keys are interpolated linearly (translation and XYZ angles); mesh sequences linearly
    between the two nearest frames (clamped at the ends of the sequence).
    """

    stage = "control"
    requires = (Kinematic,)
    writes = ("kinematic_q",)

    def bind(self, ctx, elements):
        items = []
        for e in elements:
            k = e.get(Kinematic)
            keys = None
            if k.keys:
                keys = (np.array([x.frame for x in k.keys]), np.array([x.translate for x in k.keys]),
                        np.array([x.rotate for x in k.keys]), np.array([x.pivot for x in k.keys]))
            seq = e.sequence
            if seq is not None:
                # check the sequence exists now, so a typo is an input error, not a crash later
                f0 = ctx.scene.spec.frames.start
                try:
                    g = _sequence_frame(e, f0)
                    if g.vertex_count != e.vertex_count:
                        ctx.error(e, "geometry.sequence", f"frame {f0} has {g.vertex_count} "
                                  f"vertices, the element has {e.vertex_count}")
                except (MeshReadError, KeyError) as exc:
                    ctx.error(e, "geometry.sequence", str(exc))
            if keys is None and seq is None:
                continue
            items.append((e.vertex_slice, e.geometry.points.copy(), keys, e))
        return _Anim(items, float(ctx.scene.spec.frames.start), ctx.model.fps)

    def _sequence_points(self, data, e, frame: int) -> np.ndarray:
        key = (e.name, frame)
        if key not in data.cache:
            if len(data.cache) > 8:
                data.cache.clear()
            try:
                data.cache[key] = _sequence_frame(e, frame).points
            except MeshReadError:
                data.cache[key] = None  # past the end of the sequence: hold the last pose
        return data.cache[key]

    def step(self, ctx, data):
        f = data.start_frame + ctx.control.time * data.fps
        q = ctx.control.kinematic_q
        for sl, rest, keys, e in data.slices:
            if keys is not None:
                fr, tr, rot, piv = keys
                t = np.array([np.interp(f, fr, tr[:, i]) for i in range(3)])
                r = np.array([np.interp(f, fr, rot[:, i]) for i in range(3)])
                pv = np.array([np.interp(f, fr, piv[:, i]) for i in range(3)])
                R = rotation_matrix_xyz(r)
                q[sl] = (rest - pv) @ R.T + pv + t
            else:
                f0 = int(np.floor(f))
                a = self._sequence_points(data, e, f0)
                b = self._sequence_points(data, e, f0 + 1)
                if a is None:
                    continue
                if b is None:
                    q[sl] = a
                else:
                    s = f - f0
                    q[sl] = (1 - s) * a + s * b

    def describe(self, data):
        return f"{len(data.slices)} animated elements"


class HardPins(Behavior):
    """Hard pins: pinned vertices get zero inverse mass and zero velocity at compile time, so no
    force or constraint ever moves them (they stay exactly at their initial position)."""

    stage = "solve"
    requires = (Dynamic, Pins)

    def bind(self, ctx, elements):
        idx = []
        for e in elements:
            mask = e.get(Pins).pinned(e)
            idx.append(np.flatnonzero(mask) + e.vertex_offset)
        idx = np.concatenate(idx).astype(np.int64)
        ctx.model.particle_inv_mass[idx] = 0.0
        ctx.model.particle_qd0[idx] = 0.0
        return _Indexed(idx)

    def describe(self, data):
        return f"{len(data.idx)} pinned vertices"
