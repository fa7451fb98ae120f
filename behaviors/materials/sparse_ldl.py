"""LDL^T of the global strain step's symmetric positive definite systems (QDLDL with an AMD
ordering per system, the ``qdldl`` package of the OSQP project), behind SuperLU's ``solve``.

The global step (strain_limit_global.py) factorises principal submatrices of ``J W J^T +
alpha diag`` about 40 times a frame on a 128 x 128 cloth; they are symmetric positive
definite, so no pivoting is needed and an LDL^T of the upper triangle is enough. Measured on
the 128 x 128 drop's systems (``graphs/bench/global_factor.py``): SuperLU with the minimum-
degree ordering of each system against QDLDL with its AMD ordering, and against an LDL^T of our
own in numba ordered once at bind (one minimum-degree order of every row the step can have,
restricted to each system: no ordering work per system, but 1.9x the fill and 1.17x SuperLU's
time; not kept).
"""

from __future__ import annotations

import numpy as np
import qdldl


class LDLFactor:
    """P M P^T = L D L^T of a symmetric positive definite CSC matrix M (both triangles, or the
    upper one) by QDLDL; ``solve`` takes one right-hand side or a matrix of them (columns),
    as SuperLU's does."""

    def __init__(self, M):
        self.n = M.shape[0]
        self._s = qdldl.Solver(M.tocsc())

    def solve(self, b):
        b = np.asarray(b, np.float64)
        if b.ndim == 1:
            return self._s.solve(b)
        out = np.empty_like(b)
        for k in range(b.shape[1]):
            out[:, k] = self._s.solve(np.ascontiguousarray(b[:, k]))
        return out
