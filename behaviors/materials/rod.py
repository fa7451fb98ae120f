"""Rod (hair) solved directly per strand: stretch and bend of every strand in one linear solve.

Gauss-Seidel over a chain of stiff constraints (Nucleus types 1 and 2 on a strand) moves
information one segment per sweep, so a strand of n segments needs O(n) iterations to feel its
root: at the default 4 substeps x 15 iterations inextensible hair stretched by 10-27 % and a
heavy cantilever hung like a chain (issue #13). Following Deul, Kugelstadt, Weiler and Bender,
"Direct Position-Based Solver for Stiff Rods" (Computer Graphics Forum 2018), the constraints of
a strand are solved together: a strand is a chain, so ordering its constraints along it (stretch
of segment 0, bend at vertex 1, stretch of segment 1, bend at vertex 2, ...) makes the XPBD
system

    (J W J^T + alpha~) dlam = -C - alpha~ lam,        alpha~ = alpha / h^2

banded (half bandwidth ``BAND`` = 7: the bend rows at vertices k and k + 2 share vertex k + 1).
Every projection call linearises the strand's constraints at the current positions, factors the
band with LDL^T and solves it (O(n) per strand: one Newton step of the strand's XPBD system),
then moves ``p += W J^T dlam`` and accumulates the multipliers. Strands are independent and are
solved in parallel (``prange``) above ``PARALLEL_MIN_CONSTRAINTS`` segments. The call takes part
in the Nucleus interleaving like any constraint type (default importance 1.0, order 28), so
contacts, pins and attachments still alternate with it.

Constraints (physical meaning as the Gauss-Seidel pair :class:`~.stretch.StretchConstraint` +
:class:`~.bend.BendConstraint` on a Rod):

- stretch of segment k: ``C = |p_k - p_{k+1}| - L_k`` with compliance ``L / (E pi r^2)`` (0 when
  inextensible) and the compression compliance ``alpha / compression_ratio``;
- bend at an interior vertex k that is straight at rest (rest turning angle < ``STRAIGHT_REST``):
  the vector ``C = t_k - t_{k-1}`` of the unit tangents (``|C| = 2 sin(phi / 2)`` for a turning
  angle phi), two rows: its components along ``C / |C|`` and ``b x C / |C|`` (b the unit
  bisector; C is normal to it), their multipliers kept as one world vector. Energy
  ``|C|^2 / (2 alpha) = (1 - cos phi) / alpha``, i.e. ``EI phi^2 / (2 l)`` for small phi. Unlike
  the angle at the vertex (``|phi|``, whose gradient flips through straight), it is smooth at
  straight: measured on the elastica bench, the angle form stuck vertices exactly straight and
  left the strand 9 mm (4.7 % of L) stiffer than the discrete equilibrium, the vector form
  reaches it to 7 micrometres;
- bend at a vertex curved at rest: the type 2 angle ``C = angle(p_{k-1} - p_k, p_{k+1} - p_k) -
  gamma_k`` (one row, the second is off);
- bend compliance ``l_k / EI`` with l_k the strand length vertex k stands for: half of each
  adjacent segment, and for the first and last interior vertices the whole end segment (the bend
  cells tile the strand; the Gauss-Seidel BendConstraint leaves the end half-cells out, an
  O(segment) error at a clamped root: 3.1 % of L on the 20-segment elastica, 0.4 % with them).

A row whose vertices are all pinned, a degenerate corner (zero-length segment, an angle row at
exactly straight, a vector row folded back on itself) takes no part in that call (``dlam = 0``).
A dependent set of hard rows (more hard constraints than free coordinates) keeps its pivots
bounded (``_PIVOT_REL``). Only open polylines (every vertex of degree <= 2, no loop) are solved
here; other curve topologies stay with the Gauss-Seidel constraints (:func:`solved_directly`
decides, and those behaviors skip what it claims).

Measured (graphs/bench/rod_direct.py): at 4 substeps x 15 iterations the elastica benches
(q L^3 / EI = 3 and 1.5) are within 0.36 % and 0.20 % of L (Gauss-Seidel: 101 % and 115 %; it
needs 64 x 15 or 128 x 4 with bend importance 1 for 2 %, 60-80x the time per frame), and
inextensible hair keeps every segment within 1e-5 of its rest length in every frame of
hair_strands and within 0.1 % on hair_head_gusts with head contacts, 64 and 200 strands
(Gauss-Seidel with tethers: 10 % and 27 %), at 2-4x the CPU time per frame of Gauss-Seidel.
With mesh contacts the strands are also projected in the final collision rounds
(``project_joint``): without it the contacts' last word left 1.2 % on 200 strands.

One Newton step per iteration is not a safe budget when the prediction is far from feasible:
with light hair streaming at 4-7 m/s in gusts (hair_head_gusts without its head contacts, 4
substeps) 3 steps per substep (importance 0.2) let segments stretch 8x transiently, 6 (0.35)
held 0.01 %, 8 (0.5) and 15 (1.0, the default) 0.000 %. A strand whose right-hand sides are
all below ``CONVERGED`` skips its solve, so the default's extra steps cost little once the
strands have converged (hair_strands: 12.5 ms/frame CPU at importance 1.0, 9.9 at 0.5).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit, prange

from lokigraph.behavior import ConstraintBehavior
from lokigraph.components.core import Dynamic
from lokigraph.components.materials import Rod
from lokigraph.meshfile import curve_chains

from ..solvers.nucleus.xpbd import (_INF, _LEN_EPS, PARALLEL_MIN_CONSTRAINTS, _hot,
                                    residual)
from .common import _rest
from .shear import _apex, rest_angles

#: constraint rows per segment: the stretch of segment k is row 3k, the bend at vertex k rows
#: 3k - 2 and 3k - 1 (two components of the curvature vector across the strand)
ROWS_PER_SEG = 3
#: half bandwidth of a strand's system in that order (bend rows at vertices k and k + 2 share
#: vertex k + 1)
BAND = 7
#: a pivot below this fraction of its diagonal (a dependent hard row) falls back to the diagonal
_PIVOT_REL = 1e-10
#: a vertex whose rest turning angle is below this [rad] is straight at rest: vector bend
STRAIGHT_REST = 1e-6
#: a strand whose every XPBD right-hand side ``-C - alpha~ lam`` is below this (stretch rows
#: divided by their rest length) is converged and skips its solve: the Newton steps converge
#: quadratically, so after a few iterations of a substep most strands pass this test
CONVERGED = 1e-9
#: strain up to which the final collision rounds count a strand as satisfied
JOINT_STRAIN = 1e-4
#: row kinds
_STRETCH, _BEND_VEC, _BEND_ANGLE, _OFF = 0, 1, 2, 3


# ==============================================================================================
# Kernels
# ==============================================================================================
@_hot
def _row_first(r):
    """First local vertex of row r: row 3k is the stretch of segment k (vertices k, k + 1), rows
    3k - 2 and 3k - 1 the bend at vertex k (vertices k - 1, k, k + 1)."""
    return r // 3 if r % 3 == 0 else (r + 2) // 3 - 1


@_hot
def _row_count(r):
    return 2 if r % 3 == 0 else 3


@_hot
def _off(j, G, at, rhs):
    for a in range(3):
        for k in range(3):
            G[j, a, k] = 0.0
    at[j] = 1.0
    rhs[j] = 0.0


@_hot
def _strand_rows(s, p, w, verts, vptr, rptr, kind, rest, alpha, alpha2, lam, lamv, G, dvec, at,
                 rhs, inv_h2):
    """Constraint values, gradients G[row, local vertex, 3], alpha~ and right-hand sides of the
    rows of strand s. An inactive row gets G = 0, alpha~ = 1, rhs = 0 (dlam = 0). A vector bend
    stores its two directions in dvec and reads its multiplier from the world vector lamv of its
    first row."""
    v0 = vptr[s]
    r0 = rptr[s]
    nrow = rptr[s + 1] - r0
    for r in range(nrow):
        j = r0 + r
        kd = kind[j]
        if kd == _OFF:
            _off(j, G, at, rhs)
            continue
        if kd == _STRETCH:  # stretch of segment r // 3
            _off(j, G, at, rhs)
            k0 = r // 3
            a = verts[v0 + k0]
            b = verts[v0 + k0 + 1]
            if w[a] + w[b] <= 0.0:
                continue
            dx = p[a, 0] - p[b, 0]
            dy = p[a, 1] - p[b, 1]
            dz = p[a, 2] - p[b, 2]
            ln = math.sqrt(dx * dx + dy * dy + dz * dz)
            if ln < _LEN_EPS:
                continue
            c = ln - rest[j]
            al = alpha[j] if c >= 0.0 else alpha2[j]
            if not al < _INF:
                continue
            il = 1.0 / ln
            G[j, 0, 0] = dx * il
            G[j, 0, 1] = dy * il
            G[j, 0, 2] = dz * il
            G[j, 1, 0] = -dx * il
            G[j, 1, 1] = -dy * il
            G[j, 1, 2] = -dz * il
            at[j] = al * inv_h2
            rhs[j] = -c - at[j] * lam[j]
            continue
        k0 = (r + 2) // 3  # bend at vertex k0, component cc
        cc = r - (3 * k0 - 2)
        if kd == _BEND_VEC and cc == 1:
            continue  # filled with its first row
        _off(j, G, at, rhs)
        if kd == _BEND_VEC:
            _off(j + 1, G, at, rhs)
        a = verts[v0 + k0 - 1]
        o = verts[v0 + k0]
        b = verts[v0 + k0 + 1]
        if w[a] + w[o] + w[b] <= 0.0:
            continue
        al = alpha[j]
        if not al < _INF:
            continue
        if kd == _BEND_VEC:
            # C = t_v - t_u (unit tangents of the segments before and after vertex k0):
            # |C| = 2 sin(phi / 2) for a turning angle phi, C is normal to t_u + t_v. Rows: C
            # along d1 = C / |C| and d2 = b x d1 (b = (t_u + t_v) / |t_u + t_v|), whose
            # squares sum to |C|^2; dt/dp = (I - t t^T) / |e|.
            ux = p[o, 0] - p[a, 0]
            uy = p[o, 1] - p[a, 1]
            uz = p[o, 2] - p[a, 2]
            vx = p[b, 0] - p[o, 0]
            vy = p[b, 1] - p[o, 1]
            vz = p[b, 2] - p[o, 2]
            lu = math.sqrt(ux * ux + uy * uy + uz * uz)
            lv = math.sqrt(vx * vx + vy * vy + vz * vz)
            if lu < _LEN_EPS or lv < _LEN_EPS:
                continue
            iu = 1.0 / lu
            iv = 1.0 / lv
            ux *= iu
            uy *= iu
            uz *= iu
            vx *= iv
            vy *= iv
            vz *= iv
            bx = ux + vx
            by = uy + vy
            bz = uz + vz
            nb = math.sqrt(bx * bx + by * by + bz * bz)
            if nb < 1e-6:
                continue  # folded back on itself: no bisector
            bx /= nb
            by /= nb
            bz /= nb
            cx = vx - ux
            cy = vy - uy
            cz = vz - uz
            cn = math.sqrt(cx * cx + cy * cy + cz * cz)
            if cn > 1e-12:
                e1x = cx / cn
                e1y = cy / cn
                e1z = cz / cn
            else:  # straight: any unit vector normal to b
                if abs(bx) <= abs(by) and abs(bx) <= abs(bz):
                    e1x, e1y, e1z = 1.0 - bx * bx, -bx * by, -bx * bz
                elif abs(by) <= abs(bz):
                    e1x, e1y, e1z = -by * bx, 1.0 - by * by, -by * bz
                else:
                    e1x, e1y, e1z = -bz * bx, -bz * by, 1.0 - bz * bz
                ne = math.sqrt(e1x * e1x + e1y * e1y + e1z * e1z)
                e1x /= ne
                e1y /= ne
                e1z /= ne
            e2x = by * e1z - bz * e1y
            e2y = bz * e1x - bx * e1z
            e2z = bx * e1y - by * e1x
            att = al * inv_h2
            for q in range(2):
                jq = j + q
                dx = e1x if q == 0 else e2x
                dy = e1y if q == 0 else e2y
                dz = e1z if q == 0 else e2z
                dvec[jq, 0] = dx
                dvec[jq, 1] = dy
                dvec[jq, 2] = dz
                du = dx * ux + dy * uy + dz * uz
                dv = dx * vx + dy * vy + dz * vz
                # vertex a: d^T (I - t_u t_u^T) / |e_u|, vertex b: d^T (I - t_v t_v^T) / |e_v|
                G[jq, 0, 0] = (dx - du * ux) * iu
                G[jq, 0, 1] = (dy - du * uy) * iu
                G[jq, 0, 2] = (dz - du * uz) * iu
                G[jq, 2, 0] = (dx - dv * vx) * iv
                G[jq, 2, 1] = (dy - dv * vy) * iv
                G[jq, 2, 2] = (dz - dv * vz) * iv
                for k in range(3):
                    G[jq, 1, k] = -G[jq, 0, k] - G[jq, 2, k]
                c = dx * cx + dy * cy + dz * cz
                lq = dx * lamv[j, 0] + dy * lamv[j, 1] + dz * lamv[j, 2]
                at[jq] = att
                rhs[jq] = -c - att * lq
            continue
        # _BEND_ANGLE (curved rest): C = angle at the apex - rest (type 2)
        st, theta, gax, gay, gaz, gbx, gby, gbz, gox, goy, goz = _apex(p, o, a, b)
        if st < 2:
            continue  # a short arm, or collinear: the direction of the angle change is undefined
        c = theta - rest[j]
        G[j, 0, 0] = gax
        G[j, 0, 1] = gay
        G[j, 0, 2] = gaz
        G[j, 2, 0] = gbx
        G[j, 2, 1] = gby
        G[j, 2, 2] = gbz
        for k in range(3):
            G[j, 1, k] = -G[j, 0, k] - G[j, 2, k]
        at[j] = al * inv_h2
        rhs[j] = -c - at[j] * lam[j]


@_hot
def _strand_solve(s, p, w, verts, vptr, rptr, kind, rest, alpha, alpha2, lam, lamv, G, dvec, at,
                  rhs, Ab, inv_h2):
    """One Newton step of strand s: assemble J W J^T + alpha~ in band form, LDL^T, solve, move."""
    _strand_rows(s, p, w, verts, vptr, rptr, kind, rest, alpha, alpha2, lam, lamv, G, dvec, at,
                 rhs, inv_h2)
    v0 = vptr[s]
    r0 = rptr[s]
    nrow = rptr[s + 1] - r0
    # converged (every right-hand side below CONVERGED, stretch rows relative to their rest
    # length): the Newton step is dlam = 0, skip the factorisation
    worst = 0.0
    for r in range(nrow):
        v = abs(rhs[r0 + r])
        if kind[r0 + r] == _STRETCH:
            v /= max(rest[r0 + r], _LEN_EPS)
        if v > worst:
            worst = v
    if worst < CONVERGED:
        return
    # assemble the upper band: Ab[r0 + r, k] = A[r, r + k]
    for r in range(nrow):
        fr = _row_first(r)
        cr = _row_count(r)
        for k in range(BAND + 1):
            q = r + k
            if q >= nrow:
                Ab[r0 + r, k] = 0.0
                continue
            fq = _row_first(q)
            cq = _row_count(q)
            lo = max(fr, fq)
            hi = min(fr + cr, fq + cq)
            acc = 0.0
            for lv in range(lo, hi):
                wi = w[verts[v0 + lv]]
                if wi > 0.0:
                    ia = lv - fr
                    ib = lv - fq
                    acc += wi * (G[r0 + r, ia, 0] * G[r0 + q, ib, 0]
                                 + G[r0 + r, ia, 1] * G[r0 + q, ib, 1]
                                 + G[r0 + r, ia, 2] * G[r0 + q, ib, 2])
            if k == 0:
                acc += at[r0 + r]
            Ab[r0 + r, k] = acc
    # banded LDL^T in place: Ab[j, 0] = D_j, Ab[j, k] = L[j + k, j] (k >= 1)
    for jr in range(nrow):
        j = r0 + jr
        d0 = Ab[j, 0]
        d = d0
        for kr in range(max(0, jr - BAND), jr):
            lk = Ab[r0 + kr, jr - kr]
            d -= lk * lk * Ab[r0 + kr, 0]
        if not d > _PIVOT_REL * d0:
            d = d0  # a dependent hard row: keep it bounded
        Ab[j, 0] = d
        for ir in range(jr + 1, min(jr + BAND, nrow - 1) + 1):
            v = Ab[j, ir - jr]
            for kr in range(max(0, ir - BAND), jr):
                v -= Ab[r0 + kr, ir - kr] * Ab[r0 + kr, jr - kr] * Ab[r0 + kr, 0]
            Ab[j, ir - jr] = v / d
    # solve L D L^T x = rhs in place in rhs
    for ir in range(nrow):
        v = rhs[r0 + ir]
        for kr in range(max(0, ir - BAND), ir):
            v -= Ab[r0 + kr, ir - kr] * rhs[r0 + kr]
        rhs[r0 + ir] = v
    for ir in range(nrow):
        rhs[r0 + ir] /= Ab[r0 + ir, 0]
    for ir in range(nrow - 1, -1, -1):
        v = rhs[r0 + ir]
        for kr in range(ir + 1, min(ir + BAND, nrow - 1) + 1):
            v -= Ab[r0 + ir, kr - ir] * rhs[r0 + kr]
        rhs[r0 + ir] = v
    # p += W J^T dlam, lam += dlam (a vector bend accumulates d dlam into its world multiplier)
    for r in range(nrow):
        j = r0 + r
        dl = rhs[j]
        if kind[j] == _BEND_VEC:
            jl = j if (r - (3 * ((r + 2) // 3) - 2)) == 0 else j - 1
            lamv[jl, 0] += dl * dvec[j, 0]
            lamv[jl, 1] += dl * dvec[j, 1]
            lamv[jl, 2] += dl * dvec[j, 2]
        else:
            lam[j] += dl
        fr = _row_first(r)
        for ia in range(_row_count(r)):
            g = verts[v0 + fr + ia]
            wi = w[g]
            if wi > 0.0:
                f = wi * dl
                p[g, 0] += f * G[j, ia, 0]
                p[g, 1] += f * G[j, ia, 1]
                p[g, 2] += f * G[j, ia, 2]


@njit(cache=True, parallel=True)
def project_rods(p, w, verts, vptr, rptr, kind, rest, alpha, alpha2, lam, lamv, G, dvec, at,
                 rhs, Ab, h):
    """Direct stretch + bend solve of every strand, strands in parallel.

    p positions [m] (n, 3), in place; w inverse masses [1/kg] (n,). Strand s has the global
    vertices ``verts[vptr[s]:vptr[s+1]]`` in chain order (m_s = vptr[s+1] - vptr[s] - 1 segments)
    and the rows ``rptr[s]:rptr[s+1]`` (3 m_s - 2 of them): row 3k is the stretch of segment k,
    rows 3k - 2 and 3k - 1 the bend at vertex k. Per row: kind (``_STRETCH``, ``_BEND_VEC``,
    ``_BEND_ANGLE``, ``_OFF``), rest (length [m] or angle [rad]), alpha (stretch [m/N] or bend
    [1/(N m)] compliance; inf = off), alpha2 (compression compliance of stretch rows), lam
    (multipliers of stretch and angle rows), lamv (R, 3) world multiplier vector of a vector
    bend (on its first row); both reset every substep. Workspace (allocated at bind, see
    ``strand_workspace``): G (R, 3, 3), dvec (R, 3), at (R,), rhs (R,), Ab (R, BAND + 1).
    h substep [s]. One Newton step of the XPBD system of every strand.
    """
    inv_h2 = 1.0 / (h * h)
    for s in prange(vptr.shape[0] - 1):
        _strand_solve(s, p, w, verts, vptr, rptr, kind, rest, alpha, alpha2, lam, lamv, G, dvec,
                      at, rhs, Ab, inv_h2)


@njit(cache=True)
def project_rods_seq(p, w, verts, vptr, rptr, kind, rest, alpha, alpha2, lam, lamv, G, dvec, at,
                     rhs, Ab, h):
    """Sequential variant of ``project_rods`` (same arguments)."""
    inv_h2 = 1.0 / (h * h)
    for s in range(vptr.shape[0] - 1):
        _strand_solve(s, p, w, verts, vptr, rptr, kind, rest, alpha, alpha2, lam, lamv, G, dvec,
                      at, rhs, Ab, inv_h2)


def strand_workspace(R: int):
    """(G, dvec, at, rhs, Ab) workspace of ``project_rods`` for R rows."""
    return (np.zeros((R, 3, 3)), np.zeros((R, 3)), np.zeros(R), np.zeros(R),
            np.zeros((R, BAND + 1)))


@njit(cache=True)
def rod_values(p, verts, vptr, rptr, kind, rest):
    """Constraint values of every row, shape (R,): stretch [m]; a vector bend gives |t_v - t_u|
    = 2 sin(phi / 2) [-] on its first row and 0 on its second; an angle bend angle - rest [rad];
    0 for rows that are off."""
    out = np.zeros(rest.shape[0])
    for s in range(vptr.shape[0] - 1):
        v0 = vptr[s]
        r0 = rptr[s]
        for r in range(rptr[s + 1] - r0):
            kd = kind[r0 + r]
            if kd == _OFF:
                continue
            if kd == _STRETCH:
                a = verts[v0 + r // 3]
                b = verts[v0 + r // 3 + 1]
                d = 0.0
                for k in range(3):
                    t = p[a, k] - p[b, k]
                    d += t * t
                out[r0 + r] = math.sqrt(d) - rest[r0 + r]
                continue
            k0 = (r + 2) // 3
            if r - (3 * k0 - 2) != 0:
                continue
            a = verts[v0 + k0 - 1]
            o = verts[v0 + k0]
            b = verts[v0 + k0 + 1]
            ux = p[a, 0] - p[o, 0]
            uy = p[a, 1] - p[o, 1]
            uz = p[a, 2] - p[o, 2]
            vx = p[b, 0] - p[o, 0]
            vy = p[b, 1] - p[o, 1]
            vz = p[b, 2] - p[o, 2]
            lu = max(math.sqrt(ux * ux + uy * uy + uz * uz), _LEN_EPS)
            lv = max(math.sqrt(vx * vx + vy * vy + vz * vz), _LEN_EPS)
            if kd == _BEND_VEC:
                cx = vx / lv + ux / lu
                cy = vy / lv + uy / lu
                cz = vz / lv + uz / lu
                out[r0 + r] = math.sqrt(cx * cx + cy * cy + cz * cz)
                continue
            cx = uy * vz - uz * vy
            cy = uz * vx - ux * vz
            cz = ux * vy - uy * vx
            ang = math.atan2(math.sqrt(cx * cx + cy * cy + cz * cz),
                             ux * vx + uy * vy + uz * vz)
            out[r0 + r] = ang - rest[r0 + r]
    return out


# ==============================================================================================
# Packing and the Nucleus constraint behavior
# ==============================================================================================
def strand_chains(e) -> list[np.ndarray] | None:
    """The strands of a curve element as local vertex index arrays in chain order, or None when
    its topology is not a set of open polylines (a vertex of degree 3 or more, or a loop)."""
    g = e.geometry
    edges = np.asarray(g.edges, np.int64)
    if not len(edges):
        return None
    deg = np.bincount(edges.ravel(), minlength=e.vertex_count)
    if deg.max() > 2:
        return None
    chains = curve_chains(edges, e.vertex_count)
    if any(len(c) > 2 and c[0] == c[-1] for c in chains):
        return None
    return chains


def solved_directly(e) -> bool:
    """True when the Rod of element e is solved by :class:`RodConstraint` (``Rod.solve ==
    "direct"`` on open polylines); the Gauss-Seidel stretch and bend constraints then skip it."""
    if not e.has(Rod) or not e.has(Dynamic):
        return False
    if e.get(Rod).solve != "direct":
        return False
    return strand_chains(e) is not None


def rod_bend_stiffness(c) -> float:
    """EI [N m^2] of a Rod: ``bend_resistance``, else E pi r^4 / 4 (1e-9 if inextensible)."""
    EI = c.bend_resistance
    if EI is None:
        EI = (c.youngs_modulus * np.pi * c.radius ** 4 / 4.0 if c.youngs_modulus is not None
              else 1e-9)
    return float(EI)


@dataclass
class RodData:
    verts: np.ndarray  # (V,) global vertex indices, strands back to back in chain order
    vptr: np.ndarray  # (S + 1,)
    rptr: np.ndarray  # (S + 1,)
    kind: np.ndarray  # (R,) int64 row kind
    rest: np.ndarray  # (R,)
    alpha: np.ndarray  # (R,)
    alpha2: np.ndarray  # (R,)
    lam: np.ndarray  # (R,) stretch and angle-bend multipliers
    lamv: np.ndarray  # (R, 3) world multiplier vector of a vector bend (its first row)
    G: np.ndarray  # (R, 3, 3) workspace
    dvec: np.ndarray  # (R, 3) workspace
    at: np.ndarray  # (R,) workspace
    rhs: np.ndarray  # (R,) workspace
    Ab: np.ndarray  # (R, BAND + 1) workspace
    parallel: bool
    #: stretch rows as (m, 2) global vertex pairs and rest lengths [m] (for strain reports)
    idx: np.ndarray
    rest_len: np.ndarray

    def __len__(self):
        return len(self.rest)


def _strand_rows_params(X, chain, c):
    """kind, rest, alpha, alpha2 of the rows of one strand (chain: local vertex indices)."""
    m = len(chain) - 1
    P = X[chain]
    L = np.linalg.norm(P[1:] - P[:-1], axis=1)
    if c.youngs_modulus is None:
        a = np.zeros(m)
    else:
        a = L / (c.youngs_modulus * np.pi * c.radius ** 2)
    ac = a / c.compression_ratio if c.compression_ratio > 0 else np.full(m, np.inf)
    R = ROWS_PER_SEG * m - 2
    kind = np.full(R, _OFF, np.int64)
    rest = np.zeros(R)
    alpha = np.full(R, np.inf)
    alpha2 = np.full(R, np.inf)
    kind[0::3] = _STRETCH
    rest[0::3] = L * c.rest_length_scale
    alpha[0::3] = a
    alpha2[0::3] = ac
    if m > 1:
        EI = rod_bend_stiffness(c)
        apex = np.stack([chain[1:-1], chain[:-2], chain[2:]], axis=1)
        gamma = rest_angles(X, apex)
        # the bend cells tile the strand: vertex k stands for half of each adjacent segment,
        # and the end bend vertices also for the outer half of the end segments (at a clamped
        # root the curvature is largest there: without it the tip error is O(segment length),
        # 3 % of L on the 20-segment elastica bench, with it 0.4 %)
        lv = 0.5 * (L[:-1] + L[1:])
        lv[0] += 0.5 * L[0]
        lv[-1] += 0.5 * L[-1]
        ab = lv / EI if EI > 0 else np.full(m - 1, np.inf)
        straight = np.pi - gamma < STRAIGHT_REST
        for cc in range(2):
            rows = np.arange(1 + cc, R, 3)
            kind[rows] = np.where(straight, _BEND_VEC, _BEND_ANGLE if cc == 0 else _OFF)
            rest[rows] = np.where(straight, 0.0, gamma)
            alpha[rows] = np.where(straight | (cc == 0), ab, np.inf)
    return kind, rest, alpha, alpha2


class RodConstraint(ConstraintBehavior):
    """Stretch and bend of Rod strands, solved directly per strand (module docstring)."""

    requires = (Dynamic, Rod)
    default_importance = 1.0
    default_order = 28

    def bind(self, ctx, elements):
        verts, vptr, rptr = [], [0], [0]
        kind, rest, alpha, alpha2 = [], [], [], []
        for e in elements:
            if not solved_directly(e):
                continue
            c = e.get(Rod)
            X = _rest(ctx, e, c)
            for chain in strand_chains(e):
                if len(chain) < 2:
                    continue
                kd, r, a, a2 = _strand_rows_params(X, chain, c)
                verts.append(chain + e.vertex_offset)
                vptr.append(vptr[-1] + len(chain))
                rptr.append(rptr[-1] + len(r))
                kind.append(kd)
                rest.append(r)
                alpha.append(a)
                alpha2.append(a2)
        if not verts:
            return None
        vv = np.ascontiguousarray(np.concatenate(verts), dtype=np.int64)
        vp = np.asarray(vptr, np.int64)
        rp = np.asarray(rptr, np.int64)
        R = int(rp[-1])
        rs = np.ascontiguousarray(np.concatenate(rest))
        # stretch rows, for strain reports: every third row of every strand
        srow = np.concatenate([np.arange(rp[s], rp[s + 1], 3) for s in range(len(rp) - 1)])
        spair = np.concatenate([np.stack([vv[vp[s]:vp[s + 1] - 1], vv[vp[s] + 1:vp[s + 1]]], 1)
                                for s in range(len(vp) - 1)])
        return RodData(vv, vp, rp, np.ascontiguousarray(np.concatenate(kind)), rs,
                       np.ascontiguousarray(np.concatenate(alpha)),
                       np.ascontiguousarray(np.concatenate(alpha2)), np.zeros(R),
                       np.zeros((R, 3)), *strand_workspace(R),
                       len(vp) > 2 and len(spair) >= PARALLEL_MIN_CONSTRAINTS,
                       np.ascontiguousarray(spair), np.ascontiguousarray(rs[srow]))

    def project(self, ctx, d, p):
        fn = project_rods if d.parallel else project_rods_seq
        fn(p, ctx.model.particle_inv_mass, d.verts, d.vptr, d.rptr, d.kind, d.rest, d.alpha,
           d.alpha2, d.lam, d.lamv, d.G, d.dvec, d.at, d.rhs, d.Ab, ctx.dt)

    def begin_substep(self, ctx, d):
        d.lam[:] = 0.0
        d.lamv[:] = 0.0

    # the final collision rounds (CollisionConstraint.finalize and its CCD safe step) solve the
    # strands together with the contacts, so the contacts do not have the last word alone
    def project_joint(self, ctx, d, p):
        self.project(ctx, d, p)

    def joint_iterations(self) -> int:
        return 0  # as many as the contacts' own final iterations

    def satisfied(self, ctx, d, p) -> bool:
        """Every stretch row within ``JOINT_STRAIN`` of its rest length."""
        v = rod_values(p, d.verts, d.vptr, d.rptr, d.kind, d.rest)
        s = d.kind == _STRETCH
        return bool((np.abs(v[s]) <= JOINT_STRAIN * d.rest[s]).all())

    def residual(self, ctx, d, p):
        """Max |C| over the active rows (stretch [m] and bend [rad] together)."""
        v = rod_values(p, d.verts, d.vptr, d.rptr, d.kind, d.rest)
        v[~(d.alpha < np.inf)] = 0.0
        return float(residual(v)[0])

    def describe(self, d):
        if d is None:
            return ""
        return (f"{len(d.vptr) - 1} strands, {len(d.idx)} segments, direct "
                f"{'parallel' if d.parallel else 'sequential'}")



# ==============================================================================================
# Implicit energy (behaviors/solvers/implicit/energy.py has the protocol): the same rows as
# energies, stretch rows as the stretch module's springs, bend rows as the bend module's rod
# bending energy (curvature binormal). Imported at call time (stretch and bend import this module).
# ==============================================================================================
def _rod_energy_rows(d):
    """(edges, rest, alpha, alpha2) of the stretch rows and (apex triplets, rest apex angle,
    alpha) of the bend rows of every strand, packed once (cached on the data). A strand of m
    segments has its stretch of segment k at row ``stride * k`` and the first row of its bend at
    vertex k at ``stride * k - stride + 1`` (stride 4 with vector bend rows, 2 with one angle row
    per vertex); the bend compliance (``l / EI``, end cells included) is taken as packed."""
    rows = getattr(d, "_implicit_rows", None)
    if rows is None:
        kind = getattr(d, "kind", None)
        e, er, ea, ea2, t, tr, ta = [], [], [], [], [], [], []
        for s in range(len(d.vptr) - 1):
            ch = d.verts[d.vptr[s]:d.vptr[s + 1]]
            r0, r1 = int(d.rptr[s]), int(d.rptr[s + 1])
            m = len(ch) - 1
            if m < 1:
                continue
            stride = 1 if m == 1 else (r1 - r0 - 1) // (m - 1)
            e.append(np.stack([ch[:-1], ch[1:]], 1))
            srow = r0 + stride * np.arange(m)
            er.append(d.rest[srow])
            ea.append(d.alpha[srow])
            ea2.append(d.alpha2[srow])
            if m > 1:
                brow = r0 + stride * np.arange(1, m) - stride + 1
                t.append(np.stack([ch[1:-1], ch[:-2], ch[2:]], 1))
                gamma = d.rest[brow].copy()
                if kind is not None:  # vector rows: straight at rest (apex angle pi)
                    gamma[kind[brow] == _BEND_VEC] = np.pi
                tr.append(gamma)
                ta.append(d.alpha[brow])
        cat = [np.ascontiguousarray(np.concatenate(a)) for a in (e, er, ea, ea2)]
        if t:
            cat += [np.ascontiguousarray(np.concatenate(a)) for a in (t, tr, ta)]
        else:
            cat += [np.zeros((0, 3), np.int64), np.zeros(0), np.zeros(0)]
        cat[0] = cat[0].astype(np.int64)
        cat[4] = cat[4].astype(np.int64)
        rows = d._implicit_rows = cat
    return rows


def _rod_energy_stencils(self, ctx, d):
    rows = _rod_energy_rows(d)
    return [rows[0], rows[4]]


def _rod_multipliers(self, d):
    """Multipliers [N] of the hard stretch rows (see ``stretch.spring_energy``)."""
    lam = getattr(d, "_implicit_lam", None)
    if lam is None:
        lam = d._implicit_lam = np.zeros(len(_rod_energy_rows(d)[0]))
    return lam


def _rod_energy(self, ctx, d, x, grad, hess, opts):
    from ..solvers.implicit.energy import grad_or_dummy, hess_or_dummy
    from .bend import rod_bend_energy
    from .stretch import spring_energy

    e, er, ea, ea2, t, tr, ta = _rod_energy_rows(d)
    gr = grad_or_dummy(grad, opts)
    E = spring_energy(x, e, er, ea, ea2, _rod_multipliers(self, d), opts.hard_k, opts.mode, gr,
                      hess_or_dummy(hess, 0, opts))
    if len(t):
        E += rod_bend_energy(x, t, tr, ta, opts.mode, gr, hess_or_dummy(hess, 1, opts))
    return E


# the implicit energy protocol on the Nucleus constraint type of this effect
def _rod_update_multipliers(self, ctx, d, x, opts):
    from .stretch import spring_update_lam

    e, er, ea, ea2 = _rod_energy_rows(d)[:4]
    spring_update_lam(x, e, er, ea, ea2, _rod_multipliers(self, d), opts.hard_k)


RodConstraint.energy_stencils = _rod_energy_stencils
RodConstraint.energy = _rod_energy
RodConstraint.energy_update_multipliers = _rod_update_multipliers
RodConstraint.energy_multipliers = _rod_multipliers


def _rod_state_arrays(self, d):
    """Checkpointed run state: the implicit solver's multipliers of the hard stretch rows."""
    return {"implicit_lam": _rod_multipliers(self, d)} if d is not None else {}


def _rod_load_state_arrays(self, d, arrays):
    if d is not None and "implicit_lam" in arrays:
        _rod_multipliers(self, d)[:] = arrays["implicit_lam"]


RodConstraint.state_arrays = _rod_state_arrays
RodConstraint.load_state_arrays = _rod_load_state_arrays
