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

Twist (``Rod.twist_resistance``; Bergou, Wardetzky, Robinson, Audoly, Grinspun, "Discrete
Elastic Rods", SIGGRAPH 2008): every segment carries a reference director d1 (unit, normal to
its tangent t) and a twist angle theta with rate omega; the material frame is
``m1 = cos(theta) d1 + sin(theta) t x d1``, ``m2 = t x m1`` (:func:`material_frames`). Once per
substep, after the position iterations (``after_finalize``, :func:`twist_step`):

1. each d1 is carried to its segment's new tangent by time-parallel transport (the rotation
   taking the old tangent to the new one), so d1 never spins about t;
2. the reference twist at interior vertex k, the angle about t_k from d1_{k-1} transported along
   the strand onto t_k to d1_k, is updated continuously (no 2 pi jumps);
3. theta~ = theta + h omega (omega damped by ``Dynamic.damping`` like the vertices), then XPBD on
   the twist rows ``C_k = theta_k - theta_{k-1} + reft_k`` (rest twist 0: the frames start as
   the twist-free Bishop frame of the initial shape, :func:`bishop_frames`), compliance
   ``l_k / GJ`` (l_k the distance between the segment centres), inverse inertia per segment
   ``1 / (rho J l) = 2 / (m r^2)`` (a solid circular fibre, m the segment's mass); a pinned or
   followed root vertex adds the row ``C_0 = theta_0 - Rod.root_twist`` over half the first
   segment, and a root carried by a body (``Pins.follow``) adds the body's spin to that angle:
   its initial reference director is stored in the frame of the carrying triangle at bind, and
   the angle about t_0 from d1_0 to that body-fixed director is followed continuously
   (``bphi``). The rows form a chain, linear in theta: (J W J^T + alpha~) dlam = -C is tridiagonal
   and one Thomas solve per strand (O(n), strands in ``prange`` like the position solve) gives
   the exact XPBD answer, what projecting in every iteration would converge to;
4. omega = (theta_new - theta) / h.

The coupling is one-way: the frame follows the centre line (through the transport and the
reference twist), but the twist energy does not push back on the positions (its gradient
through the reference twist, what makes a twisted rod buckle into plectonemes, is left out), and
the bending is isotropic, so positions are bit-identical with twist on or off (a straight strand
decouples exactly anyway). Measured (tests/test_rod_twist.py, graphs/bench/rod_twist.py): a
straight strand turned at its root oscillates at its tip with the fixed-free shaft period
4 L / c, c = sqrt(GJ / (rho J)), to 0.05 % at the default 4 substeps (2.2 % at one substep: the
implicit stepping stretches a period by atan(omega h) / (omega h)); a tangent swept once around
a cone of half angle a leaves the reference twist at the solid angle 2 pi (1 - cos a) to
3e-7; a strand on the axis of a ball turned by 45 degrees ends twisted uniformly by it (0.1 %).
The twist step costs about 70 ns per segment and substep (3-4 % of hair_strands and
hair_head_gusts). Only Nucleus advances the twist (the implicit solver takes the Rod as
energies and does not call this type's ``after_finalize``: there the frames stay as bound);
curves on Gauss-Seidel (``solve: gauss_seidel``, branched curves) have no material frame.
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
                e1x, e1y, e1z = _any_normal(bx, by, bz)
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
# Twist: a material frame per segment (Bergou et al. 2008, "Discrete Elastic Rods")
# ==============================================================================================
@_hot
def _wrap(x):
    """x wrapped to [-pi, pi]."""
    return x - 2.0 * math.pi * math.floor(x / (2.0 * math.pi) + 0.5)


@_hot
def _transport(ux, uy, uz, ax, ay, az, bx, by, bz):
    """Parallel transport of u from unit tangent a to unit tangent b: the rotation about a x b
    taking a to b (Rodrigues, R u = c u + k x u + k (k . u) / (1 + c), k = a x b, c = a . b),
    then made normal to b. Antiparallel tangents (no unique rotation): u projected on b's normal
    plane."""
    kx = ay * bz - az * by
    ky = az * bx - ax * bz
    kz = ax * by - ay * bx
    c = ax * bx + ay * by + az * bz
    if c > -1.0 + 1e-12:
        f = (kx * ux + ky * uy + kz * uz) / (1.0 + c)
        rx = c * ux + (ky * uz - kz * uy) + f * kx
        ry = c * uy + (kz * ux - kx * uz) + f * ky
        rz = c * uz + (kx * uy - ky * ux) + f * kz
    else:
        rx, ry, rz = ux, uy, uz
    d = rx * bx + ry * by + rz * bz
    return rx - d * bx, ry - d * by, rz - d * bz


@_hot
def _any_normal(bx, by, bz):
    """A unit vector normal to unit b (across its smallest component)."""
    if abs(bx) <= abs(by) and abs(bx) <= abs(bz):
        x, y, z = 1.0 - bx * bx, -bx * by, -bx * bz
    elif abs(by) <= abs(bz):
        x, y, z = -by * bx, 1.0 - by * by, -by * bz
    else:
        x, y, z = -bz * bx, -bz * by, 1.0 - bz * bz
    n = math.sqrt(x * x + y * y + z * z)
    return x / n, y / n, z / n


@_hot
def _transport_unit(ux, uy, uz, ax, ay, az, bx, by, bz):
    """:func:`_transport` normalised; a vector that (nearly) vanishes in transport is replaced
    by :func:`_any_normal` of b."""
    ux, uy, uz = _transport(ux, uy, uz, ax, ay, az, bx, by, bz)
    nu = math.sqrt(ux * ux + uy * uy + uz * uz)
    if nu > 1e-6:
        return ux / nu, uy / nu, uz / nu
    return _any_normal(bx, by, bz)


@_hot
def _twist_row_on(k, g0, v0, verts, w, alpha):
    """Row k of a strand's twist chain is active: row 0 (the root) when the root vertex is
    pinned or kinematic (w = 0), the others when their compliance is finite."""
    if k == 0:
        return w[verts[v0]] <= 0.0 and alpha[g0] < _INF
    return alpha[g0 + k] < _INF


@_hot
def _twist_strand(s, p, w, verts, vptr, d1, tan, theta, omega, winv, reft, alpha, root, bdir,
                  bphi, damp, tp, cp, dl, h):
    """One substep of the twist of strand s (``twist_step`` has the arguments): frames carried
    to the new tangents, reference twists updated, theta predicted and its chain of twist
    constraints solved exactly (Thomas algorithm), omega from the change of theta."""
    v0 = vptr[s]
    n = vptr[s + 1] - v0 - 1
    g0 = v0 - s
    # 1. time-parallel transport of every reference director to its segment's new tangent
    for k in range(n):
        g = g0 + k
        a = verts[v0 + k]
        b = verts[v0 + k + 1]
        ex = p[b, 0] - p[a, 0]
        ey = p[b, 1] - p[a, 1]
        ez = p[b, 2] - p[a, 2]
        ln = math.sqrt(ex * ex + ey * ey + ez * ez)
        if ln < _LEN_EPS:
            continue  # no tangent: the frame stays
        ex /= ln
        ey /= ln
        ez /= ln
        ux, uy, uz = _transport_unit(d1[g, 0], d1[g, 1], d1[g, 2], tan[g, 0], tan[g, 1],
                                     tan[g, 2], ex, ey, ez)
        d1[g, 0] = ux
        d1[g, 1] = uy
        d1[g, 2] = uz
        tan[g, 0] = ex
        tan[g, 1] = ey
        tan[g, 2] = ez
    # 2. reference twist at interior vertex k: the angle about t_k from d1_{k-1} transported
    # along the strand onto t_k to d1_k, continued from its last value (no 2 pi jumps)
    for k in range(1, n):
        g = g0 + k
        ux, uy, uz = _transport(d1[g - 1, 0], d1[g - 1, 1], d1[g - 1, 2], tan[g - 1, 0],
                                tan[g - 1, 1], tan[g - 1, 2], tan[g, 0], tan[g, 1], tan[g, 2])
        cx = uy * d1[g, 2] - uz * d1[g, 1]
        cy = uz * d1[g, 0] - ux * d1[g, 2]
        cz = ux * d1[g, 1] - uy * d1[g, 0]
        sn = cx * tan[g, 0] + cy * tan[g, 1] + cz * tan[g, 2]
        cs = ux * d1[g, 0] + uy * d1[g, 1] + uz * d1[g, 2]
        reft[g] += _wrap(math.atan2(sn, cs) - reft[g])
    # a root carried by a body: its spin about the root tangent, the angle about t_0 from d1_0
    # to the body-fixed director bdir (made normal to t_0), continued from its last value
    bx, by, bz = bdir[s, 0], bdir[s, 1], bdir[s, 2]
    if bx != 0.0 or by != 0.0 or bz != 0.0:
        tx, ty, tz = tan[g0, 0], tan[g0, 1], tan[g0, 2]
        dd = bx * tx + by * ty + bz * tz
        bx -= dd * tx
        by -= dd * ty
        bz -= dd * tz
        if bx * bx + by * by + bz * bz > 1e-12:  # else along the tangent: the angle stays
            cx = d1[g0, 1] * bz - d1[g0, 2] * by
            cy = d1[g0, 2] * bx - d1[g0, 0] * bz
            cz = d1[g0, 0] * by - d1[g0, 1] * bx
            sn = cx * tx + cy * ty + cz * tz
            cs = d1[g0, 0] * bx + d1[g0, 1] * by + d1[g0, 2] * bz
            bphi[s] += _wrap(math.atan2(sn, cs) - bphi[s])
    # 3. predict theta~ = theta + h omega (omega damped like the vertices: exp(-damping h))
    for k in range(n):
        g = g0 + k
        if damp[g] > 0.0:
            omega[g] *= math.exp(-damp[g] * h)
        tp[g] = theta[g] + h * omega[g]
    # 4. XPBD on the chain of twist rows, exact (the rows are linear in theta, so one solve
    # from lam = 0 leaves every right-hand side -C - alpha~ lam at zero): row k couples
    # theta_{k-1} (-1) and theta_k (+1), C_k = theta_k - theta_{k-1} + reft_k (the rest is
    # twist-free); row 0 is C_0 = theta_0 - root angle. (J W J^T + alpha~) dlam = -C is
    # tridiagonal: diagonal W_{k-1} + W_k + alpha~_k (W_{-1} = 0), off-diagonal -W_k between
    # rows k and k + 1 (0 when either is off). Thomas: forward sweep (cp, dl), back substitution.
    inv_h2 = 1.0 / (h * h)
    pc = 0.0
    pd = 0.0
    on_prev = False
    on_k = _twist_row_on(0, g0, v0, verts, w, alpha)
    for k in range(n):
        g = g0 + k
        on_n = _twist_row_on(k + 1, g0, v0, verts, w, alpha) if k + 1 < n else False
        wl = winv[g - 1] if k > 0 else 0.0
        diag = wl + winv[g] + alpha[g] * inv_h2
        if on_k and diag > 0.0:
            c = tp[g] - (tp[g - 1] - reft[g] if k > 0 else root[s] + bphi[s])
            lower = -wl if on_prev else 0.0
            upper = -winv[g] if on_n else 0.0
            den = diag - lower * pc
            cp[g] = upper / den
            dl[g] = (-c - lower * pd) / den
        else:
            cp[g] = 0.0
            dl[g] = 0.0
        pc = cp[g]
        pd = dl[g]
        on_prev = on_k and diag > 0.0
        on_k = on_n
    for k in range(n - 2, -1, -1):
        g = g0 + k
        dl[g] -= cp[g] * dl[g + 1]
    # theta += W J^T dlam (theta_k is + in row k and - in row k + 1); omega = dtheta / h
    ih = 1.0 / h
    for k in range(n):
        g = g0 + k
        nxt = dl[g + 1] if k + 1 < n else 0.0
        th = tp[g] + winv[g] * (dl[g] - nxt)
        omega[g] = (th - theta[g]) * ih
        theta[g] = th


@njit(cache=True, parallel=True)
def twist_step(p, w, verts, vptr, on, d1, tan, theta, omega, winv, reft, alpha, root, bdir, bphi,
               damp, tp, cp, dl, h):
    """One substep of the twist of every strand (strands in parallel), after the positions p
    [m] (n, 3) of the substep are final; w inverse masses [1/kg] (n,). Per segment (segments of
    strand s start at ``vptr[s] - s``): d1 reference director (unit, normal to the tangent), tan
    unit tangent it was last carried to, theta twist angle [rad] of the material frame from d1
    about tan, omega its rate [rad/s], winv inverse rotational inertia [1/(kg m^2)], alpha
    compliance [1/(N m)] of the twist row at the segment's first vertex (row 0 of a strand: the
    root; inf = off), reft reference twist [rad] at that vertex, damp rate [1/s]; root (S,) root
    angle [rad]; bdir (S, 3) a body-fixed director of a root carried by a body (zeros: none)
    and bphi (S,) that body's spin about the root tangent [rad] (continued, added to root);
    on (S,) strands with twist. tp, cp, dl (segments,) workspace; h substep [s]."""
    for s in prange(vptr.shape[0] - 1):
        if on[s]:
            _twist_strand(s, p, w, verts, vptr, d1, tan, theta, omega, winv, reft, alpha, root,
                          bdir, bphi, damp, tp, cp, dl, h)


@njit(cache=True)
def twist_step_seq(p, w, verts, vptr, on, d1, tan, theta, omega, winv, reft, alpha, root, bdir,
                   bphi, damp, tp, cp, dl, h):
    """Sequential variant of ``twist_step`` (same arguments)."""
    for s in range(vptr.shape[0] - 1):
        if on[s]:
            _twist_strand(s, p, w, verts, vptr, d1, tan, theta, omega, winv, reft, alpha, root,
                          bdir, bphi, damp, tp, cp, dl, h)


@njit(cache=True)
def bishop_frames(p, verts, vptr, d1, tan):
    """Twist-free frames of every strand at positions p: unit tangents, and reference directors
    carried along the strand by space-parallel transport from a normal of the first tangent (a
    zero-length segment takes the tangent before it). Its reference twists are zero."""
    for s in range(vptr.shape[0] - 1):
        v0 = vptr[s]
        n = vptr[s + 1] - v0 - 1
        g0 = v0 - s
        px, py, pz = 0.0, 0.0, 1.0
        for k in range(n):
            a = verts[v0 + k]
            b = verts[v0 + k + 1]
            ex = p[b, 0] - p[a, 0]
            ey = p[b, 1] - p[a, 1]
            ez = p[b, 2] - p[a, 2]
            ln = math.sqrt(ex * ex + ey * ey + ez * ez)
            if ln >= _LEN_EPS:
                px, py, pz = ex / ln, ey / ln, ez / ln
            g = g0 + k
            tan[g, 0] = px
            tan[g, 1] = py
            tan[g, 2] = pz
            if k == 0:
                ux, uy, uz = _any_normal(px, py, pz)
            else:
                ux, uy, uz = _transport_unit(d1[g - 1, 0], d1[g - 1, 1], d1[g - 1, 2],
                                             tan[g - 1, 0], tan[g - 1, 1], tan[g - 1, 2], px, py,
                                             pz)
            d1[g, 0] = ux
            d1[g, 1] = uy
            d1[g, 2] = uz


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


def rod_twist_stiffness(c) -> float:
    """GJ [N m^2] of a Rod: ``twist_resistance``, else EI / (1 + nu) (G = E / (2 (1 + nu)),
    J = pi r^4 / 2 = 2 I); 0 = no twist."""
    GJ = c.twist_resistance
    if GJ is None:
        GJ = rod_bend_stiffness(c) / (1.0 + c.poisson_ratio)
    return float(GJ)


@dataclass
class TwistData:
    """The material frames of the strands of a :class:`RodData` (segment g of strand s is
    ``vptr[s] - s + k``; see ``twist_step``)."""

    on: np.ndarray  # (S,) bool: strand has twist
    d1: np.ndarray  # (M, 3) reference director (unit, normal to tan)
    tan: np.ndarray  # (M, 3) unit tangent d1 was last carried to
    theta: np.ndarray  # (M,) twist angle [rad] of the material frame from d1 about tan
    omega: np.ndarray  # (M,) its rate [rad/s]
    winv: np.ndarray  # (M,) inverse rotational inertia [1/(kg m^2)]
    reft: np.ndarray  # (M,) reference twist [rad] at the segment's first vertex
    alpha: np.ndarray  # (M,) twist compliance [1/(N m)] of that vertex's row (row 0: root)
    root: np.ndarray  # (S,) root angle [rad]
    damp: np.ndarray  # (M,) angular velocity damping rate [1/s]
    keyed_damp: list  # [(segment slice, Keyed)]
    keyed_root: list  # [(strand slice, Keyed)]
    tp: np.ndarray  # (M,) workspace
    cp: np.ndarray  # (M,) workspace
    dl: np.ndarray  # (M,) workspace
    bdir: np.ndarray  # (S, 3) body-fixed director at a carried root (zeros: not carried)
    bphi: np.ndarray  # (S,) the carrying body's spin about the root tangent [rad], continued
    #: roots carried by a body (Pins.follow): strand indices (F,), global vertices of the
    #: carrying triangle (F, 3), and the root director in that triangle's frame (F, 3)
    fstrand: np.ndarray | None = None
    ftri: np.ndarray | None = None
    fcoef: np.ndarray | None = None


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
    #: material frames (None when no strand has twist)
    twist: TwistData | None = None

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
        d = RodData(vv, vp, rp, np.ascontiguousarray(np.concatenate(kind)), rs,
                    np.ascontiguousarray(np.concatenate(alpha)),
                    np.ascontiguousarray(np.concatenate(alpha2)), np.zeros(R),
                    np.zeros((R, 3)), *strand_workspace(R),
                    len(vp) > 2 and len(spair) >= PARALLEL_MIN_CONSTRAINTS,
                    np.ascontiguousarray(spair), np.ascontiguousarray(rs[srow]))
        d.twist = _bind_twist(ctx, elements, d)
        return d

    def project(self, ctx, d, p):
        fn = project_rods if d.parallel else project_rods_seq
        fn(p, ctx.model.particle_inv_mass, d.verts, d.vptr, d.rptr, d.kind, d.rest, d.alpha,
           d.alpha2, d.lam, d.lamv, d.G, d.dvec, d.at, d.rhs, d.Ab, ctx.dt)

    def begin_substep(self, ctx, d):
        d.lam[:] = 0.0
        d.lamv[:] = 0.0

    def after_finalize(self, ctx, d, p):
        """The twist of the substep, on its final positions (``twist_step``). Once per substep,
        not in every projection: no other constraint acts on theta and the twist does not act
        on the positions, so a linear chain solved exactly once gives what every iteration
        would."""
        t = d.twist if d is not None else None
        if t is None:
            return
        if t.keyed_damp or t.keyed_root:
            from lokigraph.keys import step_frame

            f = step_frame(ctx)
            for sl, key in t.keyed_damp:
                t.damp[sl] = key.evaluate(f)
            f_end = f + 1.0 / int(ctx.model.substeps)  # the root's pose at the substep's end
            for sl, key in t.keyed_root:
                t.root[sl] = key.evaluate(f_end)
        if t.fstrand is not None:  # carried roots: the body's director at the substep's end
            from ..attachments.pins import triangle_frames

            e1, e2, nrm = triangle_frames(p[t.ftri])
            t.bdir[t.fstrand] = (t.fcoef[:, :1] * e1 + t.fcoef[:, 1:2] * e2
                                 + t.fcoef[:, 2:] * nrm)
        fn = twist_step if d.parallel else twist_step_seq
        fn(p, ctx.model.particle_inv_mass, d.verts, d.vptr, t.on, t.d1, t.tan, t.theta, t.omega,
           t.winv, t.reft, t.alpha, t.root, t.bdir, t.bphi, t.damp, t.tp, t.cp, t.dl, ctx.dt)

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
        tw = "" if d.twist is None else f", twist on {int(d.twist.on.sum())} strands"
        return (f"{len(d.vptr) - 1} strands, {len(d.idx)} segments, direct "
                f"{'parallel' if d.parallel else 'sequential'}{tw}")


def _bind_twist(ctx, elements, d) -> TwistData | None:
    """Pack the material frames of the strands of ``d`` (bound from ``elements`` in the same
    order as ``RodConstraint.bind``): twist compliance per row, rotational inertia per segment
    (a solid circular fibre: rho J l = m r^2 / 2, m the segment's mass, lumped from the vertex
    masses: each vertex gives its mass divided by its number of segments), damping and root
    angle per element, frames twist-free (Bishop) on the initial positions."""
    from lokigraph.keys import Keyed

    S = len(d.vptr) - 1
    M = len(d.verts) - S
    on = np.zeros(S, bool)
    winv = np.zeros(M)
    alpha = np.full(M, np.inf)
    root = np.zeros(S)
    damp = np.zeros(M)
    keyed_damp, keyed_root = [], []
    mass = ctx.model.particle_mass
    follow = []  # (strand, global root vertex, body element)
    s = 0
    for e in elements:
        if not solved_directly(e):
            continue
        c = e.get(Rod)
        X = _rest(ctx, e, c)
        GJ = rod_twist_stiffness(c)
        dmp = e.get(Dynamic).damping
        body, pinned = _follow_body_of(ctx, e)
        s_first = s
        for chain in strand_chains(e):
            if len(chain) < 2:
                continue
            if body is not None and GJ > 0 and pinned[chain[0]]:
                follow.append((s, int(chain[0]) + e.vertex_offset, body))
            g0 = int(d.vptr[s]) - s
            m = len(chain) - 1
            sl = slice(g0, g0 + m)
            if GJ > 0:
                on[s] = True
                L = np.linalg.norm(X[chain[1:]] - X[chain[:-1]], axis=1) * c.rest_length_scale
                # row 0 spans the root to the first segment's centre, row k the centres of
                # segments k - 1 and k
                sp = np.concatenate([[0.5 * L[0]], 0.5 * (L[:-1] + L[1:])])
                alpha[sl] = sp / GJ
            deg = np.full(m + 1, 2.0)
            deg[0] = deg[-1] = 1.0
            mv = mass[chain + e.vertex_offset] / deg
            inertia = 0.5 * c.radius ** 2 * (mv[:-1] + mv[1:])
            winv[sl] = np.where(inertia > 0, 1.0 / np.where(inertia > 0, inertia, 1.0), 0.0)
            if isinstance(dmp, Keyed):
                keyed_damp.append((sl, dmp))
            else:
                damp[sl] = float(dmp)
            s += 1
        if isinstance(c.root_twist, Keyed):
            keyed_root.append((slice(s_first, s), c.root_twist))
        else:
            root[s_first:s] = float(c.root_twist)
    if not on.any():
        return None
    d1, tan = np.zeros((M, 3)), np.zeros((M, 3))
    q0 = np.ascontiguousarray(ctx.model.particle_q0, np.float64)
    bishop_frames(q0, d.verts, d.vptr, d1, tan)
    t = TwistData(on, d1, tan, np.zeros(M), np.zeros(M), winv, np.zeros(M), alpha, root, damp,
                  keyed_damp, keyed_root, np.zeros(M), np.zeros(M), np.zeros(M),
                  np.zeros((S, 3)), np.zeros(S))
    _bind_follow_roots(t, follow, q0, d.vptr)
    return t


def _follow_body_of(ctx, e):
    """(body element, pinned mask) of an element whose pins follow a kinematic body
    (``Pins.follow``), else (None, None); problems are reported by the pins behaviors."""
    from lokigraph.components.core import Kinematic, Pins
    from lokigraph.errors import InputError

    pins = e.get(Pins)
    if pins is None or pins.follow is None:
        return None, None
    try:
        body = ctx.scene.element(pins.follow)
        pinned = np.asarray(pins.pinned(e), bool)
    except (KeyError, InputError):
        return None, None
    if (body is e or not body.has(Kinematic) or body.geometry is None
            or not len(body.geometry.triangles)):
        return None, None
    return body, pinned


def _bind_follow_roots(t, follow, q0, vptr):
    """Carried roots take their twist from their body: each is bound to the closest triangle of
    the body (as ``Pins.follow`` binds it), and its initial reference director is stored in
    that triangle's frame (e1 along its first edge, n its normal), so that it turns with the
    body; the body's spin about the root tangent is then added to the root angle."""
    if not follow:
        return
    from ..attachments.pins import bind_follow, triangle_frames

    strands, tris = [], []
    for body in {id(b): b for _, _, b in follow}.values():
        sel = [(s, v) for s, v, b in follow if b is body]
        idx = np.array([v for _, v in sel], np.int64)
        tri, _, _, framed = bind_follow(q0[idx], q0[body.vertex_slice], body.geometry.triangles,
                                        body.vertex_offset)
        strands += [s for (s, _), f in zip(sel, framed) if f]
        tris.append(tri[framed])
    if not strands:
        return
    t.fstrand = np.asarray(strands, np.int64)
    t.ftri = np.ascontiguousarray(np.concatenate(tris), dtype=np.int64)
    e1, e2, nrm = triangle_frames(q0[t.ftri])
    d0 = t.d1[vptr[t.fstrand] - t.fstrand]
    t.fcoef = np.stack([np.einsum("ij,ij->i", d0, x) for x in (e1, e2, nrm)], axis=1)


def material_frames(d):
    """Unit tangent t, material directors m1 = cos(theta) d1 + sin(theta) t x d1 and m2 = t x m1
    per segment (each (M, 3), segments of strand s from ``vptr[s] - s``), as of the last
    substep; None without twist."""
    t = d.twist if d is not None else None
    if t is None:
        return None
    d2 = np.cross(t.tan, t.d1)
    m1 = np.cos(t.theta)[:, None] * t.d1 + np.sin(t.theta)[:, None] * d2
    return t.tan.copy(), m1, np.cross(t.tan, m1)



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


def _rod_hard_k(d, opts):
    """The hard penalty per vertex of the rod rows: the solver's ``hard_stiffness * m / h^2``
    of the heaviest vertex of each strand, for all its vertices. A strand carries the load of
    its heaviest vertex (a weight hung from a light rope: tests/test_implicit_capstan.py)
    through every row; a penalty from each row's own light vertices let that rope stretch by
    up to 130 % under the load (the multipliers lag it) and slide off the drum. Unchanged for
    strands of uniform density (every row already takes its heavier, interior vertex).
    Refilled in place when the solver hands a new array (once per substep)."""
    cache = getattr(d, "_implicit_hk", None)
    if cache is None or cache[1].shape != opts.hard_k.shape:
        lens = np.diff(d.vptr)
        owner = np.repeat(np.arange(len(lens)), lens)  # strand of every entry of d.verts
        starts = np.ascontiguousarray(d.vptr[:-1][lens > 0])
        cache = d._implicit_hk = [None, np.zeros_like(opts.hard_k), owner,
                                  np.cumsum(lens > 0) - 1, starts]
    if cache[0] is not opts.hard_k:
        hk, owner, dense, starts = cache[1], cache[2], cache[3], cache[4]
        hk[:] = opts.hard_k
        if len(starts):
            top = np.maximum.reduceat(opts.hard_k[d.verts], starts)
            hk[d.verts] = top[dense[owner]]
        cache[0] = opts.hard_k
    return cache[1]


def _rod_energy(self, ctx, d, x, grad, hess, opts):
    from ..solvers.implicit.energy import grad_or_dummy, hess_or_dummy
    from .bend import rod_bend_energy
    from .stretch import spring_energy

    e, er, ea, ea2, t, tr, ta = _rod_energy_rows(d)
    gr = grad_or_dummy(grad, opts)
    E = spring_energy(x, e, er, ea, ea2, _rod_multipliers(self, d), _rod_hard_k(d, opts),
                      opts.mode, gr, hess_or_dummy(hess, 0, opts))
    if len(t):
        E += rod_bend_energy(x, t, tr, ta, opts.mode, gr, hess_or_dummy(hess, 1, opts))
    return E


# the implicit energy protocol on the Nucleus constraint type of this effect
def _rod_update_multipliers(self, ctx, d, x, opts):
    from .stretch import spring_update_lam

    e, er, ea, ea2 = _rod_energy_rows(d)[:4]
    spring_update_lam(x, e, er, ea, ea2, _rod_multipliers(self, d), _rod_hard_k(d, opts))


RodConstraint.energy_stencils = _rod_energy_stencils
RodConstraint.energy = _rod_energy
RodConstraint.energy_update_multipliers = _rod_update_multipliers
RodConstraint.energy_multipliers = _rod_multipliers


#: checkpointed arrays of the material frames (TwistData attribute names)
_TWIST_STATE = ("theta", "omega", "d1", "tan", "reft", "damp", "root", "bphi")


def _rod_state_arrays(self, d):
    """Checkpointed run state: the implicit solver's multipliers of the hard stretch rows, and
    the material frames (twist angle and rate, reference director and its tangent, reference
    twist; the keyed damping and root angle as last evaluated)."""
    if d is None:
        return {}
    out = {"implicit_lam": _rod_multipliers(self, d)}
    if d.twist is not None:
        out.update({f"twist_{k}": getattr(d.twist, k) for k in _TWIST_STATE})
    return out


def _rod_load_state_arrays(self, d, arrays):
    if d is not None and "implicit_lam" in arrays:
        _rod_multipliers(self, d)[:] = arrays["implicit_lam"]
    if d is not None and d.twist is not None:
        for k in _TWIST_STATE:
            if f"twist_{k}" in arrays:
                getattr(d.twist, k)[...] = arrays[f"twist_{k}"]


RodConstraint.state_arrays = _rod_state_arrays
RodConstraint.load_state_arrays = _rod_load_state_arrays
