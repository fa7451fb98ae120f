"""Bend (Nucleus type 3): the dihedral angle across every interior edge of a surface (with rest
angles and angle dropoff), and the bend of a curve at every vertex (the angle between
consecutive segments, with the type 2 angle kernel of :mod:`lokigraph.behaviors.materials.shear`).
The dihedral kernel also serves the geometric torsion of a curve centre line
(``topology.curve_torsion_quads``)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit, prange

from lokigraph.behavior import ConstraintBehavior
from lokigraph.components.core import Dynamic
from lokigraph.components.materials import DiscreteShell, Rod

from .. import topology as T
from ..solvers.nucleus.xpbd import (_INF, _LEN_EPS, _PI, _REL_EPS, _hot, _nudge, _xpbd_step,
                                    residual, sequential_sweep)
from .common import Packed, _rest
from .rod import solved_directly
from .shear import project_angle, project_angle_seq, residual_angle, rest_angles


# ==============================================================================================
# XPBD kernels: dihedral angle across a hinge (bend of a surface, torsion of a curve)
# ==============================================================================================
@njit(cache=True)
def bend_dropoff_scale(delta, dropoff):
    """Stiffness multiplier of the bend angle dropoff: ``1 + dropoff * |delta| / pi``.

    delta is the current angle minus the rest angle [rad] wrapped to (-pi, pi]; dropoff >= 0
    (0: constant stiffness). The effective compliance is ``alpha / scale``: the stiffness at the
    rest angle is unchanged and grows linearly to ``(1 + dropoff)`` times at a 180 degree fold,
    as Maya's bendAngleDropoff ("at higher values the bend resists more at high angles than when
    the surface is nearly flat").
    """
    return 1.0 + dropoff * abs(delta) / _PI


@njit(cache=True)
def _wrap_angle(d):
    if d > _PI:
        d -= 2.0 * _PI
    elif d <= -_PI:
        d += 2.0 * _PI
    return d


@_hot
def _hinge(p, i0, i1, i2, i3):
    """Signed dihedral angle of the hinge (i0, i1) with wings i2, i3 and its gradients.

    Returns ``(status, theta, g0x, g0y, g0z, g1x, ..., g3z)``: status 0 = hinge edge too
    short (nothing valid), 1 = a wing of (almost) zero height (theta valid, no gradient
    direction), 2 = theta and the gradients valid (Bridson et al. 2003: g2 = -|e| NA / |NA|^2,
    g3 = -|e| NB / |NB|^2, g1 = -(s2 g2 + s3 g3), g0 = -((1 - s2) g2 + (1 - s3) g3), s the
    projection on the hinge). Shared by the Nucleus projection and the implicit energy."""
    ex = p[i1, 0] - p[i0, 0]
    ey = p[i1, 1] - p[i0, 1]
    ez = p[i1, 2] - p[i0, 2]
    ax = p[i2, 0] - p[i0, 0]
    ay = p[i2, 1] - p[i0, 1]
    az = p[i2, 2] - p[i0, 2]
    bx = p[i3, 0] - p[i0, 0]
    by = p[i3, 1] - p[i0, 1]
    bz = p[i3, 2] - p[i0, 2]
    e2 = ex * ex + ey * ey + ez * ez
    if e2 < _LEN_EPS * _LEN_EPS:
        return 0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    el = math.sqrt(e2)
    # NA = e x a (normal of (i0, i1, i2)), NB = b x e (normal of (i1, i0, i3))
    nax = ey * az - ez * ay
    nay = ez * ax - ex * az
    naz = ex * ay - ey * ax
    nbx = by * ez - bz * ey
    nby = bz * ex - bx * ez
    nbz = bx * ey - by * ex
    na2 = nax * nax + nay * nay + naz * naz
    nb2 = nbx * nbx + nby * nby + nbz * nbz
    lim = _REL_EPS * e2
    # signed angle: atan2((NA x NB) . e_hat, NA . NB)
    cx = nay * nbz - naz * nby
    cy = naz * nbx - nax * nbz
    cz = nax * nby - nay * nbx
    # both atan2 arguments scaled by |e|: saves a division
    theta = math.atan2(cx * ex + cy * ey + cz * ez, el * (nax * nbx + nay * nby + naz * nbz))
    if na2 <= lim * lim or nb2 <= lim * lim:
        return 1, theta, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    f2 = -el / na2
    f3 = -el / nb2
    g2x = f2 * nax
    g2y = f2 * nay
    g2z = f2 * naz
    g3x = f3 * nbx
    g3y = f3 * nby
    g3z = f3 * nbz
    ie2 = 1.0 / e2
    s2 = (ax * ex + ay * ey + az * ez) * ie2
    s3 = (bx * ex + by * ey + bz * ez) * ie2
    g1x = -(s2 * g2x + s3 * g3x)
    g1y = -(s2 * g2y + s3 * g3y)
    g1z = -(s2 * g2z + s3 * g3z)
    g0x = -(g2x + g3x) - g1x
    g0y = -(g2y + g3y) - g1y
    g0z = -(g2z + g3z) - g1z
    return 2, theta, g0x, g0y, g0z, g1x, g1y, g1z, g2x, g2y, g2z, g3x, g3y, g3z


@_hot
def _dihedral_one(j, p, w, quads, rest, alpha, dropoff, lam, inv_h2):
    i0 = quads[j, 0]
    i1 = quads[j, 1]
    i2 = quads[j, 2]
    i3 = quads[j, 3]
    w0 = w[i0]
    w1 = w[i1]
    w2 = w[i2]
    w3 = w[i3]
    if w0 + w1 + w2 + w3 <= 0.0:
        return
    al = alpha[j]
    if not al < _INF:
        return
    (st, theta, g0x, g0y, g0z, g1x, g1y, g1z, g2x, g2y, g2z, g3x, g3y,
     g3z) = _hinge(p, i0, i1, i2, i3)
    if st < 2:
        return  # a short hinge or a wing of (almost) zero height
    c = _wrap_angle(theta - rest[j])
    al = al / bend_dropoff_scale(c, dropoff[j])
    den = (w0 * (g0x * g0x + g0y * g0y + g0z * g0z) + w1 * (g1x * g1x + g1y * g1y + g1z * g1z)
           + w2 * (g2x * g2x + g2y * g2y + g2z * g2z) + w3 * (g3x * g3x + g3y * g3y + g3z * g3z))
    if den <= 0.0:
        return
    dl = _xpbd_step(c, al * inv_h2, den, lam, j)
    _nudge(p, i0, w0, dl, g0x, g0y, g0z)
    _nudge(p, i1, w1, dl, g1x, g1y, g1z)
    _nudge(p, i2, w2, dl, g2x, g2y, g2z)
    _nudge(p, i3, w3, dl, g3x, g3y, g3z)


@njit(cache=True, parallel=True)
def project_dihedral(p, w, quads, rest, alpha, dropoff, lam, h, color_ptr):
    """Type 3 bend (dihedral angle), coloured parallel sweep.

    quads (m, 4) int64 rows ``(i, j, k, l)``: hinge ``(i, j)``, opposite vertices k and l (see
    ``topology.bend_quads``); rest signed dihedral [rad] (m,) (``rest_dihedrals``); alpha
    compliance [1/(N m)] (m,); dropoff (m,) >= 0, see ``bend_dropoff_scale``; lam (m,).

    ``theta = atan2((N_A x N_B) . e_hat, N_A . N_B)`` with ``e = p_j - p_i``,
    ``N_A = e x (p_k - p_i)``, ``N_B = (p_l - p_i) x e``; theta is 0 for a flat hinge and lies in
    (-pi, pi]; ``C = wrap(theta - rest)``. This is Nucleus's ``acos(n_A . n_B) - theta_0`` made
    signed, so that the Newton direction is defined at the flat rest state. Sign: theta < 0 when
    the wings fold towards the side N_A points to (a valley seen from there), > 0 for a ridge.
    The effective compliance is ``alpha / bend_dropoff_scale(C, dropoff)``.
    """
    inv_h2 = 1.0 / (h * h)
    for c in range(color_ptr.shape[0] - 1):
        for j in prange(color_ptr[c], color_ptr[c + 1]):
            _dihedral_one(j, p, w, quads, rest, alpha, dropoff, lam, inv_h2)


@njit(cache=True)
def project_dihedral_seq(p, w, quads, rest, alpha, dropoff, lam, h, color_ptr):
    """Sequential variant of ``project_dihedral`` (``color_ptr`` unused)."""
    inv_h2 = 1.0 / (h * h)
    for j in range(quads.shape[0]):
        _dihedral_one(j, p, w, quads, rest, alpha, dropoff, lam, inv_h2)


@_hot
def _signed_dihedral(p, i0, i1, i2, i3):
    ex = p[i1, 0] - p[i0, 0]
    ey = p[i1, 1] - p[i0, 1]
    ez = p[i1, 2] - p[i0, 2]
    ax = p[i2, 0] - p[i0, 0]
    ay = p[i2, 1] - p[i0, 1]
    az = p[i2, 2] - p[i0, 2]
    bx = p[i3, 0] - p[i0, 0]
    by = p[i3, 1] - p[i0, 1]
    bz = p[i3, 2] - p[i0, 2]
    el = math.sqrt(ex * ex + ey * ey + ez * ez)
    if el < _LEN_EPS:
        return 0.0
    nax = ey * az - ez * ay
    nay = ez * ax - ex * az
    naz = ex * ay - ey * ax
    nbx = by * ez - bz * ey
    nby = bz * ex - bx * ez
    nbz = bx * ey - by * ex
    cx = nay * nbz - naz * nby
    cy = naz * nbx - nax * nbz
    cz = nax * nby - nay * nbx
    return math.atan2((cx * ex + cy * ey + cz * ez) / el, nax * nbx + nay * nby + naz * nbz)


@njit(cache=True)
def dihedral_values(p, quads, rest):
    """C = wrap(signed dihedral - rest) [rad] in (-pi, pi] for every quad, shape (m,)."""
    out = np.empty(quads.shape[0])
    for j in range(quads.shape[0]):
        th = _signed_dihedral(p, quads[j, 0], quads[j, 1], quads[j, 2], quads[j, 3])
        out[j] = _wrap_angle(th - rest[j])
    return out


def residual_dihedral(p, quads, rest):
    """(max |C| [rad], RMS [rad]) of the dihedral constraints."""
    return residual(dihedral_values(p, quads, rest))


def rest_dihedrals(x, quads):
    """Rest signed dihedral angles [rad] at positions x, shape (m,)."""
    x = np.ascontiguousarray(x, dtype=np.float64)
    return dihedral_values(x, np.ascontiguousarray(quads, dtype=np.int64),
                           np.zeros(len(quads)))


# ------------------------------------------------------------------ Nucleus constraint behavior


def _cross_norm(a, b):
    """|a x b| row by row, shape (m,): np.linalg.norm(np.cross(a, b), axis=1) with the same
    floating-point operations (bitwise equal), without np.cross's temporaries."""
    cx = a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1]
    cy = a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2]
    cz = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    return np.sqrt(cx * cx + cy * cy + cz * cz)


