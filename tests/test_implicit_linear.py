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


def _cloth_system(side=40, k=1e4, seed=5):
    """A cloth-like SPD block system: a side x side grid in a plane, stiff springs along its
    edges and diagonals (k n n^T, n the rest direction: no stiffness across them) plus a unit
    mass term; block-Jacobi PCG needs hundreds of iterations on it (the implicit solver's
    stretch rows)."""
    import scipy.sparse as sp

    rng = np.random.default_rng(seed)
    n = side * side
    pos = np.stack(np.meshgrid(np.arange(side), np.arange(side), indexing="ij"), -1)
    pos = np.concatenate([pos.reshape(-1, 2), 0.1 * rng.normal(size=(n, 1))], 1)
    ij = np.arange(n).reshape(side, side)
    edges = np.concatenate([np.stack([ij[:, :-1].ravel(), ij[:, 1:].ravel()], 1),
                            np.stack([ij[:-1, :].ravel(), ij[1:, :].ravel()], 1),
                            np.stack([ij[:-1, :-1].ravel(), ij[1:, 1:].ravel()], 1)])
    d = pos[edges[:, 1]] - pos[edges[:, 0]]
    d /= np.linalg.norm(d, axis=1)[:, None]
    K = k * rng.uniform(0.5, 2.0, len(edges))[:, None, None] * d[:, :, None] * d[:, None, :]
    rows = np.concatenate([edges[:, 0], edges[:, 1], edges[:, 0], edges[:, 1], np.arange(n)])
    cols = np.concatenate([edges[:, 0], edges[:, 1], edges[:, 1], edges[:, 0], np.arange(n)])
    data = np.concatenate([K, K, -K, -K, np.repeat(np.eye(3)[None], n, 0)])
    A = sp.bsr_matrix(sp.coo_matrix((data.ravel(), (
        (3 * rows[:, None, None] + np.arange(3)[None, :, None]).repeat(3, 2).ravel(),
        (3 * cols[:, None, None] + np.arange(3)[None, None, :]).repeat(3, 1).ravel())),
        shape=(3 * n, 3 * n)).tocsr(), blocksize=(3, 3))
    A.sort_indices()
    diag = np.array([np.flatnonzero(A.indices[A.indptr[i]:A.indptr[i + 1]] == i)[0]
                     + A.indptr[i] for i in range(n)])
    return A, diag, rng.normal(size=(n, 3))


def test_amg_reuse_solves_in_fewer_iterations_and_is_symmetric():
    """preconditioner: amg_reuse (linear.AggregationReuse), both cycles: PCG with it reaches
    the direct solution in under a third of block-Jacobi's iterations on a cloth-like system;
    the preconditioner is a symmetric positive definite operator (<M r, s> = <r, M s>,
    <M r, r> > 0), which PCG needs; after the matrix changes in place (some springs 100x
    stiffer: contacts or strain limits switching on) the kept aggregation, its coarse matrices
    refreshed, still solves the new system without a rebuild."""
    import scipy.sparse.linalg as sla

    from lokigraph.behaviors.solvers.implicit import linear as L

    A, diag, b = _cloth_system()
    n = b.shape[0]
    work = {k: np.zeros((n, 3)) for k in ("r", "z", "p", "Ap")}
    bj = L.BlockJacobi(n)
    bj.setup(A, diag)
    x = np.zeros((n, 3))
    it_bj, res = bj.solve(A, b, 1e-8, 20000, x, work)
    assert res <= 1e-8
    want = sla.spsolve(A.tocsc(), b.reshape(-1)).reshape(-1, 3)
    rng = np.random.default_rng(1)
    r, s = rng.normal(size=(n, 3)), rng.normal(size=(n, 3))
    for cycle in ("additive", "v"):
        P = L.AggregationReuse(n, "tentative", 1e9, max_coarse=60, cycle=cycle)
        P.setup(A, diag)
        x = np.zeros((n, 3))
        it, res = P.solve(A, b, 1e-8, 20000, x, work)
        assert len(P.levels) >= 3  # a multilevel hierarchy, not one dense solve
        assert res <= 1e-8
        np.testing.assert_allclose(x, want, atol=1e-6 * np.abs(want).max())
        assert (2 if cycle == "additive" else 4) * it < it_bj, (cycle, it, it_bj)
        Mr, Ms = np.zeros((n, 3)), np.zeros((n, 3))
        P(r.copy(), Mr)
        P(s.copy(), Ms)
        np.testing.assert_allclose(np.vdot(Mr, s), np.vdot(r, Ms), rtol=1e-9)
        assert np.vdot(Mr, r) > 0.0
        # the matrix changes in place (the solver refills it): a tenth of the rows stiffer
        A2 = A.copy()
        stiff = rng.random(n) < 0.1
        rows = np.repeat(np.arange(n), np.diff(A2.indptr))
        A2.data[stiff[rows] & stiff[A2.indices]] *= 100.0
        A2.data[diag] += 1.0  # keeps it SPD: a scaled SPD part plus the mass
        P.setup(A2, diag)
        x = np.zeros((n, 3))
        it2, res = P.solve(A2, b, 1e-8, 20000, x, work)
        assert res <= 1e-8 and P.builds == 1
        want2 = sla.spsolve(A2.tocsc(), b.reshape(-1)).reshape(-1, 3)
        np.testing.assert_allclose(x, want2, atol=1e-6 * np.abs(want2).max())


