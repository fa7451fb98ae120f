"""Shape stiffness of the compliant collider surface in the implicit solve (issue #11).

With ``compliant_kinematics: energy`` the compliant collider vertices are momentum-free unknowns
held by their own goal spring ``K/2 |x - x_anim|^2`` (``K = 1 / (inverse mass h^2)``, ~7 N/m at
the knee's painted 2e4). Held only by it, each vertex recedes on its own and the compliant
surface crumples (graphs/bench/implicit_compliant_diag.py). ``compliant_shape_stiffness`` ``s``
couples neighbours: over the collider mesh's edges whose two vertices are compliant unknowns,

    E = sum_edges k_e / 2 |u_a - u_b|^2,   u = x - x_anim,   k_e = s (K_a + K_b) / 2,

a Laplacian smoothing of the recession (a dent spreads over about sqrt(s) edges instead of one
vertex). Gradient ``k_e (u_a - u_b)`` / ``-k_e (u_a - u_b)``, exact Hessian ``k_e I`` on the
two diagonal blocks and ``-k_e I`` on the two off-diagonal blocks (PSD per edge).

Kernels: the edge list (``compliant_edges``, once at the first substep) and the energy
(``shape_energy``).
"""

from __future__ import annotations

import numpy as np
from numba import njit


def compliant_edges(tris: np.ndarray, compliant: np.ndarray) -> np.ndarray:
    """The unique edges (int64 (m, 2), a < b) of the triangles ``tris`` (global vertex indices)
    whose two vertices are compliant unknowns (``compliant`` bool per vertex)."""
    if len(tris) == 0:
        return np.zeros((0, 2), np.int64)
    e = np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]]).astype(np.int64)
    e.sort(axis=1)
    e = np.unique(e, axis=0)
    keep = compliant[e[:, 0]] & compliant[e[:, 1]] & (e[:, 0] != e[:, 1])
    return np.ascontiguousarray(e[keep])


@njit(cache=True)
def shape_energy(x, xt, edges, kbar, s, mode, grad, data, bmap):
    """``sum_e s kbar_e / 2 |u_a - u_b|^2`` with ``u = x - xt`` (``xt`` the animated pose at the
    compliant vertices) over ``edges`` (m, 2); ``kbar`` (m,) the edges' mean goal spring [N/m].
    The gradient into ``grad`` (mode >= 1); with mode 2 the exact Hessian blocks straight into
    the BSR ``data`` through ``bmap`` ((m, 2, 2) block map of the edge stencil). Returns the
    energy [J]."""
    E = 0.0
    for j in range(edges.shape[0]):
        a = edges[j, 0]
        b = edges[j, 1]
        k = s * kbar[j]
        d0 = (x[a, 0] - xt[a, 0]) - (x[b, 0] - xt[b, 0])
        d1 = (x[a, 1] - xt[a, 1]) - (x[b, 1] - xt[b, 1])
        d2 = (x[a, 2] - xt[a, 2]) - (x[b, 2] - xt[b, 2])
        E += 0.5 * k * (d0 * d0 + d1 * d1 + d2 * d2)
        if mode >= 1:
            grad[a, 0] += k * d0
            grad[a, 1] += k * d1
            grad[a, 2] += k * d2
            grad[b, 0] -= k * d0
            grad[b, 1] -= k * d1
            grad[b, 2] -= k * d2
        if mode >= 2:
            for r in range(3):
                data[bmap[j, 0, 0], r, r] += k
                data[bmap[j, 1, 1], r, r] += k
                data[bmap[j, 0, 1], r, r] -= k
                data[bmap[j, 1, 0], r, r] -= k
    return E