@dataclass
class _Multi:
    parts: dict
    lam: None = None


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
                qrest.append(rest_dihedrals(X, q))
                qa.append(1.0 / k)
                qdrop.append(np.full(len(q), c.bend_angle_dropoff))
            elif e.has(Rod) and len(g.edges) and not solved_directly(e):
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
                trest.append(rest_angles(X, apex))
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
            fn = project_dihedral_seq if sequential_sweep(q.sequential) else project_dihedral
            fn(p, w, q.idx, q.rest, q.alpha, q.alpha2, q.lam, ctx.dt, q.color_ptr)
        c = d.parts.get("curves")
        if c is not None:
            fn = project_angle_seq if sequential_sweep(c.sequential) else project_angle
            fn(p, w, c.idx, c.rest, c.alpha, c.lam, ctx.dt, c.color_ptr)

    def residual(self, ctx, d, p):
        r = 0.0
        if "quads" in d.parts:
            q = d.parts["quads"]
            r = max(r, float(residual_dihedral(p, q.idx, q.rest)[0]))
        if "curves" in d.parts:
            c = d.parts["curves"]
            r = max(r, float(residual_angle(p, c.idx, c.rest)[0]))
        return r

    def describe(self, d):
        return ", ".join(f"{len(v)} {k}" for k, v in d.parts.items()) if d else ""


