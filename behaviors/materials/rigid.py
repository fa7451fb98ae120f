"""Rigid and soft bodies by shape matching (Mueller et al. 2005): every element with Rigid moves
as one rigid body (stiffness 1) or softly (< 1)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from lokigraph.behavior import ConstraintBehavior, vertex_indices
from lokigraph.components.core import Dynamic
from lokigraph.components.materials import Rigid

from ..solvers.nucleus.xpbd import residual


# ==============================================================================================
# kernels: rigid shape matching
# ==============================================================================================
_PINNED_MASS_SCALE = 1e9


@njit(cache=True)
def _cluster_frame(p, w, cluster_idx, cluster_rest, lo, hi):
    """Mass-weighted centres (current c, rest c0) and the optimal rotation R of one cluster."""
    # masses: 1/w; a pinned vertex (w == 0) weighs _PINNED_MASS_SCALE x the heaviest dynamic one
    mmax = 0.0
    for r in range(lo, hi):
        wv = w[cluster_idx[r]]
        if wv > 0.0 and 1.0 / wv > mmax:
            mmax = 1.0 / wv
    if mmax == 0.0:
        mmax = 1.0
    mp = _PINNED_MASS_SCALE * mmax
    c = np.zeros(3)
    c0 = np.zeros(3)
    mt = 0.0
    for r in range(lo, hi):
        v = cluster_idx[r]
        wv = w[v]
        mv = 1.0 / wv if wv > 0.0 else mp
        mt += mv
        for k in range(3):
            c[k] += mv * p[v, k]
            c0[k] += mv * cluster_rest[r, k]
    for k in range(3):
        c[k] /= mt
        c0[k] /= mt
    a = np.zeros((3, 3))
    for r in range(lo, hi):
        v = cluster_idx[r]
        wv = w[v]
        mv = 1.0 / wv if wv > 0.0 else mp
        for k in range(3):
            dk = mv * (p[v, k] - c[k])
            for l in range(3):
                a[k, l] += dk * (cluster_rest[r, l] - c0[l])
    u, _s, vt = np.linalg.svd(a)
    rot = u @ vt
    if np.linalg.det(rot) < 0.0:
        for k in range(3):
            u[k, 2] = -u[k, 2]
        rot = u @ vt
    return c, c0, rot


@njit(cache=True)
def shape_match(p, w, cluster_ptr, cluster_idx, cluster_rest, stiffness):
    """Rigid shape matching (Mueller et al. 2005), clusters one after another.

    Cluster q owns rows ``cluster_ptr[q] .. cluster_ptr[q+1]-1`` of ``cluster_idx`` (vertex,
    int64) and ``cluster_rest`` (rest position [m], (K, 3)). The goal of every member is
    ``g = c + R (q - c0)`` with c, c0 the mass-weighted current and rest centres and R the
    rotation of the polar decomposition of ``sum m (p - c)(q - c0)^T`` (via SVD, reflections
    removed); dynamic members move ``p += stiffness[q] * (g - p)``, stiffness in [0, 1] per
    iteration. Pinned members (w == 0) are not moved and weigh 1e9 x the heaviest dynamic member.
    Conserves linear momentum when every member is dynamic.
    """
    for q in range(cluster_ptr.shape[0] - 1):
        lo = cluster_ptr[q]
        hi = cluster_ptr[q + 1]
        if hi <= lo:
            continue
        c, c0, rot = _cluster_frame(p, w, cluster_idx, cluster_rest, lo, hi)
        s = stiffness[q]
        for r in range(lo, hi):
            v = cluster_idx[r]
            if w[v] <= 0.0:
                continue
            for k in range(3):
                g = c[k]
                for l in range(3):
                    g += rot[k, l] * (cluster_rest[r, l] - c0[l])
                p[v, k] += s * (g - p[v, k])


@njit(cache=True)
def shape_match_values(p, w, cluster_ptr, cluster_idx, cluster_rest):
    """Distance [m] of every cluster member to its rigid goal, shape (K,)."""
    out = np.empty(cluster_idx.shape[0])
    for q in range(cluster_ptr.shape[0] - 1):
        lo = cluster_ptr[q]
        hi = cluster_ptr[q + 1]
        if hi <= lo:
            continue
        c, c0, rot = _cluster_frame(p, w, cluster_idx, cluster_rest, lo, hi)
        for r in range(lo, hi):
            d = 0.0
            for k in range(3):
                g = c[k]
                for l in range(3):
                    g += rot[k, l] * (cluster_rest[r, l] - c0[l])
                t = p[cluster_idx[r], k] - g
                d += t * t
            out[r] = math.sqrt(d)
    return out


def residual_shape_match(p, w, cluster_ptr, cluster_idx, cluster_rest):
    """(max, RMS) distance [m] of cluster members to their rigid goals."""
    return residual(shape_match_values(p, w, cluster_ptr, cluster_idx, cluster_rest))


# ------------------------------------------------------------------ Nucleus constraint behavior


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
        shape_match(p, ctx.model.particle_inv_mass, d.ptr, d.idx, d.rest, d.stiffness)

    def residual(self, ctx, d, p):
        return float(residual_shape_match(p, ctx.model.particle_inv_mass, d.ptr, d.idx,
                                            d.rest)[0])
