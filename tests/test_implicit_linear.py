"""The implicit solver's linear algebra, exact speedups (issue #11: the cost per CG iteration):
the parallel block-Jacobi PCG is bitwise the serial loop."""

from __future__ import annotations

import numpy as np
from numba import get_num_threads, set_num_threads

from test_implicit_forcing import _mesh_system


def test_parallel_pcg_is_bitwise_the_serial_loop():
    """pcg_block_jacobi_par (vertex loops in prange, dot products summed serially from
    per-vertex terms) returns bitwise the iterates, iteration count and residual of the serial
    fused loop at 1 and at every available thread count, converged, at the cap and with the
    ``after`` stop; BlockJacobi.solve picks it with PARALLEL_PCG from PARALLEL_MIN_VERTICES
    unknowns on more than one thread, with the same result. An iterate differs from the start
    (the test can fail)."""
    from lokigraph.behaviors.solvers.implicit import linear as L

    A, diag, b = _mesh_system(seed=3, side=20)
    n = b.shape[0]
    inv = np.zeros((n, 3, 3))
    L.invert_blocks(A.data[diag], inv)
    keep = get_num_threads()
    try:
        for tol, after, loose, maxit in ((1e-10, 5001, 0.0, 5000), (1e-10, 5001, 0.0, 23),
                                         (1e-10, 10, 0.5, 5000)):
            x0, w0 = np.zeros((n, 3)), [np.zeros((n, 3)) for _ in range(4)]
            want = L.pcg_block_jacobi_after(A.indptr, A.indices, A.data, inv, b, tol, after,
                                            loose, maxit, x0, *w0)
            assert np.abs(x0).max() > 0.0
            for th in sorted({1, keep}):
                set_num_threads(th)
                x, w = np.zeros((n, 3)), [np.zeros((n, 3)) for _ in range(4)]
                got = L.pcg_block_jacobi_par(A.indptr, A.indices, A.data, inv, b, tol, after,
                                             loose, maxit, x, *w, np.zeros((n, 2)))
                assert got == want, (th, got, want)
                assert np.array_equal(x, x0)
                assert np.array_equal(w[0], w0[0])  # the residual r
            if maxit == 23:
                assert want[0] == 23 and want[1] > tol
        set_num_threads(keep)
        saved = L.PARALLEL_MIN_VERTICES, L.PARALLEL_PCG
        L.PARALLEL_MIN_VERTICES, L.PARALLEL_PCG = 1, True  # the switch, on this small system
        try:
            P = L.BlockJacobi(n)
            P.setup(A, diag)
            work = {k: np.zeros((n, 3)) for k in ("r", "z", "p", "Ap")}
            x = np.zeros((n, 3))
            got = P.solve(A, b, 1e-6, 5000, x, work)
            x1 = np.zeros((n, 3))
            want = L.pcg_block_jacobi(A.indptr, A.indices, A.data, inv, b, 1e-6, 5000, x1,
                                      *[np.zeros((n, 3)) for _ in range(4)])
            assert got == want and np.array_equal(x, x1)
        finally:
            L.PARALLEL_MIN_VERTICES, L.PARALLEL_PCG = saved
    finally:
        set_num_threads(keep)


def test_gather_blocks_is_bitwise_the_scatter():
    """energy.gather_blocks (the energies' blocks added matrix block by matrix block through
    gather_map) gives bitwise the matrix of scatter_blocks, on top of blocks already there (as
    after another energy), for stencils of 2 and 4 vertices whose local blocks land many to one
    block and in an order unlike the rows' (shuffled terms); the matrix changes (the test can
    fail)."""
    from lokigraph.behaviors.solvers.implicit.energy import (build_pattern, gather_blocks,
                                                             gather_map, scatter_blocks)

    rng = np.random.default_rng(2)
    side = 15
    n = side * side
    idx = np.arange(n).reshape(side, side)
    edges = np.concatenate([np.stack([idx[:, :-1].ravel(), idx[:, 1:].ravel()], 1),
                            np.stack([idx[:-1, :].ravel(), idx[1:, :].ravel()], 1)])
    quads = np.stack([idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel(),
                      idx[1:, 1:].ravel()], 1)
    edges = edges[rng.permutation(len(edges))]
    quads = quads[rng.permutation(len(quads))]
    indptr, indices, diag, maps = build_pattern(n, [edges, quads])
    nb = len(indices)
    base = rng.normal(size=(nb, 3, 3))
    for mp, m, k in ((maps[0], len(edges), 2), (maps[1], len(quads), 4)):
        h = rng.normal(size=(m, k, k, 3, 3)) * 10.0 ** rng.uniform(-8, 8, size=(m, 1, 1, 1, 1))
        want = base.copy()
        scatter_blocks(want, mp, h)
        got = base.copy()
        ptr, src = gather_map(mp, nb)
        gather_blocks(got, ptr, src, h)
        assert np.array_equal(got, want)
        assert np.abs(want - base).max() > 0.0
        assert ptr[-1] == m * k * k
