"""Collision narrow phase: distance queries and conservative continuous collision detection.

All kernels are float64 numba ``@njit(cache=True)`` functions. The batch kernels run in
parallel (``prange``) over candidate pairs and take mesh-level arrays plus index arrays, so
the caller never loops over queries in Python.

Public API
----------
Distance (proximity) kernels, exact closest points on closed primitives:

* ``point_triangle_distance(p, a, b, c) -> (dist, b0, b1, b2)``
  Distance from point ``p`` to the closed triangle ``abc`` and the barycentric coordinates of
  the closest point ``b0*a + b1*b + b2*c`` (``b_i >= 0``, ``sum == 1``).
* ``edge_edge_distance(p0, p1, q0, q1) -> (dist, s, t)``
  Distance between the closed segments ``p0p1`` and ``q0q1``; the closest points are
  ``p0 + s*(p1-p0)`` and ``q0 + t*(q1-q0)`` with ``s, t`` in [0, 1].
* ``point_segment_distance(p, a, b) -> (dist, t)``.
* ``vf_proximity_batch(X, verts, faces, dist_out, bary_out)``: for each candidate ``i``, the
  distance of vertex ``X[verts[i]]`` to the triangle ``X[faces[i]]`` (``faces`` is (n, 3) vertex
  indices); fills ``dist_out`` (n,) and ``bary_out`` (n, 3).
* ``ee_proximity_batch(X, ea, eb, dist_out, st_out)``: ``ea``, ``eb`` (n, 2) vertex indices; fills
  ``dist_out`` (n,) and ``st_out`` (n, 2).

Continuous collision detection (CCD) over one step, every vertex moving linearly from its
position at t = 0 (``x0``) to its position at t = 1 (``x1``), with a minimum separation
(thickness) ``d >= 0``:

* ``vf_ccd(x0, x1, d=0.0, tol_t=1e-6, tol_x=1e-10, max_iter=100_000) -> toi``: ``x0``, ``x1`` are
  (4, 3); row 0 is the vertex, rows 1..3 the triangle.
* ``ee_ccd(x0, x1, d=0.0, tol_t=1e-6, tol_x=1e-10, max_iter=100_000) -> toi``: rows 0-1 are edge
  a, rows 2-3 edge b.
* ``vf_ccd_batch(X0, X1, vidx, fidx, d=0.0, toi_out=None, tol_t=1e-6, tol_x=1e-10,
  max_iter=100_000, iters_out=None) -> toi_out``: ``X0``, ``X1`` (nv, 3) positions of all
  vertices at t = 0 and 1; ``vidx`` (n,) and ``fidx`` (n, 3) vertex indices; ``d`` a scalar or an
  (n,) array of per-candidate thickness.
* ``ee_ccd_batch(X0, X1, ea, eb, d=0.0, toi_out=None, ...) -> toi_out``: ``ea``, ``eb`` (n, 2).
* ``vf_ccd_batch_kernel`` / ``ee_ccd_batch_kernel``: the njit kernels behind the two wrappers,
  callable from other numba code. Positional arguments, ``d_arr`` of length 1 or n, and
  ``iters_out`` of length n, or length 0 to skip the statistics.

Return value of the CCD functions: a time of impact ``toi`` in [0, 1], or ``np.inf`` when there
is no collision. The result is *conservative*: if the primitives come within Euclidean
distance ``d`` at some time ``t*`` in [0, 1], then ``toi <= t*``. ``d == 0`` means exact
touching: the vertex lies in the closed triangle, or the two closed segments intersect.

``tol_x`` is relative to ``S``, the extent (largest side of the bounding box) of the query's 8
points. A pair whose separation stays above about ``d + tol_x*S`` returns ``inf``. Nearer
misses may be reported as hits (false positives). Apart from the safety exits described
below, a reported hit certifies that the primitives come within about ``d + 2*tol_x*S`` at
some time in ``[toi, toi + tol_t]``. Usually that time is ``toi`` itself. Non-finite input
returns ``toi = 0``, which is conservative.

Algorithm (and why)
-------------------
The CCD is an inclusion-based root finder over the space-time parameter domain, in the spirit
of "Tight Inclusion" (Wang et al. 2021). It adds a few contraction and certification steps
that make it cheap in practice. The separation vector of the pair is

* VF: ``F(t, u, v) = p(t) - [a(t) + u (b(t) - a(t)) + w (c(t) - a(t))]`` with ``w = (1 - u) v``.
* EE: ``F(t, u, v) = [p0(t) + u (p1(t) - p0(t))] - [q0(t) + v (q1(t) - q0(t))]``.

Both use ``(t, u, v)`` in the unit cube. For VF, the "collapsed square"
``(u, v) -> (u, (1 - u) v)`` maps the cube onto the closed triangle exactly, so no box ever
contains parameters outside the triangle. A contact with thickness ``d`` is a point of the
domain where ``|F| <= d``. The motion is linear, so ``F`` is affine in each of ``t``, ``u``
and ``v`` separately (multilinear). Hence every linear functional ``n . F`` takes its extreme
values over an axis-aligned box at the box's 8 corners. The corner values are computed in
floating point. Each is then widened by a forward error bound ``eps_k``, so the inclusions are
rigorous (see ``_EPS_REL`` and ``_finalize_coeffs``). The bound is built from same-time
differences of the points, so it is translation invariant.

Per box, the solver does the following:

1. Discard the box if the Euclidean distance from the origin to the widened range box of
   ``F`` exceeds ``d``. The coordinates are those of a frame aligned with the approximate
   contact normal (``e1 x e2``).
2. Separating axis: let ``n`` point from the origin to the closest point of ``F(t_lo, ., .)``
   over the box. If ``n . F > d`` at all 8 corners (minus the error bound), discard the box.
   This adaptive axis makes boxes near the round boundary of the thickness ball, and near
   nearly parallel edges, cheap to reject.
3. Contraction in t: each corner value is linear in ``t``, so a proven sign of a coordinate, or
   of ``n . F``, at ``t_lo`` yields the earliest time it can cross ``d``. The box's start time is
   moved forward to that time. The rounding is handled conservatively.
4. Keep the boxes in a priority queue ordered by ``t_lo``, with ties going to the deepest box,
   and split the popped box along the parameter that contributes most to the range width.
   Whenever the queue reaches a new earliest time ``t_lo``, compute the exact distance of the
   primitives at ``t_lo``. If it is ``<= d + tol_x*S``, return ``t_lo`` (certified hit). A box
   is also accepted when it is narrower than ``tol_t`` in t and its range is within
   ``tol_x*S`` of the origin.

Why the answer is never late: the queued boxes, together with the boxes and time prefixes
proven contact-free, always cover the whole domain. The earliest true contact therefore
lies in a queued box whose ``t_lo`` is at most the contact time. The returned value is the
smallest ``t_lo`` in the queue. The safety exits are conservative by the same argument: past
``max_iter`` iterations, or when the fixed 1,024-box queue is full, the solver returns the
current smallest ``t_lo`` as a hit.

Degenerate cases need no special path. Coplanarity for the whole step (the cubic vanishes
identically), parallel or collinear edges, zero-length edges, zero-area triangles, zero motion,
and contact at t = 0 or t = 1 all go through the same code. There is no polynomial solve and no
division by a geometric quantity. The one shortcut is for speed: a triangle with two coincident
vertices is solved exactly as a point-segment (EE) query. The thickness enters only the tests,
and it is measured with the Euclidean norm.

Why not a cubic root solver? Floating-point root finding misses contacts unless it has
error-bounded filters, and it needs a separate path for every degenerate case. The data set's
README reports misses on the hand-crafted benchmark. Why not pure conservative advancement
(Li et al. 2021)? It needs ``d > 0`` or a separate path for ``d == 0``, and it converges slowly
for grazing motion, because its step is the distance divided by the *total* relative speed.
Step 3 is a local, per-box form of that idea.

Measured cost: single-thread CPU time per query, median over repeats after warm-up, from
``lokigraph/bench/narrowphase.py``. On the cloth-funnel queries, which are all near contacts, VF takes
about 0.6 µs and EE about 0.9 µs. Randomly built hits with large motion take 3-6 µs. Clear
misses leave after the first box.

Distance kernels: point-triangle projects the point onto the plane with cross-product
(Lagrange-identity) formulas, which stay accurate for nearly parallel configurations. If the
projection falls outside the triangle, or the triangle is ill conditioned, the kernel also
takes the three point-segment distances. Segment-segment takes the interior critical point
from cross products, plus the four endpoint-segment candidates when that point is outside
``[0, 1]^2`` or the segments are nearly parallel. Every candidate is a true point pair on the
primitives, so the result is exact up to rounding for well-conditioned input and never
below the true distance by more than rounding.

References
----------
* B. Wang, Z. Ferguson, T. Schneider, X. Jiang, M. Attene, D. Panozzo. "A Large Scale Benchmark
  and an Inclusion-Based Algorithm for Continuous Collision Detection". ACM TOG 40(5), 2021.
  This module takes from it the multilinear inclusion over the (t, u, v) box and the
  conservative floating-point filter. It was written from the paper's description and
  copies no code.
* M. Li, D. M. Kaufman, C. Jiang. "Codimensional Incremental Potential Contact". ACM TOG 40(4),
  2021. Additive CCD / conservative advancement: the contraction in step 3 is its per-box
  analogue.
* M. G. Duffy. "Quadrature over a pyramid or cube of integrands with a singularity at a vertex".
  SIAM J. Numer. Anal. 19(6), 1982. The collapsed-square map of the triangle.
* R. Bridson, R. Fedkiw, J. Anderson. "Robust treatment of collisions, contact and friction for
  cloth animation". SIGGRAPH 2002. The cubic-root formulation that this method replaces.
* J. Stam. "Nucleus: Towards a Unified Dynamics Solver for Computer Graphics". 2009, section 7
  (space-time collisions with thickness).
* C. Ericson. "Real-Time Collision Detection". 2005, chapter 5 (closest-point queries).

Limitations
-----------
* False positives are possible, by design. Pairs closer than about ``d + tol_x*S`` that do not
  touch are reported as hits. So are pairs that exhaust ``max_iter`` or the 1,024-box queue.
  On the hand-crafted set at ``d = 0`` there are 70 VF and 68 EE false positives. Each of them
  has an estimated minimum separation below 1e-8 relative, and 36 lie below 1e-15, below what a
  double can resolve (for example, a vertex passing an edge at 5e-17). On the cloth funnel the
  count is 0, and with ``d > 0`` it is 0 on both sets.
* Neither safety exit was reached on the benchmark data. Randomly built contacts between a
  point and a collinear (zero-area but not coincident) or sliver triangle that is coplanar
  with the motion are the slow case. They take up to about 3,000 iterations, and about 1 in
  10,000 of them fills the queue, which returns the conservative, earlier TOI.
* The TOI is a lower bound, certified only up to the spatial tolerance. For a pair that
  approaches slowly while already within ``d + tol_x*S``, it can lie well before the exact
  contact time: roughly ``tol_x*S / (approach speed)``. The largest such gap on the
  cloth-funnel data is about 1e-5.
* The thickness is tested with the Euclidean norm. The VF and EE queries of a mesh are
  separate, so a vertex-vertex or vertex-edge contact is found through the VF and EE pairs
  that contain it, as usual.
* The ``d > 0`` semantics are "within distance d". The true earliest time for ``d > 0`` is not
  checked against external data, because the benchmark has TOIs only for ``d = 0``. The tests
  check it against densely sampled exact distances instead.
* The floating-point error bound assumes IEEE double with round-to-nearest, no
  flush-to-zero and no fast-math contraction. That is numba's default without
  ``fastmath``.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

__all__ = [
    "point_segment_distance",
    "point_triangle_distance",
    "edge_edge_distance",
    "vf_proximity_batch",
    "ee_proximity_batch",
    "vf_ccd",
    "ee_ccd",
    "vf_ccd_batch",
    "ee_ccd_batch",
    "vf_ccd_batch_kernel",
    "ee_ccd_batch_kernel",
    "CCD_HEAP_CAPACITY",
    "DEFAULT_TOL_T",
    "DEFAULT_TOL_X",
    "DEFAULT_MAX_ITER",
]

# Forward error bound of one corner evaluation. Notation: u = 2^-53, Dmax = largest spread
# (max - min) of a coordinate over the 8 input points, D'_k = max_j |C_jk| over the solver
# coefficients of coordinate k after the rotation (see _finalize_coeffs).
# * Raw coefficients are same-time differences x_i - x_j: |.| <= Dmax, error <= u Dmax.
# * Rotated coefficients are 3-term dot products with a unit frame axis: error
#   <= 3.01 u |c|_2 + |a|_1 u Dmax <= 11 u Dmax. This perturbs F (|u|, |v|, |w| <= 1) by <= 33 u Dmax.
# * Evaluation: g = fl(fl(r + fl(u e1)) + fl(w e2)), w = fl((1 - u) v) (VF) or v (EE), then
#   F = fl(fl((1 - t) g0) + fl(t g1)). With |r|, |e1|, |e2| <= D'_k this is
#   <= 20 u D'_k (including the rounding of w and of 1 - t for non-dyadic t).
# So |F_computed - F_exact| <= 33 u Dmax + 20 u D'_k. We use eps_k = 256 u (D'_k + Dmax),
# a factor of at least 7 margin, which also covers the rounding of the widened bounds.
_EPS_REL = 256.0 * 2.0 ** -53
_EPS_ABS = 1e-300  # guards underflow of tiny inputs
_D_PAD = 1.0 + 1e-12  # relative padding of d in all tests (rounding, frame non-orthogonality)
_U = 2.0 ** -53
CCD_HEAP_CAPACITY = 1024
_NBLOCKS = 256  # parallel work items per batch call (one workspace each, interleaved candidates)
DEFAULT_TOL_T = 1e-6
DEFAULT_TOL_X = 1e-10
DEFAULT_MAX_ITER = 100_000

# ---------------------------------------------------------------------------------------
# Distance kernels (scalar components, no allocation)
# ---------------------------------------------------------------------------------------
#
# _outside_unit: the kernels test a quotient q = num / den (den > 0) against 0 and 1 without
# dividing where the numerator alone decides: num < -_TINY den gives a negative q that does
# not underflow to -0.0, num > _ONE_UP den (or a sum of two such numerators, both >= 0) a q
# (or a sum of two rounded q) above 1 after rounding. Elsewhere, and for non-finite or NaN
# values (every comparison false), they divide and test as before, so the results are bitwise
# those of dividing first (tests/test_collision_distance.py checks this on random, degenerate,
# lattice and non-finite inputs). Measured on the moving scene's first detection of frame 8
# (2.77M edge-edge / 1.11M vertex-face candidates, 1 thread): 146 -> 132 ms / 51 -> 47 ms.
_TINY = 1e-290
_ONE_UP = 1.0 + 1e-14


@njit(cache=True, inline="always")
def _pt_seg_sq(px, py, pz, ax, ay, az, bx, by, bz):
    """Squared distance from p to the closed segment ab and parameter t (closest = a + t (b - a))."""
    dx = bx - ax
    dy = by - ay
    dz = bz - az
    wx = px - ax
    wy = py - ay
    wz = pz - az
    dd = dx * dx + dy * dy + dz * dz
    t = 0.0
    if dd > 0.0:
        # the clamped quotient without the division where it is clamped (bitwise the same:
        # wd >= dd > 0 gives wd / dd >= 1; wd < -_TINY dd a negative quotient that does not
        # underflow to -0.0, so 0.0 either way; non-finite and NaN inputs take the division)
        wd = wx * dx + wy * dy + wz * dz
        if wd >= dd and dd < np.inf:
            t = 1.0
        elif not wd < -_TINY * dd:
            t = wd / dd
            if t < 0.0:
                t = 0.0
            elif t > 1.0:
                t = 1.0
    qx = wx - t * dx
    qy = wy - t * dy
    qz = wz - t * dz
    return qx * qx + qy * qy + qz * qz, t


@njit(cache=True)
def _pt_tri_sq(px, py, pz, ax, ay, az, bx, by, bz, cx, cy, cz):
    """Squared distance from p to the closed triangle abc and barycentrics of the closest point."""
    e1x = bx - ax
    e1y = by - ay
    e1z = bz - az
    e2x = cx - ax
    e2y = cy - ay
    e2z = cz - az
    wx = px - ax
    wy = py - ay
    wz = pz - az
    nx = e1y * e2z - e1z * e2y
    ny = e1z * e2x - e1x * e2z
    nz = e1x * e2y - e1y * e2x
    nn = nx * nx + ny * ny + nz * nz
    l1 = e1x * e1x + e1y * e1y + e1z * e1z
    l2 = e2x * e2x + e2y * e2y + e2z * e2z
    best = np.inf
    b0 = 1.0
    b1 = 0.0
    b2 = 0.0
    well_conditioned = nn > 1e-10 * l1 * l2
    if nn > 0.0:
        # s = ((w x e2) . n) / |n|^2,  t = ((e1 x w) . n) / |n|^2
        ux = wy * e2z - wz * e2y
        uy = wz * e2x - wx * e2z
        uz = wx * e2y - wy * e2x
        vx = e1y * wz - e1z * wy
        vy = e1z * wx - e1x * wz
        vz = e1x * wy - e1y * wx
        sn = ux * nx + uy * ny + uz * nz
        tn = vx * nx + vy * ny + vz * nz
        # the divisions only where the projection can be inside (see _outside_unit)
        lim = -_TINY * nn
        if not (sn < lim or tn < lim or sn + tn > _ONE_UP * nn):
            s = sn / nn
            t = tn / nn
            if s >= 0.0 and t >= 0.0 and s + t <= 1.0:
                qx = wx - s * e1x - t * e2x
                qy = wy - s * e1y - t * e2y
                qz = wz - s * e1z - t * e2z
                best = qx * qx + qy * qy + qz * qz
                b0 = 1.0 - s - t
                b1 = s
                b2 = t
                if well_conditioned:
                    return best, b0, b1, b2
    # boundary: three edges
    d2, tt = _pt_seg_sq(px, py, pz, ax, ay, az, bx, by, bz)
    if d2 < best:
        best = d2
        b0 = 1.0 - tt
        b1 = tt
        b2 = 0.0
    d2, tt = _pt_seg_sq(px, py, pz, bx, by, bz, cx, cy, cz)
    if d2 < best:
        best = d2
        b0 = 0.0
        b1 = 1.0 - tt
        b2 = tt
    d2, tt = _pt_seg_sq(px, py, pz, cx, cy, cz, ax, ay, az)
    if d2 < best:
        best = d2
        b0 = tt
        b1 = 0.0
        b2 = 1.0 - tt
    return best, b0, b1, b2


@njit(cache=True)
def _seg_seg_sq(p0x, p0y, p0z, p1x, p1y, p1z, q0x, q0y, q0z, q1x, q1y, q1z):
    """Squared distance between closed segments p0p1 and q0q1 and the parameters (s, t)."""
    d1x = p1x - p0x
    d1y = p1y - p0y
    d1z = p1z - p0z
    d2x = q1x - q0x
    d2y = q1y - q0y
    d2z = q1z - q0z
    rx = p0x - q0x
    ry = p0y - q0y
    rz = p0z - q0z
    nx = d1y * d2z - d1z * d2y
    ny = d1z * d2x - d1x * d2z
    nz = d1x * d2y - d1y * d2x
    nn = nx * nx + ny * ny + nz * nz
    a = d1x * d1x + d1y * d1y + d1z * d1z
    e = d2x * d2x + d2y * d2y + d2z * d2z
    best = np.inf
    bs = 0.0
    bt = 0.0
    if nn > 0.0:
        # s = ((d1 x d2) . (d2 x r)) / |n|^2,  t = ((d1 x d2) . (d1 x r)) / |n|^2
        ax_ = d2y * rz - d2z * ry
        ay_ = d2z * rx - d2x * rz
        az_ = d2x * ry - d2y * rx
        cx_ = d1y * rz - d1z * ry
        cy_ = d1z * rx - d1x * rz
        cz_ = d1x * ry - d1y * rx
        sn = nx * ax_ + ny * ay_ + nz * az_
        tn = nx * cx_ + ny * cy_ + nz * cz_
        # the divisions only where the closest points can be inside (see _outside_unit)
        lim = -_TINY * nn
        hi = _ONE_UP * nn
        if not (sn < lim or tn < lim or sn > hi or tn > hi):
            s = sn / nn
            t = tn / nn
            if s >= 0.0 and s <= 1.0 and t >= 0.0 and t <= 1.0:
                qx = rx + s * d1x - t * d2x
                qy = ry + s * d1y - t * d2y
                qz = rz + s * d1z - t * d2z
                best = qx * qx + qy * qy + qz * qz
                bs = s
                bt = t
                if nn > 1e-10 * a * e:
                    return best, bs, bt
    # boundary of [0,1]^2: endpoint vs segment
    d2, tt = _pt_seg_sq(p0x, p0y, p0z, q0x, q0y, q0z, q1x, q1y, q1z)
    if d2 < best:
        best = d2
        bs = 0.0
        bt = tt
    d2, tt = _pt_seg_sq(p1x, p1y, p1z, q0x, q0y, q0z, q1x, q1y, q1z)
    if d2 < best:
        best = d2
        bs = 1.0
        bt = tt
    d2, tt = _pt_seg_sq(q0x, q0y, q0z, p0x, p0y, p0z, p1x, p1y, p1z)
    if d2 < best:
        best = d2
        bs = tt
        bt = 0.0
    d2, tt = _pt_seg_sq(q1x, q1y, q1z, p0x, p0y, p0z, p1x, p1y, p1z)
    if d2 < best:
        best = d2
        bs = tt
        bt = 1.0
    return best, bs, bt


@njit(cache=True, inline="always")
def row_coefficients(q, rows, is_vf, r):
    """Contact row r of ``rows`` (vertex-face ``(v, a, b, c)`` when ``is_vf``, else edge-edge
    ``(a0, a1, b0, b1)``) at positions ``q``: the squared distance of its closest points and
    the 4 vertices' coefficients of their separation (sum c_k q_k = x_v - x_face, or
    x_a(s) - x_b(t)). Returns (d2, c0, c1, c2, c3)."""
    i0, i1, i2, i3 = rows[r, 0], rows[r, 1], rows[r, 2], rows[r, 3]
    if is_vf:
        d2, b0, b1, b2 = _pt_tri_sq(q[i0, 0], q[i0, 1], q[i0, 2], q[i1, 0], q[i1, 1],
                                    q[i1, 2], q[i2, 0], q[i2, 1], q[i2, 2], q[i3, 0],
                                    q[i3, 1], q[i3, 2])
        return d2, 1.0, -b0, -b1, -b2
    d2, s, t = _seg_seg_sq(q[i0, 0], q[i0, 1], q[i0, 2], q[i1, 0], q[i1, 1], q[i1, 2],
                           q[i2, 0], q[i2, 1], q[i2, 2], q[i3, 0], q[i3, 1], q[i3, 2])
    return d2, 1.0 - s, s, -(1.0 - t), -t


@njit(cache=True)
def point_segment_distance(p, a, b):
    """Distance from point ``p`` (3,) to the closed segment ``ab``; returns ``(dist, t)``,
    closest point ``a + t (b - a)``, ``t`` in [0, 1] (``t = 0`` for a zero-length segment)."""
    d2, t = _pt_seg_sq(p[0], p[1], p[2], a[0], a[1], a[2], b[0], b[1], b[2])
    return np.sqrt(d2), t


@njit(cache=True)
def point_triangle_distance(p, a, b, c):
    """Distance from point ``p`` to the closed triangle ``abc`` (all (3,) float64).

    Returns ``(dist, b0, b1, b2)`` with the closest point ``b0*a + b1*b + b2*c``,
    ``b_i >= 0`` and ``b0 + b1 + b2 == 1`` (up to rounding). Zero-area and sliver triangles
    fall back to the closest point on the three edges.
    """
    d2, b0, b1, b2 = _pt_tri_sq(p[0], p[1], p[2], a[0], a[1], a[2], b[0], b[1], b[2], c[0], c[1], c[2])
    return np.sqrt(d2), b0, b1, b2


@njit(cache=True)
def edge_edge_distance(p0, p1, q0, q1):
    """Distance between the closed segments ``p0p1`` and ``q0q1`` (all (3,) float64).

    Returns ``(dist, s, t)``; closest points ``p0 + s (p1 - p0)`` and ``q0 + t (q1 - q0)``,
    ``s, t`` in [0, 1]. Parallel, collinear and zero-length segments are handled through the
    endpoint-segment candidates (for parallel segments one of the minimizing pairs is returned).
    """
    d2, s, t = _seg_seg_sq(p0[0], p0[1], p0[2], p1[0], p1[1], p1[2],
                           q0[0], q0[1], q0[2], q1[0], q1[1], q1[2])
    return np.sqrt(d2), s, t


@njit(cache=True, parallel=True)
def vf_proximity_batch(X, verts, faces, dist_out, bary_out):
    """Vertex-triangle distances for candidate pairs of a mesh.

    X: (nv, 3) float64 positions; verts: (n,) vertex indices; faces: (n, 3) triangle vertex
    indices. Fills dist_out (n,) with distances and bary_out (n, 3) with the barycentric
    coordinates (w.r.t. faces[i, 0..2]) of the closest point on the triangle.
    """
    n = verts.shape[0]
    for i in prange(n):
        p = verts[i]
        a = faces[i, 0]
        b = faces[i, 1]
        c = faces[i, 2]
        d2, b0, b1, b2 = _pt_tri_sq(X[p, 0], X[p, 1], X[p, 2], X[a, 0], X[a, 1], X[a, 2],
                                    X[b, 0], X[b, 1], X[b, 2], X[c, 0], X[c, 1], X[c, 2])
        dist_out[i] = np.sqrt(d2)
        bary_out[i, 0] = b0
        bary_out[i, 1] = b1
        bary_out[i, 2] = b2


@njit(cache=True, parallel=True)
def ee_proximity_batch(X, ea, eb, dist_out, st_out):
    """Edge-edge distances for candidate pairs of a mesh.

    X: (nv, 3) float64; ea, eb: (n, 2) vertex indices of the two edges. Fills dist_out (n,)
    and st_out (n, 2) with the segment parameters (s along ea, t along eb) of the closest points.
    """
    n = ea.shape[0]
    for i in prange(n):
        i0 = ea[i, 0]
        i1 = ea[i, 1]
        j0 = eb[i, 0]
        j1 = eb[i, 1]
        d2, s, t = _seg_seg_sq(X[i0, 0], X[i0, 1], X[i0, 2], X[i1, 0], X[i1, 1], X[i1, 2],
                               X[j0, 0], X[j0, 1], X[j0, 2], X[j1, 0], X[j1, 1], X[j1, 2])
        dist_out[i] = np.sqrt(d2)
        st_out[i, 0] = s
        st_out[i, 1] = t


# ---------------------------------------------------------------------------------------
# CCD: inclusion-based interval root finder over (t, u, v)
# ---------------------------------------------------------------------------------------


@njit(cache=True)
def _axis_test(fw, esum, fab, dpad):
    """Separating-axis test and t-contraction along an adaptive direction.

    fw: (8, 3) corner values of F; rows 0-3 are the (u, v) corners at t = tl in cyclic order
    (ll, hl, hh, lh), rows 4-7 the same corners at t = th. The direction n points from the
    origin to the closest point of the two triangles spanned by rows 0-3 (the range of
    F(tl, ., .) over the (u, v) box up to bilinear bending). Any unit n is valid: n . F is
    multilinear, so its minimum over the box is attained at a corner, and n . F > d implies
    |F| > d. Error of n . F at a corner: <= sum_k |n_k| eps_k + 3.01 u sum_k |n_k| |F_k|
    <= esum + 8 u fab. Returns (excluded, q), q the proven contraction fraction in t.
    """
    d2a, b0, b1, b2 = _pt_tri_sq(0.0, 0.0, 0.0, fw[0, 0], fw[0, 1], fw[0, 2],
                                 fw[1, 0], fw[1, 1], fw[1, 2], fw[2, 0], fw[2, 1], fw[2, 2])
    d2b, c0, c1, c2 = _pt_tri_sq(0.0, 0.0, 0.0, fw[0, 0], fw[0, 1], fw[0, 2],
                                 fw[2, 0], fw[2, 1], fw[2, 2], fw[3, 0], fw[3, 1], fw[3, 2])
    if d2a <= d2b:
        nx = b0 * fw[0, 0] + b1 * fw[1, 0] + b2 * fw[2, 0]
        ny = b0 * fw[0, 1] + b1 * fw[1, 1] + b2 * fw[2, 1]
        nz = b0 * fw[0, 2] + b1 * fw[1, 2] + b2 * fw[2, 2]
    else:
        nx = c0 * fw[0, 0] + c1 * fw[2, 0] + c2 * fw[3, 0]
        ny = c0 * fw[0, 1] + c1 * fw[2, 1] + c2 * fw[3, 1]
        nz = c0 * fw[0, 2] + c1 * fw[2, 2] + c2 * fw[3, 2]
    nn = nx * nx + ny * ny + nz * nz
    if not (nn > 0.0 and nn < np.inf):
        return False, 0.0
    inv = 1.0 / np.sqrt(nn)
    nx *= inv
    ny *= inv
    nz *= inv
    thr = dpad + esum + 8.0 * _U * fab
    # a_c: separation margin at tl, b_c: at th (positive = proven separated)
    a0 = nx * fw[0, 0] + ny * fw[0, 1] + nz * fw[0, 2] - thr
    a1 = nx * fw[1, 0] + ny * fw[1, 1] + nz * fw[1, 2] - thr
    a2 = nx * fw[2, 0] + ny * fw[2, 1] + nz * fw[2, 2] - thr
    a3 = nx * fw[3, 0] + ny * fw[3, 1] + nz * fw[3, 2] - thr
    if not (a0 > 0.0 and a1 > 0.0 and a2 > 0.0 and a3 > 0.0):
        return False, 0.0
    b0 = nx * fw[4, 0] + ny * fw[4, 1] + nz * fw[4, 2] - thr
    b1 = nx * fw[5, 0] + ny * fw[5, 1] + nz * fw[5, 2] - thr
    b2 = nx * fw[6, 0] + ny * fw[6, 1] + nz * fw[6, 2] - thr
    b3 = nx * fw[7, 0] + ny * fw[7, 1] + nz * fw[7, 2] - thr
    if b0 > 0.0 and b1 > 0.0 and b2 > 0.0 and b3 > 0.0:
        return True, 0.0
    # each corner's margin is linear in t: it stays positive before a / (a - b)
    q = 2.0
    if b0 <= 0.0:
        q = min(q, a0 / (a0 - b0))
    if b1 <= 0.0:
        q = min(q, a1 / (a1 - b1))
    if b2 <= 0.0:
        q = min(q, a2 / (a2 - b2))
    if b3 <= 0.0:
        q = min(q, a3 / (a3 - b3))
    return False, q


@njit(cache=True, inline="always")
def _coord_contraction(e, fl0, fl1, fl2, fl3, fh0, fh1, fh2, fh3):
    """Contraction fraction from one coordinate: if all 4 corner values at tl are > e (or all
    < -e), each corner value is linear in t and bounded by the line through (tl, f_l - e) and
    (th, f_h - e); the coordinate cannot reach [-e, e] before the first line crosses 0.
    e already contains the error bound and the (padded) thickness. Returns q >= 0."""
    if min(min(fl0, fl1), min(fl2, fl3)) - e > 0.0:
        s = 1.0
    elif max(max(fl0, fl1), max(fl2, fl3)) + e < 0.0:
        s = -1.0
    else:
        return 0.0
    q = 2.0
    b = s * fh0 - e
    if b <= 0.0:
        a = s * fl0 - e
        q = min(q, a / (a - b))
    b = s * fh1 - e
    if b <= 0.0:
        a = s * fl1 - e
        q = min(q, a / (a - b))
    b = s * fh2 - e
    if b <= 0.0:
        a = s * fl2 - e
        q = min(q, a / (a - b))
    b = s * fh3 - e
    if b <= 0.0:
        a = s * fl3 - e
        q = min(q, a / (a - b))
    return q


@njit(cache=True)
def _eval_box(C, eps, fw, is_vf, tl, th, ul, uh, vl, vh, d, tol_t, tol_x):
    """Evaluate the widened inclusion of F over the box [tl,th] x [ul,uh] x [vl,vh].

    C: (6, 3) coefficients, rows [r0, e1_0, e2_0, r1, e1_1, e2_1], so that
    F(t,u,v) = (1-t)(r0 + u e1_0 + w e2_0) + t (r1 + u e1_1 + w e2_1), w = (1-u) v for VF
    and w = v for EE. fw: (8, 3) scratch for the corner values.
    Returns (excluded, accepted, split_dim, q):
      excluded: proven |F| > d on the whole box;
      accepted: the box certifies a contact within d + tol_x no earlier than tl (at tl, or
        within tol_t after it);
      split_dim: 0 = t, 1 = u, 2 = v;
      q: contraction fraction: |F| > d is proven for t in [tl, tl + q (th - tl)).
    """
    dpad = d * _D_PAD
    dt2 = (d + tol_x) * (d + tol_x)
    lo2 = 0.0
    hi2 = 0.0
    width_ok = True
    ct = 0.0
    cu = 0.0
    cv = 0.0
    q = 0.0
    esum = 0.0
    fab = 0.0
    omt_l = 1.0 - tl
    omt_h = 1.0 - th
    # effective second parameter at the 4 (u, v) corners (collapsed square for VF)
    if is_vf:
        w_ll = (1.0 - ul) * vl
        w_hl = (1.0 - uh) * vl
        w_lh = (1.0 - ul) * vh
        w_hh = (1.0 - uh) * vh
    else:
        w_ll = vl
        w_hl = vl
        w_lh = vh
        w_hh = vh
    # squared norms of F at the 4 corners at tl and at th
    n_ll_l = 0.0
    n_hl_l = 0.0
    n_lh_l = 0.0
    n_hh_l = 0.0
    n_ll_h = 0.0
    n_hl_h = 0.0
    n_lh_h = 0.0
    n_hh_h = 0.0
    for k in range(3):
        r0 = C[0, k]
        a0 = C[1, k]
        b0 = C[2, k]
        r1 = C[3, k]
        a1 = C[4, k]
        b1 = C[5, k]
        g0_ll = (r0 + ul * a0) + w_ll * b0
        g0_hl = (r0 + uh * a0) + w_hl * b0
        g0_lh = (r0 + ul * a0) + w_lh * b0
        g0_hh = (r0 + uh * a0) + w_hh * b0
        g1_ll = (r1 + ul * a1) + w_ll * b1
        g1_hl = (r1 + uh * a1) + w_hl * b1
        g1_lh = (r1 + ul * a1) + w_lh * b1
        g1_hh = (r1 + uh * a1) + w_hh * b1
        # F at the 8 corners: f{t}{uv}
        fl_ll = omt_l * g0_ll + tl * g1_ll
        fl_hl = omt_l * g0_hl + tl * g1_hl
        fl_lh = omt_l * g0_lh + tl * g1_lh
        fl_hh = omt_l * g0_hh + tl * g1_hh
        fh_ll = omt_h * g0_ll + th * g1_ll
        fh_hl = omt_h * g0_hl + th * g1_hl
        fh_lh = omt_h * g0_lh + th * g1_lh
        fh_hh = omt_h * g0_hh + th * g1_hh
        fw[0, k] = fl_ll
        fw[1, k] = fl_hl
        fw[2, k] = fl_hh
        fw[3, k] = fl_lh
        fw[4, k] = fh_ll
        fw[5, k] = fh_hl
        fw[6, k] = fh_hh
        fw[7, k] = fh_lh
        n_ll_l += fl_ll * fl_ll
        n_hl_l += fl_hl * fl_hl
        n_lh_l += fl_lh * fl_lh
        n_hh_l += fl_hh * fl_hh
        n_ll_h += fh_ll * fh_ll
        n_hl_h += fh_hl * fh_hl
        n_lh_h += fh_lh * fh_lh
        n_hh_h += fh_hh * fh_hh
        mn = min(min(min(fl_ll, fl_hl), min(fl_lh, fl_hh)), min(min(fh_ll, fh_hl), min(fh_lh, fh_hh)))
        mx = max(max(max(fl_ll, fl_hl), max(fl_lh, fl_hh)), max(max(fh_ll, fh_hl), max(fh_lh, fh_hh)))
        e = eps[k]
        esum += e
        # distance of the widened range [mn - e, mx + e] from 0 (the sign of fl(x - y) is exact)
        lo = 0.0
        if mn - e > 0.0:
            lo = mn - e
        elif -mx - e > 0.0:
            lo = -mx - e
        lo2 += lo * lo
        hi = max(abs(mn), abs(mx))
        fab += hi
        hi += e
        hi2 += hi * hi
        if mx - mn > tol_x:
            width_ok = False
        # contribution of each parameter to the width of the range
        x = max(max(abs(fh_ll - fl_ll), abs(fh_hl - fl_hl)), max(abs(fh_lh - fl_lh), abs(fh_hh - fl_hh)))
        if x > ct:
            ct = x
        x = max(max(abs(fl_hl - fl_ll), abs(fh_hl - fh_ll)), max(abs(fl_hh - fl_lh), abs(fh_hh - fh_lh)))
        if x > cu:
            cu = x
        x = max(max(abs(fl_lh - fl_ll), abs(fh_lh - fh_ll)), max(abs(fl_hh - fl_hl), abs(fh_hh - fh_hl)))
        if x > cv:
            cv = x
        qk = _coord_contraction(e + dpad, fl_ll, fl_hl, fl_lh, fl_hh, fh_ll, fh_hl, fh_lh, fh_hh)
        if qk > q:
            q = qk
    # 1. Euclidean distance from the origin to the widened range box > d
    if lo2 > d * d * _D_PAD:
        return True, False, 0, 0.0
    # 2. separating axis through the closest point of the range at tl
    exn, qn = _axis_test(fw, esum, fab, dpad)
    if exn:
        return True, False, 0, 0.0
    if qn > q:
        q = qn
    if q > 1.0:
        q = 1.0
    # certified contact (within d + tol_x) at exactly t = tl: accept whatever the t-width
    if n_ll_l <= dt2 or n_hl_l <= dt2 or n_lh_l <= dt2 or n_hh_l <= dt2:
        return False, True, 0, 0.0
    # "close": the box contains a point within about d + tol_x of contact
    close = (width_ok or hi2 <= dt2 or n_ll_h <= dt2 or n_hl_h <= dt2 or n_lh_h <= dt2
             or n_hh_h <= dt2)
    if close:
        if th - tl <= tol_t:
            return False, True, 0, q
        return False, False, 0, q  # only t is still too wide
    dim = 0
    if cu > ct:
        dim = 1
        if cv > cu:
            dim = 2
    elif cv > ct:
        dim = 2
    return False, False, dim, q


@njit(cache=True)
def _contract(C, eps, fw, is_vf, tl, th, ul, uh, vl, vh, d, tol_t, tol_x):
    """Evaluate a box and move its start time forward by the proven contraction fraction
    (at most 3 contractions). Returns (excluded, accepted, split_dim, new_tl)."""
    for rnd in range(4):
        ex, acc, dim, q = _eval_box(C, eps, fw, is_vf, tl, th, ul, uh, vl, vh, d, tol_t, tol_x)
        if ex or acc or q <= 0.0 or rnd == 3:
            break
        # conservative rounding: the fraction is shrunk by 1e-9 (relative rounding of q and of
        # th - tl is ~1e-15) and the start by two ulps of 1 (t <= 1), so the rounded sum never
        # exceeds the proven bound
        tn = tl + (th - tl) * (q * (1.0 - 1e-9)) - 4.5e-16
        if tn <= tl or tn >= th:
            break
        tl = tn
    return ex, acc, dim, tl


@njit(cache=True, inline="always")
def _heap_less(box, meta, a, b):
    ta = box[a, 0]
    tb = box[b, 0]
    if ta < tb:
        return True
    if ta > tb:
        return False
    return meta[a, 0] > meta[b, 0]  # same start time: deeper (smaller) box first


@njit(cache=True)
def _heap_push(heap, n, box, meta, slot):
    i = n
    heap[i] = slot
    while i > 0:
        parent = (i - 1) >> 1
        if _heap_less(box, meta, heap[i], heap[parent]):
            tmp = heap[parent]
            heap[parent] = heap[i]
            heap[i] = tmp
            i = parent
        else:
            break
    return n + 1


@njit(cache=True)
def _heap_pop(heap, n, box, meta):
    top = heap[0]
    n -= 1
    heap[0] = heap[n]
    i = 0
    while True:
        left = 2 * i + 1
        if left >= n:
            break
        m = left
        right = left + 1
        if right < n and _heap_less(box, meta, heap[right], heap[left]):
            m = right
        if _heap_less(box, meta, heap[m], heap[i]):
            tmp = heap[m]
            heap[m] = heap[i]
            heap[i] = tmp
            i = m
        else:
            break
    return top, n


@njit(cache=True)
def _dist2_at(C, is_vf, t):
    """Squared distance between the two primitives at time t, from the solver coefficients
    (the rotation preserves distances). Used only to certify hits."""
    w0 = 1.0 - t
    rx = w0 * C[0, 0] + t * C[3, 0]
    ry = w0 * C[0, 1] + t * C[3, 1]
    rz = w0 * C[0, 2] + t * C[3, 2]
    ax = w0 * C[1, 0] + t * C[4, 0]
    ay = w0 * C[1, 1] + t * C[4, 1]
    az = w0 * C[1, 2] + t * C[4, 2]
    bx = w0 * C[2, 0] + t * C[5, 0]
    by = w0 * C[2, 1] + t * C[5, 1]
    bz = w0 * C[2, 2] + t * C[5, 2]
    if is_vf:
        # r = p - a, e1 = a - b, e2 = a - c: point r vs triangle (0, -e1, -e2)
        d2, _, _, _ = _pt_tri_sq(rx, ry, rz, 0.0, 0.0, 0.0, -ax, -ay, -az, -bx, -by, -bz)
        return d2
    # r = p0 - q0, e1 = p1 - p0, e2 = q0 - q1: segment (r, r + e1) vs segment (0, -e2)
    d2, _, _ = _seg_seg_sq(rx, ry, rz, rx + ax, ry + ay, rz + az, 0.0, 0.0, 0.0, -bx, -by, -bz)
    return d2


@njit(cache=True)
def _ccd_solve(C, eps, fw, is_vf, d, tol_t, tol_x, max_iter, box, meta, heap, free):
    """Earliest-start-time interval search. Returns (toi, iterations, status).

    status: 0 exact termination (proven miss, or certified hit), 1 max_iter reached,
    2 queue full. Workspace: box (cap, 6) float64 [tl, th, ul, uh, vl, vh], meta (cap, 3)
    int64 [depth, accepted, split dim], heap (cap,) int64, free (cap,) int64.
    """
    cap = heap.shape[0]
    ex, acc, dim, t0 = _contract(C, eps, fw, is_vf, 0.0, 1.0, 0.0, 1.0, 0.0, 1.0, d, tol_t, tol_x)
    if ex:
        return np.inf, 0, 0
    dt2 = (d + tol_x) * (d + tol_x)
    last_t = -1.0
    s = 0
    n_used = 1  # slots [0, n_used) have been handed out; freed ones go to the free stack
    nfree = 0
    box[s, 0] = t0
    box[s, 1] = 1.0
    box[s, 2] = 0.0
    box[s, 3] = 1.0
    box[s, 4] = 0.0
    box[s, 5] = 1.0
    meta[s, 0] = 0
    meta[s, 1] = 1 if acc else 0
    meta[s, 2] = dim
    nh = _heap_push(heap, np.int64(0), box, meta, np.int64(s))
    it = 0
    while nh > 0:
        s, nh = _heap_pop(heap, nh, box, meta)
        tl = box[s, 0]
        if meta[s, 1] == 1:
            return tl, it, 0
        if tl != last_t:
            # global certificate: the primitives are within d + tol_x at time tl, and tl is
            # not later than the true contact time (queue invariant)
            last_t = tl
            if _dist2_at(C, is_vf, tl) <= dt2:
                return tl, it, 0
        it += 1
        if it > max_iter:
            return tl, it, 1
        th = box[s, 1]
        ul = box[s, 2]
        uh = box[s, 3]
        vl = box[s, 4]
        vh = box[s, 5]
        dim = meta[s, 2]
        depth = meta[s, 0] + 1
        free[nfree] = s
        nfree += 1
        for child in range(2):
            ctl = tl
            cth = th
            cul = ul
            cuh = uh
            cvl = vl
            cvh = vh
            if dim == 0:
                mid = 0.5 * (tl + th)
                if child == 0:
                    cth = mid
                else:
                    ctl = mid
            elif dim == 1:
                mid = 0.5 * (ul + uh)
                if child == 0:
                    cuh = mid
                else:
                    cul = mid
            else:
                mid = 0.5 * (vl + vh)
                if child == 0:
                    cvh = mid
                else:
                    cvl = mid
            ex, acc, cdim, ctl = _contract(C, eps, fw, is_vf, ctl, cth, cul, cuh, cvl, cvh, d,
                                           tol_t, tol_x)
            if ex:
                continue
            if nfree > 0:
                nfree -= 1
                c = free[nfree]
            elif n_used < cap:
                c = n_used
                n_used += 1
            else:
                # queue full: conservative answer (tl is <= every queued box's t_lo)
                return tl, it, 2
            box[c, 0] = ctl
            box[c, 1] = cth
            box[c, 2] = cul
            box[c, 3] = cuh
            box[c, 4] = cvl
            box[c, 5] = cvh
            meta[c, 0] = depth
            meta[c, 1] = 1 if acc else 0
            meta[c, 2] = cdim
            nh = _heap_push(heap, nh, box, meta, c)
    return np.inf, it, 0


@njit(cache=True, inline="always")
def _unit(x, y, z):
    n = np.sqrt(x * x + y * y + z * z)
    return x / n, y / n, z / n


@njit(cache=True)
def _finalize_coeffs(C, eps, Dmax):
    """Rotate the raw world-frame coefficient rows into the solver frame and set ``eps``.

    The first axis of the frame is the approximate contact normal: e1 x e2 at mid-step, which
    is the triangle normal for VF and the common normal of the edge lines for EE. For parallel
    edges or a degenerate triangle it is the part of the separation perpendicular to the
    edge. The second axis follows the longer edge direction. Any orthonormal frame gives a
    valid inclusion, and this one is tighter, because the normal component of F barely
    depends on (u, v). The error bounds are derived in the comment above ``_EPS_REL``:
    eps_k = 256 u (D'_k + Dmax). The float frame is orthonormal to ~1e-15, which the relative
    padding ``_D_PAD`` of every test absorbs (|R F| > d (1 + 1e-12) implies |F| > d).
    """
    m1x = C[1, 0] + C[4, 0]
    m1y = C[1, 1] + C[4, 1]
    m1z = C[1, 2] + C[4, 2]
    m2x = C[2, 0] + C[5, 0]
    m2y = C[2, 1] + C[5, 1]
    m2z = C[2, 2] + C[5, 2]
    nx = m1y * m2z - m1z * m2y
    ny = m1z * m2x - m1x * m2z
    nz = m1x * m2y - m1y * m2x
    l1 = m1x * m1x + m1y * m1y + m1z * m1z
    l2 = m2x * m2x + m2y * m2y + m2z * m2z
    nn = nx * nx + ny * ny + nz * nz
    ok = True
    tx, ty, tz = m1x, m1y, m1z
    if l2 > l1:
        tx, ty, tz = m2x, m2y, m2z
    a1x, a1y, a1z = 1.0, 0.0, 0.0
    if nn > 1e-20 * l1 * l2 and nn > 0.0:
        a1x, a1y, a1z = _unit(nx, ny, nz)
    else:
        lt = tx * tx + ty * ty + tz * tz
        rx = C[0, 0] + C[3, 0]
        ry = C[0, 1] + C[3, 1]
        rz = C[0, 2] + C[3, 2]
        if lt > 0.0:
            ux, uy, uz = _unit(tx, ty, tz)
            pr = rx * ux + ry * uy + rz * uz
            wx = rx - pr * ux
            wy = ry - pr * uy
            wz = rz - pr * uz
            ww = wx * wx + wy * wy + wz * wz
            if ww > 1e-20 * (rx * rx + ry * ry + rz * rz) and ww > 0.0:
                a1x, a1y, a1z = _unit(wx, wy, wz)
            else:
                ax_, ay_, az_ = abs(ux), abs(uy), abs(uz)
                if ax_ <= ay_ and ax_ <= az_:
                    a1x, a1y, a1z = _unit(0.0, -uz, uy)
                elif ay_ <= az_:
                    a1x, a1y, a1z = _unit(uz, 0.0, -ux)
                else:
                    a1x, a1y, a1z = _unit(-uy, ux, 0.0)
        else:
            ok = False  # both edge directions vanish: keep the world frame
    a2x, a2y, a2z = 0.0, 1.0, 0.0
    a3x, a3y, a3z = 0.0, 0.0, 1.0
    if ok:
        pr = tx * a1x + ty * a1y + tz * a1z
        a2x, a2y, a2z = _unit(tx - pr * a1x, ty - pr * a1y, tz - pr * a1z)
        a3x, a3y, a3z = _unit(a1y * a2z - a1z * a2y, a1z * a2x - a1x * a2z, a1x * a2y - a1y * a2x)
        fin = (abs(a1x) + abs(a1y) + abs(a1z) + abs(a2x) + abs(a2y) + abs(a2z)
               + abs(a3x) + abs(a3y) + abs(a3z))
        if not fin < np.inf:
            ok = False
    if not ok:
        a1x, a1y, a1z = 1.0, 0.0, 0.0
        a2x, a2y, a2z = 0.0, 1.0, 0.0
        a3x, a3y, a3z = 0.0, 0.0, 1.0
    for j in range(6):
        cx = C[j, 0]
        cy = C[j, 1]
        cz = C[j, 2]
        C[j, 0] = a1x * cx + a1y * cy + a1z * cz
        C[j, 1] = a2x * cx + a2y * cy + a2z * cz
        C[j, 2] = a3x * cx + a3y * cy + a3z * cz
    for k in range(3):
        Dk = 0.0
        for j in range(6):
            Dk = max(Dk, abs(C[j, k]))
        eps[k] = _EPS_REL * (Dk + Dmax) + _EPS_ABS


@njit(cache=True, inline="always")
def _set_coeffs_vf(C, eps, X0, X1, ip, ia, ib, ic):
    """Fill C (6, 3) and eps (3,) for vertex ip against triangle (ia, ib, ic).
    Rows: r = p - a, e1 = a - b, e2 = a - c at t = 0 (rows 0-2) and t = 1 (rows 3-5).

    A triangle with two coincident vertices (at both times, hence for the whole step) is a
    segment: the query is then set up exactly as the edge-edge query of the zero-length edge
    (p, p) against that segment (r = p - a, e1 = 0, e2 = a - q). The collapsed-square
    parameterization of a segment-like triangle has a whole curve of parameters per physical
    point, which makes the search needlessly expensive.
    Returns (extent S, finite flag, is_vf)."""
    S = 0.0
    finite = True
    eq_ab = True
    eq_ac = True
    eq_bc = True
    for k in range(3):
        p0 = X0[ip, k]
        a0 = X0[ia, k]
        b0 = X0[ib, k]
        c0 = X0[ic, k]
        p1 = X1[ip, k]
        a1 = X1[ia, k]
        b1 = X1[ib, k]
        c1 = X1[ic, k]
        C[0, k] = p0 - a0
        C[1, k] = a0 - b0
        C[2, k] = a0 - c0
        C[3, k] = p1 - a1
        C[4, k] = a1 - b1
        C[5, k] = a1 - c1
        eq_ab = eq_ab and a0 == b0 and a1 == b1
        eq_ac = eq_ac and a0 == c0 and a1 == c1
        eq_bc = eq_bc and b0 == c0 and b1 == c1
        lo = min(min(min(p0, a0), min(b0, c0)), min(min(p1, a1), min(b1, c1)))
        hi = max(max(max(p0, a0), max(b0, c0)), max(max(p1, a1), max(b1, c1)))
        D = hi - lo
        if not (D >= 0.0 and D < np.inf):
            finite = False
        if D > S:
            S = D
    is_vf = True
    if eq_ab or eq_ac or eq_bc:
        is_vf = False
        for k in range(3):
            if not eq_ab:  # segment (a, b): e2 = a - b
                C[2, k] = C[1, k]
                C[5, k] = C[4, k]
            C[1, k] = 0.0
            C[4, k] = 0.0
    if finite:
        _finalize_coeffs(C, eps, S)
    return S, finite, is_vf


@njit(cache=True, inline="always")
def _set_coeffs_ee(C, eps, X0, X1, i0, i1, j0, j1):
    """Fill C (6, 3) and eps (3,) for edge (i0, i1) against edge (j0, j1).
    Rows: r = p0 - q0, e1 = p1 - p0, e2 = q0 - q1 at t = 0 and t = 1.
    Returns (extent S, finite flag)."""
    S = 0.0
    finite = True
    for k in range(3):
        p0 = X0[i0, k]
        p1 = X0[i1, k]
        q0 = X0[j0, k]
        q1 = X0[j1, k]
        P0 = X1[i0, k]
        P1 = X1[i1, k]
        Q0 = X1[j0, k]
        Q1 = X1[j1, k]
        C[0, k] = p0 - q0
        C[1, k] = p1 - p0
        C[2, k] = q0 - q1
        C[3, k] = P0 - Q0
        C[4, k] = P1 - P0
        C[5, k] = Q0 - Q1
        lo = min(min(min(p0, p1), min(q0, q1)), min(min(P0, P1), min(Q0, Q1)))
        hi = max(max(max(p0, p1), max(q0, q1)), max(max(P0, P1), max(Q0, Q1)))
        D = hi - lo
        if not (D >= 0.0 and D < np.inf):
            finite = False
        if D > S:
            S = D
    if finite:
        _finalize_coeffs(C, eps, S)
    return S, finite


@njit(cache=True)
def _alloc_ws():
    cap = CCD_HEAP_CAPACITY
    return (np.empty((6, 3)), np.empty(3), np.empty((8, 3)), np.empty((cap, 6)),
            np.empty((cap, 3), dtype=np.int64), np.empty(cap, dtype=np.int64),
            np.empty(cap, dtype=np.int64))


@njit(cache=True)
def _ccd_query(C, eps, fw, S, finite, is_vf, d, tol_t, tol_x, max_iter, box, meta, heap, free):
    """Guard non-finite input, scale the tolerance, and run the solver. Callers pass
    non-literal types (np.bool_, np.float64, np.int64) so that numba compiles this chain
    once per argument layout, not once per literal constant."""
    if not finite or not (d >= 0.0 or d < 0.0):  # non-finite coordinates or NaN thickness
        return 0.0, 0, 3
    if d < 0.0:
        d = 0.0
    tx = tol_x * S
    emax = max(max(eps[0], eps[1]), eps[2])
    if not tx >= 8.0 * emax:
        tx = 8.0 * emax
    return _ccd_solve(C, eps, fw, is_vf, d, tol_t, tx, max_iter, box, meta, heap, free)


@njit(cache=True)
def _vf_ccd_detail(x0, x1, d, tol_t, tol_x, max_iter):
    """Scalar VF CCD returning (toi, iterations, status); see _ccd_solve (3 = non-finite)."""
    C, eps, fw, box, meta, heap, free = _alloc_ws()
    S, finite, is_vf = _set_coeffs_vf(C, eps, x0, x1, 0, 1, 2, 3)
    return _ccd_query(C, eps, fw, S, np.bool_(finite), np.bool_(is_vf), np.float64(d), np.float64(tol_t),
                      np.float64(tol_x), np.int64(max_iter), box, meta, heap, free)


@njit(cache=True)
def _ee_ccd_detail(x0, x1, d, tol_t, tol_x, max_iter):
    """Scalar EE CCD returning (toi, iterations, status); see _ccd_solve (3 = non-finite)."""
    C, eps, fw, box, meta, heap, free = _alloc_ws()
    S, finite = _set_coeffs_ee(C, eps, x0, x1, 0, 1, 2, 3)
    return _ccd_query(C, eps, fw, S, np.bool_(finite), np.bool_(False), np.float64(d), np.float64(tol_t),
                      np.float64(tol_x), np.int64(max_iter), box, meta, heap, free)


@njit(cache=True)
def vf_ccd(x0, x1, d=0.0, tol_t=DEFAULT_TOL_T, tol_x=DEFAULT_TOL_X, max_iter=DEFAULT_MAX_ITER):
    """Conservative vertex-face CCD with thickness ``d``.

    x0, x1: (4, 3) float64 positions at t = 0 and t = 1; row 0 is the vertex, rows 1-3 the
    triangle. Returns the time of impact in [0, 1], never later than the first time the vertex
    comes within distance ``d`` of the closed triangle, or ``inf`` when there is no contact.
    ``tol_t``: accuracy of the returned time; ``tol_x``: spatial tolerance relative to the
    query's extent (misses closer than about ``tol_x * extent`` may be reported as hits).
    """
    return _vf_ccd_detail(x0, x1, np.float64(d), np.float64(tol_t), np.float64(tol_x), np.int64(max_iter))[0]


@njit(cache=True)
def ee_ccd(x0, x1, d=0.0, tol_t=DEFAULT_TOL_T, tol_x=DEFAULT_TOL_X, max_iter=DEFAULT_MAX_ITER):
    """Conservative edge-edge CCD with thickness ``d``.

    x0, x1: (4, 3) float64; rows 0-1 are edge a and rows 2-3 edge b. Same return convention
    as :func:`vf_ccd`.
    """
    return _ee_ccd_detail(x0, x1, np.float64(d), np.float64(tol_t), np.float64(tol_x), np.int64(max_iter))[0]


@njit(cache=True, parallel=True)
def vf_ccd_batch_kernel(X0, X1, vidx, fidx, d_arr, tol_t, tol_x, max_iter, toi_out, iters_out):
    """Parallel vertex-face CCD over candidates (njit; positional arguments).

    X0, X1: (nv, 3) float64 positions at t = 0 and 1; vidx (n,) vertex indices; fidx (n, 3)
    triangle vertex indices; d_arr: (1,) or (n,) thickness; toi_out: (n,) float64 output;
    iters_out: (n,) int64 (iteration count, or ``-status`` when a conservative safety exit
    was taken: -1 max_iter, -2 queue full, -3 non-finite input) or an empty array to skip.
    Indices are not bounds-checked here (the Python wrapper checks them).
    """
    n = vidx.shape[0]
    nd = d_arr.shape[0]
    want_it = iters_out.shape[0] == n
    nblk = min(_NBLOCKS, n)
    for blk in prange(nblk):
        # one workspace per work item; candidates interleaved for load balance
        C, eps, fw, box, meta, heap, free = _alloc_ws()
        for i in range(blk, n, nblk):
            S, finite, is_vf = _set_coeffs_vf(C, eps, X0, X1, vidx[i], fidx[i, 0], fidx[i, 1], fidx[i, 2])
            d = d_arr[i] if nd > 1 else d_arr[0]
            toi, it, st = _ccd_query(C, eps, fw, S, np.bool_(finite), np.bool_(is_vf), np.float64(d),
                                     np.float64(tol_t), np.float64(tol_x), np.int64(max_iter),
                                     box, meta, heap, free)
            toi_out[i] = toi
            if want_it:
                iters_out[i] = it if st == 0 else -st
    return toi_out


@njit(cache=True, parallel=True)
def ee_ccd_batch_kernel(X0, X1, ea, eb, d_arr, tol_t, tol_x, max_iter, toi_out, iters_out):
    """Parallel edge-edge CCD over candidates (njit; positional arguments).

    X0, X1: (nv, 3) float64; ea, eb: (n, 2) vertex indices of the two edges; d_arr: (1,) or
    (n,); toi_out (n,) float64; iters_out (n,) int64 or empty (see vf_ccd_batch_kernel).
    """
    n = ea.shape[0]
    nd = d_arr.shape[0]
    want_it = iters_out.shape[0] == n
    nblk = min(_NBLOCKS, n)
    for blk in prange(nblk):
        C, eps, fw, box, meta, heap, free = _alloc_ws()
        for i in range(blk, n, nblk):
            S, finite = _set_coeffs_ee(C, eps, X0, X1, ea[i, 0], ea[i, 1], eb[i, 0], eb[i, 1])
            d = d_arr[i] if nd > 1 else d_arr[0]
            toi, it, st = _ccd_query(C, eps, fw, S, np.bool_(finite), np.bool_(False), np.float64(d),
                                     np.float64(tol_t), np.float64(tol_x), np.int64(max_iter),
                                     box, meta, heap, free)
            toi_out[i] = toi
            if want_it:
                iters_out[i] = it if st == 0 else -st
    return toi_out


_EMPTY_I64 = np.empty(0, dtype=np.int64)


def _check_index(name, idx, ncols, n, nv):
    idx = np.asarray(idx)
    if not np.issubdtype(idx.dtype, np.integer):
        raise TypeError(f"{name} must be an integer array")
    shape = (n,) if ncols == 0 else (n, ncols)
    if idx.shape != shape:
        raise ValueError(f"{name} must have shape {shape}, got {idx.shape}")
    if n and (idx.min() < 0 or idx.max() >= nv):
        raise IndexError(f"{name} has vertex indices outside [0, {nv})")
    return np.ascontiguousarray(idx)


def _prep_batch(X0, X1, n, d, toi_out, iters_out):
    X0 = np.ascontiguousarray(X0, dtype=np.float64)
    X1 = np.ascontiguousarray(X1, dtype=np.float64)
    if X0.shape != X1.shape or X0.ndim != 2 or X0.shape[1] != 3:
        raise ValueError("X0 and X1 must both be (nv, 3)")
    d_arr = np.ascontiguousarray(np.atleast_1d(np.asarray(d, dtype=np.float64)).reshape(-1))
    if d_arr.shape[0] not in (1, n):
        raise ValueError("d must be a scalar or have one entry per candidate")
    if toi_out is None:
        toi_out = np.empty(n, dtype=np.float64)
    elif toi_out.shape != (n,) or toi_out.dtype != np.float64 or not toi_out.flags.writeable:
        raise ValueError("toi_out must be a writeable float64 array of shape (n,)")
    if iters_out is None:
        iters_out = _EMPTY_I64
    elif iters_out.shape != (n,) or iters_out.dtype != np.int64:
        raise ValueError("iters_out must be an int64 array of shape (n,)")
    return X0, X1, d_arr, toi_out, iters_out


def vf_ccd_batch(X0, X1, vidx, fidx, d=0.0, toi_out=None, tol_t=DEFAULT_TOL_T,
                 tol_x=DEFAULT_TOL_X, max_iter=DEFAULT_MAX_ITER, iters_out=None):
    """Vertex-face CCD for n candidates of a mesh, parallel over candidates.

    X0, X1: (nv, 3) positions at t = 0 and t = 1; vidx: (n,) vertex indices; fidx: (n, 3)
    triangle vertex indices; d: scalar or (n,) thickness. Fills and returns toi_out (n,)
    (``inf`` = no contact). iters_out, if given ((n,) int64), receives per-candidate
    iteration counts (negative = conservative safety exit: -1 max_iter, -2 queue full,
    -3 non-finite input).
    """
    n = np.shape(vidx)[0]
    nv = np.shape(X0)[0]
    vidx = _check_index("vidx", vidx, 0, n, nv)
    fidx = _check_index("fidx", fidx, 3, n, nv)
    X0, X1, d_arr, toi_out, iters_out = _prep_batch(X0, X1, n, d, toi_out, iters_out)
    vf_ccd_batch_kernel(X0, X1, vidx, fidx, d_arr, float(tol_t), float(tol_x), int(max_iter),
                        toi_out, iters_out)
    return toi_out


def ee_ccd_batch(X0, X1, ea, eb, d=0.0, toi_out=None, tol_t=DEFAULT_TOL_T,
                 tol_x=DEFAULT_TOL_X, max_iter=DEFAULT_MAX_ITER, iters_out=None):
    """Edge-edge CCD for n candidates of a mesh, parallel over candidates.

    X0, X1: (nv, 3); ea, eb: (n, 2) vertex indices of the two edges; d: scalar or (n,).
    Fills and returns toi_out (n,). See :func:`vf_ccd_batch` for iters_out.
    """
    n = np.shape(ea)[0]
    nv = np.shape(X0)[0]
    ea = _check_index("ea", ea, 2, n, nv)
    eb = _check_index("eb", eb, 2, n, nv)
    X0, X1, d_arr, toi_out, iters_out = _prep_batch(X0, X1, n, d, toi_out, iters_out)
    ee_ccd_batch_kernel(X0, X1, ea, eb, d_arr, float(tol_t), float(tol_x), int(max_iter),
                        toi_out, iters_out)
    return toi_out
