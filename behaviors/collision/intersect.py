"""Independent intersection checker: counts intersecting triangle pairs (a "penetration count").

It is a diagnostic, not part of the solver: after a frame, call :func:`find_intersections` (one
vertex array, possibly several meshes concatenated) or :func:`intersect_meshes` (a list of meshes)
and check that the count stays 0. Candidates come from the broad phase BVH
(:mod:`lokigraph.behaviors.collision.broadphase`, static triangle boxes, zero thickness); each
candidate pair is then decided exactly.

Exactness
---------
All decisions are signs of orientation determinants:

* ``orient3d(a, b, c, d) = det[a - d, b - d, c - d]`` (positive when ``d`` is below the plane of
  the counter-clockwise ``a, b, c``), and ``orient2d`` on coordinates projected to an axis plane.
* Each is first evaluated in float64 with Shewchuk's static error bound; when the result is within
  the bound, it is recomputed **exactly** with floating-point expansion arithmetic (two-sum,
  two-product), so every sign is exact for finite float64 input whose intermediate products
  neither overflow nor underflow: coordinates and nonzero coordinate differences between about
  1e-90 and 1e90 in magnitude (subnormal inputs such as ``nextafter(0, 1)`` can give wrong signs).
  When every product in the determinant is exactly zero the sign is 0 without the exact path
  (e.g. all points in one axis-aligned plane), which keeps flat meshes cheap.

Test per triangle pair: the triangles intersect iff an edge of one meets the other (this covers
every configuration of two non-degenerate triangles, coplanar ones included). Segment-triangle:
endpoints on the same strict side of the plane -> no; both on the plane -> coplanar 2-D test
(projection to the axis plane where the triangle's projection is non-degenerate, exactly
verified); otherwise the line's three signed volumes with the triangle's edges decide.

Semantics (``touching``)
------------------------
* ``touching=True`` (default): closed sets. Any common point counts: crossing, touching at a point
  or along an edge, vertex on a face, and coplanar overlap.
* ``touching=False``: only proper crossings count: an edge whose endpoints are strictly on
  opposite sides of the other triangle's plane and which passes through the open interior of that
  triangle. Touching contacts and coplanar pairs never count. (A crossing where every edge hits
  exactly a boundary of the other triangle -- a measure-zero configuration -- is not reported.)

Pairs of triangles that share a vertex index are skipped (adjacent triangles of one mesh), also
when they would intersect elsewhere (e.g. a fold across a shared vertex). Meshes in separate
vertex ranges never share indices, so coincident vertices of two different meshes count as
touching under ``touching=True``.

Cost: one BVH build over the triangles per call plus the exact tests of the candidate pairs
(parallel over pairs); the exact fallback runs only for nearly degenerate configurations.

Limitations: a zero-area (collinear) triangle is handled through the other triangle's test only;
two degenerate triangles, or a segment against a degenerate triangle lying in its line, are not
reported. Self-intersections across a shared vertex are not detected (see above).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit, prange

from lokigraph.behaviors.collision import broadphase as bp

__all__ = [
    "IntersectionReport",
    "orient3d",
    "orient2d",
    "segment_triangle_intersect",
    "triangles_intersect",
    "find_intersections",
    "intersect_meshes",
    "penetration_count",
]

_EPS = 2.0**-53
_SPLITTER = 2.0**27 + 1.0
_O3D_BOUND = (7.0 + 56.0 * _EPS) * _EPS
_O2D_BOUND = (3.0 + 16.0 * _EPS) * _EPS


# --------------------------------------------------------------------------------------------
# Expansion arithmetic (Shewchuk 1997)
# --------------------------------------------------------------------------------------------


@njit(cache=True, inline="always")
def _two_sum(a, b):
    x = a + b
    bv = x - a
    av = x - bv
    return x, (a - av) + (b - bv)


@njit(cache=True, inline="always")
def _split(a):
    c = _SPLITTER * a
    big = c - a
    hi = c - big
    return hi, a - hi


@njit(cache=True, inline="always")
def _two_prod(a, b):
    x = a * b
    ahi, alo = _split(a)
    bhi, blo = _split(b)
    err = x - ahi * bhi
    err -= alo * bhi
    err -= ahi * blo
    return x, alo * blo - err


@njit(cache=True)
def _grow(e, elen, b, h):
    """h = e + b (zero-eliminating grow_expansion); returns len(h). h must not alias e."""
    q = b
    hl = 0
    for i in range(elen):
        q, hh = _two_sum(q, e[i])
        if hh != 0.0:
            h[hl] = hh
            hl += 1
    if q != 0.0 or hl == 0:
        h[hl] = q
        hl += 1
    return hl


@njit(cache=True)
def _sum(e, elen, f, flen, h, tmp):
    """h = e + f by repeated growing (nonoverlapping inputs suffice); returns len(h)."""
    for i in range(elen):
        h[i] = e[i]
    hl = elen
    for j in range(flen):
        tl = _grow(h, hl, f[j], tmp)
        for i in range(tl):
            h[i] = tmp[i]
        hl = tl
    return hl


@njit(cache=True)
def _scale(e, elen, b, h):
    """h = e * b (scale_expansion_zeroelim); returns len(h)."""
    bhi, blo = _split(b)
    q = e[0] * b
    ahi, alo = _split(e[0])
    hh = alo * blo - (((q - ahi * bhi) - alo * bhi) - ahi * blo)
    hl = 0
    if hh != 0.0:
        h[hl] = hh
        hl += 1
    for i in range(1, elen):
        p1 = e[i] * b
        ahi, alo = _split(e[i])
        p0 = alo * blo - (((p1 - ahi * bhi) - alo * bhi) - ahi * blo)
        s, hh = _two_sum(q, p0)
        if hh != 0.0:
            h[hl] = hh
            hl += 1
        q = p1 + s
        hh = s - (q - p1)
        if hh != 0.0:
            h[hl] = hh
            hl += 1
    if q != 0.0 or hl == 0:
        h[hl] = q
        hl += 1
    return hl


@njit(cache=True)
def _minor(px, py, qx, qy, out):
    """out = px*qy - qx*py exactly; returns length (<= 4)."""
    x1, x0 = _two_prod(px, qy)
    y1, y0 = _two_prod(qx, py)
    e = np.empty(2)
    n = 0
    if x0 != 0.0:
        e[n] = x0
        n += 1
    e[n] = x1
    n += 1
    tmp = np.empty(4)
    n = _grow(e, n, -y0, tmp)
    return _grow(tmp, n, -y1, out)


@njit(cache=True)
def _orient3d_exact(a, b, c, d):
    # D = az*M(bcd) - bz*M(acd) + cz*M(abd) - dz*M(abc), M(pqr) = pq + qr + rp (2-D minors in x, y)
    ab = np.empty(4)
    bc = np.empty(4)
    cd = np.empty(4)
    da = np.empty(4)
    ac = np.empty(4)
    bd = np.empty(4)
    lab = _minor(a[0], a[1], b[0], b[1], ab)
    lbc = _minor(b[0], b[1], c[0], c[1], bc)
    lcd = _minor(c[0], c[1], d[0], d[1], cd)
    lda = _minor(d[0], d[1], a[0], a[1], da)
    lac = _minor(a[0], a[1], c[0], c[1], ac)
    lbd = _minor(b[0], b[1], d[0], d[1], bd)
    tmp = np.empty(128)
    t8 = np.empty(16)
    m = np.empty(16)
    sc = np.empty(32)
    acc = np.empty(128)
    acc2 = np.empty(128)
    acc[0] = 0.0
    alen = 1
    for which in range(4):
        if which == 0:  # +az * (bc + cd - bd)
            l1 = _sum(bc, lbc, cd, lcd, t8, tmp)
            for i in range(lbd):
                bd[i] = -bd[i]
            l2 = _sum(t8, l1, bd, lbd, m, tmp)
            for i in range(lbd):
                bd[i] = -bd[i]
            z = a[2]
        elif which == 1:  # -bz * (ac + cd + da)
            l1 = _sum(ac, lac, cd, lcd, t8, tmp)
            l2 = _sum(t8, l1, da, lda, m, tmp)
            z = -b[2]
        elif which == 2:  # +cz * (ab + bd + da)
            l1 = _sum(ab, lab, bd, lbd, t8, tmp)
            l2 = _sum(t8, l1, da, lda, m, tmp)
            z = c[2]
        else:  # -dz * (ab + bc - ac)
            l1 = _sum(ab, lab, bc, lbc, t8, tmp)
            for i in range(lac):
                ac[i] = -ac[i]
            l2 = _sum(t8, l1, ac, lac, m, tmp)
            z = -d[2]
        ls = _scale(m, l2, z, sc)
        alen = _sum(acc, alen, sc, ls, acc2, tmp)
        for i in range(alen):
            acc[i] = acc2[i]
    return acc[alen - 1]


@njit(cache=True)
def _orient2d_exact(ax, ay, bx, by, cx, cy):
    ab = np.empty(4)
    bc = np.empty(4)
    ca = np.empty(4)
    lab = _minor(ax, ay, bx, by, ab)
    lbc = _minor(bx, by, cx, cy, bc)
    lca = _minor(cx, cy, ax, ay, ca)
    tmp = np.empty(16)
    t8 = np.empty(16)
    h = np.empty(16)
    l1 = _sum(ab, lab, bc, lbc, t8, tmp)
    l2 = _sum(t8, l1, ca, lca, h, tmp)
    return h[l2 - 1]


@njit(cache=True)
def _o3d(a, b, c, d):
    """Sign (-1, 0, 1) of orient3d, exact (filtered)."""
    adx = a[0] - d[0]
    bdx = b[0] - d[0]
    cdx = c[0] - d[0]
    ady = a[1] - d[1]
    bdy = b[1] - d[1]
    cdy = c[1] - d[1]
    adz = a[2] - d[2]
    bdz = b[2] - d[2]
    cdz = c[2] - d[2]
    bdxcdy = bdx * cdy
    cdxbdy = cdx * bdy
    cdxady = cdx * ady
    adxcdy = adx * cdy
    adxbdy = adx * bdy
    bdxady = bdx * ady
    det = adz * (bdxcdy - cdxbdy) + bdz * (cdxady - adxcdy) + cdz * (adxbdy - bdxady)
    perm = ((abs(bdxcdy) + abs(cdxbdy)) * abs(adz) + (abs(cdxady) + abs(adxcdy)) * abs(bdz)
            + (abs(adxbdy) + abs(bdxady)) * abs(cdz))
    if perm == 0.0:
        return 0
    bound = _O3D_BOUND * perm
    if det > bound:
        return 1
    if -det > bound:
        return -1
    e = _orient3d_exact(a, b, c, d)
    return 1 if e > 0.0 else (-1 if e < 0.0 else 0)


@njit(cache=True)
def _o2d(ax, ay, bx, by, cx, cy):
    """Sign of (a - c) x (b - c), exact (filtered)."""
    left = (ax - cx) * (by - cy)
    right = (ay - cy) * (bx - cx)
    det = left - right
    s = abs(left) + abs(right)
    if s == 0.0:
        return 0
    bound = _O2D_BOUND * s
    if det > bound:
        return 1
    if -det > bound:
        return -1
    e = _orient2d_exact(ax, ay, bx, by, cx, cy)
    return 1 if e > 0.0 else (-1 if e < 0.0 else 0)


# --------------------------------------------------------------------------------------------
# Segment / triangle predicates
# --------------------------------------------------------------------------------------------


@njit(cache=True, inline="always")
def _on_seg2(px, py, qx, qy, rx, ry):
    # r collinear with pq: is r within the closed segment?
    return min(px, qx) <= rx <= max(px, qx) and min(py, qy) <= ry <= max(py, qy)


@njit(cache=True)
def _seg_seg2(px, py, qx, qy, ax, ay, bx, by):
    """Closed 2-D segments pq and ab intersect."""
    d1 = _o2d(px, py, qx, qy, ax, ay)
    d2 = _o2d(px, py, qx, qy, bx, by)
    d3 = _o2d(ax, ay, bx, by, px, py)
    d4 = _o2d(ax, ay, bx, by, qx, qy)
    if d1 * d2 < 0 and d3 * d4 < 0:
        return True
    if d1 == 0 and _on_seg2(px, py, qx, qy, ax, ay):
        return True
    if d2 == 0 and _on_seg2(px, py, qx, qy, bx, by):
        return True
    if d3 == 0 and _on_seg2(ax, ay, bx, by, px, py):
        return True
    if d4 == 0 and _on_seg2(ax, ay, bx, by, qx, qy):
        return True
    return False


@njit(cache=True)
def _coplanar_seg_tri(p, q, a, b, c):
    """Closed segment pq vs closed triangle abc, all five points exactly coplanar."""
    nx = (b[1] - a[1]) * (c[2] - a[2]) - (b[2] - a[2]) * (c[1] - a[1])
    ny = (b[2] - a[2]) * (c[0] - a[0]) - (b[0] - a[0]) * (c[2] - a[2])
    nz = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])
    first = 0
    if abs(ny) > abs(nx) and abs(ny) >= abs(nz):
        first = 1
    elif abs(nz) > abs(nx) and abs(nz) > abs(ny):
        first = 2
    for t in range(3):
        drop = (first + t) % 3
        u = 1 if drop == 0 else 0
        v = 1 if drop == 2 else 2
        o = _o2d(a[u], a[v], b[u], b[v], c[u], c[v])
        if o == 0:
            continue  # projection degenerate along this axis, try the next
        # endpoint inside the closed triangle?
        for w in range(2):
            x = p if w == 0 else q
            s1 = _o2d(a[u], a[v], b[u], b[v], x[u], x[v]) * o
            s2 = _o2d(b[u], b[v], c[u], c[v], x[u], x[v]) * o
            s3 = _o2d(c[u], c[v], a[u], a[v], x[u], x[v]) * o
            if s1 >= 0 and s2 >= 0 and s3 >= 0:
                return True
        if _seg_seg2(p[u], p[v], q[u], q[v], a[u], a[v], b[u], b[v]):
            return True
        if _seg_seg2(p[u], p[v], q[u], q[v], b[u], b[v], c[u], c[v]):
            return True
        if _seg_seg2(p[u], p[v], q[u], q[v], c[u], c[v], a[u], a[v]):
            return True
        return False
    return False  # degenerate (collinear) triangle


@njit(cache=True)
def _seg_tri(p, q, a, b, c, touching):
    sp = _o3d(a, b, c, p)
    sq = _o3d(a, b, c, q)
    if sp * sq > 0:
        return False
    if sp == 0 and sq == 0:
        if not touching:
            return False
        return _coplanar_seg_tri(p, q, a, b, c)
    if not touching and (sp == 0 or sq == 0):
        return False
    s1 = _o3d(p, q, a, b)
    s2 = _o3d(p, q, b, c)
    s3 = _o3d(p, q, c, a)
    if touching:
        has_pos = s1 > 0 or s2 > 0 or s3 > 0
        has_neg = s1 < 0 or s2 < 0 or s3 < 0
        return not (has_pos and has_neg)
    return (s1 > 0 and s2 > 0 and s3 > 0) or (s1 < 0 and s2 < 0 and s3 < 0)


@njit(cache=True)
def _tri_tri(a0, a1, a2, b0, b1, b2, touching):
    if _seg_tri(a0, a1, b0, b1, b2, touching):
        return True
    if _seg_tri(a1, a2, b0, b1, b2, touching):
        return True
    if _seg_tri(a2, a0, b0, b1, b2, touching):
        return True
    if _seg_tri(b0, b1, a0, a1, a2, touching):
        return True
    if _seg_tri(b1, b2, a0, a1, a2, touching):
        return True
    if _seg_tri(b2, b0, a0, a1, a2, touching):
        return True
    return False


@njit(parallel=True, cache=True)
def _tri_pairs_kernel(V, F, pairs, touching, hit):
    for t in prange(pairs.shape[0]):
        i = pairs[t, 0]
        j = pairs[t, 1]
        hit[t] = _tri_tri(V[F[i, 0]], V[F[i, 1]], V[F[i, 2]], V[F[j, 0]], V[F[j, 1]], V[F[j, 2]],
                          touching)


@njit(parallel=True, cache=True)
def _seg_tri_pairs_kernel(V, E, F, pairs, touching, hit):
    for t in prange(pairs.shape[0]):
        i = pairs[t, 0]
        j = pairs[t, 1]
        hit[t] = _seg_tri(V[E[i, 0]], V[E[i, 1]], V[F[j, 0]], V[F[j, 1]], V[F[j, 2]], touching)


# --------------------------------------------------------------------------------------------
# Public API
# --------------------------------------------------------------------------------------------


def orient3d(a, b, c, d) -> int:
    """Exact sign (-1, 0, +1) of ``det[a - d, b - d, c - d]`` for float64 3-vectors."""
    f = lambda x: np.ascontiguousarray(x, dtype=np.float64).reshape(3)  # noqa: E731
    return int(_o3d(f(a), f(b), f(c), f(d)))


def orient2d(a, b, c) -> int:
    """Exact sign (-1, 0, +1) of ``(a - c) x (b - c)`` for float64 2-vectors."""
    return int(_o2d(float(a[0]), float(a[1]), float(b[0]), float(b[1]), float(c[0]), float(c[1])))


def segment_triangle_intersect(p, q, a, b, c, touching: bool = True) -> bool:
    """Exact test of segment ``pq`` against triangle ``abc`` (see module docstring for ``touching``)."""
    f = lambda x: np.ascontiguousarray(x, dtype=np.float64).reshape(3)  # noqa: E731
    return bool(_seg_tri(f(p), f(q), f(a), f(b), f(c), bool(touching)))


def triangles_intersect(t1, t2, touching: bool = True) -> bool:
    """Exact test of two triangles given as (3, 3) vertex arrays (no shared-vertex skipping)."""
    A = np.ascontiguousarray(t1, dtype=np.float64).reshape(3, 3)
    B = np.ascontiguousarray(t2, dtype=np.float64).reshape(3, 3)
    return bool(_tri_tri(A[0], A[1], A[2], B[0], B[1], B[2], bool(touching)))


class IntersectionReport(NamedTuple):
    """Result of :func:`find_intersections`."""

    count: int
    """Number of intersecting triangle pairs plus intersecting segment-triangle pairs."""
    tri_pairs: np.ndarray
    """Intersecting triangle pairs ``(i, j)``, ``i < j`` (face indices), shape (k, 2), int64."""
    edge_tri_pairs: np.ndarray
    """Intersecting ``(segment, face)`` pairs for the optional segments, shape (m, 2), int64."""
    candidate_count: int
    """Number of broad-phase candidates tested exactly."""


def find_intersections(V, F, E=None, touching: bool = True, out=None) -> IntersectionReport:
    """Find intersecting triangle pairs (and segment-triangle pairs) of a triangle soup.

    Parameters
    ----------
    V : (vertex_count, 3) float64
        Vertex positions [m]; several meshes may be concatenated (disjoint vertex ranges).
    F : (face_count, 3) int
        Triangles. Pairs sharing a vertex index are skipped.
    E : (segment_count, 2) int, optional
        Extra segments (e.g. hair or rod edges) tested against every triangle; a segment and a
        triangle sharing a vertex index are skipped. Not the triangles' own edges.
    touching : bool
        Closed-set semantics (default) or proper crossings only; see the module docstring.
    out : broadphase.PairBuffer, optional
        Reused storage of the triangle candidate pairs (a caller checking every frame keeps
        one: the broad phase then traverses once instead of twice). Same result.

    Returns
    -------
    IntersectionReport
    """
    V = bp._as_positions(V, "V")
    if not np.all(np.isfinite(V)):
        raise ValueError("V: positions must be finite")
    F = bp._as_prims(F, "F")
    if F.shape[0] and F.shape[1] != 3:
        raise ValueError(f"F: expected shape (face_count, 3), got {F.shape}")
    if F.size and (F.min() < 0 or F.max() >= V.shape[0]):
        raise ValueError("F: vertex index out of range")
    lo, hi = bp.primitive_boxes(V, F)
    bvh_f = bp.build_bvh(lo, hi)
    cand = bp.query_self(bvh_f, F, out=out)
    hit = np.zeros(cand.shape[0], dtype=np.bool_)
    if cand.shape[0]:
        _tri_pairs_kernel(V, F, cand, bool(touching), hit)
    tri_pairs = cand[hit]
    n_cand = int(cand.shape[0])
    et_pairs = np.zeros((0, 2), dtype=np.int64)
    if E is not None:
        E = bp._as_prims(E, "E")
        if E.shape[0]:
            if E.shape[1] != 2:
                raise ValueError(f"E: expected shape (segment_count, 2), got {E.shape}")
            if E.min() < 0 or E.max() >= V.shape[0]:
                raise ValueError("E: vertex index out of range")
            le, he = bp.primitive_boxes(V, E)
            bvh_e = bp.build_bvh(le, he)
            ecand = bp.query_pairs(bvh_e, bvh_f, E, F)
            ehit = np.zeros(ecand.shape[0], dtype=np.bool_)
            if ecand.shape[0]:
                _seg_tri_pairs_kernel(V, E, F, ecand, bool(touching), ehit)
            et_pairs = ecand[ehit]
            n_cand += int(ecand.shape[0])
    # deterministic, sorted output
    if tri_pairs.shape[0]:
        tri_pairs = tri_pairs[np.lexsort((tri_pairs[:, 1], tri_pairs[:, 0]))]
    if et_pairs.shape[0]:
        et_pairs = et_pairs[np.lexsort((et_pairs[:, 1], et_pairs[:, 0]))]
    return IntersectionReport(int(tri_pairs.shape[0] + et_pairs.shape[0]),
                              np.ascontiguousarray(tri_pairs), np.ascontiguousarray(et_pairs), n_cand)


def penetration_count(V, F, E=None, touching: bool = True) -> int:
    """Number of intersecting triangle (and segment-triangle) pairs; see :func:`find_intersections`."""
    return find_intersections(V, F, E, touching).count


def intersect_meshes(meshes, touching: bool = True):
    """Intersections within and between several meshes.

    Parameters
    ----------
    meshes : sequence of ``(V, F)`` pairs (positions (n_i, 3) [m], triangles (f_i, 3) local indices).

    Returns
    -------
    count : int
        Number of intersecting triangle pairs.
    pairs : (count, 4) int64
        Rows ``(mesh_a, face_a, mesh_b, face_b)`` with local face indices and
        ``(mesh_a, face_a) < (mesh_b, face_b)``.
    """
    Vs, Fs, face_mesh, face_local = [], [], [], []
    v_off = 0
    for m, (V, F) in enumerate(meshes):
        V = bp._as_positions(V, f"meshes[{m}].V")
        F = bp._as_prims(F, f"meshes[{m}].F")
        Vs.append(V)
        Fs.append(F + v_off)
        face_mesh.append(np.full(F.shape[0], m, dtype=np.int64))
        face_local.append(np.arange(F.shape[0], dtype=np.int64))
        v_off += V.shape[0]
    if not Vs:
        return 0, np.zeros((0, 4), dtype=np.int64)
    rep = find_intersections(np.concatenate(Vs), np.concatenate(Fs), touching=touching)
    fm = np.concatenate(face_mesh)
    fl = np.concatenate(face_local)
    i, j = rep.tri_pairs[:, 0], rep.tri_pairs[:, 1]
    pairs = np.stack([fm[i], fl[i], fm[j], fl[j]], axis=1).astype(np.int64)
    return rep.count, pairs
