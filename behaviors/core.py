"""Core behaviors: gravity, rest springs, kinematic animation, hard pins."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from lokigraph.behavior import Behavior, vertex_indices
from lokigraph.component import resolve_paintable
from lokigraph.errors import InputError, SimulationError
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
class _Follow:
    """Pinned vertices carried by a kinematic element (Pins.follow), all elements packed."""

    idx: np.ndarray  # (m,) global indices of the carried (pinned) vertices
    tri: np.ndarray  # (m, 3) global vertices of the carrying triangle (or 3x the nearest vertex)
    bary: np.ndarray  # (m, 3) barycentric coordinates of the closest point
    offset: np.ndarray  # (m, 3) offset in the triangle frame (e1, e2, n), or world (vertex)
    framed: np.ndarray  # (m,) bool: offset in the triangle frame (False: nearest vertex)


@dataclass
class _Anim:
    slices: list  # per element: (slice, rest points (n,3), keys arrays or None, element)
    start_frame: float
    fps: float
    cache: dict = field(default_factory=dict)  # sequence frame -> points (file memo, not state)
    frames: dict = field(default_factory=dict)  # element name -> available sequence frames
    follow: _Follow | None = None


def _sequence_frame(e, frame: int):
    """Geometry of frame ``frame`` of element ``e``'s mesh sequence (units and transform applied;
    a frame without a file follows ``geometry.hold``)."""
    spec = e.spec.model_copy(update={"file": None, "generator": None})
    return _load_geometry(spec, Path(e.base_dir), frame)


def triangle_frames(P: np.ndarray):
    """Orthonormal frames (e1, e2, n) of triangles P (m, 3, 3): e1 along the first edge, n the
    normal by the right-hand rule. Degenerate triangles give a finite (possibly zero) frame."""
    e1 = P[:, 1] - P[:, 0]
    n = np.cross(e1, P[:, 2] - P[:, 0])
    e1 = e1 / np.maximum(np.linalg.norm(e1, axis=1, keepdims=True), 1e-300)
    n = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    return e1, np.cross(n, e1), n


def bind_follow(x: np.ndarray, body_points: np.ndarray, body_tris: np.ndarray, offset: int):
    """Bind points ``x`` (m, 3) to a body (points at bind time, local triangles, global offset
    of its vertices). Returns (tri (m,3) global, bary (m,3), local offset (m,3), framed (m,))."""
    m = len(x)
    if len(body_tris):
        from .materials import _closest_triangles  # numba, brute force over the body

        best, bary = _closest_triangles(np.ascontiguousarray(x, np.float64),
                                        np.ascontiguousarray(body_points, np.float64),
                                        np.ascontiguousarray(body_tris, np.int64))
        tl = body_tris[best]
        P = body_points[tl]
        e1, e2, n = triangle_frames(P)
        d = x - np.einsum("mk,mkj->mj", bary, P)
        local = np.stack([np.einsum("ij,ij->i", d, e) for e in (e1, e2, n)], axis=1)
        return tl + offset, bary, local, np.ones(m, bool)
    from scipy.spatial import cKDTree

    _, near = cKDTree(body_points).query(x)
    near = np.asarray(near, np.int64).reshape(m)
    tri = np.repeat((near + offset)[:, None], 3, axis=1)
    bary = np.tile([1.0, 0.0, 0.0], (m, 1))
    return tri, bary, x - body_points[near], np.zeros(m, bool)


def follow_positions(q: np.ndarray, f: _Follow) -> np.ndarray:
    """Positions (m, 3) of follow-pinned vertices carried by body positions ``q``."""
    P = q[f.tri]  # (m, 3, 3)
    x = np.einsum("mk,mkj->mj", f.bary, P)
    if f.framed.all():
        e1, e2, n = triangle_frames(P)
        return x + f.offset[:, :1] * e1 + f.offset[:, 1:2] * e2 + f.offset[:, 2:] * n
    e1, e2, n = triangle_frames(P)
    framed = f.offset[:, :1] * e1 + f.offset[:, 1:2] * e2 + f.offset[:, 2:] * n
    return x + np.where(f.framed[:, None], framed, f.offset)


def _follow_body(ctx, e, pins):
    """The element ``pins.follow`` names, or None after reporting why it cannot be followed."""
    path = ("elements", e.index, "components", "Pins", "follow")
    try:
        body = ctx.scene.element(pins.follow)
    except KeyError:
        import difflib

        names = [x.name for x in ctx.scene.elements if x.has(Kinematic)]
        near = difflib.get_close_matches(pins.follow, names, n=1)
        ctx.diagnostics.append(ctx.scene.locations.diag(
            path, f"no element named {pins.follow!r}" + (
                f"; did you mean {near[0]!r}?" if near else
                f" (kinematic elements: {', '.join(names) or 'none'})"),
            element=e.name, field="Pins.follow"))
        return None
    if body is e or not body.has(Kinematic) or body.geometry is None or body.vertex_count == 0:
        ctx.diagnostics.append(ctx.scene.locations.diag(
            path, f"{pins.follow!r} must be another element with Kinematic and geometry",
            element=e.name, field="Pins.follow"))
        return None
    return body


class KinematicAnimation(Behavior):
    """Moves kinematic elements to their animated pose at the end of each substep, and the
    pinned vertices that follow them (``Pins.follow``).

    Rigid keys are interpolated linearly (translation and XYZ angles); mesh sequences linearly
    between consecutive frames. A sequence must have a file for every frame the run needs
    (``frames.start`` .. ``frames.end``) unless ``geometry.hold`` says what a missing frame shows
    (``first``, ``last`` or ``loop``; see :mod:`lokigraph.sequence`); checked at bind (validate).
    Follow-pinned vertices become kinematic vertices (inverse mass 0) placed, every substep, by
    their body triangle's barycentric point plus the offset fixed at bind in the triangle's
    frame (see :class:`~lokigraph.components.core.Pins`).
    """

    stage = "control"
    requires = (Kinematic,)
    writes = ("kinematic_q",)

    def bind(self, ctx, elements):
        spec = ctx.scene.spec
        start, end = int(spec.frames.start), int(spec.frames.end)
        items = []
        frames = {}
        for e in elements:
            k = e.get(Kinematic)
            keys = None
            if k.keys:
                keys = (np.array([x.frame for x in k.keys]),
                        np.array([x.translate for x in k.keys]),
                        np.array([x.rotate for x in k.keys]), np.array([x.pivot for x in k.keys]))
            seq = e.sequence
            if seq is not None and e.spec is not None:
                avail = self._check_sequence(ctx, e, start, end)
                if avail is not None:
                    frames[e.name] = avail
            if keys is None and seq is None:
                continue
            items.append((e.vertex_slice, e.geometry.points.copy(), keys, e))
        data = _Anim(items, float(start), ctx.model.fps, frames=frames)
        data.follow = self._bind_follow(ctx, elements)
        return data

    # -- mesh sequences ------------------------------------------------------------------
    @staticmethod
    def _check_sequence(ctx, e, start: int, end: int):
        """Check that the frames the run needs exist (or that ``hold`` covers them) and have
        the element's vertex count. Returns the available frames (None if unknown)."""
        from lokigraph.sequence import (available_frames, describe_frames, first_missing,
                                        frame_file)

        spec = e.spec
        base = Path(e.base_dir)
        locs = ctx.scene.locations
        where = ("elements", e.index, "geometry", "sequence")

        def err(msg, key="sequence"):
            ctx.diagnostics.append(locs.diag(where[:-1] + (key,), msg, element=e.name,
                                             field=f"geometry.{key}"))

        avail = available_frames(spec.sequence, base)
        if spec.hold == "error":
            if avail is not None:
                miss = first_missing(avail, start, end)
            else:  # cannot list the folder: check the first and the last frame the run needs
                miss = next((f for f in (start, end)
                             if not (base / frame_file(spec.sequence, f)).exists()), None)
            if miss is not None:
                missing = base / frame_file(spec.sequence, miss)
                err(f"frame {miss} of the sequence is missing: {missing} not found; the run "
                    f"needs frames {start}..{end} and the sequence has "
                    f"{describe_frames(avail) if avail is not None else 'fewer'}; set "
                    f"geometry.hold to first, last or loop to run past its ends")
                return avail
        elif avail is not None and not len(avail):
            err(f"no file of the sequence found ({base / spec.sequence})")
            return avail
        for f in sorted({start, end}):
            try:
                g = _sequence_frame(e, f)
            except (MeshReadError, KeyError, ValueError) as exc:
                err(str(exc))
                break
            if g.vertex_count != e.vertex_count:
                err(f"frame {f} has {g.vertex_count} vertices, the element has "
                    f"{e.vertex_count}")
                break
        return avail

    def _sequence_points(self, data, e, frame: int) -> np.ndarray | None:
        from lokigraph.sequence import map_frame

        avail = data.frames.get(e.name)
        if avail is not None:
            shown = map_frame(frame, avail, e.spec.hold)
            if shown is None:  # 'error' mode: only past the frames checked at bind
                shown = map_frame(frame, avail, "last")
            frame = shown
        key = (e.name, frame)
        if key not in data.cache:
            if len(data.cache) > 8:
                data.cache.clear()
            try:
                pts = _sequence_frame(e, frame).points
            except MeshReadError as exc:
                raise SimulationError(f"mesh sequence: {exc}", element=e.name) from None
            if len(pts) != e.vertex_count:
                raise SimulationError(f"mesh sequence frame {frame} has {len(pts)} vertices, "
                                      f"the element has {e.vertex_count}", element=e.name)
            data.cache[key] = pts
        return data.cache[key]

    # -- pins that follow a kinematic element --------------------------------------------
    @staticmethod
    def _bind_follow(ctx, elements):
        m = ctx.model
        parts = []
        for e in ctx.scene.elements:
            pins = e.get(Pins)
            if pins is None or pins.follow is None or not e.has(Dynamic) or e.geometry is None:
                continue
            body = _follow_body(ctx, e, pins)
            if body is None:
                continue
            try:
                local = np.flatnonzero(pins.pinned(e))
            except InputError as exc:
                ctx.diagnostics.extend(exc.diagnostics)
                continue
            if not len(local):
                continue
            idx = local + e.vertex_offset
            bq = m.particle_q0[body.vertex_slice]
            tri, bary, off, framed = bind_follow(m.particle_q0[idx], bq, body.geometry.triangles,
                                                 body.vertex_offset)
            parts.append((idx, tri, bary, off, framed))
        if not parts:
            return None
        f = _Follow(*(np.concatenate(x) for x in zip(*parts)))
        # carried vertices are animated: inverse mass 0, and the run loop sets their position
        # and velocity from kinematic_q like any kinematic vertex
        m.particle_kinematic[f.idx] = True
        m.particle_inv_mass[f.idx] = 0.0
        m.particle_qd0[f.idx] = 0.0
        return f

    def step(self, ctx, data):
        f = data.start_frame + ctx.control.time * data.fps
        # mesh sequences land exactly on frames (no spurious read of the next file at the last
        # frame); rigid keys interpolate the unrounded time
        fs = float(round(f)) if abs(f - round(f)) < 1e-9 else f
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
                f0 = int(np.floor(fs))
                s = fs - f0
                a = self._sequence_points(data, e, f0)
                q[sl] = a if s == 0.0 else (1 - s) * a + s * self._sequence_points(data, e,
                                                                                   f0 + 1)
        if data.follow is not None:
            q[data.follow.idx] = follow_positions(q, data.follow)

    def describe(self, data):
        extra = "" if data.follow is None else f", {len(data.follow.idx)} follow-pinned vertices"
        return f"{len(data.slices)} animated elements{extra}"


