"""The implicit solver's linear algebra, exact speedups (issue #11: the cost per Newton and per
CG iteration): the parallel block-Jacobi PCG and the hinges' blocks assembled straight into the
Newton matrix are bitwise what they replace."""

from __future__ import annotations

import numpy as np
from numba import get_num_threads, set_num_threads

from test_implicit_forcing import _mesh_system


def test_parallel_pcg_is_bitwise_the_serial_loop():
    """pcg_block_jacobi_par (vertex loops in prange, dot products summed serially from
    per-vertex terms) returns bitwise the iterates, iteration count and residual of the serial
    fused loop at 1 and at every available thread count, converged, at the cap and with the
    ``after`` stop; BlockJacobi.solve picks it from PARALLEL_MIN_VERTICES unknowns on more than
    one thread with the same result. An iterate differs from the start (the test can fail)."""
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
        saved = L.PARALLEL_MIN_VERTICES
        L.PARALLEL_MIN_VERTICES = 1  # the solver's switch, on this small system
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
            L.PARALLEL_MIN_VERTICES = saved
    finally:
        set_num_threads(keep)


def _hinges(side=9, seed=4):
    """A crumpled side x side grid's hinge quads (i, j, k, l) with rest angles, compliances and
    dropoffs, and the positions."""
    rng = np.random.default_rng(seed)
    g = np.stack(np.meshgrid(np.arange(side), np.arange(side), indexing="ij"), -1).reshape(-1, 2)
    x = np.zeros((side * side, 3))
    x[:, 0] = g[:, 0] * 0.1
    x[:, 2] = g[:, 1] * 0.1
    x += rng.normal(scale=0.02, size=x.shape)
    quads = []
    for i in range(side - 1):
        for j in range(side - 1):
            a, b, c, d = i * side + j, i * side + j + 1, (i + 1) * side + j, (i + 1) * side + j + 1
            quads.append((b, c, a, d))  # the diagonal b-c shared by triangles (a,b,c), (b,d,c)
            if j + 1 < side - 1:
                quads.append((b, d, c, d + 1))  # edge b-d between this cell and the next
    quads = np.array(quads, dtype=np.int64)
    m = len(quads)
    rest = rng.uniform(-0.3, 0.3, m)
    alpha = 10.0 ** rng.uniform(-3, 1, m)
    alpha[::7] = np.inf  # some off
    dropoff = rng.uniform(0.0, 2.0, m)
    return x, quads, rest, alpha, dropoff


def test_hinge_blocks_into_the_matrix_are_bitwise_the_scatter():
    """dihedral_energy_into (the hinges' blocks added into the BSR data through the block map,
    BendConstraint.energy_assemble) gives bitwise the energy, gradient and matrix of
    dihedral_energy + scatter_blocks, also on top of blocks already in the matrix (another
    energy's, as in the solver); the matrix is not zero (the test can fail)."""
    from lokigraph.behaviors.materials.bend import dihedral_energy, dihedral_energy_into
    from lokigraph.behaviors.solvers.implicit.energy import build_pattern, scatter_blocks

    x, quads, rest, alpha, dropoff = _hinges()
    n = len(x)
    indptr, indices, diag, maps = build_pattern(n, [quads])
    rng = np.random.default_rng(1)
    base = rng.normal(size=(len(indices), 3, 3))
    out = []
    for into in (False, True):
        data = base.copy()
        grad = np.full((n, 3), 0.25)
        if into:
            E = dihedral_energy_into(x, quads, rest, alpha, dropoff, 2, grad, data, maps[0],
                                     np.zeros((1, 1, 1, 3, 3)))
        else:
            h = np.zeros((len(quads), 4, 4, 3, 3))
            E = dihedral_energy(x, quads, rest, alpha, dropoff, 2, grad, h)
            scatter_blocks(data, maps[0], h)
        out.append((E, grad, data))
    (E0, g0, d0), (E1, g1, d1) = out
    assert E0 == E1 and E0 > 0.0
    assert np.array_equal(g0, g1)
    assert np.array_equal(d0, d1)
    assert np.abs(d0 - base).max() > 0.0
