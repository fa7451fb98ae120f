"""Constraint types of the Nucleus solver: stretch, shear, bend, tet volume, goals, attachments,
stitches, pressure and shape matching. Each packs its constraints of all bound elements into one
set of flat arrays (coloured for parallel Gauss-Seidel) at compile time; ``project`` is one
numba sweep (see :mod:`lokigraph.behaviors.nucleus_kernels`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit, prange

from lokigraph.behavior import Behavior, ConstraintBehavior, vertex_indices
from lokigraph.component import resolve_paintable
from lokigraph.errors import InputError
from lokigraph.components.core import Dynamic
from lokigraph.components.materials import (Attachment, DiscreteShell, Goal, Pressure, Rigid,
                                            Rod, Stitch, Volume)
from lokigraph.geometry import triangle_areas, vertex_measure

from . import nucleus_kernels as K
from . import topology as T
from .collision.narrowphase import point_triangle_distance


def _rest(ctx, e, comp) -> np.ndarray:
    """Rest positions of an element (local), from the component's rest channel if any."""
    ch = getattr(comp, "rest_channel", None)
    if ch:
        if ch not in e.channels:
            ctx.error(e, f"{type(comp).__name__}.rest_channel", f"no channel named {ch!r}")
            return e.geometry.points
        r = np.asarray(e.channels[ch], dtype=np.float64)
        if r.shape != (e.vertex_count, 3):
            ctx.error(e, f"{type(comp).__name__}.rest_channel",
                      f"channel {ch!r} has shape {r.shape}, expected ({e.vertex_count}, 3)")
            return e.geometry.points
        return r
    return ctx.model.particle_rest[e.vertex_slice]


#: Constraint sets smaller than this run the sequential Gauss-Seidel kernel: below it a coloured
#: parallel sweep spends more on thread barriers (one per colour) than it saves, and it stalls
#: badly when other processes share the cores. Measured with behaviors/bench_kernels.py on 2
#: idle cores: 800 stretch rows 0.6x (parallel slower), 1536 shear rows 1.1x, 3136 stretch rows
#: 1.2x, 6144 shear rows 1.7x, 24576 shear rows 1.9x.
PARALLEL_MIN_CONSTRAINTS = 2048


@dataclass
class Packed:
    """Coloured constraint rows (global vertex indices) and their parameters."""

    idx: np.ndarray  # (m, k) int64
    rest: np.ndarray  # (m,)
    alpha: np.ndarray  # (m,) compliance
    alpha2: np.ndarray  # (m,) second compliance (compression) or dropoff
    lam: np.ndarray  # (m,)
    color_ptr: np.ndarray
    sequential: bool = False
    beta: np.ndarray | None = None  # stretch damping

    @classmethod
    def build(cls, idx, rest, alpha, alpha2=None, beta=None, sequential=None):
        idx = np.ascontiguousarray(idx, dtype=np.int64)
        if sequential is None:
            sequential = len(idx) < PARALLEL_MIN_CONSTRAINTS
        perm, ptr = T.color_constraints(idx, vertex_count=int(idx.max()) + 1 if len(idx) else 0)
        a2 = alpha2 if alpha2 is not None else np.zeros(len(idx))
        return cls(np.ascontiguousarray(idx[perm]), np.ascontiguousarray(rest[perm]),
                   np.ascontiguousarray(alpha[perm]), np.ascontiguousarray(a2[perm]),
                   np.zeros(len(idx)), ptr, sequential,
                   None if beta is None else np.ascontiguousarray(beta[perm]))

    def __len__(self):
        return len(self.idx)


def _project_edges(ctx, d, p):
    """Distance rows of a Packed set (stretch edges, stitches): damped where it has beta,
    sequential or coloured parallel by its size."""
    w = ctx.model.particle_inv_mass
    if d.beta is not None:
        fn = K.project_stretch_damped_seq if d.sequential else K.project_stretch_damped
        fn(p, ctx.state.particle_q, w, d.idx, d.rest, d.alpha, d.alpha2, d.beta, d.lam,
           ctx.dt, d.color_ptr)
    else:
        fn = K.project_stretch_seq if d.sequential else K.project_stretch
        fn(p, w, d.idx, d.rest, d.alpha, d.alpha2, d.lam, ctx.dt, d.color_ptr)


def _cross_norm(a, b):
    """|a x b| row by row, shape (m,): np.linalg.norm(np.cross(a, b), axis=1) with the same
    floating-point operations (bitwise equal), without np.cross's temporaries."""
    cx = a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1]
    cy = a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2]
    cz = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    return np.sqrt(cx * cx + cy * cy + cz * cz)