# ==============================================================================================
# Implicit energy (behaviors/solvers/implicit/energy.py has the protocol)
# ==============================================================================================
from ..solvers.implicit.energy import _scalar_term, grad_or_dummy, hess_or_dummy  # noqa: E402


@njit(cache=True)
def dihedral_energy(x, quads, rest, alpha, dropoff, mode, grad, hess):
    """Hinge bending energy of quads ``(i, j, k, l)`` (discrete shells): with
    ``C = wrap(theta - rest)`` (the signed dihedral of ``project_dihedral``), ``k = 1 / alpha``
    and the angle dropoff ``d``, ``E = k (C^2 / 2 + d |C|^3 / (3 pi))``, whose stiffness
    ``dE/dC / C = k (1 + d |C| / pi)`` is the Nucleus kernel's ``bend_dropoff_scale``. Gradient
    exact (Bridson et al. 2003 angle gradients); Hessian Gauss-Newton
    ``k (1 + 2 d |C| / pi) grad theta grad theta^T`` (PSD; exact at the rest angle)."""
    E = 0.0
    g = np.zeros((4, 3))
    for j in range(quads.shape[0]):
        al = alpha[j]
        if not (al > 0.0 and al < _INF):
            continue
        kk = 1.0 / al
        i0 = quads[j, 0]
        i1 = quads[j, 1]
        i2 = quads[j, 2]
        i3 = quads[j, 3]
        (st, theta, g0x, g0y, g0z, g1x, g1y, g1z, g2x, g2y, g2z, g3x, g3y,
         g3z) = _hinge(x, i0, i1, i2, i3)
        if st == 0:
            continue
        c = _wrap_angle(theta - rest[j])
        d = dropoff[j]
        ac = abs(c)
        E += kk * (0.5 * c * c + d * ac * ac * ac / (3.0 * _PI))
        if st == 1:
            continue  # a wing of (almost) zero height: no direction
        g[0, 0], g[0, 1], g[0, 2] = g0x, g0y, g0z
        g[1, 0], g[1, 1], g[1, 2] = g1x, g1y, g1z
        g[2, 0], g[2, 1], g[2, 2] = g2x, g2y, g2z
        g[3, 0], g[3, 1], g[3, 2] = g3x, g3y, g3z
        _scalar_term(j, quads, 4, g, kk * (1.0 + 2.0 * d * ac / _PI), c,
                     kk * (c + d * c * ac / _PI), mode, grad, hess)
    return E


