"""Tetrahedron volume: the signed volume of every tet (3-simplices) with compliance V0 / K (bulk
modulus K). Tet edges get their stretch from :mod:`lokigraph.behaviors.materials.stretch`."""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from lokigraph.behavior import ConstraintBehavior
from lokigraph.components.core import Dynamic
from lokigraph.components.materials import Volume

from .. import topology as T
from ..solvers.nucleus.xpbd import _INF, _REL_EPS, _hot, _nudge, _xpbd_step, residual
from .common import Packed, _concat, _rest


# ==============================================================================================
# XPBD kernels
# ==============================================================================================
@_hot
def _tet_volume_one(j, p, w, tets, rest, alpha, lam, inv_h2):
    i0 = tets[j, 0]
    i1 = tets[j, 1]
    i2 = tets[j, 2]
    i3 = tets[j, 3]
    w0 = w[i0]
    w1 = w[i1]
    w2 = w[i2]
    w3 = w[i3]
    if w0 + w1 + w2 + w3 <= 0.0:
        return
    ax = p[i1, 0] - p[i0, 0]
    ay = p[i1, 1] - p[i0, 1]
    az = p[i1, 2] - p[i0, 2]
    bx = p[i2, 0] - p[i0, 0]
    by = p[i2, 1] - p[i0, 1]
    bz = p[i2, 2] - p[i0, 2]
    cx = p[i3, 0] - p[i0, 0]
    cy = p[i3, 1] - p[i0, 1]
    cz = p[i3, 2] - p[i0, 2]
    s = 1.0 / 6.0
    # g1 = (b x c)/6, g2 = (c x a)/6, g3 = (a x b)/6, g0 = -(g1 + g2 + g3)
    g1x = s * (by * cz - bz * cy)
    g1y = s * (bz * cx - bx * cz)
    g1z = s * (bx * cy - by * cx)
    g2x = s * (cy * az - cz * ay)
    g2y = s * (cz * ax - cx * az)
    g2z = s * (cx * ay - cy * ax)
    g3x = s * (ay * bz - az * by)
    g3y = s * (az * bx - ax * bz)
    g3z = s * (ax * by - ay * bx)
    g0x = -(g1x + g2x + g3x)
    g0y = -(g1y + g2y + g3y)
    g0z = -(g1z + g2z + g3z)
    vol = ax * g1x + ay * g1y + az * g1z
    c = vol - rest[j]
    al = alpha[j]
    if not al < _INF:
        return
    den = (w0 * (g0x * g0x + g0y * g0y + g0z * g0z) + w1 * (g1x * g1x + g1y * g1y + g1z * g1z)
           + w2 * (g2x * g2x + g2y * g2y + g2z * g2z) + w3 * (g3x * g3x + g3y * g3y + g3z * g3z))
    # |grad V| ~ face area: a tet whose faces are all (nearly) zero relative to its squared edge
    # lengths has collapsed to a segment or a point; the Newton direction is then meaningless
    gg = (g0x * g0x + g0y * g0y + g0z * g0z + g1x * g1x + g1y * g1y + g1z * g1z
          + g2x * g2x + g2y * g2y + g2z * g2z + g3x * g3x + g3y * g3y + g3z * g3z)
    s2 = _REL_EPS * (ax * ax + ay * ay + az * az + bx * bx + by * by + bz * bz
                     + cx * cx + cy * cy + cz * cz)
    if den <= 0.0 or gg <= s2 * s2:
        return
    dl = _xpbd_step(c, al * inv_h2, den, lam, j)
    _nudge(p, i0, w0, dl, g0x, g0y, g0z)
    _nudge(p, i1, w1, dl, g1x, g1y, g1z)
    _nudge(p, i2, w2, dl, g2x, g2y, g2z)
    _nudge(p, i3, w3, dl, g3x, g3y, g3z)


@njit(cache=True, parallel=True)
def project_tet_volume(p, w, tets, rest, alpha, lam, h, color_ptr):
    """Signed tet volume, coloured parallel sweep.

    tets (m, 4) int64, positively oriented; rest volume [m^3] (m,); alpha compliance
    [m^3/Pa = m^6/J] (m,) (a bulk modulus K [Pa] gives ``alpha = rest / K``); lam (m,):
    ``lam / h**2`` is the pressure [Pa] in the tet.
    ``C = (p1-p0) . ((p2-p0) x (p3-p0)) / 6 - rest``. The edges of a tet get their stretch from
    ``project_stretch`` on ``topology.tet_edges``.
    """
    inv_h2 = 1.0 / (h * h)
    for c in range(color_ptr.shape[0] - 1):
        for j in prange(color_ptr[c], color_ptr[c + 1]):
            _tet_volume_one(j, p, w, tets, rest, alpha, lam, inv_h2)


@njit(cache=True)
def project_tet_volume_seq(p, w, tets, rest, alpha, lam, h, color_ptr):
    """Sequential variant of ``project_tet_volume`` (``color_ptr`` unused)."""
    inv_h2 = 1.0 / (h * h)
    for j in range(tets.shape[0]):
        _tet_volume_one(j, p, w, tets, rest, alpha, lam, inv_h2)


