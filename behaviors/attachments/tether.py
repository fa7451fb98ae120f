"""Tethers (long-range attachments, Kim, Chentanez, Mueller 2012): every dynamic vertex stays
within its rest geodesic distance of the nearest pinned vertices of its element."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit, prange

from lokigraph.behavior import ConstraintBehavior
from lokigraph.components.core import Dynamic
from lokigraph.components.materials import DiscreteShell, Rod

from .. import topology as T
from ..materials.common import _rest


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