def _concat(parts):
    parts = [p for p in parts if p is not None and len(p[0])]
    if not parts:
        return None
    return [np.concatenate([p[k] for p in parts]) for k in range(len(parts[0]))]


# ---------------------------------------------------------------------------------- stretch

class StretchConstraint(ConstraintBehavior):
    """Type 1 (edge length) on cloth edges, hair segments and tet edges, with separate stretch
    and compression compliance (and optional stretch damping)."""

    requires = (Dynamic,)
    requires_any = (DiscreteShell, Rod, Volume)
    default_importance = 1.0
    default_order = 30

    def bind(self, ctx, elements):
        parts = []
        for e in elements:
            g = e.geometry
            off = e.vertex_offset
            if e.has(DiscreteShell) and len(g.triangles):
                c = e.get(DiscreteShell)
                X = _rest(ctx, e, c)
                topo = T.triangle_topology(g.triangles)
                edges = topo.edges
                L = np.linalg.norm(X[edges[:, 1]] - X[edges[:, 0]], axis=1)
                area = triangle_areas(X, g.triangles)
                Ae = np.bincount(topo.tri_edges.ravel(), np.repeat(area / 3.0, 3),
                                 minlength=len(edges))
                if c.youngs_modulus is None:
                    a = np.zeros(len(edges))
                else:
                    a = L * L / (c.youngs_modulus * c.thickness * np.maximum(Ae, 1e-300))
                ac = _compress(a, c.compression_ratio)
                beta = np.full(len(edges), c.stretch_damping)
                parts.append((edges + off, L * c.rest_length_scale, a, ac, beta))
            elif e.has(Rod) and len(g.edges):
                c = e.get(Rod)
                X = _rest(ctx, e, c)
                edges = g.edges
                L = np.linalg.norm(X[edges[:, 1]] - X[edges[:, 0]], axis=1)
                a = (np.zeros(len(edges)) if c.youngs_modulus is None
                     else L / (c.youngs_modulus * np.pi * c.radius ** 2))
                parts.append((edges + off, L * c.rest_length_scale, a,
                              _compress(a, c.compression_ratio), np.zeros(len(edges))))
            elif e.has(Volume) and len(g.tetrahedra):
                c = e.get(Volume)
                X = _rest(ctx, e, c)
                tt = T.orient_tets(X, g.tetrahedra)
                edges = T.tet_edges(tt)
                L = np.linalg.norm(X[edges[:, 1]] - X[edges[:, 0]], axis=1)
                vol = K.rest_tet_volumes(X, tt)
                # volume share of an edge: each tet spreads V/6 over its 6 edges
                key = {tuple(r): i for i, r in enumerate(edges)}  # build-time only
                loc = np.array([[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]])
                te = np.sort(tt[:, loc], axis=2).reshape(-1, 2)
                ids = np.array([key[tuple(r)] for r in te])
                Ve = np.bincount(ids, np.repeat(np.abs(vol) / 6.0, 6), minlength=len(edges))
                a = L * L / (c.youngs_modulus * np.maximum(Ve, 1e-300))
                parts.append((edges + off, L, a, a, np.zeros(len(edges))))
        cat = _concat(parts)
        if cat is None:
            return None
        idx, L, a, ac, beta = cat
        return Packed.build(idx, L, a, ac, beta=beta if beta.any() else None)

    def project(self, ctx, d, p):
        _project_edges(ctx, d, p)

    def residual(self, ctx, d, p):
        return float(K.residual_stretch(p, d.idx, d.rest)[0])

    def describe(self, d):
        return f"{len(d)} edges, {len(d.color_ptr) - 1} colours" if d is not None else ""


def _compress(a, ratio):
    """Compression compliance: stretch compliance / ratio; ratio 0 switches compression off."""
    return a / ratio if ratio > 0 else np.full_like(a, np.inf)


# ---------------------------------------------------------------------------------- shear

