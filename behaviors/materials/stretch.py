"""Stretch and compression (Nucleus type 1): the length of cloth edges, hair segments and tet
edges, with separate stretch and compression compliance and optional stretch damping.

:class:`StretchConstraint` packs the edges of all bound elements at bind; the XPBD kernels below
project them (conventions in :mod:`lokigraph.behaviors.solvers.nucleus.xpbd`). Stitches
(:mod:`lokigraph.behaviors.attachments.stitch`) reuse the same edge projection."""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from lokigraph.behavior import ConstraintBehavior
from lokigraph.components.core import Dynamic
from lokigraph.components.materials import DiscreteShell, Rod, Volume
from lokigraph.geometry import triangle_areas

from .. import topology as T
from ..solvers.nucleus.xpbd import _INF, _LEN_EPS, _hot, _nudge, residual
from .common import Packed, _concat, _rest
from .volume import rest_tet_volumes


# ==============================================================================================
# XPBD kernels
# ==============================================================================================
@_hot
def _stretch_one(j, p, w, edges, rest, alpha_stretch, alpha_compress, lam, inv_h2):
    a = edges[j, 0]
    b = edges[j, 1]
    wa = w[a]
    wb = w[b]
    ws = wa + wb
    if ws <= 0.0:
        return
    dx = p[a, 0] - p[b, 0]
    dy = p[a, 1] - p[b, 1]
    dz = p[a, 2] - p[b, 2]
    ln = math.sqrt(dx * dx + dy * dy + dz * dz)
    if ln < _LEN_EPS:
        return
    c = ln - rest[j]
    alpha = alpha_stretch[j] if c >= 0.0 else alpha_compress[j]
    if not alpha < _INF:
        return
    at = alpha * inv_h2
    dl = (-c - at * lam[j]) / (ws + at)
    lam[j] += dl
    s = dl / ln
    if wa > 0.0:
        f = wa * s
        p[a, 0] += f * dx
        p[a, 1] += f * dy
        p[a, 2] += f * dz
    if wb > 0.0:
        f = wb * s
        p[b, 0] -= f * dx
        p[b, 1] -= f * dy
        p[b, 2] -= f * dz


@njit(cache=True, parallel=True)
def project_stretch(p, w, edges, rest, alpha_stretch, alpha_compress, lam, h, color_ptr):
    """Type 1 stretch, coloured parallel sweep.

    edges (m, 2) int64; rest lengths [m] (m,); alpha_stretch / alpha_compress compliance [m/N]
    (m,) used when the edge is longer / shorter than rest; lam (m,); h substep [s];
    color_ptr (ncolors + 1,).
    """
    inv_h2 = 1.0 / (h * h)
    for c in range(color_ptr.shape[0] - 1):
        for j in prange(color_ptr[c], color_ptr[c + 1]):
            _stretch_one(j, p, w, edges, rest, alpha_stretch, alpha_compress, lam, inv_h2)


@njit(cache=True)
def project_stretch_seq(p, w, edges, rest, alpha_stretch, alpha_compress, lam, h, color_ptr):
    """Type 1 stretch, sequential sweep in storage order (``color_ptr`` unused)."""
    inv_h2 = 1.0 / (h * h)
    for j in range(edges.shape[0]):
        _stretch_one(j, p, w, edges, rest, alpha_stretch, alpha_compress, lam, inv_h2)


@_hot
def _stretch_damped_one(j, p, x, w, edges, rest, alpha_stretch, alpha_compress, beta, lam, h,
                        inv_h2):
    a = edges[j, 0]
    b = edges[j, 1]
    wa = w[a]
    wb = w[b]
    ws = wa + wb
    if ws <= 0.0:
        return
    dx = p[a, 0] - p[b, 0]
    dy = p[a, 1] - p[b, 1]
    dz = p[a, 2] - p[b, 2]
    ln = math.sqrt(dx * dx + dy * dy + dz * dz)
    if ln < _LEN_EPS:
        return
    nx = dx / ln
    ny = dy / ln
    nz = dz / ln
    c = ln - rest[j]
    alpha = alpha_stretch[j] if c >= 0.0 else alpha_compress[j]
    if not alpha < _INF:
        return
    at = alpha * inv_h2
    gamma = alpha * beta[j] / h
    # grad C . (p - x): relative displacement along the edge during this substep
    vrel = (nx * ((p[a, 0] - x[a, 0]) - (p[b, 0] - x[b, 0]))
            + ny * ((p[a, 1] - x[a, 1]) - (p[b, 1] - x[b, 1]))
            + nz * ((p[a, 2] - x[a, 2]) - (p[b, 2] - x[b, 2])))
    dl = (-c - at * lam[j] - gamma * vrel) / ((1.0 + gamma) * ws + at)
    lam[j] += dl
    _nudge(p, a, wa, dl, nx, ny, nz)
    if wb > 0.0:
        f = wb * dl
        p[b, 0] -= f * nx
        p[b, 1] -= f * ny
        p[b, 2] -= f * nz


