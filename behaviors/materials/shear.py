"""Shear (Nucleus type 2): the corner angles of every triangle keep their rest value.

The angle kernel (``C = angle(p_a - p_o, p_b - p_o) - gamma``) is also the bend of a curve at a
vertex (:mod:`lokigraph.behaviors.materials.bend` uses it for rods)."""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from lokigraph.behavior import ConstraintBehavior
from lokigraph.components.core import Dynamic
from lokigraph.components.materials import DiscreteShell
from lokigraph.geometry import triangle_areas

from .. import topology as T
from ..solvers.nucleus.xpbd import _INF, _LEN_EPS, _REL_EPS, _hot, _nudge, _xpbd_step, residual
from .common import Packed, _concat, _rest


# ==============================================================================================
# XPBD kernels: angle at a vertex (shear of a triangle corner, bend of a curve)
# ==============================================================================================
@_hot
def _apex(p, o, a, b):
    """Angle at the apex o between o->a and o->b and its gradients.

    Returns ``(status, theta, gax, gay, gaz, gbx, gby, gbz, gox, goy, goz)``: status 0 = an
    arm too short (nothing valid), 1 = collinear arms (theta valid, the direction of its change
    undefined), 2 = theta and the gradients valid. With unit u, v: d theta / d p_a =
    -(v - cs u) / (|e_a| sn), d theta / d p_b = -(u - cs v) / (|e_b| sn) (|v - cs u| = sn),
    d theta / d p_o = -(both). Shared by the corner shear and curve bend projections, the
    direct rod solve and the implicit angle energy."""
    ux = p[a, 0] - p[o, 0]
    uy = p[a, 1] - p[o, 1]
    uz = p[a, 2] - p[o, 2]
    vx = p[b, 0] - p[o, 0]
    vy = p[b, 1] - p[o, 1]
    vz = p[b, 2] - p[o, 2]
    lu2 = ux * ux + uy * uy + uz * uz
    lv2 = vx * vx + vy * vy + vz * vz
    if lu2 < _LEN_EPS * _LEN_EPS or lv2 < _LEN_EPS * _LEN_EPS:
        return 0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    iu = 1.0 / math.sqrt(lu2)
    iv = 1.0 / math.sqrt(lv2)
    ux *= iu
    uy *= iu
    uz *= iu
    vx *= iv
    vy *= iv
    vz *= iv
    cs = ux * vx + uy * vy + uz * vz
    cxx = uy * vz - uz * vy
    cxy = uz * vx - ux * vz
    cxz = ux * vy - uy * vx
    sn = math.sqrt(cxx * cxx + cxy * cxy + cxz * cxz)
    theta = math.atan2(sn, cs)
    if sn < _REL_EPS:
        return 1, theta, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    ga = -iu / sn
    gb = -iv / sn
    gax = ga * (vx - cs * ux)
    gay = ga * (vy - cs * uy)
    gaz = ga * (vz - cs * uz)
    gbx = gb * (ux - cs * vx)
    gby = gb * (uy - cs * vy)
    gbz = gb * (uz - cs * vz)
    return 2, theta, gax, gay, gaz, gbx, gby, gbz, -gax - gbx, -gay - gby, -gaz - gbz


@_hot
def _angle_one(j, p, w, tri, rest, alpha, lam, inv_h2):
    o = tri[j, 0]
    a = tri[j, 1]
    b = tri[j, 2]
    wo = w[o]
    wa = w[a]
    wb = w[b]
    if wo + wa + wb <= 0.0:
        return
    al = alpha[j]
    if not al < _INF:
        return
    st, theta, gax, gay, gaz, gbx, gby, gbz, gox, goy, goz = _apex(p, o, a, b)
    if st < 2:
        return  # a short arm, or collinear: the direction of the angle change is undefined
    c = theta - rest[j]
    den = (wa * (gax * gax + gay * gay + gaz * gaz) + wb * (gbx * gbx + gby * gby + gbz * gbz)
           + wo * (gox * gox + goy * goy + goz * goz))
    if den <= 0.0:
        return
    dl = _xpbd_step(c, al * inv_h2, den, lam, j)
    _nudge(p, o, wo, dl, gox, goy, goz)
    _nudge(p, a, wa, dl, gax, gay, gaz)
    _nudge(p, b, wb, dl, gbx, gby, gbz)


@njit(cache=True, parallel=True)
def project_angle(p, w, triplets, rest, alpha, lam, h, color_ptr):
    """Type 2 angle constraint, coloured parallel sweep.

    triplets (m, 3) int64 rows ``(apex, a, b)``; rest angle gamma [rad] (m,) in [0, pi];
    alpha compliance [rad^2/J = 1/(N m)] (m,); lam (m,). ``C = angle(a - apex, b - apex) - gamma``
    with the angle in [0, pi] (Nucleus: ``acos(d_ij . d_ik) - gamma_ijk``, evaluated as
    ``atan2(|u x v|, u . v)`` for accuracy near 0 and pi).
    """
    inv_h2 = 1.0 / (h * h)
    for c in range(color_ptr.shape[0] - 1):
        for j in prange(color_ptr[c], color_ptr[c + 1]):
            _angle_one(j, p, w, triplets, rest, alpha, lam, inv_h2)