class ShearConstraint(ConstraintBehavior):
    """Type 2 on 2-simplices: the corner angles of every triangle keep their rest value."""

    requires = (Dynamic, DiscreteShell)
    default_importance = 0.27
    default_order = 20

    def bind(self, ctx, elements):
        parts = []
        for e in elements:
            c = e.get(DiscreteShell)
            g = e.geometry
            if not len(g.triangles):
                continue
            k = c.shear_stiffness
            if k is None:
                if c.youngs_modulus is None:
                    continue
                k = c.youngs_modulus / (2 * (1 + c.poisson_ratio)) * c.thickness
            if k <= 0:
                continue
            X = _rest(ctx, e, c)
            trip = T.triangle_corner_triplets(g.triangles)
            rest = K.rest_angles(X, trip)
            area = triangle_areas(X, g.triangles)
            # three corners share the triangle's shear energy 1/2 k A gamma^2
            with np.errstate(divide="ignore"):  # a zero-area triangle: infinite compliance
                a = 1.0 / (k * np.tile(area, 3) / 3.0)
            parts.append((trip + e.vertex_offset, rest, a))
        cat = _concat(parts)
        if cat is None:
            return None
        return Packed.build(cat[0], cat[1], cat[2])

    def project(self, ctx, d, p):
        fn = K.project_angle_seq if d.sequential else K.project_angle
        fn(p, ctx.model.particle_inv_mass, d.idx, d.rest, d.alpha, d.lam, ctx.dt, d.color_ptr)

    def residual(self, ctx, d, p):
        return float(K.residual_angle(p, d.idx, d.rest)[0])

    def describe(self, d):
        return f"{len(d)} corners" if d is not None else "no shear stiffness: nothing bound"


# ---------------------------------------------------------------------------------- bend

class BendConstraint(ConstraintBehavior):
    """Type 3 on 2-simplices (dihedral angle across interior edges, with angle dropoff) and the
    bend of 1-simplices (angle between consecutive segments)."""

    requires = (Dynamic,)
    requires_any = (DiscreteShell, Rod)
    default_importance = 0.35
    default_order = 10

    def bind(self, ctx, elements):
        quads, qrest, qa, qdrop = [], [], [], []
        trips, trest, ta = [], [], []
        for e in elements:
            g = e.geometry
            if e.has(DiscreteShell) and len(g.triangles):
                c = e.get(DiscreteShell)
                if c.bend_resistance <= 0:
                    continue
                X = _rest(ctx, e, c)
                q = T.bend_quads(g.triangles)
                if not len(q):
                    continue
                x0 = X[q[:, 0]]
                hinge = X[q[:, 1]] - x0
                L = np.linalg.norm(hinge, axis=1)
                A1 = 0.5 * _cross_norm(hinge, X[q[:, 2]] - x0)
                A2 = 0.5 * _cross_norm(hinge, X[q[:, 3]] - x0)
                k = c.bend_resistance * 3.0 * L * L / np.maximum(A1 + A2, 1e-300)
                quads.append(q + e.vertex_offset)
                qrest.append(K.rest_dihedrals(X, q))
                qa.append(1.0 / k)
                qdrop.append(np.full(len(q), c.bend_angle_dropoff))
            elif e.has(Rod) and len(g.edges):
                c = e.get(Rod)
                EI = c.bend_resistance
                if EI is None:
                    EI = (c.youngs_modulus * np.pi * c.radius ** 4 / 4.0
                          if c.youngs_modulus is not None else 1e-9)
                if EI <= 0:
                    continue
                X = _rest(ctx, e, c)
                tr = T.curve_bend_triplets(g.edges, e.vertex_count)
                if not len(tr):
                    continue
                apex = tr[:, [1, 0, 2]]
                lavg = 0.5 * (np.linalg.norm(X[tr[:, 0]] - X[tr[:, 1]], axis=1)
                              + np.linalg.norm(X[tr[:, 2]] - X[tr[:, 1]], axis=1))
                trips.append(apex + e.vertex_offset)
                trest.append(K.rest_angles(X, apex))
                ta.append(lavg / EI)
        data = {}
        if quads:
            data["quads"] = Packed.build(np.concatenate(quads), np.concatenate(qrest),
                                         np.concatenate(qa), np.concatenate(qdrop))
        if trips:
            data["curves"] = Packed.build(np.concatenate(trips), np.concatenate(trest),
                                          np.concatenate(ta))
        return _Multi(data) if data else None

    def begin_substep(self, ctx, d):
        for x in d.parts.values():
            x.lam[:] = 0.0

    def project(self, ctx, d, p):
        w = ctx.model.particle_inv_mass
        q = d.parts.get("quads")
        if q is not None:
            fn = K.project_dihedral_seq if q.sequential else K.project_dihedral
            fn(p, w, q.idx, q.rest, q.alpha, q.alpha2, q.lam, ctx.dt, q.color_ptr)
        c = d.parts.get("curves")
        if c is not None:
            fn = K.project_angle_seq if c.sequential else K.project_angle
            fn(p, w, c.idx, c.rest, c.alpha, c.lam, ctx.dt, c.color_ptr)

    def residual(self, ctx, d, p):
        r = 0.0
        if "quads" in d.parts:
            q = d.parts["quads"]
            r = max(r, float(K.residual_dihedral(p, q.idx, q.rest)[0]))
        if "curves" in d.parts:
            c = d.parts["curves"]
            r = max(r, float(K.residual_angle(p, c.idx, c.rest)[0]))
        return r

    def describe(self, d):
        return ", ".join(f"{len(v)} {k}" for k, v in d.parts.items()) if d else ""


