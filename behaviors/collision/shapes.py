"""Collisions with analytic collider shapes (plane, sphere, capsule) as a Nucleus constraint."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit, prange

from lokigraph.behavior import ConstraintBehavior
from lokigraph.components.colliders import ShapeCollider
from lokigraph.components.core import Dynamic

_PLANE, _SPHERE, _CAPSULE = 0, 1, 2


@njit(cache=True, parallel=True)
def project_shapes(p, x, w, kinds, centers, dirs, radii, lengths, mus, active):
    """Push every dynamic vertex out of every shape (unilateral), with Coulomb friction on the
    tangential displacement of the substep (position-based: the tangential motion since the start
    of the substep is reduced by at most mu * penetration depth). Returns nothing; counts contacts
    into active[i] (number of shapes vertex i touched)."""
    n = p.shape[0]
    for i in prange(n):
        if w[i] == 0.0:
            continue
        for s in range(kinds.shape[0]):
            k = kinds[s]
            px, py, pz = p[i, 0], p[i, 1], p[i, 2]
            cx, cy, cz = centers[s, 0], centers[s, 1], centers[s, 2]
            if k == _PLANE:
                nx, ny, nz = dirs[s, 0], dirs[s, 1], dirs[s, 2]
                d = (px - cx) * nx + (py - cy) * ny + (pz - cz) * nz - radii[s]
            else:
                qx, qy, qz = cx, cy, cz
                if k == _CAPSULE:
                    ax, ay, az = dirs[s, 0], dirs[s, 1], dirs[s, 2]
                    t = (px - cx) * ax + (py - cy) * ay + (pz - cz) * az
                    hl = 0.5 * lengths[s]
                    t = min(max(t, -hl), hl)
                    qx, qy, qz = cx + t * ax, cy + t * ay, cz + t * az
                rx, ry, rz = px - qx, py - qy, pz - qz
                r = np.sqrt(rx * rx + ry * ry + rz * rz)
                if r < 1e-15:
                    continue
                nx, ny, nz = rx / r, ry / r, rz / r
                d = r - radii[s]
            if d >= 0.0:
                continue
            active[i] += 1
            # normal correction
            p[i, 0] -= d * nx
            p[i, 1] -= d * ny
            p[i, 2] -= d * nz
            mu = mus[s]
            if mu > 0.0:
                dx = p[i, 0] - x[i, 0]
                dy = p[i, 1] - x[i, 1]
                dz = p[i, 2] - x[i, 2]
                dn = dx * nx + dy * ny + dz * nz
                tx, ty, tz = dx - dn * nx, dy - dn * ny, dz - dn * nz
                tl = np.sqrt(tx * tx + ty * ty + tz * tz)
                if tl > 0.0:
                    red = min(1.0, mu * (-d) / tl)
                    p[i, 0] -= red * tx
                    p[i, 1] -= red * ty
                    p[i, 2] -= red * tz


@dataclass
class _Shapes:
    kinds: np.ndarray
    centers: np.ndarray
    dirs: np.ndarray
    radii: np.ndarray
    lengths: np.ndarray
    mus: np.ndarray
    active: np.ndarray
    lam: None = None


class ShapeCollisionConstraint(ConstraintBehavior):
    """Keeps dynamic vertices outside analytic ShapeCollider elements (order after stretch)."""

    requires = (ShapeCollider,)
    default_importance = 1.0
    default_order = 50

    def bind(self, ctx, elements):
        kinds, centers, dirs, radii, lengths, mus = [], [], [], [], [], []
        for e in elements:
            c = e.get(ShapeCollider)
            kinds.append({"plane": _PLANE, "sphere": _SPHERE, "capsule": _CAPSULE}[c.shape])
            centers.append(c.center)
            d = np.asarray(c.normal if c.shape == "plane" else c.axis, dtype=np.float64)
            nrm = np.linalg.norm(d)
            if nrm == 0:
                ctx.error(e, "ShapeCollider", "normal/axis must be non-zero")
                nrm = 1.0
            dirs.append(d / nrm)
            radii.append((c.radius if c.shape != "plane" else 0.0) + c.thickness)
            lengths.append(c.length)
            mus.append(c.friction)
        if not any(True for e in ctx.scene.elements if e.has(Dynamic)):
            return None
        return _Shapes(np.array(kinds, np.int64), np.array(centers, np.float64),
                       np.array(dirs), np.array(radii), np.array(lengths), np.array(mus),
                       np.zeros(ctx.model.particle_count, np.int64))

    def begin_substep(self, ctx, d):
        d.active[:] = 0

    def project(self, ctx, d, p):
        project_shapes(p, ctx.state.particle_q, ctx.model.particle_inv_mass, d.kinds, d.centers,
                       d.dirs, d.radii, d.lengths, d.mus, d.active)

    def describe(self, d):
        return f"{len(d.kinds)} shapes" if d is not None else ""