@njit(cache=True)
def tet_volume_values(p, tets, rest):
    """C = signed volume - rest [m^3] for every tet, shape (m,)."""
    out = np.empty(tets.shape[0])
    for j in range(tets.shape[0]):
        i0 = tets[j, 0]
        a = p[tets[j, 1]] - p[i0]
        b = p[tets[j, 2]] - p[i0]
        c = p[tets[j, 3]] - p[i0]
        vol = (a[0] * (b[1] * c[2] - b[2] * c[1]) + a[1] * (b[2] * c[0] - b[0] * c[2])
               + a[2] * (b[0] * c[1] - b[1] * c[0])) / 6.0
        out[j] = vol - rest[j]
    return out


def residual_tet_volume(p, tets, rest):
    """(max |C| [m^3], RMS [m^3]) of the tet volume constraints."""
    return residual(tet_volume_values(p, tets, rest))


def rest_tet_volumes(x, tets):
    """Rest signed tet volumes [m^3] at positions x, shape (m,)."""
    x = np.ascontiguousarray(x, dtype=np.float64)
    return tet_volume_values(x, np.ascontiguousarray(tets, dtype=np.int64), np.zeros(len(tets)))


# ------------------------------------------------------------------ Nucleus constraint behavior


class TetVolumeConstraint(ConstraintBehavior):
    """Volume of every tetrahedron (3-simplices), compliance V0 / K (bulk modulus K)."""

    requires = (Dynamic, Volume)
    default_importance = 0.5
    default_order = 25

    def bind(self, ctx, elements):
        parts = []
        for e in elements:
            c = e.get(Volume)
            g = e.geometry
            if not len(g.tetrahedra):
                continue
            X = _rest(ctx, e, c)
            tt = T.orient_tets(X, g.tetrahedra)
            V0 = rest_tet_volumes(X, tt)
            Kb = c.youngs_modulus / (3.0 * (1.0 - 2.0 * c.poisson_ratio))
            parts.append((tt + e.vertex_offset, V0, np.abs(V0) / Kb))
        cat = _concat(parts)
        return None if cat is None else Packed.build(*cat)

    def project(self, ctx, d, p):
        fn = project_tet_volume_seq if d.sequential else project_tet_volume
        fn(p, ctx.model.particle_inv_mass, d.idx, d.rest, d.alpha, d.lam, ctx.dt, d.color_ptr)

    def residual(self, ctx, d, p):
        return float(residual_tet_volume(p, d.idx, d.rest)[0])

    def describe(self, d):
        return f"{len(d)} tetrahedra" if d is not None else ""


# ==============================================================================================
# Implicit energy (behaviors/solvers/implicit/energy.py has the protocol)
# ==============================================================================================
from ..solvers.implicit.energy import _scalar_term, grad_or_dummy, hess_or_dummy  # noqa: E402


@njit(cache=True)
def tet_volume_energy(x, tets, rest, alpha, mode, grad, hess):
    """Volume energy ``(V - V0)^2 / (2 alpha)`` of every tet (``alpha = V0 / K``, K the bulk
    modulus: ``K (V - V0)^2 / (2 V0)``, the volumetric part of linear elasticity). Gradient
    exact; Hessian Gauss-Newton ``grad V grad V^T / alpha`` (PSD; exact at rest). The deviatoric
    part comes from the tet edge springs of the stretch module; a stable neo-Hookean tet energy
    is not implemented."""
    E = 0.0
    g = np.zeros((4, 3))
    s = 1.0 / 6.0
    for j in range(tets.shape[0]):
        al = alpha[j]
        if not (al > 0.0 and al < _INF):
            continue
        i0 = tets[j, 0]
        a0 = x[tets[j, 1], 0] - x[i0, 0]
        a1 = x[tets[j, 1], 1] - x[i0, 1]
        a2 = x[tets[j, 1], 2] - x[i0, 2]
        b0 = x[tets[j, 2], 0] - x[i0, 0]
        b1 = x[tets[j, 2], 1] - x[i0, 1]
        b2 = x[tets[j, 2], 2] - x[i0, 2]
        c0 = x[tets[j, 3], 0] - x[i0, 0]
        c1 = x[tets[j, 3], 1] - x[i0, 1]
        c2 = x[tets[j, 3], 2] - x[i0, 2]
        g[1, 0] = s * (b1 * c2 - b2 * c1)
        g[1, 1] = s * (b2 * c0 - b0 * c2)
        g[1, 2] = s * (b0 * c1 - b1 * c0)
        g[2, 0] = s * (c1 * a2 - c2 * a1)
        g[2, 1] = s * (c2 * a0 - c0 * a2)
        g[2, 2] = s * (c0 * a1 - c1 * a0)
        g[3, 0] = s * (a1 * b2 - a2 * b1)
        g[3, 1] = s * (a2 * b0 - a0 * b2)
        g[3, 2] = s * (a0 * b1 - a1 * b0)
        for r in range(3):
            g[0, r] = -(g[1, r] + g[2, r] + g[3, r])
        c = a0 * g[1, 0] + a1 * g[1, 1] + a2 * g[1, 2] - rest[j]
        k = 1.0 / al
        E += 0.5 * k * c * c
        _scalar_term(j, tets, 4, g, k, c, k * c, mode, grad, hess)
    return E


def _tet_energy_stencils(self, ctx, d):
    return [d.idx]


def _tet_energy(self, ctx, d, x, grad, hess, opts):
    return tet_volume_energy(x, d.idx, d.rest, d.alpha, opts.mode, grad_or_dummy(grad, opts),
                             hess_or_dummy(hess, 0, opts))


# the implicit energy protocol on the Nucleus constraint type of this effect
TetVolumeConstraint.energy_stencils = _tet_energy_stencils
TetVolumeConstraint.energy = _tet_energy