@dataclass
class _Multi:
    parts: dict
    lam: None = None


# ---------------------------------------------------------------------------------- volume

class TetVolumeConstraint(ConstraintBehavior):
    """Volume of every tetrahedron (3-simplices), compliance V0 / K (bulk modulus K)."""

    requires = (Dynamic, Volume)
    default_importance = 0.5
    default_order = 25

    def bind(self, ctx, elements):
        parts = []
        for e in elements:
            c = e.get(Volume)
            g = e.geometry
            if not len(g.tetrahedra):
                continue
            X = _rest(ctx, e, c)
            tt = T.orient_tets(X, g.tetrahedra)
            V0 = K.rest_tet_volumes(X, tt)
            Kb = c.youngs_modulus / (3.0 * (1.0 - 2.0 * c.poisson_ratio))
            parts.append((tt + e.vertex_offset, V0, np.abs(V0) / Kb))
        cat = _concat(parts)
        return None if cat is None else Packed.build(*cat)

    def project(self, ctx, d, p):
        fn = K.project_tet_volume_seq if d.sequential else K.project_tet_volume
        fn(p, ctx.model.particle_inv_mass, d.idx, d.rest, d.alpha, d.lam, ctx.dt, d.color_ptr)

    def residual(self, ctx, d, p):
        return float(K.residual_tet_volume(p, d.idx, d.rest)[0])

    def describe(self, d):
        return f"{len(d)} tetrahedra" if d is not None else ""


# ---------------------------------------------------------------------------------- goals

@dataclass
class _Goal:
    idx: np.ndarray
    target_idx: np.ndarray  # global index of the goal vertex, or -1 for a fixed target
    target: np.ndarray  # (m, 3) goal positions (updated per substep for animated targets)
    alpha: np.ndarray
    lam: np.ndarray


class GoalConstraint(ConstraintBehavior):
    """Goal attraction toward an animated target element, or soft pins to the initial pose."""

    requires = (Dynamic, Goal)
    default_importance = 1.0
    default_order = 35

    def bind(self, ctx, elements):
        idx, tidx, alpha = [], [], []
        scene = ctx.scene
        for e in elements:
            c = e.get(Goal)
            k = resolve_paintable(c.stiffness, e, "Goal.stiffness")
            if np.any(k < 0):
                ctx.error(e, "Goal.stiffness", "must be >= 0")
                continue
            on = np.flatnonzero(k > 0)
            if c.target is not None:
                try:
                    t = scene.element(c.target)
                except KeyError:
                    ctx.error(e, "Goal.target", f"no element named {c.target!r}")
                    continue
                if t.vertex_count != e.vertex_count:
                    ctx.error(e, "Goal.target", f"target {c.target!r} has {t.vertex_count} "
                              f"vertices, this element has {e.vertex_count}")
                    continue
                tidx.append(on + t.vertex_offset)
            else:
                tidx.append(np.full(len(on), -1))
            idx.append(on + e.vertex_offset)
            alpha.append(1.0 / k[on])
        if not idx or not sum(len(i) for i in idx):
            return None
        idx = np.concatenate(idx).astype(np.int64)
        tidx = np.concatenate(tidx).astype(np.int64)
        target = ctx.model.particle_q0[idx].copy()
        return _Goal(idx, tidx, target, np.concatenate(alpha), np.zeros(len(idx)))

    def begin_substep(self, ctx, d):
        d.lam[:] = 0.0
        anim = d.target_idx >= 0
        if anim.any():
            d.target[anim] = ctx.control.kinematic_q[d.target_idx[anim]]

    def project(self, ctx, d, p):
        fn = K.project_goal_seq if len(d.idx) < PARALLEL_MIN_CONSTRAINTS else K.project_goal
        fn(p, ctx.model.particle_inv_mass, d.idx, d.target, d.alpha, d.lam, ctx.dt)

    def residual(self, ctx, d, p):
        return float(K.residual_goal(p, d.idx, d.target)[0])

    def describe(self, d):
        return f"{len(d.idx)} goal vertices" if d is not None else ""