@_hot
def _skew_col(e, r, c):
    """Entry (r, c) of the cross-product matrix [e]x (so that [e]x y = e x y)."""
    if r == c:
        return 0.0
    if r == 0:
        return -e[2] if c == 1 else e[1]
    if r == 1:
        return e[2] if c == 0 else -e[0]
    return -e[1] if c == 0 else e[0]


@njit(cache=True)
def rod_bend_energy(x, tri, rest, alpha, mode, grad, hess):
    """Bending energy of a curve at its interior vertices, rows ``(apex o, a, b)`` (the Nucleus
    curve rows; ``rest`` the rest apex angle, ``alpha = l_avg / EI``), in terms of the curvature
    binormal of discrete elastic rods (Bergou et al. 2008)
    ``kb = 2 e0 x e1 / (|e0| |e1| + e0 . e1)``, ``e0 = o - a``, ``e1 = b - o``, ``|kb| =
    2 tan(phi / 2)`` with phi the turning angle (pi - apex angle):

    - straight at rest: ``E = k |kb|^2 / 2`` (smooth through the straight state, where the
      angle has no gradient direction), Hessian Gauss-Newton ``k J^T J`` (J = d kb / dx, rank
      two: both bending directions; exact at rest);
    - curved at rest: ``E = k (|kb| - |kb0|)^2 / 2``, Hessian Gauss-Newton.

    ``k = EI / l_avg``; for small angles both are the Nucleus curve energy
    ``EI / l_avg (phi - phi0)^2 / 2`` (|kb| = phi (1 + phi^2 / 12 + ...)).
    """
    E = 0.0
    J = np.zeros((3, 3, 3))  # J[v] (3 kb components x 3 coordinates) for v = o, a, b
    e0 = np.zeros(3)
    e1 = np.zeros(3)
    kb = np.zeros(3)
    gs = np.zeros((3, 3))
    for j in range(tri.shape[0]):
        al = alpha[j]
        if not (al > 0.0 and al < _INF):
            continue
        k = 1.0 / al
        o = tri[j, 0]
        a = tri[j, 1]
        b = tri[j, 2]
        for r in range(3):
            e0[r] = x[o, r] - x[a, r]
            e1[r] = x[b, r] - x[o, r]
        l0 = math.sqrt(e0[0] ** 2 + e0[1] ** 2 + e0[2] ** 2)
        l1 = math.sqrt(e1[0] ** 2 + e1[1] ** 2 + e1[2] ** 2)
        if l0 < _LEN_EPS or l1 < _LEN_EPS:
            continue
        chi = l0 * l1 + e0[0] * e1[0] + e0[1] * e1[1] + e0[2] * e1[2]
        if chi < _REL_EPS * l0 * l1:
            continue  # folded back on itself: kb unbounded
        kb[0] = 2.0 * (e0[1] * e1[2] - e0[2] * e1[1]) / chi
        kb[1] = 2.0 * (e0[2] * e1[0] - e0[0] * e1[2]) / chi
        kb[2] = 2.0 * (e0[0] * e1[1] - e0[1] * e1[0]) / chi
        phi0 = _PI - rest[j]
        if phi0 > _PI - 1e-3:
            phi0 = _PI - 1e-3
        kb0 = 2.0 * math.tan(0.5 * phi0) if phi0 > 1e-9 else 0.0
        nkb = math.sqrt(kb[0] ** 2 + kb[1] ** 2 + kb[2] ** 2)
        if kb0 == 0.0:
            E += 0.5 * k * nkb * nkb
        else:
            E += 0.5 * k * (nkb - kb0) ** 2
        if mode < 1:
            continue
        # D0 = d kb / d e0, D1 = d kb / d e1 (3 x 3); J_a = -D0, J_o = D0 - D1, J_b = D1
        for r in range(3):
            for c in range(3):
                d0 = (-2.0 * _skew_col(e1, r, c) - kb[r] * (l1 * e0[c] / l0 + e1[c])) / chi
                d1 = (2.0 * _skew_col(e0, r, c) - kb[r] * (l0 * e1[c] / l1 + e0[c])) / chi
                J[0, r, c] = d0 - d1
                J[1, r, c] = -d0
                J[2, r, c] = d1
        if kb0 == 0.0:
            for v in range(3):
                i = tri[j, v]
                for c in range(3):
                    s = 0.0
                    for r in range(3):
                        s += J[v, r, c] * kb[r]
                    grad[i, c] += k * s
            if mode >= 2:
                for va in range(3):
                    for vb in range(3):
                        for r in range(3):
                            for s in range(3):
                                t = 0.0
                                for q in range(3):
                                    t += J[va, q, r] * J[vb, q, s]
                                hess[j, va, vb, r, s] = k * t
        else:
            if nkb < _REL_EPS:
                continue  # straight now, curved at rest: d|kb| has no direction
            for v in range(3):
                for c in range(3):
                    s = 0.0
                    for r in range(3):
                        s += J[v, r, c] * kb[r]
                    gs[v, c] = s / nkb
            cc = nkb - kb0
            _scalar_term(j, tri, 3, gs, k, cc, k * cc, mode, grad, hess)
    return E


