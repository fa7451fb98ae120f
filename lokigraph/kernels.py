"""Shared numerical kernels (numba) used by several behaviors."""

from __future__ import annotations

import numpy as np
from numba import njit, prange


@njit(cache=True, parallel=True)
def implicit_drag_solve(v, mass, D, Du, h, inv_mass):
    """In place, per vertex i with mass m_i > 0 and inv_mass > 0:
    (m_i I + h D_i) v_i' = m_i v_i + h Du_i, where D_i is an SPD 3x3 drag matrix [kg/s] and
    Du_i = D_i u_i [N] (u the air velocity). Unconditionally stable; in still air it never adds
    kinetic energy. Vertices with inv_mass == 0 are left alone."""
    n = v.shape[0]
    for i in prange(n):
        if inv_mass[i] == 0.0:
            continue
        m = mass[i]
        a00 = m + h * D[i, 0, 0]
        a01 = h * D[i, 0, 1]
        a02 = h * D[i, 0, 2]
        a10 = h * D[i, 1, 0]
        a11 = m + h * D[i, 1, 1]
        a12 = h * D[i, 1, 2]
        a20 = h * D[i, 2, 0]
        a21 = h * D[i, 2, 1]
        a22 = m + h * D[i, 2, 2]
        b0 = m * v[i, 0] + h * Du[i, 0]
        b1 = m * v[i, 1] + h * Du[i, 1]
        b2 = m * v[i, 2] + h * Du[i, 2]
        c00 = a11 * a22 - a12 * a21
        c01 = a02 * a21 - a01 * a22
        c02 = a01 * a12 - a02 * a11
        c10 = a12 * a20 - a10 * a22
        c11 = a00 * a22 - a02 * a20
        c12 = a02 * a10 - a00 * a12
        c20 = a10 * a21 - a11 * a20
        c21 = a01 * a20 - a00 * a21
        c22 = a00 * a11 - a01 * a10
        det = a00 * c00 + a01 * c10 + a02 * c20
        inv = 1.0 / det
        v[i, 0] = (c00 * b0 + c01 * b1 + c02 * b2) * inv
        v[i, 1] = (c10 * b0 + c11 * b1 + c12 * b2) * inv
        v[i, 2] = (c20 * b0 + c21 * b1 + c22 * b2) * inv


def first_nonfinite(a: np.ndarray) -> int:
    bad = ~np.isfinite(a).reshape(len(a), -1).all(axis=1)
    return int(np.argmax(bad)) if bad.any() else -1