# ---------------------------------------------------------------------------------- attachments

@njit(cache=True)
def _closest_triangles(P, X, tris):
    """For each point, the closest triangle and barycentrics (brute force; bind time and the
    sliding re-projection of a few attached vertices)."""
    n = P.shape[0]
    best = np.empty(n, np.int64)
    bary = np.empty((n, 3))
    for i in range(n):
        dbest = np.inf
        for t in range(tris.shape[0]):
            d, b0, b1, b2 = point_triangle_distance(P[i], X[tris[t, 0]], X[tris[t, 1]],
                                                    X[tris[t, 2]])
            if d < dbest:
                dbest = d
                best[i] = t
                bary[i, 0] = b0
                bary[i, 1] = b1
                bary[i, 2] = b2
    return best, bary


@njit(cache=True)
def project_plane(p, w, attach, bary):
    """Sliding attachment: vertex attach[j, 0] stays on the plane of triangle attach[j, 1:] at
    the barycentric point bary[j] (normal direction only; free to slide tangentially)."""
    for j in range(attach.shape[0]):
        v, a, b, c = attach[j, 0], attach[j, 1], attach[j, 2], attach[j, 3]
        e1 = p[b] - p[a]
        e2 = p[c] - p[a]
        n = np.cross(e1, e2)
        ln = np.sqrt(n[0] ** 2 + n[1] ** 2 + n[2] ** 2)
        if ln < 1e-30:
            continue
        n = n / ln
        s = bary[j, 0] * p[a] + bary[j, 1] * p[b] + bary[j, 2] * p[c]
        C = (p[v, 0] - s[0]) * n[0] + (p[v, 1] - s[1]) * n[1] + (p[v, 2] - s[2]) * n[2]
        den = w[v] + bary[j, 0] ** 2 * w[a] + bary[j, 1] ** 2 * w[b] + bary[j, 2] ** 2 * w[c]
        if den <= 0.0:
            continue
        dl = -C / den
        for k in range(3):
            p[v, k] += w[v] * dl * n[k]
            p[a, k] -= w[a] * bary[j, 0] * dl * n[k]
            p[b, k] -= w[b] * bary[j, 1] * dl * n[k]
            p[c, k] -= w[c] * bary[j, 2] * dl * n[k]


@dataclass
class _Attach:
    attach: np.ndarray  # (m, 4): vertex, tri a, b, c (global)
    bary: np.ndarray  # (m, 3)
    alpha: np.ndarray
    lam: np.ndarray  # (m, 3)
    sliding: np.ndarray  # (m,) bool
    target_tris: list  # per attachment group: (row slice, global triangles)