class HardPins(Behavior):
    """Hard pins: pinned vertices get zero inverse mass and zero velocity at compile time, so no
    force or constraint ever moves them: they stay exactly at their initial position, or, with
    ``Pins.follow``, are carried by a kinematic element (KinematicAnimation moves them)."""

    stage = "solve"
    requires = (Dynamic, Pins)

    def bind(self, ctx, elements):
        idx = []
        for e in elements:
            pins = e.get(Pins)
            mask = pins.pinned(e)
            local = np.flatnonzero(mask)
            g = local + e.vertex_offset
            if pins.follow is not None and len(g) and not ctx.model.particle_kinematic[g].all():
                n = len(ctx.diagnostics)
                body = _follow_body(ctx, e, pins)
                if body is not None or len(ctx.diagnostics) == n:
                    ctx.error(e, "Pins.follow", "following needs the KinematicAnimation "
                              "behavior in the graph (it moves the followed element and the "
                              "pins)")
            idx.append(g)
        idx = np.concatenate(idx).astype(np.int64) if idx else np.zeros(0, np.int64)
        ctx.model.particle_inv_mass[idx] = 0.0
        ctx.model.particle_qd0[idx] = 0.0
        return _Indexed(idx)

    def describe(self, data):
        return f"{len(data.idx)} pinned vertices"
