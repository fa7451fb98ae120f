"""Hard pins, and pins that follow an animated (kinematic) element (``Pins.follow``): a followed
vertex is carried by the closest triangle of its body, at fixed barycentrics plus an offset in the
triangle's frame. :class:`~lokigraph.behaviors.animation.KinematicAnimation` places them every
substep with :func:`follow_positions`."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lokigraph.behavior import Behavior
from lokigraph.errors import InputError
from lokigraph.components.core import Dynamic, Kinematic, Pins

from .surface import _closest_triangles


@dataclass
class _Follow:
    """Pinned vertices carried by a kinematic element (Pins.follow), all elements packed."""

    idx: np.ndarray  # (m,) global indices of the carried (pinned) vertices
    tri: np.ndarray  # (m, 3) global vertices of the carrying triangle (or 3x the nearest vertex)
    bary: np.ndarray  # (m, 3) barycentric coordinates of the closest point
    offset: np.ndarray  # (m, 3) offset in the triangle frame (e1, e2, n), or world (vertex)
    framed: np.ndarray  # (m,) bool: offset in the triangle frame (False: nearest vertex)


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


def bind_follow_pins(ctx):
    """Bind every pinned vertex with ``Pins.follow`` to the closest triangle of its body at the
    start; they become kinematic vertices. Returns the packed binding, or None."""
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


@dataclass
class _Pinned:
    idx: np.ndarray  # global vertex indices


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
        return _Pinned(idx)

    def describe(self, data):
        return f"{len(data.idx)} pinned vertices"