class AttachmentConstraint(ConstraintBehavior):
    """Point-to-surface attachments (fixed barycentrics) and sliding attachments (the closest
    point is re-found at every substep, so the vertex slides on the surface)."""

    requires = (Attachment,)
    default_importance = 1.0
    default_order = 36

    def bind(self, ctx, elements):
        rows, bary, alpha, sliding, groups = [], [], [], [], []
        start = 0
        for e in elements:
            c = e.get(Attachment)
            try:
                src, tgt = ctx.scene.element(c.source), ctx.scene.element(c.target)
            except KeyError as exc:
                ctx.error(e, "Attachment", f"no element named {exc.args[0]!r}")
                continue
            if tgt.geometry is None or not len(tgt.geometry.triangles):
                ctx.error(e, "Attachment.target", f"{c.target!r} has no triangles")
                continue
            try:  # indices, a group name or a selection on the source element
                verts = c.source_vertices(src)
            except InputError as exc:
                for d in exc.diagnostics:
                    ctx.error(e, "Attachment.vertices", f"on {c.source!r}: {d.message}")
                continue
            q0 = ctx.model.particle_q0
            tris = tgt.geometry.triangles + tgt.vertex_offset
            best, b = _closest_triangles(q0[verts + src.vertex_offset], q0, tris)
            m = len(verts)
            rows.append(np.column_stack([verts + src.vertex_offset, tris[best]]))
            bary.append(b)
            alpha.append(np.full(m, 0.0 if c.stiffness is None else 1.0 / c.stiffness))
            sliding.append(np.full(m, c.mode == "sliding"))
            groups.append((slice(start, start + m), tris, c.mode == "sliding"))
            start += m
        if not rows:
            return None
        return _Attach(np.concatenate(rows).astype(np.int64), np.concatenate(bary),
                       np.concatenate(alpha), np.zeros((start, 3)), np.concatenate(sliding),
                       groups)

    def begin_substep(self, ctx, d):
        d.lam[:] = 0.0
        q = ctx.state.particle_q
        for sl, tris, slide in d.target_tris:
            if slide:  # re-anchor at the closest point of the (moving) surface
                best, b = _closest_triangles(q[d.attach[sl, 0]], q, tris)
                d.attach[sl, 1:] = tris[best]
                d.bary[sl] = b

    def project(self, ctx, d, p):
        w = ctx.model.particle_inv_mass
        fixed = ~d.sliding
        if fixed.all():
            K.project_attach_seq(p, w, d.attach, d.bary, d.alpha, d.lam, ctx.dt,
                                 np.array([0, len(d.attach)], np.int64))
        else:
            K.project_attach_seq(p, w, d.attach[fixed], d.bary[fixed], d.alpha[fixed],
                                 d.lam[fixed], ctx.dt, np.array([0, int(fixed.sum())], np.int64))
            project_plane(p, w, d.attach[d.sliding], d.bary[d.sliding])

    def residual(self, ctx, d, p):
        return float(K.residual_attach(p, d.attach, d.bary)[0])

    def describe(self, d):
        return f"{len(d.attach)} attached vertices" if d is not None else ""


class StitchConstraint(ConstraintBehavior):
    """Stitches and welds between two elements: zero-length distance constraints."""

    requires = (Stitch,)
    default_importance = 1.0
    default_order = 31

    def bind(self, ctx, elements):
        parts = []
        for e in elements:
            c = e.get(Stitch)
            try:
                a, b = ctx.scene.element(c.a), ctx.scene.element(c.b)
            except KeyError as exc:
                ctx.error(e, "Stitch", f"no element named {exc.args[0]!r}")
                continue
            pairs = np.asarray(c.pairs, dtype=np.int64).reshape(-1, 2)
            if c.weld_distance is not None:
                from scipy.spatial import cKDTree

                qa = a.geometry.points
                qb = b.geometry.points
                res = cKDTree(qb).query(qa, distance_upper_bound=c.weld_distance)
                ok = np.isfinite(res[0])
                pairs = np.vstack([pairs, np.column_stack([np.flatnonzero(ok), res[1][ok]])])
            if len(pairs) and (pairs[:, 0].max() >= a.vertex_count
                               or pairs[:, 1].max() >= b.vertex_count or pairs.min() < 0):
                ctx.error(e, "Stitch.pairs", "vertex index out of range")
                continue
            g = np.column_stack([pairs[:, 0] + a.vertex_offset, pairs[:, 1] + b.vertex_offset])
            al = np.full(len(g), 0.0 if c.stiffness is None else 1.0 / c.stiffness)
            parts.append((g, np.zeros(len(g)), al, al))
        cat = _concat(parts)
        return None if cat is None else Packed.build(*cat)

    def project(self, ctx, d, p):
        _project_edges(ctx, d, p)

    def residual(self, ctx, d, p):
        return float(K.residual_stretch(p, d.idx, d.rest)[0])

    def describe(self, d):
        return f"{len(d)} stitches" if d is not None else ""


# ---------------------------------------------------------------------------------- pressure

@dataclass
class _Volumes:
    items: list  # (global tris, target volume, compliance, lam (1,), work)
    lam: None = None


class PressureConstraint(ConstraintBehavior):
    """Holds the enclosed volume of a triangle mesh at volume_scale x rest volume."""

    requires = (Dynamic, Pressure)
    default_importance = 0.5
    default_order = 25

    def bind(self, ctx, elements):
        items = []
        n = ctx.model.particle_count
        for e in elements:
            c = e.get(Pressure)
            if c.mode != "volume":
                continue
            if not len(e.geometry.triangles):
                ctx.error(e, "Pressure", "needs triangles")
                continue
            tris = e.geometry.triangles + e.vertex_offset
            V0 = K.mesh_volume(ctx.model.particle_rest, tris)
            items.append((tris, V0 * c.volume_scale, c.compliance, np.zeros(1), np.zeros((n, 4))))
        return _Volumes(items) if items else None

    def begin_substep(self, ctx, d):
        for it in d.items:
            it[3][:] = 0.0

    def project(self, ctx, d, p):
        for tris, target, alpha, lam, work in d.items:  # loop over elements, not vertices
            K.project_mesh_volume(p, ctx.model.particle_inv_mass, tris, target, alpha, lam,
                                  ctx.dt, work)

    def residual(self, ctx, d, p):
        return max(abs(K.mesh_volume(p, t) - v) / max(abs(v), 1e-300)
                   for t, v, *_ in d.items)

    def describe(self, d):
        return f"{len(d.items)} volumes" if d else ""