@njit(cache=True)
def project_angle_seq(p, w, triplets, rest, alpha, lam, h, color_ptr):
    """Sequential variant of ``project_angle`` (``color_ptr`` unused)."""
    inv_h2 = 1.0 / (h * h)
    for j in range(triplets.shape[0]):
        _angle_one(j, p, w, triplets, rest, alpha, lam, inv_h2)


@_hot
def _corner_angle(p, o, a, b):
    ux = p[a, 0] - p[o, 0]
    uy = p[a, 1] - p[o, 1]
    uz = p[a, 2] - p[o, 2]
    vx = p[b, 0] - p[o, 0]
    vy = p[b, 1] - p[o, 1]
    vz = p[b, 2] - p[o, 2]
    cx = uy * vz - uz * vy
    cy = uz * vx - ux * vz
    cz = ux * vy - uy * vx
    return math.atan2(math.sqrt(cx * cx + cy * cy + cz * cz), ux * vx + uy * vy + uz * vz)


@njit(cache=True)
def angle_values(p, triplets, rest):
    """C = angle at apex - rest [rad] for every triplet, shape (m,)."""
    out = np.empty(triplets.shape[0])
    for j in range(triplets.shape[0]):
        out[j] = _corner_angle(p, triplets[j, 0], triplets[j, 1], triplets[j, 2]) - rest[j]
    return out


def residual_angle(p, triplets, rest):
    """(max |C| [rad], RMS [rad]) of the angle constraints."""
    return residual(angle_values(p, triplets, rest))


def rest_angles(x, triplets):
    """Rest corner angles [rad] at positions x, shape (m,)."""
    x = np.ascontiguousarray(x, dtype=np.float64)
    return angle_values(x, np.ascontiguousarray(triplets, dtype=np.int64),
                        np.zeros(len(triplets)))


# ------------------------------------------------------------------ Nucleus constraint behavior


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
            rest = rest_angles(X, trip)
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
        fn = project_angle_seq if d.sequential else project_angle
        fn(p, ctx.model.particle_inv_mass, d.idx, d.rest, d.alpha, d.lam, ctx.dt, d.color_ptr)

    def residual(self, ctx, d, p):
        return float(residual_angle(p, d.idx, d.rest)[0])

    def describe(self, d):
        return f"{len(d)} corners" if d is not None else "no shear stiffness: nothing bound"


# ==============================================================================================
# Implicit energy (behaviors/solvers/implicit/energy.py has the protocol)
# ==============================================================================================
from ..solvers.implicit.energy import _scalar_term, grad_or_dummy, hess_or_dummy  # noqa: E402


@njit(cache=True)
def angle_energy(x, tri, rest, alpha, mode, grad, hess):
    """Energy ``(theta - gamma)^2 / (2 alpha)`` of angle rows ``(apex, a, b)`` (the shear of a
    triangle corner). Gradient exact (the Nucleus kernel's angle gradient); Hessian blocks
    Gauss-Newton ``k grad theta grad theta^T`` (PSD; exact at the rest angle, it leaves out
    ``k C d2 theta``). Collinear corners (direction undefined) add energy only."""
    E = 0.0
    g = np.zeros((3, 3))
    for j in range(tri.shape[0]):
        al = alpha[j]
        if not (al > 0.0 and al < _INF):
            continue
        k = 1.0 / al
        o = tri[j, 0]
        a = tri[j, 1]
        b = tri[j, 2]
        st, theta, gax, gay, gaz, gbx, gby, gbz, gox, goy, goz = _apex(x, o, a, b)
        if st == 0:
            continue
        c = theta - rest[j]
        E += 0.5 * k * c * c
        if st == 1:
            continue
        g[0, 0], g[0, 1], g[0, 2] = gox, goy, goz
        g[1, 0], g[1, 1], g[1, 2] = gax, gay, gaz
        g[2, 0], g[2, 1], g[2, 2] = gbx, gby, gbz
        _scalar_term(j, tri, 3, g, k, c, k * c, mode, grad, hess)
    return E


def _shear_energy_stencils(self, ctx, d):
    return [d.idx]


def _shear_energy(self, ctx, d, x, grad, hess, opts):
    return angle_energy(x, d.idx, d.rest, d.alpha, opts.mode, grad_or_dummy(grad, opts),
                        hess_or_dummy(hess, 0, opts))


# the implicit energy protocol on the Nucleus constraint type of this effect
ShearConstraint.energy_stencils = _shear_energy_stencils
ShearConstraint.energy = _shear_energy