def _bend_energy_stencils(self, ctx, d):
    return [d.parts[key].idx for key in ("quads", "curves") if key in d.parts]


def hinge_alpha_capped(x, quads, alpha, hard_k):
    """Hinge compliances for the implicit energy with the stiffness capped at the hard penalty.

    A hinge's stiffness in position space is ``|grad theta|^2 / alpha`` (discrete shells:
    ``alpha = (A1 + A2) / (3 D L^2)``, ``|grad theta| ~ 1 / wing height``), which grows without
    bound on a sliver wing (``1 / h^4``: 1e36 N/m for a 1e-9 m high wing), far beyond anything
    Newton + CG can carry. A hinge stiffer than the hard penalty of its vertices (the largest
    ``opts.hard_k``, as hard stretch rows use) is given exactly that penalty:
    ``alpha' = max(alpha, |grad theta|^2 / hard_k)`` with the gradient at ``x`` (the solver
    calls this once, at the first substep), a wing of zero height is off. Ordinary hinges are
    far below the cap (a 16x16 1 m cloth of E = 1e9 Pa, 0.5 mm thick: 15 N/m against 1.2e4
    N/m), so their energy is unchanged."""
    q0, q1, q2, q3 = (x[quads[:, i]] for i in range(4))
    e = q1 - q0
    a = q2 - q0
    b = q3 - q0
    e2 = np.einsum("ij,ij->i", e, e)
    na = np.cross(e, a)
    nb = np.cross(b, e)
    na2 = np.einsum("ij,ij->i", na, na)
    nb2 = np.einsum("ij,ij->i", nb, nb)
    with np.errstate(divide="ignore", invalid="ignore"):
        el = np.sqrt(e2)
        g2 = -(el / na2)[:, None] * na
        g3 = -(el / nb2)[:, None] * nb
        s2 = (np.einsum("ij,ij->i", a, e) / e2)[:, None]
        s3 = (np.einsum("ij,ij->i", b, e) / e2)[:, None]
        g1 = -(s2 * g2 + s3 * g3)
        g0 = -(g2 + g3) - g1
        gsq = sum(np.einsum("ij,ij->i", g, g) for g in (g0, g1, g2, g3))
    gsq = np.where(np.isfinite(gsq), gsq, np.inf)
    K = hard_k[quads].max(axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        cap = np.where(K > 0.0, gsq / K, 0.0)
    return np.ascontiguousarray(np.maximum(alpha, np.where(np.isnan(cap), np.inf, cap)))


def _bend_energy(self, ctx, d, x, grad, hess, opts):
    E = 0.0
    s = 0
    gr = grad_or_dummy(grad, opts)
    q = d.parts.get("quads")
    if q is not None:
        qa = getattr(d, "implicit_alpha", None)
        if qa is None:  # once, at the first substep (see hinge_alpha_capped)
            qa = d.implicit_alpha = hinge_alpha_capped(x, q.idx, q.alpha, opts.hard_k)
        E += dihedral_energy(x, q.idx, q.rest, qa, q.alpha2, opts.mode, gr,
                             hess_or_dummy(hess, s, opts))
        s += 1
    c = d.parts.get("curves")
    if c is not None:
        E += rod_bend_energy(x, c.idx, c.rest, c.alpha, opts.mode, gr,
                             hess_or_dummy(hess, s, opts))
    return E


# the implicit energy protocol on the Nucleus constraint type of this effect
BendConstraint.energy_stencils = _bend_energy_stencils
BendConstraint.energy = _bend_energy