class PressureForce(Behavior):
    """Gauge pressure p [Pa] on a triangle mesh: f = p * area * normal, spread to corners."""

    stage = "forces"
    requires = (Dynamic, Pressure)
    accumulates = ("particle_f",)

    def bind(self, ctx, elements):
        tris, pres = [], []
        for e in elements:
            c = e.get(Pressure)
            if c.mode == "pressure" and c.pressure != 0 and len(e.geometry.triangles):
                tris.append(e.geometry.triangles + e.vertex_offset)
                pres.append(np.full(len(e.geometry.triangles), c.pressure))
        if not tris:
            return None
        return (np.concatenate(tris), np.concatenate(pres))

    def step(self, ctx, data):
        if data is None:
            return
        tris, pres = data
        x = ctx.state.particle_q
        P = x[tris]
        fn = np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]) * (pres / 6.0)[:, None]  # p A n / 3
        f = ctx.state.particle_f
        for k in range(3):
            np.add.at(f, tris[:, k], fn)


# ---------------------------------------------------------------------------------- rigid

@dataclass
class _Rigid:
    ptr: np.ndarray
    idx: np.ndarray
    rest: np.ndarray
    stiffness: np.ndarray
    lam: None = None


class RigidConstraint(ConstraintBehavior):
    """Shape matching: the element moves as one rigid body (stiffness 1) or softly (< 1)."""

    requires = (Dynamic, Rigid)
    default_importance = 1.0
    default_order = 45

    def bind(self, ctx, elements):
        allidx = vertex_indices(elements)
        ptr = np.concatenate([[0], np.cumsum([e.vertex_count for e in elements])]).astype(np.int64)
        return _Rigid(ptr, allidx, ctx.model.particle_rest[allidx].copy(),
                      np.array([e.get(Rigid).stiffness for e in elements]))

    def begin_substep(self, ctx, d):
        pass

    def project(self, ctx, d, p):
        K.shape_match(p, ctx.model.particle_inv_mass, d.ptr, d.idx, d.rest, d.stiffness)

    def residual(self, ctx, d, p):
        return float(K.residual_shape_match(p, ctx.model.particle_inv_mass, d.ptr, d.idx,
                                            d.rest)[0])


__all__ = ["StretchConstraint", "ShearConstraint", "BendConstraint", "TetVolumeConstraint",
           "GoalConstraint", "AttachmentConstraint", "StitchConstraint", "PressureConstraint",
           "PressureForce", "RigidConstraint", "vertex_measure"]


# ---------------------------------------------------------------------------------- tethers

@njit(cache=True, parallel=True)
def project_tethers(p, w, ptr, anchor, length):
    """Long-range attachments (Kim, Chentanez, Mueller 2012): vertex i stays within
    ``length[r]`` of the pinned vertex ``anchor[r]`` for its rows r = ptr[i] .. ptr[i+1]-1.
    Unilateral; only the dynamic vertex moves (the anchor is pinned). Parallel over vertices."""
    n = ptr.shape[0] - 1
    for i in prange(n):
        if w[i] == 0.0:
            continue
        for r in range(ptr[i], ptr[i + 1]):
            a = anchor[r]
            dx = p[i, 0] - p[a, 0]
            dy = p[i, 1] - p[a, 1]
            dz = p[i, 2] - p[a, 2]
            d = np.sqrt(dx * dx + dy * dy + dz * dz)
            if d > length[r] and d > 0.0:
                s = (d - length[r]) / d
                p[i, 0] -= s * dx
                p[i, 1] -= s * dy
                p[i, 2] -= s * dz


@dataclass
class _Tethers:
    ptr: np.ndarray  # (n+1,) CSR over all vertices of the model
    anchor: np.ndarray
    length: np.ndarray
    lam: None = None