@njit(cache=True, parallel=True)
def project_stretch_damped(p, x, w, edges, rest, alpha_stretch, alpha_compress, beta, lam, h,
                           color_ptr):
    """Type 1 stretch with XPBD constraint damping, coloured parallel sweep.

    x: positions at the start of the substep [m] (n, 3), read only. beta: damping coefficient
    [N s/m] (m,); the XPBD damping ratio is ``gamma = alpha * beta / h`` and the update is
    ``dlam = (-C - alpha~ lam - gamma grad C . (p - x)) / ((1 + gamma) sum w |grad C|^2 +
    alpha~)``. beta = 0 reproduces ``project_stretch``. A hard edge (alpha = 0) gets no damping
    (it cannot oscillate). Other arguments as ``project_stretch``.
    """
    inv_h2 = 1.0 / (h * h)
    for c in range(color_ptr.shape[0] - 1):
        for j in prange(color_ptr[c], color_ptr[c + 1]):
            _stretch_damped_one(j, p, x, w, edges, rest, alpha_stretch, alpha_compress, beta,
                                lam, h, inv_h2)


@njit(cache=True)
def project_stretch_damped_seq(p, x, w, edges, rest, alpha_stretch, alpha_compress, beta, lam,
                               h, color_ptr):
    """Sequential variant of ``project_stretch_damped`` (``color_ptr`` unused)."""
    inv_h2 = 1.0 / (h * h)
    for j in range(edges.shape[0]):
        _stretch_damped_one(j, p, x, w, edges, rest, alpha_stretch, alpha_compress, beta, lam,
                            h, inv_h2)


@njit(cache=True)
def stretch_values(p, edges, rest):
    """C = |p_i - p_j| - L for every edge, shape (m,)."""
    out = np.empty(edges.shape[0])
    for j in range(edges.shape[0]):
        a = edges[j, 0]
        b = edges[j, 1]
        d = 0.0
        for k in range(3):
            t = p[a, k] - p[b, k]
            d += t * t
        out[j] = math.sqrt(d) - rest[j]
    return out


def residual_stretch(p, edges, rest):
    """(max |C| [m], RMS [m]) of the stretch constraints."""
    return residual(stretch_values(p, edges, rest))


def rest_lengths(x, edges):
    """Rest lengths [m] of edges at positions x, shape (m,)."""
    x = np.asarray(x, dtype=np.float64)
    return np.linalg.norm(x[edges[:, 0]] - x[edges[:, 1]], axis=1)


# ------------------------------------------------------------------ Nucleus constraint behavior


def _project_edges(ctx, d, p):
    """Distance rows of a Packed set (stretch edges, stitches): damped where it has beta,
    sequential or coloured parallel by its size."""
    w = ctx.model.particle_inv_mass
    if d.beta is not None:
        fn = project_stretch_damped_seq if d.sequential else project_stretch_damped
        fn(p, ctx.state.particle_q, w, d.idx, d.rest, d.alpha, d.alpha2, d.beta, d.lam,
           ctx.dt, d.color_ptr)
    else:
        fn = project_stretch_seq if d.sequential else project_stretch
        fn(p, w, d.idx, d.rest, d.alpha, d.alpha2, d.lam, ctx.dt, d.color_ptr)


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
                vol = rest_tet_volumes(X, tt)
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
        return float(residual_stretch(p, d.idx, d.rest)[0])

    def describe(self, d):
        return f"{len(d)} edges, {len(d.color_ptr) - 1} colours" if d is not None else ""


def _compress(a, ratio):
    """Compression compliance: stretch compliance / ratio; ratio 0 switches compression off."""
    return a / ratio if ratio > 0 else np.full_like(a, np.inf)