def test_amg_reuse_rebuild_policy():
    """amg_rebuild_growth: 0 rebuilds the aggregation at every substep, > 0 only after a
    solve takes more than that many times the CG iterations of the first solve after the last
    build (counted in ``builds``)."""
    from lokigraph.behaviors.solvers.implicit import linear as L

    A, diag, b = _cloth_system(side=20)
    n = b.shape[0]
    work = {k: np.zeros((n, 3)) for k in ("r", "z", "p", "Ap")}
    x = np.zeros((n, 3))
    every = L.AggregationReuse(n, growth=0.0, max_coarse=60)
    kept = L.AggregationReuse(n, growth=2.0, max_coarse=60)
    for _ in range(3):
        for P in (every, kept):
            P.begin_substep()
            P.setup(A, diag)
            P.solve(A, b, 1e-6, 500, x, work)
    assert every.builds == 3 and kept.builds == 1
    base = kept.base_it
    assert base > 0
    kept.setup(A, diag)
    kept.solve(A, b, 1e-30, 2 * base + 1, x, work)  # more than twice the first solve's
    assert kept.rebuild
    kept.setup(A, diag)
    kept.solve(A, b, 1e-6, 500, x, work)
    assert kept.builds == 2 and not kept.rebuild
    kept.setup(A, diag)  # a right-hand side of zeros: no iteration, no refresh
    assert kept.solve(A, 0.0 * b, 1e-6, 500, x, work) == (0, 0.0) and kept.stale


def test_amg_reuse_on_the_cloth_sphere_drop():
    """preconditioner: amg_reuse in the solver on graphs/bench/cloth_sphere_32.yaml (implicit,
    its 2 substeps, 10 frames through the impact): fewer than half the CG iterations of
    block_jacobi, every linear solve to cg_tolerance (block_jacobi's stop at the 500 cap),
    the same Newton iteration count within 10 %, edge strain under 5 % and no intersecting
    triangle pair in any frame."""
    from pathlib import Path

    from lokigraph.behaviors.collision.intersect import intersect_meshes
    from lokigraph.compile import compile_scene
    from lokigraph.run import Simulation
    from lokigraph.scene import load_scene

    path = Path(__file__).resolve().parents[1] / "graphs" / "bench" / "cloth_sphere_32.yaml"
    out = {}
    for pc in ("block_jacobi", "amg_reuse"):
        sc = load_scene(path)
        sc.spec = sc.spec.model_copy(update={"solver": "implicit", "graph_overrides": {
            "implicit_solver": {"preconditioner": pc}}})
        c = compile_scene(sc)
        sim = Simulation(c)
        sd = c.schedule.find("StretchConstraint")[0].data
        cl = c.scene.element("cloth")
        tot = {"cg": 0, "newton": 0, "res": 0.0, "strain": 0.0, "pairs": 0}
        for _ in range(10):
            st = sim.step_frame()
            q = sim.state.particle_q
            tot["cg"] += st.get("cg_iterations", 0)
            tot["newton"] += st.get("newton_iterations", 0)
            tot["res"] = max(tot["res"], st.get("max_cg_residual", 0.0))
            e = np.linalg.norm(q[sd.idx[:, 1]] - q[sd.idx[:, 0]], axis=1) / sd.rest - 1.0
            tot["strain"] = max(tot["strain"], float(e.max()))
            tot["pairs"] = max(tot["pairs"], int(intersect_meshes(
                [(q[cl.vertex_slice], cl.geometry.triangles)], touching=False)[0]))
        out[pc] = tot
    bj, amg = out["block_jacobi"], out["amg_reuse"]
    assert bj["cg"] > 1000 and bj["res"] > 1e-3  # the drop's solves are hard for block-Jacobi
    assert 2 * amg["cg"] < bj["cg"], out
    assert amg["res"] <= 1e-3 * (1 + 1e-9), out
    assert abs(amg["newton"] - bj["newton"]) <= 0.1 * bj["newton"], out
    assert amg["strain"] < 0.05 and amg["pairs"] == 0, out


def test_direct_solve_is_exact_and_preconditions_the_rank_one_terms():
    """preconditioner: direct (linear.Direct, the LDL^T of the Newton matrix): on a cloth-like
    system that block-Jacobi PCG needs hundreds of iterations for, one solve reaches the
    scipy direct solution (relative residual ~1e-12); with a rank-one term k u u^T in the
    product (a volume row, ``lowrank``) PCG preconditioned by it converges to the dense
    solution of A + k u u^T in a few iterations."""
    import scipy.sparse.linalg as spla

    from lokigraph.behaviors.solvers.implicit import linear as L

    A, diag, b = _cloth_system()
    n = b.shape[0]
    work = {k: np.zeros((n, 3)) for k in ("r", "z", "p", "Ap")}
    P = L.Direct(n)
    P.setup(A, diag)
    x = np.zeros((n, 3))
    it, res = P.solve(A, b, 1e-3, 500, x, work)
    want = spla.spsolve(A.tocsc(), b.reshape(-1)).reshape(-1, 3)
    assert it == 1 and res < 1e-9
    assert np.abs(x - want).max() < 1e-8 * np.abs(want).max()
    jac = L.BlockJacobi(n)
    jac.setup(A, diag)
    it_j, _ = jac.solve(A, b, 1e-6, 5000, np.zeros((n, 3)), work)
    assert it_j > 100  # what the exact solve replaces
    # a rank-one term over every vertex, its diagonal blocks not in A (sub 0)
    rng = np.random.default_rng(2)
    U = rng.normal(size=(1, n, 3))
    k = np.array([50.0])
    x = np.zeros((n, 3))
    it, res = P.solve(A, b, 1e-10, 100, x, work, lowrank=(U, k, 0.0))
    dense = A.toarray() + k[0] * np.outer(U[0].ravel(), U[0].ravel())
    want = np.linalg.solve(dense, b.reshape(-1)).reshape(-1, 3)
    assert it <= 5 and res < 1e-10
    assert np.abs(x - want).max() < 1e-7 * np.abs(want).max()