def _flat_convex(X, tris) -> bool:
    """True if the rest mesh is planar and covers its own convex hull (within 1e-9)."""
    c = X.mean(0)
    _, sv, vt = np.linalg.svd(X - c, full_matrices=False)
    scale = max(float(np.ptp(X, axis=0).max()), 1e-300)
    if sv.size < 3 or sv[2] > 1e-9 * scale * np.sqrt(len(X)):
        return False
    uv = (X - c) @ vt[:2].T
    try:
        from scipy.spatial import ConvexHull

        hull_area = ConvexHull(uv).volume
    except Exception:  # noqa: BLE001 - degenerate (collinear) panels: not a flat panel
        return False
    P = uv[tris]
    area = 0.5 * np.abs((P[:, 1, 0] - P[:, 0, 0]) * (P[:, 2, 1] - P[:, 0, 1])
                        - (P[:, 1, 1] - P[:, 0, 1]) * (P[:, 2, 0] - P[:, 0, 0])).sum()
    return abs(area - hull_area) <= 1e-9 * max(hull_area, 1e-300)


def tether_lengths(X, tris, edges, sources):
    """Rest geodesic distance from each source vertex to every vertex (Dijkstra over the mesh
    edges plus the diagonals of every pair of adjacent triangles, a tight upper bound of the
    geodesic on flat panels). Returns (len(sources), n)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import dijkstra

    n = len(X)
    if len(tris) and _flat_convex(X, tris):
        # on a flat convex panel the geodesic is the straight segment: exact tethers
        return np.linalg.norm(X[None, :, :] - X[np.asarray(sources)][:, None, :], axis=2)
    pairs = [edges]
    if len(tris):
        q = T.bend_quads(tris)
        if len(q):
            pairs.append(q[:, 2:4])
    e = np.concatenate(pairs)
    wgt = np.linalg.norm(X[e[:, 0]] - X[e[:, 1]], axis=1)
    g = coo_matrix((wgt, (e[:, 0], e[:, 1])), shape=(n, n)).tocsr()
    return dijkstra(g, directed=False, indices=sources)


class TetherConstraint(ConstraintBehavior):
    """Tethers of every dynamic vertex to the pinned vertices of its element (up to
    ``max_anchors`` nearest), so pinned cloth and hair cannot sag beyond their rest geodesic
    distance however few iterations the stretch constraints get. On by default
    (``tethers: true`` on DiscreteShell / Rod); inextensible materials only."""

    requires = (Dynamic,)
    requires_any = (DiscreteShell, Rod)
    default_importance = 1.0
    default_order = 29

    def bind(self, ctx, elements):
        n = ctx.model.particle_count
        w = ctx.model.particle_inv_mass
        rows_v, rows_a, rows_l = [], [], []
        for e in elements:
            c = e.get(DiscreteShell) or e.get(Rod)
            if not getattr(c, "tethers", False) or c.youngs_modulus is not None:
                continue
            sl = e.vertex_slice
            pinned = np.flatnonzero(w[sl] == 0.0)
            if not len(pinned) or len(pinned) == e.vertex_count:
                continue
            g = e.geometry
            X = _rest(ctx, e, c)
            edges = T.triangle_edges(g.triangles) if len(g.triangles) else g.edges
            D = tether_lengths(X, g.triangles, edges, pinned)
            D = D * getattr(c, "rest_length_scale", 1.0)
            k = min(int(c.max_tether_anchors), len(pinned))
            order = np.argsort(D, axis=0)[:k]  # nearest anchors per vertex
            dist = np.take_along_axis(D, order, axis=0)
            for r in range(k):
                ok = np.isfinite(dist[r]) & (w[sl] > 0)
                v = np.flatnonzero(ok)
                rows_v.append(v + e.vertex_offset)
                rows_a.append(pinned[order[r, v]] + e.vertex_offset)
                rows_l.append(dist[r, v])
        if not rows_v:
            return None
        v = np.concatenate(rows_v)
        srt = np.argsort(v, kind="stable")
        v = v[srt]
        ptr = np.concatenate([[0], np.cumsum(np.bincount(v, minlength=n))]).astype(np.int64)
        return _Tethers(ptr, np.concatenate(rows_a)[srt].astype(np.int64),
                        np.concatenate(rows_l)[srt])

    def begin_substep(self, ctx, d):
        pass

    def project(self, ctx, d, p):
        project_tethers(p, ctx.model.particle_inv_mass, d.ptr, d.anchor, d.length)

    def describe(self, d):
        return f"{len(d.anchor)} tethers" if d is not None else ""
