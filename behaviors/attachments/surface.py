"""Point-to-surface attachments: a vertex held at fixed barycentrics of a triangle of another
element, or sliding on that surface (the closest point is re-found every substep)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit, prange

from lokigraph.behavior import ConstraintBehavior
from lokigraph.errors import InputError
from lokigraph.components.materials import Attachment

from ..collision.narrowphase import point_triangle_distance
from ..solvers.nucleus.xpbd import _INF, _hot, residual


# ==============================================================================================
# XPBD kernels: point-to-triangle attachment at fixed barycentrics
# ==============================================================================================
@_hot
def _attach_one(j, p, w, attach, bary, alpha, lam, inv_h2):
    v = attach[j, 0]
    t0 = attach[j, 1]
    t1 = attach[j, 2]
    t2 = attach[j, 3]
    b0 = bary[j, 0]
    b1 = bary[j, 1]
    b2 = bary[j, 2]
    wv = w[v]
    w0 = w[t0]
    w1 = w[t1]
    w2 = w[t2]
    den = wv + b0 * b0 * w0 + b1 * b1 * w1 + b2 * b2 * w2
    if den <= 0.0:
        return
    al = alpha[j]
    if not al < _INF:
        return
    at = al * inv_h2
    inv = 1.0 / (den + at)
    for k in range(3):
        c = p[v, k] - (b0 * p[t0, k] + b1 * p[t1, k] + b2 * p[t2, k])
        dl = (-c - at * lam[j, k]) * inv
        lam[j, k] += dl
        if wv > 0.0:
            p[v, k] += wv * dl
        if w0 > 0.0:
            p[t0, k] -= w0 * b0 * dl
        if w1 > 0.0:
            p[t1, k] -= w1 * b1 * dl
        if w2 > 0.0:
            p[t2, k] -= w2 * b2 * dl


@njit(cache=True, parallel=True)
def project_attach(p, w, attach, bary, alpha, lam, h, color_ptr):
    """Point-to-triangle attachment ``C = p_v - (b0 p_t0 + b1 p_t1 + b2 p_t2)`` (3 rows).

    attach (m, 4) int64 rows ``(v, t0, t1, t2)``; bary (m, 3) fixed barycentric weights
    (summing to 1 for momentum conservation); alpha compliance [m/N] (m,); lam (m, 3). The three
    rows share one scalar denominator ``w_v + sum b_k^2 w_k``, so the 3-row step is exact.
    Coloured parallel sweep.
    """
    inv_h2 = 1.0 / (h * h)
    for c in range(color_ptr.shape[0] - 1):
        for j in prange(color_ptr[c], color_ptr[c + 1]):
            _attach_one(j, p, w, attach, bary, alpha, lam, inv_h2)


@njit(cache=True)
def project_attach_seq(p, w, attach, bary, alpha, lam, h, color_ptr):
    """Sequential variant of ``project_attach`` (``color_ptr`` unused)."""
    inv_h2 = 1.0 / (h * h)
    for j in range(attach.shape[0]):
        _attach_one(j, p, w, attach, bary, alpha, lam, inv_h2)


@njit(cache=True)
def attach_values(p, attach, bary):
    """C = p_v - sum_k b_k p_tk [m] per attachment, shape (m, 3)."""
    out = np.empty((attach.shape[0], 3))
    for j in range(attach.shape[0]):
        for k in range(3):
            out[j, k] = p[attach[j, 0], k] - (bary[j, 0] * p[attach[j, 1], k]
                                              + bary[j, 1] * p[attach[j, 2], k]
                                              + bary[j, 2] * p[attach[j, 3], k])
    return out


def residual_attach(p, attach, bary):
    """(max |C| [m], RMS [m]) of the attachments (|C| is the norm of the 3-vector)."""
    return residual(attach_values(p, attach, bary))


# ------------------------------------------------------------------- closest points and sliding


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


# ------------------------------------------------------------------ Nucleus constraint behavior


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
            project_attach_seq(p, w, d.attach, d.bary, d.alpha, d.lam, ctx.dt,
                                 np.array([0, len(d.attach)], np.int64))
        else:
            project_attach_seq(p, w, d.attach[fixed], d.bary[fixed], d.alpha[fixed],
                                 d.lam[fixed], ctx.dt, np.array([0, int(fixed.sum())], np.int64))
            project_plane(p, w, d.attach[d.sliding], d.bary[d.sliding])

    def residual(self, ctx, d, p):
        return float(residual_attach(p, d.attach, d.bary)[0])

    def describe(self, d):
        return f"{len(d.attach)} attached vertices" if d is not None else ""


# ==============================================================================================
# Implicit energy (behaviors/solvers/implicit/energy.py has the protocol)
# ==============================================================================================
from ..solvers.implicit.energy import grad_or_dummy, hess_or_dummy, row_k  # noqa: E402


@njit(cache=True)
def attach_energy(x, rows, bary, alpha, on, hard_k, mode, grad, hess):
    """Attachment energy ``k |x_v - sum_i b_i x_ti|^2 / 2`` of rows ``(v, t0, t1, t2)`` with
    fixed barycentrics (``k = 1 / alpha``, the hard penalty of v when alpha is 0); only rows
    with ``on`` set. Gradient and Hessian ``k c_a c_b I`` (c = (1, -b0, -b1, -b2)) exact."""
    E = 0.0
    cf = np.zeros(4)
    for j in range(rows.shape[0]):
        if not on[j]:
            continue
        v = rows[j, 0]
        k = row_k(alpha[j], hard_k, v, v)
        if k == 0.0:
            continue
        cf[0] = 1.0
        cf[1] = -bary[j, 0]
        cf[2] = -bary[j, 1]
        cf[3] = -bary[j, 2]
        for r in range(3):
            c = 0.0
            for a in range(4):
                c += cf[a] * x[rows[j, a], r]
            E += 0.5 * k * c * c
            if mode >= 1:
                for a in range(4):
                    grad[rows[j, a], r] += k * cf[a] * c
            if mode >= 2:
                for a in range(4):
                    for b in range(4):
                        hess[j, a, b, r, r] = k * cf[a] * cf[b]
    return E


def _attach_energy_stencils(self, ctx, d):
    # sliding rows change triangles every substep: they are projected (implicit_project)
    return [d.attach]


def _attach_energy(self, ctx, d, x, grad, hess, opts):
    return attach_energy(x, d.attach, d.bary, d.alpha, ~d.sliding, opts.hard_k, opts.mode,
                         grad_or_dummy(grad, opts), hess_or_dummy(hess, 0, opts))


def _attach_implicit_project(self, ctx, d, p):
    """Sliding attachments after the Newton solve: onto the plane of their closest triangle."""
    if d.sliding.any():
        project_plane(p, ctx.model.particle_inv_mass, d.attach[d.sliding], d.bary[d.sliding])


# the implicit energy protocol on the Nucleus constraint type of this effect
AttachmentConstraint.energy_stencils = _attach_energy_stencils
AttachmentConstraint.energy = _attach_energy
AttachmentConstraint.implicit_project = _attach_implicit_project
