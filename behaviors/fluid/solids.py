"""Moving solid obstacles of a fluid grid: closed triangle meshes rasterized to solid face
fractions every step, and the solid's velocity at the faces.

A kinematic character running through air displaces it: the faces of the MAC grid that the
body covers carry the body's velocity, and the pressure projection (``MacGrid.project``) makes
the rest of the flow go around it (the variational face-fraction form of
:mod:`lokigraph.behaviors.fluid.grid`). Per step:

* **Inside test by ray parity.** Each face of the grid is sampled on an s x s lattice over its
  square (s = 3, as for the static shapes). The sample lattices of the x, y and z faces are
  tensor lattices, so they are columns along z: every triangle of the mesh is visited once, the
  columns inside its projection on the xy plane get the height of the crossing, and a sample is
  inside when an odd number of crossings lie below it (``toggle`` at the first sample above a
  crossing, then a running parity along the column). Cost O(triangles x columns they cover +
  samples), no per-sample search, no sorting. The columns are shifted by a tiny irrational
  fraction of the spacing so that no column passes exactly through a mesh edge or vertex.
  The mesh must be closed (every edge shared by two triangles: checked at bind) and consistent
  (no self-intersection); orientation does not matter.
* **Face fraction** phi_s = the fraction of a face's samples inside.
* **Solid velocity at a face**: the affine least-squares fit ``v(x) = v_c + A (x - c)`` of the
  mesh's vertex velocities over the step (exact for any rigid motion to first order: a
  translation gives A = 0, a rotation its skew matrix), evaluated at the face centre, its
  normal component kept.

Limitations: a thin part of the body (under a third of a cell) can fall between samples and
let the flow through; open meshes are refused (the parity needs a closed surface).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..topology import is_closed

#: shifts of the sample columns [fraction of the spacing]: irrational-looking, so that columns
#: of a regular lattice never pass exactly through the edges of a mesh built on a lattice too
_JITTER = (1.2345671e-6, 2.7182818e-6)


@njit(cache=True)
def _toggle_crossings(verts, tris, x0, dx, nxs, y0, dy, nys, z0, dz, nzs, toggle):
    """For every column (x0 + i dx, y0 + j dy) and every triangle above it, flip
    ``toggle[i, j, k]`` at the first sample k (z0 + k dz) at or above the crossing height."""
    for t in range(tris.shape[0]):
        a = tris[t, 0]
        b = tris[t, 1]
        c = tris[t, 2]
        ax, ay, az = verts[a, 0], verts[a, 1], verts[a, 2]
        bx, by, bz = verts[b, 0], verts[b, 1], verts[b, 2]
        cx, cy, cz = verts[c, 0], verts[c, 1], verts[c, 2]
        det = (bx - ax) * (cy - ay) - (cx - ax) * (by - ay)
        if det == 0.0:
            continue  # parallel to the rays
        i0 = max(0, int(math.ceil((min(ax, bx, cx) - x0) / dx)))
        i1 = min(nxs - 1, int(math.floor((max(ax, bx, cx) - x0) / dx)))
        j0 = max(0, int(math.ceil((min(ay, by, cy) - y0) / dy)))
        j1 = min(nys - 1, int(math.floor((max(ay, by, cy) - y0) / dy)))
        inv = 1.0 / det
        for i in range(i0, i1 + 1):
            px = x0 + i * dx
            for j in range(j0, j1 + 1):
                py = y0 + j * dy
                l1 = ((bx - px) * (cy - py) - (cx - px) * (by - py)) * inv
                if l1 < 0.0:
                    continue
                l2 = ((cx - px) * (ay - py) - (ax - px) * (cy - py)) * inv
                if l2 < 0.0:
                    continue
                l3 = 1.0 - l1 - l2
                if l3 < 0.0:
                    continue
                z = l1 * az + l2 * bz + l3 * cz
                k = int(math.ceil((z - z0) / dz))
                if k < 0:
                    k = 0
                if k < nzs:
                    toggle[i, j, k] ^= 1


@njit(cache=True)
def _fractions(toggle, rx, ry, rz, out):
    """out[I, J, K] = fraction of the samples (I rx .. I rx + rx - 1, ...) inside, where a
    sample is inside when the parity of the toggles at or below it along z is odd; resets
    ``toggle`` to 0 for the next step."""
    inv = 1.0 / (rx * ry * rz)
    out[...] = 0.0
    for i in range(toggle.shape[0]):
        for j in range(toggle.shape[1]):
            par = 0
            for k in range(toggle.shape[2]):
                par ^= toggle[i, j, k]
                toggle[i, j, k] = 0
                if par:
                    out[i // rx, j // ry, k // rz] += inv


class MeshRasterizer:
    """Solid face fractions of closed meshes on one grid (sample lattices and toggles
    allocated once)."""

    def __init__(self, grid, samples: int = 3):
        self.grid = grid
        s = int(samples)
        nx, ny, nz = grid.n
        o, h = grid.origin, grid.h
        self.samples = s
        self.lattices = []
        for ax, q in enumerate((grid.u, grid.v, grid.w)):
            lat = []
            for d in range(3):
                if d == ax:  # the face planes: one sample per face index
                    lat.append((o[d], h[d], q.shape[d], 1))
                else:
                    lat.append((o[d] + 0.5 * h[d] / s, h[d] / s, s * grid.n[d], s))
            (x0, dx, nxs, rx), (y0, dy, nys, ry), (z0, dz, nzs, rz) = lat
            x0 += _JITTER[0] * dx
            y0 += _JITTER[1] * dy
            self.lattices.append(((x0, dx, nxs), (y0, dy, nys), (z0, dz, nzs), (rx, ry, rz),
                                  np.zeros((nxs, nys, nzs), np.uint8)))
        self.phi = np.zeros(grid.face_count)
        self._views = []
        start = 0
        for q in (grid.u, grid.v, grid.w):
            self._views.append(self.phi[start:start + q.size].reshape(q.shape))
            start += q.size
        self.centers = grid.face_centers()
        self.axis = np.repeat(np.arange(3), [grid.u.size, grid.v.size, grid.w.size])

    def fractions(self, verts, tris, out=None):
        """phi_s of every face (flat, the grid's face order) for one closed mesh."""
        for (x0, dx, nxs), (y0, dy, nys), (z0, dz, nzs), (rx, ry, rz), tog in self.lattices:
            _toggle_crossings(verts, tris, x0, dx, nxs, y0, dy, nys, z0, dz, nzs, tog)
        for view, (_, _, _, (rx, ry, rz), tog) in zip(self._views, self.lattices):
            _fractions(tog, rx, ry, rz, view)
        np.minimum(self.phi, 1.0, out=self.phi)  # nine ninths may round above 1
        if out is not None:
            out[:] = self.phi
            return out
        return self.phi


def affine_velocity(x, v):
    """Least-squares ``v(y) = v_c + A (y - c)`` over points ``x`` with velocities ``v``;
    returns (c, v_c, A). Exact for translations; a rotation gives its skew matrix."""
    c = x.mean(axis=0)
    vc = v.mean(axis=0)
    X = x - c
    V = v - vc
    if len(x) < 4:
        return c, vc, np.zeros((3, 3))
    At, *_ = np.linalg.lstsq(X, V, rcond=1e-10)
    return c, vc, At.T


__all__ = ["MeshRasterizer", "affine_velocity", "is_closed"]
